"""The PPO loss against hand computation: ratio 1 leaves only the value loss, clipping caps the gain,
and the selection loss enters with beta for hybrid policies."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from match_jax.rl.distributions import make_distribution
from match_jax.rl.losses import critic_loss, ppo_loss, selection_counts, selection_loss, selection_rates
from match_jax.rl.networks import Actor, Critic, NetworkConfig
from match_jax.rl.ppo import PPOConfig, Transition

N, OBS, CRITIC_OBS = 16, 5, 7


@pytest.fixture(scope="module")
def setup():
    config = PPOConfig(method="match", network=NetworkConfig(actor_hidden=16, actor_blocks=1, critic_hidden=16,
                                                             critic_blocks=1))
    dist = make_distribution("match")
    actor, critic = Actor(dist.num_continuous, dist.num_selections, config.network), Critic(config.network)
    k = jax.random.split(jax.random.PRNGKey(0), 6)
    obs, cobs = jax.random.normal(k[0], (N, OBS)), jax.random.normal(k[1], (N, CRITIC_OBS))
    params = {"actor": actor.init(k[2], obs), "critic": critic.init(k[3], cobs)}
    head = actor.apply(params["actor"], obs)
    sample = jax.vmap(dist.sample)(jax.random.split(k[4], N), head)
    labels = (jax.random.uniform(k[5], (N, 3)) > 0.7).astype(jnp.float32)
    batch = Transition(policy_obs=obs, critic_obs=cobs, final_critic_obs=cobs, sample=sample,
                       log_prob=dist.log_prob(sample, head), reward=jnp.zeros(N), done=jnp.zeros(N),
                       truncation=jnp.zeros(N), contact_label=labels)
    kw = dict(actor=actor, critic=critic, dist=dist)
    return config, params, batch, kw, head


def test_ratio_one_leaves_value_and_selection_losses(setup):
    config, params, batch, kw, head = setup
    adv, returns = jnp.linspace(-1.0, 2.0, N), jnp.linspace(0.0, 3.0, N)
    total, (m, counts) = ppo_loss(params, batch, adv, returns, config=config, **kw)
    values = kw["critic"].apply(params["critic"], batch.critic_obs)
    value_loss = 0.5 * np.mean((np.asarray(values) - np.asarray(returns)) ** 2)
    ssl = float(selection_loss(head.logits, batch.contact_label))
    assert float(m["policy_loss"]) == pytest.approx(0.0, abs=1e-6)  # normalised advantages average 0
    assert float(m["approx_kl"]) == pytest.approx(0.0, abs=1e-6) and float(m["clip_fraction"]) == 0.0
    assert float(m["value_loss"]) == pytest.approx(value_loss, rel=1e-5)
    assert float(m["ssl_loss"]) == pytest.approx(ssl, rel=1e-5)
    expected = value_loss * config.value_coef - config.entropy_coef * float(m["entropy"]) + config.ssl_beta * ssl
    assert float(total) == pytest.approx(expected, rel=1e-5)
    no_ssl = dataclasses.replace(config, ssl_coef=0.0)
    total0, _ = ppo_loss(params, batch, adv, returns, config=no_ssl, **kw)
    assert float(total) - float(total0) == pytest.approx(config.ssl_beta * ssl, rel=1e-4)
    p = jax.nn.sigmoid(head.logits)
    assert float(selection_rates(counts)["p_force"]) == pytest.approx(float(p.mean()), rel=1e-5)


@pytest.mark.parametrize("kind", ["mse", "huber"])
def test_critic_loss_is_the_value_half_of_the_ppo_loss(setup, kind):
    """critic_loss (the value-only steps' loss) is ppo_loss's value term, and its gradient reaches the critic
    only."""
    config, params, batch, kw, head = setup
    config = dataclasses.replace(config, value_loss=kind)
    adv, returns = jnp.linspace(-1.0, 2.0, N), jnp.linspace(0.0, 3.0, N)
    old_values = returns + jnp.linspace(-0.5, 0.5, N)
    _, (m, _) = ppo_loss(params, batch, adv, returns, old_values, config=config, **kw)
    value = critic_loss(params, batch, returns, old_values, critic=kw["critic"], config=config)
    assert float(value) == pytest.approx(float(m["value_loss"]), rel=1e-6) and float(value) > 0
    grads = jax.grad(critic_loss)(params, batch, returns, old_values, critic=kw["critic"], config=config)
    assert all(float(jnp.abs(g).max()) == 0.0 for g in jax.tree_util.tree_leaves(grads["actor"]))
    assert any(float(jnp.abs(g).max()) > 0.0 for g in jax.tree_util.tree_leaves(grads["critic"]))


def test_clipping_caps_the_surrogate(setup):
    """Old log-probs 1 nat below the new ones: ratio e > 1 + clip, so positive advantages gain only
    (1 + clip) A and negative ones pay the full e A."""
    config, params, batch, kw, _ = setup
    shifted = batch._replace(log_prob=batch.log_prob - 1.0)
    adv = jnp.where(jnp.arange(N) % 2 == 0, 1.0, -1.0)
    unnormalised = dataclasses.replace(config, normalize_advantages=False)
    _, (m, _) = ppo_loss(params, shifted, adv, jnp.zeros(N), config=unnormalised, **kw)
    ratio, clip = np.e, config.clip_eps
    expected = -np.mean(np.where(np.asarray(adv) > 0, (1 + clip) * 1.0, ratio * -1.0))
    assert float(m["policy_loss"]) == pytest.approx(expected, rel=1e-4)
    assert float(m["clip_fraction"]) == 1.0


def test_selection_rates_against_hand_counts():
    """Three samples: one touching on x and z, one on y, one free; p_force per axis given."""
    p = np.array([[0.9, 0.2, 0.7], [0.1, 0.6, 0.2], [0.05, 0.1, 0.15]])
    labels = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    logits = jnp.log(p / (1.0 - p))
    half = [selection_counts(logits[rows], labels[rows]) for rows in (slice(0, 2), slice(2, 3))]
    counts = jax.tree_util.tree_map(lambda a, b: a + b, *half)  # sums add over minibatches
    rates = {k: float(v) for k, v in selection_rates(counts).items()}
    assert rates["p_force"] == pytest.approx(p.mean(), rel=1e-5)
    assert rates["p_force_contact"] == pytest.approx(p[:2].mean(), rel=1e-5)
    assert rates["p_force_free"] == pytest.approx(p[2].mean(), rel=1e-5)
    assert rates["p_force_contact_axis"] == pytest.approx((0.9 + 0.7 + 0.6) / 3, rel=1e-5)
    free_axes = p[labels == 0]
    assert rates["p_force_free_axis"] == pytest.approx(free_axes.mean(), rel=1e-5)
    none = {k: float(v) for k, v in selection_rates(selection_counts(logits[2:], labels[2:])).items()}
    assert np.isnan(none["p_force_contact"]) and np.isnan(none["p_force_contact_axis"])
    assert none["p_force_free"] == pytest.approx(p[2].mean(), rel=1e-5)
