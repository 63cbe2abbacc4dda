"""Dynamics randomisation (the authors' transfer ranges, the rotational stiffness capped where the law is
stable): per-env peg mass, peg friction and controller gains, drawn per episode through the per-env model, shown to the critic only."""

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import QUIET
from match_jax.envs.controllers import ControllerConfig, ControlTarget, hybrid_torque
from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.envs.randomization import AUTHORS_DYNAMICS, DYNAMICS_PRESETS, STABLE_ROT_STIFFNESS, ModelRandomization
from match_jax.training.runs import RunSpec

import train
from test_controllers import _c_dynamics, _home

DYNAMICS = ModelRandomization().with_dynamics()


def test_dynamics_is_off_by_default_and_bad_ranges_name_the_value():
    assert not FPiHConfig().randomization.dynamics and DYNAMICS.dynamics
    assert DYNAMICS.peg_offset_range == ModelRandomization().peg_offset_range  # the grasp still moves
    with pytest.raises(ValueError, match=r"force_gain.*\(0.6, 0.05\)"):
        ModelRandomization(force_gain=(0.6, 0.05))
    with pytest.raises(ValueError, match=r"peg_friction.*\(-1.0, 2.0\)"):
        ModelRandomization(peg_friction=(-1.0, 2.0))
    # a run config from before these fields existed loads without dynamics randomisation
    data = json.loads(RunSpec().to_json())
    for name in AUTHORS_DYNAMICS:
        data["env"]["randomization"].pop(name)
    assert not RunSpec.from_json(json.dumps(data)).env.randomization.dynamics


def test_train_flag_records_the_ranges_in_the_run_config():
    spec = train.build_spec(train.parse_args(["--method", "match", "--out", "/tmp/x", "--dynamics-randomization"]))
    assert spec.env.randomization == DYNAMICS
    again = RunSpec.from_json(spec.to_json()).env.randomization
    assert again == DYNAMICS and again.pos_stiffness == (60.0, 140.0)
    assert again.rot_stiffness == (20.0, STABLE_ROT_STIFFNESS)  # the authors' lower bound, capped above
    authors = train.build_spec(train.parse_args(["--method", "match", "--out", "/tmp/x",
                                                 "--dynamics-randomization", "authors"])).env.randomization
    assert authors == ModelRandomization().with_dynamics(**AUTHORS_DYNAMICS) and authors.rot_stiffness == (20.0, 60.0)
    assert set(train.DYNAMICS) == set(DYNAMICS_PRESETS)
    plain = train.build_spec(train.parse_args(["--method", "match", "--out", "/tmp/x"]))
    assert not plain.env.randomization.dynamics


@pytest.fixture(scope="module")
def draws():
    """256 envs' draws of the default scene with the default dynamics ranges."""
    env = FPiHEnv(FPiHConfig(randomization=DYNAMICS))
    keys = jax.random.split(jax.random.PRNGKey(11), 256)
    fields = jax.jit(jax.vmap(env.model_sampler.sample))(keys)
    gains = jax.jit(jax.vmap(env.model_sampler.sample_gains))(keys)
    return env, {k: np.asarray(v) for k, v in fields.items()}, {k: np.asarray(v) for k, v in gains.items()}


def _spread_in(values, low, high):
    values = np.asarray(values)
    assert values.min() >= low - 1e-6 and values.max() <= high + 1e-6, (values.min(), values.max())
    assert len(np.unique(values)) == len(values), "one draw per env"
    # uniform: the draws fill the range (sd of U[low, high] is (high - low) / sqrt(12))
    assert abs(values.std() - (high - low) / math.sqrt(12)) < 0.15 * (high - low) / math.sqrt(12)


