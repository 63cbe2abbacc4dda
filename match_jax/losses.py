"""Losses of the PPO update, module-level and unit-tested: the clipped PPO objective with the value
loss, and MATCH's supervised selection loss (SSL)."""

from __future__ import annotations

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


def ppo_loss(params, batch, adv, returns, *, actor, critic, dist, config):
    """PPO's clipped surrogate + value loss (+ beta x selection loss for hybrid policies, 'joint' phase).

    params: {'actor', 'critic'}; batch: a `ppo.Transition` minibatch (normalised observations, the
    rollout's latent samples and their log-probs, contact labels); adv, returns: (N,) from GAE.
    actor / critic: the Flax modules; dist: the method's action distribution; config: `PPOConfig`.
    Returns (total loss, metrics); the metrics whose names start with "_" are sums and counts the
    trainer turns into p_force on in-contact / free-space samples and axes.
    """
    head = actor.apply(params["actor"], batch.policy_obs)
    log_prob = dist.log_prob(batch.sample, head)
    log_ratio = log_prob - batch.log_prob
    ratio = jnp.exp(log_ratio)
    if config.normalize_advantages:
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    pg_loss = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - config.clip_eps, 1 + config.clip_eps) * adv).mean()
    values = critic.apply(params["critic"], batch.critic_obs)
    value_loss = 0.5 * jnp.mean((values - returns) ** 2)
    entropy = dist.entropy(head).mean()
    total = pg_loss + config.value_coef * value_loss - config.entropy_coef * entropy
    ssl_loss = jnp.zeros(())
    p_force = jnp.zeros(())
    contact_stats = {}
    if dist.num_selections:
        ssl_loss = selection_loss(head.logits, batch.contact_label, config.ssl_samples == "contact")
        p_axes = jax.nn.sigmoid(head.logits).mean(-1)
        p_force = p_axes.mean()
        in_contact = batch.contact_label.max(-1)
        p_each = jax.nn.sigmoid(head.logits)  # (N, 3)
        contact_stats = {"_p_force_contact_sum": (p_axes * in_contact).sum(), "_contact_count": in_contact.sum(),
                         "_p_force_axis_contact_sum": (p_each * batch.contact_label).sum(),
                         "_axis_contact_count": batch.contact_label.sum()}
        if config.uses_ssl and config.ssl_phase == "joint":
            total = total + config.ssl_beta * ssl_loss
    metrics = {
        "loss": total,
        "policy_loss": pg_loss,
        "value_loss": value_loss,
        "entropy": entropy,
        "ssl_loss": ssl_loss,
        "approx_kl": jnp.mean((ratio - 1.0) - log_ratio),
        "clip_fraction": jnp.mean(jnp.abs(ratio - 1.0) > config.clip_eps),
        "p_force": p_force,
        **contact_stats,
    }
    return total, metrics
