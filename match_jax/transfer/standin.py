"""A robot stand-in: an exported policy (ONNX) run in MuJoCo C, as on a real Franka FR3, without JAX.

The scene is the training scene with stated perturbations outside the training distribution (softer
contacts, lower friction, heavier links and rotors that the control law's model does not know, a
one-step observation delay). The hybrid force/position law runs at 1 kHz on the robot's own model
(the nominal scene), the contact force is estimated from the joint torques at 1 kHz and filtered with
an exponential moving average (alpha 0.08), the peg breaks at 20 N on that filtered force, and the
policy runs at 15 Hz through the ONNX file only.

    python -m match_jax.transfer.standin policy/policy_seed0.onnx --trials 30 --out trials.json
    python -m match_jax.transfer.standin policy/policy_seed0.onnx --trials 50 --noise-mm 5 --noise-type shell --out t.json

Units: m, rad, s, N, N m, J; world frame unless stated.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.resources
import json
import math
import pathlib
import sys
from typing import Callable

import mujoco
import numpy as np

ARM_JOINTS = 7
R_DOWN = np.diag([1.0, -1.0, -1.0])  # end effector pointing down, yaw 0
SHELL_EDGES_MM = (0.0, 1.0, 2.5, 5.0, 7.5)  # the authors' noise shells: radius U[previous edge, level]
ACTION_NOISE_STREAM = 1  # run_trials seeds the stochastic policy's noise with (seed, this)
NOISE_TYPES = ("shell", "gaussian")
FORCE_SOURCES = ("joint_torque", "wrist")


@dataclasses.dataclass(frozen=True)
class Perturbation:
    """How the stand-in's physics differs from the training scene (None = as trained).

    Attributes:
      contact_timeconst: solref time constant of every peg contact (s; the scene's 0.02): softer contact.
      friction: tangential friction of every peg contact (the scene's 0.75; dynamics randomisation
        draws 0.5-2.0).
      link_mass_scale: factor on the arm links' and the hand's masses and inertias, physics only (the
        control law keeps the nominal model, as a robot's controller keeps its identified one).
      armature_scale: factor on the joints' rotor inertia, physics only.
      obs_delay_steps: policy steps between an observation and the action computed from it.
    """

    contact_timeconst: float | None = 0.03
    friction: float | None = 0.4
    link_mass_scale: float | None = 1.01
    armature_scale: float | None = 1.2
    obs_delay_steps: int = 1

    @classmethod
    def none(cls) -> "Perturbation":
        return cls(None, None, None, None, 0)

    def __post_init__(self):
        for name in ("contact_timeconst", "friction", "link_mass_scale", "armature_scale"):
            value = getattr(self, name)
            if value is not None and not (value > 0 and math.isfinite(value)):
                raise ValueError(f"Perturbation.{name} must be None or > 0, got {value!r}")
        if not (isinstance(self.obs_delay_steps, int) and self.obs_delay_steps >= 0):
            raise ValueError(f"Perturbation.obs_delay_steps must be an integer >= 0, got {self.obs_delay_steps!r}")


@dataclasses.dataclass(frozen=True)
class StandInConfig:
    """The stand-in's rates, force estimate, break and task (the training task's values where it has them).

    Attributes:
      control_hz: rate of the control law and of the physics step (Hz).
      policy_hz: policy rate (Hz); each policy step runs round(control_hz / policy_hz) control steps.
      force_source: 'joint_torque' = the contact wrench estimated from the joint torques it causes
        (J^T pseudo-inverse at the wrist site, as a torque-sensing arm estimates it); 'wrist' = the
        scene's wrist F/T sensor, tared (the training signal).
      ema_alpha: weight of a new force sample in the force filter, per control step (1 = no filter).
      break_force: the peg breaks when the filtered |F| reaches this (N; math.inf = unbreakable),
        checked every control step.
      episode_steps: policy steps per trial.
      perturbation: the physics' differences from the training scene.
      The rest mirror the training task (`FPiHConfig`, `ControllerConfig`): hole placement, spawn, the
      peg's offset in the hand, success, contact threshold and the law's gains.
    """

    control_hz: float = 1000.0
    policy_hz: float = 15.0
    force_source: str = "joint_torque"
    ema_alpha: float = 0.08
    break_force: float = 20.0
    episode_steps: int = 150
    perturbation: Perturbation = Perturbation()
    hole_xy: tuple[float, float] = (0.55, 0.0)
    hole_xy_range: float = 0.02
    hole_yaw_range: float = math.pi
    spawn_height: float = 0.047
    spawn_min_clearance: float = 0.005
    spawn_noise: tuple[float, float, float] = (0.02, 0.02, 0.01)
    hand_yaw_range: float = 0.785
    peg_offset_range: tuple[float, float, float] = (0.003, 0.0, 0.003)
    success_radius: float = 0.0025
    success_height: float = 0.001
    contact_threshold: float = 1.0
    pos_stiffness: float = 100.0
    rot_stiffness: float = 30.0
    force_gain: float = 0.5
    null_stiffness: float = 10.0

    def __post_init__(self):
        if not (self.control_hz > 0 and self.policy_hz > 0 and self.control_hz >= self.policy_hz):
            raise ValueError(f"need control_hz >= policy_hz > 0, got {self.control_hz!r}, {self.policy_hz!r}")
        if self.force_source not in FORCE_SOURCES:
            raise ValueError(f"force_source must be one of {FORCE_SOURCES}, got {self.force_source!r}")
        if not 0 < self.ema_alpha <= 1:
            raise ValueError(f"ema_alpha must be in (0, 1], got {self.ema_alpha!r}")
        if not self.break_force > 0:
            raise ValueError(f"break_force must be > 0 N (math.inf = unbreakable), got {self.break_force!r}")
        if not (isinstance(self.episode_steps, int) and self.episode_steps >= 1):
            raise ValueError(f"episode_steps must be an integer >= 1, got {self.episode_steps!r}")

    @property
    def control_steps(self) -> int:
        """Control (= physics) steps per policy step."""
        return max(1, round(self.control_hz / self.policy_hz))

    @classmethod
    def like_training(cls, **changes) -> "StandInConfig":
        """The training env's timing and signal: law at 120 Hz, wrist sensor, no filter, no
        perturbation, unbreakable (to compare trajectories with the MJX env)."""
        return cls(**{"control_hz": 120.0, "force_source": "wrist", "ema_alpha": 1.0, "break_force": math.inf,
                      "perturbation": Perturbation.none(), **changes})


@dataclasses.dataclass(frozen=True)
class Episode:
    """One trial's start: hole pose, the peg's offset in the hand, the hand's spawn pose, and the
    hole-position observation error (m)."""

    hole_pos: np.ndarray  # bore bottom centre, (3,)
    hole_yaw: float
    peg_offset: np.ndarray  # hand frame, (3,)
    qpos: np.ndarray  # arm joint angles at the start (also the posture target), (7,)
    hole_obs_offset: np.ndarray  # (3,)


def scene_path() -> pathlib.Path:
    return pathlib.Path(str(importlib.resources.files("match_jax") / "envs" / "assets" / "fpih_scene.xml"))


def shell_offset(rng: np.random.Generator, level_mm: float) -> np.ndarray:
    """A hole-position error (m) on the authors' noise shell out to `level_mm`: uniform direction,
    radius U[previous shell edge, level]."""
    inner = max([e for e in SHELL_EDGES_MM if e < level_mm - 1e-9], default=0.0)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    return direction * rng.uniform(inner, level_mm) / 1000.0


def _yaw_rotation(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def orientation_error(rot: np.ndarray, rot_target: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) taking `rot` to `rot_target`, 0.5 sum e_i x e_d,i (the training law's)."""
    return 0.5 * np.sum(np.cross(rot.T, rot_target.T), axis=0)


class Policy:
    """An exported policy (`match_jax.transfer.export`): ONNX file + its JSON, run with onnxruntime.

    noise_seed: None for the deterministic action (tanh of the mean); a numpy seed (int or ints) to sample the exported
    stochastic action (`--stochastic`: tanh(mean + std_scale * std * noise), selections deterministic) with
    standard-normal noise from a numpy generator seeded with it.
    """

    def __init__(self, onnx_path: str | pathlib.Path, noise_seed=None):
        import onnxruntime

        path = pathlib.Path(onnx_path)
        if not path.is_file():
            raise FileNotFoundError(f"no ONNX policy at {path}")
        json_path = path.with_suffix(".json")
        if not json_path.is_file():
            raise FileNotFoundError(f"no description {json_path.name} beside {path} (write both with match_jax.transfer.export)")
        self.description = json.loads(json_path.read_text())
        stochastic = self.description.get("stochastic")
        if noise_seed is not None and not stochastic:
            raise ValueError(f"{path} has no stochastic output (export it with --stochastic to sample actions)")
        self.std_scale = None if noise_seed is None else float(stochastic["std_scale"])
        self.noise = None if noise_seed is None else np.random.default_rng(noise_seed)
        self.noise_size = len(self.description["action"]["continuous_indices"])
        self.session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        self.has_noise_input = bool(stochastic)

    @property
    def deployment(self) -> str:
        """'deterministic', or 'stochastic, std x <scale>'."""
        return "deterministic" if self.noise is None else f"stochastic, std x {self.std_scale:g}"

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        feeds = {"obs": np.asarray(obs, np.float32)[None]}
        if self.has_noise_input:  # 'action' does not read it
            feeds["noise"] = np.zeros((1, self.noise_size), np.float32) if self.noise is None else \
                self.noise.standard_normal((1, self.noise_size)).astype(np.float32)
        output = "action" if self.noise is None else "sampled_action"
        return self.session.run([output], feeds)[0][0].astype(np.float64)


class StandIn:
    """The scene in MuJoCo C with the perturbations of `config`, and the robot's own (nominal) model."""

    def __init__(self, description: dict, config: StandInConfig = StandInConfig()):
        self.config, self.description = config, description
        self.actions = description["action"]
        self.control = description["control"]
        self.obs_names = [c["name"] for c in description["observation"]["components"]]
        self.obs_size = int(description["observation"]["size"])
        self.robot = mujoco.MjModel.from_xml_path(str(scene_path()))  # the controller's model
        self.robot.opt.timestep = 1.0 / config.control_hz
        self.model = self._perturbed(config.perturbation)
        self.data, self.robot_data = mujoco.MjData(self.model), mujoco.MjData(self.robot)
        m = self.robot
        self.ee_site, self.peg_tip_site, self.wrist_site = m.site("ee").id, m.site("peg_tip").id, m.site("wrist").id
        self.hand_body, self.peg_body = m.body("hand").id, m.body("peg").id
        self.hole_mocap = int(m.body("hole").mocapid[0])
        self.hole_top_offset = float(m.site_pos[m.site("hole_top").id][2])
        self.nominal_peg_pos = m.body_pos[self.peg_body].copy()
        self.force_adr = int(m.sensor_adr[m.sensor("wrist_force").id])
        self.torque_adr = int(m.sensor_adr[m.sensor("wrist_torque").id])
        self.low, self.high = m.actuator_ctrlrange[:, 0].copy(), m.actuator_ctrlrange[:, 1].copy()
        self.home_qpos = self._solve_ik(np.array([0.0, 0.3, 0.0, -2.2, 0.0, 2.5, 0.785]),
                                        np.array([*config.hole_xy, self.hole_top_offset + config.spawn_height]),
                                        R_DOWN, iterations=200)

    # ------------------------------------------------------------------------------ the scene
    def _perturbed(self, p: Perturbation) -> mujoco.MjModel:
        model = mujoco.MjModel.from_xml_path(str(scene_path()))
        model.opt.timestep = 1.0 / self.config.control_hz
        if p.contact_timeconst is not None:
            model.pair_solref[:, 0] = p.contact_timeconst
        if p.friction is not None:
            model.pair_friction[:, :2] = p.friction
        if p.link_mass_scale is not None:
            peg = model.body("peg").id
            for body in range(1, model.nbody):
                if body != peg and model.body_mocapid[body] < 0:
                    model.body_mass[body] *= p.link_mass_scale
                    model.body_inertia[body] *= p.link_mass_scale
        if p.armature_scale is not None:
            model.dof_armature[:] *= p.armature_scale
        return model

    def _set_peg_offset(self, offset: np.ndarray) -> None:
        for model in (self.model, self.robot):
            model.body_pos[self.peg_body] = self.nominal_peg_pos + offset

    def _solve_ik(self, qpos0, pos, rot, iterations: int = 50) -> np.ndarray:
        """Damped least-squares IK of the robot's model to an EE pose."""
        m, d = self.robot, self.robot_data
        d.qpos[:] = qpos0
        for _ in range(iterations):
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            ee_pos, ee_rot = d.site_xpos[self.ee_site], d.site_xmat[self.ee_site].reshape(3, 3)
            err = np.concatenate([pos - ee_pos, orientation_error(ee_rot, rot)])
            jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
            mujoco.mj_jac(m, d, jacp, jacr, ee_pos, self.hand_body)
            jac = np.vstack([jacp, jacr])
            d.qpos[:] += jac.T @ np.linalg.solve(jac @ jac.T + 1e-8 * np.eye(6), err)
        return d.qpos.copy()

    def sample_episode(self, rng: np.random.Generator, noise_mm: float = 0.0, noise_type: str = "shell") -> Episode:
        """A trial's start, drawn as the training task draws it (uniform hole jitter, yaw and spawn,
        the peg's offset in the hand), with the hole observation error at `noise_mm` ('shell': on the
        authors' shell out to it; 'gaussian': sd per axis)."""
        if noise_type not in NOISE_TYPES:
            raise ValueError(f"noise_type must be one of {NOISE_TYPES}, got {noise_type!r}")
        if not (noise_mm >= 0 and math.isfinite(noise_mm)):
            raise ValueError(f"noise_mm must be a finite number >= 0, got {noise_mm!r}")
        cfg = self.config
        hole_pos = np.array([*(np.asarray(cfg.hole_xy) + rng.uniform(-cfg.hole_xy_range, cfg.hole_xy_range, 2)), 0.0])
        hole_yaw = float(rng.uniform(-cfg.hole_yaw_range, cfg.hole_yaw_range))
        peg_offset = rng.uniform(-1.0, 1.0, 3) * np.asarray(cfg.peg_offset_range)
        self._set_peg_offset(peg_offset)
        tip_below_ee = self._tip_below_ee()
        target = hole_pos + [0.0, 0.0, self.hole_top_offset + cfg.spawn_height] + \
            rng.uniform(-1.0, 1.0, 3) * np.asarray(cfg.spawn_noise)
        target[2] = max(target[2], self.hole_top_offset + tip_below_ee + cfg.spawn_min_clearance)
        hand_yaw = float(rng.uniform(-cfg.hand_yaw_range, cfg.hand_yaw_range))
        qpos = self._solve_ik(self.home_qpos, target, _yaw_rotation(hand_yaw) @ R_DOWN)
        if noise_type == "shell":
            obs_offset = shell_offset(rng, noise_mm) if noise_mm > 0 else np.zeros(3)
        else:
            obs_offset = rng.normal(size=3) * noise_mm / 1000.0
        return Episode(hole_pos, hole_yaw, peg_offset, qpos, obs_offset)

    def _tip_below_ee(self) -> float:
        d = mujoco.MjData(self.robot)
        mujoco.mj_kinematics(self.robot, d)
        rot = d.site_xmat[self.ee_site].reshape(3, 3)
        return float((rot.T @ (d.site_xpos[self.peg_tip_site] - d.site_xpos[self.ee_site]))[2])

    # ------------------------------------------------------------------------ robot signals
    def _robot_dynamics(self, d: mujoco.MjData):
        """What the robot's controller computes from its own model at the measured q, qdot: mass matrix
        (7, 7), bias torques (7,), EE Jacobian (6, 7) at the fingertip point of the hand, EE pose."""
        m, r = self.robot, self.robot_data
        r.qpos[:], r.qvel[:] = d.qpos, d.qvel
        mujoco.mj_fwdPosition(m, r)
        mujoco.mj_fwdVelocity(m, r)
        mass = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, r, mass)
        ee_pos = r.site_xpos[self.ee_site].copy()
        jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        mujoco.mj_jac(m, r, jacp, jacr, ee_pos, self.hand_body)
        return mass, r.qfrc_bias.copy(), np.vstack([jacp, jacr]), ee_pos, r.site_xmat[self.ee_site].reshape(3, 3).copy()

    def _wrench_sample(self, d: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """(force, torque) the robot applies to the environment, per `force_source` (world frame,
        torque about the wrist site), from the state after a physics step's constraint solve."""
        if self.config.force_source == "wrist":
            rot = d.site_xmat[self.wrist_site].reshape(3, 3)
            body = int(self.model.site_bodyid[self.wrist_site])
            weight = self.model.body_subtreemass[body] * self.model.opt.gravity
            force = rot @ d.sensordata[self.force_adr:self.force_adr + 3] + weight
            lever = d.subtree_com[body] - d.site_xpos[self.wrist_site]
            torque = rot @ d.sensordata[self.torque_adr:self.torque_adr + 3] + np.cross(lever, weight)
            return force, torque
        # the joint torques the contacts cause, mapped to a wrench at the wrist: J^T w = tau_ext
        jacp, jacr = np.zeros((3, self.model.nv)), np.zeros((3, self.model.nv))
        mujoco.mj_jacSite(self.model, d, jacp, jacr, self.wrist_site)
        jac = np.vstack([jacp, jacr])
        wrench_on_robot = np.linalg.lstsq(jac.T, d.qfrc_constraint[:ARM_JOINTS], rcond=None)[0]
        return -wrench_on_robot[:3], -wrench_on_robot[3:]

    def _law(self, dyn, target: dict, force: np.ndarray) -> np.ndarray:
        """Joint torques of the hybrid law (IsaacLab Factory's J^T law; the training law's terms)."""
        mass, bias, jac, ee_pos, ee_rot = dyn
        cfg, qvel = self.config, self.data.qvel[:ARM_JOINTS]
        kp = target["pos_stiffness"]
        kp_rot = np.full(3, cfg.rot_stiffness)
        ee_vel = jac @ qvel
        pos_cmd = kp * (target["pos"] - ee_pos) - 2.0 * np.sqrt(kp) * ee_vel[:3]
        force_axes = 1.0 - target["position_axes"]
        force_cmd = force_axes * cfg.force_gain * (target["force"] - force)
        rot_cmd = kp_rot * orientation_error(ee_rot, target["rot"]) - 2.0 * np.sqrt(kp_rot) * ee_vel[3:]
        task_force = np.concatenate([target["position_axes"] * pos_cmd + force_cmd, rot_cmd])
        torque = jac.T @ task_force
        mx = np.linalg.inv(jac @ np.linalg.solve(mass, jac.T) + 1e-6 * np.eye(6))
        kn = cfg.null_stiffness
        posture_torque = mass @ (kn * (target["posture"] - self.data.qpos[:ARM_JOINTS]) - 2.0 * np.sqrt(kn) * qvel)
        jbar = np.linalg.solve(mass, jac.T) @ mx
        torque = torque + posture_torque - jac.T @ (jbar.T @ posture_torque) + bias
        return np.clip(torque, self.low, self.high)

    # ------------------------------------------------------------------------------ policy I/O
    def _observe(self, d: mujoco.MjData, episode: Episode, force, torque, prev_action) -> np.ndarray:
        ee_pos = d.site_xpos[self.ee_site]
        jacp, jacr = np.zeros((3, self.model.nv)), np.zeros((3, self.model.nv))
        mujoco.mj_jac(self.model, d, jacp, jacr, ee_pos, self.hand_body)
        hole_top = episode.hole_pos + [0.0, 0.0, self.hole_top_offset]
        parts = {"ee_rel_hole": ee_pos - (hole_top + episode.hole_obs_offset),
                 "hole_yaw_cos_sin": np.array([math.cos(episode.hole_yaw), math.sin(episode.hole_yaw)]),
                 "ee_lin_vel": jacp @ d.qvel, "ee_ang_vel": jacr @ d.qvel, "ee_force": force, "ee_torque": torque,
                 "prev_action": prev_action}
        obs = np.concatenate([parts[name] for name in self.obs_names])
        assert obs.shape == (self.obs_size,), (obs.shape, self.obs_size)
        return obs

    def _target(self, d: mujoco.MjData, episode: Episode, action: np.ndarray) -> dict:
        """The control target of a (smoothed) action, as the training env builds it."""
        a, cfg = self.actions["config"], self.config
        index = {c["name"]: c["index"] for c in self.actions["components"]}
        ee_pos, ee_rot = d.site_xpos[self.ee_site].copy(), d.site_xmat[self.ee_site].reshape(3, 3)
        observed_top = episode.hole_pos + episode.hole_obs_offset + [0.0, 0.0, self.hole_top_offset]
        pos = ee_pos + action[[index[f"pos_{x}"] for x in "xyz"]] * a["pos_scale"]
        pos = np.clip(pos, observed_top - a["pos_box"], observed_top + a["pos_box"])
        yaw = math.atan2(ee_rot[1, 0], ee_rot[0, 0]) + action[index["yaw_z"]] * a["yaw_scale"]
        kp = np.full(3, cfg.pos_stiffness)
        if "stiffness_x" in index:
            lo, hi = a["stiffness_range"]
            kp = lo + 0.5 * (action[[index[f"stiffness_{x}"] for x in "xyz"]] + 1.0) * (hi - lo)
        force, axes = np.zeros(3), np.ones(3)
        if "force_x" in index:
            lo, hi = a["force_z_range"]
            f = action[[index[f"force_{x}"] for x in "xyz"]]
            force = np.array([f[0] * a["force_xy_max"], f[1] * a["force_xy_max"], lo + 0.5 * (f[2] + 1.0) * (hi - lo)])
            axes = (action[[index[f"select_force_{x}"] for x in "xyz"]] <= a["selection_threshold"]).astype(float)
        return {"pos": pos, "rot": _yaw_rotation(yaw) @ R_DOWN, "force": force, "position_axes": axes,
                "pos_stiffness": kp, "posture": episode.qpos}

    # ---------------------------------------------------------------------------------- trial
    def run(self, policy: Callable[[np.ndarray], np.ndarray], episode: Episode, record: bool = False) -> dict:
        """One trial of `policy` (raw observation -> action) from `episode`. Returns success, broken,
        time to success (s), mean and max filtered |F| (N; mean over control steps with |F| above the
        contact threshold), energy = integral of |tau . qdot| (J), a hybrid policy's force-selection counts
        (`SELECTION_COUNTS`; None for other policies), and with `record` per-policy-step
        arrays (ee_pos, action, force) and per-control-step arrays (force_raw, force_filtered)."""
        cfg, m, d = self.config, self.model, self.data
        self._set_peg_offset(episode.peg_offset)
        mujoco.mj_resetData(m, d)
        d.qpos[:ARM_JOINTS] = episode.qpos
        half = 0.5 * episode.hole_yaw
        d.mocap_pos[self.hole_mocap] = episode.hole_pos
        d.mocap_quat[self.hole_mocap] = [math.cos(half), 0.0, 0.0, math.sin(half)]
        mujoco.mj_forward(m, d)
        ema = np.asarray(self.actions["config"]["ema"])
        selection = np.asarray(self.actions["selection_indices"], int)
        prev = np.asarray(self.actions["neutral"], np.float64)
        force, torque = np.zeros(3), np.zeros(3)
        obs_queue = [self._observe(d, episode, force, torque, prev)] * (cfg.perturbation.obs_delay_steps + 1)
        dt, steps = m.opt.timestep, cfg.control_steps
        success_step, broken, energy, max_force = None, False, 0.0, 0.0
        contact_force_sum, contact_samples = 0.0, 0
        # hybrid policies: axis-steps in contact / free (the axis's filtered force at the start of the policy step
        # above the contact threshold or not) and those of them on force control, whole trial and before success
        selection_counts = dict.fromkeys(SELECTION_COUNTS, 0) if len(selection) else None
        rec = {"ee_pos": [], "action": [], "force": [], "force_raw": [], "force_filtered": []}
        for t in range(cfg.episode_steps):
            action = np.clip(policy(obs_queue[0]), -1.0, 1.0)
            action[selection] = np.clip(action[selection], 0.0, 1.0)
            if selection_counts is not None:
                touching, on_force = np.abs(force) > cfg.contact_threshold, action[selection] > 0.5
                for part in ("", "before_success_") if success_step is None else ("",):
                    for where, axes in (("contact", touching), ("free", ~touching)):
                        selection_counts[f"{part}{where}_axis_steps"] += int(axes.sum())
                        selection_counts[f"{part}force_selected_{where}_axis_steps"] += int((axes & on_force).sum())
            smoothed = ema * action + (1.0 - ema) * prev
            smoothed[selection] = action[selection]
            target = self._target(d, episode, smoothed)
            for _ in range(steps):
                mujoco.mj_step1(m, d)
                tau = self._law(self._robot_dynamics(d), target, force)
                d.ctrl[:] = tau
                mujoco.mj_step2(m, d)
                energy += abs(float(tau @ d.qvel[:ARM_JOINTS])) * dt
                raw_force, raw_torque = self._wrench_sample(d)
                force = cfg.ema_alpha * raw_force + (1.0 - cfg.ema_alpha) * force
                torque = cfg.ema_alpha * raw_torque + (1.0 - cfg.ema_alpha) * torque
                magnitude = float(np.linalg.norm(force))
                max_force = max(max_force, magnitude)
                if magnitude > cfg.contact_threshold:
                    contact_force_sum, contact_samples = contact_force_sum + magnitude, contact_samples + 1
                if record:
                    rec["force_raw"].append(raw_force.copy())
                    rec["force_filtered"].append(force.copy())
                if magnitude >= cfg.break_force:
                    broken = True
                    break
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            prev = smoothed
            if record:
                rec["ee_pos"].append(d.site_xpos[self.ee_site].copy())
                rec["action"].append(action)
                rec["force"].append(force.copy())
            tip = d.site_xpos[self.peg_tip_site]
            lateral = float(np.linalg.norm(tip[:2] - episode.hole_pos[:2]))
            if not broken and success_step is None and lateral < cfg.success_radius and \
                    tip[2] - episode.hole_pos[2] < cfg.success_height:
                success_step = t
            if broken:
                break
            obs_queue = obs_queue[1:] + [self._observe(d, episode, force, torque, prev)]
        result = {"success": success_step is not None, "broken": broken,
                  "time_to_success_s": None if success_step is None else (success_step + 1) * steps * dt,
                  "mean_force_n": contact_force_sum / contact_samples if contact_samples else None,
                  "max_force_n": max_force, "energy_j": energy, "selection": selection_counts}
        if record:
            result.update({k: np.asarray(v) for k, v in rec.items()})
        return result


def wilson_interval(successes: int, trials: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a rate."""
    if trials == 0:
        return float("nan"), float("nan")
    p = successes / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / (1 + z * z / trials)
    return centre - half, centre + half


SELECTION_COUNTS = tuple(f"{part}{kind}{where}_axis_steps" for part in ("", "before_success_")
                         for kind in ("", "force_selected_") for where in ("contact", "free"))


def selection_rates(trials: list[dict]) -> dict | None:
    """A hybrid policy's pooled force selection over `trials`: force-selected / all axis-steps in contact and
    in free space, whole trial and before success (NaN where there is none), with the counts; None otherwise."""
    counts = [t["selection"] for t in trials if t.get("selection") is not None]
    if not counts:
        return None
    total = {key: sum(c[key] for c in counts) for key in SELECTION_COUNTS}
    out = dict(total)
    for part in ("", "before_success_"):
        for where in ("contact", "free"):
            steps = total[f"{part}{where}_axis_steps"]
            hits = total[f"{part}force_selected_{where}_axis_steps"]
            out[f"{part}force_selected_{where}_per_axis"] = hits / steps if steps else float("nan")
    return out


def summarize(trials: list[dict]) -> dict:
    """Rates with 95 % Wilson intervals, means (with 95 % normal intervals) of the trial metrics, and for
    hybrid policies the pooled force selection (`selection_rates`)."""
    n = len(trials)
    out = {"trials": n}
    for name in ("success", "broken"):
        k = sum(bool(t[name]) for t in trials)
        out[f"{name}_rate"] = k / n if n else float("nan")
        out[f"{name}_rate_ci95"] = wilson_interval(k, n)
    for name in ("time_to_success_s", "mean_force_n", "max_force_n", "energy_j"):
        values = np.asarray([t[name] for t in trials if t[name] is not None], np.float64)
        mean = float(values.mean()) if len(values) else float("nan")
        half = 1.96 * float(values.std(ddof=1)) / math.sqrt(len(values)) if len(values) > 1 else float("nan")
        out[name] = {"mean": mean, "ci95": (mean - half, mean + half), "n": int(len(values))}
    selection = selection_rates(trials)
    if selection is not None:
        out["selection"] = selection
    return out


def run_trials(onnx_path: str | pathlib.Path, trials: int, noise_mm: float = 0.0, noise_type: str = "shell",
               seed: int = 0, config: StandInConfig = StandInConfig(), stochastic: bool = False) -> dict:
    """`trials` trials of an exported policy at one noise level: per-trial rows and their summary.

    `seed` draws the episodes; with `stochastic` the policy samples its exported stochastic action, the
    noise drawn from a second stream of the same seed (the episodes do not change)."""
    if not (isinstance(trials, int) and trials >= 1):
        raise ValueError(f"trials must be a positive integer, got {trials!r}")
    policy = Policy(onnx_path, noise_seed=(seed, ACTION_NOISE_STREAM) if stochastic else None)
    standin = StandIn(policy.description, config)
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(trials):
        episode = standin.sample_episode(rng, noise_mm, noise_type)
        row = standin.run(policy, episode)
        row.update(trial=i, hole_obs_offset_mm=(episode.hole_obs_offset * 1000.0).tolist())
        rows.append(row)
    return {"policy": str(onnx_path), "method": policy.description.get("method"), "noise_mm": noise_mm,
            "noise_type": noise_type, "seed": seed, "deployment": policy.deployment,
            "config": dataclasses.asdict(config),
            "summary": summarize(rows), "trials": rows}


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m match_jax.transfer.standin", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("policy", type=pathlib.Path, help="ONNX file written by match_jax.transfer.export (its .json beside it)")
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--noise-mm", type=float, default=0.0,
                        help="hole-position observation error level, mm (default 0: the hole observed where it is, "
                             "as a robot trial at a measured hole; eval.py's default is the training noise, "
                             "--noise-mm 1 --noise-type gaussian here)")
    parser.add_argument("--noise-type", choices=NOISE_TYPES, default="shell",
                        help="'shell': radius U[previous shell edge, level] in a random direction (default); "
                             "'gaussian': sd per axis")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-perturbation", action="store_true", help="the training scene's physics and no delay")
    parser.add_argument("--stochastic", action="store_true",
                        help="sample the policy's stochastic action (an export with --stochastic)")
    parser.add_argument("--out", type=pathlib.Path, required=True, help="JSON file of the trials and their summary")
    args = parser.parse_args(argv)
    if args.trials < 1:
        parser.error(f"--trials must be a positive integer, got {args.trials}")
    if not (args.noise_mm >= 0 and math.isfinite(args.noise_mm)):
        parser.error(f"--noise-mm must be a finite number >= 0, got {args.noise_mm}")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    config = StandInConfig(perturbation=Perturbation.none()) if args.no_perturbation else StandInConfig()
    try:
        result = run_trials(args.policy, args.trials, args.noise_mm, args.noise_type, args.seed, config,
                            args.stochastic)
    except (FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1, default=float) + "\n")
    s = result["summary"]
    print(f"{result['method']} ({result['deployment']}) at {args.noise_mm:g} mm ({args.noise_type}): "
          f"success {100 * s['success_rate']:.0f} %, "
          f"breaks {100 * s['broken_rate']:.0f} %, mean force {s['mean_force_n']['mean']:.2f} N, "
          f"max force {s['max_force_n']['mean']:.2f} N over {s['trials']} trials -> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
