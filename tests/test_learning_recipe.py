"""The pieces of the authors' learning recipe, each a PPOConfig / NetworkConfig field: separate step sizes,
critic steps per minibatch, the per-update KL stop, the Huber value loss, return normalisation, the
initialisation; the responsive start of every squashed action component."""

import match_jax  # noqa: F401

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from match_jax.rl import losses
from match_jax.rl.distributions import make_distribution
from match_jax.envs import FPiHConfig
from match_jax.envs.point_mass import PointMassEnv
from match_jax.rl.networks import Actor, Critic, NetworkConfig
from match_jax.rl.ppo import (PPOConfig, apply_gradients, initial_mean_bias, make_optimizer, make_trainer,
                           to_critic_units, to_return_units)
from match_jax.training.presets import PRESETS, get_preset

TINY_NET = NetworkConfig(8, 1, 8, 1)


def _small(**overrides) -> PPOConfig:
    return PPOConfig(**{"method": "pose", "num_envs": 4, "rollout_steps": 8, "iterations_per_chunk": 1,
                        "epochs": 2, "minibatches": 4, "total_steps": 32, "network": TINY_NET, **overrides})


def _adam_counts(opt_state) -> dict:
    """Adam's step count per network (the scale_by_adam state's `count`)."""
    return {k: int(np.asarray(optax.tree_utils.tree_get(opt_state.inner_states[k], "count")).reshape(-1)[0])
            for k in ("actor", "critic")}


def test_huber_value_loss_uses_the_mad_of_the_critics_change():
    rng = np.random.default_rng(0)
    predicted, returns, old = (jnp.asarray(rng.normal(size=64), jnp.float32) for _ in range(3))
    change = np.asarray(old - predicted)
    delta = 1.35 * (np.median(np.abs(change - np.median(change))) + 1e-8)
    err = np.abs(np.asarray(predicted - returns))
    expected = np.where(err < delta, 0.5 * err ** 2, delta * (err - 0.5 * delta)).mean()
    np.testing.assert_allclose(losses.value_loss(predicted, returns, old, "huber"), expected, rtol=1e-5)
    np.testing.assert_allclose(losses.value_loss(predicted, returns, old, "mse"),
                               0.5 * np.mean(np.asarray(predicted - returns) ** 2), rtol=1e-6)
    # beyond delta the gradient is delta x sign, whatever the error's size (the delta itself has no gradient)
    grad = jax.grad(lambda p: losses.value_loss(p, returns, old, "huber"))(predicted)
    far = err > delta
    np.testing.assert_allclose(np.abs(np.asarray(grad))[far] * 64, delta, rtol=1e-4)
    with pytest.raises(ValueError, match="'l1'"):
        losses.value_loss(predicted, returns, old, "l1")


def test_actor_and_critic_step_sizes_are_separate():
    cfg = _small(learning_rate=1e-3, actor_learning_rate=1e-3, critic_learning_rate=1e-5)
    optimizer = make_optimizer(cfg)
    params = {"actor": jnp.zeros(()), "critic": jnp.zeros(())}
    state = optimizer.init(params)
    updates, _ = optimizer.update({"actor": jnp.ones(()), "critic": jnp.ones(())}, state, params)
    np.testing.assert_allclose([-float(updates["actor"]), -float(updates["critic"])], [1e-3, 1e-5], rtol=1e-4)
    assert _small(learning_rate=3e-4).critic_lr == 3e-4  # None: the shared learning_rate
    with pytest.raises(ValueError, match="desired_kl"):
        _small(desired_kl=0.01, critic_learning_rate=1e-5)
    with pytest.raises(ValueError, match="critic_learning_rate must be"):
        _small(critic_learning_rate=0.0)


def test_a_network_that_is_off_keeps_its_parameters_and_adam_state():
    optimizer = make_optimizer(_small())
    params = {"actor": jnp.zeros(3), "critic": jnp.zeros(2)}
    state = optimizer.init(params)
    grads = {"actor": jnp.ones(3), "critic": jnp.ones(2)}
    new_params, new_state = apply_gradients(optimizer, params, state, grads, actor_on=jnp.asarray(False))
    np.testing.assert_array_equal(new_params["actor"], params["actor"])
    assert np.all(np.asarray(new_params["critic"]) < 0)
    assert _adam_counts(new_state) == {"actor": 0, "critic": 1}


@pytest.fixture(scope="module")
def point_mass():
    return PointMassEnv()


def _one_iteration(cfg, env, seeds=1):
    trainer = make_trainer(cfg, env)
    state = jax.jit(trainer.init)(jax.random.split(jax.random.PRNGKey(0), seeds))
    return state, *jax.jit(trainer.train_chunk)(state)


