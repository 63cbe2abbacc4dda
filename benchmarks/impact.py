"""The break at first contact: P(15 Hz wrist reading >= 10 N) against contact speed, and the contact speeds
of the trained policies.

    python benchmarks/impact.py --json results/impact/impact.json | tee results/impact/impact.md
    python benchmarks/impact.py --part descent --speeds 5,20 --timeconsts 0.02 --episodes 16   # quick look
    python benchmarks/impact.py --part policies

Part 1, scripted descent (`--part descent`). The pose controller (the env's 'pose' action space and its
step, as the policies use them) brings the hand from the env's own reset (hole pose, hand yaw, the peg's
offset in the hand and the spawn all drawn as in training) to a point above the block, holds it, then
moves it straight down at a commanded speed v until it lands, and keeps commanding v after contact.
Motion is commanded as a velocity (the spiral baseline's rule: the target leads the hand by what the
pose PD needs to move at v, plus a feedback term on the velocity error, issued through the action
smoothing); the quasi-static push after contact is what the action range allows, <= 2 N. Two landing
places, the peg tip's axis at a random direction from the bore axis: 'top', 12 mm off (the peg's face,
circumradius 4 mm, entirely over the flat block top, outside the capsule ring at 4.5-6.5 mm) and 'rim',
4.5 mm off (the bore's edge: the face lands on the ring of rounded capsule tops). The descent starts
3 mm + v x 0.3 s above the block top, plus a random part of one policy step's travel, so that contact
begins at a uniformly random time within a policy step (the 15 Hz reading samples the impact at every
phase); the hand moves at its speed when it lands (the measured speed is reported beside the commanded
one). Every speed, place and time constant runs the same episodes (reset draws, directions and phases).
The rollouts are unbreakable; the env's 15 Hz break check (`break_sampling='policy_step'`: |wrist force|
at the end of a policy step) is applied afterwards to the readings of the first 8 policy steps from the
step in which contact begins (0.53 s), so a reading is not cut off by the break. Reported per speed, place
and contact time constant (`FPiHConfig.contact_timeconst`, the solref time constant of every peg contact
pair): the fraction of episodes whose reading reaches 10 N, the median of its peak, the hand's measured
vertical speed at the start of the contact step, and the median of the peg's peak contact force over the
physics steps of those 8 steps (what `break_sampling='peak'` reads). Speeds are a batch dimension: one
compiled program per time constant.

Part 2, trained policies (`--part policies`). The exported best actors of seed 0 of
results/suite_authors/runs/pose and .../match (`--runs`), deterministic, on their own task (hole noise
N(0, 1 mm), the env's draw), unbreakable, 150 steps: the hand's vertical speed at the start of the policy
step in which the peg first touches (mm/s, percentiles over the episodes that touch), where the peg's
axis is then (lateral distance of the tip from the bore axis: < 0.5 mm the face fits the bore, 0.5-10.5 mm
it overlaps the capsule ring, >= 10.5 mm it is entirely over the flat top), the fraction of first contacts
whose 15 Hz reading reaches 10 N within the same 8 steps, and the whole-episode 15 Hz break rate with
the share of those breaks that fall in that window, and the success rate under the 15 Hz check (success
before a reading of 10 N), its mean time to success and the success rate unbreakable.
`--policy-timeconsts 0.05` runs them with softer contact instead (they were trained at 0.02 s).

Runtime at the default sizes, on 2 cores shared with a training run and other jobs (load 3-5): 19-22 min
from an empty compilation cache (5 programs, ~2-2.5 min of compiling each), 11 min with the descent's
programs cached (the persistent cache of the command lines, `match_jax.compile_cache`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import pathlib
import sys
import time

import match_jax  # noqa: F401  (fast XLA CPU flag before JAX starts)

import jax
import jax.numpy as jnp
import numpy as np

from match_jax import compile_cache
from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.rl.ppo import deterministic_policy
from match_jax.training.runs import batch_mesh, load_policy, shard_batch

REPO = pathlib.Path(__file__).resolve().parents[1]
BREAK_N = 10.0
WINDOW_STEPS = 8  # policy steps from the step in which contact begins (8 / 15 Hz = 0.53 s)
PLACES_MM = {"top": 12.0, "rim": 4.5}  # peg axis from the bore axis at landing
TOP_CLEAR_MM = 10.5  # capsule ring outer edge 6.5 mm + peg circumradius 4 mm: the face is all over the top
BORE_FIT_MM = 0.5  # bore radius 4.5 mm - peg circumradius 4 mm
RUN_UP_MM, RUN_UP_S = 3.0, 0.3  # descent start above the block top: RUN_UP_MM + v x RUN_UP_S (+ phase)
APPROACH_SPEED = 0.05  # m/s, free-space speed cap of the approach
APPROACH_TIME = 0.2  # s: the approach aims at a velocity of (remaining error / this) in x, y ...
APPROACH_Z_TIME = 0.4  # s: ... and in z, slower: the velocity loop lags ~0.15 s and must not overshoot
APPROACH_DOWN_SPEED = 0.02  # m/s, the approach's downward speed cap
VELOCITY_GAIN = 80.0  # N s/m, extra target lead per m/s of velocity error (the spiral baseline's)
APPROACH_MAX_STEPS = 36
DESCENT_STEPS = 72
APPROACH, DESCEND = 0, 1


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x.strip()]


# ------------------------------------------------------------------------------------------ rollouts
def _scan_episode(env: FPiHEnv, state, policy, pstate, steps: int, key, extra: tuple[str, ...] = ()):
    """Roll one env `steps` policy steps from `state`; per step the readings the analysis needs:
    vz (hand vertical velocity at the step's start, m/s), phase (the policy state's, if any), in_contact,
    wrist (|end-of-step force signal|, N), peak (the peg's contact peak over the step's physics steps, N),
    lateral (peg tip's distance from the bore axis at the step's end, m), and the `extra` keys of the
    env's info after the step."""
    layout = env.policy_obs_layout

    def body(carry, step_key):
        state, pstate = carry
        vz = state.obs["state"][layout["ee_lin_vel"]][2]  # J qdot, noise-free
        phase = pstate["phase"] if isinstance(pstate, dict) else jnp.zeros((), jnp.int32)
        action, pstate = policy(state, pstate, step_key)
        state = env.step(state, action)
        tip = state.pipeline_state.site_xpos[env.ids.peg_tip_site]
        record = {"vz": vz, "phase": phase, "in_contact": state.info["in_contact"],
                  "wrist": jnp.linalg.norm(state.info["ee_force"]), "peak": state.info["max_force"],
                  "lateral": jnp.linalg.norm(tip[:2] - state.info["hole_pos"][:2]),
                  **{k: state.info[k] for k in extra}}
        return (state, pstate), record

    _, traj = jax.lax.scan(body, (state, pstate), jax.random.split(key, steps))
    return traj


