"""Scripted physics probes of the fPiH env: quantities a test or a benchmark measures, not a policy.

`static_compliance` pushes on the end effector with a constant external force while the pose law
holds a fixed target, and reports how far the end effector settles per newton along each world axis:
the effective translational stiffness the controller gives the arm (N/m = 1 / compliance).
`press_down` lowers the peg onto the hole from lateral offsets and presses with z force control: the
geometry's capture range, penetration, force holding and the controller's self-centring range.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from match_jax.envs import randomization
from match_jax.envs.controllers import ControlTarget
from match_jax.envs.sim import mjx


def static_compliance(env, force_n: float = 1.0, seconds: float = 5.0) -> np.ndarray:
    """Settled end-effector displacement (m/N, world x, y, z) under an external force at the EE site.

    The env's pose law holds the reset pose (hole nominal, no noise expected: use a quiet config) while
    a force of `force_n` newtons acts at the end-effector site along +x, +y and +z in turn (applied as
    the joint torques J^T F of the reset pose). Returns the displacement after `seconds` of simulated
    time, relative to an unloaded run, divided by `force_n`; the diagonal of the compliance matrix.
    """
    if not force_n > 0:
        raise ValueError(f"force_n must be > 0 N, got {force_n!r}")
    s0 = env.reset(jax.random.PRNGKey(0))
    d0 = s0.pipeline_state
    m, ids = env.mjx_model, env.ids
    ee0 = d0.site_xpos[ids.ee_site]
    jacp, _ = mjx.jac(m, d0, ee0, ids.hand_body)  # (nv, 3)
    target = ControlTarget(pos=ee0, rot=d0.site_xmat[ids.ee_site], force=jnp.zeros(3),
                           position_axes=jnp.ones(3),
                           pos_stiffness=jnp.asarray(env.config.controller.pos_stiffness, jnp.float32),
                           posture=s0.info["posture"])
    control_steps = int(round(seconds / env.config.control_dt))
    model = randomization.apply(env.mjx_model, s0.info["model"])

    def settle(force):
        d = d0.replace(qfrc_applied=jacp @ force)
        d = env.simulate(d, jnp.zeros(3), target, control_steps=control_steps, model=model).data
        return d.site_xpos[ids.ee_site]

    forces = jnp.concatenate([jnp.zeros((1, 3)), force_n * jnp.eye(3)])
    ee = np.asarray(jax.jit(jax.vmap(settle))(forces))
    return np.diag(ee[1:] - ee[0]) / force_n


def press_down(env, cases, policy_steps: int = 45, approach_steps: int = 12) -> dict:
    """Press the peg down onto the hole from lateral offsets, all cases in one compiled batch.

    Each case (offset_x m, f_z N, k_xy N/m): pose control for `approach_steps` policy steps to 1 mm above
    the block top at the offset, then z force control at f_z while x, y hold the offset with stiffness
    k_xy (z stiffness: the config's), `policy_steps` in all. Use a quiet env (hole at its nominal pose).
    Returns the peg-tip trajectory relative to the hole bottom centre (policy rate, (cases, steps, 3)),
    the last force reading ('forces': the env's force signal; 'contact_forces': the peg's contact force)
    and the peg's max contact force over the physics steps of each policy step, and the block top height
    above the hole bottom (m).
    """
    s0 = env.reset(jax.random.PRNGKey(0))
    model = randomization.apply(env.mjx_model, s0.info["model"])
    hole = s0.info["hole_pos"]
    rot = s0.pipeline_state.site_xmat[env.ids.ee_site]
    hover = env.hole_depth + env.peg_tip_below_ee + 0.001
    kp_z = env.config.controller.pos_stiffness[2]

    def run(offset_x, force_z, k_xy):
        def target(position_axes):
            return ControlTarget(pos=hole + jnp.array([offset_x, 0.0, hover]), rot=rot,
                                 force=jnp.array([0.0, 0.0, force_z]), position_axes=position_axes,
                                 pos_stiffness=jnp.array([k_xy, k_xy, kp_z]), posture=s0.info["posture"])

        def body(carry, i):
            d, f = carry
            out = jax.lax.cond(
                i < approach_steps, lambda: env.simulate(d, f, target(jnp.ones(3)), model=model),
                lambda: env.simulate(d, f, target(jnp.array([1.0, 1.0, 0.0])), model=model))
            return (out.data, out.force), (out.data.site_xpos[env.ids.peg_tip_site], out.force, out.max_force,
                                           out.contact_force)

        _, out = jax.lax.scan(body, (s0.pipeline_state, jnp.zeros(3)), jnp.arange(policy_steps))
        return out

    args = [jnp.array(col, jnp.float32) for col in zip(*cases)]
    tips, forces, max_forces, contact_forces = jax.jit(jax.vmap(run))(*args)
    return {"cases": list(cases), "tips": np.asarray(tips - hole), "forces": np.asarray(forces),
            "max_forces": np.asarray(max_forces), "contact_forces": np.asarray(contact_forces),
            "block_top": env.hole_depth}
