"""Action distributions against independent computations (numpy / finite differences)."""

import match_jax  # noqa: F401

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from match_jax.rl import distributions as D
from match_jax.rl.networks import Actor, NetworkConfig
from match_jax.rl.ppo import selection_loss


def _normal_cdf(x):
    return 0.5 * (1.0 + np.vectorize(math.erf)(x / math.sqrt(2.0)))


def test_tanh_gaussian_log_prob_is_the_change_of_variables_density():
    mean, std = 0.3, 0.7
    a = np.linspace(-0.995, 0.995, 41)
    u = np.arctanh(a)
    # Independent: differentiate the CDF P(tanh(U) <= a) = Phi((atanh(a) - mean) / std) numerically.
    h = 1e-6
    cdf = lambda x: _normal_cdf((np.arctanh(x) - mean) / std)
    density = (cdf(a + h) - cdf(a - h)) / (2 * h)
    ours = np.asarray(D.tanh_gaussian_log_prob(jnp.asarray(u, jnp.float32), jnp.float32(mean),
                                               jnp.float32(math.log(std))))
    np.testing.assert_allclose(ours, np.log(density), rtol=0, atol=2e-3)
    # and it integrates to one over (-1, 1)
    grid = np.linspace(-1 + 1e-7, 1 - 1e-7, 200001)
    dens = np.exp(np.asarray(D.tanh_gaussian_log_prob(jnp.asarray(np.arctanh(grid)), mean, math.log(std))))
    assert abs(np.trapezoid(dens, grid) - 1.0) < 1e-3


def test_tanh_gaussian_log_prob_is_finite_at_the_bounds():
    u = jnp.array([-40.0, -15.0, 15.0, 40.0])
    logp = D.tanh_gaussian_log_prob(u, jnp.zeros(4), jnp.zeros(4))
    grad = jax.grad(lambda m: D.tanh_gaussian_log_prob(u, m, jnp.zeros(4)).sum())(jnp.zeros(4))
    assert np.all(np.isfinite(logp)) and np.all(np.isfinite(grad))
    # log(1 - tanh(u)^2) by the naive formula where it is still accurate
    u = jnp.linspace(-5.0, 5.0, 11)
    np.testing.assert_allclose(D.tanh_log_det_jacobian(u), np.log(1 - np.tanh(np.asarray(u, np.float64)) ** 2),
                               atol=1e-5)


def _head(key, batch, n_sel, n_cont):
    k1, k2, k3 = jax.random.split(key, 3)
    return D.PolicyHead(logits=jax.random.normal(k1, (batch, n_sel)),
                        mean=jax.random.normal(k2, (batch, n_cont)),
                        log_std=0.3 * jax.random.normal(k3, (batch, n_cont)) - 0.5)


def _np_terms(sample, head):
    """Independent numpy log-densities per component (float64)."""
    u, s = np.asarray(sample.pre_tanh, np.float64), np.asarray(sample.selection, np.float64)
    lg, mu, ls = (np.asarray(x, np.float64) for x in head)
    std = np.exp(ls)
    gauss = -0.5 * ((u - mu) / std) ** 2 - np.log(std * np.sqrt(2 * np.pi)) - np.log(1 - np.tanh(u) ** 2)
    p = 1 / (1 + np.exp(-lg))
    bern = np.log(np.where(s > 0, p, 1 - p))
    return gauss, bern


