"""A small pure-JAX control task with the fPiH env's interface, for testing the learner quickly.

A 3-D point mass (1 kg, world frame, meters) must reach a random target and stay there. It takes the
'pose' action space: the three position components are force commands of up to `max_force` N held
over one policy step of `dt` s (the yaw component is ignored). Reward: exp(-distance / 5 cm), plus 1
while within `success_radius`. Observations, info keys and episode bookkeeping match FPiHEnv, so
`match_jax.rl.ppo` trains it unchanged; there is no contact (labels are 0) and nothing breaks.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from brax.envs.base import State

from match_jax.envs.controllers.action_spaces import get_action_space


@dataclasses.dataclass(frozen=True)
class PointMassConfig:
    control: str = "pose"
    episode_steps: int = 50
    dt: float = 0.1  # s per policy step
    max_force: float = 2.0  # N at |a| = 1
    damping: float = 2.0  # N s/m
    start_range: float = 0.2  # m, uniform start and target box half-width
    success_radius: float = 0.02  # m


class PointMassEnv:
    """Point mass reaching a target; Brax-style reset/step over one env."""

    def __init__(self, config: PointMassConfig = PointMassConfig()):
        self.config = config
        self.action_space = get_action_space(config.control)

    @property
    def action_size(self) -> int:
        return self.action_space.size

    @property
    def observation_size(self) -> dict[str, tuple[int, ...]]:
        return {"state": (6,), "privileged_state": (9,)}

    @property
    def dt(self) -> float:
        return self.config.dt

    def _obs(self, pos, vel, target):
        return {"state": jnp.concatenate([pos - target, vel]),
                "privileged_state": jnp.concatenate([pos - target, vel, target])}

    def reset(self, rng: jax.Array) -> State:
        cfg = self.config
        rng, k_pos, k_target = jax.random.split(rng, 3)
        pos = jax.random.uniform(k_pos, (3,), minval=-cfg.start_range, maxval=cfg.start_range)
        target = jax.random.uniform(k_target, (3,), minval=-cfg.start_range, maxval=cfg.start_range)
        vel = jnp.zeros(3)
        zero = jnp.zeros(())
        info = {"rng": rng, "steps": jnp.zeros((), jnp.int32), "target": target, "contact_axes": jnp.zeros(3),
                "success": zero, "broken": zero, "truncation": zero, "in_contact": zero}
        return State(pipeline_state={"pos": pos, "vel": vel}, obs=self._obs(pos, vel, target), reward=zero,
                     done=zero, metrics={"success": zero}, info=info)

    def step(self, state: State, action: jax.Array) -> State:
        cfg = self.config
        force = jnp.clip(action[jnp.asarray(self.action_space.position)], -1.0, 1.0) * cfg.max_force
        pos, vel = state.pipeline_state["pos"], state.pipeline_state["vel"]
        vel = vel + cfg.dt * (force - cfg.damping * vel)
        pos = pos + cfg.dt * vel
        target = state.info["target"]
        dist = jnp.linalg.norm(pos - target)
        success = (dist < cfg.success_radius).astype(jnp.float32)
        steps = state.info["steps"] + 1
        truncation = (steps >= cfg.episode_steps).astype(jnp.float32)
        info = {**state.info, "steps": steps, "success": success, "truncation": truncation}
        return state.replace(pipeline_state={"pos": pos, "vel": vel}, obs=self._obs(pos, vel, target),
                             reward=jnp.exp(-dist / 0.05) + success, done=truncation,
                             metrics={"success": success}, info=info)
