"""Evaluation: roll a policy out for whole episodes and compute the paper's Table 1 metrics.

A policy is `policy(obs, policy_state, key) -> (action, policy_state)` for ONE env (it is vmapped),
where `obs` is the env's observation dict. Metrics come only from the env's own per-step info.
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from match_jax.envs.fpih import break_signal

Policy = Callable[[dict, Any, jax.Array], tuple[jax.Array, Any]]

# Per-step info recorded during a rollout: name -> key in State.info.
RECORDED = ("success", "engaged", "broken", "in_contact", "mean_force", "max_force", "phase",
            "position_axes", "contact_axes", "truncation", "ee_force")


def make_rollout(env, policy: Policy, num_steps: int | None = None, batched_policy_state: bool = True,
                 record_obs: bool = False):
    """A jittable function (keys (B, 2), policy_state) -> trajectory dict of (T, B, ...) arrays.

    Each env runs exactly one episode of `num_steps` (default env.config.episode_steps) policy steps
    from `env.reset(key)`; steps after the episode ended (break) are marked by `done_before`.
    `policy_state` has a leading batch axis, or (batched_policy_state=False) is shared by all envs,
    e.g. a learned policy's parameters. record_obs=True also records 'policy_obs', the policy
    observation each action was computed from.
    """
    num_steps = num_steps or env.config.episode_steps

    def one_env(key, policy_state, hole_obs_offset=None):
        reset_key, policy_key = jax.random.split(key)
        state = env.reset(reset_key)
        if hole_obs_offset is not None:
            state = env.set_hole_obs_offset(state, hole_obs_offset)

        def body(carry, step_key):
            state, pstate, ended = carry
            action, pstate = policy(state.obs, pstate, step_key)
            obs_before, contact_before = state.obs["state"], state.info["contact_axes"]
            state = env.step(state, action)
            record = {name: state.info[name] for name in RECORDED}
            record["contact_axes_before"] = contact_before  # the contact the action was chosen in
            if record_obs:
                record["policy_obs"] = obs_before
            record["done_before"] = ended
            record["done"] = state.done
            return (state, pstate, jnp.maximum(ended, state.done)), record

        keys = jax.random.split(policy_key, num_steps)
        _, traj = jax.lax.scan(body, (state, policy_state, jnp.zeros(())), keys)
        return traj

    def rollout(keys, policy_states, hole_obs_offsets=None):
        """hole_obs_offsets: optional (B, 3) observation errors (m) replacing the env's own draw."""
        in_axes = (0, 0 if batched_policy_state else None, None if hole_obs_offsets is None else 0)
        traj = jax.vmap(one_env, in_axes=in_axes)(keys, policy_states, hole_obs_offsets)  # (B, T, ...)
        return jax.tree_util.tree_map(lambda x: jnp.swapaxes(x, 0, 1), traj)

    return rollout


def apply_break_threshold(traj: dict, break_force: float, sampling: str = "peak") -> dict:
    """The trajectory a peg that breaks at `break_force` N would have had, from an unbreakable rollout.

    Breaking only ends the episode, so up to the first step whose break signal (`fpih.break_signal`,
    the env's own check) reaches the threshold the two rollouts are identical; later steps are marked
    `done_before`.
    """
    traj = {k: np.asarray(v) for k, v in traj.items()}
    alive = 1.0 - traj["done_before"]
    signal = np.asarray(break_signal(sampling, traj["max_force"], traj["ee_force"]))
    broken = ((signal >= break_force) & (alive > 0)).astype(np.float32)
    ended = np.maximum(broken, traj["done"] * alive)
    done_before = np.zeros_like(alive)
    done_before[1:] = np.maximum.accumulate(ended, axis=0)[:-1]
    out = dict(traj)
    out["broken"], out["done_before"] = broken, np.maximum(done_before, traj["done_before"])
    return out


