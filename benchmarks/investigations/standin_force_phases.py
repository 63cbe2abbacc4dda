"""Where an exported policy's mean contact force comes from on the stand-in: the filtered force estimate's
samples above the contact threshold, split at the first success (before: search and insertion; after: the
peg resting in the hole until the episode ends); for hybrid policies, the in-contact and free axis-steps on
force control (the stand-in's counts, per policy step and axis as eval.py's per-axis rates). Noiseless trials,
the protocol's episodes (seed 0); `--config` removes differences from the training simulator (`like-training`:
its timing and force signal).

    python benchmarks/investigations/standin_force_phases.py --policies pose=RUN/onnx/policy_seed0.onnx,vices=... \
        --stochastic pose --trials 8 --json results/transfer/dynamics_randomization/force_phases.json
"""

import argparse
import dataclasses
import json
import math
import pathlib

import numpy as np

from match_jax.transfer import standin


_DEFAULT = standin.StandInConfig()
_PERTURBATION = _DEFAULT.perturbation
CONFIGS = {
    "standin": _DEFAULT,
    # one difference from the training simulator removed at a time
    "no-filter": dataclasses.replace(_DEFAULT, ema_alpha=1.0, break_force=math.inf),  # unbreakable: raw spikes
    "wrist-sensor": dataclasses.replace(_DEFAULT, force_source="wrist"),
    "no-delay": dataclasses.replace(_DEFAULT, perturbation=dataclasses.replace(_PERTURBATION, obs_delay_steps=0)),
    "training-contact": dataclasses.replace(
        _DEFAULT, perturbation=dataclasses.replace(_PERTURBATION, contact_timeconst=None, friction=None)),
    "nominal-links": dataclasses.replace(
        _DEFAULT, perturbation=dataclasses.replace(_PERTURBATION, link_mass_scale=None, armature_scale=None)),
    # every physics difference removed (1 kHz law, estimated and filtered force)
    "no-perturbation": dataclasses.replace(_DEFAULT, perturbation=standin.Perturbation.none()),
    # the training simulator's timing and force signal (120 Hz law, wrist sensor, no filter), 20 N break
    "like-training": standin.StandInConfig.like_training(break_force=_DEFAULT.break_force),
}


def phases(policy_path: str, trials: int, stochastic: bool, config_name: str = "standin") -> dict:
    """Per trial: the stand-in's mean force (N) and, before and after the first success, the mean filtered
    force (N) over samples above the contact threshold and the fraction of samples above it; for hybrid
    policies, the stand-in's force-selection counts (`standin.selection_rates` pools them)."""
    policy = standin.Policy(policy_path, noise_seed=(0, standin.ACTION_NOISE_STREAM) if stochastic else None)
    stand_in = standin.StandIn(policy.description, CONFIGS[config_name])
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
        row["selection"] = result["selection"]  # hybrid policies: the stand-in's force-selection counts
        rows.append(row)
    return {"policy": policy_path, "deployment": policy.deployment, "config": config_name, "trials": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policies", required=True, help="NAME=PATH.onnx,... ")
    parser.add_argument("--stochastic", default="", help="comma-separated names to run sampled")
    parser.add_argument("--trials", type=int, default=8)
    parser.add_argument("--config", choices=sorted(CONFIGS), default="standin",
                        help="the stand-in as the protocol runs it (default), with one difference from the training "
                             "simulator removed, or with the training timing and force signal")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    sampled = {n for n in args.stochastic.split(",") if n}
    out = {}
    policies = [item.split("=", 1) for item in args.policies.split(",")]
    for item, pair in zip(args.policies.split(","), policies):
        if len(pair) != 2 or not pathlib.Path(pair[1]).is_file():
            parser.error(f"--policies: expected NAME=PATH.onnx with an existing file, got {item!r}")
    if args.trials < 1:
        parser.error(f"--trials must be >= 1, got {args.trials}")
    for name, path in policies:
        out[name] = phases(path, args.trials, name in sampled, args.config)
        for key in ("mean_force_n", "before_mean_force_n", "after_mean_force_n", "after_contact_fraction"):
            values = [r[key] for r in out[name]["trials"] if r[key] is not None]
            if not values:  # e.g. no success: nothing after it
                continue
            print(f"{name} {key}: median {np.median(values):.2f} ({min(values):.2f}-{max(values):.2f})")
        pooled = standin.selection_rates(out[name]["trials"])
        if pooled is not None:
            out[name]["selection"] = pooled
            for part, label in (("", "whole trials"), ("before_success_", "before success")):
                for where in ("contact", "free"):
                    hits, steps = (pooled[f"{part}{kind}{where}_axis_steps"] for kind in ("force_selected_", ""))
                    print(f"{name} force control on {where} axis-steps, {label}: {hits} / {steps}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
