"""Selection analysis of hybrid policies: probability of force control per axis over an episode,
segmented into the env's phases and time-normalised within each phase (the paper's figure).

Phases come from the env's per-step info['phase']: approach (before the first contact), contact
(from the first contact until the peg is first engaged: centred within the success radius and
below the engagement height) and insertion (after that). Each episode's steps in a phase are mapped to
normalised time tau = (k + 0.5) / n for its k-th of n steps in that phase, binned, and the force
probabilities averaged per bin over all episodes.
"""

from __future__ import annotations

import numpy as np

from match_jax.envs.fpih import PHASE_NAMES as PHASES


def selection_profile(phase: np.ndarray, p_force: np.ndarray, alive: np.ndarray, bins: int = 10) -> dict:
    """Mean p_force per (phase, time bin, axis) from (T, B) phase, (T, B, 3) p_force, (T, B) alive masks.

    Returns {'mean': (3 phases, bins, 3 axes) with NaN where empty, 'count': (3, bins) episode-steps per
    bin, 'episodes': (3,) episodes that reached each phase, 'bin_centres': (bins,)}.
    """
    phase, p_force, alive = np.asarray(phase), np.asarray(p_force, np.float64), np.asarray(alive) > 0
    if not (isinstance(bins, int) and bins >= 1):
        raise ValueError(f"bins must be a positive integer, got {bins!r}")
    if p_force.shape[:2] != phase.shape or alive.shape != phase.shape:
        raise ValueError(f"shapes disagree: phase {phase.shape}, p_force {p_force.shape}, alive {alive.shape}")
    axes = p_force.shape[-1]
    total = np.zeros((len(PHASES), bins, axes))
    count = np.zeros((len(PHASES), bins))
    episodes = np.zeros(len(PHASES), int)
    for b in range(phase.shape[1]):
        for k in range(len(PHASES)):
            steps = np.nonzero((phase[:, b] == k) & alive[:, b])[0]
            if len(steps) == 0:
                continue
            episodes[k] += 1
            tau = (np.arange(len(steps)) + 0.5) / len(steps)
            which = np.minimum((tau * bins).astype(int), bins - 1)
            np.add.at(total[k], which, p_force[steps, b])
            np.add.at(count[k], which, 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count[..., None]
    return {"mean": mean, "count": count, "episodes": episodes, "bin_centres": (np.arange(bins) + 0.5) / bins}


def contact_selection_rates(in_contact: np.ndarray, p_force: np.ndarray, alive: np.ndarray) -> dict:
    """Mean probability of force control (over axes) on in-contact vs free-space steps."""
    in_contact, alive = np.asarray(in_contact) > 0, np.asarray(alive) > 0
    p = np.asarray(p_force, np.float64).mean(-1)
    contact, free = in_contact & alive, ~in_contact & alive
    return {"p_force_contact": float(p[contact].mean()) if contact.any() else float("nan"),
            "p_force_free": float(p[free].mean()) if free.any() else float("nan"),
            "contact_steps": int(contact.sum()), "free_steps": int(free.sum())}
