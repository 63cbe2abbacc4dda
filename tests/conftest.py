"""Shared, session-scoped envs and compiled functions: MJX compiles take 10-50 s on CPU."""

import match_jax  # noqa: F401  (fast XLA CPU flag before JAX starts)

import pathlib
import tempfile

import jax
import jax.numpy as jnp
import pytest

from match_jax.controllers import ControlTarget
from match_jax.envs import FPiHConfig, FPiHEnv

# Identical programs compiled by separate Run objects (train -> resume -> train) come from the cache.
jax.config.update("jax_compilation_cache_dir", str(pathlib.Path(tempfile.gettempdir()) / "match_jax_test_jit_cache"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

# A deterministic placement: hole at its nominal pose, no spawn or observation noise.
QUIET = dict(hole_xy_range=0.0, hole_yaw_range=0.0, spawn_noise=(0.0, 0.0, 0.0), hand_yaw_range=0.0,
             hole_obs_noise=0.0, force_obs_noise=0.0, ee_pos_obs_noise=0.0)


@pytest.fixture(scope="session")
def env():
    return FPiHEnv(FPiHConfig())


@pytest.fixture(scope="session")
def quiet_env():
    return FPiHEnv(FPiHConfig(**QUIET))


@pytest.fixture(scope="session")
def batched(env):
    """jit(vmap(reset)) and jit(vmap(step)) of the default (hybrid) env."""
    return jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))


@pytest.fixture(scope="session")
def press_experiment(quiet_env):
    """Press the peg down onto the hole from lateral offsets, all in one compiled batch.

    For each (offset_x m, f_z N, k_xy): 1.5 s of pose control to 1 mm above the block top at the
    offset, then z force control at f_z while x, y hold the offset with stiffness k_xy, for 3 s in
    total. Returns the peg-tip trajectory (policy rate), the last force reading and the max force
    over the physics steps of each policy step.
    """
    env = quiet_env
    s0 = env.reset(jax.random.PRNGKey(0))
    hole = s0.info["hole_pos"]
    rot = s0.pipeline_state.site_xmat[env.ids.ee_site]
    hover = env.hole_depth + env.peg_tip_below_ee + 0.001

    def run(offset_x, force_z, k_xy):
        def target(position_axes):
            return ControlTarget(pos=hole + jnp.array([offset_x, 0.0, hover]), rot=rot,
                                 force=jnp.array([0.0, 0.0, force_z]), position_axes=position_axes,
                                 pos_stiffness=jnp.array([k_xy, k_xy, 100.0]), posture=s0.info["posture"])

        def body(carry, i):
            d, f = carry
            d, f, max_f, _ = jax.lax.cond(
                i < 12, lambda: env.simulate(d, f, target(jnp.ones(3))),
                lambda: env.simulate(d, f, target(jnp.array([1.0, 1.0, 0.0]))))
            return (d, f), (d.site_xpos[env.ids.peg_tip_site], f, max_f)

        _, out = jax.lax.scan(body, (s0.pipeline_state, jnp.zeros(3)), jnp.arange(45))
        return out

    cases = [(off * 1e-3, -5.0, 1000.0) for off in (0.0, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0)]
    cases += [(0.0, -10.0, 100.0), (8e-3, -10.0, 100.0), (8e-3, -5.0, 100.0)]
    args = [jnp.array(col) for col in zip(*cases)]
    tips, forces, max_forces = jax.jit(jax.vmap(run))(*args)
    return {"cases": cases, "tips": tips - hole, "forces": forces, "max_forces": max_forces,
            "block_top": env.hole_depth}
