"""Analytical baselines: scripted policies that use the same env, observations and action spaces.

- `spiral_policy`: the classic hybrid spiral search (hybrid action space). Position control brings the
  peg above the observed hole and lowers it slowly until contact; then z switches to force control
  (pressing with `press_force_n`) while x, y trace an Archimedean spiral around the observed hole; when
  the peg drops into the bore it descends under position control (fast, then slow near the bottom,
  which it locates from the height at which it met the hole top) and finally holds still, seated.
  Far from any surface it moves fast; every speed at which it can touch a surface stays slow.
- `pose_descent_policy`: the naive reference (pose action space): align over the observed hole and
  descend straight down under position control.

Both read only the policy observation obs['state'] (noisy hole position and force), so they face
the same uncertainty as a learned policy. Policies are per-env functions
`(obs, policy_state, key) -> (action, policy_state)`; vmap them over a batch.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

APPROACH, DESCEND, SPIRAL, INSERT, SEAT = 0, 1, 2, 3, 4


@dataclasses.dataclass(frozen=True)
class SpiralConfig:
    """Spiral-search parameters (m, m/s, m/s^2, s, N)."""

    hover_height: float = 0.003  # peg tip above the observed hole top before the descent
    transit_height: float = 0.008  # tip height while still more than `align_radius` off in xy
    align_radius: float = 0.002
    approach_speed: float = 0.03  # free-space speed cap (far from any surface)
    approach_time: float = 0.2  # s: free-space motion aims at a velocity of (remaining error / this)
    aligned_radius: float = 0.001  # xy error (and z error) below which the descent starts
    descend_speed: float = 0.004  # descent toward the hole top (slow: ~10 kg arm inertia, 10 N peg)
    transit_speed: float = 0.010  # descent while still above the hover height
    press_force_n: float = 0.3  # downward force during the spiral
    chamfer_force_n: float = 1.0  # downward force while sliding through the chamfer (damped: safe)
    spiral_pitch: float = 0.002  # radial growth per turn (the chamfer catches the peg ~1.4 mm off the axis)
    spiral_speed: float = 0.004  # tangential speed along the spiral (lateral impacts: ~10 kg x v)
    spiral_lead: float = 1.0  # feed-forward of the spiral velocity (fraction of the PD's tracking lag)
    spiral_max_radius: float = 0.006  # restart the spiral beyond this radius
    sink_depth: float = 0.0003  # tip this far below the contact height: on the chamfer, hold xy
    drop_depth: float = 0.0006  # tip this far below the contact height: entering, insert
    insert_speed: float = 0.020  # top descent speed in the bore
    insert_decel: float = 0.08  # deceleration planned toward the careful zone
    insert_accel: float = 0.06  # the commanded speed leads the actual one by at most this times the step
    careful_speed: float = 0.003  # descent near the bottom
    careful_zone: float = 0.0025  # careful descent below this height above the bottom seen from the contact height
    slow_zone: float = 0.004  # same, above the bottom seen from the observed hole top (no contact seen)
    chamfer_depth: float = 0.002  # below the contact height the peg is past the chamfer
    chamfer_patience: int = 16  # policy steps in the chamfer without sinking further: resume the spiral
    free_drop_depth: float = 0.003  # descending this far below the observed top without contact: in the bore
    seat_depth: float = 0.0005  # once seated, hold the commanded height this far below the tip
    contact_force_n: float = 1.5  # filtered -F_z above this counts as contact
    stall_fraction: float = 0.3  # moving slower than this fraction of the commanded descent counts as blocked
    stall_steps: int = 2  # ... for this many policy steps in a row
    approach_gain: float = 2.0
    force_filter: float = 0.3  # EMA weight of the new force observation
    # N s/m: extra lead of the position target per m/s of velocity error (v_cmd - v), so the compliant
    # arm (task inertia up to ~10 kg against k_d = 20 N s/m) reaches a commanded velocity in ~0.1 s
    velocity_gain: float = 80.0


def _position_action(delta, pos_scale: float, gain: float):
    """Position action aiming `gain` times the remaining error `delta` (m) ahead, clipped to [-1, 1]."""
    return jnp.clip(gain * delta / pos_scale, -1.0, 1.0)


def initial_state() -> dict:
    """Policy state of the scripted policies: phase, steps in phase, filtered force, spiral angle,
    tip height at the last contact (m above the observed hole top), the hole top as met by the peg
    (`referenced` says whether it met it, so that the bottom is known from it), the commanded tip
    height and the number of consecutive steps the peg moved down slower than commanded."""
    return {
        "phase": jnp.zeros((), jnp.int32),
        "steps_in_phase": jnp.zeros((), jnp.int32),
        "force": jnp.zeros(3),
        "theta": jnp.zeros(()),
        "contact_height": jnp.zeros(()),
        "top": jnp.zeros(()),
        "referenced": jnp.zeros(()),
        "z_cmd": jnp.zeros(()),
        "stalled": jnp.zeros((), jnp.int32),
    }


class _Arm(NamedTuple):
    """What the spiral policy uses of an env: action layout and mapping, observation layout, geometry."""

    space: Any  # the hybrid ActionSpace
    layout: dict  # policy observation layout
    actions: Any  # ActionConfig (pos_scale, ema, force_z_action)
    tip_below_ee: float  # m
    depth: float  # hole depth, m
    dt: float  # policy step, s
    kp: jax.Array  # (3,) pose stiffness, N/m
    lead_time: jax.Array  # (3,) s: a target held for one step, leading the EE by L, moves it at L / lead_time


class _Reading(NamedTuple):
    """The spiral policy's view of one step: the observation and its state, derived (m, m/s, N)."""

    rel: jax.Array  # EE relative to the observed hole top
    vel: jax.Array  # EE linear velocity
    prev_pos: jax.Array  # last smoothed position action
    force: jax.Array  # filtered force observation
    height: jax.Array  # peg tip above the observed hole top
    xy_err: jax.Array
    above_bottom: jax.Array  # tip above the bottom (from the met hole top where known)
    zone: jax.Array  # careful zone above the bottom
    in_chamfer: jax.Array


