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
import numpy as np

with contextlib.redirect_stdout(io.StringIO()):  # mujoco.mjx prints a notice when warp is absent
    from mujoco import mjx
    from mujoco.mjx import warp as _mjx_warp
    from mujoco.mjx._src import solver as _mjx_solver
    from mujoco.mjx._src import support as _mjx_support

from match_jax.envs.controllers.osc import ArmDynamics

SCENE_FILE = "fpih_scene.xml"
ARM_JOINTS = 7
PHYSICS_BACKENDS = ("jax", "warp")
# MuJoCo Warp's buffer sizes. Broadphase pairs and contacts: one buffer of naconmax for all the worlds
# of a batch together (`warp_naconmax`); one world of this scene peaked at 8 pairs and 4 contacts
# (MuJoCo Warp's own allowance for it: 48). Constraint rows: njmax per world (peak 16). On overflow
# MuJoCo Warp prints a warning and drops the excess.
WARP_CONTACTS_PER_WORLD = 8
WARP_MIN_NACONMAX = 256
WARP_NJMAX = 256
PEG_FORCE_SENSORS = ("peg_force", "peg_rim_proxy_force")


def scene_path() -> str:
    """Path of the packaged fPiH scene MJCF (installed as package data)."""
    return str(importlib.resources.files("match_jax") / "envs" / "assets" / SCENE_FILE)


def load_model(physics_substeps: int = 1, control_dt: float = 1.0 / 120.0,
               path: str | None = None, physics_backend: str = "jax") -> mujoco.MjModel:
    """The C MuJoCo model of the scene (`path`, default the packaged one), timestep control_dt / physics_substeps (s).

    For physics_backend 'warp' it also carries the peg's contact-force sensors (`add_peg_force_sensors`).
    """
    if not (isinstance(physics_substeps, int) and physics_substeps >= 1):
        raise ValueError(f"physics_substeps must be an integer >= 1, got {physics_substeps!r}")
    if not control_dt > 0:
        raise ValueError(f"control_dt must be > 0 s, got {control_dt!r}")
    path = path or scene_path()
    try:
        if physics_backend == "warp":
            model = add_peg_force_sensors(mujoco.MjSpec.from_file(path)).compile()
        else:
            model = mujoco.MjModel.from_xml_path(path)
    except ValueError as err:
        raise ValueError(f"cannot load scene MJCF {path!r}: {err}") from None
    model.opt.timestep = control_dt / physics_substeps
    return model


def add_peg_force_sensors(spec: mujoco.MjSpec) -> mujoco.MjSpec:
    """Adds PEG_FORCE_SENSORS to `spec`: per peg geom, the net force (N, world) of its contacts.

    Same as `<contact geom1="..." data="force" reduce="netforce" num="1"/>`: intprm = (data bit of
    'force', reduce 'netforce', num). MJX's JAX backend does not support this sensor type.
    """
    for name, geom in zip(PEG_FORCE_SENSORS, ("peg", "peg_rim_proxy")):
        spec.add_sensor(name=name, type=mujoco.mjtSensor.mjSENS_CONTACT, objtype=mujoco.mjtObj.mjOBJ_GEOM,
                        objname=geom, intprm=[2, 3, 1])
    return spec


WARP_MISSING = 'needs NVIDIA Warp: pip install "match_jax[warp]"'


def warp_installed() -> bool:
    """Whether MuJoCo Warp can run here (the `warp` extra)."""
    return bool(_mjx_warp.WARP_INSTALLED)


def put_model(model: mujoco.MjModel, physics_backend: str = "jax") -> mjx.Model:
    """The MJX model of `model` for physics_backend 'jax' (MJX in JAX) or 'warp' (MuJoCo Warp)."""
    if physics_backend == "jax":
        return mjx.put_model(model)
    if physics_backend != "warp":
        raise ValueError(f"physics_backend must be one of {PHYSICS_BACKENDS}, got {physics_backend!r}")
    if not warp_installed():
        raise ImportError(f'physics_backend="warp" {WARP_MISSING}')
    return mjx.put_model(model, impl="warp")


def warp_naconmax(worlds: int) -> int:
    """MuJoCo Warp's contact buffer for a batch of `worlds` worlds (one buffer for all of them)."""
    return max(WARP_MIN_NACONMAX, WARP_CONTACTS_PER_WORLD * int(worlds))


def make_data(model: mujoco.MjModel, m: mjx.Model, warp_worlds: int = 1) -> mjx.Data:
    """Fresh MJX data of the C model `model` for its MJX model `m` (either backend).

    warp_worlds: on MuJoCo Warp, the most worlds one vmapped call will hold: its contact buffer is shared
    by all worlds of a batch, so vmapping this function over more worlds than that drops contacts."""
    if m.impl == mjx.Impl.WARP:
        return mjx.make_data(model, impl="warp", naconmax=warp_naconmax(warp_worlds), njmax=WARP_NJMAX)
    return mjx.make_data(m)


