"""The authors' task: hidden in-hand peg offset (per-env model randomisation), wrist force/torque sensor,
uniform spawn, the spherical-shell noise sweep and the authors' evaluation metrics."""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import QUIET
from match_jax.envs import randomization, sensors
from match_jax.envs import AutoResetEnv, FPiHConfig, FPiHEnv
from match_jax.envs.point_mass import PointMassConfig, PointMassEnv
from match_jax.training.evaluation import (SHELL_EDGES_MM, authors_rates, episode_metrics, shell_inner_mm, shell_offsets,
                                  summarize)
from match_jax.envs.randomization import ModelRandomization
from match_jax.training.runs import RunSpec

SPREAD = {k: v for k, v in QUIET.items() if k != "randomization"}  # quiet, but the grasp is drawn per episode


def test_defaults_are_the_authors_task():
    cfg = FPiHConfig()
    assert cfg.force_sensor == "wrist" and cfg.force_frame == "world" and cfg.observe_torque
    assert cfg.break_sampling == "policy_step" and cfg.spawn_noise_type == "uniform"
    assert cfg.randomization.peg_offset_range == (0.003, 0.0, 0.003)
    assert not cfg.controller.force_feedforward and cfg.controller.force_damping == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="peg_offset_range.*0.05"):
        ModelRandomization(peg_offset_range=(0.05, 0.0, 0.0))
    with pytest.raises(ValueError, match="force_sensor.*'ft'"):
        FPiHConfig(force_sensor="ft")
    with pytest.raises(ValueError, match="observe_torque"):
        FPiHConfig(force_sensor="peg_contact")


def test_a_config_recorded_before_the_new_fields_loads_as_it_ran():
    """A run directory's config.json from before the wrist sensor and the peg offset existed."""
    data = json.loads(RunSpec().to_json())
    for name in ("force_sensor", "observe_torque", "randomization", "force_frame", "torque_obs_noise"):
        data["env"].pop(name)
    env = RunSpec.from_json(json.dumps(data)).env
    assert env.force_sensor == "peg_contact" and not env.observe_torque
    assert not env.randomization.enabled


@pytest.fixture(scope="module")
def offset_batch():
    """64 resets of the default (hybrid) env, and the same with the peg held rigidly."""
    keys = jax.random.split(jax.random.PRNGKey(3), 64)
    env = FPiHEnv(FPiHConfig())
    rigid = FPiHEnv(FPiHConfig(randomization=ModelRandomization((0.0, 0.0, 0.0))))
    return env, jax.jit(jax.vmap(env.reset))(keys), jax.jit(jax.vmap(rigid.reset))(keys)


def test_peg_offset_spread_and_the_actor_does_not_see_it(offset_batch):
    env, state, rigid = offset_batch
    offset = np.asarray(state.info["peg_offset"])  # (64, 3), hand frame
    assert np.all(np.abs(offset[:, [0, 2]]) <= 0.003 + 1e-7) and np.all(offset[:, 1] == 0.0)
    assert offset[:, 0].std() > 0.0012 and offset[:, 2].std() > 0.0012  # U(+-3 mm): sd 1.73 mm
    assert len(np.unique(offset[:, 0])) == 64, "one draw per env"
    # The peg really moved: tip position relative to the EE differs from the rigid grasp by the offset.
    ids = env.ids
    tip = np.asarray(state.pipeline_state.site_xpos[:, ids.peg_tip_site] - state.pipeline_state.site_xpos[:, ids.ee_site])
    rot = np.asarray(state.pipeline_state.site_xmat[:, ids.ee_site])
    tip_rigid = np.asarray(rigid.pipeline_state.site_xpos[:, ids.peg_tip_site] - rigid.pipeline_state.site_xpos[:, ids.ee_site])
    in_hand = np.einsum("bji,bj->bi", rot, tip - tip_rigid)
    np.testing.assert_allclose(in_hand, offset, atol=2e-5)
    # The actor's observation is the same function of the arm's state as with the rigid grasp: same keys
    # (hole, spawn, noise draws), so it differs only where the arm's pose differs (the IK target height).
    actor, actor_rigid = np.asarray(state.obs["state"]), np.asarray(rigid.obs["state"])
    layout = env.policy_obs_layout
    same = [s for name, s in layout.items() if name != "ee_rel_hole"]
    for s in same:
        np.testing.assert_allclose(actor[:, s], actor_rigid[:, s], atol=1e-5)
    # the offset is not a linear function of what the actor sees, but is one of the critic's inputs
    critic = np.asarray(state.obs["privileged_state"])
    assert np.allclose(critic[:, -3:], offset, atol=1e-7)
    design = np.concatenate([actor, np.ones((64, 1))], axis=1)
    residual = offset[:, 0] - design @ np.linalg.lstsq(design, offset[:, 0], rcond=None)[0]
    assert residual.std() > 0.5 * offset[:, 0].std()


class _ModelPointMass(PointMassEnv):
    """PointMassEnv with per-episode model fields in info['model'], as FPiHEnv keeps them."""

    def reset(self, rng):
        state = super().reset(rng)
        body_pos = jax.random.uniform(jax.random.fold_in(rng, 7), (4, 3))
        return state.replace(info={**state.info, "model": {"body_pos": body_pos}})


