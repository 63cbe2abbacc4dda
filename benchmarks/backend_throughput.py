"""Env steps/s of the two physics backends (MJX's JAX backend, MuJoCo Warp) at several batch sizes, in
contact-rich states: every env pressing on the hole block, as `step_breakdown.py` does.

    python benchmarks/backend_throughput.py --batches 1024,4096,16384 --json results/backend_throughput.json
    python benchmarks/backend_throughput.py --batches 4,8 --steps 2 --press-steps 4     # a quick check on CPU

One process. Per (backend, batch): the hybrid env of the authors' task (in-hand peg offsets, wrist
sensor), `jit(vmap(reset))`, `--press-steps` policy steps pushing down (unbreakable), then a jitted
`lax.scan` of `--steps` vmapped env steps timed after its compiling call (median of `--rounds`).
Reports env (policy) steps/s and the compile seconds of the timed scan. A backend that is not installed
or fails is recorded with its one-line error and skipped; `--deadline-s` skips what would start after it.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import time

import match_jax  # noqa: F401  (fast XLA CPU flag)

import jax
import jax.numpy as jnp
import numpy as np

from match_jax.envs import FPiHConfig, FPiHEnv

BACKENDS = ("jax", "warp")


def measure(backend: str, batch: int, steps: int, press_steps: int, rounds: int) -> dict:
    """Env steps/s of `batch` hybrid envs on `backend` pressing on the block; compile seconds of the scan."""
    env = FPiHEnv(FPiHConfig(control="hybrid", physics_backend=backend, warp_worlds=batch)).with_values(
        break_force=math.inf)
    press = jnp.tile(env.neutral_action().at[env.action_space.position[2]].set(-0.5), (batch, 1))

    def run(states, length):
        return jax.lax.scan(lambda s, _: (jax.vmap(env.step)(s, press), None), states, None, length=length)[0]

    start = time.perf_counter()
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), batch))
    states = jax.block_until_ready(jax.jit(run, static_argnums=1)(states, press_steps))
    setup_s = time.perf_counter() - start
    timed = jax.jit(run, static_argnums=1)
    start = time.perf_counter()
    jax.block_until_ready(timed(states, steps))  # compiles
    compile_s = time.perf_counter() - start
    seconds = []
    for _ in range(rounds):
        start = time.perf_counter()
        jax.block_until_ready(timed(states, steps))
        seconds.append(time.perf_counter() - start)
    median = float(np.median(seconds))
    return {"backend": backend, "batch": batch, "env_steps_per_s": batch * steps / median,
            "seconds_per_scan": median, "compile_s": compile_s, "setup_s": setup_s,
            "contact_fraction": float(jnp.mean(states.info["in_contact"]))}


def row_of(backend: str, batch: int, args, late: bool) -> dict:
    """The printed result row of one measurement: measured, its one-line error, or skipped when late."""
    if late:
        row = {"backend": backend, "batch": batch, "skipped": "deadline"}
        print(f"{backend:5s} {batch:6d} envs: skipped (deadline)", flush=True)
        return row
    try:
        row = measure(backend, batch, args.steps, args.press_steps, args.rounds)
    except Exception as err:  # noqa: BLE001  (recorded, the other measurements go on)
        row = {"backend": backend, "batch": batch, "error": f"{type(err).__name__}: {str(err).splitlines()[0]}"}
        print(f"{backend:5s} {batch:6d} envs: {row['error']}", flush=True)
        return row
    print(f"{backend:5s} {batch:6d} envs: {row['env_steps_per_s']:10.0f} env steps/s "
          f"(compile {row['compile_s']:.0f} s, contact {100 * row['contact_fraction']:.0f} %)", flush=True)
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--backends", default=",".join(BACKENDS))
    parser.add_argument("--batches", default="1024,4096,16384", help="comma-separated env counts")
    parser.add_argument("--steps", type=int, default=20, help="policy steps per timed scan")
    parser.add_argument("--press-steps", type=int, default=40, help="policy steps pressing down before timing")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--deadline-s", type=float, default=math.inf, help="start nothing after this many s")
    parser.add_argument("--json", type=pathlib.Path, default=None)
    args = parser.parse_args(argv)
    backends = [b for b in args.backends.split(",") if b]
    if any(b not in BACKENDS for b in backends):
        parser.error(f"--backends must be from {BACKENDS}, got {args.backends!r}")
    try:
        batches = [int(x) for x in args.batches.split(",") if x]
    except ValueError:
        parser.error(f"--batches must be comma-separated integers, got {args.batches!r}")
    start, rows = time.perf_counter(), []
    for batch in batches:
        for backend in backends:
            row = row_of(backend, batch, args, late=time.perf_counter() - start > args.deadline_s)
            rows.append(row)
            if args.json:
                args.json.write_text(json.dumps({"device": str(jax.devices()[0]), "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