def test_each_env_draws_its_own_mass_friction_and_gains_within_the_ranges(draws):
    env, fields, gains = draws
    model, peg, hand = env.mj_model, env.ids.peg_body, env.ids.hand_body
    scale = fields["body_mass"][:, peg] / model.body_mass[peg]
    _spread_in(scale, 0.8, 1.2)
    np.testing.assert_allclose(fields["body_inertia"][:, peg] / model.body_inertia[peg], scale[:, None] * np.ones(3),
                               rtol=1e-5)
    # every other body keeps its mass; the subtree masses above the peg carry the change (the wrist tare)
    others = np.arange(model.nbody) != peg
    np.testing.assert_allclose(fields["body_mass"][:, others], np.broadcast_to(model.body_mass[others], (256, others.sum())),
                               rtol=1e-6)
    np.testing.assert_allclose(fields["body_subtreemass"][:, hand],
                               model.body_subtreemass[hand] + (scale - 1.0) * model.body_mass[peg], rtol=1e-6)
    np.testing.assert_allclose(fields["body_subtreemass"][:, 0], model.body_subtreemass[0] + (scale - 1.0) *
                               model.body_mass[peg], rtol=1e-6)
    # friction: both tangential coefficients of every peg contact pair, the torsional/rolling ones kept
    mu = fields["pair_friction"][:, 0, 0]
    _spread_in(mu, 0.5, 2.0)
    np.testing.assert_array_equal(fields["pair_friction"][:, :, :2], np.broadcast_to(mu[:, None, None], (256, model.npair, 2)))
    np.testing.assert_allclose(fields["pair_friction"][:, :, 2:], np.broadcast_to(model.pair_friction[:, 2:], (256, model.npair, 3)),
                               rtol=1e-6)
    _spread_in(gains["pos_stiffness"][:, 0], 60.0, 140.0)
    _spread_in(gains["rot_stiffness"][:, 0], 20.0, STABLE_ROT_STIFFNESS)
    _spread_in(gains["force_gain"], 0.05, 0.6)
    assert np.all(gains["pos_stiffness"] == gains["pos_stiffness"][:, :1])  # one draw for x, y, z
    # the draws are independent of each other
    corr = np.corrcoef([scale, mu, gains["pos_stiffness"][:, 0], gains["rot_stiffness"][:, 0], gains["force_gain"]])
    assert np.abs(corr - np.eye(5)).max() < 0.25
    # the peg offset keeps its draw of the grasp-only randomisation (same key, same offset)
    grasp_only = FPiHEnv(FPiHConfig())
    offsets = jax.vmap(grasp_only.model_sampler.sample)(jax.random.split(jax.random.PRNGKey(11), 256))["body_pos"]
    np.testing.assert_allclose(fields["body_pos"], np.asarray(offsets), atol=1e-7)


def test_drawn_gains_in_the_target_replace_the_configs(env):
    """A target carrying k_f and rotational k_p gives the torque of a config with those gains."""
    data = _home(env, qvel=np.random.default_rng(1).normal(0, 0.2, 7))
    dyn = _c_dynamics(env, data, ee_force=np.array([0.5, -0.3, -2.0]))
    base = ControlTarget(pos=dyn.ee_pos + 0.01, rot=dyn.ee_rot, force=np.array([1.0, 0.0, -5.0]),
                         position_axes=np.array([1.0, 0.0, 0.0]), pos_stiffness=np.full(3, 80.0), posture=dyn.qpos)
    drawn = dataclasses.replace(base, rot_stiffness=np.full(3, 45.0), force_gain=np.float32(0.2))
    config = ControllerConfig()
    expected = hybrid_torque(dyn, base, dataclasses.replace(config, rot_stiffness=(45.0,) * 3, force_gain=0.2))
    np.testing.assert_allclose(hybrid_torque(dyn, drawn, config), expected, rtol=1e-5, atol=1e-6)
    assert not np.allclose(hybrid_torque(dyn, base, config), expected, atol=1e-3)