def _read(obs, state, arm: _Arm, config: SpiralConfig) -> _Reading:
    o = obs["state"]
    rel = o[arm.layout["ee_rel_hole"]]
    force = config.force_filter * o[arm.layout["ee_force"]] + (1.0 - config.force_filter) * state["force"]
    height = rel[2] - arm.tip_below_ee
    # Height above the bottom: seen from the contact height when the peg met the hole top (the
    # observation noise cancels), else from the observed hole top.
    referenced = state["referenced"] > 0
    return _Reading(
        rel=rel, vel=o[arm.layout["ee_lin_vel"]],
        prev_pos=o[arm.layout["prev_action"]][jnp.asarray(arm.space.position)],
        force=force, height=height, xy_err=jnp.linalg.norm(rel[:2]),
        above_bottom=jnp.where(referenced, height - (state["top"] - arm.depth), height + arm.depth),
        zone=jnp.where(referenced, config.careful_zone, config.slow_zone),
        in_chamfer=height > state["contact_height"] - config.chamfer_depth)


def _velocity_action(v, vel, arm: _Arm, config: SpiralConfig):
    """Smoothed position action driving the PD to velocity v (m/s, (3,)) from velocity vel."""
    return (v * arm.lead_time + config.velocity_gain * (v - vel) / arm.kp) / arm.actions.pos_scale


def _free_velocity(error, speed_cap, config: SpiralConfig):
    """Velocity toward a target `error` (m) away, capped in norm."""
    v = error / config.approach_time
    norm = jnp.linalg.norm(v)
    return v * jnp.minimum(1.0, speed_cap / jnp.maximum(norm, 1e-9))


def _down_speed(r: _Reading, phase, arm: _Arm, config: SpiralConfig):
    """Commanded descent speed (m/s) of the phase: DESCEND toward the hole top, INSERT in the bore
    (planned from where the tip will be at the end of this step, and sped up gradually: a peg caught on
    the chamfer does not follow, so it is not driven into it); 0 otherwise."""
    ahead = r.above_bottom + jnp.minimum(r.vel[2], 0.0) * arm.dt - r.zone
    insert_speed = jnp.clip(
        jnp.sqrt(config.careful_speed**2 + 2.0 * config.insert_decel * jnp.maximum(ahead, 0.0)),
        config.careful_speed,
        jnp.minimum(config.insert_speed, jnp.maximum(-r.vel[2], config.careful_speed) + config.insert_accel * arm.dt))
    descend_speed = jnp.where(r.height > config.hover_height + 0.001, config.transit_speed, config.descend_speed)
    return jnp.select([phase == DESCEND, phase == INSERT], [descend_speed, insert_speed], 0.0)


