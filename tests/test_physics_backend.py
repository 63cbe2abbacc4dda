"""FPiHConfig.physics_backend: 'jax' (MJX) or 'warp' (MuJoCo Warp, the `warp` extra)."""

import copy
import dataclasses
import importlib.util
import pathlib
import types

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import QUIET

from match_jax.envs import sim
from match_jax.envs.controllers.osc import ArmDynamics, hybrid_torque
from match_jax.envs import FPiHConfig, FPiHEnv


def test_unknown_backend_is_rejected():
    with pytest.raises(ValueError, match=r"physics_backend must be one of \('jax', 'warp'\), got 'cuda'") as err:
        FPiHConfig(physics_backend="cuda")
    assert "\n" not in str(err.value)


@pytest.mark.skipif(importlib.util.find_spec("warp") is not None, reason="warp is installed")
def test_warp_backend_without_warp_says_how_to_install():
    with pytest.raises(ImportError, match=r'pip install "match_jax\[warp\]"') as err:
        FPiHEnv(FPiHConfig(physics_backend="warp"))
    assert "\n" not in str(err.value)


def test_training_env_must_use_the_methods_controller():
    from match_jax.training.presets import get_preset
    from match_jax.training.runs import make_env

    with pytest.raises(ValueError, match="method 'match' needs control='hybrid', env has 'pose'") as err:
        make_env(get_preset("tiny", method="match"), FPiHConfig(control="pose"))
    assert "\n" not in str(err.value)


def test_warp_batches_step_on_one_device_with_a_contact_buffer_for_all_worlds():
    """MuJoCo Warp: no env sharding, and the env config's shared contact buffer sized for the whole batch
    (every seed's envs step together); MJX-JAX configs are left as they are."""
    from match_jax.training.runs import batch_mesh, sized_for_batch

    assert batch_mesh(128, "warp") is None
    jax_config = FPiHConfig(control="pose")
    assert sized_for_batch(jax_config, 384) is jax_config
    warp_config = sized_for_batch(FPiHConfig(control="pose", physics_backend="warp"), 384)
    assert warp_config.warp_worlds == 384 and sim.warp_naconmax(384) == 384 * sim.WARP_CONTACTS_PER_WORLD
    assert sim.warp_naconmax(1) == sim.WARP_MIN_NACONMAX
    with pytest.raises(ValueError, match="warp_worlds must be an integer >= 1, got 0"):
        FPiHConfig(warp_worlds=0)


def test_seed_axes_merge_and_split_around_per_batch_leaves(monkeypatch):
    """The trainer steps (seeds, envs) worlds as one batch: leaves with a world axis merge seeds x envs;
    MuJoCo Warp's once-per-batch leaves (no world axis, one copy per seed) pass the first copy to the
    step and come back as one copy per seed."""
    from match_jax.rl import ppo

    data = {"qpos": jnp.arange(2 * 3 * 4.0).reshape(2, 3, 4), "contact": jnp.stack([jnp.arange(10.0)] * 2),
            "nacon": jnp.array([[5], [5]])}
    monkeypatch.setattr(sim, "world_axis_leaves", lambda d: {"qpos": True, "contact": False, "nacon": False})
    merged = ppo._merge_seeds(data, (2, 3))
    assert merged["qpos"].shape == (6, 4) and np.array_equal(merged["qpos"][3], data["qpos"][1, 0])
    assert merged["contact"].shape == (10,) and merged["nacon"].shape == (1,)
    split = ppo._split_seeds(merged, data)
    for key in data:
        assert split[key].shape == data[key].shape and np.array_equal(split[key], data[key]), key


