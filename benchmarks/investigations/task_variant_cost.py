"""What the authors' task costs against the earlier variant: env and training throughput in one run.

    python benchmarks/investigations/task_variant_cost.py --json results/task_variant_cost.json
    python benchmarks/investigations/task_variant_cost.py --batch 128 --repeats 5 --training-iterations 1

Env variants (jit(vmap(env.step)) at one batch, hybrid controller, in contact-rich states: every env is
first driven onto the block top and pressed there, as benchmarks/step_breakdown.py does):
- earlier: the peg's summed contact force as the force signal, rigid peg, peak break check;
- + wrist sensor: MuJoCo's wrist force/torque sensors (rne_postconstraint every physics step) as the
  force signal, torque observed;
- + peg offset: the per-env model (the peg's pose in the hand drawn per episode, a batched mjx.Model);
- authors: both (the default task).
Training: env steps/s of whole MATCH PPO iterations at the cpu preset's sizes (one seed), earlier vs
authors. All ratios come from the same process, one measurement after the other.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import time

import match_jax  # noqa: F401  (fast XLA CPU flag)

import jax
import jax.numpy as jnp

from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.envs.randomization import ModelRandomization
from match_jax.training.runs import batch_mesh, shard_batch

RIGID = ModelRandomization(peg_offset_range=(0.0, 0.0, 0.0))
VARIANTS = {
    "earlier": dict(force_sensor="peg_contact", observe_torque=False, randomization=RIGID, break_sampling="peak"),
    "+ wrist sensor": dict(randomization=RIGID),
    "+ peg offset": dict(force_sensor="peg_contact", observe_torque=False, break_sampling="peak"),
    "authors": {},
}


def _timed(fn, state, repeats: int) -> float:
    state = fn(fn(state))  # compile, and let weak types settle
    jax.block_until_ready(state)
    start = time.perf_counter()
    for _ in range(repeats):
        state = fn(state)
    jax.block_until_ready(state)
    return (time.perf_counter() - start) / repeats


def env_rate(overrides: dict, batch: int, repeats: int) -> dict:
    """Policy steps/s of the hybrid env pressing down on the block (force control on z at -5 N)."""
    env = FPiHEnv(FPiHConfig(control="hybrid", hole_xy_range=0.0, spawn_noise=(0.0, 0.0, 0.0), **overrides))
    mesh = batch_mesh(batch)
    step = jax.vmap(env.step)
    states = jax.jit(jax.vmap(env.reset))(shard_batch(jax.random.split(jax.random.PRNGKey(0), batch), 0, mesh))
    space, acfg = env.action_space, env.config.actions
    press = env.neutral_action().at[space.selection[2]].set(1.0).at[space.force[2]].set(acfg.force_z_action(-5.0))
    actions = shard_batch(jnp.tile(press, (batch, 1)), 0, mesh)
    settle = jax.jit(lambda s: jax.lax.fori_loop(0, 30, lambda _, x: step(x, actions), s))
    states = settle(states)  # ~2 s of force control: every env on the block top
    contact = float(jnp.mean(states.info["in_contact"]))
    seconds = _timed(jax.jit(lambda s: step(s, actions)), states, repeats)
    return {"batch": batch, "policy_steps_per_s": batch / seconds, "in_contact": contact}


def training_rate(overrides: dict, iterations: int) -> dict:
    """Env steps/s of whole PPO iterations (MATCH, cpu preset sizes, one seed), after compilation."""
    from match_jax.rl.ppo import make_trainer
    from match_jax.training.presets import get_preset

    ppo = get_preset("cpu", method="match", iterations_per_chunk=iterations)
    env = FPiHEnv(dataclasses.replace(FPiHConfig(control="hybrid"), **overrides))
    trainer = make_trainer(ppo, env)
    ts = jax.jit(trainer.init)(jax.random.PRNGKey(0)[None])
    chunk = jax.jit(trainer.train_chunk)
    seconds = _timed(lambda s: chunk(s)[0], ts, 1)
    return {"env_steps_per_s": ppo.steps_per_iteration * iterations / seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=128)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--training-iterations", type=int, default=1, help="PPO iterations per timed chunk; 0: skip")
    parser.add_argument("--json", type=pathlib.Path, default=None)
    args = parser.parse_args()
    rows = {}
    for name, overrides in VARIANTS.items():
        rows[name] = env_rate(overrides, args.batch, args.repeats)
        print(f"env {name:>15}: {rows[name]['policy_steps_per_s']:8.0f} policy steps/s "
              f"({rows[name]['in_contact']:.0%} in contact)", flush=True)
    base = rows["earlier"]["policy_steps_per_s"]
    for row in rows.values():
        row["ratio_to_earlier"] = row["policy_steps_per_s"] / base
    out = {"device": str(jax.devices()[0]), "host_devices": len(jax.devices()), "env": rows}
    if args.training_iterations:
        training = {name: training_rate(VARIANTS[name], args.training_iterations) for name in ("earlier", "authors")}
        training["authors"]["ratio_to_earlier"] = (training["authors"]["env_steps_per_s"]
                                                   / training["earlier"]["env_steps_per_s"])
        for name, row in training.items():
            print(f"training {name:>10}: {row['env_steps_per_s']:8.0f} env steps/s", flush=True)
        out["training"] = training
    print(json.dumps(out, indent=2))
    if args.json:
        args.json.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