def _motion(r: _Reading, phase, down_speed, arm: _Arm, config: SpiralConfig):
    """Smoothed position action of APPROACH (free-space motion to the hover point over the observed hole,
    via the transit height while off in xy), DESCEND and INSERT (hold xy over the hole, down at
    `down_speed`; in the bore x, y only hold still: the observed hole centre is off by the noise)."""
    approach_height = jnp.where(r.xy_err > config.align_radius, config.transit_height, config.hover_height)
    v_approach = _free_velocity(jnp.concatenate([-r.rel[:2], (approach_height - r.height)[None]]),
                                config.approach_speed, config)
    v_xy = jnp.where(phase == DESCEND, _free_velocity(-r.rel[:2], config.approach_speed, config), jnp.zeros(2))
    v_hold = jnp.concatenate([v_xy, -down_speed[None]])
    return _velocity_action(jnp.where(phase == APPROACH, v_approach, v_hold), r.vel, arm, config)


def _spiral(r: _Reading, state, arm: _Arm, config: SpiralConfig):
    """(next spiral angle, xy smoothed position action): track an Archimedean spiral around the observed
    hole (with velocity feed-forward); hold still once the tip starts sinking into the chamfer."""
    radius = config.spiral_pitch * state["theta"] / (2.0 * jnp.pi)
    sinking = r.height < state["contact_height"] - config.sink_depth
    omega = config.spiral_speed / jnp.maximum(radius, 0.0005)
    theta = state["theta"] + jnp.where(sinking, 0.0, omega * arm.dt)
    theta = jnp.where(radius > config.spiral_max_radius, 0.0, theta)
    c, s = jnp.cos(state["theta"]), jnp.sin(state["theta"])
    spiral_xy = radius * jnp.array([c, s])
    spiral_vel = (config.spiral_speed * jnp.array([-s, c])
                  + config.spiral_pitch * omega / (2 * jnp.pi) * jnp.array([c, s]))
    spiral_target = spiral_xy + config.spiral_lead * arm.lead_time[:2] * spiral_vel
    return theta, jnp.where(sinking, 0.0, (spiral_target - r.rel[:2]) / arm.actions.pos_scale)


def _hybrid_action(r: _Reading, state, phase, motion, spiral_xy, arm: _Arm, config: SpiralConfig):
    """(env action, whether z is under force control). z is force-controlled while searching and through
    the chamfer, x and y (at 0 N: compliant) through the chamfer; position control elsewhere. Position
    actions are issued through the env's EMA: the action that makes the smoothed one the wanted one."""
    space, acfg = arm.space, arm.actions
    force_z = (phase == SPIRAL) | ((phase == INSERT) & r.in_chamfer)
    force_xy = (phase == INSERT) & r.in_chamfer
    seat_z = _position_action(state["z_cmd"] - r.height, acfg.pos_scale, config.approach_gain)
    wanted = jnp.where(phase == SPIRAL, jnp.concatenate([spiral_xy, motion[2:]]), motion)
    wanted = jnp.where(phase == SEAT, jnp.zeros(3).at[2].set(seat_z), wanted)
    pos_action = jnp.clip((wanted - (1.0 - acfg.ema) * r.prev_pos) / acfg.ema, -1.0, 1.0)
    pos_action = jnp.where(phase == SEAT, wanted, pos_action)
    press = jnp.where(phase == SPIRAL, config.press_force_n, config.chamfer_force_n)
    action = jnp.zeros(space.size)
    action = action.at[jnp.asarray(space.position)].set(pos_action)
    action = action.at[jnp.asarray(space.selection)].set(jnp.array([force_xy, force_xy, force_z], jnp.float32))
    action = action.at[space.force[2]].set(
        jnp.where(force_z, acfg.force_z_action(-press), acfg.force_z_action(0.0)))
    return action, force_z


