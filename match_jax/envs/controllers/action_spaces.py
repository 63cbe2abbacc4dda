"""Policy action spaces of the fPiH task, declared in one place.

Every action component is a number in [-1, 1] except the selections, which are 0/1 per world axis
(1 = force control; the env treats a value > 0.5 as force). The env turns actions into a
`ControlTarget` held over the substeps of one policy step:

- position: target = current end-effector position + a * pos_scale (m), clipped to a box of
  +-pos_box around the observed hole top (world frame).
- yaw: target yaw = current yaw + a * yaw_scale (rad); roll and pitch are held pointing down.
- force (hybrid): f_x, f_y = a * force_xy_max; f_z = f_z_min + (a + 1) / 2 (f_z_max - f_z_min) (N).
- stiffness (VICES): k_p = k_min + (a + 1) / 2 (k_max - k_min) per translational axis.
Continuous components are smoothed with an EMA, a_ema = ema * a + (1 - ema) a_prev; selections are not.
Actions are clipped to [-1, 1] first (`ActionConfig.clip`); unclipped, as the authors' env takes them, a
component beyond +-1 scales past its range (position targets stay in their box, VICES gains in their range).
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class ActionConfig:
    """Scaling of actions to controller targets (IsaacLab Factory's and the authors' values)."""

    pos_scale: float = 0.02  # m per policy step at |a| = 1
    pos_box: float = 0.05  # m, half-width of the target box around the observed hole top
    yaw_scale: float = 0.1  # rad per policy step at |a| = 1
    force_xy_max: float = 20.0  # N
    force_z_range: tuple[float, float] = (-20.0, 0.0)  # N (robot on environment; < 0 presses down)
    stiffness_range: tuple[float, float] = (0.0, 200.0)  # VICES k_p range, N/m on Factory's law
    ema: float = 0.2  # weight of the new action
    selection_threshold: float = 0.5  # force control on an axis when its selection > threshold
    clip: bool = True  # actions clipped to [-1, 1] before smoothing; False: passed on as the authors' env does

    def __post_init__(self):
        for name in ("pos_scale", "pos_box", "yaw_scale", "force_xy_max"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ActionConfig.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 < self.ema <= 1.0:
            raise ValueError(f"ActionConfig.ema must be in (0, 1], got {self.ema!r}")
        lo, hi = self.force_z_range
        if not lo < hi:
            raise ValueError(
                f"ActionConfig.force_z_range must be (low, high) with low < high, got {self.force_z_range!r}")
        lo, hi = self.stiffness_range
        if not 0 <= lo < hi:
            raise ValueError(f"ActionConfig.stiffness_range must be 0 <= low < high, got {self.stiffness_range!r}")

    def force_z(self, a):
        """Force-z target (N, robot on environment) of a force-z action component a in [-1, 1]."""
        lo, hi = self.force_z_range
        return lo + 0.5 * (a + 1.0) * (hi - lo)

    def force_z_action(self, force_n):
        """Inverse of `force_z`: the action component whose target is `force_n` N (F_z, < 0 presses)."""
        lo, hi = self.force_z_range
        return -1.0 + 2.0 * (force_n - lo) / (hi - lo)

    def stiffness(self, a):
        """VICES translational k_p of a stiffness action component a in [-1, 1]."""
        lo, hi = self.stiffness_range
        return lo + 0.5 * (a + 1.0) * (hi - lo)


@dataclasses.dataclass(frozen=True)
class ActionSpace:
    """Layout of one action vector: which slice holds which component.

    Attributes:
      name: 'pose', 'vices' or 'hybrid'.
      size: length of the action vector.
      position, yaw, selection, force, stiffness: index arrays into the vector (empty if absent).
    """

    name: str
    size: int
    position: tuple[int, ...]
    yaw: tuple[int, ...]
    selection: tuple[int, ...] = ()
    force: tuple[int, ...] = ()
    stiffness: tuple[int, ...] = ()

    @property
    def continuous(self) -> tuple[int, ...]:
        """Indices of the continuous components (everything but the selections)."""
        return tuple(i for i in range(self.size) if i not in self.selection)

    @property
    def low(self) -> np.ndarray:
        low = -np.ones(self.size, np.float32)
        low[list(self.selection)] = 0.0
        return low

    @property
    def high(self) -> np.ndarray:
        return np.ones(self.size, np.float32)

    def describe(self) -> list[str]:
        """Human-readable name of each action component, in order."""
        names = [""] * self.size
        for group, idx in (("pos", self.position), ("yaw", self.yaw), ("select_force", self.selection),
                           ("force", self.force), ("stiffness", self.stiffness)):
            axes = "xyz" if len(idx) == 3 else ("z",) if group == "yaw" else ""
            for k, i in enumerate(idx):
                names[i] = f"{group}_{axes[k]}" if axes else group
        return names


ACTION_SPACES: dict[str, ActionSpace] = {
    # Pose: 3 position deltas + yaw (paper).
    "pose": ActionSpace("pose", 4, position=(0, 1, 2), yaw=(3,)),
    # VICES: pose + 3 translational stiffnesses.
    "vices": ActionSpace("vices", 7, position=(0, 1, 2), yaw=(3,), stiffness=(4, 5, 6)),
    # Hybrid-Basic and MATCH: 3 selections + 3 position + 3 force + yaw.
    "hybrid": ActionSpace("hybrid", 10, selection=(0, 1, 2), position=(3, 4, 5), force=(6, 7, 8), yaw=(9,)),
}


def get_action_space(control: str) -> ActionSpace:
    """The action space of a controller name ('pose', 'vices', 'hybrid'); ValueError otherwise."""
    if control not in ACTION_SPACES:
        raise ValueError(f"unknown controller {control!r}; choose one of {sorted(ACTION_SPACES)}")
    return ACTION_SPACES[control]
