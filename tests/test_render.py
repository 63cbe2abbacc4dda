"""Image strip of one episode: real pixels where an OpenGL backend exists, a clear message where not."""

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from match_jax import render

REPO = pathlib.Path(__file__).resolve().parents[1]


def _states(env, steps=3):
    """A hand-made 'trajectory': the arm at its home posture, the hole at its nominal pose."""
    return {"qpos": np.tile(env.home_qpos, (steps + 1, 1)), "hole_pos": np.array([0.55, 0.0, 0.0]),
            "hole_quat": np.array([1.0, 0.0, 0.0, 0.0]), "phase": np.zeros(steps, np.int32),
            "max_force": np.zeros(steps), "success": np.zeros(steps), "broken": np.zeros(steps),
            "done": np.array([0.0] * (steps - 1) + [1.0])}


def test_episode_length_stops_at_the_end():
    states = {"done": np.array([0, 0, 1, 1, 1], np.float32)}
    assert render.episode_length(states) == 3
    assert render.episode_length({"done": np.zeros(4)}) == 4


def test_render_frames_or_clear_message(env):
    """In this process MuJoCo's GL backend is whatever MUJOCO_GL said at import: either it renders the
    scene (not a blank image), or it raises RenderUnavailable naming MUJOCO_GL."""
    try:
        images = render.render_frames(env, _states(env), [0, 2], width=96, height=96)
    except render.RenderUnavailable as err:
        assert "MUJOCO_GL" in str(err)
        return
    assert len(images) == 2 and images[0].shape == (96, 96, 3)
    assert images[0].std() > 5.0, "a rendered scene is not a uniform image"
    with pytest.raises(ValueError, match="exceeds"):
        render.render_frames(env, _states(env), [0], width=10_000, height=96)


def test_eval_picks_egl_only_when_headless_and_unset(monkeypatch):
    """eval.py's GL choice (the slow test below runs it end to end): EGL on headless Linux with libEGL,
    nothing when a display exists, MUJOCO_GL is set or libEGL is missing."""
    import ctypes.util

    import eval as eval_cli

    def choice(environ, egl):
        for key in ("MUJOCO_GL", "DISPLAY"):
            monkeypatch.delenv(key, raising=False)
        for key, value in environ.items():
            monkeypatch.setenv(key, value)
        monkeypatch.setattr(ctypes.util, "find_library", lambda name: "libEGL.so.1" if egl and name == "EGL" else None)
        eval_cli.choose_gl_backend()
        return os.environ.get("MUJOCO_GL")

    monkeypatch.setattr(sys, "platform", "linux")
    assert choice({}, egl=True) == "egl"
    assert choice({}, egl=False) is None
    assert choice({"DISPLAY": ":0"}, egl=True) is None
    assert choice({"MUJOCO_GL": "osmesa"}, egl=True) == "osmesa"


@pytest.mark.slow
def test_eval_render_writes_a_strip_or_explains(tmp_path):
    """eval.py --render picks EGL on a headless machine that has libEGL: a PNG strip of a real episode;
    without it, a one-line message and exit code 0, never a traceback."""
    out = tmp_path / "strip.png"
    proc = subprocess.run([sys.executable, str(REPO / "eval.py"), "--baseline", "pose", "--episodes", "1",
                           "--render", str(out)], capture_output=True, text=True, cwd=tmp_path,
                          env={k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY")},
                          timeout=900)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    if out.exists():
        import matplotlib.image

        image = matplotlib.image.imread(out)
        assert image.shape[1] > 4 * image.shape[0] / 2, "six frames side by side"
        assert image.std() > 0.02
    else:
        assert "no image strip" in proc.stderr and "MUJOCO_GL" in proc.stderr, proc.stderr[-2000:]


@pytest.mark.slow
def test_record_episode_is_the_evaluation_rollout(env):
    """The strip's episode is the evaluation rollout of the same key: same steps, and its first frame is
    the reset state that rollout started from (make_rollout's key split)."""
    import jax

    from match_jax.evaluation import make_rollout

    def policy(obs, policy_state, key):
        return env.neutral_action(), policy_state

    key = jax.random.PRNGKey(3)
    states = render.record_episode(env, policy, None, key, num_steps=6)
    traj = jax.device_get(make_rollout(env, policy, 6, batched_policy_state=False, record_qpos=True)(key[None], None))
    reset = jax.jit(env.reset)(jax.random.split(key)[0])
    np.testing.assert_allclose(states["qpos"][0], np.asarray(reset.pipeline_state.qpos), atol=1e-6)
    np.testing.assert_allclose(states["qpos"][1:], traj["qpos"][:, 0], atol=1e-6)
    np.testing.assert_array_equal(states["phase"], traj["phase"][:, 0])
    np.testing.assert_allclose(states["max_force"], traj["max_force"][:, 0], atol=1e-5)
    assert states["qpos"].shape == (7, env.mj_model.nq) and states["done"].shape == (6,)
