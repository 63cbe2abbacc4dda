"""Control laws against independent numpy computations on MuJoCo C's dynamics."""

import mujoco
import numpy as np
import pytest

from match_jax.envs.controllers import ArmDynamics, ControllerConfig, ControlTarget, hybrid_torque


def _c_dynamics(env, data, ee_force=np.zeros(3)):
    model = env.mj_model
    mujoco.mj_forward(model, data)
    jacp, jacr = np.zeros((3, 7)), np.zeros((3, 7))
    mujoco.mj_jacSite(model, data, jacp, jacr, env.ids.ee_site)
    mass = np.zeros((7, 7))
    mujoco.mj_fullM(model, data, mass)
    return ArmDynamics(qpos=data.qpos.copy(), qvel=data.qvel.copy(), mass_matrix=mass, bias=data.qfrc_bias.copy(),
                       jacobian=np.vstack([jacp, jacr]), ee_pos=data.site_xpos[env.ids.ee_site].copy(),
                       ee_rot=data.site_xmat[env.ids.ee_site].reshape(3, 3).copy(), ee_force=ee_force)


def _home(env, qvel=None):
    data = mujoco.MjData(env.mj_model)
    data.qpos[:] = env.home_qpos
    if qvel is not None:
        data.qvel[:] = qvel
    data.mocap_pos[0] = (0.55, 0.0, -1.0)  # hole out of the way: free space
    return data


def _target(dyn, pos, axes=(1.0, 1.0, 1.0), force=(0.0, 0.0, 0.0), kp=100.0, posture=None):
    return ControlTarget(pos=np.asarray(pos), rot=dyn.ee_rot, force=np.asarray(force), position_axes=np.asarray(axes),
                         pos_stiffness=np.full(3, kp), posture=dyn.qpos if posture is None else posture)


def _rotvec_error(rot, rot_target):
    """Rotation vector of rot_target rot^T (exact, via the matrix logarithm)."""
    rel = rot_target @ rot.T
    angle = np.arccos(np.clip((np.trace(rel) - 1) / 2, -1, 1))
    if angle < 1e-9:
        return np.zeros(3)
    axis = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]]) / (2 * np.sin(angle))
    return angle * axis


@pytest.mark.parametrize("use_task_inertia", [False, True])
def test_pose_law_equals_formula(env, use_task_inertia):
    """u = J^T [k_p (x_d - x) - k_d xdot] + g(q) + null-space term (Factory, default), or with M_x in
    front of the bracket (the paper's equation), computed here with numpy."""
    rng = np.random.default_rng(0)
    data = _home(env, qvel=rng.normal(0, 0.2, 7))
    dyn = _c_dynamics(env, data)
    config = ControllerConfig(use_task_inertia=use_task_inertia)
    target = _target(dyn, dyn.ee_pos + np.array([0.01, -0.02, 0.015]))
    rot_target = dyn.ee_rot @ np.array([[np.cos(0.05), -np.sin(0.05), 0], [np.sin(0.05), np.cos(0.05), 0], [0, 0, 1]])
    target = ControlTarget(**{**target.__dict__, "rot": rot_target, "posture": dyn.qpos + 0.1})

    jac, mass = dyn.jacobian, dyn.mass_matrix
    mx = np.linalg.inv(jac @ np.linalg.solve(mass, jac.T))
    xdot = jac @ dyn.qvel
    kp = np.array([100.0] * 3 + [30.0] * 3)
    err = np.concatenate([target.pos - dyn.ee_pos, _rotvec_error(dyn.ee_rot, rot_target)])
    task = kp * err - 2 * np.sqrt(kp) * xdot
    if use_task_inertia:
        task = mx @ task
    posture_torque = mass @ (10.0 * (target.posture - dyn.qpos) - 2 * np.sqrt(10.0) * dyn.qvel)
    jbar = np.linalg.solve(mass, jac.T) @ mx
    null = (np.eye(7) - jac.T @ jbar.T) @ posture_torque
    expected = jac.T @ task + dyn.bias + null

    got = np.asarray(hybrid_torque(dyn, target, config))
    # the law uses the small-angle rotation error 0.5 sum e_i x e_d,i (exact to O(angle^3)).
    np.testing.assert_allclose(got, expected, rtol=2e-3, atol=2e-3)