def descent_env(timeconst: float) -> FPiHEnv:
    """The pose-controlled env of the descent: the default task, unbreakable, the hole observed exactly
    (the script steers by the true state anyway), contact time constant `timeconst` s."""
    return FPiHEnv(FPiHConfig(control="pose", break_force=math.inf, hole_obs_noise=0.0,
                              contact_timeconst=timeconst))


def make_descent(env: FPiHEnv, steps: int = DESCENT_STEPS):
    """jit((keys (B, 2), speeds (B,) m/s, offsets (B,) m) -> dict of (T, B) arrays): one scripted descent
    per env (module docstring), landing `offset` from the bore axis at a random direction."""
    space, acfg, ids = env.action_space, env.config.actions, env.ids
    pos = jnp.asarray(space.position)
    kp = jnp.asarray(env.config.controller.pos_stiffness, jnp.float32)
    # A target held for one policy step, leading the hand by L at its start, moves it at L / lead_time
    # (the spiral baseline's `lead_time`: k_d / k_p + dt / 2, k_d = 2 sqrt(k_p)).
    lead_time = 2.0 / jnp.sqrt(kp) + 0.5 * env.dt

    def velocity_action(v_cmd, state):
        vel = state.obs["state"][env.policy_obs_layout["ee_lin_vel"]]
        wanted = (v_cmd * lead_time + VELOCITY_GAIN * (v_cmd - vel) / kp) / acfg.pos_scale
        prev = state.info["prev_action"][pos]  # the smoothed action of the last step
        raw = jnp.clip((wanted - (1.0 - acfg.ema) * prev) / acfg.ema, -1.0, 1.0)
        return jnp.zeros(space.size).at[pos].set(raw)

    def one_env(key, speed, offset):
        k_reset, k_dir, k_phase, k_roll = jax.random.split(key, 4)
        state = env.reset(k_reset)
        angle = jax.random.uniform(k_dir, (), minval=-jnp.pi, maxval=jnp.pi)
        hole = state.info["hole_pos"]
        land_xy = hole[:2] + offset * jnp.array([jnp.cos(angle), jnp.sin(angle)])
        top = hole[2] + env.hole_depth
        # up to one policy step's travel more: contact begins at a uniformly random time within a policy
        # step, so the 15 Hz readings sample the impact at every phase
        hover = top + RUN_UP_MM * 1e-3 + speed * (RUN_UP_S + env.dt * jax.random.uniform(k_phase, ()))

        def policy(state, pstate, _key):
            d = state.pipeline_state
            tip = d.site_xpos[ids.peg_tip_site]
            vel = state.obs["state"][env.policy_obs_layout["ee_lin_vel"]]
            err = jnp.concatenate([land_xy - tip[:2], (hover - tip[2])[None]])
            v_free = err / jnp.array([APPROACH_TIME, APPROACH_TIME, APPROACH_Z_TIME])
            v_free = v_free * jnp.minimum(1.0, APPROACH_SPEED / jnp.maximum(jnp.linalg.norm(v_free), 1e-9))
            v_free = v_free.at[2].max(-APPROACH_DOWN_SPEED)
            phase, t = pstate["phase"], pstate["t"]
            aligned = (jnp.linalg.norm(err) < 5e-4) & (jnp.linalg.norm(vel) < 2e-3)
            phase = jnp.where((phase == APPROACH) & (aligned | (t >= APPROACH_MAX_STEPS)), DESCEND, phase)
            v_cmd = jnp.where(phase == DESCEND, v_free.at[2].set(-speed), v_free)
            return velocity_action(v_cmd, state), {"phase": phase, "t": t + 1}

        pstate = {"phase": jnp.zeros((), jnp.int32), "t": jnp.zeros((), jnp.int32)}
        traj = _scan_episode(env, state, policy, pstate, steps, k_roll)
        # the phase recorded is the one the step ran under (after the policy's own switch)
        traj["phase"] = jnp.concatenate([traj["phase"][1:], traj["phase"][-1:]])
        return traj

    def rollout(keys, speeds, offsets):
        traj = jax.vmap(one_env)(keys, speeds, offsets)
        return jax.tree_util.tree_map(lambda x: jnp.swapaxes(x, 0, 1), traj)

    return jax.jit(rollout)


