"""Which rotational stiffness the control law holds still: Pose envs at the neutral action, every drawn gain
nominal but the rotational k_p, for 40 policy steps (5.3 s).

    python benchmarks/investigations/gain_stability.py --json results/transfer/gain_stability.json

Per k_p (N m/rad; k_d = 2 sqrt(k_p), applied once per control step) and control rate: the fraction of envs
whose peg broke (the 15 Hz wrist check, 10 N) and that touched the block, and the mean |joint velocity| of
the wrist joints 5 and 7 over the last 10 policy steps (rad/s; an arm holding still reads ~0). The default
scene and spawn (uniform spawn noise, the peg moving in the hand); the k_p is set in each env's drawn gains,
so one compiled step serves every value of one control rate.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib

import match_jax  # noqa: F401  (fast XLA CPU flag)

import jax
import jax.numpy as jnp
import numpy as np

from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.envs.randomization import AUTHORS_DYNAMICS


def hold(env: FPiHEnv, rot_stiffness: list[float], envs: int, steps: int) -> list[dict]:
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), envs))
    step = jax.jit(jax.vmap(env.step))
    action = jnp.broadcast_to(env.neutral_action(), (envs, env.action_size))
    rows = []
    for kp in rot_stiffness:
        s = state.replace(info={**state.info, "gains": {"rot_stiffness": jnp.full((envs, 3), kp)}})
        broken, touched, speeds = np.zeros(envs, bool), np.zeros(envs, bool), []
        for t in range(steps):
            s = step(s, action)
            broken |= np.asarray(s.metrics["broken"]) > 0
            touched |= np.asarray(s.metrics["in_contact"]) > 0
            if t >= steps - 10:
                speeds.append(np.abs(np.asarray(s.pipeline_state.qvel)[:, [4, 6]]).mean())
        rows.append({"rot_stiffness": kp, "control_hz": round(1.0 / env.config.control_dt), "broken": broken.mean(),
                     "touched": touched.mean(), "wrist_speed_rad_s": float(np.mean(speeds))})
        print(rows[-1], flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rot-stiffness", default="20,30,33,36,40,50,60", help="k_p values, N m/rad")
    parser.add_argument("--fast-control", default="60", help="k_p values also run with the law at 240 Hz")
    parser.add_argument("--envs", type=int, default=32)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--json", type=pathlib.Path)
    args = parser.parse_args(argv)
    # The authors' rotational range makes the env carry a drawn 'rot_stiffness' gain; no other gain is drawn.
    randomization = dataclasses.replace(FPiHConfig().randomization, rot_stiffness=AUTHORS_DYNAMICS["rot_stiffness"])
    config = FPiHConfig(control="pose", randomization=randomization)
    rows = hold(FPiHEnv(config), [float(v) for v in args.rot_stiffness.split(",")], args.envs, args.steps)
    if args.fast_control:
        fast = dataclasses.replace(config, control_dt=config.control_dt / 2, control_substeps=2 * config.control_substeps)
        rows += hold(FPiHEnv(fast), [float(v) for v in args.fast_control.split(",")], args.envs, args.steps)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"command": "python benchmarks/investigations/gain_stability.py", "envs": args.envs,
                                         "steps": args.steps, "rows": rows}, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
