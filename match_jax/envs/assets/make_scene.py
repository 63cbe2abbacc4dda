"""Writes fpih_scene.xml: the Franka FR3 arm, hand, peg and hole block for fragile peg-in-hole.

Run `python match_jax/envs/assets/make_scene.py` after changing a number here; the generated XML is
committed so that nothing is generated or downloaded at run time. Units: meters, kilograms, radians.

Sources of the numbers (facts, not copied code):
- Kinematics: Franka's published modified-DH parameters of the FR3 (a, d, alpha below).
- Joint position limits and torque limits: FR3 datasheet.
- Link masses, centres of mass and principal inertias: published identified dynamic parameters of
  the FR3 (the same values MuJoCo Menagerie's FR3 model carries), expressed in the DH link frames.
- Peg and hole dimensions: the paper and IsaacLab Factory (docs/task.md).
"""

from __future__ import annotations

import math
import pathlib

import numpy as np

# Modified DH (Craig): frame i = RotX(alpha_{i-1}) TransX(a_{i-1}) RotZ(q_i) TransZ(d_i).
DH_A = (0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088)
DH_D = (0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.0)
DH_ALPHA = (0.0, -math.pi / 2, math.pi / 2, math.pi / 2, -math.pi / 2, math.pi / 2, math.pi / 2)
FLANGE_D = 0.107
JOINT_LIMITS = (
    (-2.7437, 2.7437), (-1.7837, 1.7837), (-2.9007, 2.9007), (-3.0421, -0.1518),
    (-2.8065, 2.8065), (0.5445, 4.5169), (-3.0159, 3.0159),
)
TORQUE_LIMITS = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
ARMATURE = (0.195, 0.195, 0.195, 0.195, 0.074, 0.074, 0.074)
JOINT_DAMPING = 0.21
# (mass kg, com in link frame m, principal-axes quaternion wxyz, principal inertias kg m^2)
LINK_INERTIA = (
    (2.92747, (4.128e-07, -0.0181251, -0.0386036), (0.998098, -0.0605364, 0.00380499, 0.0110109),
     (0.0239286, 0.0227246, 0.00610634)),
    (2.93554, (0.00318289, -0.0743222, 0.00881461), (0.502599, 0.584437, -0.465998, 0.434366),
     (0.0629567, 0.0411924, 0.0246371)),
    (2.2449, (0.0407016, -0.00482006, -0.0289731), (0.921025, -0.244161, 0.155272, 0.260745),
     (0.0267409, 0.0189869, 0.0171587)),
    (2.6156, (-0.0459101, 0.0630493, -0.00851879), (0.438018, 0.803311, 0.00937812, 0.403414),
     (0.05139, 0.0372717, 0.0160047)),
    (2.32712, (-0.00160396, 0.0292536, -0.0972966), (0.919031, 0.125604, 0.0751531, -0.366003),
     (0.0579335, 0.0449144, 0.0130634)),
    (1.81704, (0.0597131, -0.0410295, -0.0101693), (0.621301, 0.552665, 0.510011, 0.220081),
     (0.0175039, 0.0161123, 0.00193529)),
    (0.627143, (0.00452258, 0.00862619, -0.0161633), (0.727579, 0.0978688, -0.24906, 0.63168),
     (0.000223836, 0.000223642, 5.64132e-07)),
)
# Franka hand with fingers, lumped into one rigid body (the grasp is not part of the task).
HAND_MASS = 0.73
HAND_TCP = 0.1034  # flange -> fingertip centre, along the hand z axis
# Peg (paper / Factory): 7.986 mm diameter, 50 mm long, 19 g, tip 32 mm below the fingertip frame.
PEG_RADIUS = 0.003993
PEG_HALF_LENGTH = 0.025
PEG_CHAMFER = 0.0005
PEG_SIDES = 12
PEG_MASS = 0.019
PEG_TIP_BELOW_TCP = 0.032
# Hole: 9.0 mm bore, 25 mm deep, 40 x 40 mm block. The bore wall is a ring of vertical capsules whose
# rounded tops act as a ~1 mm chamfer; four boxes frame the ring and form the block's top face.
HOLE_DEPTH = 0.025
BORE_RADIUS = 0.0045
WALL_CAPSULE_RADIUS = 0.001
WALL_CAPSULES = 16
BLOCK_HALF_WIDTH = 0.020
FRICTION = 0.75


def _fmt(values) -> str:
  return " ".join(f"{v:.9g}" for v in values)