# ------------------------------------------------------------------------------------------ analysis
def first_contact(traj: dict, window: int = WINDOW_STEPS, threshold: float = BREAK_N) -> dict:
    """Per episode (arrays (B,)) from a dict of (T, B) arrays (`_scan_episode`): touched (some step in
    contact), step (the first such step; T if none), speed_mm_s (downward hand speed at its start),
    reading_peak_n (max 15 Hz reading over `window` steps from it), hit (that peak >= threshold),
    contact_peak_n (the peg's contact peak over the same steps), lateral_mm (tip from the bore axis at
    the end of the first contact step). Episodes that never touch get NaN."""
    contact = np.asarray(traj["in_contact"]) > 0
    T, B = contact.shape
    touched = contact.any(axis=0)
    step = np.where(touched, np.argmax(contact, axis=0), T)
    rows = np.arange(T)[:, None]
    in_window = (rows >= step[None]) & (rows < step[None] + window)
    cols = np.arange(B)
    at = np.minimum(step, T - 1)

    def window_max(x):
        return np.where(touched, np.where(in_window, np.asarray(x), -np.inf).max(axis=0), np.nan)

    reading = window_max(traj["wrist"])
    return {"touched": touched, "step": step,
            "speed_mm_s": np.where(touched, -1e3 * np.asarray(traj["vz"])[at, cols], np.nan),
            "reading_peak_n": reading, "hit": touched & (reading >= threshold),
            "contact_peak_n": window_max(traj["peak"]),
            "lateral_mm": np.where(touched, 1e3 * np.asarray(traj["lateral"])[at, cols], np.nan),
            "window_complete": touched & (step + window <= T)}


