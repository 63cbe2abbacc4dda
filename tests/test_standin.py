"""The robot stand-in (MuJoCo C, no JAX): its force filter and break, its task mirror, and its
trajectory against the MJX env's when its differences from training are switched off."""

import dataclasses
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from conftest import QUIET
from match_jax.transfer import export
from match_jax.envs.controllers import ControllerConfig
from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.transfer.standin import Episode, Perturbation, StandIn, StandInConfig, summarize, wilson_interval

RAM = np.array([0.0, 0.0, -1.0, 0.0])  # pose action: down at full speed


@pytest.fixture(scope="module")
def pose_description():
    return export.env_description(FPiHEnv(FPiHConfig(control="pose")))


def _on_the_rim(standin: StandIn) -> Episode:
    """The hole 10 mm to -x of the nominal spawn point: the peg lands on the block's top (+x rim)."""
    return Episode(hole_pos=np.array([0.54, 0.0, 0.0]), hole_yaw=0.0, peg_offset=np.zeros(3),
                   qpos=standin.home_qpos.copy(), hole_obs_offset=np.zeros(3))


def test_the_task_mirror_matches_the_training_task():
    env, law, standin = FPiHConfig(), ControllerConfig(), StandInConfig()
    for name in ("hole_xy", "hole_xy_range", "hole_yaw_range", "spawn_height", "spawn_min_clearance", "spawn_noise",
                 "hand_yaw_range", "success_radius", "success_height", "contact_threshold", "episode_steps"):
        assert getattr(standin, name) == getattr(env, name), name
    assert standin.peg_offset_range == env.randomization.peg_offset_range
    assert (standin.pos_stiffness,) * 3 == law.pos_stiffness and (standin.rot_stiffness,) * 3 == law.rot_stiffness
    assert standin.force_gain == law.force_gain and standin.null_stiffness == law.null_stiffness
    # the stand-in's law is the training default: Factory's J^T law, literal force term, gravity compensated
    assert not law.use_task_inertia and not law.force_feedforward and law.force_damping == (0.0, 0.0, 0.0)
    assert law.gravity_compensation
    assert StandInConfig().control_steps == 67 and StandInConfig.like_training().control_steps == 8
    with pytest.raises(ValueError, match="force_source.*'ft'"):
        StandInConfig(force_source="ft")
    with pytest.raises(ValueError, match="ema_alpha.*1.5"):
        StandInConfig(ema_alpha=1.5)


def test_filtered_force_and_the_break_on_a_scripted_ram(pose_description):
    """Ram onto the block top at 1 kHz: the filtered force is the EMA of the raw estimate, lags it at the
    impact, and the peg breaks on the first control step whose filtered |F| reaches the threshold."""
    config = StandInConfig(perturbation=Perturbation.none(), break_force=10.0)
    standin = StandIn(pose_description, config)
    result = standin.run(lambda obs: RAM, _on_the_rim(standin), record=True)
    raw, filtered = result["force_raw"], result["force_filtered"]
    expected = np.zeros(3)
    for k in range(len(raw)):
        expected = 0.08 * raw[k] + 0.92 * expected
        np.testing.assert_allclose(filtered[k], expected, atol=1e-9)
    raw_norm, filtered_norm = np.linalg.norm(raw, axis=1), np.linalg.norm(filtered, axis=1)
    assert result["broken"] and not result["success"]
    first = int(np.argmax(filtered_norm >= 10.0))
    assert first == len(filtered) - 1, "the trial ends on the break step"
    assert np.argmax(raw_norm >= 10.0) < first, "the raw estimate crosses first: the filter lags"
    assert raw_norm.max() > filtered_norm.max()
    assert raw[-1][2] < 0, "pressing down: the robot pushes on the environment along -z"
    # unbreakable: the impact's raw estimate (~50 N) is filtered to below the 20 N break, and the ram
    # settles at k_p x (target below the surface) = 2 N
    standin = StandIn(pose_description, dataclasses.replace(config, break_force=math.inf, episode_steps=45))
    settled = standin.run(lambda obs: RAM, _on_the_rim(standin), record=True)
    assert not settled["broken"]
    assert 1.5 < -settled["force"][-1][2] < 2.5 and 10.0 < settled["max_force_n"] < 20.0
    assert settled["energy_j"] > 0 and settled["mean_force_n"] > 1.0


def test_the_joint_torque_estimate_reads_what_the_wrist_sensor_reads(pose_description):
    """The same scripted ram with each force source (unfiltered, unbreakable; a Pose law does not feed the force
    back, so the trajectories are identical): the contact wrench estimated from the joint torques equals the
    tared wrist sensor's once the payload is still, and differs only in the impact transients."""
    results = {}
    for source in ("wrist", "joint_torque"):
        config = StandInConfig(perturbation=Perturbation.none(), break_force=math.inf, episode_steps=45,
                               ema_alpha=1.0, force_source=source)
        standin = StandIn(pose_description, config)
        results[source] = standin.run(lambda obs: RAM, _on_the_rim(standin), record=True)
    wrist, estimate = results["wrist"]["force_raw"], results["joint_torque"]["force_raw"]
    np.testing.assert_array_equal(results["wrist"]["ee_pos"], results["joint_torque"]["ee_pos"])
    np.testing.assert_allclose(estimate[-1], wrist[-1], atol=1e-3)
    assert -2.5 < estimate[-1][2] < -1.5, "settled on the block: k_p x (target below the surface) = 2 N, down"
    contact = np.linalg.norm(wrist, axis=1) > 1.0
    assert contact.sum() > 1000
    assert np.median(np.abs(estimate[contact] - wrist[contact]), axis=0).max() < 0.01