def _transition(r: _Reading, state, theta, down_speed, force_z, config: SpiralConfig) -> dict:
    """The next policy state: the phase change this step's reading calls for, and what it records."""
    phase, t = state["phase"], state["steps_in_phase"]
    # Blocked: pressing on something, or (position-controlled descent) moving down much slower than
    # commanded for `stall_steps` steps in a row.
    slow = (r.vel[2] > -config.stall_fraction * down_speed) & ~force_z & (t > 2)
    stalled = jnp.where(slow, state["stalled"] + 1, 0)
    blocked = (r.force[2] < -config.contact_force_n) | (stalled >= config.stall_steps)
    aligned = ((r.xy_err < config.aligned_radius) & (jnp.abs(r.height - config.hover_height) < 0.001)
               & (jnp.linalg.norm(r.vel) < 0.01))
    dropped = r.height < state["contact_height"] - config.drop_depth
    lost_contact = (r.force[2] > -0.3) & (r.height > state["contact_height"] + 0.002)
    next_phase = jnp.select(
        [(phase == APPROACH) & (aligned | (t >= 30)),
         (phase == DESCEND) & blocked,
         (phase == DESCEND) & (r.height < -config.free_drop_depth) & (r.vel[2] < -0.6 * config.descend_speed),
         (phase == SPIRAL) & dropped,
         (phase == SPIRAL) & lost_contact,
         (phase == INSERT) & blocked & (r.above_bottom < r.zone + 0.001),
         (phase == INSERT) & blocked & (t > 10),
         (phase == INSERT) & r.in_chamfer & (t > config.chamfer_patience)],
        [DESCEND, SPIRAL, INSERT, INSERT, DESCEND, SEAT, SPIRAL, SPIRAL], phase)
    changed = next_phase != phase
    met_top = (phase == DESCEND) & (next_phase == SPIRAL)
    referenced = state["referenced"] > 0
    return {
        "phase": next_phase,
        "steps_in_phase": jnp.where(changed, 0, t + 1),
        "force": r.force,
        "theta": jnp.where(next_phase == SPIRAL, theta, 0.0),
        "contact_height": jnp.select(
            [(next_phase == SPIRAL) & changed, (phase == DESCEND) & (next_phase == INSERT)],
            [r.height, 0.0], state["contact_height"]),
        # the hole top as met on a descent (the highest, should a contact come early)
        "top": jnp.where(met_top, jnp.where(referenced, jnp.maximum(state["top"], r.height), r.height), state["top"]),
        "referenced": jnp.where(met_top, 1.0, state["referenced"]),
        "z_cmd": jnp.where((next_phase == SEAT) & changed, r.height - config.seat_depth, state["z_cmd"]),
        "stalled": jnp.where(changed, 0, stalled),
    }


def make_spiral_policy(env, config: SpiralConfig = SpiralConfig()):
    """The spiral-search policy for an env with the 'hybrid' action space.

    Position actions are issued through the env's action smoothing (an EMA on the continuous action
    components, whose last output is part of the observation): the policy picks the action that makes
    the smoothed action equal the one it wants, as far as [-1, 1] allows, so that its commands act
    within one policy step. Motion commands are velocities: the pose PD (k_p, k_d = 2 sqrt(k_p))
    settles at v when its target leads the end effector by v k_d / k_p.
    """
    if env.action_space.name != "hybrid":
        raise ValueError(f"the spiral baseline needs the 'hybrid' controller, got {env.action_space.name!r}")
    kp = jnp.asarray(env.config.controller.pos_stiffness, jnp.float32)
    # A target held for one policy step dt, leading the end effector by L at the step's start, moves it
    # at v = L / (k_d / k_p + dt / 2) (the lead shrinks by v dt / 2 on average over the step).
    arm = _Arm(space=env.action_space, layout=env.policy_obs_layout, actions=env.config.actions,
               tip_below_ee=env.peg_tip_below_ee, depth=env.hole_depth, dt=env.dt, kp=kp,
               lead_time=2.0 / jnp.sqrt(kp) + 0.5 * env.dt)

    def policy(obs, state, key):
        del key
        reading = _read(obs, state, arm, config)
        down_speed = _down_speed(reading, state["phase"], arm, config)
        motion = _motion(reading, state["phase"], down_speed, arm, config)
        theta, spiral_xy = _spiral(reading, state, arm, config)
        action, force_z = _hybrid_action(reading, state, state["phase"], motion, spiral_xy, arm, config)
        return action, _transition(reading, state, theta, down_speed, force_z, config)

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