def test_hybrid_law_force_axes(env):
    """Force-selected axes: u_task = [pose on position axes] + k_f (f_d - f) + f_d (default)."""
    data = _home(env)
    dyn = _c_dynamics(env, data, ee_force=np.array([0.0, 0.0, -2.0]))
    config = ControllerConfig().with_force_law("damped")  # feed-forward and damping terms
    target = _target(dyn, dyn.ee_pos + 0.01, axes=(1.0, 1.0, 0.0), force=(0.0, 0.0, -5.0))
    pose_only = _target(dyn, dyn.ee_pos + 0.01, axes=(1.0, 1.0, 0.0), force=(0.0, 0.0, 0.0))
    # the difference of two commands isolates the force term: J^T [0, 0, k_f (f_d - 0) + f_d, 0, 0, 0]
    diff = np.asarray(hybrid_torque(dyn, target, config)) - np.asarray(hybrid_torque(dyn, pose_only, config))
    expected = dyn.jacobian.T @ np.array([0, 0, 0.5 * (-5.0) + (-5.0), 0, 0, 0])
    np.testing.assert_allclose(diff, expected, rtol=1e-5, atol=1e-6)
    # the paper's literal law multiplies the force term by M_x and has no feedforward
    literal = ControllerConfig(use_task_inertia=True, force_through_task_inertia=True, force_feedforward=False)
    diff = np.asarray(hybrid_torque(dyn, target, literal)) - np.asarray(hybrid_torque(dyn, pose_only, literal))
    mx = np.linalg.inv(dyn.jacobian @ np.linalg.solve(dyn.mass_matrix, dyn.jacobian.T))
    np.testing.assert_allclose(diff, dyn.jacobian.T @ (mx @ np.array([0, 0, 0.5 * -5.0, 0, 0, 0])), rtol=1e-4, atol=1e-5)


def _simulate(env, config, target_fn, steps):
    """C MuJoCo at 120 Hz with the law in the loop; returns the EE positions and velocities."""
    data = _home(env)
    positions, velocities = [], []
    for _ in range(steps):
        dyn = _c_dynamics(env, data)
        data.ctrl[:] = np.clip(np.asarray(hybrid_torque(dyn, target_fn(dyn), config)), -87, 87)
        data.ctrl[4:] = np.clip(data.ctrl[4:], -12, 12)
        mujoco.mj_step(env.mj_model, data)
        mujoco.mj_forward(env.mj_model, data)
        positions.append(data.site_xpos[env.ids.ee_site].copy())
        jacp = np.zeros((3, 7))
        mujoco.mj_jacSite(env.mj_model, data, jacp, None, env.ids.ee_site)
        velocities.append(jacp @ data.qvel)
    return np.array(positions), np.array(velocities)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_pose_step_with_task_inertia_converges_without_overshoot(env, axis):
    """Paper's law (M_x, critically damped per unit mass): a 2 cm step of the position target is within
    5 % after 1 s, overshoots below 5 % (1 mm), and is within 1 % after 2 s."""
    start = _c_dynamics(env, _home(env)).ee_pos
    goal = start.copy()
    goal[axis] += 0.02
    posture = np.array(env.home_qpos)
    config = ControllerConfig(use_task_inertia=True)
    positions, _ = _simulate(env, config, lambda dyn: _target(dyn, goal, posture=posture), 240)
    progress = (positions[:, axis] - start[axis]) / 0.02
    assert abs(progress[120] - 1.0) < 0.05, f"after 1 s: {progress[120]:.3f} of the step"
    assert progress.max() < 1.05, f"overshoot {100 * (progress.max() - 1):.1f} %"
    assert abs(progress[-1] - 1.0) < 0.01


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_pose_step_factory_law_is_underdamped_and_settles(env, axis):
    """Factory's law (default: k_p = 100 N/m, k_d = 2 sqrt(k_p) N s/m on the arm's 2-6 kg task inertia,
    damping ratio 1 / sqrt(M) < 1): a 2 cm step overshoots by 10-35 % and is within 2 % after 5 s."""
    start = _c_dynamics(env, _home(env)).ee_pos
    goal = start.copy()
    goal[axis] += 0.02
    posture = np.array(env.home_qpos)
    positions, _ = _simulate(env, ControllerConfig(), lambda dyn: _target(dyn, goal, posture=posture), 600)
    progress = (positions[:, axis] - start[axis]) / 0.02
    assert 1.10 < progress.max() < 1.35, f"overshoot {100 * (progress.max() - 1):.1f} %"
    assert abs(progress[-1] - 1.0) < 0.02, f"after 5 s: {progress[-1]:.3f} of the step"