def test_the_critic_sees_the_drawn_dynamics_and_the_actor_does_not():
    """Reset with and without dynamics randomisation from the same keys: the actor's observation is the
    same; the critic's ends with (mass scale, friction, k_p, rotational k_p, k_f); the control target
    carries the drawn gains."""
    cfg = FPiHConfig(**{**QUIET, "randomization": DYNAMICS})
    env, plain = FPiHEnv(cfg), FPiHEnv(dataclasses.replace(cfg, randomization=ModelRandomization()))
    keys = jax.random.split(jax.random.PRNGKey(2), 4)
    state, plain_state = jax.jit(jax.vmap(env.reset))(keys), jax.jit(jax.vmap(plain.reset))(keys)
    np.testing.assert_allclose(np.asarray(state.obs["state"]), np.asarray(plain_state.obs["state"]), atol=1e-6)
    critic, gains = np.asarray(state.obs["privileged_state"]), state.info["gains"]
    assert critic.shape[1] == plain_state.obs["privileged_state"].shape[1] + 5
    mass = np.asarray(state.info["model"]["body_mass"])[:, env.ids.peg_body] / env.mj_model.body_mass[env.ids.peg_body]
    np.testing.assert_allclose(critic[:, -5:], np.stack([
        mass, np.asarray(state.info["model"]["pair_friction"])[:, 0, 0], np.asarray(gains["pos_stiffness"])[:, 0],
        np.asarray(gains["rot_stiffness"])[:, 0], np.asarray(gains["force_gain"])], axis=1), rtol=1e-6)
    one = jax.tree_util.tree_map(lambda x: x[0], state)
    target = env._control_target(one.pipeline_state, one.info, env.neutral_action())
    np.testing.assert_array_equal(np.asarray(target.pos_stiffness), np.asarray(gains["pos_stiffness"][0]))
    assert float(target.force_gain) == float(gains["force_gain"][0])


@pytest.mark.slow
def test_a_heavier_or_lighter_peg_is_tared_and_the_randomised_env_steps():
    """The wrist sensor is tared for the drawn peg mass (reads ~0 N held still in free space), and a
    batch of randomised envs steps without diverging."""
    cfg = FPiHConfig(control="pose", **{**QUIET, "randomization": dataclasses.replace(
        DYNAMICS, peg_mass_scale=(0.5, 2.0))})
    env = FPiHEnv(cfg)
    keys = jax.random.split(jax.random.PRNGKey(4), 4)
    state = jax.jit(jax.vmap(env.reset))(keys)
    step = jax.jit(jax.vmap(env.step))
    hold = jnp.zeros((4, env.action_size))
    for _ in range(3):
        state = step(state, hold)
    assert np.all(np.isfinite(np.asarray(state.pipeline_state.qpos)))
    mass = np.asarray(state.info["model"]["body_mass"])[:, env.ids.peg_body]
    assert mass.max() - mass.min() > 0.005  # kg: an untared difference would read > 0.05 N
    assert np.abs(np.asarray(state.info["ee_force"])).max() < 0.05


@pytest.mark.slow
def test_the_arm_holds_still_at_the_top_of_every_gain_range_but_not_at_the_authors_rotational_top():
    """Pose envs hold the neutral action for 40 policy steps with every drawn gain at its range's top: the
    wrist stays still and nothing touches. The same with the rotational k_p at
    the authors' 60 N m/rad: the wrist joints oscillate (why the default range stops at 30)."""
    cfg = FPiHConfig(control="pose", **{**QUIET, "randomization": DYNAMICS})
    env = FPiHEnv(cfg)
    envs = 8
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(5), envs))
    step = jax.jit(jax.vmap(env.step))
    hold = jnp.broadcast_to(env.neutral_action(), (envs, env.action_size))

    def wrist_speed(rot_stiffness: float) -> tuple[float, float]:
        gains = {"pos_stiffness": jnp.full((envs, 3), DYNAMICS.pos_stiffness[1]),
                 "rot_stiffness": jnp.full((envs, 3), rot_stiffness),
                 "force_gain": jnp.full((envs,), DYNAMICS.force_gain[1])}
        s = state.replace(info={**state.info, "gains": gains})
        contact = 0.0
        for _ in range(40):
            s = step(s, hold)
            contact = max(contact, float(np.asarray(s.metrics["in_contact"]).max()))
        return float(np.abs(np.asarray(s.pipeline_state.qvel)[:, 4:7]).max()), contact  # rad/s, joints 5-7

    speed, contact = wrist_speed(DYNAMICS.rot_stiffness[1])
    assert speed < 0.01 and contact == 0.0, (speed, contact)
    speed, _ = wrist_speed(AUTHORS_DYNAMICS["rot_stiffness"][1])
    assert speed > 0.1, speed
