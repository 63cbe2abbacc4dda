"""The scripted spiral search on the authors' task: at N(0, 1 mm) hole noise and on the four noise
shells, with the peg moved in the hand every episode (the default) and held rigidly; break rates under both samplings
on the same episodes (one unbreakable rollout, thresholds applied afterwards).

    python benchmarks/investigations/spiral_authors_task.py --episodes 200 --json results/authors_task/spiral_baseline.json

The spiral search reads only the actor's observation, so the in-hand offset is hidden from it as from a
learned policy: a search, it should still find the hole. Each row: `evaluation.evaluate_baseline`.
"""

from __future__ import annotations

import argparse
import json
import pathlib

import match_jax  # noqa: F401  (fast XLA CPU flag)

from match_jax import compile_cache
from match_jax.training import evaluation
from match_jax.envs.randomization import ModelRandomization

GRASPS = {"peg offset": {}, "rigid": {"randomization": ModelRandomization(peg_offset_range=(0.0, 0.0, 0.0))}}

LEVELS = [(1.0, "gaussian")] + [(level, "shell") for level in evaluation.SHELL_EDGES_MM[1:]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--json", type=pathlib.Path, default=None)
    args = parser.parse_args()
    compile_cache.enable()
    rows = []
    for grasp, task in GRASPS.items():
        for level, kind in LEVELS:
            summary = evaluation.evaluate_baseline("spiral", args.episodes, level / 1000.0, kind, **task)
            summary["grasp"] = grasp
            rows.append(summary)
            print(f"spiral, {grasp}, {kind} {level:g} mm: {100 * summary['success_rate']:.1f} % success, "
                  f"breaks {100 * summary['break_rate_policy_step']:.1f} % (15 Hz) / "
                  f"{100 * summary['break_rate_peak']:.1f} % (peak), {summary['mean_time_to_success_s']:.2f} s, "
                  f"auth force {summary['authors_mean_force_n']:.2f} N", flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