def _shown(path) -> str:
    """`path` relative to the repository when it lies inside it."""
    path = pathlib.Path(path).resolve()
    return str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path)


def _pct(x, q):
    x = np.asarray(x, np.float64)
    x = x[~np.isnan(x)]
    return float(np.percentile(x, q)) if len(x) else float("nan")


def run_descent(speeds_mm_s, timeconsts, episodes: int, seed: int, batch: int) -> dict:
    """Part 1: {timeconst: {place: {speed: stats}}} and the settings."""
    places = list(PLACES_MM)
    cases = [(v, place) for v in speeds_mm_s for place in places]
    speeds = np.repeat([v * 1e-3 for v, _ in cases], episodes).astype(np.float32)
    offsets = np.repeat([PLACES_MM[p] * 1e-3 for _, p in cases], episodes).astype(np.float32)
    # the same episodes (reset draws) for every speed and place, and for every time constant
    keys = np.tile(np.asarray(jax.random.split(jax.random.PRNGKey(seed), episodes)), (len(cases), 1))
    n = len(speeds)
    batch = min(batch or n, n)
    out = {}
    for tc in timeconsts:
        start = time.time()
        env = descent_env(tc)
        rollout = make_descent(env)
        mesh = batch_mesh(batch)
        parts = []
        for lo in range(0, n, batch):
            if lo:
                print(f"  call {lo // batch + 1} of {-(-n // batch)} at {time.time() - start:.0f} s", file=sys.stderr,
                      flush=True)
            idx = np.arange(lo, lo + batch) % n  # the last batch padded with repeats, dropped below
            traj = rollout(shard_batch(keys[idx], 0, mesh), shard_batch(speeds[idx], 0, mesh),
                           shard_batch(offsets[idx], 0, mesh))
            parts.append({k: np.asarray(v)[:, : min(batch, n - lo)] for k, v in jax.device_get(traj).items()})
        traj = {k: np.concatenate([p[k] for p in parts], axis=1) for k in parts[0]}
        stats = first_contact(traj)
        phase_at = traj["phase"][np.minimum(stats["step"], traj["phase"].shape[0] - 1), np.arange(n)]
        early = stats["touched"] & (phase_at != DESCEND)  # touched before the descent began
        table = {}
        for ci, (v, place) in enumerate(cases):
            sl = slice(ci * episodes, (ci + 1) * episodes)
            ok = stats["touched"][sl] & ~early[sl] & stats["window_complete"][sl]
            hit = stats["hit"][sl][ok]
            table.setdefault(place, {})[f"{v:g}"] = {
                "episodes": int(ok.sum()), "no_contact": int((~stats["touched"][sl]).sum()),
                "early_contact": int(early[sl].sum()),
                "p_reading_ge_10n": float(hit.mean()) if ok.any() else float("nan"),
                "reading_peak_median_n": _pct(stats["reading_peak_n"][sl][ok], 50),
                "reading_peak_p90_n": _pct(stats["reading_peak_n"][sl][ok], 90),
                "reading_peak_max_n": _pct(stats["reading_peak_n"][sl][ok], 100),
                "speed_at_contact_median_mm_s": _pct(stats["speed_mm_s"][sl][ok], 50),
                "contact_peak_median_n": _pct(stats["contact_peak_n"][sl][ok], 50),
                "lateral_median_mm": _pct(stats["lateral_mm"][sl][ok], 50),
            }
        out[f"{tc:g}"] = table
        print(f"descent, contact time constant {tc:g} s: {n} episodes in {time.time() - start:.0f} s",
              file=sys.stderr, flush=True)
    return {"speeds_mm_s": list(speeds_mm_s), "timeconsts_s": list(timeconsts), "episodes": episodes,
            "seed": seed, "places_mm": PLACES_MM, "window_steps": WINDOW_STEPS, "break_n": BREAK_N,
            "results": out}


