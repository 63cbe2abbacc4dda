"""Offscreen pictures of one fPiH episode: an image strip or a video of MuJoCo's C model driven by the
MJX trajectory.

    states = record_episode(env, policy, policy_state, key)      # jitted MJX rollout, numpy out
    render_strip(env, states, "episode.png", frames=6)          # PNG: frames + time, phase, force
    render_video(env, states, "episode.gif")                    # every policy step, real time (or .mp4)

Rendering needs an OpenGL backend. MuJoCo picks it from the MUJOCO_GL environment variable when
`mujoco` is first imported: on a headless Linux machine set MUJOCO_GL=egl (GPU or Mesa EGL) or
MUJOCO_GL=osmesa before starting Python (eval.py --render sets egl itself on a headless machine
with libEGL). Without
a working backend `render_strip` and `render_video` raise `RenderUnavailable` with that advice instead
of crashing. GIFs need only Pillow (matplotlib's dependency); mp4 needs imageio and imageio-ffmpeg
(`pip install 'match_jax[video]'`).
"""

from __future__ import annotations

import importlib.util
import pathlib

import jax
import numpy as np

from match_jax.envs.fpih import PHASE_NAMES
from match_jax.evaluation import make_rollout


class RenderUnavailable(RuntimeError):
    """No OpenGL backend could render offscreen."""


VIDEO_PACKAGES = {"gif": ("PIL",), "mp4": ("imageio", "imageio_ffmpeg")}  # importable modules each format needs
VIDEO_INSTALL = {"gif": "pip install pillow", "mp4": "pip install 'match_jax[video]' (imageio, imageio-ffmpeg)"}


class VideoUnavailable(ImportError):
    """The packages that write a video format are not installed (one-line message)."""


def record_episode(env, policy, policy_state, key: jax.Array, num_steps: int | None = None) -> dict[str, np.ndarray]:
    """Run one episode (`evaluation.make_rollout`) and return what a renderer and a caption need, as numpy
    arrays over time.

    Keys: 'qpos' (T+1, nq) joint positions (rad) including the reset state; 'hole_pos' (3,) and
    'hole_quat' (4,) (world, the hole's mocap pose); per step (T,): 'phase', 'max_force' (N),
    'success', 'broken', 'done' (the episode has ended by this step). `policy(obs, policy_state, key) ->
    (action, policy_state)` acts on one env.
    """
    rollout = make_rollout(env, policy, num_steps, batched_policy_state=False, record_qpos=True)

    def episode(key, policy_state):
        traj = jax.tree_util.tree_map(lambda x: x[:, 0], rollout(key[None], policy_state))
        data = env.reset(jax.random.split(key)[0]).pipeline_state  # make_rollout's reset of this key
        hole = env.ids.hole_mocap
        return traj, data.qpos, data.mocap_pos[hole], data.mocap_quat[hole]

    traj, qpos0, hole_pos, hole_quat = jax.device_get(jax.jit(episode)(key, policy_state))
    out = {k: np.asarray(traj[k]) for k in ("phase", "max_force", "success", "broken")}
    out["done"] = np.maximum(np.asarray(traj["done_before"]), np.asarray(traj["done"]))
    out["qpos"] = np.concatenate([np.asarray(qpos0)[None], np.asarray(traj["qpos"])], axis=0)
    out["hole_pos"], out["hole_quat"] = np.asarray(hole_pos), np.asarray(hole_quat)
    return out


def episode_length(states: dict[str, np.ndarray]) -> int:
    """Policy steps until the episode ended (success keeps going; a break or the time limit ends it)."""
    ended = np.nonzero(states["done"] > 0)[0]
    return int(ended[0]) + 1 if len(ended) else len(states["done"])


_FAILED: list[str] = []  # the first failure's message: MuJoCo aborts the process on a second failed try


def _make_renderer(model, width: int, height: int):
    import mujoco

    if _FAILED:
        raise RenderUnavailable(_FAILED[0])
    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as err:  # backend missing, no display, no EGL/OSMesa library
        _FAILED.append(f"offscreen rendering is not available ({type(err).__name__}: {err}); set MUJOCO_GL=egl or "
                       "MUJOCO_GL=osmesa before starting Python, with the matching library installed")
        raise RenderUnavailable(_FAILED[0]) from None


def render_frames(env, states: dict[str, np.ndarray], steps, width: int = 320, height: int = 320,
                  distance: float = 0.22, azimuth: float = 135.0, elevation: float = -20.0) -> list[np.ndarray]:
    """RGB images (height, width, 3) of the C model at the given policy steps (0 = after reset), with a
    free camera looking at the hole top from `distance` meters."""
    import mujoco

    model = env.mj_model
    if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
        raise ValueError(f"frame size {width}x{height} exceeds the model's offscreen buffer "
                         f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}")
    data = mujoco.MjData(model)
    data.mocap_pos[env.ids.hole_mocap] = states["hole_pos"]
    data.mocap_quat[env.ids.hole_mocap] = states["hole_quat"]
    camera = mujoco.MjvCamera()
    camera.lookat[:] = states["hole_pos"] + np.array([0.0, 0.0, env.hole_depth])
    camera.distance, camera.azimuth, camera.elevation = distance, azimuth, elevation
    renderer = _make_renderer(model, width, height)
    images = []
    try:
        for step in steps:
            data.qpos[:] = states["qpos"][step]
            data.qvel[:] = 0.0
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera)
            images.append(renderer.render().copy())
    finally:
        renderer.close()
    return images


