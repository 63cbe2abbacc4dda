"""Task protocols: named sets of `FPiHConfig` task settings.

- 'authors': the authors' task (FPiHConfig's defaults): the peg moved in the hand every episode, the
  wrist force/torque sensor as the force signal and observation, the break read once per policy step,
  uniform spawn, the literal force law k_f (f_d - f).
- 'earlier': this project's earlier variant, behind its first 3-seed suite: a rigid peg, the peg's summed
  contact force as the force signal (3-D force observed), the break on the peak over physics steps, the
  damped force law with feed-forward, gaussian spawn.
- 'authors_dr': the authors' task as their randomised runs train it: 'authors' plus their dynamics
  randomisation (`randomization.AUTHORS_DYNAMICS`), end-effector position noise 0.5 mm instead of 0.25 mm,
  and the force alone observed (no torque). Their orientation noise has no counterpart: our policy does not
  observe the hand's orientation.

Each task names its force law and whose metrics and noise sweep it reports ('authors': the authors' mean
force and spherical shells; 'earlier': ours and uniform boxes).
"""

from __future__ import annotations

import dataclasses

from match_jax.envs.fpih import FPiHConfig
from match_jax.envs.randomization import AUTHORS_DYNAMICS, ModelRandomization

TASKS = {
    "authors": {"settings": {}, "force_law": "literal", "metrics": "authors"},
    "earlier": {"settings": {"break_sampling": "peak", "force_sensor": "peg_contact", "observe_torque": False,
                             "spawn_noise_type": "gaussian",
                             "randomization": ModelRandomization(peg_offset_range=(0.0, 0.0, 0.0))},
                "force_law": "damped", "metrics": "earlier"},
    "authors_dr": {"settings": {"randomization": ModelRandomization().with_dynamics(**AUTHORS_DYNAMICS),
                                "ee_pos_obs_noise": 0.0005, "observe_torque": False},
                   "force_law": "literal", "metrics": "authors"},
}


def reports_authors_metrics(task: str) -> bool:
    """Whether task protocol `task` reports the authors' metrics (their mean force, spherical shells)."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; choose one of {sorted(TASKS)}")
    return TASKS[task]["metrics"] == "authors"


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