def run_policies(run_dirs, timeconsts, episodes: int, seed: int, seed_index: int = 0) -> dict:
    """Part 2: per run and contact time constant, the first-contact statistics of one seed's best actor."""
    out = {}
    for run_dir in run_dirs:
        run, policy = load_policy(run_dir, seed_index, "best")
        act = deterministic_policy(run.trainer)
        params = (policy["params"], policy["policy_stats"])
        for tc in timeconsts:
            start = time.time()
            env = FPiHEnv(dataclasses.replace(run.spec.env, break_force=math.inf, contact_timeconst=tc))

            def one_env(key, params, env=env):
                k_reset, k_roll = jax.random.split(key)
                state = env.reset(k_reset)
                return _scan_episode(env, state, lambda s, p, k: act(s.obs, p, k), params,
                                     env.config.episode_steps, k_roll, extra=("success",))

            rollout = jax.jit(lambda keys, params, f=one_env: jax.tree_util.tree_map(
                lambda x: jnp.swapaxes(x, 0, 1), jax.vmap(f, in_axes=(0, None))(keys, params)))
            keys = jax.random.split(jax.random.PRNGKey(seed), episodes)
            traj = {k: np.asarray(v) for k, v in jax.device_get(
                rollout(shard_batch(keys, 0, batch_mesh(episodes)), params)).items()}
            stats = first_contact(traj)
            touched = stats["touched"]
            broke_any = (traj["wrist"] >= BREAK_N).any(axis=0)
            first_break = np.where(broke_any, np.argmax(traj["wrist"] >= BREAK_N, axis=0), -1)
            in_window = broke_any & touched & (first_break < stats["step"] + WINDOW_STEPS)
            T = traj["success"].shape[0]
            first_success = np.where((traj["success"] > 0).any(axis=0), np.argmax(traj["success"] > 0, axis=0), T)
            success = first_success < np.where(broke_any, first_break, T)  # before the 15 Hz break
            time_s = (first_success[success] + 1) * env.dt
            lateral = stats["lateral_mm"][touched]
            speed = stats["speed_mm_s"][touched]
            hits = stats["hit"][touched]
            name = pathlib.Path(run_dir).name
            out.setdefault(name, {})[f"{tc:g}"] = {
                "run_dir": _shown(run_dir), "seed_index": seed_index, "checkpoint": "best",
                "method": run.spec.ppo.method, "episodes": episodes, "touched": int(touched.sum()),
                "speed_p10_mm_s": _pct(speed, 10), "speed_p50_mm_s": _pct(speed, 50),
                "speed_p90_mm_s": _pct(speed, 90),
                "lateral_p10_mm": _pct(lateral, 10), "lateral_p50_mm": _pct(lateral, 50),
                "lateral_p90_mm": _pct(lateral, 90),
                "place_bore": float(np.mean(lateral < BORE_FIT_MM)) if len(lateral) else float("nan"),
                "place_rim": float(np.mean((lateral >= BORE_FIT_MM) & (lateral < TOP_CLEAR_MM)))
                if len(lateral) else float("nan"),
                "place_top": float(np.mean(lateral >= TOP_CLEAR_MM)) if len(lateral) else float("nan"),
                "p_first_contact_reading_ge_10n": float(hits.mean()) if len(hits) else float("nan"),
                "first_contact_reading_peak_median_n": _pct(stats["reading_peak_n"][touched], 50),
                "break_rate_15hz": float(broke_any.mean()),
                "success_rate_15hz": float(success.mean()),
                "time_to_success_s": float(time_s.mean()) if len(time_s) else float("nan"),
                "success_rate_unbreakable": float((first_success < T).mean()),
                "breaks_in_first_contact_window": float(in_window.sum() / max(broke_any.sum(), 1)),
                "speed_of_hits_mm_s": sorted(round(float(s), 1) for s in speed[hits]),
                "place_of_hits_lateral_mm": sorted(round(float(s), 1) for s in lateral[hits]),
                "speed_mm_s": [round(float(s), 2) for s in speed],
                "reading_peak_n": [round(float(s), 2) for s in stats["reading_peak_n"][touched]],
                "lateral_mm": [round(float(s), 2) for s in lateral],
            }
            print(f"policies, {name}, contact time constant {tc:g} s: {episodes} episodes in "
                  f"{time.time() - start:.0f} s", file=sys.stderr, flush=True)
    return {"episodes": episodes, "seed": seed, "seed_index": seed_index, "results": out}