def caption(env, states: dict[str, np.ndarray], step: int) -> tuple[str, str]:
    """(time, status) of policy step `step` (0 = after reset): 't = 1.20 s' and 'reset', or the task phase
    (success, BROKEN) with the step's largest contact force."""
    time = f"t = {step * env.dt:.2f} s"
    if step == 0:
        return time, "reset"
    i = step - 1
    status = "success" if states["success"][i] > 0 else "BROKEN" if states["broken"][i] > 0 else \
        PHASE_NAMES[int(states["phase"][i])]
    return time, f"{status}, |F| {states['max_force'][i]:.1f} N"


def missing_video_packages(video_format: str) -> list[str]:
    """The modules `render_video` needs for `video_format` ('gif' or 'mp4') that are not installed."""
    if video_format not in VIDEO_PACKAGES:
        raise ValueError(f"video format must be one of {sorted(VIDEO_PACKAGES)}, got {video_format!r}")
    return [name for name in VIDEO_PACKAGES[video_format] if importlib.util.find_spec(name) is None]


def gif_durations_ms(frames: int, fps: float) -> list[int]:
    """Per-frame delays of a GIF (whole centiseconds) whose running total stays within 5 ms of real time."""
    ends = np.round(100.0 * np.arange(frames + 1) / fps).astype(int)
    return [10 * int(d) for d in np.diff(ends)]


def _with_caption(image: np.ndarray, text: str):
    from PIL import Image, ImageDraw

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    left, top, right, bottom = draw.textbbox((4, 4), text)
    draw.rectangle((left - 2, top - 2, right + 2, bottom + 2), fill=(0, 0, 0))
    draw.text((4, 4), text, fill=(255, 255, 255))
    return picture


def render_video(env, states: dict[str, np.ndarray], path: str | pathlib.Path, fps: float | None = None,
                 width: int = 320, height: int = 320) -> pathlib.Path:
    """Save a video of the episode up to its end: one frame for the reset state and one for the state after
    every policy step, each captioned with time, phase and contact force. `fps` None plays it in real
    time (1 / env.dt, the policy rate). The path's suffix picks the format: .gif (Pillow; at most 50
    fps, GIF delays being whole centiseconds) or .mp4 (H.264 through imageio-ffmpeg)."""
    path = pathlib.Path(path)
    video_format = path.suffix.lower().lstrip(".")
    missing = missing_video_packages(video_format)
    if missing:
        raise VideoUnavailable(f"writing {video_format} needs {', '.join(missing)}: {VIDEO_INSTALL[video_format]}")
    fps = 1.0 / env.dt if fps is None else float(fps)
    if not fps > 0 or (video_format == "gif" and fps > 50):
        raise ValueError(f"fps must be > 0{' and <= 50 for a GIF' if video_format == 'gif' else ''}, got {fps}")
    steps = range(episode_length(states) + 1)
    frames = [_with_caption(image, ", ".join(caption(env, states, step)))
              for step, image in zip(steps, render_frames(env, states, steps, width=width, height=height))]
    path.parent.mkdir(parents=True, exist_ok=True)
    if video_format == "gif":
        frames[0].save(path, save_all=True, append_images=frames[1:], duration=gif_durations_ms(len(frames), fps),
                       loop=0)
    else:
        import imageio.v2 as imageio

        with imageio.get_writer(str(path), format="FFMPEG", mode="I", fps=fps, codec="libx264") as writer:
            for frame in frames:
                writer.append_data(np.asarray(frame))
    return path


def render_strip(env, states: dict[str, np.ndarray], path: str | pathlib.Path, frames: int = 6,
                 title: str = "") -> pathlib.Path:
    """Save a PNG strip of `frames` evenly spaced moments of the episode (up to its end), each captioned
    with the time (s), the task phase and the largest contact force of that step (N)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if frames < 2:
        raise ValueError(f"frames must be >= 2, got {frames}")
    length = episode_length(states)
    steps = np.unique(np.linspace(0, length, frames).round().astype(int))
    images = render_frames(env, states, steps)
    fig, axes = plt.subplots(1, len(steps), figsize=(2.4 * len(steps), 2.9))
    for ax, step, image in zip(np.atleast_1d(axes), steps, images):
        ax.imshow(image)
        ax.set_axis_off()
        ax.set_title("\n".join(caption(env, states, int(step))), fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
