"""Offscreen pictures of one fPiH episode: an image strip or a video of MuJoCo's C model driven by the
MJX trajectory.

    states = record_episode(env, policy, policy_state, key)      # jitted MJX rollout, numpy out
    render_strip(env, states, "episode.png", frames=6)          # PNG: two views x frames + time, phase, force
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
import math
import pathlib

import jax
import numpy as np

from match_jax.envs.fpih import PHASE_NAMES
from match_jax.training.evaluation import make_rollout


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


# The strip's views, each a free camera aimed at a point above the hole top (world offset, m). The close-up
# looks almost horizontally at the hole top from the side, below the hand, so the hand never hides the peg
# tip, and draws the hole see-through so the inserted part of the peg stays in sight; the overview shows the
# hand and peg above the hole from higher up, as the earlier default did.
CLOSE_UP = {"distance": 0.13, "azimuth": 135.0, "elevation": -4.0, "lookat_offset": (0.0, 0.0, 0.012),
            "hole_alpha": 0.3}
OVERVIEW = {"distance": 0.3, "azimuth": 150.0, "elevation": -15.0, "lookat_offset": (0.0, 0.0, 0.03),
            "hole_alpha": 1.0}
VIEWS = {"overview": OVERVIEW, "close-up from the side, hole see-through": CLOSE_UP}


def render_frames(env, states: dict[str, np.ndarray], steps, width: int = 320, height: int = 320,
                  distance: float = CLOSE_UP["distance"], azimuth: float = CLOSE_UP["azimuth"],
                  elevation: float = CLOSE_UP["elevation"], lookat_offset=CLOSE_UP["lookat_offset"],
                  hole_alpha: float = CLOSE_UP["hole_alpha"]) -> list[np.ndarray]:
    """RGB images (height, width, 3) of the C model at the given policy steps (0 = after reset), with a
    free camera `distance` meters from the hole top plus `lookat_offset` (world, m), at `azimuth` and
    `elevation` (degrees). The default is the close-up (`CLOSE_UP`): a low side view of the hole top.
    `hole_alpha` < 1 draws the hole's walls translucent and its bore (the thin capsules lining it) nearly
    invisible, so a peg inside the hole shows through; the model's colors are restored afterwards."""
    import mujoco

    model = env.mj_model
    if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
        raise ValueError(f"frame size {width}x{height} exceeds the model's offscreen buffer "
                         f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}")
    if not 0.0 <= hole_alpha <= 1.0:
        raise ValueError(f"hole_alpha must be in [0, 1], got {hole_alpha}")
    data = mujoco.MjData(model)
    data.mocap_pos[env.ids.hole_mocap] = states["hole_pos"]
    data.mocap_quat[env.ids.hole_mocap] = states["hole_quat"]
    camera = mujoco.MjvCamera()
    camera.lookat[:] = states["hole_pos"] + np.array([0.0, 0.0, env.hole_depth]) + np.asarray(lookat_offset)
    camera.distance, camera.azimuth, camera.elevation = distance, azimuth, elevation
    rgba = model.geom_rgba.copy()
    hole = model.geom_bodyid == model.body_mocapid.tolist().index(env.ids.hole_mocap)
    bore = np.array([(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, i) or "").startswith("bore")
                     for i in range(model.ngeom)])
    renderer = _make_renderer(model, width, height)
    images = []
    try:
        if hole_alpha < 1.0:
            model.geom_rgba[hole & ~bore, 3] = hole_alpha
            model.geom_rgba[hole & bore, 3] = 0.2 * hole_alpha
        for step in steps:
            data.qpos[:] = states["qpos"][step]
            data.qvel[:] = 0.0
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera)
            images.append(renderer.render().copy())
    finally:
        model.geom_rgba[:] = rgba
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


def strip_steps(states: dict[str, np.ndarray], frames: int) -> np.ndarray:
    """The policy steps a strip shows: `frames` evenly spaced from the reset (0) to the first success, or to
    the episode's end (`episode_length`) when it never succeeds (duplicates dropped)."""
    if frames < 2:
        raise ValueError(f"frames must be >= 2, got {frames}")
    succeeded = np.nonzero(np.asarray(states["success"]) > 0)[0]
    end = int(succeeded[0]) + 1 if len(succeeded) else episode_length(states)
    return np.unique(np.linspace(0, end, frames).round().astype(int))


def run_title(spec, run_dir: str | pathlib.Path, seed_index: int, checkpoint: str) -> str:
    """A strip's title for a training run: method, task and the run's folder name (no machine's path), e.g.
    "MATCH, the authors' task: run 'match', seed index 0, best checkpoint"."""
    from match_jax.envs.tasks import TASKS, task_config

    labels = {"pose": "Pose", "vices": "VICES", "hybrid": "Hybrid-Basic", "match": "MATCH"}
    names = {"authors": "the authors' task", "earlier": "the earlier task variant",
             "authors_dr": "the authors' randomised task"}
    keys = {key for task in TASKS.values() for key in task["settings"]}
    env = spec.env
    task = next((name for name in ("earlier", "authors_dr", "authors")  # 'authors' sets nothing: the last to try
                 if env is not None and all(getattr(env, k) == getattr(task_config(name, env.control), k)
                                            for k in keys)), None)
    where = names.get(task, "a custom task") + ("" if env is None or math.isfinite(env.break_force)
                                                else ", unbreakable peg")
    return (f"{labels.get(spec.ppo.method, spec.ppo.method)}, {where}: run '{pathlib.Path(run_dir).resolve().name}', "
            f"seed index {seed_index}, {checkpoint} checkpoint")


def strip_figure(env, states: dict[str, np.ndarray], frames: int = 6, title: str = "",
                 views: dict[str, dict] | None = None):
    """The matplotlib figure of `render_strip` (open; the caller saves and closes it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    views = VIEWS if views is None else views
    steps = strip_steps(states, frames)
    rows = [render_frames(env, states, steps, **camera) for camera in views.values()]
    top = 0.3 if title else 0.0  # inches above the frames' captions for the title
    fig, axes = plt.subplots(len(rows), len(steps), figsize=(2.4 * len(steps), 2.5 * len(rows) + 0.35 + top),
                             squeeze=False)
    for r, (label, images) in enumerate(zip(views, rows)):
        for c, (step, image) in enumerate(zip(steps, images)):
            ax = axes[r, c]
            ax.imshow(image)
            ax.set_xticks([])
            ax.set_yticks([])
            for spine in ax.spines.values():
                spine.set_visible(False)
            if r == 0:
                ax.set_title("\n".join(caption(env, states, int(step))), fontsize=9)
        axes[r, 0].set_ylabel(label if len(label) < 20 else label.replace(", ", ",\n"), fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - top / fig.get_figheight()), h_pad=0.3, w_pad=0.3)
    return fig


def render_strip(env, states: dict[str, np.ndarray], path: str | pathlib.Path, frames: int = 6,
                 title: str = "", views: dict[str, dict] | None = None) -> pathlib.Path:
    """Save a PNG strip of `frames` evenly spaced moments of the episode (`strip_steps`: up to its first
    success, else its end), one row per view (`views`: row label -> `render_frames` camera keywords;
    default `VIEWS`, an overview and a low close-up of the hole), each frame captioned with the time (s),
    the task phase and the largest contact force of that step (N); `title` above the captions."""
    import matplotlib.pyplot as plt

    fig = strip_figure(env, states, frames, title, views)
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