def test_auto_reset_redraws_the_model_fields_of_finished_envs_only():
    """The trainer's auto-reset carries info['model'] (a dict) and redraws it where an env finished."""
    env = AutoResetEnv(_ModelPointMass(PointMassConfig(episode_steps=2)))
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    state = reset(jax.random.split(jax.random.PRNGKey(5), 4))
    before = np.asarray(state.info["model"]["body_pos"])
    actions = jnp.zeros((4, env.action_size))
    state = step(state, actions)
    np.testing.assert_array_equal(np.asarray(state.info["model"]["body_pos"]), before)  # mid-episode: kept
    state = step(state.replace(info={**state.info, "steps": state.info["steps"].at[0].set(0)}), actions)
    after = np.asarray(state.info["model"]["body_pos"])
    assert np.asarray(state.done).tolist() == [0.0, 1.0, 1.0, 1.0]
    np.testing.assert_array_equal(after[0], before[0])  # env 0 is still in its episode
    assert np.all(np.abs(after[1:] - before[1:]) > 0)  # the others restarted with a fresh draw


@pytest.mark.slow
def test_auto_reset_draws_a_new_peg_offset_for_finished_envs_only():
    env = AutoResetEnv(FPiHEnv(FPiHConfig(control="pose", episode_steps=2, **SPREAD)))
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    state = reset(jax.random.split(jax.random.PRNGKey(5), 4))
    before = np.asarray(state.info["peg_offset"])
    actions = jnp.zeros((4, env.action_size))
    state = step(state, actions)
    np.testing.assert_array_equal(np.asarray(state.info["peg_offset"]), before)  # mid-episode: kept
    state = step(state, actions)  # time-out: every env restarts with a fresh grasp
    after = np.asarray(state.info["peg_offset"])
    assert np.all(np.abs(after - before)[:, 0] > 0)
    np.testing.assert_allclose(np.asarray(state.info["model"]["body_pos"])[:, env.ids.peg_body] -
                               env.model_sampler.nominal_body_pos[env.ids.peg_body], after, atol=1e-7)


def test_model_randomisation_batches_the_model_under_vmap():
    env = FPiHEnv(FPiHConfig(**SPREAD))
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    fields = jax.vmap(env.model_sampler.sample)(keys)
    models = jax.vmap(lambda f: randomization.apply(env.mjx_model, f).body_pos)(fields)
    assert models.shape == (3, env.mj_model.nbody, 3)
    assert not np.allclose(models[0], models[1])
    assert randomization.apply(env.mjx_model, {}) is env.mjx_model


@pytest.fixture(scope="module")
def wrist_ram():
    """A pose-controlled descent onto the block top, rigid peg, unbreakable: per policy step the wrist
    reading and the peg's contact force at its end, and the peg's peak contact force."""
    env = FPiHEnv(FPiHConfig(control="pose", break_force=math.inf, **QUIET))
    ram = jnp.array([0.0, 0.0, -1.0, 0.0])

    def episode(key):
        def body(state, _):
            state = env.step(state, ram)
            return state, (state.info["ee_force"], state.info["contact_force"], state.info["max_force"],
                           state.info["ee_torque"])
        return jax.lax.scan(body, env.reset(key), None, length=40)[1]

    return [np.asarray(x) for x in jax.jit(episode)(jax.random.PRNGKey(0))]


def test_wrist_reading_equals_the_contact_force_at_rest_and_reads_less_at_impact(wrist_ram):
    wrist, contact, peak, torque = wrist_ram
    # free space before the contact: the tared wrist reads only the hand's inertial force while it
    # accelerates (0.75 kg x ~1 m/s^2), never the 7.3 N weight of the hand and peg
    free = np.linalg.norm(contact, axis=-1) == 0
    assert free[:3].all() and np.abs(wrist[free]).max() < 1.5
    # pressed and settled (last 10 steps): the wrist reads the contact force within 2 % + 0.05 N. MJX-JAX
    # may drop the contact for a physics step (seen with mujoco 4.0.1: one step ends with no contact force
    # while the wrist still reads 0.2 N of the arm's decaying push); such a step is not at rest.
    pressed = np.linalg.norm(contact[-10:], axis=-1) > 0.5
    assert pressed.sum() >= 8
    np.testing.assert_allclose(wrist[-10:][pressed], contact[-10:][pressed], rtol=0.02, atol=0.05)
    assert contact[-1, 2] < -0.5
    # the impact: the peak of the contact force is far above anything the wrist reads at a step's end
    first = int(np.argmax(peak > 1.0))
    assert peak[first] > 1.5 * np.linalg.norm(wrist[first:first + 3], axis=-1).max()
    assert np.isfinite(torque).all()


