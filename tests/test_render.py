"""Image strip of one episode: real pixels where an OpenGL backend exists, a clear message where not."""

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from match_jax.training import render

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
    """eval.py --render picks EGL on a headless machine that has libEGL: a PNG strip of a real episode and
    a GIF of it beside the strip; without it, a one-line message and exit code 0, never a traceback."""
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
        from PIL import Image

        with Image.open(out.with_suffix(".gif")) as gif:
            assert gif.n_frames > 6, "a frame per policy step"
    else:
        assert "no image strip" in proc.stderr and "MUJOCO_GL" in proc.stderr, proc.stderr[-2000:]


@pytest.mark.slow
def test_record_episode_is_the_evaluation_rollout(env):
    """The strip's episode is the evaluation rollout of the same key: same steps, and its first frame is
    the reset state that rollout started from (make_rollout's key split)."""
    import jax

    from match_jax.training.evaluation import make_rollout

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


def _ending_states(env, steps=6, end=4):
    """`_states` whose episode ends after `end` policy steps (the recording runs on to `steps`)."""
    states = _states(env, steps)
    states["done"] = (np.arange(steps) >= end - 1).astype(np.float32)
    return states


def _uniform_frames(env, states, steps, width=320, height=320, **kwargs):
    return [np.full((height, width, 3), 90, np.uint8) for _ in steps]


def test_gif_has_a_frame_per_policy_step_in_real_time(env, tmp_path, monkeypatch):
    """A GIF of an episode that ends after 4 policy steps: 5 frames (reset + one per step), together one
    policy step each long. The rendered images here are all alike: the captions keep the frames apart."""
    from PIL import Image, ImageSequence

    monkeypatch.setattr(render, "render_frames", _uniform_frames)
    states = _ending_states(env)
    path = render.render_video(env, states, tmp_path / "episode.gif")
    with Image.open(path) as gif:
        durations = [frame.info["duration"] for frame in ImageSequence.Iterator(gif)]
        assert gif.n_frames == render.episode_length(states) + 1 == 5
    assert abs(sum(durations) - 5 * env.dt * 1000) <= 5
    assert render.gif_durations_ms(6, 15.0) == [70, 60, 70, 70, 60, 70]
    with pytest.raises(ValueError, match="<= 50 for a GIF"):
        render.render_video(env, states, tmp_path / "fast.gif", fps=60)


def test_render_video_shows_the_scene_or_clear_message(env, tmp_path):
    """With an OpenGL backend (MUJOCO_GL, as in test_render_frames_or_clear_message) a GIF of real frames."""
    from PIL import Image

    try:
        path = render.render_video(env, _ending_states(env, steps=3, end=2), tmp_path / "episode.gif", width=96,
                                   height=96)
    except render.RenderUnavailable as err:
        assert "MUJOCO_GL" in str(err)
        pytest.skip(f"no OpenGL backend: {err}")
    with Image.open(path) as gif:
        assert gif.n_frames == 3 and gif.size == (96, 96)
        assert np.asarray(gif.convert("RGB"))[48:].std() > 5.0, "a rendered scene is not a uniform image"


def test_mp4_has_a_frame_per_policy_step(env, tmp_path, monkeypatch):
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    monkeypatch.setattr(render, "render_frames", _uniform_frames)
    path = render.render_video(env, _ending_states(env), tmp_path / "episode.mp4")
    with imageio.get_reader(str(path), format="FFMPEG") as reader:
        assert reader.count_frames() == 5
        assert reader.get_meta_data()["fps"] == pytest.approx(1.0 / env.dt, rel=1e-3)


def test_video_format_needs_its_packages_and_render(env, tmp_path, monkeypatch, capsys):
    """A missing writer package is a one-line error naming it and the extra, before any evaluation;
    --video-format needs --render; the video lies beside the strip."""
    import eval as eval_cli

    monkeypatch.setitem(render.VIDEO_PACKAGES, "mp4", ("no_such_module_for_video",))
    assert render.missing_video_packages("mp4") == ["no_such_module_for_video"]
    with pytest.raises(render.VideoUnavailable, match="no_such_module_for_video.*match_jax\\[video\\]"):
        render.render_video(env, _ending_states(env), tmp_path / "episode.mp4")
    monkeypatch.setattr(eval_cli, "choose_gl_backend", lambda: None)
    assert eval_cli.main(["--baseline", "pose", "--render", str(tmp_path / "s.png"), "--video-format", "mp4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no_such_module_for_video" in err[0] and "match_jax[video]" in err[0], err
    with pytest.raises(SystemExit):
        eval_cli.parse_args(["--baseline", "pose", "--video-format", "gif"])
    assert "--video-format needs --render" in capsys.readouterr().err
    assert eval_cli.video_path(pathlib.Path("out/ep.png"), "gif") == pathlib.Path("out/ep.gif")
    assert eval_cli.video_path(pathlib.Path("out/ep.gif"), "gif") == pathlib.Path("out/ep_video.gif")


def test_strip_steps_end_at_the_first_success():
    """Evenly spaced from the reset to the state right after the first successful step; to the episode's end
    when it never succeeds."""
    states = {"success": np.array([0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1], np.float32), "done": np.zeros(12)}
    steps = render.strip_steps(states, 6)
    assert steps[0] == 0 and steps[-1] == 10 and len(steps) == 6
    failed = {"success": np.zeros(12), "done": (np.arange(12) >= 7).astype(np.float32)}
    assert render.strip_steps(failed, 3).tolist() == [0, 4, 8]
    with pytest.raises(ValueError, match="frames"):
        render.strip_steps(failed, 1)


def test_run_title_names_method_and_task_not_the_machines_path(tmp_path):
    """The strip's title of a run: its method, its task and its folder's name, never the absolute path."""
    from match_jax.training.runs import load_spec

    spec = load_spec(REPO / "results" / "suite_authors" / "runs" / "match")
    title = render.run_title(spec, REPO / "results" / "suite_authors" / "runs" / "match", 0, "best")
    assert title == "MATCH, the authors' task: run 'match', seed index 0, best checkpoint"
    assert str(REPO) not in title
    spec = load_spec(REPO / "results" / "suite_authors" / "runs" / "pose_unbreakable")
    assert render.run_title(spec, "runs/pose_unbreakable/", 2, "latest").startswith(
        "Pose, the authors' task, unbreakable peg: run 'pose_unbreakable', seed index 2")


def test_strip_has_a_row_per_view_and_its_title_above_the_captions(env, monkeypatch):
    """Two views: two rows of frames, captions on the first; the title's box lies above every caption's."""
    import matplotlib.pyplot as plt

    monkeypatch.setattr(render, "render_frames", _uniform_frames)
    states = _ending_states(env, steps=12, end=12)
    fig = render.strip_figure(env, states, frames=6, title="MATCH, the authors' task: run 'match'")
    try:
        axes = fig.get_axes()
        assert len(axes) == 2 * 6 and {ax.get_subplotspec().get_geometry()[:2] for ax in axes} == {(2, 6)}
        assert [ax.get_ylabel() for ax in axes[::6]] == ["overview", "close-up from the side,\nhole see-through"]
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        title = fig._suptitle.get_window_extent(renderer)
        assert all(title.y0 >= ax.title.get_window_extent(renderer).y1 for ax in axes[:6])
    finally:
        plt.close(fig)
