"""Where an exported policy's mean contact force comes from on the stand-in: the filtered force estimate's
samples above the contact threshold, split at the first success (before: search and insertion; after: the
peg resting in the hole until the episode ends); for hybrid policies, the fraction of in-contact and of free
axes on force control (per policy step and axis, as eval.py's per-axis rates). Noiseless trials, the protocol's
episodes (seed 0); `--config` removes differences from the training simulator (`like-training`: its timing and
force signal).

    python benchmarks/standin_force_phases.py --policies pose=RUN/onnx/policy_seed0.onnx,vices=... \
        --stochastic pose --trials 8 --json results/transfer/dynamics_randomization/force_phases.json
"""

import argparse
import dataclasses
import json
import math
import pathlib

import numpy as np

from match_jax import standin


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
    policies, the fraction of in-contact and of free axis-steps on force control, whole trial and before success."""
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
        selection = stand_in.actions["selection_indices"]
        if selection:
            force_axes = result["action"][:, selection] > 0.5  # (policy steps, axes)
            # an axis is in contact when its filtered force at the start of the policy step (what the action
            # was chosen on) is above the threshold, as eval.py's per-axis rates count the sim's contact force
            seen = np.concatenate([np.zeros((1, 3)), result["force"][:-1]])
            touching = np.abs(seen) > stand_in.config.contact_threshold  # (policy steps, 3)
            policy_dt = stand_in.config.control_steps * stand_in.model.opt.timestep
            steps = len(touching) if success_t is None else round(success_t / policy_dt)
            before = (np.arange(len(touching)) < steps)[:, None]
            for where, axes in (("contact", touching), ("free", ~touching),
                                ("before_contact", touching & before), ("before_free", ~touching & before)):
                row[f"force_selected_{where}_per_axis"] = float(force_axes[axes].mean()) if axes.any() else None
                row[f"{where}_axis_steps"] = int(axes.sum())
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
        for key in ("mean_force_n", "before_mean_force_n", "after_mean_force_n", "after_contact_fraction",
                    "force_selected_contact_per_axis", "force_selected_free_per_axis"):
            values = [r[key] for r in out[name]["trials"] if r.get(key) is not None]
            if not values:
                continue
            print(f"{name} {key}: median {np.median(values):.2f} ({min(values):.2f}-{max(values):.2f})")
        for where in ("contact", "free", "before_contact", "before_free"):
            rows = [r for r in out[name]["trials"] if r.get(f"force_selected_{where}_per_axis") is not None]
            if rows:
                steps = sum(r[f"{where}_axis_steps"] for r in rows)
                hits = sum(r[f"force_selected_{where}_per_axis"] * r[f"{where}_axis_steps"] for r in rows)
                print(f"{name} force selected on {where.replace('_', ' ')} axes (pooled): {hits / steps:.3f} "
                      f"of {steps} axis-steps")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
