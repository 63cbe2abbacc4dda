"""Per-env model randomisation: model fields and controller gains drawn per episode, one set per env.

The env keeps the drawn model fields in `state.info['model']` (a dict: mjx.Model field name -> that env's
full array) and steps with `apply(mjx_model, fields)`. Under `vmap` over envs the replaced model is
batched along the same axis as the data, as MuJoCo Playground's domain randomisation batches it, so
auto-reset (a fresh draw per finished env), the seed batch and env sharding carry it like any other
state. Drawn controller gains live in `state.info['gains']` and enter the control target.

Randomised: the peg's pose in the hand (IsaacLab Factory's `held_asset_pos_noise`: the grasp moves on
every reset), and, with the dynamics ranges on (`DYNAMICS_RANGES`, or the authors' `AUTHORS_DYNAMICS`), the
held peg's mass and contact friction and the controller's position stiffness, rotation stiffness and force gain.
With the arm model error on (`ARM_MODEL_ERROR`), the robot's masses and rotor inertias are drawn for the
physics only: the control law keeps the nominal model (`nominal_law_view`), as a robot's controller keeps its
identified one.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from match_jax.envs.sim import mjx

Range = tuple[float, float]
GAIN_NAMES = ("pos_stiffness", "rot_stiffness", "force_gain")
ARM_ERROR_NAMES = ("arm_mass_scale", "arm_armature_scale")


def _check_range(name: str, value, low: float, high: float) -> None:
    if value is None:
        return
    if len(value) != 2 or not (low <= value[0] <= value[1] <= high):
        raise ValueError(f"{name} must be None or (low, high) with {low} <= low <= high <= {high}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class ModelRandomization:
    """Ranges of the per-episode draws (uniform; None = the nominal value, not drawn).

    Attributes:
      peg_offset_range: half-widths (m) of the uniform offset of the peg in the hand, along the hand's
        x (across the fingers), y and z (along the peg, + = further out of the hand) axes.
      peg_mass_scale: factor on the held peg's mass and inertia.
      peg_friction: tangential friction coefficient of every peg contact (the scene's contact pairs all
        involve the peg; nominal 0.75).
      pos_stiffness: translational k_p (N/m), one draw shared by x, y and z; damping stays critical.
      rot_stiffness: rotational k_p (N m/rad), one draw shared by the three axes.
      force_gain: k_f of the force law.
      arm_mass_scale: factor on the mass and inertia of every body of the robot (links, hand and the held
        peg), physics only: the control law computes with the nominal values.
      arm_armature_scale: factor on the arm joints' rotor inertia (armature), physics only.
    """

    peg_offset_range: tuple[float, float, float] = (0.003, 0.0, 0.003)
    peg_mass_scale: Range | None = None
    peg_friction: Range | None = None
    pos_stiffness: Range | None = None
    rot_stiffness: Range | None = None
    force_gain: Range | None = None
    arm_mass_scale: Range | None = None
    arm_armature_scale: Range | None = None

    def __post_init__(self):
        if len(self.peg_offset_range) != 3 or any(not (0 <= v < 0.02) for v in self.peg_offset_range):
            raise ValueError(f"peg_offset_range must be 3 half-widths in [0, 0.02) m, got {self.peg_offset_range!r}")
        _check_range("peg_mass_scale", self.peg_mass_scale, 1e-3, 1e3)
        _check_range("peg_friction", self.peg_friction, 0.0, 10.0)
        _check_range("pos_stiffness", self.pos_stiffness, 0.0, 1e5)
        _check_range("rot_stiffness", self.rot_stiffness, 0.0, 1e5)
        _check_range("force_gain", self.force_gain, 0.0, 100.0)
        _check_range("arm_mass_scale", self.arm_mass_scale, 0.5, 2.0)
        _check_range("arm_armature_scale", self.arm_armature_scale, 0.1, 10.0)

    @property
    def enabled(self) -> bool:
        """Whether the peg moves in the hand."""
        return any(v > 0 for v in self.peg_offset_range)

    @property
    def dynamics(self) -> bool:
        """Whether any dynamics parameter (mass, friction, gains, arm model error) is drawn."""
        return any(getattr(self, name) is not None
                   for name in ("peg_mass_scale", "peg_friction") + GAIN_NAMES + ARM_ERROR_NAMES)

    @property
    def arm_model_error(self) -> bool:
        """Whether the physics' robot masses or rotor inertias differ from the control law's model."""
        return any(getattr(self, name) is not None for name in ARM_ERROR_NAMES)

    def with_dynamics(self, **ranges) -> "ModelRandomization":
        """This config with the given dynamics ranges (default: `DYNAMICS_RANGES`)."""
        return dataclasses.replace(self, **(ranges or DYNAMICS_RANGES))

    def with_arm_model_error(self, **ranges) -> "ModelRandomization":
        """This config with the given arm model error ranges (default: `ARM_MODEL_ERROR`)."""
        return dataclasses.replace(self, **(ranges or ARM_MODEL_ERROR))


# The authors' dynamics randomisation for transfer: peg mass x U[0.8, 1.2], peg friction U[0.5, 2.0],
# k_p U[60, 140] N/m, rotational k_p U[20, 60] N m/rad, k_f U[0.05, 0.6].
AUTHORS_DYNAMICS = {"peg_mass_scale": (0.8, 1.2), "peg_friction": (0.5, 2.0), "pos_stiffness": (60.0, 140.0),
                    "rot_stiffness": (20.0, 60.0), "force_gain": (0.05, 0.6)}
# The highest rotational k_p (N m/rad) at which the law at 120 Hz holds the arm still in this scene: with
# k_d = 2 sqrt(k_p) applied explicitly once per 1/120 s control step, the wrist joints (5 and 7) oscillate
# from about 34 N m/rad up.
STABLE_ROT_STIFFNESS = 30.0
# The default ranges: the authors' with the rotational k_p drawn from U[20, 30] N m/rad (docs/transfer.md).
DYNAMICS_RANGES = {**AUTHORS_DYNAMICS, "rot_stiffness": (AUTHORS_DYNAMICS["rot_stiffness"][0], STABLE_ROT_STIFFNESS)}
DYNAMICS_PRESETS = {"stable": DYNAMICS_RANGES, "authors": AUTHORS_DYNAMICS}
# Model error of the robot that its controller does not know (ours; the authors draw none): every robot body's
# mass and inertia x U[0.99, 1.01] and the rotor inertias x U[0.8, 1.25]. At the spawn pose 1 % of mass is
# ~0.8 N of uncompensated weight at the hand; a position action moves the target at most 2 cm, 1.2-2.8 N at
# k_p 60-140 N/m, so a wider mass range would outweigh what the policy can command.
ARM_MODEL_ERROR = {"arm_mass_scale": (0.99, 1.01), "arm_armature_scale": (0.8, 1.25)}


def _uniform(key: jax.Array, bounds: Range) -> jax.Array:
    return jax.random.uniform(key, (), minval=bounds[0], maxval=bounds[1])


class ModelSampler:
    """Draws per-env model fields and controller gains for one scene (`model`) and one `ModelRandomization`."""

    def __init__(self, model: mujoco.MjModel, peg_body: int, config: ModelRandomization):
        self.config = config
        self.peg_body = peg_body
        self.nominal_body_pos = np.asarray(model.body_pos, np.float32)  # (nbody, 3), parent frames
        self.nominal_body_mass = np.asarray(model.body_mass, np.float32)  # (nbody,), kg
        self.nominal_body_inertia = np.asarray(model.body_inertia, np.float32)  # (nbody, 3), kg m^2
        self.nominal_pair_friction = np.asarray(model.pair_friction, np.float32)  # (npair, 5)
        self.nominal_armature = np.asarray(model.dof_armature, np.float32)  # (nv,), kg m^2
        # in_subtree[a, b]: body b is in a's subtree (a itself included); subtree masses = in_subtree @ masses
        self.in_subtree = np.zeros((model.nbody, model.nbody), np.float32)
        for body in range(model.nbody):
            node = body
            while True:
                self.in_subtree[node, body] = 1.0
                if node == 0:
                    break
                node = int(model.body_parentid[node])
        # the robot: every body moved by a joint (mocap bodies, such as the hole, and the fixed base excluded)
        self.robot_bodies = np.asarray([b for b in range(1, model.nbody) if model.body_weldid[b] != 0
                                        and model.body_mocapid[b] < 0])
        self.robot_root = int(self.robot_bodies[0])

    def sample(self, key: jax.Array) -> dict[str, jax.Array]:
        """One env's randomised model fields (empty when nothing of the model is randomised)."""
        cfg, fields = self.config, {}
        k_offset, k_mass, k_friction = key, jax.random.fold_in(key, 1), jax.random.fold_in(key, 2)
        k_arm_mass, k_rotor = (jax.random.fold_in(key, 3 + len(GAIN_NAMES) + i) for i in range(2))  # after the gains
        if cfg.enabled:
            half = jnp.asarray(cfg.peg_offset_range, jnp.float32)
            offset = jax.random.uniform(k_offset, (3,), minval=-1.0, maxval=1.0) * half
            fields["body_pos"] = jnp.asarray(self.nominal_body_pos).at[self.peg_body].add(offset)
        if cfg.peg_mass_scale is not None or cfg.arm_mass_scale is not None:
            factor = jnp.ones(len(self.nominal_body_mass))
            if cfg.arm_mass_scale is not None:
                factor = factor.at[self.robot_bodies].set(_uniform(k_arm_mass, cfg.arm_mass_scale))
            if cfg.peg_mass_scale is not None:
                factor = factor.at[self.peg_body].multiply(_uniform(k_mass, cfg.peg_mass_scale))
            mass = jnp.asarray(self.nominal_body_mass) * factor
            fields["body_mass"] = mass
            fields["body_inertia"] = jnp.asarray(self.nominal_body_inertia) * factor[:, None]
            fields["body_subtreemass"] = jnp.asarray(self.in_subtree) @ mass
        if cfg.arm_armature_scale is not None:
            fields["dof_armature"] = jnp.asarray(self.nominal_armature) * _uniform(k_rotor, cfg.arm_armature_scale)
        if cfg.peg_friction is not None:
            mu = _uniform(k_friction, cfg.peg_friction)
            fields["pair_friction"] = jnp.asarray(self.nominal_pair_friction).at[:, :2].set(mu)
        return fields

    def sample_gains(self, key: jax.Array) -> dict[str, jax.Array]:
        """One env's controller gains: 'pos_stiffness' (3,) N/m, 'rot_stiffness' (3,) N m/rad, 'force_gain'
        () for the ranges that are set (empty when no gain is randomised). `key`: the same key as
        `sample`'s (the draws are independent of its)."""
        gains = {}
        for i, name in enumerate(GAIN_NAMES):
            bounds = getattr(self.config, name)
            if bounds is not None:
                value = _uniform(jax.random.fold_in(key, 3 + i), bounds)
                gains[name] = value if name == "force_gain" else jnp.full(3, value)
        return gains

    def peg_offset(self, fields: dict[str, jax.Array]) -> jax.Array:
        """The peg's offset (m, hand frame) from its nominal pose in the hand, (3,)."""
        if "body_pos" not in fields:
            return jnp.zeros(3)
        return fields["body_pos"][self.peg_body] - jnp.asarray(self.nominal_body_pos[self.peg_body])

    def arm_error(self, body_mass: jax.Array | None, armature: jax.Array | None) -> tuple[jax.Array, jax.Array]:
        """One env's drawn arm model error, (mass scale, rotor inertia scale) (1 where not drawn), from its
        model's `body_mass` and `dof_armature`."""
        mass = body_mass[self.robot_root] / self.nominal_body_mass[self.robot_root] \
            if self.config.arm_mass_scale is not None else jnp.ones(())
        rotor = armature[0] / self.nominal_armature[0] if self.config.arm_armature_scale is not None else jnp.ones(())
        return mass, rotor

    def nominal_law_view(self, m: mjx.Model, dyn):
        """`dyn` (a `controllers.ArmDynamics` computed on one env's drawn model `m`) as the control law's
        nominal model gives it: the joint-space inertia and bias forces without the drawn arm model error.
        Both are linear in the robot's masses and inertias (scaled by one factor) and M in the rotor
        inertias (its diagonal)."""
        mass, rotor = self.arm_error(m.body_mass, m.dof_armature)
        nominal = jnp.asarray(self.nominal_armature)
        inertia = (dyn.mass_matrix - jnp.diag(nominal * rotor)) / mass + jnp.diag(nominal)
        return dataclasses.replace(dyn, mass_matrix=inertia, bias=dyn.bias / mass)

    def dynamics_values(self, fields: dict[str, jax.Array], gains: dict[str, jax.Array]) -> jax.Array:
        """The dynamics parameters of one env as a vector for the critic, (5,): peg mass scale, peg contact
        friction, k_p (N/m), rotational k_p (N m/rad), k_f; a gain that is not drawn reads 0. With the arm
        model error drawn, (7,): then also the robot's mass scale and rotor inertia scale."""
        arm_mass, armature = self.arm_error(fields.get("body_mass"), fields.get("dof_armature"))
        mass = fields["body_mass"][self.peg_body] / (self.nominal_body_mass[self.peg_body] * arm_mass) \
            if "body_mass" in fields else jnp.ones(())
        friction = fields["pair_friction"][0, 0] if "pair_friction" in fields \
            else jnp.asarray(self.nominal_pair_friction[0, 0])
        values = [mass, friction] + [gains[n].reshape(-1)[0] if n in gains else jnp.zeros(()) for n in GAIN_NAMES]
        if self.config.arm_model_error:
            values += [arm_mass, armature]
        return jnp.stack([jnp.asarray(v, jnp.float32) for v in values])


def apply(m: mjx.Model, fields: dict[str, jax.Array]) -> mjx.Model:
    """`m` with the given fields replaced (one env's values; under vmap, a batched model)."""
    return m.replace(**fields) if fields else m
