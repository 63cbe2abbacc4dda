"""Batched auto-reset with fresh randomness for the fPiH env.

Brax's `AutoResetWrapper` restarts finished envs from the first reset state (same spawn every time);
this wrapper draws a new episode (new hole pose, spawn and noise) for every finished env, and skips
the reset computation entirely on steps where no env finished (`lax.cond` on the whole batch).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from brax.envs.base import State

from match_jax.envs import sim


# Info keys that describe the finished transition (kept for the learner and the metrics); every
# other key is replaced by the fresh episode's value when an env resets.
TRANSITION_KEYS = ("truncation", "broken", "success", "engaged", "in_contact", "max_force", "mean_force")


class AutoResetEnv:
    """Batched env: `reset(keys)` and `step(state, actions)` over a leading batch axis.

    After `step`, `reward`, `done`, `metrics` and the TRANSITION_KEYS of `info` describe the
    transition just taken; for envs whose episode ended, `obs`, `pipeline_state` and the rest of
    `info` already belong to the next episode, and the last observation of the finished one is kept
    in `info['final_obs']`.
    """

    def __init__(self, env):
        self.env = env

    def __getattr__(self, name):
        return getattr(self.env, name)

    def reset(self, keys: jax.Array) -> State:
        state = jax.vmap(self.env.reset)(keys)
        state.info["final_obs"] = state.obs
        return state

    def step(self, state: State, actions: jax.Array) -> State:
        state.info.pop("final_obs", None)
        next_state = jax.vmap(self.env.step)(state, actions)
        final_obs = next_state.obs
        done = next_state.done > 0

        def reset_finished(s: State) -> State:
            keys = jax.vmap(lambda k: jax.random.split(k)[1])(s.info["rng"])
            fresh = jax.vmap(self.env.reset)(keys)

            def pick(new, old):
                mask = done.reshape(done.shape + (1,) * (old.ndim - 1))
                return jnp.where(mask, new, old)

            info = dict(s.info)
            for key in fresh.info:
                if key not in TRANSITION_KEYS:
                    info[key] = jax.tree_util.tree_map(pick, fresh.info[key], s.info[key])  # e.g. info['model']
            # MuJoCo Warp's once-per-batch scratch leaves (no world axis) pass through.
            pipeline_state = jax.tree_util.tree_map(lambda new, old, world: pick(new, old) if world else old,
                                                    fresh.pipeline_state, s.pipeline_state,
                                                    sim.world_axis_leaves(s.pipeline_state))
            return s.replace(pipeline_state=pipeline_state, obs=jax.tree_util.tree_map(pick, fresh.obs, s.obs),
                             info=info)

        next_state = jax.lax.cond(jnp.any(done), reset_finished, lambda s: s, next_state)
        next_state.info["final_obs"] = final_obs
        return next_state
