"""Analytical baselines: scripted policies that use the same env, observations and action spaces.

- `spiral_policy`: the classic hybrid spiral search (hybrid action space). Position control brings the
  peg above the observed hole and lowers it slowly until contact; then z switches to force control
  (pressing with `press_force_n`) while x, y trace an Archimedean spiral around the observed hole; when
  the peg drops into the bore it descends under position control (fast, then slow near the bottom)
  and finally seats under z force control.
- `pose_descent_policy`: the naive reference (pose action space): align over the observed hole and
  descend straight down under position control.

Both read only the policy observation obs['state'] (noisy hole position and force), so they face
the same uncertainty as a learned policy. Policies are per-env functions
`(obs, policy_state, key) -> (action, policy_state)`; vmap them over a batch.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

APPROACH, DESCEND, SPIRAL, INSERT, SEAT = 0, 1, 2, 3, 4


@dataclasses.dataclass(frozen=True)
class SpiralConfig:
    """Spiral-search parameters (m, m/s, N)."""

    hover_height: float = 0.004  # peg tip above the observed hole top before the descent
    transit_height: float = 0.010  # tip height while still more than `align_radius` off in xy
    align_radius: float = 0.002
    approach_max_action: float = 0.5  # |z action| cap while approaching (avoids diving at the block)
    descend_speed: float = 0.004  # descent toward the hole top (slow: ~10 kg arm inertia, 10 N peg)
    transit_speed: float = 0.010  # descent while still above the hover height
    press_force_n: float = 0.3  # downward force during the spiral
    chamfer_force_n: float = 1.0  # downward force while sliding through the chamfer (damped: safe)
    spiral_pitch: float = 0.0015  # radial growth per turn
    spiral_speed: float = 0.004  # tangential speed along the spiral (lateral impacts: ~10 kg x v)
    spiral_max_radius: float = 0.006  # restart the spiral beyond this radius
    sink_depth: float = 0.0003  # tip this far below the contact height: on the chamfer, hold xy
    drop_depth: float = 0.0006  # tip this far below the contact height: entering, insert
    insert_speed: float = 0.015  # descent in the bore
    careful_speed: float = 0.003  # descent over the last `slow_zone` above the bottom
    slow_zone: float = 0.006
    chamfer_depth: float = 0.002  # below the contact height the peg is past the chamfer
    chamfer_patience: int = 16  # policy steps in the chamfer without sinking further: resume the spiral
    free_drop_depth: float = 0.003  # descending this far below the observed top without contact: in the bore
    seat_depth: float = 0.0005  # once seated, hold the commanded height this far below the tip
    contact_force_n: float = 1.5  # filtered -F_z above this counts as contact
    blocked_depth: float = 0.004  # commanded height this far below the tip counts as contact
    approach_gain: float = 2.0
    approach_damping: float = 0.25  # s: position actions aim at (error - damping * velocity)
    force_filter: float = 0.3  # EMA weight of the new force observation


def _position_action(delta, pos_scale: float, gain: float):
    """Position action aiming `gain` times the remaining error `delta` (m) ahead, clipped to [-1, 1]."""
    return jnp.clip(gain * delta / pos_scale, -1.0, 1.0)


def initial_state() -> dict:
    """Policy state of the scripted policies: phase, steps in phase, filtered force, spiral angle,
    tip height at first contact and the commanded tip height (m above the observed hole top)."""
    return {
        "phase": jnp.zeros((), jnp.int32),
        "steps_in_phase": jnp.zeros((), jnp.int32),
        "force": jnp.zeros(3),
        "theta": jnp.zeros(()),
        "contact_height": jnp.zeros(()),
        "z_cmd": jnp.zeros(()),
    }


def make_spiral_policy(env, config: SpiralConfig = SpiralConfig()):
    """The spiral-search policy for an env with the 'hybrid' action space."""
    if env.action_space.name != "hybrid":
        raise ValueError(f"the spiral baseline needs the 'hybrid' controller, got {env.action_space.name!r}")
    space, layout, acfg = env.action_space, env.policy_obs_layout, env.config.actions
    tip_below_ee, depth, dt = env.peg_tip_below_ee, env.hole_depth, env.dt
    f_lo, f_hi = acfg.force_z_range

    def force_z_action(force_n):  # inverse of f_z = lo + (a + 1) / 2 (hi - lo), for a push of force_n
        return -1.0 + 2.0 * (-force_n - f_lo) / (f_hi - f_lo)

    def to_position_action(delta):
        return _position_action(delta, acfg.pos_scale, config.approach_gain)

    def policy(obs, state, key):
        del key
        o = obs["state"]
        rel, vel = o[layout["ee_rel_hole"]], o[layout["ee_lin_vel"]]
        force = config.force_filter * o[layout["ee_force"]] + (1.0 - config.force_filter) * state["force"]
        height = rel[2] - tip_below_ee  # peg tip above the observed hole top (m)
        phase, t = state["phase"], state["steps_in_phase"]
        blocked = (force[2] < -config.contact_force_n) | (
            (t > 3) & (state["z_cmd"] < height - config.blocked_depth))
        lost_contact = (force[2] > -0.3) & (height > state["contact_height"] + 0.002)

        # z: an absolute commanded tip height, lowered at the phase's speed and tracked by position.
        near_bottom = height < -depth + config.slow_zone
        in_chamfer = height > state["contact_height"] - config.chamfer_depth
        speed = jnp.select([(phase == DESCEND) & (state["z_cmd"] > config.hover_height), phase == DESCEND,
                            (phase == INSERT) & near_bottom, phase == INSERT],
                           [config.transit_speed, config.descend_speed, config.careful_speed, config.insert_speed],
                           0.0)
        approach_height = jnp.where(jnp.linalg.norm(rel[:2]) > config.align_radius, config.transit_height,
                                    config.hover_height)
        z_cmd = jnp.where(phase == APPROACH, approach_height, state["z_cmd"] - speed * dt)
        z = to_position_action(z_cmd - height)
        z_approach = to_position_action(z_cmd - height - config.approach_damping * vel[2])
        z = jnp.where(phase == APPROACH,
                      jnp.clip(z_approach, -config.approach_max_action, config.approach_max_action), z)

        # xy: centre on the observed hole; in the spiral, track an Archimedean spiral around it and
        # hold still (damping only) once the tip starts sinking into the chamfer; in the bore, comply.
        radius = config.spiral_pitch * state["theta"] / (2.0 * jnp.pi)
        sinking = height < state["contact_height"] - config.sink_depth
        theta = state["theta"] + jnp.where(sinking, 0.0, config.spiral_speed * dt / jnp.maximum(radius, 0.0005))
        theta = jnp.where(radius > config.spiral_max_radius, 0.0, theta)
        spiral_xy = radius * jnp.array([jnp.cos(state["theta"]), jnp.sin(state["theta"])])
        spiral_action = jnp.where(sinking, 0.0, jnp.clip((spiral_xy - rel[:2]) / acfg.pos_scale, -1.0, 1.0))
        xy_center = jnp.clip((-rel[:2] - config.approach_damping * vel[:2]) / acfg.pos_scale, -1.0, 1.0)
        xy = jnp.select([phase <= DESCEND, phase == SPIRAL], [xy_center, spiral_action],
                        jnp.zeros(2))

        # z under force control while searching and through the chamfer, position control otherwise;
        # x, y under force control (0 N: compliant) through the chamfer, damped position control elsewhere.
        force_z = (phase == SPIRAL) | ((phase == INSERT) & in_chamfer)
        force_xy = (phase == INSERT) & in_chamfer
        press = jnp.where(phase == SPIRAL, config.press_force_n, config.chamfer_force_n)
        action = jnp.zeros(space.size)
        action = action.at[jnp.asarray(space.position)].set(jnp.concatenate([xy, z[None]]))
        action = action.at[jnp.asarray(space.selection)].set(
            jnp.array([force_xy, force_xy, force_z], jnp.float32))
        action = action.at[space.force[2]].set(jnp.where(force_z, force_z_action(press), force_z_action(0.0)))

        aligned = (jnp.linalg.norm(rel[:2]) < 0.0015) & (jnp.abs(height - config.hover_height) < 0.0015)
        dropped = height < state["contact_height"] - config.drop_depth
        next_phase = jnp.select(
            [(phase == APPROACH) & (aligned | (t >= 30)),
             (phase == DESCEND) & blocked,
             (phase == DESCEND) & (height < -config.free_drop_depth),
             (phase == SPIRAL) & dropped,
             (phase == SPIRAL) & lost_contact,
             (phase == INSERT) & blocked & near_bottom,
             (phase == INSERT) & blocked & ~near_bottom & (t > 10),
             (phase == INSERT) & in_chamfer & (t > config.chamfer_patience)],
            [DESCEND, SPIRAL, INSERT, INSERT, DESCEND, SEAT, SPIRAL, SPIRAL], phase)
        changed = next_phase != phase
        new_state = {
            "phase": next_phase,
            "steps_in_phase": jnp.where(changed, 0, t + 1),
            "force": force,
            "theta": jnp.where(next_phase == SPIRAL, theta, 0.0),
            "contact_height": jnp.select(
                [(next_phase == SPIRAL) & changed, (phase == DESCEND) & (next_phase == INSERT)],
                [height, 0.0], state["contact_height"]),
            # entering the bore or resuming the descent: command from the current height
            "z_cmd": jnp.select(
                [(((next_phase == INSERT) | (next_phase == DESCEND)) & changed) | ((phase == INSERT) & in_chamfer),
                 (next_phase == SEAT) & changed],
                [height, height - config.seat_depth], z_cmd),
        }
        return action, new_state

    return policy


def _speed_action(speed: float, env) -> float:
    """z position action that makes the pose PD (k_p, k_d = 2 sqrt(k_p)) settle at `speed` (m/s).

    The law settles where k_p e = k_d v, so the target must lead the end effector by e = v k_d / k_p.
    """
    kp = env.config.controller.pos_stiffness[2]
    return speed * 2.0 * kp**0.5 / kp / env.config.actions.pos_scale


def make_pose_descent_policy(env, descend_speed: float = 0.005, hover_height: float = 0.005,
                             approach_gain: float = 2.0):
    """Naive reference: align over the observed hole, then descend straight down (pose action space)."""
    if env.action_space.name != "pose":
        raise ValueError(f"the pose-descent baseline needs the 'pose' controller, got {env.action_space.name!r}")
    space, layout, acfg = env.action_space, env.policy_obs_layout, env.config.actions
    tip_below_ee = env.peg_tip_below_ee

    def policy(obs, state, key):
        del key
        rel = obs["state"][layout["ee_rel_hole"]]
        height = rel[2] - tip_below_ee
        phase, t = state["phase"], state["steps_in_phase"]
        xy = _position_action(-rel[:2], acfg.pos_scale, approach_gain)
        z = jnp.where(phase == APPROACH,
                      _position_action(hover_height - height, acfg.pos_scale, approach_gain),
                      -_speed_action(descend_speed, env))
        action = jnp.zeros(space.size).at[jnp.asarray(space.position)].set(jnp.concatenate([xy, z[None]]))
        aligned = (jnp.linalg.norm(rel[:2]) < 0.001) & (jnp.abs(height - hover_height) < 0.0015)
        next_phase = jnp.where((phase == APPROACH) & (aligned | (t >= 30)), DESCEND, phase)
        new_state = dict(state, phase=next_phase, steps_in_phase=jnp.where(next_phase != phase, 0, t + 1))
        return action, new_state

    return policy


BASELINES = {"spiral": ("hybrid", make_spiral_policy), "pose": ("pose", make_pose_descent_policy)}


def make_baseline(name: str, env):
    """(policy, initial policy state) of a named baseline ('spiral' or 'pose')."""
    if name not in BASELINES:
        raise ValueError(f"unknown baseline {name!r}; choose one of {sorted(BASELINES)}")
    return BASELINES[name][1](env), initial_state()
