"""Where the stand-in's transfer gap comes from: one exported policy's noiseless trials on the stand-in with
all its differences from the training simulator, then with one difference removed at a time, then with all
removed (the training simulator's timing and force signal, `StandInConfig.like_training`, breakable at the
stand-in's 20 N). Every configuration runs the same episodes (same seed), so the rates are paired.

    python benchmarks/investigations/standin_gap.py ~/transfer/pose/policy_seed1.onnx --trials 30 --out results/transfer/gap.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import time

from match_jax.transfer.standin import Perturbation, StandInConfig, run_trials

DEFAULT = StandInConfig()
CONFIGS = {
    "stand-in (all differences)": DEFAULT,
    "no observation delay": dataclasses.replace(
        DEFAULT, perturbation=dataclasses.replace(DEFAULT.perturbation, obs_delay_steps=0)),
    "training contact softness and friction": dataclasses.replace(
        DEFAULT, perturbation=dataclasses.replace(DEFAULT.perturbation, contact_timeconst=None, friction=None)),
    "nominal link masses and armature": dataclasses.replace(
        DEFAULT, perturbation=dataclasses.replace(DEFAULT.perturbation, link_mass_scale=None, armature_scale=None)),
    "no physics perturbation (1 kHz law, estimated and filtered force)": dataclasses.replace(
        DEFAULT, perturbation=Perturbation.none()),
    "training timing and force signal (120 Hz law, wrist sensor, no filter)": StandInConfig.like_training(
        break_force=DEFAULT.break_force),
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("policy", type=pathlib.Path, help="ONNX file written by match_jax.transfer.export")
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--noise-mm", type=float, default=0.0)
    parser.add_argument("--out", type=pathlib.Path, required=True)
    args = parser.parse_args(argv)
    if args.trials < 1:
        parser.error(f"--trials must be >= 1, got {args.trials}")
    if not args.policy.is_file():
        parser.error(f"no such file: {args.policy}")
    results = {"policy": str(args.policy), "trials": args.trials, "noise_mm": args.noise_mm, "configs": {}}
    for name, config in CONFIGS.items():
        start = time.time()
        run = run_trials(args.policy, args.trials, args.noise_mm, "shell", seed=0, config=config)
        s = run["summary"]
        results["configs"][name] = {**s, "config": run["config"], "wall_clock_s": time.time() - start}
        print(f"{name:<75} success {100 * s['success_rate']:5.1f} %  breaks {100 * s['broken_rate']:5.1f} %  "
              f"mean force {s['mean_force_n']['mean']:5.2f} N  max force {s['max_force_n']['mean']:5.2f} N", flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