@pytest.mark.skipif(importlib.util.find_spec("warp") is not None, reason="warp is installed")
def test_train_on_warp_without_warp_is_a_one_line_error(capsys):
    import train

    with pytest.raises(SystemExit):
        train.parse_args(["--method", "pose", "--physics-backend", "warp", "--out", "/tmp/unused"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith('--physics-backend warp needs NVIDIA Warp: pip install "match_jax[warp]"')


@pytest.mark.skipif(importlib.util.find_spec("warp") is not None, reason="warp is installed")
def test_a_warp_run_loads_its_policies_on_mjx_jax_without_warp(tmp_path):
    """A run trained on Warp (here: the shipped Pose actors, relabelled) evaluates on MJX-JAX on a
    machine without Warp: its policies do not depend on the physics backend."""
    import json
    import shutil

    from match_jax.training.runs import load_policies, load_spec

    shipped = pathlib.Path(__file__).parents[1] / "results" / "authors_task" / "runs" / "pose"
    run_dir = shutil.copytree(shipped, tmp_path / "pose_on_warp")
    config = json.loads((run_dir / "config.json").read_text())
    config["env"]["physics_backend"] = "warp"
    (run_dir / "config.json").write_text(json.dumps(config))
    assert load_spec(run_dir).env.physics_backend == "warp"
    with pytest.raises(ImportError, match="needs NVIDIA Warp"):
        load_policies(run_dir)
    run, policies = load_policies(run_dir, physics_backend="jax")
    assert run.env.config.physics_backend == "jax" and len(policies) == 3
    _, own = load_policies(shipped)
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(policies),
                                                    jax.tree_util.tree_leaves(own)))


# Pose control from the spawn pose: 3 policy steps sideways, then down at a_z = -0.5 (target 1 cm below
# the end effector): free space until step 16, then the peg lands on the hole block's rim 6.8 mm
# (world 0) and 6.6 mm (world 1) off the bore axis (a ~35 N impact) and presses on it with ~1 N.
LATERAL = ((-0.3, 0.0), (0.0, 0.45))
STEPS = 30
# The peg's summed contact force is the force signal here ("force"), as MuJoCo C computes it. Largest
# differences measured over both worlds (CPU, jax 0.10.2, mujoco 4.0.1, mujoco-mjx 3.17.0, warp-lang
# 1.18.0), rigid peg, between any two of MJX-JAX, MJX-Warp and MuJoCo C: peg tip 0.96 um, joint angles
# 5.8e-6 rad, force 0.010 N, peak force 0.015 N. With the peg moved in the hand, Warp and C as close
# (0.89 um, 2.9e-6 rad, 0.004 N, 0.016 N), while MJX-JAX parts from both after the impact (31 um,
# 1.2e-4 rad, 0.19 N, 1.1 N peak). TOL leaves ~5x room; a force of the wrong sign is off by ~2 N in contact.
TOL = {"tip": 5e-6, "qpos": 5e-5, "force": 0.05, "max_force": 0.05}
JAX_MOVED_PEG_TOL = {"tip": 1e-4, "qpos": 4e-4, "force": 0.6, "max_force": 3.0}
CONTACT_SIGNAL = dict(force_sensor="peg_contact", observe_torque=False)


def _actions() -> np.ndarray:
    actions = np.zeros((len(LATERAL), STEPS, 4), np.float32)
    actions[:, :3, :2] = np.asarray(LATERAL, np.float32)[:, None]
    actions[:, 3:, 2] = -0.5
    return actions


def _rollout(env: FPiHEnv, actions: np.ndarray) -> dict[str, np.ndarray]:
    """jit(vmap) reset from PRNGKey(0) and STEPS env steps; per step: tip, qpos, force, max |F|."""

    @jax.jit
    def run(actions):
        state = jax.vmap(env.reset)(jnp.stack([jax.random.PRNGKey(0)] * len(LATERAL)))

        def body(state, action):
            state = jax.vmap(env.step)(state, action)
            d = state.pipeline_state
            return state, {"tip": d.site_xpos[:, env.ids.peg_tip_site], "qpos": d.qpos,
                           "force": state.info["ee_force"], "max_force": state.info["max_force"]}

        return jax.lax.scan(body, state, jnp.swapaxes(actions, 0, 1))[1]

    return {k: np.swapaxes(np.asarray(v), 0, 1) for k, v in run(jnp.asarray(actions)).items()}


