"""Action distributions of the four methods: Pose, VICES, Hybrid-Basic and MATCH.

Every distribution is a small frozen dataclass of pure functions over the policy head's outputs
(`PolicyHead`: selection logits, means and log standard deviations, leading batch axes allowed).
A sample is kept in the distribution's *latent* form (`Sample`): the pre-tanh Gaussian values and
the 0/1 selections. PPO stores latents, so log-probs are computed from the pre-tanh value and stay
exact and finite at the action bounds; `to_action` maps a latent to the env's action vector.

Continuous components are tanh-squashed Gaussians scaled to the env's action bounds [-1, 1]:
    a = tanh(u), u ~ N(mean, std),   log p(a) = log N(u) - log(1 - tanh(u)^2)
(the log-det-Jacobian of the squash). Selections (hybrid only) are Bernoulli per world axis with
p_force = sigmoid(logit); selection 1 means force control on that axis.

- Pose / VICES (`ProductDistribution`): sum of the continuous log-probs.
- Hybrid-Basic (`HybridBasicDistribution`): log p = sum_i [log Bern(s_i) + log N(pos_i) + log N(force_i)]
  + log N(yaw): every component counts, whichever mode acted.
- MATCH (`MatchDistribution`): per axis, the probability of the selected mode times the density of
  that mode's component only, a masked piecewise mixture:
    log p = sum_i [c * log Bern(s_i) + (1 - s_i) log N(pos_i) + s_i log N(force_i)] + log N(yaw),
  with c = 1 (`selection_in_ratio=True`, the paper's equation) or c = 0 (the authors' public code:
  the selection then learns from the supervised selection loss only). The unselected component's
  mean and std get exactly zero gradient.

Entropy: the tanh-Gaussian has no closed form; `entropy` uses the pre-tanh Gaussian's entropy (the
usual approximation; the paper's entropy coefficient is 0). For MATCH each axis's component
entropies are weighted by the probability of their mode.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from match_jax.envs.controllers.action_spaces import ActionSpace, get_action_space

LOG_2PI = math.log(2.0 * math.pi)
LOG_2 = math.log(2.0)
# p(position) at initialisation (the paper's ~93 %): the selection logit bias is log(p_force / (1 - p_force)).
INITIAL_P_POSITION = 0.93


def selection_bias(p_position: float) -> float:
    """Selection-logit bias (log-odds of force control) giving p(position) = p_position."""
    return math.log((1.0 - p_position) / p_position)


INITIAL_SELECTION_BIAS = selection_bias(INITIAL_P_POSITION)


class PolicyHead(NamedTuple):
    """Raw outputs of the actor for one observation (leading batch axes allowed).

    logits: (..., n_sel) selection logits (log-odds of force control); n_sel = 0 without selections.
    mean: (..., n_cont) pre-tanh means of the continuous components, in `continuous` order.
    log_std: (..., n_cont) pre-tanh log standard deviations.
    """

    logits: jax.Array
    mean: jax.Array
    log_std: jax.Array


class Sample(NamedTuple):
    """A latent action: pre-tanh values of the continuous components and 0/1 selections (1 = force)."""

    pre_tanh: jax.Array
    selection: jax.Array


def gaussian_log_prob(u: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """Elementwise log N(u; mean, exp(log_std))."""
    z = (u - mean) * jnp.exp(-log_std)
    return -0.5 * z * z - log_std - 0.5 * LOG_2PI


def tanh_log_det_jacobian(u: jax.Array) -> jax.Array:
    """Elementwise log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)), finite for every finite u."""
    return 2.0 * (LOG_2 - u - jax.nn.softplus(-2.0 * u))


def tanh_gaussian_log_prob(u: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """Elementwise log-density of a = tanh(u) on (-1, 1), from the pre-tanh value u."""
    return gaussian_log_prob(u, mean, log_std) - tanh_log_det_jacobian(u)


def gaussian_entropy(log_std: jax.Array) -> jax.Array:
    return log_std + 0.5 * (1.0 + LOG_2PI)


def bernoulli_log_prob(selection: jax.Array, logits: jax.Array) -> jax.Array:
    """Elementwise log Bern(selection; p = sigmoid(logits))."""
    return selection * jax.nn.log_sigmoid(logits) + (1.0 - selection) * jax.nn.log_sigmoid(-logits)


def bernoulli_entropy(logits: jax.Array) -> jax.Array:
    p = jax.nn.sigmoid(logits)
    return -(p * jax.nn.log_sigmoid(logits) + (1.0 - p) * jax.nn.log_sigmoid(-logits))


@dataclasses.dataclass(frozen=True)
class ProductDistribution:
    """Independent tanh-Gaussians on every continuous component (Pose, VICES) and, if the action
    space has selections, independent Bernoullis on them (the base of Hybrid-Basic)."""

    space: ActionSpace

    @property
    def num_selections(self) -> int:
        return len(self.space.selection)

    @property
    def num_continuous(self) -> int:
        return len(self.space.continuous)

    # -------------------------------------------------------------------------------- sampling
    def sample(self, key: jax.Array, head: PolicyHead) -> Sample:
        k_cont, k_sel = jax.random.split(key)
        u = head.mean + jnp.exp(head.log_std) * jax.random.normal(k_cont, head.mean.shape)
        sel = jax.random.bernoulli(k_sel, jax.nn.sigmoid(head.logits)).astype(jnp.float32)
        return Sample(u, sel)

    def mode(self, head: PolicyHead) -> Sample:
        """The deterministic action: tanh of the mean; force control where p_force > 0.5."""
        return Sample(head.mean, (head.logits > 0.0).astype(jnp.float32))

    def to_action(self, sample: Sample, squash: bool = True) -> jax.Array:
        """The env's action vector (..., space.size) of a latent sample: tanh of its continuous components
        (squash=False: the pre-tanh values themselves, as the authors' deterministic evaluation sends them)."""
        batch = sample.pre_tanh.shape[:-1]
        action = jnp.zeros(batch + (self.space.size,), sample.pre_tanh.dtype)
        continuous = jnp.tanh(sample.pre_tanh) if squash else sample.pre_tanh
        action = action.at[..., jnp.asarray(self.space.continuous)].set(continuous)
        if self.num_selections:
            action = action.at[..., jnp.asarray(self.space.selection)].set(sample.selection)
        return action

    # ------------------------------------------------------------------------------ densities
    def component_log_probs(self, sample: Sample, head: PolicyHead) -> tuple[jax.Array, jax.Array]:
        """(per-continuous-component tanh-Gaussian log-probs, per-axis Bernoulli log-probs)."""
        cont = tanh_gaussian_log_prob(sample.pre_tanh, head.mean, head.log_std)
        sel = bernoulli_log_prob(sample.selection, head.logits)
        return cont, sel

    def log_prob(self, sample: Sample, head: PolicyHead) -> jax.Array:
        cont, sel = self.component_log_probs(sample, head)
        return cont.sum(-1) + sel.sum(-1)

    def entropy(self, head: PolicyHead) -> jax.Array:
        return gaussian_entropy(head.log_std).sum(-1) + bernoulli_entropy(head.logits).sum(-1)

    def p_force(self, head: PolicyHead) -> jax.Array:
        """Probability of force control per axis (..., n_sel)."""
        return jax.nn.sigmoid(head.logits)


@dataclasses.dataclass(frozen=True)
class HybridBasicDistribution(ProductDistribution):
    """Hybrid-Basic: the independent product of selections, positions, forces and yaw."""


@dataclasses.dataclass(frozen=True)
class MatchDistribution(ProductDistribution):
    """MATCH: per axis, p(selected mode) x density of the selected mode's component only."""

    selection_in_ratio: bool = True

    def _axis_masks(self, selection: jax.Array) -> jax.Array:
        """(..., n_cont) weights: 1 for components that count, 0 for the unselected mode's."""
        cont_index = {j: k for k, j in enumerate(self.space.continuous)}
        ones = jnp.ones(selection.shape[:-1] + (self.num_continuous,), selection.dtype)
        weights = ones
        for axis in range(3):
            force = selection[..., axis]
            weights = weights.at[..., cont_index[self.space.position[axis]]].set(1.0 - force)
            weights = weights.at[..., cont_index[self.space.force[axis]]].set(force)
        return weights

    def log_prob(self, sample: Sample, head: PolicyHead) -> jax.Array:
        cont, sel = self.component_log_probs(sample, head)
        weights = self._axis_masks(sample.selection)
        # jnp.where, not a product: the unselected branch contributes an exact 0 with an exact 0 gradient.
        total = jnp.where(weights > 0, cont, 0.0).sum(-1)
        if self.selection_in_ratio:
            total = total + sel.sum(-1)
        return total

    def entropy(self, head: PolicyHead) -> jax.Array:
        p_force = jax.nn.sigmoid(head.logits)
        weights = self._axis_masks(p_force)  # expected mask: p(position) / p(force) per component
        ent = (weights * gaussian_entropy(head.log_std)).sum(-1)
        if self.selection_in_ratio:
            ent = ent + bernoulli_entropy(head.logits).sum(-1)
        return ent


METHODS = ("pose", "vices", "hybrid", "match")
METHOD_CONTROL = {"pose": "pose", "vices": "vices", "hybrid": "hybrid", "match": "hybrid"}


def make_distribution(method: str, selection_in_ratio: bool = True) -> ProductDistribution:
    """The action distribution of a method: 'pose', 'vices', 'hybrid' (Hybrid-Basic) or 'match'."""
    if method not in METHOD_CONTROL:
        raise ValueError(f"unknown method {method!r}; choose one of {list(METHODS)}")
    space = get_action_space(METHOD_CONTROL[method])
    if method == "match":
        return MatchDistribution(space, selection_in_ratio=selection_in_ratio)
    if method == "hybrid":
        return HybridBasicDistribution(space)
    return ProductDistribution(space)