def _quat_rot_x(angle: float) -> tuple[float, float, float, float]:
  return (math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0)


def peg_vertices() -> np.ndarray:
  """Vertices (m, peg frame) of a PEG_SIDES-gon prism with a chamfered tip at +z."""
  rings = [(-PEG_HALF_LENGTH, PEG_RADIUS), (PEG_HALF_LENGTH - PEG_CHAMFER, PEG_RADIUS),
           (PEG_HALF_LENGTH, PEG_RADIUS - PEG_CHAMFER)]
  verts = []
  for z, r in rings:
    for k in range(PEG_SIDES):
      ang = 2 * math.pi * (k + 0.5) / PEG_SIDES
      verts.append((r * math.cos(ang), r * math.sin(ang), z))
  return np.array(verts)


def _arm_xml() -> str:
  lines = []
  indent = "    "
  for i in range(7):
    alpha, a, d = DH_ALPHA[i], DH_A[i], DH_D[i]
    # Position of frame i in frame i-1: TransX(a) then RotX(alpha) applied to TransZ(d).
    pos = (a, -math.sin(alpha) * d, math.cos(alpha) * d)
    quat = _quat_rot_x(alpha)
    mass, com, iquat, inertia = LINK_INERTIA[i]
    lo, hi = JOINT_LIMITS[i]
    lines += [
        f'{indent}<body name="link{i + 1}" pos="{_fmt(pos)}" quat="{_fmt(quat)}">',
        f'{indent}  <inertial pos="{_fmt(com)}" quat="{_fmt(iquat)}" mass="{mass}" '
        f'diaginertia="{_fmt(inertia)}"/>',
        f'{indent}  <joint name="joint{i + 1}" range="{lo} {hi}" armature="{ARMATURE[i]}" '
        f'actuatorfrcrange="{-TORQUE_LIMITS[i]} {TORQUE_LIMITS[i]}"/>',
        f'{indent}  <geom class="visual" type="capsule" fromto="0 0 -0.05 0 0 0.05" size="0.045"/>',
    ]
    indent += "  "
  hand_quat = (math.cos(-math.pi / 8), 0.0, 0.0, math.sin(-math.pi / 8))  # hand yawed -45 deg
  peg_center = HAND_TCP + PEG_TIP_BELOW_TCP - PEG_HALF_LENGTH
  lines += [
      f'{indent}<body name="hand" pos="0 0 {FLANGE_D}" quat="{_fmt(hand_quat)}">',
      f'{indent}  <inertial pos="0 0 0.04" mass="{HAND_MASS}" diaginertia="0.0025 0.001 0.0017"/>',
      f'{indent}  <geom class="visual" type="box" pos="0 0 0.06" size="0.02 0.09 0.025"/>',
      f'{indent}  <site name="ee" pos="0 0 {HAND_TCP}" size="0.002"/>',
      # Wrist force/torque sensor frame: the flange, where the hand meets link 7 (sensors below).
      f'{indent}  <site name="wrist" pos="0 0 0" size="0.002"/>',
      f'{indent}  <body name="peg" pos="0 0 {peg_center:.6f}">',
      f'{indent}    <inertial pos="0 0 0" mass="{PEG_MASS}" diaginertia="4.0e-06 4.0e-06 1.5e-07"/>',
      f'{indent}    <geom name="peg" type="mesh" mesh="peg" rgba="0.9 0.6 0.1 1" contype="0" '
      f'conaffinity="0"/>',
      # Rim proxy: the block's top face meets the peg through this capsule, whose lowest point is
      # the peg tip (capsule-box is ~5x cheaper in MJX than box-mesh; the bore walls meet the mesh).
      f'{indent}    <geom name="peg_rim_proxy" type="capsule" size="{PEG_RADIUS}" '
      f'fromto="0 0 {-PEG_HALF_LENGTH + PEG_RADIUS} 0 0 {PEG_HALF_LENGTH - PEG_RADIUS}" group="3" '
      f'contype="0" conaffinity="0"/>',
      f'{indent}    <site name="peg_tip" pos="0 0 {PEG_HALF_LENGTH}" size="0.001"/>',
      f'{indent}  </body>',
      f'{indent}</body>',
  ]
  for _ in range(7):
    indent = indent[:-2]
    lines.append(f"{indent}</body>")
  return "\n".join(lines)