def test_a_hybrid_policys_force_selection_is_counted_per_axis_step():
    """Pressing down on the block top by position control counts in-contact axis-steps and no force selection;
    by force control on every axis, every axis-step is force-selected, in contact and free."""
    description = export.env_description(FPiHEnv(FPiHConfig(control="hybrid")))
    selection = description["action"]["selection_indices"]
    standin = StandIn(description, StandInConfig(perturbation=Perturbation.none(), break_force=math.inf,
                                                 episode_steps=30))
    by_position = np.array(description["action"]["neutral"], np.float32)
    by_position[selection] = 0.0
    by_position[5] = -1.0  # pos_z: down at full speed
    by_force = by_position.copy()
    by_force[selection] = 1.0
    by_force[8] = -0.25  # force_z: press down with 5 N
    counts = {}
    for name, action in (("position", by_position), ("force", by_force)):
        trial = standin.run(lambda obs, a=action: a.copy(), _on_the_rim(standin))
        counts[name] = summarize([trial, trial])["selection"]
    position, force = counts["position"], counts["force"]
    for rates in (position, force):
        assert rates["contact_axis_steps"] > 0 and rates["free_axis_steps"] > 0
        assert rates["contact_axis_steps"] + rates["free_axis_steps"] == 2 * 30 * 3
        assert 0 < rates["before_success_contact_axis_steps"] <= rates["contact_axis_steps"]
    # held on the rim, position control never succeeds: every axis-step is before success
    assert position["before_success_contact_axis_steps"] == position["contact_axis_steps"]
    assert position["force_selected_contact_per_axis"] == 0.0 and position["force_selected_free_per_axis"] == 0.0
    assert force["force_selected_contact_per_axis"] == 1.0 and force["force_selected_free_per_axis"] == 1.0
    pose = StandIn(export.env_description(FPiHEnv(FPiHConfig(control="pose"))), StandInConfig(episode_steps=2))
    assert pose.run(lambda obs: RAM, _on_the_rim(pose))["selection"] is None


def test_summary_intervals():
    lo, hi = wilson_interval(15, 30)
    assert lo < 0.5 < hi and hi - lo == pytest.approx(0.34, abs=0.01)
    rows = [{"success": s, "broken": False, "time_to_success_s": 1.0 if s else None, "mean_force_n": 2.0,
             "max_force_n": 5.0, "energy_j": 1.0} for s in (True, True, False, True)]
    summary = summarize(rows)
    assert summary["success_rate"] == 0.75 and summary["time_to_success_s"]["n"] == 3


def test_the_standin_process_runs_without_jax(pose_description, tmp_path):
    path = tmp_path / "description.json"
    path.write_text(json.dumps(pose_description))
    code = f"""
import json, sys, numpy as np
from match_jax.transfer.standin import StandIn, StandInConfig, Perturbation
d = json.load(open({str(path)!r}))
s = StandIn(d, StandInConfig(episode_steps=2))
r = s.run(lambda obs: np.zeros(4), s.sample_episode(np.random.default_rng(0), 2.5, "shell"))
assert not r["broken"], r
print("jax" in sys.modules, "jaxlib" in sys.modules)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"], out.stdout + out.stderr


@pytest.mark.slow
def test_without_its_differences_the_standin_reproduces_the_mjx_env(pose_description):
    """Training timing (law at 120 Hz), the wrist sensor, no filter, no perturbation, no delay: the
    stand-in's end-effector trajectory and force for the same actions equal the MJX env's: a move, a
    descent onto the block top, pressing, and lifting off."""
    import jax
    import jax.numpy as jnp

    env = FPiHEnv(FPiHConfig(control="pose", break_force=math.inf, **QUIET))
    actions = np.array([[0.5, 0.0, 0.0, 0.0]] * 5 + [[0.0, 0.0, -1.0, 0.0]] * 20 + [[0.0, 0.0, 0.5, 0.0]] * 5)

    def rollout(key):
        def body(state, action):
            state = env.step(state, action)
            d = state.pipeline_state
            return state, (d.site_xpos[env.ids.ee_site], state.info["ee_force"])
        state = env.reset(key)
        return state, jax.lax.scan(body, state, jnp.asarray(actions, jnp.float32))[1]

    start, (ee, force) = jax.jit(rollout)(jax.random.PRNGKey(0))
    ee, force = np.asarray(ee), np.asarray(force)
    standin = StandIn(pose_description, StandInConfig.like_training(episode_steps=len(actions)))
    episode = Episode(hole_pos=np.asarray(start.info["hole_pos"], np.float64), hole_yaw=float(start.info["hole_yaw"]),
                      peg_offset=np.zeros(3), qpos=np.asarray(start.pipeline_state.qpos, np.float64),
                      hole_obs_offset=np.zeros(3))
    step = iter(actions)
    result = standin.run(lambda obs: next(step), episode, record=True)
    assert not result["broken"]
    np.testing.assert_allclose(result["ee_pos"], ee, atol=5e-4)  # m
    assert np.abs(force[:, 2]).max() > 1.0, "the script presses on the block"
    np.testing.assert_allclose(result["force"], force, atol=0.5)  # N
