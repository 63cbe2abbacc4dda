"""TensorBoard scalars of a run's metric rows (optional: needs tensorboardX, `pip install 'match_jax[tensorboard]'`).

    logger = TensorBoardLogger("runs/match/tensorboard")
    train(spec, "runs/match", on_rows=logger)      # each chunk's rows, as written to metrics.jsonl
    logger.close()

Tags: `seed<i>/<metric>` for seed index i and `mean/<metric>` (the mean over the seeds that logged a
value), step = env steps per seed. A resumed run appends a new event file to the same directory; its
first step is the writer's purge step, so TensorBoard hides what an earlier session logged from there
on (the chunks after the checkpoint the run resumed from) and shows each step once.
"""

from __future__ import annotations

import math
import pathlib
import time

NOT_SCALARS = ("seed_index", "seed", "iteration", "env_steps", "wall_clock_s")  # row keys that are not metrics


class TensorBoardUnavailable(ImportError):
    """tensorboardX is not installed (one-line message naming the package and the extra)."""


def summary_writer_class():
    """tensorboardX.SummaryWriter, or TensorBoardUnavailable."""
    try:
        from tensorboardX import SummaryWriter
    except ImportError:
        raise TensorBoardUnavailable("TensorBoard logging needs the tensorboardX package: "
                                     "pip install 'match_jax[tensorboard]' (or tensorboardX)") from None
    return SummaryWriter


def scalars(rows: list[dict]) -> list[tuple[str, float, int]]:
    """(tag, value, step) of every numeric metric of `rows` per seed, and of its mean over seeds per step."""
    out, by_step = [], {}
    for row in rows:
        step = int(row["env_steps"])
        for key, value in row.items():
            if key in NOT_SCALARS or isinstance(value, bool) or not isinstance(value, (int, float)):
                continue
            if not math.isfinite(value):
                continue
            out.append((f"seed{row['seed_index']}/{key}", float(value), step))
            by_step.setdefault(step, {}).setdefault(key, []).append(float(value))
    for step, metrics in by_step.items():
        out.extend((f"mean/{key}", sum(values) / len(values), step) for key, values in metrics.items())
    return out


class TensorBoardLogger:
    """A `train(on_rows=...)` hook that writes each chunk's metric rows to an event file in `log_dir`."""

    def __init__(self, log_dir: str | pathlib.Path):
        self.log_dir = pathlib.Path(log_dir)
        self._writer_class = summary_writer_class()
        self._writer = None

    def __call__(self, rows: list[dict]) -> None:
        if not rows:
            return
        if self._writer is None:  # opened at the first rows: their step is where this session takes over
            self.log_dir.mkdir(parents=True, exist_ok=True)
            # file names start with the second; the suffix keeps two sessions of one second apart and in order
            self._writer = self._writer_class(str(self.log_dir), purge_step=min(int(r["env_steps"]) for r in rows),
                                              filename_suffix=f".{time.time_ns()}")
        for tag, value, step in scalars(rows):
            self._writer.add_scalar(tag, value, step)
        self._writer.flush()

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
