"""Arm model error: the robot's masses and rotor inertias drawn per episode for the physics only, the
control law computing with the nominal model, the critic told the draw."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import QUIET
from match_jax.envs import randomization, sim
from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.envs.randomization import ARM_MODEL_ERROR, ModelRandomization
from match_jax.envs.sim import mjx
from match_jax.training.runs import RunSpec

import train

ARM_ERROR = ModelRandomization().with_arm_model_error()
BOTH = ModelRandomization().with_dynamics().with_arm_model_error()


def test_the_flag_records_the_ranges_and_bad_ranges_name_the_value():
    spec = train.build_spec(train.parse_args(["--method", "pose", "--out", "/tmp/x", "--dynamics-randomization",
                                              "--arm-model-error"]))
    assert spec.env.randomization == BOTH and RunSpec.from_json(spec.to_json()).env.randomization == BOTH
    assert BOTH.arm_mass_scale == ARM_MODEL_ERROR["arm_mass_scale"] and BOTH.arm_model_error and BOTH.dynamics
    plain = train.build_spec(train.parse_args(["--method", "pose", "--out", "/tmp/x", "--dynamics-randomization"]))
    assert not plain.env.randomization.arm_model_error
    with pytest.raises(ValueError, match=r"arm_mass_scale.*\(1.1, 0.9\)"):
        ModelRandomization(arm_mass_scale=(1.1, 0.9))


@pytest.fixture(scope="module")
def env():
    return FPiHEnv(FPiHConfig(control="pose", **{**QUIET, "randomization": BOTH}))


def test_each_env_draws_one_mass_and_one_rotor_scale_for_the_whole_robot(env):
    model, peg, hole = env.mj_model, env.ids.peg_body, model_hole(env)
    fields = jax.jit(jax.vmap(env.model_sampler.sample))(jax.random.split(jax.random.PRNGKey(3), 256))
    fields = {k: np.asarray(v) for k, v in fields.items()}
    robot = env.model_sampler.robot_bodies
    assert set(robot) == {model.body(f"link{i}").id for i in range(1, 8)} | {env.ids.hand_body, peg}
    factor = fields["body_mass"][:, robot[0]] / model.body_mass[robot[0]]
    assert 0.99 - 1e-6 <= factor.min() and factor.max() <= 1.01 + 1e-6 and factor.std() > 0.004
    links = [b for b in robot if b != peg]
    np.testing.assert_allclose(fields["body_mass"][:, links], factor[:, None] * model.body_mass[links], rtol=1e-5)
    np.testing.assert_allclose(fields["body_inertia"][:, links],
                               factor[:, None, None] * model.body_inertia[links], rtol=1e-5)
    peg_scale = fields["body_mass"][:, peg] / (factor * model.body_mass[peg])  # the peg's own draw on top
    assert 0.8 - 1e-5 <= peg_scale.min() and peg_scale.max() <= 1.2 + 1e-5 and peg_scale.std() > 0.05
    np.testing.assert_allclose(fields["body_mass"][:, hole], model.body_mass[hole], rtol=1e-7)  # not the robot's
    np.testing.assert_allclose(fields["body_subtreemass"][:, env.ids.hand_body],
                               fields["body_mass"][:, env.ids.hand_body] + fields["body_mass"][:, peg], rtol=1e-5)
    np.testing.assert_allclose(fields["body_subtreemass"][:, 0], fields["body_mass"].sum(axis=1), rtol=1e-5)
    rotor = fields["dof_armature"] / model.dof_armature
    np.testing.assert_allclose(rotor, np.broadcast_to(rotor[:, :1], rotor.shape), rtol=1e-5)  # one draw
    assert 0.8 - 1e-6 <= rotor.min() and rotor.max() <= 1.25 + 1e-6 and rotor.std() > 0.1
    assert abs(np.corrcoef(factor, rotor[:, 0])[0, 1]) < 0.25


def model_hole(env) -> int:
    return env.mj_model.body("hole").id


def test_the_law_computes_with_the_nominal_model_while_the_physics_uses_the_drawn_one(env):
    """At a moving state, the law's view of the drawn model (inertia, bias forces) equals MJX's on the model
    the law knows: nominal robot, the drawn peg mass and place in the hand; without the view it differs."""
    sampler, ids = env.model_sampler, env.ids
    fields = sampler.sample(jax.random.PRNGKey(8))
    drawn = randomization.apply(env.mjx_model, fields)
    arm, rotor = (float(x) for x in sampler.arm_error(fields["body_mass"], fields["dof_armature"]))
    assert abs(arm - 1.0) > 1e-3 and abs(rotor - 1.0) > 0.02, (arm, rotor)
    # the law's model, built from the draw's peg mass alone
    peg = ids.peg_body
    peg_scale = float(fields["body_mass"][peg]) / (arm * env.mj_model.body_mass[peg])
    model = env.mj_model
    mass = model.body_mass.copy()
    mass[peg] *= peg_scale
    subtree = mass.copy()  # MJX divides by the subtree masses for the subtrees' centres of mass
    for body in range(model.nbody - 1, 0, -1):
        subtree[model.body_parentid[body]] += subtree[body]
    law_model = randomization.apply(env.mjx_model, {
        "body_pos": fields["body_pos"],  # the peg's drawn place in the hand
        "body_mass": jnp.asarray(mass, jnp.float32), "body_subtreemass": jnp.asarray(subtree, jnp.float32),
        "body_inertia": jnp.asarray(model.body_inertia, jnp.float32).at[peg].multiply(peg_scale)})
    rng = np.random.default_rng(0)
    qpos = np.asarray(env.home_qpos, np.float32) + rng.normal(0, 0.2, 7).astype(np.float32)
    data = mjx.make_data(env.mjx_model).replace(qpos=jnp.asarray(qpos), qvel=jnp.asarray(rng.normal(0, 0.5, 7),
                                                                                          jnp.float32))

    @jax.jit
    def dynamics(m):
        d = mjx.fwd_velocity(m, mjx.fwd_position(m, data))
        return sim.arm_dynamics(m, d, ids, jnp.zeros(3))

    seen = sampler.nominal_law_view(drawn, dynamics(drawn))
    want, raw = dynamics(law_model), dynamics(drawn)
    np.testing.assert_allclose(np.asarray(seen.mass_matrix), np.asarray(want.mass_matrix), rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(np.asarray(seen.bias), np.asarray(want.bias), rtol=1e-4, atol=1e-4)
    assert np.abs(np.asarray(raw.mass_matrix) - np.asarray(want.mass_matrix)).max() > 1e-3  # kg m^2, the rotors
    assert np.abs(np.asarray(raw.bias) - np.asarray(want.bias)).max() > 0.05  # N m, the weight


def test_the_critic_sees_the_arm_error_after_the_dynamics_values(env):
    fields = env.model_sampler.sample(jax.random.PRNGKey(8))
    gains = env.model_sampler.sample_gains(jax.random.PRNGKey(8))
    values = np.asarray(env.model_sampler.dynamics_values(fields, gains))
    arm, rotor = env.model_sampler.arm_error(fields["body_mass"], fields["dof_armature"])
    assert values.shape == (7,)
    np.testing.assert_allclose(values[-2:], [float(arm), float(rotor)], rtol=1e-6)
    assert 0.8 <= values[0] <= 1.2  # the peg's own mass scale, without the arm's factor
    plain = FPiHEnv(FPiHConfig(control="pose", **{**QUIET, "randomization": ModelRandomization().with_dynamics()}))
    assert np.asarray(plain.model_sampler.dynamics_values(plain.model_sampler.sample(jax.random.PRNGKey(8)),
                                                          gains)).shape == (5,)


@pytest.mark.slow
def test_a_heavier_robot_sinks_under_the_neutral_action_and_a_nominal_one_does_not():
    """Pose envs hold the neutral action (target = the current pose) for 6 policy steps, from the same
    starts: with the robot 1 % heavier than the law's model the hand sinks (the uncompensated weight);
    with the scale drawn at exactly 1 it moves as the nominal env does."""
    def sink(arm_mass: float) -> np.ndarray:
        cfg = FPiHConfig(control="pose", **{**QUIET, "randomization": ModelRandomization(
            arm_mass_scale=(arm_mass, arm_mass), arm_armature_scale=(1.0, 1.0))})
        env = FPiHEnv(cfg)
        state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(6), 4))
        start = np.asarray(state.pipeline_state.site_xpos[:, env.ids.ee_site, 2])
        step = jax.jit(jax.vmap(env.step))
        hold = jnp.broadcast_to(env.neutral_action(), (4, env.action_size))
        for _ in range(6):
            state = step(state, hold)
        return np.asarray(state.pipeline_state.site_xpos[:, env.ids.ee_site, 2]) - start

    nominal_env = FPiHEnv(FPiHConfig(control="pose", **QUIET))
    state = jax.jit(jax.vmap(nominal_env.reset))(jax.random.split(jax.random.PRNGKey(6), 4))
    start = np.asarray(state.pipeline_state.site_xpos[:, nominal_env.ids.ee_site, 2])
    step = jax.jit(jax.vmap(nominal_env.step))
    for _ in range(6):
        state = step(state, jnp.broadcast_to(nominal_env.neutral_action(), (4, nominal_env.action_size)))
    nominal = np.asarray(state.pipeline_state.site_xpos[:, nominal_env.ids.ee_site, 2]) - start
    heavy, same = sink(1.01), sink(1.0)
    np.testing.assert_allclose(same, nominal, atol=2e-4)
    assert np.all(heavy - nominal < -3e-3), (heavy, nominal)  # m: 4.7 mm lower after 0.4 s
