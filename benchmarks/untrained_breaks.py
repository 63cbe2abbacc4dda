"""What the untrained policy does at the start of training: breaks and contact per method and setting.

    python benchmarks/untrained_breaks.py --episodes 64 --json results/untrained_breaks.json

On the earlier task variant (`--task earlier`: rigid peg, the peg's contact force, peak break check, damped
force law) with the cpu preset's networks and the untrained force-z target it had then (-1 N), the
settings the table in docs/training.md was measured with. Each setting builds the untrained actor (seed 0, observation normaliser at its initial
statistics, as in the first training rollout) and runs it stochastically, as training samples it, for
one 150-step episode in each of `--episodes` envs (gaussian 1 mm hole noise, 10 N break). Reported per
setting: the fraction of episodes that broke the peg, that touched the block, the fraction of
axis-steps with force control selected, and the mean policy step of the first contact and of the
break. Settings: Pose; MATCH and Hybrid-Basic with the default damped force law; MATCH with the
literal force law; MATCH with the untrained selection at p(position) 0.99 instead of 0.93; MATCH with
the untrained mean force-z target at 0, -0.5 and -10 N (mid-range, a zero mean action) instead of -1 N.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib

import match_jax  # noqa: F401  (fast XLA CPU flag)

import jax
import numpy as np

from match_jax.envs.tasks import task_config
from match_jax.training.evaluation import make_rollout
from match_jax.rl.ppo import make_trainer
from match_jax.training.runs import make_env
from match_jax.training.presets import get_preset

EARLIER_FORCE_Z = -1.0  # N: the cpu preset's untrained force-z target when this was measured (0 N now)
SETTINGS = {
    "Pose": dict(method="pose"),
    "Hybrid-Basic": dict(method="hybrid"),
    "MATCH": dict(method="match"),
    "MATCH, literal force law": dict(method="match", force_law="literal"),
    "MATCH, initial p(position) 0.99": dict(method="match", initial_p_position=0.99),
    "MATCH, initial force-z 0 N": dict(method="match", initial_force_z=0.0),
    "MATCH, initial force-z -0.5 N": dict(method="match", initial_force_z=-0.5),
    "MATCH, initial force-z -10 N (mean action 0)": dict(method="match", initial_force_z=None),
}
# The force-z start on the authors' task (`--task authors --only ...`): responsive targets, and the authors'
# initial pre-tanh std 1.0.
SETTINGS.update({
    "MATCH, initial force-z -1 N": dict(method="match", initial_force_z=-1.0),
    "MATCH, initial force-z -2 N": dict(method="match", initial_force_z=-2.0),
    "MATCH, initial force-z -5 N": dict(method="match", initial_force_z=-5.0),
    "MATCH, initial force-z -2 N, std 1.0": dict(method="match", initial_force_z=-2.0, initial_log_std=0.0),
    "MATCH, initial force-z -10 N, std 1.0": dict(method="match", initial_force_z=None, initial_log_std=0.0),
    "Pose, std 1.0": dict(method="pose", initial_log_std=0.0),
})


def untrained_episodes(method: str, episodes: int, force_law: str | None = None, task: str = "earlier",
                       **network) -> dict:
    """Break and contact statistics of one setting's untrained, stochastic policy (see the module docstring);
    `network` replaces fields of the preset's NetworkConfig (e.g. initial_p_position=0.99)."""
    ppo = get_preset("cpu", method=method)
    network = {"initial_force_z": EARLIER_FORCE_Z if task == "earlier" else ppo.network.initial_force_z, **network}
    ppo = dataclasses.replace(ppo, network=dataclasses.replace(ppo.network, **network))
    env = make_env(ppo, task_config(task, ppo.control, force_law))
    trainer = make_trainer(ppo, env)
    state = jax.jit(trainer.init)(jax.random.split(jax.random.PRNGKey(0), 1))
    params, stats = jax.tree_util.tree_map(lambda x: x[0], (state.params, state.policy_stats))
    dist = trainer.distribution

    def policy(obs, policy_state, key):
        return dist.to_action(dist.sample(key, trainer.policy_head(params, stats, obs["state"]))), policy_state

    rollout = jax.jit(make_rollout(env, policy, batched_policy_state=False))
    traj = jax.device_get(rollout(jax.random.split(jax.random.PRNGKey(1), episodes), None))
    alive = 1.0 - np.asarray(traj["done_before"])
    broken = np.asarray(traj["broken"]) * alive
    contact = np.asarray(traj["in_contact"]) * alive
    force_axes = (1.0 - np.asarray(traj["position_axes"])) * alive[..., None]
    broke, touched = broken.max(0) > 0, contact.max(0) > 0

    def first_step(mask, which):
        return float(np.argmax(mask > 0, axis=0)[which].mean()) if which.any() else float("nan")

    return {"breaks": float(broke.mean()), "contact_episodes": float(touched.mean()),
            "force_selected": float(force_axes.sum() / (3 * alive.sum())),
            "first_contact_step": first_step(contact, touched), "break_step": first_step(broken, broke),
            "breaks_at_first_contact": float((np.argmax(broken > 0, 0) == np.argmax(contact > 0, 0))[broke].mean())
            if broke.any() else float("nan")}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=64, help="episodes per setting (default 64)")
    parser.add_argument("--json", type=pathlib.Path, default=None, help="also write the numbers here")
    parser.add_argument("--only", nargs="+", metavar="SETTING", choices=list(SETTINGS), default=list(SETTINGS),
                        help="run only these settings (default: all)")
    parser.add_argument("--task", choices=["earlier", "authors"], default="earlier",
                        help="task protocol (default: earlier, what the committed table was measured on)")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be a positive integer, got {args.episodes}")
    rows = {}
    print("| setting | episodes broken % | episodes touching the block % | force-selected axis-steps % "
          "| mean step of first contact | mean step of the break | breaks on the first contact step % |")
    print("|---|---|---|---|---|---|---|")
    for label in args.only:
        r = rows[label] = untrained_episodes(episodes=args.episodes, task=args.task, **SETTINGS[label])
        print(f"| {label} | {100 * r['breaks']:.0f} | {100 * r['contact_episodes']:.0f} | {100 * r['force_selected']:.1f} "
              f"| {r['first_contact_step']:.0f} | {r['break_step']:.0f} | {100 * r['breaks_at_first_contact']:.0f} |",
              flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"episodes": args.episodes, "task": args.task, "settings": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