def _c_peg_force(model, d, peg_geoms) -> np.ndarray:
    """`sim.peg_contact_force` in MuJoCo C: the force (N, world) the peg applies to the environment."""
    total, wrench = np.zeros(3), np.zeros(6)
    for i in range(d.ncon):
        mujoco.mj_contactForce(model, d, i, wrench)
        on_env = 1.0 if d.contact[i].geom1 in peg_geoms else -1.0
        total += on_env * d.contact[i].frame.reshape(3, 3).T @ wrench[:3]
    return total


def _rollout_c(env: FPiHEnv, actions: np.ndarray) -> dict[str, np.ndarray]:
    """The same episodes in MuJoCo C (float64): the env's targets and control law, C dynamics on the
    model the env's reset drew (its per-env model fields, e.g. the peg's place in the hand), the peg's
    force summed over C's contacts."""
    s0 = jax.jit(env.reset)(jax.random.PRNGKey(0))
    model = copy.deepcopy(env.mj_model)
    for name, value in s0.info["model"].items():
        getattr(model, name)[:] = np.asarray(value, np.float64)
    ids, low, high = env.ids, model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    target_fn = jax.jit(lambda site_xpos, site_xmat, info, action: env._control_target(
        types.SimpleNamespace(site_xpos=site_xpos, site_xmat=site_xmat), info, env._smooth(action, info["prev_action"])))
    smooth_fn = jax.jit(env._smooth)
    torque_fn = jax.jit(lambda dyn, target: jnp.clip(hybrid_torque(dyn, target, env.config.controller), low, high))
    out = {"tip": [], "qpos": [], "force": [], "max_force": []}
    for episode in actions:
        d = mujoco.MjData(model)
        d.qpos[:] = np.asarray(s0.pipeline_state.qpos)
        d.mocap_pos[:], d.mocap_quat[:] = np.asarray(s0.pipeline_state.mocap_pos), np.asarray(s0.pipeline_state.mocap_quat)
        mujoco.mj_kinematics(model, d)
        info, force = dict(s0.info), np.zeros(3)
        for series in out.values():
            series.append([])
        for action in episode:
            target = target_fn(d.site_xpos.copy(), d.site_xmat.reshape(-1, 3, 3).copy(), info, action)
            info["prev_action"] = smooth_fn(action, info["prev_action"])
            max_force = 0.0
            for _ in range(env.config.control_substeps):
                mujoco.mj_forward(model, d)
                jacp, jacr, mass = np.zeros((3, model.nv)), np.zeros((3, model.nv)), np.zeros((model.nv, model.nv))
                mujoco.mj_jac(model, d, jacp, jacr, d.site_xpos[ids.ee_site], ids.hand_body)
                mujoco.mj_fullM(model, d, mass)
                dyn = ArmDynamics(qpos=d.qpos[:sim.ARM_JOINTS].copy(), qvel=d.qvel[:sim.ARM_JOINTS].copy(),
                                  mass_matrix=mass, bias=d.qfrc_bias.copy(), jacobian=np.vstack([jacp, jacr]),
                                  ee_pos=d.site_xpos[ids.ee_site].copy(),
                                  ee_rot=d.site_xmat[ids.ee_site].reshape(3, 3).copy(), ee_force=force)
                d.ctrl[:] = np.asarray(torque_fn(dyn, target))
                mujoco.mj_step(model, d)
                force = _c_peg_force(model, d, ids.peg_geoms)
                max_force = max(max_force, float(np.linalg.norm(force)))
            mujoco.mj_kinematics(model, d)
            for key, value in (("tip", d.site_xpos[ids.peg_tip_site].copy()), ("qpos", d.qpos.copy()),
                               ("force", force), ("max_force", max_force)):
                out[key][-1].append(value)
    return {k: np.asarray(v) for k, v in out.items()}


