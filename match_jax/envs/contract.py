"""What the trainer (`match_jax.rl.ppo`) and the evaluator read from an env, declared once.

An env trainable here is a Brax-style functional env: `reset(key) -> State` and `step(State, action)
-> State`, jit- and vmap-able, one env per call (batch with vmap), no auto-reset (wrap it in
`match_jax.envs.AutoResetEnv`, which adds info['final_obs']). `FPiHEnv` and `PointMassEnv` satisfy it;
`check_env` verifies an env against it from abstract shapes, without compiling.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import jax

# State.obs: a dict of 1-D float arrays.
OBS_KEYS = {
    "state": "the policy's observation (noisy)",
    "privileged_state": "the critic's observation",
}
# State.info: scalars unless a shape is given.
INFO_KEYS = {
    "rng": "the env's own PRNG key",
    "steps": "policy steps taken in this episode (int32)",
    "success": "1.0 on a step whose end state meets the success condition",
    "broken": "1.0 on the step that ended the episode by a break (terminal, no bootstrap)",
    "in_contact": "1.0 if the peg touched something during the step",
    "truncation": "1.0 on the step that ended the episode by its time limit (bootstrapped)",
    "contact_axes": "(3,) per-axis contact label of this state: the selection loss's target",
}


@runtime_checkable
class TrainableEnv(Protocol):
    """The attributes and methods the trainer uses (`config.episode_steps`: steps per episode)."""

    config: Any

    @property
    def action_size(self) -> int: ...

    @property
    def observation_size(self) -> dict[str, tuple[int, ...]]: ...

    def reset(self, rng: jax.Array) -> Any: ...

    def step(self, state: Any, action: jax.Array) -> Any: ...


def check_interface(env) -> None:
    """ValueError unless `env` has the contract's methods, sizes and config.episode_steps (no tracing)."""
    if not isinstance(env, TrainableEnv):
        raise ValueError(f"{type(env).__name__} lacks reset/step/action_size/observation_size/config")
    if not isinstance(getattr(env.config, "episode_steps", None), int):
        raise ValueError(f"{type(env).__name__}.config has no integer episode_steps")


def check_state(state, where: str, batched: bool = True) -> None:
    """ValueError naming the obs / info keys a (possibly abstract or traced) State lacks; `where` names it.
    batched=False: one env's state, whose info['contact_axes'] must be exactly (3,)."""
    missing_obs = sorted(set(OBS_KEYS) - set(state.obs))
    missing_info = sorted(set(INFO_KEYS) - set(state.info))
    if missing_obs or missing_info:
        raise ValueError(f"{where} state lacks obs keys {missing_obs} / info keys {missing_info}")
    shape = state.info["contact_axes"].shape
    if (shape[-1:] if batched else shape) != (3,):
        expected = "(..., 3)" if batched else "(3,)"
        raise ValueError(f"{where}: info['contact_axes'] has shape {shape}, expected {expected}")


def check_env(env) -> None:
    """ValueError naming what `env` lacks of the contract (checked on abstract shapes: nothing compiles).
    The trainer runs the same checks on the states it traces (`ppo.make_trainer`)."""
    check_interface(env)
    key = jax.random.PRNGKey(0)
    state = jax.eval_shape(env.reset, key)
    action = jax.ShapeDtypeStruct((env.action_size,), jax.numpy.float32)
    stepped = jax.eval_shape(env.step, state, action)
    for name, s in (("reset", state), ("step", stepped)):
        check_state(s, f"{type(env).__name__}.{name}", batched=False)