def world_axis_leaves(d: mjx.Data):
    """A pytree like `d` of bools: whether each leaf carries the batch (world) axis once `d` is vmapped.

    MJX-JAX: every leaf. MuJoCo Warp keeps its contact buffer and counters once per batch, without a world
    axis: such leaves are scratch that every step rewrites, so batch plumbing (auto-reset selects, seed
    axes) must pass them through rather than index them by world."""
    if getattr(d, "impl", None) != mjx.Impl.WARP:  # MJX-JAX data, or another env's physics state
        return jax.tree_util.tree_map(lambda _: True, d)
    from mujoco.mjx._src.types import tree_path_to_attr_str
    from mujoco.mjx.warp import types as warp_types

    batched = warp_types._BATCH_DIM["Data"]
    return jax.tree_util.tree_map_with_path(lambda path, _: bool(batched.get(tree_path_to_attr_str(path), True)), d)


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
        mass_matrix=mass_matrix(m, d),
        bias=d.qfrc_bias,
        jacobian=jnp.concatenate([jacp.T, jacr.T], axis=0),
        ee_pos=ee_pos,
        ee_rot=d.site_xmat[ids.ee_site],
        ee_force=ee_force,
    )


def mass_matrix(m: mjx.Model, d: mjx.Data) -> jax.Array:
    """Dense joint-space inertia matrix (nv, nv) from `d` after fwd_position.

    MuJoCo Warp keeps it in MuJoCo's sparse layout (`M`, rows M_rowadr/M_rownnz, columns M_colind),
    which `mjx.full_m` does not unpack.
    """
    if m.impl != mjx.Impl.WARP:
        return mjx.full_m(m, d)
    rows = np.repeat(np.arange(m.nv), m.M_rownnz)
    lower = jnp.zeros((m.nv, m.nv)).at[rows, m.M_colind].set(d._impl.M)
    return lower + jnp.tril(lower, -1).T


def peg_contact_force(m: mjx.Model, d: mjx.Data, peg_geoms: tuple[int, ...]) -> jax.Array:
    """Total force (N, world) the peg applies to the environment, from the last constraint solve.

    Every contact pair of the scene involves one of the peg's geoms `peg_geoms` (condim 3). A
    contact's force acts on geom2 along +frame^T f; MuJoCo may order a pair either way, so the sign
    follows which side the peg is on.
    Pressing down gives a negative z component. On MuJoCo Warp: `peg_force_sensors`.
    """
    if m.impl == mjx.Impl.WARP:
        return peg_force_sensors(m, d)
    forces, ids = _mjx_support.contact_force_dim(m, d, 3)
    contact = d._impl.contact
    frames = contact.frame[ids]
    on_env = jnp.where(jnp.isin(contact.geom[ids, 0], jnp.asarray(peg_geoms)), 1.0, -1.0)
    return jnp.einsum("c,ci,cij->j", on_env, forces[:, :3], frames)


def peg_force_sensors(m: mjx.Model, d: mjx.Data) -> jax.Array:
    """`peg_contact_force` from PEG_FORCE_SENSORS, the model's last sensors (N, world; their sum).

    The sensor's net force of a geom's contacts has the sign of `peg_contact_force` when the peg geom
    is geom1 of every contact pair, as in the scene: the force the peg applies to the environment.
    """
    return sum(d.sensordata[adr:adr + 3] for adr in m.sensor_adr[-len(PEG_FORCE_SENSORS):])


def controlled_step(m: mjx.Model, d: mjx.Data, torque_fn) -> mjx.Data:
    """One mjx.step with the actuator controls computed from the freshly computed dynamics.

    Same stages as `mjx.step` (fwd_position, fwd_velocity, actuation, acceleration, constraint solve,
    integration); `torque_fn(d) -> ctrl` runs between velocity and actuation, so it sees the mass
    matrix, bias forces and site poses at the current state without a second forward pass.
    MuJoCo Warp runs only whole passes: `warp_controlled_step`.
    """
    if m.impl == mjx.Impl.WARP:
        return warp_controlled_step(m, d, torque_fn)
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


def warp_controlled_step(m: mjx.Model, d: mjx.Data, torque_fn) -> mjx.Data:
    """`controlled_step` for MuJoCo Warp: mjx.forward, `torque_fn` on its result, then mjx.step.

    MuJoCo Warp has no separate forward stages, so this computes the forward pass once more than
    `controlled_step`; the result is the same step.
    """
    d = mjx.forward(m, d)
    return mjx.step(m, d.replace(ctrl=torque_fn(d)))
