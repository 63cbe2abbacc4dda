"""The fragile peg-in-hole (fPiH) environment: FR3 arm + peg + hole block in MuJoCo-MJX.

A Brax-style functional env: `reset(key) -> State`, `step(State, action) -> State`, State a pytree
(Brax's `envs.State`), jit- and vmap-able. One policy step (15 Hz) holds the action's targets over
8 control substeps (120 Hz); each control substep computes the control law from MJX's Jacobian, mass
matrix and bias forces and advances the physics by `physics_substeps` MuJoCo steps.

Frames: world z up; the hole block sits on the table (z = 0), its bore axis vertical. Forces are the
force the robot applies to the environment, world frame (pressing down gives F_z < 0).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from match_jax.envs import sim  # first: imports mujoco.mjx quietly (it prints a notice when warp is absent)

from brax.envs.base import Env as BraxEnv  # noqa: E402
from brax.envs.base import State  # noqa: E402
from match_jax.envs.controllers.action_spaces import ActionConfig, ActionSpace, get_action_space
from match_jax.envs.controllers.osc import ControllerConfig, ControlTarget, hybrid_torque, orientation_error
from match_jax.envs import randomization, sensors
from match_jax.envs.randomization import ModelRandomization
from match_jax.envs.sim import mjx

# Hand pointing down: EE x = world x, EE y = -world y, EE z = -world z (at zero yaw).
R_DOWN = np.diag([1.0, -1.0, -1.0])
NOISE_TYPES = ("gaussian", "uniform")
BREAK_SAMPLINGS = ("peak", "policy_step")
FORCE_SENSORS = ("wrist", "peg_contact")
PHASE_APPROACH, PHASE_CONTACT, PHASE_INSERTION = 0, 1, 2
PHASE_NAMES = ("approach", "contact", "insertion")  # info['phase'] -> name


@dataclasses.dataclass(frozen=True)
class FPiHConfig:
    """Task, timing, noise and reward settings (the paper's and the authors' values; docs/task.md).

    Lengths in meters, forces in newtons, angles in radians, times in seconds.
    """

    # Fields added after runs were recorded: a run config without them ran these values.
    LEGACY_DEFAULTS = {"force_sensor": "peg_contact", "observe_torque": False,
                       "randomization": {"peg_offset_range": (0.0, 0.0, 0.0)}}

    control: str = "hybrid"  # 'pose' | 'vices' | 'hybrid'
    scene_file: str = ""  # MJCF path; "" = the packaged fpih_scene.xml
    physics_backend: str = "jax"  # 'jax' (MJX) | 'warp' (MuJoCo Warp; pip install "match_jax[warp]")
    # MuJoCo Warp only: the most envs one vmapped reset/step holds (its contact buffer is shared by the
    # batch: sim.warp_naconmax). The trainer and the evaluator set it to their batch sizes.
    warp_worlds: int = 1024
    controller: ControllerConfig = ControllerConfig()  # the task-space control law and its gains
    actions: ActionConfig = ActionConfig()  # how actions map to targets: scales, ranges, smoothing
    # Timing: policy 15 Hz, control law 120 Hz, physics `physics_substeps` x 120 Hz.
    control_substeps: int = 8  # control-law steps per policy step
    control_dt: float = 1.0 / 120.0  # s, one control-law step
    physics_substeps: int = 1  # physics steps per control-law step
    episode_steps: int = 150  # policy steps per episode (10 s)
    # Force signal of the force law, the 'policy_step' break check and the force/torque observation:
    # 'wrist' = the wrist force/torque sensor, tared (`match_jax.envs.sensors`; the authors' signal);
    # 'peg_contact' = the sum of the peg's contact forces (no torque). `force_frame`: 'world' = that
    # reading in the world frame, the law's frame; 'hand' = the authors' reading, negated in the hand
    # frame and fed unrotated to the law and the policy (`sensors.authors_reading`: x/y mirrored).
    force_sensor: str = "wrist"  # 'wrist' | 'peg_contact'
    force_frame: str = "world"  # 'world' | 'hand'
    observe_torque: bool = True  # the policy sees the wrist torque beside the force (6-D, the authors')
    # Break: the episode ends when the force reaches break_force (math.inf = unbreakable), sampled as
    # `break_sampling` says: 'policy_step' = |F| of the force signal read once per policy step, at its end
    # (the authors': the wrist force at 15 Hz); 'peak' = the peg's peak contact |F| over every physics step
    # of the policy step (what a real peg feels).
    break_force: float = 10.0  # N; inf = unbreakable
    break_sampling: str = "policy_step"  # 'policy_step' | 'peak'
    # Contact softness: the solref time constant (s) of every peg contact pair, written into the model
    # before it goes to MJX (the scene's value, make_scene.py `solref="0.02 1"`, keeps the model as built;
    # larger is softer; MuJoCo raises values below 2 x the physics timestep to that).
    contact_timeconst: float = 0.02  # s, solref time constant of the peg contacts; larger is softer
    # Per-episode model draws (the peg's pose in the hand; with dynamics ranges, the peg's mass and
    # friction and the controller gains: all shown to the critic only).
    randomization: ModelRandomization = ModelRandomization()  # per-episode model draws
    # Hole placement: nominal bore centre on the table, uniform xy jitter, uniform yaw.
    hole_xy: tuple[float, float] = (0.55, 0.0)  # m, nominal bore centre on the table
    hole_xy_range: float = 0.02  # m, half-width of the uniform xy jitter of the hole
    hole_yaw_range: float = math.pi  # rad, half-width of the uniform hole yaw
    # Spawn: end effector (fingertip frame) `spawn_height` above the hole top, plus noise (gaussian sd /
    # uniform half-width); the height is clipped so the peg tip starts >= `spawn_min_clearance` above it.
    spawn_height: float = 0.047  # m, end effector above the hole top at spawn
    spawn_min_clearance: float = 0.005  # m, least peg-tip height above the hole top at spawn
    spawn_noise: tuple[float, float, float] = (0.02, 0.02, 0.01)  # m, spawn noise per axis (sd or half-width)
    spawn_noise_type: str = "uniform"  # 'uniform' | 'gaussian'
    hand_yaw_range: float = 0.785  # rad, half-width of the uniform hand yaw at spawn
    ik_iterations: int = 12  # inverse-kinematics iterations of the spawn pose
    # Observation noise: hole position per episode; force and EE position per step.
    hole_obs_noise: float = 0.001  # m, hole-position observation noise, drawn per episode
    hole_obs_noise_type: str = "gaussian"  # 'gaussian' (sd) | 'uniform' (half-width)
    force_obs_noise: float = 1.0  # N, per step
    torque_obs_noise: float = 0.2  # N m
    ee_pos_obs_noise: float = 0.00025  # m, per step
    # Success / engagement: peg tip within `success_radius` of the bore axis and below these heights
    # above the hole bottom.
    success_radius: float = 0.0025  # m, from the bore axis
    success_height: float = 0.001  # m, peg tip above the hole bottom for success
    engage_height: float = 0.0225  # m, peg tip above the hole bottom for engagement
    contact_threshold: float = 1.0  # N, per-axis contact label
    keypoint_offsets: tuple[float, ...] = (-0.075, -0.025, 0.025, 0.075)  # m, reward keypoints along the peg axis
    # (a, b) of each keypoint reward term 1 / (exp(a d) + b + exp(-a d)), d the keypoint distance (m)
    reward_terms: tuple[tuple[float, float], ...] = ((5.0, 4.0), (50.0, 2.0), (100.0, 0.0))

    def __post_init__(self):
        get_action_space(self.control)  # raises on an unknown controller name
        if self.physics_backend not in sim.PHYSICS_BACKENDS:
            raise ValueError(f"physics_backend must be one of {sim.PHYSICS_BACKENDS}, got {self.physics_backend!r}")
        if not (isinstance(self.break_force, (int, float)) and self.break_force > 0):
            raise ValueError(f"break_force must be > 0 N (math.inf for unbreakable), got {self.break_force!r}")
        for name in ("control_substeps", "physics_substeps", "episode_steps", "ik_iterations", "warp_worlds"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if self.break_sampling not in BREAK_SAMPLINGS:
            raise ValueError(f"break_sampling must be one of {BREAK_SAMPLINGS}, got {self.break_sampling!r}")
        if self.force_sensor not in FORCE_SENSORS:
            raise ValueError(f"force_sensor must be one of {FORCE_SENSORS}, got {self.force_sensor!r}")
        if self.force_frame not in sensors.FORCE_FRAMES:
            raise ValueError(f"force_frame must be one of {sensors.FORCE_FRAMES}, got {self.force_frame!r}")
        if self.observe_torque and self.force_sensor != "wrist":
            raise ValueError("observe_torque needs force_sensor='wrist' (the peg's contact forces carry no torque)")
        for name in ("spawn_noise_type", "hole_obs_noise_type"):
            if getattr(self, name) not in NOISE_TYPES:
                raise ValueError(f"{name} must be one of {NOISE_TYPES}, got {getattr(self, name)!r}")
        for name in ("hole_obs_noise", "force_obs_noise", "torque_obs_noise", "ee_pos_obs_noise", "hole_xy_range",
                     "hole_yaw_range", "hand_yaw_range", "contact_threshold"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if len(self.spawn_noise) != 3 or any(not v >= 0 for v in self.spawn_noise):
            raise ValueError(f"spawn_noise must be 3 non-negative numbers, got {self.spawn_noise!r}")
        if not self.control_dt > 0:
            raise ValueError(f"control_dt must be > 0 s, got {self.control_dt!r}")
        if not (isinstance(self.contact_timeconst, (int, float)) and 0 < self.contact_timeconst < math.inf):
            raise ValueError(f"contact_timeconst must be a finite number > 0 s, got {self.contact_timeconst!r}")

    @property
    def policy_dt(self) -> float:
        return self.control_dt * self.control_substeps


def break_signal(sampling: str, max_force, ee_force):
    """The force (N) compared with the break threshold, as `FPiHConfig.break_sampling` says: 'peak' = the
    peg's max contact |F| over a policy step's physics steps (`max_force`); 'policy_step' = |F| of the
    force signal at its end (`ee_force`, (..., 3): the wrist reading by default). Works on one step or on
    a recorded (T, B) trajectory."""
    if sampling == "peak":
        return max_force
    if sampling == "policy_step":
        return jnp.linalg.norm(ee_force, axis=-1)
    raise ValueError(f"break_sampling must be one of {BREAK_SAMPLINGS}, got {sampling!r}")


class SimResult(NamedTuple):
    """What `FPiHEnv.simulate` returns: the final data and the readings of its last physics step.

    force / torque: the force signal (N, N m; `force_sensor` in `force_frame`); max_force / mean_force:
    the peg's peak and mean contact |F| over the physics steps (N); contact_force: the peg's contact
    force at the end (N, world), the source of the true contact label.
    """

    data: mjx.Data
    force: jax.Array
    max_force: jax.Array
    mean_force: jax.Array
    torque: jax.Array
    contact_force: jax.Array


def _yaw_rotation(yaw: jax.Array) -> jax.Array:
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    return jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _down_rotation(yaw: jax.Array) -> jax.Array:
    """EE orientation pointing down, rotated by `yaw` about world z."""
    return _yaw_rotation(yaw) @ jnp.asarray(R_DOWN)


def _ee_yaw(rot: jax.Array) -> jax.Array:
    return jnp.arctan2(rot[1, 0], rot[0, 0])


class FPiHEnv(BraxEnv):
    """Fragile peg-in-hole with a pose, VICES or hybrid force/position low-level controller.

    Observations are a dict: 'state' (policy) and 'privileged_state' (critic). `step` does not reset
    finished envs; use `match_jax.envs.AutoResetEnv` (or Brax's training wrappers) for that.
    """

    def __init__(self, config: FPiHConfig = FPiHConfig()):
        self.config = config
        self.action_space: ActionSpace = get_action_space(config.control)
        self.mj_model = sim.load_model(config.physics_substeps, config.control_dt, config.scene_file or None,
                                       config.physics_backend)
        self.mj_model.pair_solref[:, 0] = config.contact_timeconst  # every pair is a peg pair
        self.ids = sim.SceneIds(self.mj_model)
        self.mjx_model = sim.put_model(self.mj_model, config.physics_backend)
        self.wrist = sensors.WristSensor(self.mj_model)
        self.model_sampler = randomization.ModelSampler(self.mj_model, self.ids.peg_body, config.randomization)
        self._hole_top_offset = float(self.mj_model.site_pos[self.ids.hole_top_site][2])
        self._peg_tip_below_ee = self._nominal_peg_tip_below_ee()
        self._home_qpos = self._nominal_qpos()
        self._obs_sizes = None
        self._break_force, self._hole_obs_noise = config.break_force, config.hole_obs_noise

    def with_values(self, break_force=None, hole_obs_noise=None) -> "FPiHEnv":
        """This env with its break force (N; inf = unbreakable) and hole-observation noise (m: gaussian sd
        or uniform half-width) taken from these values, which may be traced, instead of its config. The
        trainer passes them as arguments, so runs that differ only in them share one compiled program."""
        env = copy.copy(self)
        if break_force is not None:
            env._break_force = break_force
        if hole_obs_noise is not None:
            env._hole_obs_noise = hole_obs_noise
        return env

    # ----------------------------------------------------------------------------------- set-up
    def _nominal_peg_tip_below_ee(self) -> float:
        data = mujoco.MjData(self.mj_model)
        mujoco.mj_kinematics(self.mj_model, data)
        rot = data.site_xmat[self.ids.ee_site].reshape(3, 3)
        offset = data.site_xpos[self.ids.peg_tip_site] - data.site_xpos[self.ids.ee_site]
        return float((rot.T @ offset)[2])

    def _nominal_qpos(self) -> np.ndarray:
        """Joint angles (C MuJoCo damped least squares) with the EE at the nominal spawn point."""
        model, data = self.mj_model, mujoco.MjData(self.mj_model)
        hole = np.array([*self.config.hole_xy, self._hole_top_offset])
        target = hole + np.array([0.0, 0.0, self.config.spawn_height])
        data.qpos[:] = np.array([0.0, 0.3, 0.0, -2.2, 0.0, 2.5, 0.785])
        for _ in range(200):
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            err = self._pose_error_np(data, target, R_DOWN)
            jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
            mujoco.mj_jacSite(model, data, jacp, jacr, self.ids.ee_site)
            jac = np.vstack([jacp, jacr])
            data.qpos[:] += jac.T @ np.linalg.solve(jac @ jac.T + 1e-8 * np.eye(6), err)
        if np.linalg.norm(err) > 1e-6:
            raise RuntimeError(f"IK for the nominal spawn pose did not converge (error {np.linalg.norm(err)})")
        return data.qpos.copy()

    def _pose_error_np(self, data, pos_target, rot_target) -> np.ndarray:
        pos = data.site_xpos[self.ids.ee_site]
        rot = data.site_xmat[self.ids.ee_site].reshape(3, 3)
        rot_err = 0.5 * np.sum(np.cross(rot.T, np.asarray(rot_target).T), axis=0)
        return np.concatenate([pos_target - pos, rot_err])

    # ------------------------------------------------------------------------------ interface
    @property
    def action_size(self) -> int:
        return self.action_space.size

    @property
    def observation_size(self) -> dict[str, tuple[int, ...]]:
        if self._obs_sizes is None:
            obs = jax.eval_shape(self.reset, jax.random.PRNGKey(0)).obs
            self._obs_sizes = {k: tuple(v.shape) for k, v in obs.items()}
        return self._obs_sizes

    @property
    def policy_obs_layout(self) -> dict[str, slice]:
        """Where each quantity sits in obs['state'] (units: m, rad-free cos/sin, m/s, rad/s, N, N m)."""
        sizes = [("ee_rel_hole", 3), ("hole_yaw_cos_sin", 2), ("ee_lin_vel", 3), ("ee_ang_vel", 3),
                 ("ee_force", 3)] + ([("ee_torque", 3)] if self.config.observe_torque else []) + [
                 ("prev_action", self.action_size)]
        layout, start = {}, 0
        for name, size in sizes:
            layout[name] = slice(start, start + size)
            start += size
        return layout

    @property
    def home_qpos(self) -> np.ndarray:
        """Joint angles (rad) with the EE at the nominal spawn pose: the IK start and posture reference."""
        return self._home_qpos

    @property
    def peg_tip_below_ee(self) -> float:
        """Distance (m) from the end-effector site down to the peg tip, along the hand axis."""
        return self._peg_tip_below_ee

    @property
    def hole_depth(self) -> float:
        """Bore depth (m): the hole top is this far above the hole bottom."""
        return self._hole_top_offset

    @property
    def backend(self) -> str:
        return "mjx"

    @property
    def dt(self) -> float:
        """Policy step duration (s)."""
        return self.config.policy_dt

    # --------------------------------------------------------------------------------- reset
    def reset(self, rng: jax.Array) -> State:
        cfg = self.config
        rng, k_hole, k_yaw, k_spawn, k_hand, k_obs, k_model = jax.random.split(rng, 7)
        model_fields = self.model_sampler.sample(k_model)
        gains = self.model_sampler.sample_gains(k_model)
        m = randomization.apply(self.mjx_model, model_fields)
        peg_offset = self.model_sampler.peg_offset(model_fields)  # hand frame; +z = further out
        hole_xy = jnp.asarray(cfg.hole_xy) + jax.random.uniform(
            k_hole, (2,), minval=-cfg.hole_xy_range, maxval=cfg.hole_xy_range)
        hole_pos = jnp.concatenate([hole_xy, jnp.zeros(1)])  # bore bottom centre, on the table
        hole_yaw = jax.random.uniform(k_yaw, (), minval=-cfg.hole_yaw_range, maxval=cfg.hole_yaw_range)
        spawn_noise = self._noise(k_spawn, jnp.asarray(cfg.spawn_noise), cfg.spawn_noise_type, (3,))
        hole_top = hole_pos + jnp.array([0.0, 0.0, self._hole_top_offset])
        ee_target = hole_top + jnp.array([0.0, 0.0, cfg.spawn_height]) + spawn_noise
        min_ee_height = hole_top[2] + self._peg_tip_below_ee + peg_offset[2] + cfg.spawn_min_clearance
        ee_target = ee_target.at[2].set(jnp.maximum(ee_target[2], min_ee_height))
        hand_yaw = jax.random.uniform(k_hand, (), minval=-cfg.hand_yaw_range, maxval=cfg.hand_yaw_range)
        hole_obs_offset = self._noise(k_obs, self._hole_obs_noise, cfg.hole_obs_noise_type, (3,))

        data = sim.make_data(self.mj_model, self.mjx_model, self.config.warp_worlds)
        half = 0.5 * hole_yaw
        data = data.replace(
            mocap_pos=data.mocap_pos.at[self.ids.hole_mocap].set(hole_pos),
            mocap_quat=data.mocap_quat.at[self.ids.hole_mocap].set(
                jnp.array([jnp.cos(half), 0.0, 0.0, jnp.sin(half)])),
        )
        data = self._inverse_kinematics(data, ee_target, _down_rotation(hand_yaw), m)
        posture = data.qpos

        zeros3 = jnp.zeros(3)
        info = {
            "rng": rng,
            "steps": jnp.zeros((), jnp.int32),
            "hole_pos": hole_pos,
            "hole_yaw": hole_yaw,
            "hole_obs_offset": hole_obs_offset,
            "posture": posture,
            "prev_action": self.neutral_action(),
            "model": model_fields,
            "gains": gains,
            "peg_offset": peg_offset,
            "ee_force": zeros3,
            "ee_torque": zeros3,
            "contact_force": zeros3,
            "contact_axes": zeros3,
            "in_contact": jnp.zeros(()),
            "max_force": jnp.zeros(()),
            "mean_force": jnp.zeros(()),
            "success": jnp.zeros(()),
            "engaged": jnp.zeros(()),
            "broken": jnp.zeros(()),
            "truncation": jnp.zeros(()),
            "had_contact": jnp.zeros(()),
            "had_engaged": jnp.zeros(()),
            "phase": jnp.zeros((), jnp.int32),
            "position_axes": jnp.ones(3),
        }
        obs = self._observations(data, info, jax.random.split(rng)[1])
        metrics = self._metrics(info, jnp.zeros(()))
        return State(pipeline_state=data, obs=obs, reward=jnp.zeros(()), done=jnp.zeros(()),
                     metrics=metrics, info=info)

    def set_hole_obs_offset(self, state: State, offset: jax.Array) -> State:
        """The same episode with another hole-position observation error `offset` (m, world, (3,)).

        Evaluation uses it to sweep noise levels in one compiled rollout (common random numbers); the
        reset observation is recomputed with the reset's own noise key.
        """
        info = {**state.info, "hole_obs_offset": jnp.asarray(offset, jnp.float32)}
        obs = self._observations(state.pipeline_state, info, jax.random.split(state.info["rng"])[1])
        return state.replace(obs=obs, info=info)

    def _noise(self, key, scale, kind: str, shape) -> jax.Array:
        if kind == "gaussian":
            return scale * jax.random.normal(key, shape)
        return scale * jax.random.uniform(key, shape, minval=-1.0, maxval=1.0)

    def neutral_action(self) -> jax.Array:
        """The neutral action: zero, with the force-z target at 0 N (a = 1 maps to f_z_max = 0)."""
        action = jnp.zeros(self.action_size)
        if self.action_space.force:
            action = action.at[self.action_space.force[2]].set(self.config.actions.force_z_action(0.0))
        return action

    def _inverse_kinematics(self, data: mjx.Data, pos: jax.Array, rot: jax.Array, m: mjx.Model) -> mjx.Data:
        """Damped least-squares IK from the nominal joint angles to an EE pose (fixed iterations)."""
        ids = self.ids

        def body(qpos, _):
            d = mjx.com_pos(m, mjx.kinematics(m, data.replace(qpos=qpos)))
            ee_pos, ee_rot = d.site_xpos[ids.ee_site], d.site_xmat[ids.ee_site]
            err = jnp.concatenate([pos - ee_pos, orientation_error(ee_rot, rot)])
            jacp, jacr = mjx.jac(m, d, ee_pos, ids.hand_body)
            jac = jnp.concatenate([jacp.T, jacr.T])
            dq = jac.T @ jnp.linalg.solve(jac @ jac.T + 1e-6 * jnp.eye(6), err)
            return qpos + dq, None

        qpos, _ = jax.lax.scan(body, jnp.asarray(self._home_qpos), None, length=self.config.ik_iterations)
        return mjx.com_pos(m, mjx.kinematics(m, data.replace(qpos=qpos)))

    # ---------------------------------------------------------------------------------- step
    def step(self, state: State, action: jax.Array) -> State:
        cfg, space = self.config, self.action_space
        action = jnp.asarray(action)
        if action.shape != (self.action_size,):
            raise ValueError(
                f"action has shape {action.shape}; the '{cfg.control}' controller expects ({self.action_size},) "
                f"per env ({', '.join(space.describe())}); vmap over a batch")
        data, info = state.pipeline_state, state.info
        action = self._bounded(action)
        smoothed = self._smooth(action, info["prev_action"])
        target = self._control_target(data, info, smoothed)
        m = randomization.apply(self.mjx_model, info["model"])
        data, ee_force, max_force, mean_force, ee_torque, contact_force = self.simulate(
            data, info["ee_force"], target, model=m)

        rng, obs_key = jax.random.split(info["rng"])
        steps = info["steps"] + 1
        tip, hole_pos = data.site_xpos[self.ids.peg_tip_site], info["hole_pos"]
        lateral = jnp.linalg.norm(tip[:2] - hole_pos[:2])
        height = tip[2] - hole_pos[2]
        success = ((lateral < cfg.success_radius) & (height < cfg.success_height)).astype(jnp.float32)
        engaged = ((lateral < cfg.success_radius) & (height < cfg.engage_height)).astype(jnp.float32)
        broken = (break_signal(cfg.break_sampling, max_force, ee_force) >= self._break_force).astype(jnp.float32)
        contact_axes = (jnp.abs(contact_force) > cfg.contact_threshold).astype(jnp.float32)  # true contact
        in_contact = (jnp.any(contact_axes > 0) | (max_force > cfg.contact_threshold)).astype(jnp.float32)
        had_contact = jnp.maximum(info["had_contact"], in_contact)
        had_engaged = jnp.maximum(info["had_engaged"], engaged)
        phase = jnp.where(had_engaged > 0, PHASE_INSERTION, jnp.where(had_contact > 0, PHASE_CONTACT, PHASE_APPROACH))
        diverged = jnp.any(~jnp.isfinite(data.qpos)) | jnp.any(~jnp.isfinite(data.qvel))
        truncation = (steps >= cfg.episode_steps).astype(jnp.float32)
        done = jnp.maximum(jnp.maximum(broken, truncation), diverged.astype(jnp.float32))
        reward = self._reward(data, hole_pos) + engaged + success
        reward = jnp.where(diverged, 0.0, reward)

        info = {
            **info,
            "rng": rng,
            "steps": steps,
            "prev_action": smoothed,
            "ee_force": ee_force,
            "ee_torque": ee_torque,
            "contact_force": contact_force,
            "contact_axes": contact_axes,
            "in_contact": in_contact,
            "max_force": max_force,
            "mean_force": mean_force,
            "success": success,
            "engaged": engaged,
            "broken": broken,
            "truncation": truncation * (1.0 - broken),
            "had_contact": had_contact,
            "had_engaged": had_engaged,
            "phase": phase.astype(jnp.int32),
            "position_axes": target.position_axes,
        }
        obs = self._observations(data, info, obs_key)
        obs = jax.tree_util.tree_map(lambda x: jnp.where(diverged, 0.0, x), obs)
        return state.replace(pipeline_state=data, obs=obs, reward=reward, done=done,
                             metrics=self._metrics(info, reward), info=info)

    def simulate(self, data: mjx.Data, ee_force: jax.Array, target: ControlTarget,
                 control_steps: int | None = None, model: mjx.Model | None = None) -> "SimResult":
        """Run the control law toward `target` for `control_steps` 120 Hz steps (default: one policy step).

        `ee_force` is the force signal (N, `force_sensor` in `force_frame`) the law starts from; `model`
        the env's randomised model (default: the nominal one). Returns a `SimResult`, with `data`
        kinematics refreshed at the final state. Exposed for tests and scripted experiments.
        """
        cfg = self.config
        m = self.mjx_model if model is None else model
        control_steps = cfg.control_substeps if control_steps is None else control_steps
        low, high = m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1]
        zeros3 = jnp.zeros(3)

        law_keeps_nominal = cfg.randomization.arm_model_error

        def torque_fn(d, force):
            dyn = sim.arm_dynamics(m, d, self.ids, force)
            if law_keeps_nominal:  # the physics' robot differs from the law's model
                dyn = self.model_sampler.nominal_law_view(m, dyn)
            return jnp.clip(hybrid_torque(dyn, target, cfg.controller), low, high)

        def physics_step(carry, hold_torque: bool):
            d, force, _, _, max_force, force_sum = carry
            fn = (lambda d_: d_.ctrl) if hold_torque else (lambda d_: torque_fn(d_, force))
            d = sim.controlled_step(m, d, fn)
            contact = sim.peg_contact_force(m, d, self.ids.peg_geoms)
            torque = zeros3
            if cfg.force_sensor == "wrist":
                d = sensors.compute(m, d)
                force, torque = self.wrist.read(m, d)  # kinematics of the step's start, as the sensor's
            else:
                force = contact
            if cfg.force_frame == "hand":
                hand_rot = d.site_xmat[self.ids.ee_site]
                force, torque = sensors.authors_reading(force, hand_rot), sensors.authors_reading(torque, hand_rot)
            magnitude = jnp.linalg.norm(contact)
            return d, force, torque, contact, jnp.maximum(max_force, magnitude), force_sum + magnitude

        def control_step(carry, _):
            # The law runs at 120 Hz on the latest force reading; its torque is held over the physics
            # substeps (physics_substeps > 1); the force sensor is read after every physics step.
            carry = physics_step(carry, hold_torque=False)
            if cfg.physics_substeps > 1:
                carry, _ = jax.lax.scan(lambda c, _: (physics_step(c, hold_torque=True), None), carry, None,
                                        length=cfg.physics_substeps - 1)
            return carry, None

        carry = (data, ee_force, zeros3, zeros3, jnp.zeros(()), jnp.zeros(()))
        (data, force, torque, contact, max_force, force_sum), _ = jax.lax.scan(
            control_step, carry, None, length=control_steps)
        data = mjx.com_pos(m, mjx.kinematics(m, data))
        return SimResult(data, force, max_force, force_sum / (control_steps * cfg.physics_substeps), torque,
                         contact)

    def _bounded(self, action: jax.Array) -> jax.Array:
        """The action clipped to the space's bounds, or as given with `ActionConfig.clip` off."""
        if not self.config.actions.clip:
            return action
        return jnp.clip(action, jnp.asarray(self.action_space.low), jnp.asarray(self.action_space.high))

    def _smooth(self, action: jax.Array, prev: jax.Array) -> jax.Array:
        """EMA on continuous components; selections pass through."""
        alpha = self.config.actions.ema
        smoothed = alpha * action + (1.0 - alpha) * prev
        if self.action_space.selection:
            sel = jnp.asarray(self.action_space.selection)
            smoothed = smoothed.at[sel].set(action[sel])
        return smoothed

    def _control_target(self, data: mjx.Data, info: dict, action: jax.Array) -> ControlTarget:
        cfg, space, acfg = self.config, self.action_space, self.config.actions
        ee_pos, ee_rot = data.site_xpos[self.ids.ee_site], data.site_xmat[self.ids.ee_site]
        observed_hole_top = info["hole_pos"] + info["hole_obs_offset"] + jnp.array([0.0, 0.0, self._hole_top_offset])
        pos = ee_pos + action[jnp.asarray(space.position)] * acfg.pos_scale
        pos = jnp.clip(pos, observed_hole_top - acfg.pos_box, observed_hole_top + acfg.pos_box)
        yaw = _ee_yaw(ee_rot) + action[space.yaw[0]] * acfg.yaw_scale
        gains = info["gains"]
        kp = gains.get("pos_stiffness", jnp.asarray(cfg.controller.pos_stiffness, jnp.float32))
        if space.stiffness:
            kp = acfg.stiffness(jnp.clip(action[jnp.asarray(space.stiffness)], -1.0, 1.0))
        force = jnp.zeros(3)
        position_axes = jnp.ones(3)
        if space.force:
            f = action[jnp.asarray(space.force)]
            force = jnp.array([f[0] * acfg.force_xy_max, f[1] * acfg.force_xy_max, acfg.force_z(f[2])])
            position_axes = (action[jnp.asarray(space.selection)] <= acfg.selection_threshold).astype(jnp.float32)
        return ControlTarget(pos=pos, rot=_down_rotation(yaw), force=force, position_axes=position_axes,
                             pos_stiffness=kp, posture=info["posture"], rot_stiffness=gains.get("rot_stiffness"),
                             force_gain=gains.get("force_gain"))

    def _reward(self, data: mjx.Data, hole_pos: jax.Array) -> jax.Array:
        """Factory keypoint reward: keypoints on the peg axis vs the same keypoints at the goal."""
        cfg = self.config
        tip = data.site_xpos[self.ids.peg_tip_site]
        axis = -data.xmat[self.ids.peg_body][:, 2]  # peg axis from tip to top (peg frame +z is the tip)
        offsets = jnp.asarray(cfg.keypoint_offsets)[:, None]
        keypoints = tip + offsets * axis
        goal = hole_pos + offsets * jnp.array([0.0, 0.0, 1.0])
        dist = jnp.mean(jnp.linalg.norm(keypoints - goal, axis=-1))
        return sum(1.0 / (jnp.exp(a * dist) + b + jnp.exp(-a * dist)) for a, b in cfg.reward_terms)

    def _observations(self, data: mjx.Data, info: dict, key: jax.Array) -> dict[str, jax.Array]:
        cfg, ids = self.config, self.ids
        k_force, k_pos = jax.random.split(key)  # the force key's draw stays that of earlier versions
        k_torque = jax.random.fold_in(key, 1)
        ee_pos, ee_rot = data.site_xpos[ids.ee_site], data.site_xmat[ids.ee_site]
        m = randomization.apply(self.mjx_model, info["model"])
        jacp, jacr = mjx.jac(m, data, ee_pos, ids.hand_body)
        lin_vel, ang_vel = jacp.T @ data.qvel, jacr.T @ data.qvel
        hole_top = info["hole_pos"] + jnp.array([0.0, 0.0, self._hole_top_offset])
        hole_yaw = jnp.array([jnp.cos(info["hole_yaw"]), jnp.sin(info["hole_yaw"])])
        force = info["ee_force"]
        noisy_ee = ee_pos + cfg.ee_pos_obs_noise * jax.random.normal(k_pos, (3,))
        noisy_force = force + cfg.force_obs_noise * jax.random.normal(k_force, (3,))
        wrench = [noisy_force]
        if cfg.observe_torque:
            wrench.append(info["ee_torque"] + cfg.torque_obs_noise * jax.random.normal(k_torque, (3,)))
        policy = jnp.concatenate([
            noisy_ee - (hole_top + info["hole_obs_offset"]), hole_yaw, lin_vel, ang_vel, *wrench,
            info["prev_action"]])
        tip = data.site_xpos[ids.peg_tip_site]
        # The critic also sees what the actor cannot: the peg's pose (and its offset in the hand), the
        # true contact force, the noise-free wrench.
        privileged = jnp.concatenate([
            ee_pos - hole_top, hole_yaw, lin_vel, ang_vel, force, info["contact_axes"], data.qpos,
            tip, data.xquat[ids.peg_body], info["hole_pos"], ee_pos, ee_rot.ravel(), info["prev_action"]]
            + ([info["ee_torque"], info["contact_force"], info["peg_offset"]]
               if cfg.randomization.enabled or cfg.force_sensor == "wrist" else [])
            + ([self.model_sampler.dynamics_values(info["model"], info["gains"])]
               if cfg.randomization.dynamics else []))
        return {"state": policy, "privileged_state": privileged}

    def _metrics(self, info: dict, reward: jax.Array) -> dict[str, jax.Array]:
        return {
            "success": info["success"],
            "engaged": info["engaged"],
            "broken": info["broken"],
            "in_contact": info["in_contact"],
            "max_force": info["max_force"],
            "reward": reward,
        }