def _hole_xml() -> tuple[str, list[str]]:
  """Geoms of the hole block (in the mocap body 'hole', origin at the hole bottom centre)."""
  geoms, names = [], []
  ring = BORE_RADIUS + WALL_CAPSULE_RADIUS
  z0, z1 = WALL_CAPSULE_RADIUS, HOLE_DEPTH - WALL_CAPSULE_RADIUS
  for k in range(WALL_CAPSULES):
    ang = 2 * math.pi * k / WALL_CAPSULES
    x, y = ring * math.cos(ang), ring * math.sin(ang)
    name = f"bore{k:02d}"
    names.append(name)
    geoms.append(f'      <geom name="{name}" type="capsule" size="{WALL_CAPSULE_RADIUS}" '
                 f'fromto="{_fmt((x, y, z0, x, y, z1))}" rgba="0.3 0.5 0.8 1"/>')
  half_h = HOLE_DEPTH / 2
  w, s = BLOCK_HALF_WIDTH, ring
  rims = {  # name: (center x, center y, half x, half y): four boxes framing the capsule ring
      "rim_px": ((w + s) / 2, 0.0, (w - s) / 2, w),
      "rim_nx": (-(w + s) / 2, 0.0, (w - s) / 2, w),
      "rim_py": (0.0, (w + s) / 2, s, (w - s) / 2),
      "rim_ny": (0.0, -(w + s) / 2, s, (w - s) / 2),
  }
  for name, (cx, cy, hx, hy) in rims.items():
    names.append(name)
    geoms.append(f'      <geom name="{name}" type="box" pos="{_fmt((cx, cy, half_h))}" '
                 f'size="{_fmt((hx, hy, half_h))}" rgba="0.3 0.5 0.8 1"/>')
  return "\n".join(geoms), names


def scene_xml() -> str:
  hole_geoms, hole_names = _hole_xml()
  pairs = "\n".join(
      f'    <pair geom1="{"peg_rim_proxy" if n.startswith("rim") else "peg"}" geom2="{n}"/>'
      for n in ["floor"] + hole_names)
  motors = "\n".join(f'    <motor name="motor{i + 1}" joint="joint{i + 1}" ctrlrange="{-t} {t}"/>'
                     for i, t in enumerate(TORQUE_LIMITS))
  return f"""<!-- Generated by make_scene.py: edit the numbers there, not here. -->
<mujoco model="fr3_fpih">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.00833333333" integrator="Euler" cone="pyramidal" solver="Newton"
          iterations="8" ls_iterations="8">
  </option>
  <custom>
    <!-- MJX: collide only the 4 nearest geoms of each pair type (the peg never touches more). -->
    <numeric name="max_geom_pairs" data="4"/>
  </custom>
  <default>
    <joint axis="0 0 1" damping="{JOINT_DAMPING}"/>
    <geom contype="0" conaffinity="0"/>
    <default class="visual">
      <geom group="2" rgba="0.95 0.95 0.95 1" mass="0" density="0"/>
    </default>
    <pair condim="3" friction="{FRICTION} {FRICTION} 0.005 0.0001 0.0001"
          solref="0.02 1" solimp="0.99 0.999 0.001 0.5 2"/>
  </default>
  <asset>
    <mesh name="peg" vertex="{_fmt(peg_vertices().ravel())}"/>
  </asset>
  <worldbody>
    <light pos="0.5 0 1.5" dir="0 0 -1"/>
    <geom name="floor" type="plane" size="1 1 0.05" rgba="0.8 0.8 0.75 1"/>
    <body name="base">
{_arm_xml()}
    </body>
    <body name="hole" mocap="true" pos="0.55 0 0">
{hole_geoms}
      <site name="hole_bottom" pos="0 0 0" size="0.001"/>
      <site name="hole_top" pos="0 0 {HOLE_DEPTH}" size="0.001"/>
    </body>
  </worldbody>
  <contact>
{pairs}
  </contact>
  <sensor>
    <!-- Wrist force/torque: the wrench link 7 exerts on the hand subtree (hand + peg), wrist frame. -->
    <force name="wrist_force" site="wrist"/>
    <torque name="wrist_torque" site="wrist"/>
  </sensor>
  <actuator>
{motors}
  </actuator>
</mujoco>
"""


def main() -> None:
  out = pathlib.Path(__file__).with_name("fpih_scene.xml")
  out.write_text(scene_xml())
  print(f"wrote {out}")


if __name__ == "__main__":
  main()