def episode_metrics(traj: dict, policy_dt: float) -> dict[str, np.ndarray]:
    """Per-episode metrics from a (T, B, ...) trajectory of env info.

    success: the success condition held on some step before any break.
    broken: the peg broke (the episode ended by break).
    time_to_success_s: (first success step + 1) * policy_dt, NaN for failures.
    mean_force_n: mean force magnitude (N) over in-contact steps, NaN if never in contact.
    force_selected_contact / force_selected_free: fraction of in-contact / free-space steps on which
      force control was selected, averaged over the three axes (NaN if no such step).
    axis_contact_steps, axis_force_in_contact_steps, axis_free_steps, axis_force_in_free_steps: (B, 3)
      per-axis step counts behind the per-axis selection rates of `summarize`: an axis is in contact on a
      step when |F| along that world axis exceeded the env's contact threshold (1 N) at the start of the
      step (the contact the action was chosen in, the selection loss's label), force-selected when the
      step ran that axis under force control.
    """
    traj = {k: np.asarray(v) for k, v in traj.items()}
    alive = 1.0 - traj["done_before"]  # (T, B)
    success_t = (traj["success"] > 0) & (alive > 0)
    broken_t = (traj["broken"] > 0) & (alive > 0)
    T = alive.shape[0]
    steps = np.arange(T)[:, None]
    first_success = np.where(success_t, steps, T).min(axis=0)
    first_break = np.where(broken_t, steps, T).min(axis=0)
    success = first_success < np.minimum(first_break, T)
    broken = first_break < T
    time_to_success = np.where(success, (first_success + 1) * policy_dt, np.nan)

    contact = (traj["in_contact"] > 0) & (alive > 0)
    free = (traj["in_contact"] <= 0) & (alive > 0)
    n_contact = contact.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_force = np.where(n_contact > 0, (traj["mean_force"] * contact).sum(axis=0) / n_contact, np.nan)
        force_sel = (1.0 - traj["position_axes"]).mean(axis=-1)  # (T, B)
        sel_contact = np.where(n_contact > 0, (force_sel * contact).sum(axis=0) / n_contact, np.nan)
        n_free = free.sum(axis=0)
        sel_free = np.where(n_free > 0, (force_sel * free).sum(axis=0) / n_free, np.nan)
    axis_alive = (alive > 0)[..., None]
    axis_contact = (traj["contact_axes_before"] > 0) & axis_alive  # (T, B, 3)
    axis_free = (traj["contact_axes_before"] <= 0) & axis_alive
    axis_force = traj["position_axes"] < 0.5
    return {
        "success": success.astype(np.float64),
        "broken": broken.astype(np.float64),
        "time_to_success_s": time_to_success,
        "mean_force_n": mean_force,
        "force_selected_contact": sel_contact,
        "force_selected_free": sel_free,
        "axis_contact_steps": axis_contact.sum(axis=0),
        "axis_force_in_contact_steps": (axis_contact & axis_force).sum(axis=0),
        "axis_free_steps": axis_free.sum(axis=0),
        "axis_force_in_free_steps": (axis_free & axis_force).sum(axis=0),
    }


def axis_selection_rates(metrics: dict[str, np.ndarray]) -> dict[str, float]:
    """Per-axis force selection, pooled over episodes: sum_i [force_i and contact_i] / sum_i contact_i
    over all steps and axes i (the paper's figure), the same for each axis x, y, z, and likewise on
    free-space axes. NaN where there is no such axis-step."""
    out = {}
    for where in ("contact", "free"):
        hits = np.asarray(metrics[f"axis_force_in_{where}_steps"], np.float64).sum(axis=0)  # (3,)
        total = np.asarray(metrics[f"axis_{where}_steps"], np.float64).sum(axis=0)
        out[f"force_selected_{where}_per_axis"] = float(hits.sum() / total.sum()) if total.sum() > 0 else float("nan")
        for i, axis in enumerate("xyz"):
            out[f"force_selected_{where}_{axis}"] = float(hits[i] / total[i]) if total[i] > 0 else float("nan")
    return out


def summarize(metrics: dict[str, np.ndarray]) -> dict[str, float]:
    """Means over episodes (NaN-aware): the JSON/table numbers of eval.py."""

    def nanmean(x):
        x = np.asarray(x, np.float64)
        return float(np.nanmean(x)) if np.any(~np.isnan(x)) else float("nan")

    return {
        "episodes": int(len(metrics["success"])),
        "success_rate": nanmean(metrics["success"]),
        "break_rate": nanmean(metrics["broken"]),
        "mean_time_to_success_s": nanmean(metrics["time_to_success_s"]),
        "mean_force_n": nanmean(metrics["mean_force_n"]),
        "force_selected_contact": nanmean(metrics["force_selected_contact"]),
        "force_selected_free": nanmean(metrics["force_selected_free"]),
        **axis_selection_rates(metrics),
    }


def mean_and_standard_error(values) -> tuple[float, float]:
    """Mean and standard error over seeds (NaN entries dropped; SE is NaN with fewer than 2 values)."""
    x = np.asarray([v for v in values if v is not None and not np.isnan(v)], np.float64)
    if len(x) == 0:
        return float("nan"), float("nan")
    se = float(np.std(x, ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")
    return float(np.mean(x)), se
