"""Task protocols: named sets of `FPiHConfig` task settings.

- 'authors': the authors' task (FPiHConfig's defaults): the peg moved in the hand every episode, the
  wrist force/torque sensor as the force signal and observation, the break read once per policy step,
  uniform spawn, the literal force law k_f (f_d - f).
- 'earlier': this project's earlier variant, behind its first 3-seed suite: a rigid peg, the peg's summed
  contact force as the force signal (3-D force observed), the break on the peak over physics steps, the
  damped force law with feed-forward, gaussian spawn.
"""

from __future__ import annotations

import dataclasses

from match_jax.envs.fpih import FPiHConfig
from match_jax.envs.randomization import ModelRandomization

TASKS = {
    "authors": {"settings": {}, "force_law": "literal"},
    "earlier": {"settings": {"break_sampling": "peak", "force_sensor": "peg_contact", "observe_torque": False,
                             "spawn_noise_type": "gaussian",
                             "randomization": ModelRandomization(peg_offset_range=(0.0, 0.0, 0.0))},
                "force_law": "damped"},
}


def task_config(task: str, control: str, force_law: str | None = None, **overrides) -> FPiHConfig:
    """The FPiHConfig of task protocol `task` for controller `control`, its force law replaced by
    `force_law` ('literal' | 'damped'; None: the task's) and any other field by `overrides`."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; choose one of {sorted(TASKS)}")
    settings = {**TASKS[task]["settings"], **overrides}
    if settings.get("force_sensor") == "peg_contact":
        settings.setdefault("observe_torque", False)
    config = FPiHConfig(control=control, **settings)
    controller = config.controller.with_force_law(force_law or TASKS[task]["force_law"])
    return dataclasses.replace(config, controller=controller)
