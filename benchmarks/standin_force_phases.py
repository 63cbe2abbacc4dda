"""Where an exported policy's mean contact force comes from on the stand-in: the filtered force estimate's
samples above the contact threshold, split at the first success (before: search and insertion; after: the
peg resting in the hole until the episode ends). Noiseless trials, the protocol's episodes (seed 0).

    python benchmarks/standin_force_phases.py --policies pose=RUN/onnx/policy_seed0.onnx,vices=... \
        --stochastic pose --trials 8 --json results/transfer/dynamics_randomization/force_phases.json
"""

import argparse
import json

import numpy as np

from match_jax import standin


def phases(policy_path: str, trials: int, stochastic: bool) -> dict:
    """Per trial: the stand-in's mean force (N) and, before and after the first success, the mean filtered
    force (N) over samples above the contact threshold and the fraction of samples above it."""
    policy = standin.Policy(policy_path, noise_seed=(0, standin.ACTION_NOISE_STREAM) if stochastic else None)
    stand_in = standin.StandIn(policy.description, standin.StandInConfig())
    rng, rows = np.random.default_rng(0), []
    for _ in range(trials):
        result = stand_in.run(policy, stand_in.sample_episode(rng, 0.0), record=True)
        force = np.linalg.norm(result["force_filtered"], axis=1)
        success_t = result["time_to_success_s"]
        cut = len(force) if success_t is None else int(round(success_t * stand_in.config.control_hz))
        row = {"success": result["success"], "mean_force_n": result["mean_force_n"]}
        for name, part in (("before", force[:cut]), ("after", force[cut:])):
            contact = part > stand_in.config.contact_threshold
            row[f"{name}_contact_fraction"] = float(contact.mean()) if len(part) else None
            row[f"{name}_mean_force_n"] = float(part[contact].mean()) if contact.any() else None
        rows.append(row)
    return {"policy": policy_path, "deployment": policy.deployment, "trials": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policies", required=True, help="NAME=PATH.onnx,... ")
    parser.add_argument("--stochastic", default="", help="comma-separated names to run sampled")
    parser.add_argument("--trials", type=int, default=8)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    sampled = {n for n in args.stochastic.split(",") if n}
    out = {}
    for item in args.policies.split(","):
        name, path = item.split("=", 1)
        out[name] = phases(path, args.trials, name in sampled)
        for key in ("mean_force_n", "before_mean_force_n", "after_mean_force_n", "after_contact_fraction"):
            values = [r[key] for r in out[name]["trials"] if r[key] is not None]
            print(f"{name} {key}: median {np.median(values):.2f} ({min(values):.2f}-{max(values):.2f})")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