# ------------------------------------------------------------------------------------------ output
def _f(x, digits=1):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def descent_markdown(part: dict) -> str:
    tcs = list(part["results"])
    lines = [f"Scripted descent, pose control, {part['episodes']} episodes per cell: P(15 Hz wrist reading "
             f">= {part['break_n']:g} N within {part['window_steps']} policy steps of first contact) in %, "
             f"(median peak reading N); measured speed at contact (median mm/s); contact time constant in s.", ""]
    for place in PLACES_MM:
        lines.append(f"**{place}** (peg axis {PLACES_MM[place]:g} mm from the bore axis)")
        lines.append("")
        lines.append("| v (mm/s) | measured v | " + " | ".join(f"tc {tc}" for tc in tcs)
                     + " | contact peak, tc " + " / ".join(tcs) + " (N) |")
        lines.append("|---|---|" + "---|" * len(tcs) + "---|")
        for v in part["results"][tcs[0]][place]:
            cells = [part["results"][tc][place][v] for tc in tcs]
            lines.append(f"| {v} | {_f(cells[0]['speed_at_contact_median_mm_s'])} | "
                         + " | ".join(f"{_f(100 * c['p_reading_ge_10n'], 0)} ({_f(c['reading_peak_median_n'])})"
                                      for c in cells)
                         + " | " + " / ".join(_f(c["contact_peak_median_n"], 0) for c in cells) + " |")
        dropped = [(tc, v, c["no_contact"], c["early_contact"]) for tc in tcs
                   for v, c in part["results"][tc][place].items() if c["no_contact"] or c["early_contact"]]
        if dropped:
            lines.append("")
            lines.append("Left out (tc, v: no contact, touched during the approach): "
                         + "; ".join(f"{tc}, {v}: {a}, {b}" for tc, v, a, b in dropped))
        lines.append("")
    return "\n".join(lines)


