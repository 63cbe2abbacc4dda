"""The fPiH env: jit/vmap, fixed shapes, no NaN, auto-reset, break, configuration errors."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from match_jax.envs import AutoResetEnv, FPiHConfig, FPiHEnv
from match_jax.envs.point_mass import PointMassConfig, PointMassEnv

from conftest import QUIET


def _random_actions(key, batch, env):
    space = env.action_space
    actions = jax.random.uniform(key, (batch, space.size), minval=-1.0, maxval=1.0)
    if space.selection:  # Bernoulli selections, mostly position control as an initial policy would
        sel = jax.random.bernoulli(key, 0.1, (batch, len(space.selection))).astype(jnp.float32)
        actions = actions.at[:, jnp.asarray(space.selection)].set(sel)
    return actions


def _signature(tree):
    return jax.tree_util.tree_map(lambda x: (x.shape, x.dtype), tree)


# batch 64 is the program the tests below reuse; batch 1 compiles its own (~90 s): with -m slow
@pytest.mark.parametrize("batch", [pytest.param(1, marks=pytest.mark.slow), 64])
def test_jit_vmap_shapes_and_dtypes_are_fixed(env, batched, batch):
    reset, step = batched
    state = reset(jax.random.split(jax.random.PRNGKey(1), batch))
    nxt = step(state, _random_actions(jax.random.PRNGKey(2), batch, env))
    assert _signature(nxt) == _signature(state)
    assert nxt.obs["state"].shape == (batch, env.observation_size["state"][0])
    assert nxt.obs["privileged_state"].shape == (batch, env.observation_size["privileged_state"][0])
    assert nxt.reward.shape == (batch,) and nxt.done.shape == (batch,)


def test_full_episodes_with_random_actions_have_no_nan(env, batched):
    reset, step = batched
    batch = 64
    state = reset(jax.random.split(jax.random.PRNGKey(3), batch))
    ended = np.zeros(batch, bool)
    for t in range(env.config.episode_steps):
        state = step(state, _random_actions(jax.random.PRNGKey(100 + t), batch, env))
        for leaf in jax.tree_util.tree_leaves((state.obs, state.reward, state.pipeline_state.qpos)):
            assert np.all(np.isfinite(np.asarray(leaf))), f"non-finite value at step {t}"
        ended |= np.asarray(state.done) > 0
    assert ended.all(), "every episode ends by break or time-out within episode_steps"
    assert np.asarray(state.info["steps"]).max() <= env.config.episode_steps
    holes = np.asarray(reset(jax.random.split(jax.random.PRNGKey(3), batch)).info["hole_pos"])
    assert np.unique(holes[:, 0]).size == batch, "every episode draws its own hole position"
    # the last step is the time-out of every env: done, and a truncation unless that step broke the peg
    assert np.all(np.asarray(state.done) == 1)
    np.testing.assert_array_equal(np.asarray(state.info["truncation"]), 1.0 - np.asarray(state.info["broken"]))


def test_hole_observation_offset_replaces_the_resets_own_draw(env, batched):
    """`set_hole_obs_offset` (the evaluation grid's noise levels) determines the hole part of the policy
    observation alone: the reset's own offset gives back the reset observation exactly, another offset
    shifts only the hole-relative position, by the difference."""
    reset, _ = batched
    state = reset(jax.random.split(jax.random.PRNGKey(5), 4))
    set_offset = jax.jit(jax.vmap(env.set_hole_obs_offset))
    same = set_offset(state, state.info["hole_obs_offset"])
    np.testing.assert_array_equal(np.asarray(same.obs["state"]), np.asarray(state.obs["state"]))
    offset = jnp.tile(jnp.array([0.004, -0.003, 0.001]), (4, 1))
    moved = set_offset(state, offset)
    delta = np.asarray(moved.obs["state"] - state.obs["state"])
    hole_rel = env.policy_obs_layout["ee_rel_hole"]
    np.testing.assert_allclose(delta[:, hole_rel], -np.asarray(offset - state.info["hole_obs_offset"]), atol=1e-6)
    rest = np.ones(delta.shape[1], bool)
    rest[hole_rel] = False
    np.testing.assert_array_equal(delta[:, rest], 0.0)
    np.testing.assert_array_equal(np.asarray(moved.obs["privileged_state"]), np.asarray(state.obs["privileged_state"]))


def test_unclipped_actions_scale_past_their_range_as_the_authors_env_takes_them(env, batched):
    """With `ActionConfig.clip` off a force-x action of 2 targets 40 N (clipped: 20 N) and a position action of
    -5 moves the target 10 cm down (clipped: 2 cm), which the box around the observed hole top stops."""
    reset, _ = batched
    state = jax.tree_util.tree_map(lambda x: x[0], reset(jax.random.split(jax.random.PRNGKey(5), 4)))
    config = env.config
    unclipped = FPiHEnv(dataclasses.replace(config, actions=dataclasses.replace(config.actions, clip=False)))
    space = env.action_space
    action = env.neutral_action().at[space.force[0]].set(2.0).at[space.selection[0]].set(1.0)
    action = action.at[space.position[2]].set(-5.0)
    ee_z = float(state.pipeline_state.site_xpos[env.ids.ee_site][2])
    box_bottom = float(state.info["hole_pos"][2] + state.info["hole_obs_offset"][2]) + env.hole_depth \
        - config.actions.pos_box
    assert ee_z - 0.10 < box_bottom < ee_z - 0.02
    for e, force_x, target_z in ((env, 20.0, ee_z - 0.02), (unclipped, 40.0, box_bottom)):
        target = e._control_target(state.pipeline_state, state.info, e._bounded(action))
        assert float(target.force[0]) == pytest.approx(force_x, rel=1e-6)
        assert float(target.pos[2]) == pytest.approx(target_z, abs=1e-6)


def test_reward_is_highest_at_the_goal(env):
    """Keypoint reward: near its maximum (1/6 + 1/4 + 1/2) with the peg at the bottom, small far away."""
    state = env.reset(jax.random.PRNGKey(0))
    data = state.pipeline_state
    far = float(env._reward(data, state.info["hole_pos"]))
    tip = data.site_xpos[env.ids.peg_tip_site]
    at_goal = float(env._reward(data, tip))  # pretend the hole bottom is exactly at the tip
    assert at_goal == pytest.approx(1 / 6 + 1 / 4 + 1 / 2, abs=1e-3)
    assert far < 0.5 * at_goal


def test_auto_reset_starts_fresh_episodes():
    """AutoResetEnv, the trainer's wrapper, on the cheap PointMassEnv (same info keys and episode
    bookkeeping as FPiHEnv; FPiHEnv's own time-out is checked in the full-episode test above)."""
    env = AutoResetEnv(PointMassEnv(PointMassConfig(episode_steps=3)))
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    state = reset(jax.random.split(jax.random.PRNGKey(4), 4))
    targets = [np.asarray(state.info["target"])]
    zero = jnp.zeros((4, env.action_size))
    for _ in range(3):
        state = step(state, zero)
    assert np.all(np.asarray(state.done) == 1), "time-out after episode_steps"
    assert np.all(np.asarray(state.info["truncation"]) == 1)
    assert np.all(np.asarray(state.info["steps"]) == 0), "finished envs restart"
    targets.append(np.asarray(state.info["target"]))
    assert not np.allclose(targets[0], targets[1]), "a new episode draws a new target"
    assert "final_obs" in state.info
    state = step(state, zero)
    assert np.all(np.asarray(state.info["steps"]) == 1) and np.all(np.asarray(state.done) == 0)


@pytest.fixture(scope="module")
def ram_results():
    """A scripted policy rams the peg down at full speed (pose action -1 in z): breakable at the config's
    10 N and unbreakable at inf, each break force given as an argument (`FPiHEnv.with_values`, as the
    trainer passes it)."""
    env = FPiHEnv(FPiHConfig(control="pose", **QUIET))
    ram = jnp.array([0.0, 0.0, -1.0, 0.0])

    def episode(key, task):
        def body(state, _):
            state = task.step(state, ram)
            return state, (state.info["broken"], state.info["max_force"])
        return jax.lax.scan(body, task.reset(key), None, length=40)[1]

    key = jax.random.PRNGKey(0)
    rollout = jax.jit(lambda k, f: episode(k, env.with_values(break_force=f)))  # one compile for both
    return {"breakable": rollout(key, jnp.float32(env.config.break_force)),
            "unbreakable": rollout(key, jnp.float32(math.inf))}


def test_ramming_breaks_the_peg(ram_results):
    broken, max_force = (np.asarray(x) for x in ram_results["breakable"])
    assert broken.max() == 1.0, f"max force {max_force.max():.1f} N"
    first = int(np.argmax(broken))
    assert max_force[first] >= 10.0 and np.all(max_force[:first] < 10.0)


def test_unbreakable_mode_never_breaks(ram_results):
    broken, max_force = (np.asarray(x) for x in ram_results["unbreakable"])
    assert max_force.max() >= 10.0, "the same ram exceeds the threshold"
    assert broken.max() == 0.0


def test_bad_configuration_raises_clear_errors(env):
    with pytest.raises(ValueError, match="break_force.*-1"):
        FPiHConfig(break_force=-1.0)
    with pytest.raises(ValueError, match="unknown controller 'impedance'"):
        FPiHConfig(control="impedance")
    with pytest.raises(ValueError, match="hole_obs_noise_type"):
        FPiHConfig(hole_obs_noise_type="laplace")
    with pytest.raises(ValueError, match=r"action has shape \(4,\).*expects \(10,\)"):
        env.step(env.reset(jax.random.PRNGKey(0)), jnp.zeros(4))


def test_action_space_layout(env):
    space = env.action_space
    assert space.size == 10 and env.action_size == 10
    assert space.describe()[:3] == ["select_force_x", "select_force_y", "select_force_z"]
    np.testing.assert_array_equal(space.low[:3], 0.0)