def test_free_space_force_selection_accelerates(env):
    """The paper's law (no damping on force axes) in free space (f_ee = 0, f_d = -5 N): z speed keeps
    growing, unlike position control with the same downward command, which settles (the reason for
    the selection loss)."""
    start = _c_dynamics(env, _home(env)).ee_pos
    posture = np.array(env.home_qpos)
    steps = 20  # 0.17 s: the peg tip starts 4 cm above the table and must not reach it
    paper_law = ControllerConfig(use_task_inertia=True, force_feedforward=True, force_damping=(0.0, 0.0, 0.0))
    pos_force, vel_force = _simulate(env, paper_law, lambda dyn: _target(
        dyn, start, axes=(1.0, 1.0, 0.0), force=(0.0, 0.0, -5.0), posture=posture), steps)
    _, vel_pos = _simulate(env, paper_law, lambda dyn: _target(
        dyn, dyn.ee_pos - np.array([0, 0, 0.004]), posture=posture), steps)
    assert pos_force[-1, 2] > start[2] - 0.035, "the test must stay in free space"
    speed_force = -vel_force[:, 2]
    assert np.all(np.diff(speed_force[3:]) > 0), "free-space force control must keep accelerating"
    assert speed_force[-1] > 5.0 * -vel_pos[-1, 2], (speed_force[-1], vel_pos[-1, 2])
    assert speed_force[-1] > 0.15  # m/s after 0.17 s: 30x the ~5 mm/s that is safe at contact


@pytest.mark.parametrize("use_task_inertia", [False, True])
def test_force_axis_damping_bounds_free_space_speed(env, use_task_inertia):
    """Force-axis damping k_vf = 20 of the damped law (N s/m on Factory's law; 1/s through M_x on the paper's):
    free-space force selection still drives the arm, but toward a terminal speed instead of accelerating
    without bound. Closed loop along z: zddot = a_F - k zdot, so v(t) = (a_F / k) (1 - exp(-k t)); on the
    M_x law the task space is decoupled: a_F = (M_x^-1)_zz |F|, k = k_vf; on Factory's law the held x, y
    and rotation leave z the inertia (M_x)_zz: a_F = |F| / (M_x)_zz, k = k_vf / (M_x)_zz."""
    start_dyn = _c_dynamics(env, _home(env))
    posture = np.array(env.home_qpos)
    config = ControllerConfig(use_task_inertia=use_task_inertia).with_force_law("damped")
    assert config.force_damping[2] == 20.0
    force = -5.0 * (1.0 + config.force_gain)  # task force on the axis in free space (feedforward + P)
    mx_inv = start_dyn.jacobian @ np.linalg.solve(start_dyn.mass_matrix, start_dyn.jacobian.T)
    inertia_z = 1.0 / mx_inv[2, 2] if use_task_inertia else np.linalg.inv(mx_inv)[2, 2]  # kg
    accel = abs(force) / inertia_z  # m/s^2
    rate = config.force_damping[2] / (1.0 if use_task_inertia else inertia_z)  # 1/s
    steps = 30
    expected = accel / rate * (1.0 - np.exp(-rate * np.arange(1, steps + 1) / 120.0))  # m/s
    _, vel = _simulate(env, config, lambda dyn: _target(
        dyn, start_dyn.ee_pos, axes=(1.0, 1.0, 0.0), force=(0.0, 0.0, -5.0), posture=posture), steps)
    speed = -vel[:, 2]
    assert speed[3] > 0.5 * expected[3], "force selection must still move the arm"
    assert speed.max() < 1.3 * accel / rate, (speed.max(), accel / rate)
    assert abs(speed[-1] - expected[-1]) < 0.25 * expected[-1], (speed[-1], expected[-1])


def test_controller_config_rejects_bad_values():
    with pytest.raises(ValueError, match="force_gain"):
        ControllerConfig(force_gain=-1.0)
    with pytest.raises(ValueError, match="force_damping"):
        ControllerConfig(force_damping=(1.0, 1.0, -1.0))
    with pytest.raises(ValueError, match="pos_stiffness"):
        ControllerConfig(pos_stiffness=(1.0, 2.0))


def test_action_config_force_z_and_its_inverse():
    from match_jax.envs.controllers import ActionConfig

    actions = ActionConfig()
    for a in (-1.0, -0.3, 0.0, 1.0):
        assert actions.force_z_action(actions.force_z(a)) == pytest.approx(a)
    assert actions.force_z(1.0) == 0.0 and actions.force_z(-1.0) == -20.0  # (-20, 0) N
    assert actions.stiffness(-1.0) == 0.0 and actions.stiffness(1.0) == 200.0


def test_with_force_law_switches_feedforward_and_damping_only():
    damped = ControllerConfig(pos_stiffness=(50.0, 50.0, 50.0)).with_force_law("damped")
    assert damped.force_feedforward and damped.force_damping == (20.0, 20.0, 20.0)
    literal = damped.with_force_law("literal")
    assert not literal.force_feedforward and literal.force_damping == (0.0, 0.0, 0.0)
    assert literal == ControllerConfig(pos_stiffness=(50.0, 50.0, 50.0))  # the default: the authors' law
    with pytest.raises(ValueError, match="'Literal'"):
        ControllerConfig().with_force_law("Literal")