def policies_markdown(part: dict) -> str:
    lines = [f"Trained policies, seed index {part['seed_index']}, best actor, deterministic, "
             f"{part['episodes']} episodes, hole noise N(0, 1 mm), unbreakable rollouts, 15 Hz check applied "
             "afterwards.", "",
             "| run | tc (s) | touched | speed at first contact p10 / p50 / p90 (mm/s) "
             "| peg axis from the bore axis p10 / p50 / p90 (mm) | place bore / rim / top % "
             "| first contacts reading >= 10 N % | median peak reading (N) | 15 Hz break rate % "
             "| breaks in the first-contact window % | success % (10 N, 15 Hz) | time to success (s) "
             "| success % unbreakable |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, by_tc in part["results"].items():
        for tc, r in by_tc.items():
            lines.append(
                f"| {name} | {tc} | {r['touched']}/{r['episodes']} | {_f(r['speed_p10_mm_s'])} / "
                f"{_f(r['speed_p50_mm_s'])} / {_f(r['speed_p90_mm_s'])} | {_f(r['lateral_p10_mm'])} / "
                f"{_f(r['lateral_p50_mm'])} / {_f(r['lateral_p90_mm'])} | {_f(100 * r['place_bore'], 0)} / "
                f"{_f(100 * r['place_rim'], 0)} / {_f(100 * r['place_top'], 0)} | "
                f"{_f(100 * r['p_first_contact_reading_ge_10n'])} | {_f(r['first_contact_reading_peak_median_n'])} | "
                f"{_f(100 * r['break_rate_15hz'])} | {_f(100 * r['breaks_in_first_contact_window'], 0)} | "
                f"{_f(100 * r['success_rate_15hz'])} | {_f(r['time_to_success_s'], 2)} | "
                f"{_f(100 * r['success_rate_unbreakable'])} |")
    for name, by_tc in part["results"].items():
        for tc, r in by_tc.items():
            if r["speed_of_hits_mm_s"]:
                lines.append("")
                lines.append(f"{name}, tc {tc}: speeds of the first contacts reading >= 10 N (mm/s): "
                             f"{', '.join(f'{s:g}' for s in r['speed_of_hits_mm_s'])}; peg axis from the bore "
                             f"axis (mm): {', '.join(f'{s:g}' for s in r['place_of_hits_lateral_mm'])}")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=["both", "descent", "policies"], default="both")
    parser.add_argument("--speeds", type=_floats, default=[3, 5, 7, 9, 11, 15, 20, 25, 34],
                        help="descent speeds, mm/s (default 3,5,7,9,11,15,20,25,34)")
    parser.add_argument("--timeconsts", type=_floats, default=[0.02, 0.03, 0.05],
                        help="contact time constants of the descent, s (default 0.02,0.03,0.05)")
    parser.add_argument("--episodes", type=int, default=64, help="descent episodes per speed and place (64)")
    parser.add_argument("--batch", type=int, default=384, help="envs per compiled descent call (384)")
    parser.add_argument("--runs", nargs="+", type=pathlib.Path,
                        default=[REPO / "results/suite_authors/runs/pose", REPO / "results/suite_authors/runs/match"])
    parser.add_argument("--policy-episodes", type=int, default=64, help="episodes per trained policy (64)")
    parser.add_argument("--policy-timeconsts", type=_floats, default=[0.02],
                        help="contact time constants of the policy rollouts, s (default 0.02, as trained)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=pathlib.Path, default=None, help="also write the numbers here")
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.policy_episodes < 1 or args.batch < 0:
        parser.error("--episodes and --policy-episodes must be >= 1, --batch >= 0")
    for tc in args.timeconsts + args.policy_timeconsts:
        FPiHConfig(contact_timeconst=tc)  # one-line error on a bad value before any work
    compile_cache.enable()
    out = {"command": "python benchmarks/impact.py " + " ".join(argv if argv is not None else sys.argv[1:])}
    start = time.time()
    if args.part in ("both", "descent"):
        out["descent"] = run_descent(args.speeds, args.timeconsts, args.episodes, args.seed, args.batch)
        print(descent_markdown(out["descent"]), flush=True)
    if args.part in ("both", "policies"):
        runs = [r.resolve() for r in args.runs]
        out["policies"] = run_policies(runs, args.policy_timeconsts, args.policy_episodes, args.seed)
        print(policies_markdown(out["policies"]), flush=True)
    out["seconds"] = round(time.time() - start, 1)
    print(f"total {out['seconds']:.0f} s", file=sys.stderr)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
