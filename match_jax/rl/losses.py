"""Losses of the PPO update, module-level and unit-tested: the clipped PPO objective with the value
loss, and MATCH's supervised selection loss (SSL); with the counts behind the selection metrics."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax


def selection_loss(logits: jax.Array, contact_label: jax.Array, contact_only: bool = False) -> jax.Array:
    """Supervised selection loss (before beta): mean over axes and batch of BCE(p_force, psi).

    The axis mean is the paper's form; beta times this equals (beta / 3) times the axis sum.

    logits: (..., 3) selection logits (log-odds of force control); contact_label: (..., 3) 0/1 per axis.
    contact_only: average over the samples with at least one axis in contact only (0 if there are none).
    """
    per_sample = optax.sigmoid_binary_cross_entropy(logits, contact_label).mean(-1)
    if not contact_only:
        return per_sample.mean()
    weight = contact_label.max(-1)
    return (per_sample * weight).sum() / jnp.maximum(weight.sum(), 1.0)


class SelectionCounts(NamedTuple):
    """Sums over a batch behind the p_force metrics (`selection_rates`); p_i = sigmoid(logit_i) is the
    probability of force control on axis i, psi_i the axis's 0/1 contact label. They add up over
    minibatches, so the rates of a whole update are ratios of the summed counts."""

    p_sum: jax.Array  # sum over samples of the axis-mean p
    samples: jax.Array
    p_contact_sum: jax.Array  # the same over samples with some axis in contact
    contact_samples: jax.Array
    p_axis_contact_sum: jax.Array  # sum over samples and axes of p_i psi_i
    axis_contacts: jax.Array  # sum over samples and axes of psi_i


def selection_counts(logits: jax.Array, contact_label: jax.Array) -> SelectionCounts:
    """`SelectionCounts` of a batch: logits (N, 3) selection log-odds, contact_label (N, 3) 0/1."""
    p_each = jax.nn.sigmoid(logits)
    p_axes = p_each.mean(-1)
    in_contact = contact_label.max(-1)
    return SelectionCounts(p_sum=p_axes.sum(), samples=jnp.asarray(p_axes.size, jnp.float32),
                           p_contact_sum=(p_axes * in_contact).sum(), contact_samples=in_contact.sum(),
                           p_axis_contact_sum=(p_each * contact_label).sum(), axis_contacts=contact_label.sum())


def selection_rates(counts: SelectionCounts, axes: int = 3) -> dict[str, jax.Array]:
    """Mean p_force overall ('p_force'), over samples with some axis in contact / none
    ('p_force_contact' / 'p_force_free'), and per axis over in-contact / free axes ('p_force_contact_axis'
    = sum p_i psi_i / sum psi_i, the paper's per-axis figure; 'p_force_free_axis'); NaN where a set is empty."""

    def ratio(total, count):
        return jnp.where(count > 0, total / jnp.maximum(count, 1.0), jnp.nan)

    c = counts
    axis_free = axes * c.samples - c.axis_contacts
    return {"p_force": ratio(c.p_sum, c.samples),
            "p_force_contact": ratio(c.p_contact_sum, c.contact_samples),
            "p_force_free": ratio(c.p_sum - c.p_contact_sum, c.samples - c.contact_samples),
            "p_force_contact_axis": ratio(c.p_axis_contact_sum, c.axis_contacts),
            "p_force_free_axis": ratio(axes * c.p_sum - c.p_axis_contact_sum, axis_free)}


HUBER_MAD_SCALE = 1.35  # the adaptive Huber delta in units of the median absolute deviation


def value_loss(predicted: jax.Array, returns: jax.Array, old_values: jax.Array | None = None,
               kind: str = "mse") -> jax.Array:
    """The critic's loss on a batch, mean over samples, in the critic's output units.

    'mse': 0.5 (V - R)^2. 'huber': Huber(V - R) with delta = 1.35 x (the median absolute deviation of
    old_values - V, plus 1e-8), held constant for the gradient: old_values are the rollout's values, so
    delta tracks how far the critic has moved since the rollout (the authors' adaptive delta).
    """
    if kind == "mse":
        return 0.5 * jnp.mean((predicted - returns) ** 2)
    if kind != "huber":
        raise ValueError(f"value loss must be 'mse' or 'huber', got {kind!r}")
    change = jax.lax.stop_gradient(old_values - predicted)
    mad = jnp.median(jnp.abs(change - jnp.median(change))) + 1e-8
    return jnp.mean(optax.huber_loss(predicted, returns, delta=HUBER_MAD_SCALE * mad))


def critic_loss(params, batch, returns, old_values=None, *, critic, config) -> jax.Array:
    """`value_loss` of the critic on a minibatch (`ppo.Transition`'s critic_obs), unweighted: the value half
    of `ppo_loss`, and the loss of the value-only steps that `critic_steps` adds."""
    return value_loss(critic.apply(params["critic"], batch.critic_obs), returns, old_values, config.value_loss)


def ppo_loss(params, batch, adv, returns, old_values=None, *, actor, critic, dist, config, ssl_beta=None):
    """PPO's clipped surrogate + value loss (+ beta x selection loss for hybrid policies, 'joint' phase).

    params: {'actor', 'critic'}; batch: a `ppo.Transition` minibatch (normalised observations, the
    rollout's latent samples and their log-probs, contact labels); adv, returns: (N,) from GAE, returns
    in the critic's units; old_values: (N,) the rollout's values in those units (the Huber loss's delta).
    actor / critic: the Flax modules; dist: the method's action distribution; config: `PPOConfig`;
    ssl_beta: the selection loss's weight, a value or a traced scalar (None: config.ssl_beta).
    Returns (total loss, (metrics, SelectionCounts of the batch, or None for policies without selection)).
    """
    head = actor.apply(params["actor"], batch.policy_obs)
    log_prob = dist.log_prob(batch.sample, head)
    log_ratio = log_prob - batch.log_prob
    ratio = jnp.exp(log_ratio)
    if config.normalize_advantages:
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    pg_loss = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - config.clip_eps, 1 + config.clip_eps) * adv).mean()
    value = critic_loss(params, batch, returns, old_values, critic=critic, config=config)
    entropy = dist.entropy(head).mean()
    total = pg_loss + config.value_coef * value - config.entropy_coef * entropy
    ssl_loss = jnp.zeros(())
    counts = None
    if dist.num_selections:
        ssl_loss = selection_loss(head.logits, batch.contact_label, config.ssl_samples == "contact")
        counts = selection_counts(head.logits, batch.contact_label)
        if config.uses_ssl and config.ssl_phase == "joint":
            total = total + (config.ssl_beta if ssl_beta is None else ssl_beta) * ssl_loss
    metrics = {
        "loss": total,
        "policy_loss": pg_loss,
        "value_loss": value,
        "entropy": entropy,
        "ssl_loss": ssl_loss,
        "approx_kl": jnp.mean((ratio - 1.0) - log_ratio),
        "clip_fraction": jnp.mean(jnp.abs(ratio - 1.0) > config.clip_eps),
    }
    return total, (metrics, counts)
