"""Operational-space control laws: pose, VICES (variable stiffness) and hybrid position/force.

Pure functions of the arm's dynamics quantities, evaluated every physics substep inside `env.step`.
All vectors are in the world frame; translation in meters, rotation in radians, force in newtons,
torque in newton-meters. The task point is the end-effector (fingertip-centre) site.

    pose:   u = J^T [k_p (x_d - x) - k_d xdot] + g(q)                      (Factory, default)
            u = J^T M_x [k_p (x_d - x) - k_d xdot] + g(q)                  (paper, use_task_inertia)
    hybrid: position law on axes with Lambda = 1, on the others the task force
            k_f (f_d - f_ee)                    (the authors', default)
            k_f (f_d - f_ee) + f_d - k_vf xdot  (the damped law: feed-forward and damping)

with M_x = (J M^-1 J^T)^-1, Lambda the per-axis selection (1 = position control) on the three
translational axes only (rotation is always pose-controlled), f_ee the force the robot applies to the
environment. On Factory's law k_p is a stiffness at the end effector (N/m, N m/rad) and k_d a damping
(N s/m); on the paper's law both are per unit task inertia. A dynamically consistent null-space term
pulls the redundant 7th degree of freedom toward a posture. `force_through_task_inertia=True,
force_feedforward=False, force_damping=(0, 0, 0)` with `use_task_inertia=True` is the paper's literal
hybrid law.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp


DAMPED_FORCE_DAMPING = (20.0, 20.0, 20.0)  # N s/m: k_vf of the 'damped' force law


@dataclasses.dataclass(frozen=True)
class ControllerConfig:
    """Gains of the operational-space controller (IsaacLab Factory's law and gains, and the authors'
    'literal' force law, by default).

    Attributes:
      pos_stiffness: k_p for x, y, z (N/m on Factory's law; 1/s^2, i.e. N/m per kg, through M_x).
      rot_stiffness: k_p for rotation about x, y, z (N m/rad; 1/s^2 through M_x).
      force_gain: k_f, proportional gain of the force law.
      force_feedforward: add f_d itself to the task force on force-controlled axes, so that the
        steady-state contact force equals f_d (without it: k_f / (1 + k_f) f_d).
      force_through_task_inertia: multiply the force term by M_x as the paper's equation is written
        (unstable in contact with this arm: docs/controllers.md).
      force_damping: k_vf per world axis x, y, z: velocity damping -k_vf xdot (N s/m; through M_x on the
        paper's law, 1/s) on the force-controlled axes, as in Khatib's hybrid law; 0 gives the paper's
        and the authors' undamped law.
      null_stiffness: joint-space stiffness of the posture term (1/s^2), damping is critical.
      use_task_inertia: False: Factory's J^T law (default; the authors' code); True: the paper's J^T M_x.
      gravity_compensation: add the bias forces g(q) + Coriolis (MJX qfrc_bias).
      task_inertia_damping: Tikhonov term added to J M^-1 J^T before inverting (near singularities).
    """

    pos_stiffness: tuple[float, float, float] = (100.0, 100.0, 100.0)
    rot_stiffness: tuple[float, float, float] = (30.0, 30.0, 30.0)
    force_gain: float = 0.5
    force_feedforward: bool = False
    force_through_task_inertia: bool = False
    force_damping: tuple[float, float, float] = (0.0, 0.0, 0.0)
    null_stiffness: float = 10.0
    use_task_inertia: bool = False
    gravity_compensation: bool = True
    task_inertia_damping: float = 1e-6

    def with_force_law(self, law: str) -> "ControllerConfig":
        """This config with force law `law`: 'damped' k_f (f_d - f) + f_d - k_vf xdot (the default terms) or
        'literal' k_f (f_d - f), no feed-forward and no damping (the authors' code; the paper's
        equation without the M_x that `force_through_task_inertia` adds)."""
        if law == "damped":
            return dataclasses.replace(self, force_feedforward=True, force_damping=DAMPED_FORCE_DAMPING)
        if law == "literal":
            return dataclasses.replace(self, force_feedforward=False, force_damping=(0.0, 0.0, 0.0))
        raise ValueError(f"force law must be 'damped' or 'literal', got {law!r}")

    def __post_init__(self):
        for name in ("pos_stiffness", "rot_stiffness", "force_damping"):
            values = getattr(self, name)
            if len(values) != 3 or any(not (v >= 0) for v in values):
                raise ValueError(f"ControllerConfig.{name} must be 3 non-negative numbers, got {values!r}")
        if not self.force_gain >= 0:
            raise ValueError(f"ControllerConfig.force_gain must be >= 0, got {self.force_gain!r}")
        if not self.null_stiffness >= 0:
            raise ValueError(f"ControllerConfig.null_stiffness must be >= 0, got {self.null_stiffness!r}")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ArmDynamics:
    """What the control law needs from the simulator at one instant (world frame).

    Attributes:
      qpos, qvel: joint positions (rad) and velocities (rad/s), shape (7,).
      mass_matrix: joint-space inertia M(q) including rotor armature, (7, 7).
      bias: Coriolis, centrifugal and gravity torques, (7,) (MJX qfrc_bias).
      jacobian: end-effector Jacobian, rows 0-2 translational, 3-5 rotational, (6, 7).
      ee_pos: end-effector position (m), (3,).
      ee_rot: end-effector orientation as a rotation matrix (columns are the EE axes), (3, 3).
      ee_force: force the robot applies to the environment (N), (3,).
    """

    qpos: jax.Array
    qvel: jax.Array
    mass_matrix: jax.Array
    bias: jax.Array
    jacobian: jax.Array
    ee_pos: jax.Array
    ee_rot: jax.Array
    ee_force: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ControlTarget:
    """A low-level command, held over the substeps of one policy step.

    Attributes:
      pos: position target x_d (m, world), (3,).
      rot: orientation target R_d (rotation matrix), (3, 3).
      force: force target f_d (N, world, robot on environment), (3,).
      position_axes: Lambda, 1.0 = position control, 0.0 = force control per world axis, (3,).
      pos_stiffness: per-axis translational k_p (VICES sets it; others use the config's), (3,).
      posture: null-space posture target (rad), (7,).
      rot_stiffness: per-axis rotational k_p (N m/rad), (3,); None = the config's.
      force_gain: k_f of the force law, (); None = the config's.
    """

    pos: jax.Array
    rot: jax.Array
    force: jax.Array
    position_axes: jax.Array
    pos_stiffness: jax.Array
    posture: jax.Array
    rot_stiffness: jax.Array | None = None
    force_gain: jax.Array | None = None


def orientation_error(rot: jax.Array, rot_target: jax.Array) -> jax.Array:
    """Rotation vector (rad, world) taking `rot` to `rot_target`: small-angle-exact, 0.5 sum e_i x e_d,i."""
    return 0.5 * jnp.sum(jnp.cross(rot.T, rot_target.T), axis=0)


def task_inertia(mass_matrix: jax.Array, jacobian: jax.Array, damping: float = 1e-6) -> jax.Array:
    """Operational-space inertia M_x = (J M^-1 J^T)^-1, (6, 6)."""
    minv_jt = jnp.linalg.solve(mass_matrix, jacobian.T)
    lam_inv = jacobian @ minv_jt
    return jnp.linalg.inv(lam_inv + damping * jnp.eye(lam_inv.shape[0]))


def hybrid_torque(dyn: ArmDynamics, target: ControlTarget, config: ControllerConfig) -> jax.Array:
    """Joint torques (N m, unclamped) of the hybrid law; Lambda = 1 on all axes gives the pose law."""
    kp_pos = target.pos_stiffness
    kd_pos = 2.0 * jnp.sqrt(kp_pos)
    kp_rot = jnp.asarray(config.rot_stiffness if target.rot_stiffness is None else target.rot_stiffness)
    force_gain = config.force_gain if target.force_gain is None else target.force_gain
    kd_rot = 2.0 * jnp.sqrt(kp_rot)

    ee_vel = dyn.jacobian @ dyn.qvel
    pos_cmd = kp_pos * (target.pos - dyn.ee_pos) - kd_pos * ee_vel[:3]
    force_axes = 1.0 - target.position_axes
    force_cmd = force_axes * force_gain * (target.force - dyn.ee_force)
    force_axes_damping = -force_axes * jnp.asarray(config.force_damping) * ee_vel[:3]  # Khatib's k_vf xdot term
    rot_cmd = kp_rot * orientation_error(dyn.ee_rot, target.rot) - kd_rot * ee_vel[3:]
    zeros3 = jnp.zeros(3)
    if config.force_through_task_inertia:  # the paper's equation, literally
        motion_cmd = jnp.concatenate([target.position_axes * pos_cmd + force_cmd + force_axes_damping, rot_cmd])
        wrench = jnp.zeros(6)
    else:
        motion_cmd = jnp.concatenate([target.position_axes * pos_cmd + force_axes_damping, rot_cmd])
        wrench = jnp.concatenate([force_cmd, zeros3])
    if config.force_feedforward:
        wrench = wrench + jnp.concatenate([force_axes * target.force, zeros3])

    mx = task_inertia(dyn.mass_matrix, dyn.jacobian, config.task_inertia_damping)
    task_force = (mx @ motion_cmd if config.use_task_inertia else motion_cmd) + wrench
    torque = dyn.jacobian.T @ task_force

    # Dynamically consistent null-space posture term: (I - J^T Jbar^T) M (k (q0 - q) - d qdot).
    kn = config.null_stiffness
    posture_acc = kn * (target.posture - dyn.qpos) - 2.0 * jnp.sqrt(kn) * dyn.qvel
    posture_torque = dyn.mass_matrix @ posture_acc
    jbar = jnp.linalg.solve(dyn.mass_matrix, dyn.jacobian.T) @ mx  # (7, 6)
    torque = torque + posture_torque - dyn.jacobian.T @ (jbar.T @ posture_torque)

    if config.gravity_compensation:
        torque = torque + dyn.bias
    return torque
