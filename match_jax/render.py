"""Offscreen pictures of one fPiH episode: an image strip of MuJoCo's C model driven by the MJX trajectory.

    states = record_episode(env, policy, policy_state, key)      # jitted MJX rollout, numpy out
    render_strip(env, states, "episode.png", frames=6)          # PNG: frames + time, phase, force

Rendering needs an OpenGL backend. MuJoCo picks it from the MUJOCO_GL environment variable when
`mujoco` is first imported: on a headless Linux machine set MUJOCO_GL=egl (GPU or Mesa EGL) or
MUJOCO_GL=osmesa before starting Python (eval.py --render sets egl itself on a headless machine
with libEGL). Without
a working backend `render_strip` raises `RenderUnavailable` with that advice instead of crashing.
"""

from __future__ import annotations

import pathlib

import jax
import numpy as np

from match_jax.envs.fpih import PHASE_NAMES
from match_jax.evaluation import make_rollout


class RenderUnavailable(RuntimeError):
    """No OpenGL backend could render offscreen."""


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


def _make_renderer(model, width: int, height: int):
    import mujoco

    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as err:  # backend missing, no display, no EGL/OSMesa library
        raise RenderUnavailable(
            f"offscreen rendering is not available ({type(err).__name__}: {err}); set MUJOCO_GL=egl or "
            "MUJOCO_GL=osmesa before starting Python, with the matching library installed") from None


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
        caption = f"t = {step * env.dt:.2f} s"
        if step > 0:
            i = step - 1
            status = "success" if states["success"][i] > 0 else "BROKEN" if states["broken"][i] > 0 else \
                PHASE_NAMES[int(states["phase"][i])]
            caption += f"\n{status}, |F| {states['max_force'][i]:.1f} N"
        else:
            caption += "\nreset"
        ax.set_title(caption, fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
