"""PPO on a small JAX task, GAE bookkeeping against a numpy loop."""

import match_jax  # noqa: F401

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from match_jax.envs.point_mass import PointMassEnv
from match_jax.rl.networks import NetworkConfig
from match_jax.rl.ppo import (KL_LR_MAX, KL_LR_MIN, PPOConfig, generalized_advantages, kl_adapted_learning_rate,
                           learning_rate_schedule, make_optimizer, make_trainer, optimizer_learning_rate)


def test_ppo_solves_point_mass_reaching():
    """Two seeds in one program: mean reward per step goes from < 0.7 (random) to >= 1.5 of a maximum of
    2 (at the target) within 40 iterations x 32 envs x 50 steps = 64k env steps per seed."""
    cfg = PPOConfig(method="pose", num_envs=32, rollout_steps=50, iterations_per_chunk=10, epochs=4, minibatches=4,
                    learning_rate=1e-3, gamma=0.95, reward_scale=1.0, total_steps=64_000,
                    network=NetworkConfig(64, 1, 64, 1, initial_log_std=-0.5))
    trainer = make_trainer(cfg, PointMassEnv())
    state = jax.jit(trainer.init)(jax.random.split(jax.random.PRNGKey(0), 2))
    chunk = jax.jit(trainer.train_chunk)
    rewards = []
    for _ in range(4):
        state, metrics = chunk(state)
        rewards.append(np.asarray(metrics["mean_reward"]))
    rewards = np.concatenate(rewards)  # (40, 2)
    assert np.all(rewards[0] < 0.7), rewards[0]
    assert np.all(rewards[-1] >= 1.5), rewards[-1]
    assert np.all(np.isfinite(np.asarray(metrics["loss"])))
    assert not np.allclose(rewards[:, 0], rewards[:, 1])  # the seeds are different runs
    assert int(state.env_steps[0]) == 40 * 32 * 50


def test_learning_rate_decays_linearly_over_the_budget():
    """learning_rate_end: Adam's step size falls linearly to it over num_iterations x updates per iteration,
    the logged learning_rate follows, and Adam on a constant gradient moves by exactly that step size."""
    cfg = PPOConfig(method="pose", num_envs=4, rollout_steps=8, iterations_per_chunk=4, epochs=2, minibatches=2,
                    learning_rate=1e-3, learning_rate_end=0.0, total_steps=4 * 4 * 8,
                    network=NetworkConfig(8, 1, 8, 1))
    assert cfg.optimizer_steps_per_iteration == 4 and cfg.num_iterations == 4
    assert PPOConfig(method="match", ssl_phase="after", epochs=2, minibatches=2).optimizer_steps_per_iteration == 6
    assert PPOConfig(method="pose", ssl_phase="after", epochs=2, minibatches=2).optimizer_steps_per_iteration == 4
    schedule = learning_rate_schedule(cfg)
    np.testing.assert_allclose([schedule(t) for t in (0, 4, 8, 16, 32)], [1e-3, 7.5e-4, 5e-4, 0.0, 0.0], atol=1e-12)
    assert learning_rate_schedule(dataclasses.replace(cfg, learning_rate_end=None)) == 1e-3  # constant

    optimizer = make_optimizer(cfg)
    params = {"actor": jnp.zeros(()), "critic": jnp.zeros(())}
    opt_state, moves = optimizer.init(params), []
    for _ in range(16):
        updates, opt_state = optimizer.update({"actor": jnp.ones(()), "critic": jnp.ones(())}, opt_state, params)
        moves.append(-float(updates["actor"]))
    np.testing.assert_allclose(moves, [float(schedule(t)) for t in range(16)], rtol=1e-4, atol=1e-9)

    trainer = make_trainer(cfg, PointMassEnv())
    state = jax.jit(trainer.init)(jax.random.split(jax.random.PRNGKey(0), 2))
    state, metrics = jax.jit(trainer.train_chunk)(state)
    np.testing.assert_allclose(np.asarray(metrics["learning_rate"]),
                               np.repeat([[1e-3], [7.5e-4], [5e-4], [2.5e-4]], 2, axis=1), rtol=1e-6)


def test_kl_adapted_learning_rate_rule():
    """/ 1.5 above 2 x desired_kl, x 1.5 below half of it, unchanged between, clipped to [1e-5, 1e-2]."""
    kl = jnp.array([0.05, 0.021, 0.02, 0.01, 0.005, 0.0049, 0.0, 0.05, 0.0])
    lr = jnp.array([3e-4, 3e-4, 3e-4, 3e-4, 3e-4, 3e-4, 3e-4, 1.2e-5, 9e-3])
    np.testing.assert_allclose(kl_adapted_learning_rate(lr, kl, 0.01),
                               [2e-4, 2e-4, 3e-4, 3e-4, 3e-4, 4.5e-4, 4.5e-4, KL_LR_MIN, KL_LR_MAX], rtol=1e-6)


