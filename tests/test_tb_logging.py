"""TensorBoard scalars of the metric rows: per seed and their mean, a resume appends without repeating a
step, a missing tensorboardX is a one-line error. The tiny run with train.py --tensorboard is in
test_training.py (it shares that file's compiled programs)."""

import match_jax  # noqa: F401

import sys

import pytest

import train as train_cli
from match_jax.training import tb_logging

pytest.importorskip("tensorboardX")
from tb_events import read_scalars  # noqa: E402


def test_scalars_per_seed_and_mean_leave_out_bookkeeping_and_missing_values():
    rows = [{"seed_index": 0, "seed": 5, "iteration": 1, "env_steps": 32, "wall_clock_s": 3.0,
             "success_rate": 0.5, "break_rate": None, "episodes": 2},
            {"seed_index": 1, "seed": 6, "iteration": 1, "env_steps": 32, "wall_clock_s": 3.0,
             "success_rate": 0.25, "break_rate": 0.1, "episodes": 4}]
    got = {(tag, step): value for tag, value, step in tb_logging.scalars(rows)}
    assert got == {("seed0/success_rate", 32): 0.5, ("seed0/episodes", 32): 2.0,
                   ("seed1/success_rate", 32): 0.25, ("seed1/break_rate", 32): 0.1, ("seed1/episodes", 32): 4.0,
                   ("mean/success_rate", 32): 0.375, ("mean/break_rate", 32): 0.1, ("mean/episodes", 32): 3.0}


def test_a_resumed_session_replaces_the_steps_it_repeats(tmp_path):
    """A run resumed from an older checkpoint logs some steps again: TensorBoard shows each step once,
    with the new session's value."""
    def rows(steps, value):
        return [{"seed_index": 0, "env_steps": s, "success_rate": value} for s in steps]

    first = tb_logging.TensorBoardLogger(tmp_path)
    first(rows([32, 64], 0.1))
    first(rows([96], 0.1))
    first.close()
    second = tb_logging.TensorBoardLogger(tmp_path)
    second(rows([64, 96, 128], 0.7))
    second.close()
    assert read_scalars(tmp_path)["seed0/success_rate"] == pytest.approx({32: 0.1, 64: 0.7, 96: 0.7, 128: 0.7})


def test_tensorboard_without_tensorboardx_is_a_one_line_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "tensorboardX", None)  # import tensorboardX raises ImportError
    argv = ["--method", "match", "--preset", "tiny", "--out", str(tmp_path / "run"), "--tensorboard"]
    assert train_cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "tensorboardX" in err[0] and "match_jax[tensorboard]" in err[0], err
    assert not (tmp_path / "run").exists()  # nothing started
