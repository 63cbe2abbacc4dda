"""MJX plumbing shared by the env, the tests and the benchmark: model loading, a physics step split
around the controller, arm dynamics and the peg's contact force.

One concept: how this project talks to MuJoCo-MJX. Nothing here knows about rewards or policies.
"""

from __future__ import annotations

import contextlib
import importlib.resources
import io

import jax
import jax.numpy as jnp
import mujoco

with contextlib.redirect_stdout(io.StringIO()):  # mujoco.mjx prints a notice when warp is absent
    from mujoco import mjx
    from mujoco.mjx._src import solver as _mjx_solver
    from mujoco.mjx._src import support as _mjx_support

from match_jax.controllers.osc import ArmDynamics

SCENE_FILE = "fpih_scene.xml"
ARM_JOINTS = 7


def scene_path() -> str:
    """Path of the packaged fPiH scene MJCF (installed as package data)."""
    return str(importlib.resources.files("match_jax") / "assets" / SCENE_FILE)


def load_model(physics_substeps: int = 1, control_dt: float = 1.0 / 120.0,
               path: str | None = None) -> mujoco.MjModel:
    """The C MuJoCo model of the scene (`path`, default the packaged one), timestep control_dt / physics_substeps (s)."""
    if not (isinstance(physics_substeps, int) and physics_substeps >= 1):
        raise ValueError(f"physics_substeps must be an integer >= 1, got {physics_substeps!r}")
    if not control_dt > 0:
        raise ValueError(f"control_dt must be > 0 s, got {control_dt!r}")
    path = path or scene_path()
    try:
        model = mujoco.MjModel.from_xml_path(path)
    except ValueError as err:
        raise ValueError(f"cannot load scene MJCF {path!r}: {err}") from None
    model.opt.timestep = control_dt / physics_substeps
    return model


class SceneIds:
    """Indices of the named objects of the scene in a model."""

    def __init__(self, model: mujoco.MjModel):
        self.ee_site = model.site("ee").id
        self.peg_tip_site = model.site("peg_tip").id
        self.hole_bottom_site = model.site("hole_bottom").id
        self.hole_top_site = model.site("hole_top").id
        self.hand_body = model.body("hand").id
        self.peg_body = model.body("peg").id
        self.hole_mocap = int(model.body("hole").mocapid[0])
        self.peg_geom = model.geom("peg").id
        self.peg_geoms = (self.peg_geom, model.geom("peg_rim_proxy").id)
        self.floor_geom = model.geom("floor").id


def arm_dynamics(m: mjx.Model, d: mjx.Data, ids: SceneIds, ee_force: jax.Array) -> ArmDynamics:
    """Controller inputs from `d` after fwd_position and fwd_velocity (world frame)."""
    ee_pos = d.site_xpos[ids.ee_site]
    jacp, jacr = mjx.jac(m, d, ee_pos, ids.hand_body)
    return ArmDynamics(
        qpos=d.qpos[:ARM_JOINTS],
        qvel=d.qvel[:ARM_JOINTS],
        mass_matrix=mjx.full_m(m, d),
        bias=d.qfrc_bias,
        jacobian=jnp.concatenate([jacp.T, jacr.T], axis=0),
        ee_pos=ee_pos,
        ee_rot=d.site_xmat[ids.ee_site],
        ee_force=ee_force,
    )


def peg_contact_force(m: mjx.Model, d: mjx.Data, peg_geoms: tuple[int, ...]) -> jax.Array:
    """Total force (N, world) the peg applies to the environment, from the last constraint solve.

    Every contact pair of the scene involves one of the peg's geoms `peg_geoms` (condim 3). A
    contact's force acts on geom2 along +frame^T f; MuJoCo may order a pair either way, so the sign
    follows which side the peg is on.
    Pressing down gives a negative z component.
    """
    forces, ids = _mjx_support.contact_force_dim(m, d, 3)
    contact = d._impl.contact
    frames = contact.frame[ids]
    on_env = jnp.where(jnp.isin(contact.geom[ids, 0], jnp.asarray(peg_geoms)), 1.0, -1.0)
    return jnp.einsum("c,ci,cij->j", on_env, forces[:, :3], frames)


def controlled_step(m: mjx.Model, d: mjx.Data, torque_fn) -> mjx.Data:
    """One mjx.step with the actuator controls computed from the freshly computed dynamics.

    Same stages as `mjx.step` (fwd_position, fwd_velocity, actuation, acceleration, constraint solve,
    integration); `torque_fn(d) -> ctrl` runs between velocity and actuation, so it sees the mass
    matrix, bias forces and site poses at the current state without a second forward pass.
    """
    d = mjx.fwd_position(m, d)
    d = mjx.fwd_velocity(m, d)
    d = d.replace(ctrl=torque_fn(d))
    d = mjx.fwd_actuation(m, d)
    d = mjx.fwd_acceleration(m, d)
    if d._impl.efc_J.size == 0:
        d = d.replace(qacc=d.qacc_smooth)
    else:
        d = _mjx_solver.solve(m, d)
    if m.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER:
        return mjx.euler(m, d)
    if m.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST:
        return mjx.implicit(m, d)
    raise ValueError(f"integrator {m.opt.integrator} is not supported by controlled_step")
