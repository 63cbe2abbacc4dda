"""Throughput of the fPiH env on this machine, with bare MJX and MuJoCo C on the same model as references.

    python benchmarks/throughput.py                     # batch sizes 1, 16, 64, 256
    python benchmarks/throughput.py --batch-sizes 256 --repeats 5 --json results/throughput.json

Measured in one run, so the ratios are meaningful on a noisy machine:
- env: jit(vmap(env.step)) policy steps/s (8 control substeps each: control law, contact force,
  break check, observations, reward), and the physics steps/s that represents;
- bare mjx.step: physics steps/s at the same batch on the same model and states, with the torques
  held at gravity compensation (the arm hovers over the hole as at the start of an episode);
- MuJoCo C: physics steps/s of `mujoco.rollout` over the same initial states and torques, using
  all cores (one thread per core).

    python benchmarks/throughput.py --training cpu,paper --method match

measures training throughput instead: env steps/s of whole PPO iterations (rollout + GAE + update
epochs, one jitted chunk) at each preset's sizes, after compilation, and in the same run the env
alone (jit(vmap(step)) with auto-reset) at the same batch, so the ratio shows what learning costs.

The env batch is split over JAX's CPU devices as train.py splits it (`import match_jax` makes one
per core; `runs.batch_mesh`), in both modes, for the env and for bare mjx.step alike.

    python benchmarks/throughput.py --training cpu --method match --host-devices 1,2

runs the measurement once per CPU device count (each in a fresh process with JAX_NUM_CPU_DEVICES
set, since JAX fixes it at start-up) and writes all rows, tagged `host_devices`, to one JSON.

    python benchmarks/throughput.py --training cpu --method match --seeds 3 --minibatches 8,150

measures each preset once per minibatch count (the update's epochs split into that many gradient steps).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import match_jax  # noqa: F401  (fast XLA CPU flag)

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout

from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.envs.sim import mjx
from match_jax.training.runs import batch_mesh, shard_batch


def _timed(fn, state, repeats):
    state = fn(state)  # compile
    state = fn(state)  # and a second call: weak types settle after the first
    jax.block_until_ready(state)
    start = time.perf_counter()
    for _ in range(repeats):
        state = fn(state)
    jax.block_until_ready(state)
    return (time.perf_counter() - start) / repeats


def benchmark(batch_sizes, repeats: int, control: str = "hybrid") -> dict:
    env = FPiHEnv(FPiHConfig(control=control))
    substeps = env.config.control_substeps * env.config.physics_substeps
    reset, step = jax.jit(jax.vmap(env.reset)), jax.vmap(env.step)
    action = env.neutral_action()
    m = env.mjx_model
    results = {"control": control, "device": str(jax.devices()[0]), "physics_steps_per_policy_step": substeps,
               "cpu_count": os.cpu_count(), "host_devices": len(jax.devices()), "rows": []}

    for batch in batch_sizes:
        mesh = batch_mesh(batch)
        states = reset(shard_batch(jax.random.split(jax.random.PRNGKey(0), batch), 0, mesh))
        actions = shard_batch(jnp.tile(action, (batch, 1)), 0, mesh)
        env_fn = jax.jit(lambda s: step(s, actions))
        env_dt = _timed(env_fn, states, repeats)

        # bare mjx.step: same model, same start states, gravity-compensation torques held
        data = jax.jit(jax.vmap(lambda d: d.replace(ctrl=mjx.fwd_velocity(m, mjx.fwd_position(m, d)).qfrc_bias)))(
            states.pipeline_state)
        bare_fn = jax.jit(jax.vmap(lambda d: jax.lax.fori_loop(0, substeps, lambda i, d: mjx.step(m, d), d)))
        bare_dt = _timed(bare_fn, data, repeats)

        # MuJoCo C on the same states and torques
        model = env.mj_model
        c_data = [mujoco.MjData(model) for _ in range(os.cpu_count() or 1)]
        host = jax.device_get(data)
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        init = np.empty((batch, mujoco.mj_stateSize(model, spec)))
        for i in range(batch):
            c_data[0].qpos[:], c_data[0].qvel[:] = host.qpos[i], host.qvel[i]
            c_data[0].mocap_pos[:], c_data[0].mocap_quat[:] = host.mocap_pos[i], host.mocap_quat[i]
            mujoco.mj_getState(model, c_data[0], init[i], spec)
        controls = np.repeat(np.asarray(host.ctrl)[:, None, :], substeps * repeats, axis=1)
        rollout.rollout(model, c_data, init, controls[:, :substeps])  # warm-up
        start = time.perf_counter()
        rollout.rollout(model, c_data, init, controls)
        c_dt = (time.perf_counter() - start) / repeats

        row = {
            "batch": batch,
            "devices_used": 1 if mesh is None else mesh.size,
            "env_policy_steps_per_s": batch / env_dt,
            "env_physics_steps_per_s": batch * substeps / env_dt,
            "bare_mjx_physics_steps_per_s": batch * substeps / bare_dt,
            "mujoco_c_physics_steps_per_s": batch * substeps / c_dt,
        }
        row["env_vs_bare_mjx"] = row["env_physics_steps_per_s"] / row["bare_mjx_physics_steps_per_s"]
        row["env_vs_mujoco_c"] = row["env_physics_steps_per_s"] / row["mujoco_c_physics_steps_per_s"]
        results["rows"].append(row)
        print(f"batch {batch:4d}: env {row['env_policy_steps_per_s']:9.0f} policy steps/s "
              f"({row['env_physics_steps_per_s']:9.0f} physics/s) | bare mjx.step "
              f"{row['bare_mjx_physics_steps_per_s']:9.0f}/s | MuJoCo C {row['mujoco_c_physics_steps_per_s']:9.0f}/s "
              f"| env/bare {row['env_vs_bare_mjx']:.2f}, env/C {row['env_vs_mujoco_c']:.3f}", flush=True)
    return results


def benchmark_training(presets, method: str, chunks: int, seeds: int = 1, minibatches=(None,)) -> dict:
    """Training env steps/s (all `seeds` together) at each preset and minibatch count (None: the preset's),
    and the bare env at the same total batch."""
    from match_jax.envs import AutoResetEnv
    from match_jax.training.presets import get_preset
    from match_jax.training.runs import Run, RunSpec, shard_envs

    results = {"method": method, "device": str(jax.devices()[0]), "cpu_count": os.cpu_count(),
               "host_devices": len(jax.devices()), "seeds": seeds, "rows": []}
    for name, count in [(p, m) for p in presets for m in minibatches]:
        overrides = {} if count is None else {"minibatches": count}
        ppo = get_preset(name, method=method, iterations_per_chunk=1, **overrides)
        run = Run(RunSpec(ppo=ppo, num_seeds=seeds), "/tmp/unused-benchmark-run")
        state = shard_envs(run.initial_state())
        start = time.perf_counter()
        state, _ = run.chunk(state)
        jax.block_until_ready(state)
        compile_s = time.perf_counter() - start
        start = time.perf_counter()
        for _ in range(chunks):
            state, _ = run.chunk(state)
        jax.block_until_ready(state)
        train_rate = chunks * seeds * ppo.steps_per_iteration / (time.perf_counter() - start)

        benv = AutoResetEnv(run.env)
        batch = seeds * ppo.num_envs
        mesh = batch_mesh(batch)
        states = jax.jit(benv.reset)(shard_batch(jax.random.split(jax.random.PRNGKey(0), batch), 0, mesh))
        actions = shard_batch(jnp.tile(run.env.neutral_action(), (batch, 1)), 0, mesh)
        env_fn = jax.jit(lambda s: jax.lax.scan(lambda c, _: (benv.step(c, actions), None), s, None, length=10)[0])
        env_rate = 10 * batch / _timed(env_fn, states, 3)
        row = {"preset": name, "minibatches": ppo.minibatches, "epochs": ppo.epochs, "num_envs": ppo.num_envs,
               "seeds": seeds, "steps_per_iteration": ppo.steps_per_iteration,
               "first_chunk_s_incl_compile": compile_s, "train_env_steps_per_s": train_rate,
               "env_only_steps_per_s": env_rate, "train_vs_env": train_rate / env_rate}
        results["rows"].append(row)
        print(f"{name:6s} preset ({seeds} x {ppo.num_envs} envs, {method}, {ppo.minibatches} minibatches x "
              f"{ppo.epochs} epochs): training {train_rate:8.0f} env steps/s | env alone "
              f"{env_rate:8.0f} steps/s | ratio {row['train_vs_env']:.2f} | first chunk incl. compile {compile_s:.0f} s",
              flush=True)
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch-sizes", default="1,16,64,256", help="comma-separated env counts")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per measurement")
    parser.add_argument("--control", default="hybrid", choices=["pose", "vices", "hybrid"])
    parser.add_argument("--json", type=pathlib.Path, default=None)
    parser.add_argument("--training", default=None, help="comma-separated presets: measure training throughput")
    parser.add_argument("--method", default="match", choices=["pose", "vices", "hybrid", "match"])
    parser.add_argument("--chunks", type=int, default=2, help="timed PPO iterations per preset (--training)")
    parser.add_argument("--seeds", type=int, default=1, help="seeds trained in one program (--training)")
    parser.add_argument("--minibatches", default=None,
                        help="comma-separated minibatch counts per epoch (--training; default: the preset's)")
    parser.add_argument("--host-devices", default=None,
                        help="comma-separated CPU device counts: rerun the measurement in a fresh process per count")
    args = parser.parse_args()
    if args.host_devices:
        compare_host_devices(parser, args)
        return
    if args.training:
        from match_jax.training.presets import PRESETS
        presets = [p for p in args.training.split(",") if p]
        unknown = [p for p in presets if p not in PRESETS]
        if unknown or args.chunks < 1 or args.seeds < 1:
            parser.error(f"--training takes presets from {sorted(PRESETS)}, --chunks >= 1 and --seeds >= 1, got "
                         f"{args.training!r}, {args.chunks}, {args.seeds}")
        try:
            counts = [int(m) for m in args.minibatches.split(",") if m] if args.minibatches else [None]
        except ValueError:
            parser.error(f"--minibatches must be comma-separated integers, got {args.minibatches!r}")
        if any(m is not None and m < 1 for m in counts) or not counts:
            parser.error(f"--minibatches must be integers >= 1, got {args.minibatches!r}")
        results = benchmark_training(presets, args.method, args.chunks, args.seeds, counts)
        _write_json(args.json, results)
        return
    try:
        sizes = [int(b) for b in args.batch_sizes.split(",")]
    except ValueError:
        parser.error(f"--batch-sizes must be comma-separated integers, got {args.batch_sizes!r}")
    if any(b < 1 for b in sizes) or args.repeats < 1:
        parser.error(f"batch sizes and --repeats must be >= 1, got {sizes} and {args.repeats}")
    results = benchmark(sizes, args.repeats, args.control)
    _write_json(args.json, results)


def compare_host_devices(parser, args) -> None:
    """Rerun this script once per CPU device count (JAX_NUM_CPU_DEVICES) and merge the rows."""
    try:
        counts = [int(c) for c in args.host_devices.split(",") if c]
    except ValueError:
        counts = []
    if not counts or any(c < 1 for c in counts):
        parser.error(f"--host-devices must be comma-separated integers >= 1, got {args.host_devices!r}")
    argv = _without_options(sys.argv[1:], ("--host-devices", "--json"))
    rows, part = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for count in counts:
            out = pathlib.Path(tmp) / f"{count}.json"
            env = dict(os.environ, JAX_NUM_CPU_DEVICES=str(count))
            print(f"--- {count} CPU device(s)", flush=True)
            subprocess.run([sys.executable, __file__, *argv, "--json", str(out)], env=env, check=True)
            part = json.loads(out.read_text())
            rows += [{"host_devices": part["host_devices"], **row} for row in part["rows"]]
    _write_json(args.json, {**part, "host_devices": counts, "rows": rows})


def _without_options(argv: list[str], names) -> list[str]:
    """`argv` without the options `names` and their values (`--name value` or `--name=value`)."""
    kept, skip = [], False
    for arg in argv:
        if skip:
            skip = False
        elif arg in names:
            skip = True
        elif not arg.startswith(tuple(f"{name}=" for name in names)):
            kept.append(arg)
    return kept


def _write_json(path: pathlib.Path | None, results: dict) -> None:
    if path:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(results, indent=2))
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
