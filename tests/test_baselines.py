"""The scripted baselines on the real env (small batch; the 100-episode numbers come from eval.py)."""

import numpy as np
import pytest

from match_jax.training.evaluation import evaluate_baseline


@pytest.fixture(scope="module")
def spiral_summary():
    return evaluate_baseline("spiral", episodes=24, noise_m=0.001, seed=7)


def test_spiral_search_inserts(spiral_summary):
    assert spiral_summary["episodes"] == 24
    assert spiral_summary["success_rate"] >= 0.75, spiral_summary
    assert spiral_summary["break_rate"] <= 0.15, spiral_summary
    assert 0.0 < spiral_summary["mean_time_to_success_s"] <= 10.0
    assert np.isfinite(spiral_summary["mean_force_n"])


@pytest.mark.slow
def test_spiral_search_100_episodes():
    summary = evaluate_baseline("spiral", episodes=100, noise_m=0.001, seed=0)
    assert summary["success_rate"] >= 0.9 and summary["break_rate"] <= 0.02, summary


@pytest.mark.slow
def test_pose_descent_is_worse_at_2p5mm():
    spiral = evaluate_baseline("spiral", episodes=100, noise_m=0.0025, seed=0)
    pose = evaluate_baseline("pose", episodes=100, noise_m=0.0025, seed=0)
    assert pose["success_rate"] < spiral["success_rate"], (pose, spiral)