def test_critic_steps_and_kl_stop_count_adam_steps(point_mass):
    """critic_steps=3: three critic steps per actor step. kl_threshold below any KL but the rollout policy's
    own (0): the actor steps on the first minibatch only, the critic on all."""
    cfg = _small(critic_steps=3, kl_threshold=1e-12)
    before, after, metrics = _one_iteration(cfg, point_mass)
    steps = cfg.epochs * cfg.minibatches
    assert _adam_counts(jax.tree_util.tree_map(lambda x: x[0], after.opt_state)) == {"actor": 1, "critic": 3 * steps}
    np.testing.assert_allclose(np.asarray(metrics["actor_steps"]), [[1 / steps]])
    _, after, metrics = _one_iteration(_small(kl_threshold=1e9), point_mass)
    assert _adam_counts(jax.tree_util.tree_map(lambda x: x[0], after.opt_state)) == {"actor": steps, "critic": steps}
    np.testing.assert_allclose(np.asarray(metrics["actor_steps"]), [[1.0]])


def test_return_normalisation_tracks_the_returns(point_mass):
    """The critic's targets are the rollout's returns normalised by statistics that have seen them; the
    conversions invert each other; a run without normalisation carries no statistics."""
    before, after, metrics = _one_iteration(_small(normalize_returns=True, reward_scale=1.0), point_mass, seeds=2)
    stats = after.return_stats
    assert stats.mean.shape == (2, 1) and stats.std.shape == (2, 1)
    # point-mass rewards are in (0, 2] per step: returns of a 0.995 discount are positive and spread
    assert np.all(np.asarray(stats.mean) > 0) and np.all(np.asarray(stats.std) > 0)
    one = jax.tree_util.tree_map(lambda x: x[0], stats)
    x = jnp.linspace(-3.0, 3.0, 7)
    np.testing.assert_allclose(to_critic_units(to_return_units(x, one), one), x, rtol=1e-5, atol=1e-5)
    assert _one_iteration(_small(), point_mass)[1].return_stats is None


def test_network_init_fields():
    net = NetworkConfig(8, 1, 8, 1, head_scale=0.5, critic_init_value=12.5)
    critic = Critic(net)
    params = critic.init(jax.random.PRNGKey(0), jnp.zeros((1, 5)))
    head = [v for k, v in params["params"].items() if k.startswith("Dense")][-1]
    np.testing.assert_allclose(head["bias"], [12.5])
    big, small = (Actor(4, 3, dataclasses.replace(net, head_scale=s)).init(jax.random.PRNGKey(0), jnp.zeros((1, 5)))
                  for s in (0.5, 0.01))
    norm = {k: float(jnp.linalg.norm(p["params"]["Dense_0"]["kernel"])) for k, p in (("big", big), ("small", small))}
    assert norm["big"] == pytest.approx(50 * norm["small"], rel=1e-4)
    with pytest.raises(ValueError, match="head_scale"):
        NetworkConfig(head_scale=0.0)


@pytest.mark.parametrize("preset", sorted(PRESETS))
@pytest.mark.parametrize("method", ["pose", "vices", "hybrid", "match"])
def test_every_squashed_component_starts_where_tanh_responds(preset, method):
    """The untrained mean of every tanh-squashed component (positions, yaw, VICES gains, forces) sits where
    d tanh / du >= 0.1, so gradient can move it: a force-z target at the top of its range (0 N, a pre-tanh
    mean of 3.8) fails (slope 0.002)."""

    class _Env:  # only the action scaling is read
        config = FPiHConfig()

    bias = np.asarray(initial_mean_bias(get_preset(preset, method=method), _Env()))
    assert bias.shape == (make_distribution(method).num_continuous,)
    slope = 1.0 - np.tanh(bias) ** 2
    assert np.all(slope >= 0.1), (preset, method, bias, slope)


def test_a_saturated_force_z_start_is_caught():
    class _Env:
        config = FPiHConfig()

    cfg = dataclasses.replace(get_preset("cpu", method="match"),
                              network=dataclasses.replace(get_preset("cpu").network, initial_force_z=0.0))
    assert np.min(1.0 - np.tanh(np.asarray(initial_mean_bias(cfg, _Env()))) ** 2) < 0.01


def test_authors_preset_holds_their_recipe():
    cfg = get_preset("authors", method="match")
    assert (cfg.actor_lr, cfg.critic_lr, cfg.adam_b1, cfg.adam_b2, cfg.adam_eps) == (1e-5, 1e-5, 0.999, 0.999, 1e-8)
    assert (cfg.epochs, cfg.minibatches, cfg.critic_steps, cfg.kl_threshold) == (4, 150, 2, 0.05)
    assert (cfg.value_loss, cfg.normalize_returns, cfg.gamma, cfg.value_coef) == ("huber", True, 0.995, 1.0)
    net = cfg.network
    assert (net.actor_hidden, net.actor_blocks, net.critic_hidden, net.critic_blocks) == (512, 2, 1024, 4)
    assert (net.initial_log_std, net.initial_force_z, net.critic_init_value) == (0.0, None, 12.5)
    assert math.log(net.initial_p_position / (1 - net.initial_p_position)) == pytest.approx(2.5)
