"""Per-env model randomisation: model fields drawn per episode, one value set per env.

The env keeps the drawn fields in `state.info['model']` (a dict: mjx.Model field name -> that env's full
array) and steps with `apply(mjx_model, fields)`. Under `vmap` over envs the replaced model is batched
along the same axis as the data, as MuJoCo Playground's domain randomisation batches it, so auto-reset
(a fresh draw per finished env), the seed batch and env sharding carry it like any other state.

Randomised now: the peg's pose in the hand (IsaacLab Factory's `held_asset_pos_noise`: the grasp moves
on every reset). Masses, friction and gains can be added as more fields of the same dict.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from match_jax.sim import mjx


@dataclasses.dataclass(frozen=True)
class ModelRandomization:
    """Ranges of the per-episode model draws.

    Attributes:
      peg_offset_range: half-widths (m) of the uniform offset of the peg in the hand, along the hand's
        x (across the fingers), y and z (along the peg, + = further out of the hand) axes.
    """

    peg_offset_range: tuple[float, float, float] = (0.003, 0.0, 0.003)

    def __post_init__(self):
        if len(self.peg_offset_range) != 3 or any(not (0 <= v < 0.02) for v in self.peg_offset_range):
            raise ValueError(f"peg_offset_range must be 3 half-widths in [0, 0.02) m, got {self.peg_offset_range!r}")

    @property
    def enabled(self) -> bool:
        return any(v > 0 for v in self.peg_offset_range)


class ModelSampler:
    """Draws per-env model fields for one scene (`model`) and one `ModelRandomization`."""

    def __init__(self, model: mujoco.MjModel, peg_body: int, config: ModelRandomization):
        self.config = config
        self.peg_body = peg_body
        self.nominal_body_pos = np.asarray(model.body_pos, np.float32)  # (nbody, 3), parent frames

    def sample(self, key: jax.Array) -> dict[str, jax.Array]:
        """One env's randomised fields (empty when nothing is randomised)."""
        if not self.config.enabled:
            return {}
        half = jnp.asarray(self.config.peg_offset_range, jnp.float32)
        offset = jax.random.uniform(key, (3,), minval=-1.0, maxval=1.0) * half
        body_pos = jnp.asarray(self.nominal_body_pos).at[self.peg_body].add(offset)
        return {"body_pos": body_pos}

    def peg_offset(self, fields: dict[str, jax.Array]) -> jax.Array:
        """The peg's offset (m, hand frame) from its nominal pose in the hand, (3,)."""
        if "body_pos" not in fields:
            return jnp.zeros(3)
        return fields["body_pos"][self.peg_body] - jnp.asarray(self.nominal_body_pos[self.peg_body])


def apply(m: mjx.Model, fields: dict[str, jax.Array]) -> mjx.Model:
    """`m` with the given fields replaced (one env's values; under vmap, a batched model)."""
    return m.replace(**fields) if fields else m
