"""The wrist force/torque sensor: MuJoCo `force` and `torque` sensors at the flange site 'wrist'.

MuJoCo reports the wrench that link 7 exerts on the hand subtree (hand + peg), in the wrist site's
frame, about the site. A real F/T sensor is tared for its payload; here the subtree's static weight is
removed, which leaves the wrench the robot applies to the environment plus the subtree's inertial
terms: at rest it equals the peg's contact wrench, during an impact it reads less (the hand's own
momentum is stopped by the contact, not through the wrist).

Units: N and N m. `WristSensor.read` returns the world frame (the frame of the control law);
`authors_reading` gives the authors' variant of it, in the hand frame.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from match_jax.envs.sim import mjx

WRIST_SITE = "wrist"
WRIST_FORCE, WRIST_TORQUE = "wrist_force", "wrist_torque"
FORCE_FRAMES = ("world", "hand")


class WristSensor:
    """Addresses of the wrist sensors in a model and the tare of the subtree they carry."""

    def __init__(self, model: mujoco.MjModel):
        try:
            self.force_adr = int(model.sensor_adr[model.sensor(WRIST_FORCE).id])
            self.torque_adr = int(model.sensor_adr[model.sensor(WRIST_TORQUE).id])
            self.site = model.site(WRIST_SITE).id
        except KeyError as err:
            raise ValueError(f"the scene has no wrist force/torque sensor ({err}); regenerate it with "
                             "match_jax/envs/assets/make_scene.py") from None
        self.body = int(model.site_bodyid[self.site])
        self.subtree_mass = float(model.body_subtreemass[self.body])  # kg, hand + peg, nominal
        self.gravity = np.asarray(model.opt.gravity, np.float32)  # m/s^2, world

    def read(self, m: mjx.Model, d: mjx.Data) -> tuple[jax.Array, jax.Array]:
        """(force, torque) the robot applies to the environment through the wrist (N, N m, world frame,
        torque about the wrist site), tared for the subtree's weight, from `d`'s sensordata.

        `d` must have its acceleration-stage sensors computed (`compute`, or a backend whose step does it).
        """
        rot = d.site_xmat[self.site]
        weight = m.body_subtreemass[self.body] * jnp.asarray(self.gravity)
        force = rot @ d.sensordata[self.force_adr:self.force_adr + 3] + weight
        lever = d.subtree_com[self.body] - d.site_xpos[self.site]
        torque = rot @ d.sensordata[self.torque_adr:self.torque_adr + 3] + jnp.cross(lever, weight)
        return force, torque


def compute(m: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`d` with its acceleration-stage sensors computed (after the constraint solve of a step; MJX's
    JAX backend, whose split step `sim.controlled_step` runs the stages itself). MuJoCo Warp's step
    computes them."""
    if m.impl == mjx.Impl.WARP:
        return d
    return mjx.sensor_acc(m, d)


def authors_reading(vector: jax.Array, hand_rot: jax.Array) -> jax.Array:
    """The authors' wrist reading of a world-frame wrench part (..., 3) the robot applies: the joint
    force that the arm exerts on the hand, in the hand frame (rotation matrix `hand_rot`, columns the
    hand axes), negated, -R^T v. Their force law uses it without rotating it back: with the hand pointing
    down at yaw 0 it reads (-F_x, F_y, F_z), so z and y act as in the world frame and x is mirrored (at
    yaw psi the x/y loop is a reflection, inverted along the world direction psi / 2)."""
    return -jnp.einsum("...ji,...j->...i", hand_rot, vector)
