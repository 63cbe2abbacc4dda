"""Scripted physics probes of the fPiH env: quantities a test or a benchmark measures, not a policy.

`static_compliance` pushes on the end effector with a constant external force while the pose law
holds a fixed target, and reports how far the end effector settles per newton along each world axis:
the effective translational stiffness the controller gives the arm (N/m = 1 / compliance).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from match_jax.controllers import ControlTarget
from match_jax.sim import mjx


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

    def settle(force):
        d = d0.replace(qfrc_applied=jacp @ force)
        d, _, _, _ = env.simulate(d, jnp.zeros(3), target, control_steps=control_steps)
        return d.site_xpos[ids.ee_site]

    forces = jnp.concatenate([jnp.zeros((1, 3)), force_n * jnp.eye(3)])
    ee = np.asarray(jax.jit(jax.vmap(settle))(forces))
    return np.diag(ee[1:] - ee[0]) / force_n
