"""Low-level control laws (pose, VICES, hybrid force/position) and the policy action spaces."""

from match_jax.envs.controllers.osc import (
    ArmDynamics,
    ControlTarget,
    ControllerConfig,
    hybrid_torque,
    orientation_error,
    task_inertia,
)
from match_jax.envs.controllers.action_spaces import (
    ACTION_SPACES,
    ActionSpace,
    ActionConfig,
    get_action_space,
)

__all__ = [
    "ACTION_SPACES",
    "ActionConfig",
    "ActionSpace",
    "ArmDynamics",
    "ControlTarget",
    "ControllerConfig",
    "get_action_space",
    "hybrid_torque",
    "orientation_error",
    "task_inertia",
]
