"""Evaluate a scripted baseline on the fragile peg-in-hole env: success, break, time, force.

    python eval.py --baseline spiral --episodes 100 --noise-mm 1 --json results/spiral.json
    python eval.py --baseline pose --episodes 100 --noise-mm 2.5

Writes JSON with episodes, success_rate, break_rate, mean_time_to_success_s, mean_force_n (mean
force magnitude over in-contact steps) and prints a table. Evaluating trained runs (RUN_DIR) comes
with the training code.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import pathlib
import sys
import time

import match_jax  # noqa: F401  (sets the fast XLA CPU flag before JAX starts)


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", choices=["spiral", "pose"], required=True, help="scripted policy")
    parser.add_argument("--episodes", type=int, default=100, help="number of episodes (default 100)")
    parser.add_argument("--noise-mm", type=float, default=1.0,
                        help="hole-position observation noise in mm (sd for gaussian, half-width for uniform)")
    parser.add_argument("--noise-type", choices=["gaussian", "uniform"], default="gaussian")
    parser.add_argument("--break-force", type=float, default=10.0, help="break threshold in N (default 10)")
    parser.add_argument("--unbreakable", action="store_true", help="no break threshold")
    parser.add_argument("--batch", type=int, default=0, help="episodes per jitted batch (default: all)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=pathlib.Path, default=None, help="write the results here")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if not (args.noise_mm >= 0 and math.isfinite(args.noise_mm)):
        parser.error(f"--noise-mm must be a finite number >= 0, got {args.noise_mm}")
    if not args.break_force > 0:
        parser.error(f"--break-force must be > 0 N, got {args.break_force}")
    if args.batch < 0:
        parser.error(f"--batch must be >= 0, got {args.batch}")
    return args


def evaluate_baseline(name: str, episodes: int, noise_m: float, noise_type: str = "gaussian",
                      break_force: float = 10.0, seed: int = 0, batch: int = 0) -> dict:
    """Run `episodes` episodes of a baseline and return the summary dict (see match_jax.evaluation)."""
    import jax
    import numpy as np

    from match_jax import baselines, evaluation
    from match_jax.envs import FPiHConfig, FPiHEnv

    control = baselines.BASELINES[name][0]
    env = FPiHEnv(FPiHConfig(control=control, hole_obs_noise=noise_m, hole_obs_noise_type=noise_type,
                             break_force=break_force))
    policy, policy_state = baselines.make_baseline(name, env)
    rollout = jax.jit(evaluation.make_rollout(env, policy))
    batch = batch or episodes
    keys = jax.random.split(jax.random.PRNGKey(seed), episodes)
    per_episode = []
    for start in range(0, episodes, batch):
        chunk = keys[start:start + batch]
        if len(chunk) < batch:  # pad to the compiled batch size, drop the padding afterwards
            chunk = np.concatenate([chunk, keys[: batch - len(chunk)]])
        states = jax.tree_util.tree_map(lambda x: np.broadcast_to(x, (batch,) + x.shape), policy_state)
        traj = rollout(chunk, states)
        metrics = evaluation.episode_metrics(traj, env.dt)
        n = min(batch, episodes - start)
        per_episode.append({k: v[:n] for k, v in metrics.items()})
    merged = {k: np.concatenate([m[k] for m in per_episode]) for k in per_episode[0]}
    summary = evaluation.summarize(merged)
    summary.update(baseline=name, noise_mm=noise_m * 1000.0, noise_type=noise_type,
                   break_force_n=break_force if math.isfinite(break_force) else None, seed=seed,
                   env_config={k: v for k, v in dataclasses.asdict(env.config).items()
                               if isinstance(v, (int, float, str))})
    return summary


def format_table(summary: dict) -> str:
    rows = [
        ("episodes", f"{summary['episodes']}"),
        ("success %", f"{100 * summary['success_rate']:.1f}"),
        ("break %", f"{100 * summary['break_rate']:.1f}"),
        ("time to success (s)", f"{summary['mean_time_to_success_s']:.2f}"),
        ("mean contact force (N)", f"{summary['mean_force_n']:.2f}"),
    ]
    title = (f"{summary['baseline']} baseline, hole noise {summary['noise_mm']:g} mm ({summary['noise_type']}), "
             f"break force {summary['break_force_n'] or 'none'}")
    width = max(len(k) for k, _ in rows)
    return "\n".join([title] + [f"  {k:<{width}}  {v:>8}" for k, v in rows])


def main(argv=None) -> int:
    args = parse_args(argv)
    start = time.time()
    summary = evaluate_baseline(args.baseline, args.episodes, args.noise_mm / 1000.0, args.noise_type,
                                math.inf if args.unbreakable else args.break_force, args.seed, args.batch)
    summary["wall_clock_s"] = round(time.time() - start, 1)
    print(format_table(summary))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary, indent=2, allow_nan=True))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