@pytest.mark.slow
@pytest.mark.parametrize("peg", ["rigid", "moved_in_hand"])
def test_warp_backend_matches_jax_backend_and_mujoco_c(peg):
    """Scripted descents on the three physics: Warp against MuJoCo C within TOL, rigid peg or moved in the
    hand (the per-env model randomisation: a batched body_pos, applied to C's model as drawn); MJX-JAX
    within TOL with the rigid peg, within JAX_MOVED_PEG_TOL with the moved one."""
    pytest.importorskip("warp")
    quiet = QUIET if peg == "rigid" else {k: v for k, v in QUIET.items() if k != "randomization"}
    actions = _actions()
    config = FPiHConfig(control="pose", **CONTACT_SIGNAL, **quiet)
    jax_env = FPiHEnv(config)
    runs = {"jax": _rollout(jax_env, actions),
            "warp": _rollout(FPiHEnv(dataclasses.replace(config, physics_backend="warp")), actions),
            "c": _rollout_c(jax_env, actions)}
    if peg == "moved_in_hand":
        assert np.abs(np.asarray(jax.jit(jax_env.reset)(jax.random.PRNGKey(0)).info["model"]["body_pos"])
                      - jax_env.mj_model.body_pos).max() > 1e-4  # the peg did move in the hand

    # The scenario: free space, then an impact and a steady press on the block (pressing down: F_z < 0).
    for name, run in runs.items():
        contact = run["max_force"] > 0.1
        assert not contact[:, :16].any() and contact[:, 16:].all(), name
        assert (run["max_force"][:, 16] > 5.0).all(), name
        np.testing.assert_array_less(run["force"][:, 20:, 2], -0.5, err_msg=name)
    for a, b in (("warp", "c"), ("warp", "jax"), ("jax", "c")):
        tolerances = TOL if peg == "rigid" or "jax" not in (a, b) else JAX_MOVED_PEG_TOL
        for key, tol in tolerances.items():
            for phase, steps in (("free", slice(0, 16)), ("contact", slice(16, None))):
                diff = np.abs(runs[a][key][:, steps] - runs[b][key][:, steps]).max()
                assert diff <= tol, f"{a} vs {b}, {phase}: max |d {key}| = {diff:.3g} > {tol}"


@pytest.mark.slow
def test_training_on_warp_checkpoints_resumes_and_evaluates(tmp_path):
    """A tiny MATCH run on MuJoCo Warp (the authors' task: in-hand peg offsets, wrist sensor), 2 seeds in
    one program: trains a chunk, resumes to a larger budget from its checkpoint, and evaluates on Warp and
    on the JAX backend."""
    pytest.importorskip("warp")
    from match_jax.training.evaluation import evaluate_run
    from match_jax.training.presets import get_preset
    from match_jax.training.runs import RunSpec, read_metrics, train

    spec = RunSpec(ppo=get_preset("tiny", method="match"), env=FPiHConfig(control="hybrid", physics_backend="warp"),
                   num_seeds=2)
    run_dir = tmp_path / "warp_run"
    first = train(spec, run_dir, max_chunks=1, progress=False)
    assert first["iterations"] == 1 and not first["finished"]
    again = train(None, run_dir, resume=True, total_steps=128, progress=False)
    assert again["iterations"] == 4 and again["finished"]
    rows = read_metrics(run_dir)
    assert sorted({(r["iteration"], r["seed_index"]) for r in rows}) == [(i, s) for i in range(1, 5) for s in (0, 1)]
    assert all(np.isfinite(r["loss"]) for r in rows)
    for backend in ("warp", "jax"):
        result = evaluate_run(run_dir, episodes=4, physics_backend=backend)
        assert result["seeds"] == 2 and 0.0 <= result["aggregate"]["success_rate"]["mean"] <= 1.0, backend