def test_wrist_sensor_matches_mujoco_c_at_rest():
    """MJX's sensor reading vs MuJoCo C's, the arm held still by gravity compensation (no contact)."""
    import mujoco

    env = FPiHEnv(FPiHConfig(**QUIET))
    model, data = env.mj_model, mujoco.MjData(env.mj_model)
    data.qpos[:] = env.home_qpos
    mujoco.mj_forward(model, data)
    data.qfrc_applied[:] = data.qfrc_bias + np.array([0.0, 0.0, 0.0, 0.0, 0.3, -0.2, 0.1])
    mujoco.mj_forward(model, data)
    c_force = data.site_xmat[env.wrist.site].reshape(3, 3) @ data.sensordata[0:3]
    d = sensors.compute(env.mjx_model, jax.jit(lambda d: __import__("mujoco").mjx.forward(env.mjx_model, d))(
        __import__("mujoco").mjx.put_data(model, data)))
    force, torque = env.wrist.read(env.mjx_model, d)
    np.testing.assert_allclose(np.asarray(force), c_force + env.wrist.subtree_mass * model.opt.gravity, atol=1e-3)
    assert np.linalg.norm(np.asarray(force)) > 0.01  # the wrist torques accelerate the hand: it reads it


def test_authors_reading_is_the_negated_hand_frame_reading():
    rot = jnp.diag(jnp.array([1.0, -1.0, -1.0]))  # hand pointing down, yaw 0
    np.testing.assert_allclose(np.asarray(sensors.authors_reading(jnp.array([1.0, 2.0, -3.0]), rot)), [-1.0, 2.0, -3.0])
    env = FPiHEnv(FPiHConfig(force_frame="hand", **QUIET))
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    assert state.obs["state"].shape == (27,)


def test_shell_offsets_have_the_shells_radii():
    key_d, key_r = jax.random.split(jax.random.PRNGKey(0))
    n = 4000
    for lo, hi in zip(SHELL_EDGES_MM[:-1], SHELL_EDGES_MM[1:]):
        assert shell_inner_mm(hi) == lo
        off = np.asarray(shell_offsets(jax.random.normal(key_d, (n, 3)), jax.random.uniform(key_r, (n,)),
                                       lo / 1000.0, hi / 1000.0))
        radius = np.linalg.norm(off, axis=-1) * 1000.0
        assert radius.min() >= lo - 1e-4 and radius.max() <= hi + 1e-4
        assert abs(radius.mean() - 0.5 * (lo + hi)) < 0.03 * hi  # uniform in radius
        unit = off / np.linalg.norm(off, axis=-1, keepdims=True)
        assert np.abs(unit.mean(axis=0)).max() < 0.05 and abs((unit[:, 2] ** 2).mean() - 1 / 3) < 0.03


def test_authors_force_metric_against_a_hand_computed_trajectory():
    """T = 4 steps, B = 2 episodes; episode 1 breaks at step 2 (its later steps are not alive)."""
    T, B = 4, 2
    traj = {k: np.zeros((T, B)) for k in ("success", "broken", "in_contact", "mean_force", "max_force",
                                            "done_before", "done", "truncation")}
    traj.update(position_axes=np.ones((T, B, 3)), contact_axes=np.zeros((T, B, 3)),
                contact_axes_before=np.zeros((T, B, 3)), ee_force=np.zeros((T, B, 3)))
    traj["ee_force"][:, 0] = [[0, 0, -3.0], [0, 4.0, -3.0], [0, 0, -0.5], [0, 0, -2.0]]
    traj["contact_axes"][:, 0] = [[0, 0, 1], [0, 1, 1], [0, 0, 0], [0, 0, 1]]
    traj["ee_force"][:, 1] = [[0, 0, 0.0], [0, 0, -6.0], [0, 0, -11.0], [0, 0, -9.0]]
    traj["contact_axes"][:, 1] = [[0, 0, 0], [0, 0, 1], [0, 0, 1], [0, 0, 1]]
    traj["broken"][2, 1], traj["done"][2, 1] = 1, 1
    traj["done_before"][3, 1] = 1
    traj["success"][2:, 0] = 1
    traj["position_axes"][:, 0, 2] = [0, 0, 1, 0]  # episode 0 force-controls z on steps 0, 1, 3
    metrics = episode_metrics(traj, policy_dt=1 / 15)
    rates = authors_rates(metrics)
    # contact steps: ep 0 steps 0, 1, 3 (|F| 3, 5, 2); ep 1 steps 1, 2 (6, 11; step 3 is after the break)
    assert rates["authors_mean_force_n"] == pytest.approx((3 + 5 + 2 + 6 + 11) / 5)
    # z force-selected 3 times, all ending in contact: accuracy 1 on z, the only force-selected axis
    assert rates["authors_force_accuracy"] == pytest.approx(1.0)
    # position-selected axis-steps ending in free space: x 7 of 7, y 6 of 7 (ep 0 step 1), z 2 of 4 (ep 0
    # step 2; ep 1 steps 0-2, free at step 0)
    assert rates["authors_position_accuracy"] == pytest.approx((1.0 + 6 / 7 + 2 / 4) / 3)
    summary = summarize(metrics)
    assert summary["authors_time_to_success_s"] == pytest.approx(2 / 15)  # 0-based success step 2
    assert summary["mean_time_to_success_s"] == pytest.approx(3 / 15)
