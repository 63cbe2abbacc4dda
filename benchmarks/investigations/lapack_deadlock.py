"""Does an XLA flag prevent the batched-LAPACK deadlock on CPU? Reproduces it and counts hangs.

    python benchmarks/investigations/lapack_deadlock.py --tries 4                                            # no extra flag
    python benchmarks/investigations/lapack_deadlock.py --tries 4 --xla-flag=--xla_cpu_experimental_ynn_fusion_type=

Each try is a fresh process that initialises 3 seeds of the cpu-preset MATCH trainer with the seeds
vmapped (`jax.lax.map` replaced by `jax.vmap`, as the trainer did before it looped over seeds), which
makes Flax's orthogonal initialisers one batched LAPACK QR. A try counts as hung when the process has
used no CPU time for `--stall-s` seconds before printing 'ready' (a compile or a computation uses CPU;
the deadlock parks every thread); it is then killed. Linux only (reads /proc/PID/stat).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys
import time

REPO = pathlib.Path(__file__).resolve().parents[2]
CHILD = """
import match_jax, jax
jax.lax.map = lambda f, xs, **kw: jax.vmap(f)(xs)
from match_jax.rl.ppo import make_trainer
from match_jax.training.presets import get_preset
from match_jax.training.runs import make_env
ppo = get_preset('cpu', method='match')
trainer = make_trainer(ppo, make_env(ppo))
jax.block_until_ready(jax.jit(trainer.init)(jax.random.split(jax.random.PRNGKey(0), 3)))
print('ready', flush=True)
"""


def cpu_ticks(pid: int) -> int:
    fields = pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])  # utime + stime


def one_try(xla_flag: str, stall_s: float, limit_s: float) -> str:
    env = dict(os.environ, PYTHONPATH=str(REPO), XLA_FLAGS=(os.environ.get("XLA_FLAGS", "") + " " + xla_flag).strip())
    child = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                             text=True, env=env)
    start, last, last_change = time.time(), -1, time.time()
    try:
        while child.poll() is None:
            time.sleep(1.0)
            ticks = cpu_ticks(child.pid)
            if ticks != last:
                last, last_change = ticks, time.time()
            if time.time() - last_change > stall_s:
                return "hung"
            if time.time() - start > limit_s:
                return "slow"
        return "ready" if "ready" in child.stdout.read() else f"exit {child.returncode}"
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tries", type=int, default=4)
    parser.add_argument("--xla-flag", default="", help="added to XLA_FLAGS of every try")
    parser.add_argument("--stall-s", type=float, default=15.0, help="no CPU time for this long: hung")
    parser.add_argument("--limit-s", type=float, default=600.0)
    args = parser.parse_args(argv)
    outcomes = [one_try(args.xla_flag, args.stall_s, args.limit_s) for _ in range(args.tries)]
    print(f"XLA flag {args.xla_flag or '(none)'}: " + ", ".join(outcomes)
          + f"; hung {outcomes.count('hung')} of {len(outcomes)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
