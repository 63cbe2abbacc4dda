"""Shared, session-scoped envs and compiled functions: MJX compiles take 10-50 s on CPU.

The default run spreads test files over one pytest-xdist worker per core (`-n auto --dist loadfile`
in pyproject.toml); XLA compiles on one thread, so two workers halve the wait on two cores. Files are
handed out heaviest first (HEAVY_FIRST) so that the workers finish together.
"""

import match_jax  # noqa: F401  (fast XLA CPU flag before JAX starts)

import pathlib
import tempfile

import jax
import pytest

from match_jax.envs.controllers import ControllerConfig
from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.envs.probes import press_down
from match_jax.envs.randomization import ModelRandomization

# Identical programs compiled by separate Run objects (train -> resume -> train) come from the cache.
jax.config.update("jax_compilation_cache_dir", str(pathlib.Path(tempfile.gettempdir()) / "match_jax_test_jit_cache"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

# Test files by their cold-cache duration on 2 cores, longest first; the rest follow in name order.
HEAVY_FIRST = ("test_training.py", "test_physics.py", "test_env.py", "test_baselines.py")


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: a file keeps its order


# A deterministic placement: hole at its nominal pose, the peg at its nominal pose in the hand, no spawn
# or observation noise.
QUIET = dict(hole_xy_range=0.0, hole_yaw_range=0.0, spawn_noise=(0.0, 0.0, 0.0), hand_yaw_range=0.0,
             hole_obs_noise=0.0, force_obs_noise=0.0, torque_obs_noise=0.0, ee_pos_obs_noise=0.0,
             randomization=ModelRandomization(peg_offset_range=(0.0, 0.0, 0.0)))


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
def press_experiment():
    """`probes.press_down` from 0-4 mm offsets with x, y held stiffly (3,000 N/m: the geometry alone
    decides), and at 0 / 8 mm with the default 100 N/m, pressing 5 or 10 N for 3 s in total. The damped
    force law holds the commanded force (the authors' literal law settles at a third of it)."""
    env = FPiHEnv(FPiHConfig(controller=ControllerConfig().with_force_law("damped"), **QUIET))
    cases = [(off * 1e-3, -5.0, 3000.0) for off in (0.0, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0)]
    cases += [(0.0, -10.0, 100.0), (8e-3, -10.0, 100.0), (8e-3, -5.0, 100.0)]
    return press_down(env, cases)