def test_hybrid_basic_is_the_sum_of_independent_terms():
    dist = D.make_distribution("hybrid")
    head = _head(jax.random.PRNGKey(0), 64, 3, 7)
    sample = dist.sample(jax.random.PRNGKey(1), head)
    gauss, bern = _np_terms(sample, head)
    np.testing.assert_allclose(dist.log_prob(sample, head), gauss.sum(-1) + bern.sum(-1), rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("in_ratio", [True, False])
def test_match_counts_the_selected_mode_only(in_ratio):
    dist = D.make_distribution("match", selection_in_ratio=in_ratio)
    space = dist.space
    head = _head(jax.random.PRNGKey(2), 64, 3, 7)
    sample = dist.sample(jax.random.PRNGKey(3), head)
    gauss, bern = _np_terms(sample, head)
    cont = {j: k for k, j in enumerate(space.continuous)}
    s = np.asarray(sample.selection)
    expected = gauss[:, cont[space.yaw[0]]].copy()
    for axis in range(3):
        pos, force = gauss[:, cont[space.position[axis]]], gauss[:, cont[space.force[axis]]]
        expected += np.where(s[:, axis] > 0, force, pos) + (bern[:, axis] if in_ratio else 0.0)
    np.testing.assert_allclose(dist.log_prob(sample, head), expected, rtol=1e-5, atol=1e-4)


def test_match_unselected_component_gets_exactly_zero_gradient():
    dist = D.make_distribution("match")
    space = dist.space
    head = _head(jax.random.PRNGKey(4), 16, 3, 7)
    sample = dist.sample(jax.random.PRNGKey(5), head)
    selection = jnp.tile(jnp.array([1.0, 0.0, 1.0]), (16, 1))  # x force, y position, z force
    sample = sample._replace(selection=selection)
    grads = jax.grad(lambda h: dist.log_prob(sample, h).sum())(head)
    cont = {j: k for k, j in enumerate(space.continuous)}
    unselected = [cont[space.position[0]], cont[space.force[1]], cont[space.position[2]]]
    selected = [cont[space.force[0]], cont[space.position[1]], cont[space.force[2]], cont[space.yaw[0]]]
    for g in (grads.mean, grads.log_std):
        assert np.all(np.asarray(g)[:, unselected] == 0.0)
        assert np.all(np.abs(np.asarray(g)[:, selected]).sum(0) > 0)
    # Hybrid-Basic, by contrast, trains every component
    basic = D.make_distribution("hybrid")
    g = jax.grad(lambda h: basic.log_prob(sample, h).sum())(head)
    assert np.all(np.abs(np.asarray(g.mean)[:, unselected]).sum(0) > 0)


def test_sampled_selection_frequencies_match_p_force():
    dist = D.make_distribution("match")
    logits = jnp.array([[-2.0, 0.0, 1.5]])
    head = D.PolicyHead(logits=jnp.broadcast_to(logits, (20000, 3)), mean=jnp.zeros((20000, 7)),
                        log_std=jnp.zeros((20000, 7)))
    sample = dist.sample(jax.random.PRNGKey(6), head)
    freq = np.asarray(sample.selection).mean(0)
    expected = 1 / (1 + np.exp(-np.asarray(logits[0])))
    np.testing.assert_allclose(freq, expected, atol=0.015)  # 4.5 standard errors at n = 20000


def test_mode_and_action_layout():
    dist = D.make_distribution("hybrid")
    space = dist.space
    head = D.PolicyHead(logits=jnp.array([[0.3, -0.3, 2.0]]), mean=jnp.arange(7.0)[None] / 10,
                        log_std=jnp.zeros((1, 7)))
    action = np.asarray(dist.to_action(dist.mode(head)))[0]
    np.testing.assert_array_equal(action[list(space.selection)], [1.0, 0.0, 1.0])
    np.testing.assert_allclose(action[list(space.continuous)], np.tanh(np.arange(7) / 10), rtol=1e-6)
    raw = np.asarray(dist.to_action(dist.mode(head), squash=False))[0]  # the authors' evaluation: the mean itself
    np.testing.assert_allclose(raw[list(space.continuous)], np.arange(7) / 10, rtol=1e-6)
    np.testing.assert_array_equal(raw[list(space.selection)], [1.0, 0.0, 1.0])
    pose = D.make_distribution("pose")
    assert pose.num_selections == 0 and pose.to_action(pose.mode(_head(jax.random.PRNGKey(0), 2, 0, 4))).shape == (2, 4)


def test_initial_selection_probability_is_position_093():
    actor = Actor(num_continuous=7, num_selections=3, config=NetworkConfig(32, 1, 32, 1))
    obs = jax.random.normal(jax.random.PRNGKey(0), (256, 24))
    params = actor.init(jax.random.PRNGKey(1), obs)
    p_position = 1 - jax.nn.sigmoid(actor.apply(params, obs).logits)
    assert abs(float(p_position.mean()) - 0.93) < 0.005
    assert float(p_position.min()) > 0.9


def test_selection_loss_gradient_pushes_p_force_toward_the_label():
    labels = jnp.array([[1.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    logits = jnp.zeros((2, 3))
    grad = jax.grad(selection_loss)(logits, labels)
    stepped = logits - 1.0 * grad
    p_before, p_after = jax.nn.sigmoid(logits), jax.nn.sigmoid(stepped)
    moved = np.sign(np.asarray(p_after - p_before))
    np.testing.assert_array_equal(moved, np.where(np.asarray(labels) > 0, 1.0, -1.0))
    # BCE value against numpy
    expected = -np.log(0.5)  # mean over the 3 axes
    assert abs(float(selection_loss(logits, labels)) - expected) < 1e-6


def test_contact_only_selection_loss_ignores_free_space_samples():
    labels = jnp.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 1.0]])
    logits = jnp.array([[0.3, -1.0, 2.0], [5.0, 5.0, 5.0], [-0.5, 0.1, 0.7]])
    grad = jax.grad(selection_loss)(logits, labels, True)
    np.testing.assert_array_equal(np.asarray(grad[1]), 0.0)  # the free-space sample gets no SSL gradient
    assert np.all(np.abs(np.asarray(grad[jnp.array([0, 2])])) > 0)
    in_contact = selection_loss(logits[jnp.array([0, 2])], labels[jnp.array([0, 2])])
    assert abs(float(selection_loss(logits, labels, True)) - float(in_contact)) < 1e-6
    assert float(selection_loss(logits, jnp.zeros_like(labels), True)) == 0.0  # no contact at all: no loss


def test_unknown_method_is_named():
    with pytest.raises(ValueError, match="'sac'"):
        D.make_distribution("sac")


def test_untrained_hybrid_policy_commands_a_gentle_force():
    from match_jax.envs import FPiHConfig
    from match_jax.rl.ppo import PPOConfig, initial_mean_bias

    class _Env:  # only the action scaling is read
        config = FPiHConfig()

    cfg = PPOConfig(method="match")
    bias = initial_mean_bias(cfg, _Env())
    space = D.make_distribution("match").space
    a = np.tanh(bias[space.continuous.index(space.force[2])])
    lo, hi = FPiHConfig().actions.force_z_range
    assert lo + 0.5 * (a + 1) * (hi - lo) == pytest.approx(-1.0, abs=1e-4)
    assert sum(abs(b) for b in bias) == pytest.approx(abs(np.arctanh(a)))  # everything else starts at 0
    assert initial_mean_bias(PPOConfig(method="pose"), _Env()) == (0.0,) * 4
