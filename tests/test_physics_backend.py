"""FPiHConfig.physics_backend: 'jax' (MJX) or 'warp' (MuJoCo Warp, the `warp` extra)."""

import importlib.util
import types

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import QUIET

from match_jax import sim
from match_jax.controllers.osc import ArmDynamics, hybrid_torque
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


def test_training_on_warp_is_a_one_line_error():
    from match_jax.ppo import make_env
    from match_jax.presets import get_preset

    with pytest.raises(ValueError, match="training runs on physics_backend 'jax', got 'warp'") as err:
        make_env(get_preset("tiny", method="pose"), FPiHConfig(control="pose", physics_backend="warp"))
    assert "\n" not in str(err.value)


# Pose control from the spawn pose: 3 policy steps sideways, then down at a_z = -0.5 (target 1 cm below
# the end effector): free space until step 16, then the peg lands on the hole block's rim 6.8 mm
# (world 0) and 6.6 mm (world 1) off the bore axis (a ~35 N impact) and presses on it with ~1 N.
LATERAL = ((-0.3, 0.0), (0.0, 0.45))
STEPS = 30
# Largest differences measured over both worlds, between any two of MJX-JAX, MJX-Warp and MuJoCo C
# (CPU, jax 0.10.2, mujoco 4.0.0, mujoco-mjx 3.17.0, warp-lang 1.18.0): peg tip 0.72 um, joint angles
# 4.5e-6 rad, force reading 0.009 N, peak force 0.009 N. The tolerances leave ~5x room; a force with the
# wrong sign would be off by ~2 N in contact.
TOL = {"tip": 5e-6, "qpos": 5e-5, "force": 0.05, "max_force": 0.05}


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
    """The same episodes in MuJoCo C (float64): the env's targets and control law, C dynamics, the peg's
    force summed over C's contacts."""
    model = env.mj_model
    ids, low, high = env.ids, model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    s0 = jax.jit(env.reset)(jax.random.PRNGKey(0))
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
def test_warp_backend_matches_jax_backend_and_mujoco_c():
    pytest.importorskip("warp")
    actions = _actions()
    config = FPiHConfig(control="pose", **QUIET)
    jax_env = FPiHEnv(config)
    runs = {"jax": _rollout(jax_env, actions),
            "warp": _rollout(FPiHEnv(FPiHConfig(control="pose", physics_backend="warp", **QUIET)), actions),
            "c": _rollout_c(jax_env, actions)}

    # The scenario: free space, then an impact and a steady press on the block (pressing down: F_z < 0).
    for name, run in runs.items():
        contact = run["max_force"] > 0.1
        assert not contact[:, :16].any() and contact[:, 16:].all(), name
        assert (run["max_force"][:, 16] > 5.0).all(), name
        np.testing.assert_array_less(run["force"][:, 20:, 2], -0.5, err_msg=name)
    for a, b in (("warp", "jax"), ("warp", "c"), ("jax", "c")):
        for key, tol in TOL.items():
            for phase, steps in (("free", slice(0, 16)), ("contact", slice(16, None))):
                diff = np.abs(runs[a][key][:, steps] - runs[b][key][:, steps]).max()
                assert diff <= tol, f"{a} vs {b}, {phase}: max |d {key}| = {diff:.3g} > {tol}"