@pytest.mark.parametrize("desired_kl,expected", [
    # every step far below half the target: x 1.5 per step (4 per iteration) up to the 1e-2 ceiling
    (1e9, [np.mean([1e-3 * 1.5 ** k for k in range(1, 5)]), np.mean([1.5e-3 * 1.5 ** 4, 1e-2, 1e-2, 1e-2]), 1e-2]),
    # above twice the target on every step but each iteration's first (the rollout policy itself: KL 0)
    # (x 1.5, then / 1.5 three times: / 1.5 ** 2 per iteration)
    (1e-12, [np.mean([1e-3 * 1.5 ** -k for k in range(-1, 3)]), np.mean([1e-3 * 1.5 ** -k for k in range(1, 5)]),
             np.mean([1e-3 * 1.5 ** -k for k in range(3, 7)])]),
])
def test_kl_adaptive_step_size_is_set_per_minibatch(desired_kl, expected):
    """desired_kl: the logged learning_rate is the mean step size of the iteration's 4 Adam steps, each set
    from its minibatch's KL before the step, per seed; the optimizer state carries the last one over."""
    cfg = PPOConfig(method="pose", num_envs=4, rollout_steps=8, iterations_per_chunk=3, epochs=2, minibatches=2,
                    learning_rate=1e-3, desired_kl=desired_kl, total_steps=3 * 4 * 8,
                    network=NetworkConfig(8, 1, 8, 1))
    trainer = make_trainer(cfg, PointMassEnv())
    state = jax.jit(trainer.init)(jax.random.split(jax.random.PRNGKey(0), 2))
    np.testing.assert_allclose(optimizer_learning_rate(state.opt_state), [1e-3, 1e-3])
    state, metrics = jax.jit(trainer.train_chunk)(state)
    np.testing.assert_allclose(np.asarray(metrics["learning_rate"]), np.repeat(np.array(expected)[:, None], 2, 1),
                               rtol=1e-5)
    if desired_kl > 1:
        np.testing.assert_allclose(optimizer_learning_rate(state.opt_state), [KL_LR_MAX] * 2, rtol=1e-6)
    else:
        np.testing.assert_allclose(optimizer_learning_rate(state.opt_state), [1e-3 / 1.5 ** 6] * 2, rtol=1e-5)


def _gae_numpy(reward, value, final_value, last_value, done, truncation, gamma, lam):
    T, B = reward.shape
    adv = np.zeros((T, B))
    for b in range(B):
        running = 0.0
        for t in reversed(range(T)):
            if done[t, b]:
                boot = final_value[t, b] if truncation[t, b] else 0.0
                running = 0.0
            else:
                boot = value[t + 1, b] if t + 1 < T else last_value[b]
            delta = reward[t, b] + gamma * boot - value[t, b]
            running = delta + gamma * lam * running
            adv[t, b] = running
    return adv


def test_gae_bootstraps_time_outs_and_not_breaks():
    rng = np.random.default_rng(0)
    T, B = 12, 3
    reward, value, final_value = rng.normal(size=(T, B)), rng.normal(size=(T, B)), rng.normal(size=(T, B))
    last_value = rng.normal(size=B)
    done, truncation = np.zeros((T, B)), np.zeros((T, B))
    done[4, 0] = truncation[4, 0] = 1  # time-out: bootstrap from the episode's last observation
    done[7, 1] = 1  # break: terminal
    done[2, 2] = truncation[2, 2] = done[9, 2] = 1
    adv, ret = generalized_advantages(*(jnp.asarray(x, jnp.float32) for x in
                                        (reward, value, final_value, last_value, done, truncation)), 0.9, 0.8)
    expected = _gae_numpy(reward, value, final_value, last_value, done, truncation, 0.9, 0.8)
    np.testing.assert_allclose(adv, expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ret, expected + value, rtol=1e-5, atol=1e-5)
    # the two kinds of ending differ by exactly gamma * final_value at the ending step
    adv_break, _ = generalized_advantages(*(jnp.asarray(x, jnp.float32) for x in
                                            (reward, value, final_value, last_value, done, np.zeros((T, B)))),
                                          0.9, 0.8)
    assert abs(float(adv[4, 0] - adv_break[4, 0]) - 0.9 * final_value[4, 0]) < 1e-5


@pytest.mark.parametrize("field,value,match", [
    ("method", "sac", "unknown method 'sac'"),
    ("total_steps", 0, "total_steps must be a positive integer, got 0"),
    ("num_envs", -4, "num_envs must be a positive integer, got -4"),
    ("gamma", 1.5, "gamma must be in"),
    ("ssl_coef", -1.0, "ssl_coef must be >= 0"),
    ("ssl_phase", "before", "ssl_phase must be 'joint' or 'after', got 'before'"),
    ("ssl_samples", "free", "ssl_samples must be 'all' or 'contact', got 'free'"),
    ("learning_rate_end", -1e-4, "learning_rate_end must be a finite number >= 0 or None, got -0.0001"),
    ("learning_rate_end", float("inf"), "learning_rate_end must be a finite number >= 0 or None, got inf"),
    ("desired_kl", 0.0, "desired_kl must be a finite number > 0 or None, got 0.0"),
])
def test_bad_config_is_named(field, value, match):
    with pytest.raises(ValueError, match=match):
        PPOConfig(**{field: value})


def test_two_step_size_schedules_are_refused():
    with pytest.raises(ValueError, match=r"desired_kl \(0.01\) and learning_rate_end \(0.0\) are two step-size"):
        PPOConfig(desired_kl=0.01, learning_rate_end=0.0)


def test_ssl_beta_defaults_per_method_and_ratio():
    # the paper's ratio: 0.3 on the axis-mean BCE (= 0.1 on the sum); 3x that learned slowly or not at all
    assert PPOConfig(method="match").ssl_beta == 0.3
    assert PPOConfig(method="match", selection_in_ratio=False).ssl_beta == 1.0  # authors' ratio
    assert PPOConfig(method="hybrid").ssl_beta == 1.0
    assert PPOConfig(method="match", ssl_coef=1.0).ssl_beta == 1.0  # an explicit beta wins
    assert not PPOConfig(method="match", ssl_coef=0.0).uses_ssl
    # a preset built for MATCH keeps the per-method default when another method is swapped in
    assert dataclasses.replace(PPOConfig(method="match"), method="hybrid").ssl_beta == 1.0
