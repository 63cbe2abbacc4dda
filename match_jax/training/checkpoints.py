"""Orbax checkpoints of a training run: the latest full TrainState and, per seed, the best policy.

Layout under RUN_DIR/checkpoints/:
- latest/<iteration>/: the whole TrainState of all seeds (params, optimiser, normaliser, env state,
  keys), so `--resume` continues exactly where the run stopped. Only the newest is kept.
- best_seed<i>/<iteration>/: seed i's actor/critic params and normaliser state at its highest
  training success rate so far, with the rate in best_seed<i>/best.json.
Orbax writes each checkpoint to a temporary directory and renames it when complete, so a run killed
mid-save leaves the previous checkpoint intact.
"""

from __future__ import annotations

import json
import logging
import pathlib
import sys

import jax
import numpy as np
import orbax.checkpoint as ocp


class CheckpointError(RuntimeError):
    """A checkpoint directory is missing, empty or unreadable (one-line message)."""


class _ReadOnlyNotices(logging.Filter):
    """Drops orbax's notices that a read-only manager ignores its write options (several per read)."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        return not ("read_only=True" in message or "directory is read only" in message)


logging.getLogger("absl").addFilter(_ReadOnlyNotices())


class _QuietClosedLoop:
    """An unraisable-exception hook that drops the "Event loop is closed" reports of a failed restore and
    passes everything else to the hook it wraps. When orbax's restore of a damaged checkpoint fails, it
    closes its asyncio event loop while other tensorstore reads are still in flight; each of those, on
    completing, tries to wake the closed loop, and Python prints that RuntimeError's traceback (after
    the one-line CheckpointError)."""

    def __init__(self, hook):
        self.hook = hook

    def __call__(self, unraisable) -> None:
        if not _closed_loop_report(unraisable):
            self.hook(unraisable)


def _closed_loop_report(unraisable) -> bool:
    exc = unraisable.exc_value
    if not (isinstance(exc, RuntimeError) and str(exc) == "Event loop is closed" and unraisable.object is None):
        return False
    tb = unraisable.exc_traceback
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb is not None and tb.tb_frame.f_code.co_name == "_check_closed"


def _quiet_closed_loop_reports() -> None:
    """Install `_QuietClosedLoop` over the current sys.unraisablehook (once)."""
    if not isinstance(sys.unraisablehook, _QuietClosedLoop):
        sys.unraisablehook = _QuietClosedLoop(sys.unraisablehook)


def _manager(directory: pathlib.Path, read_only: bool = False) -> ocp.CheckpointManager:
    options = ocp.CheckpointManagerOptions(max_to_keep=1, create=not read_only, read_only=read_only,
                                           enable_async_checkpointing=False)
    return ocp.CheckpointManager(directory.absolute(), options=options)


def _to_saveable(tree) -> dict:
    """The non-empty leaves of `tree` keyed by their flat index (orbax refuses zero-size arrays, and
    mjx.Data has some); the structure comes back from the restore target."""
    leaves = jax.tree_util.tree_leaves(jax.device_get(tree))
    return {f"leaf{i:05d}": np.asarray(leaf) for i, leaf in enumerate(leaves) if np.size(leaf) > 0}


def save(directory: pathlib.Path, step: int, tree) -> None:
    """Save `tree` as checkpoint `step` under `directory`, keeping only the newest."""
    with _manager(directory) as manager:
        manager.save(int(step), args=ocp.args.StandardSave(_to_saveable(tree)), force=True)
        manager.wait_until_finished()


def latest_step(directory: pathlib.Path) -> int | None:
    if not directory.is_dir():
        return None
    with _manager(directory, read_only=True) as manager:
        return manager.latest_step()


def restore(directory: pathlib.Path, target, step: int | None = None):
    """Restore the checkpoint `step` (default: newest) of `directory` into the structure of `target`."""
    step = latest_step(directory) if step is None else step
    if step is None:
        raise CheckpointError(f"no checkpoint found in {directory}")
    leaves, treedef = jax.tree_util.tree_flatten(target)
    abstract = {f"leaf{i:05d}": jax.ShapeDtypeStruct(np.shape(leaf), leaf.dtype)
                for i, leaf in enumerate(leaves) if np.size(leaf) > 0}
    _quiet_closed_loop_reports()  # a damaged checkpoint: one line, not the in-flight reads' tracebacks as well
    try:
        with _manager(directory, read_only=True) as manager:
            saved = manager.restore(step, args=ocp.args.StandardRestore(abstract))
        restored = [saved[f"leaf{i:05d}"] if np.size(leaf) > 0 else np.zeros(np.shape(leaf), leaf.dtype)
                    for i, leaf in enumerate(leaves)]
        return jax.tree_util.tree_unflatten(treedef, [jax.numpy.asarray(x) for x in restored])
    except Exception as err:  # orbax raises many types for damaged files; report one line
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise CheckpointError(f"checkpoint {directory / str(step)} is unreadable ({type(err).__name__}: "
                              f"{first[:300]})") from None


def run_checkpoints_dir(run_dir: pathlib.Path) -> pathlib.Path:
    """The folder holding a run's training checkpoints (latest and best per seed)."""
    return run_dir / "checkpoints"


def best_dir(run_dir: pathlib.Path, seed_index: int) -> pathlib.Path:
    return run_checkpoints_dir(run_dir) / f"best_seed{seed_index}"


def latest_dir(run_dir: pathlib.Path) -> pathlib.Path:
    return run_checkpoints_dir(run_dir) / "latest"


def read_best_record(run_dir: pathlib.Path, seed_index: int) -> dict | None:
    path = best_dir(run_dir, seed_index) / "best.json"
    return json.loads(path.read_text()) if path.exists() else None


def write_best_record(run_dir: pathlib.Path, seed_index: int, record: dict) -> None:
    path = best_dir(run_dir, seed_index) / "best.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(record, indent=2))
    tmp.replace(path)
