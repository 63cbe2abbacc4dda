"""Evaluation: roll policies out for whole episodes and compute the paper's Table 1 metrics, for the
scripted baselines and for every seed of a training run.

    from match_jax.training.evaluation import evaluate_run, format_result
    result = evaluate_run("runs/match_cpu", episodes=100)             # at the training noise
    result = evaluate_run("runs/match_cpu", episodes=500, noise_mm=5.0, noise_type="uniform")
    summary = evaluate_baseline("spiral", episodes=100, noise_m=1e-3)

A policy is `policy(obs, policy_state, key) -> (action, policy_state)` for ONE env (it is vmapped),
where `obs` is the env's observation dict; a trained run's is `ppo.deterministic_policy` (tanh of the
mean, force control where p_force > 0.5; `mean_action='pre_tanh'`: the pre-tanh mean, unclipped, as the
authors' evaluation sends it). Metrics come only from the env's own per-step info; over
seeds they are reported as mean +- standard error.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import pathlib
from typing import Any, Callable

import jax
import jax.numpy as jnp
import jax.scipy.stats  # noqa: F401
import numpy as np

from match_jax.training import analysis
from match_jax.envs import baselines
from match_jax.envs import FPiHConfig, FPiHEnv
from match_jax.envs.fpih import BREAK_SAMPLINGS, break_signal
from match_jax.rl.ppo import PPOConfig, deterministic_policy, make_trainer
from match_jax.training.runs import batch_mesh, load_policies, load_spec, on_backend, shard_batch, sized_for_batch

Policy = Callable[[dict, Any, jax.Array], tuple[jax.Array, Any]]

# The authors' noise sweep: per episode a uniformly random 3-D direction times a radius drawn from
# U[previous edge, level] (mm): shells 0-1, 1-2.5, 2.5-5, 5-7.5.
SHELL_EDGES_MM = (0.0, 1.0, 2.5, 5.0, 7.5)
NOISE_KINDS = ("gaussian", "uniform", "shell")
# The deterministic action of a squashed policy: 'tanh' = tanh of the mean, clipped to [-1, 1] by the env
# (ours, and what the authors' robot scripts send); 'pre_tanh' = the pre-tanh mean, unclipped (the
# authors' simulated evaluation).
MEAN_ACTIONS = ("tanh", "pre_tanh")


def shell_inner_mm(level_mm: float) -> float:
    """Inner radius (mm) of the noise shell whose outer radius is `level_mm`: the largest edge of
    SHELL_EDGES_MM below it (0 for levels up to 1 mm)."""
    return max([edge for edge in SHELL_EDGES_MM if edge < level_mm], default=0.0)


def shell_offsets(direction_draw: jax.Array, radius_draw: jax.Array, inner_m, outer_m) -> jax.Array:
    """Offsets (m, (..., 3)) on a spherical shell: direction = the standard-normal `direction_draw`
    (..., 3) normalised (uniform on the sphere), radius = inner + u (outer - inner) with u the U(0, 1)
    `radius_draw` (...,) (uniform in radius, as the authors sample it)."""
    norm = jnp.linalg.norm(direction_draw, axis=-1, keepdims=True)
    direction = direction_draw / jnp.maximum(norm, 1e-12)
    radius = inner_m + radius_draw * (outer_m - inner_m)
    return direction * radius[..., None]


# Per-step info recorded during a rollout: name -> key in State.info.
RECORDED = ("success", "engaged", "broken", "in_contact", "mean_force", "max_force", "phase",
            "position_axes", "contact_axes", "truncation", "ee_force")


def make_rollout(env, policy: Policy, num_steps: int | None = None, batched_policy_state: bool = True,
                 record_obs: bool = False, record_qpos: bool = False):
    """A jittable function (keys (B, 2), policy_state) -> trajectory dict of (T, B, ...) arrays.

    Each env runs exactly one episode of `num_steps` (default env.config.episode_steps) policy steps
    from `env.reset(key)`; steps after the episode ended (break) are marked by `done_before`.
    `policy_state` has a leading batch axis, or (batched_policy_state=False) is shared by all envs,
    e.g. a learned policy's parameters. record_obs=True also records 'policy_obs', the policy
    observation each action was computed from; record_qpos=True 'qpos', the joint positions (rad)
    after each step.
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
            if record_qpos:
                record["qpos"] = state.pipeline_state.qpos
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
    The authors' metrics (their evaluation code), as per-episode sums that `summarize` pools:
    authors_time_to_success_s: first success step (0-based) * policy_dt; authors_force_sum_n /
      authors_contact_steps: |end-of-step force signal| summed over the steps ending with some axis of the
      peg in contact (|F_i| > 1 N, true contact), and their count (the break step included);
      authors_axis_force_steps / authors_axis_force_contact_steps, authors_axis_position_steps /
      authors_axis_position_free_steps: (B, 3) per-axis counts of force- (position-) selected steps and of
      those ending in contact (in free space), behind their force- and position-control accuracies.
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
    end_contact_axes = traj["contact_axes"] > 0  # (T, B, 3), at the end of the step
    end_contact = end_contact_axes.any(axis=-1) & (alive > 0)
    force_norm = np.linalg.norm(traj["ee_force"], axis=-1)
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
        "authors_time_to_success_s": np.where(success, first_success * policy_dt, np.nan),
        "authors_force_sum_n": (force_norm * end_contact).sum(axis=0),
        "authors_contact_steps": end_contact.sum(axis=0),
        "authors_axis_force_steps": (axis_force & axis_alive).sum(axis=0),
        "authors_axis_force_contact_steps": (axis_force & end_contact_axes & axis_alive).sum(axis=0),
        "authors_axis_position_steps": (~axis_force & axis_alive).sum(axis=0),
        "authors_axis_position_free_steps": (~axis_force & ~end_contact_axes & axis_alive).sum(axis=0),
    }


def authors_rates(metrics: dict[str, np.ndarray]) -> dict[str, float]:
    """The authors' pooled metrics over all episodes of `metrics` (`episode_metrics`): mean force (N) over
    every step that ends in contact; force-control accuracy = force-selected axis-steps ending in contact /
    force-selected axis-steps, position-control accuracy = position-selected axis-steps ending in free
    space / position-selected axis-steps, each per axis then averaged over x, y, z. NaN where undefined."""
    def ratio(num, den):
        num, den = float(np.sum(num)), float(np.sum(den))
        return num / den if den > 0 else float("nan")

    def axis_mean(num_key, den_key):
        num = np.asarray(metrics[num_key], np.float64).sum(axis=0)
        den = np.asarray(metrics[den_key], np.float64).sum(axis=0)
        rates = [n / d for n, d in zip(num, den) if d > 0]
        return float(np.mean(rates)) if rates else float("nan")

    return {
        "authors_mean_force_n": ratio(metrics["authors_force_sum_n"], metrics["authors_contact_steps"]),
        "authors_force_accuracy": axis_mean("authors_axis_force_contact_steps", "authors_axis_force_steps"),
        "authors_position_accuracy": axis_mean("authors_axis_position_free_steps", "authors_axis_position_steps"),
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
        "authors_time_to_success_s": nanmean(metrics["authors_time_to_success_s"]),
        **authors_rates(metrics),
    }


def mean_and_standard_error(values) -> tuple[float, float]:
    """Mean and standard error over seeds (NaN entries dropped; SE is NaN with fewer than 2 values)."""
    x = np.asarray([v for v in values if v is not None and not np.isnan(v)], np.float64)
    if len(x) == 0:
        return float("nan"), float("nan")
    se = float(np.std(x, ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")
    return float(np.mean(x)), se


SELECTION_COLUMNS = ("force_selected_contact", "force_selected_free", "force_selected_contact_per_axis",
                     "force_selected_free_per_axis", "authors_force_accuracy", "authors_position_accuracy")
COLUMNS = ("success_rate", "break_rate", "mean_time_to_success_s", "mean_force_n", *SELECTION_COLUMNS,
           "break_rate_peak", "break_rate_policy_step", "authors_time_to_success_s", "authors_mean_force_n")
AXIS_COLUMNS = tuple(f"force_selected_{where}_{axis}" for where in ("contact", "free") for axis in "xyz")


def evaluation_config(ppo: PPOConfig, env_config: FPiHConfig) -> tuple[PPOConfig, FPiHConfig]:
    """What a run's evaluation program depends on: the policy (method and network) and the env, with the
    settings the grid replaces set to fixed values: learning settings and SSL (training only), break
    force (the rollout is unbreakable, thresholds are applied afterwards) and hole-observation noise (the
    grid sets every episode's offset). Runs that differ only in those share one compiled rollout."""
    # Hybrid-Basic and MATCH differ only in their log-prob: their deterministic policies are one function
    policy = PPOConfig(method="match" if ppo.method == "hybrid" else ppo.method, network=ppo.network)
    env = dataclasses.replace(env_config, break_force=math.inf, hole_obs_noise=FPiHConfig.hole_obs_noise,
                              hole_obs_noise_type=FPiHConfig.hole_obs_noise_type)
    return policy, env


@functools.lru_cache(maxsize=4)
def _grid_rollout(ppo: PPOConfig, env_config: FPiHConfig, mean_action: str = "tanh"):
    """(unbreakable env, jitted rollout) of a run configuration's deterministic policy (`mean_action`, one
    of MEAN_ACTIONS), compiled once per process and shape (`evaluation_config`): (keys (S, E, 2), stacked
    (params, policy_stats) of S seeds, hole observation offsets (S, L, E, 3) m) -> trajectory dict of
    (S, L, T, E, ...) arrays, with 'p_force' (T, E, 3) for hybrid methods."""
    squash = mean_action == "tanh"
    if not squash:
        env_config = dataclasses.replace(env_config, actions=dataclasses.replace(env_config.actions, clip=False))
    env = FPiHEnv(env_config)
    trainer = make_trainer(ppo, env)  # for its policy head and distribution; nothing of it is compiled
    hybrid = trainer.distribution.num_selections > 0
    rollout = make_rollout(env, deterministic_policy(trainer, squash), batched_policy_state=False,
                           record_obs=hybrid)

    def one_level(keys, policy_state, offsets):
        traj = rollout(keys, policy_state, offsets)
        if hybrid:  # probability of force control behind every action, (T, E, 3)
            params, stats = policy_state
            traj["p_force"] = jax.nn.sigmoid(trainer.policy_head(params, stats, traj.pop("policy_obs")).logits)
        return traj

    def one_seed(keys, policy_state, offsets):  # offsets (L, E, 3)
        return jax.vmap(one_level, in_axes=(None, None, 0))(keys, policy_state, offsets)

    return env, jax.jit(jax.vmap(one_seed))


def evaluate_run_grid(run_dir: str | pathlib.Path, episodes: int = 100, noise_levels_mm=None,
                      noise_type: str | None = None, break_forces=None, checkpoint: str = "best",
                      seed: int = 1000, return_trajectories: bool = False, noise_specs=None,
                      physics_backend: str | None = None, env_config: FPiHConfig | None = None,
                      mean_action: str = "tanh") -> list[dict]:
    """Evaluate every seed of a run at several noise levels and break thresholds in ONE compiled rollout.

    The rollout runs unbreakable; a break threshold is applied afterwards (identical up to the first
    break, see `apply_break_threshold`). The hole-position observation error of episode e is
    level x z_e, with z_e the same standard-gaussian (or uniform +-1) draw at every level, so noise
    levels are compared on the same episodes. Defaults: the run's training noise level and type, and
    its break threshold. `noise_specs`, a list of (level mm, 'gaussian' | 'uniform'), replaces
    noise_levels_mm / noise_type to mix noise types in the same compiled rollout. Returns one result
    dict (see `evaluate_run`) per (noise level, break force). `physics_backend` ('jax' | 'warp'; None: the
    run's own) evaluates the policies on that physics backend. `env_config` (None: the run's) replaces the
    run's task config, e.g. with a softer contact; it must keep the run's controller and observations.
    `mean_action` (MEAN_ACTIONS): 'tanh' (tanh of the mean) or 'pre_tanh' (the authors' evaluation: the
    pre-tanh mean, unclipped).
    """
    if not (isinstance(episodes, int) and episodes >= 1):
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    if mean_action not in MEAN_ACTIONS:
        raise ValueError(f"mean_action must be one of {MEAN_ACTIONS}, got {mean_action!r}")
    spec = load_spec(run_dir)
    if env_config is not None:
        if env_config.control != spec.env.control or env_config.observe_torque != spec.env.observe_torque:
            raise ValueError(f"the run's policies need control={spec.env.control!r} and observe_torque="
                             f"{spec.env.observe_torque}; the env to evaluate them on has {env_config.control!r} "
                             f"and {env_config.observe_torque}")
        spec = dataclasses.replace(spec, env=env_config)
    spec = on_backend(spec, physics_backend)
    if noise_specs is None:
        levels = [spec.env.hole_obs_noise * 1000.0] if noise_levels_mm is None else [float(x) for x in noise_levels_mm]
        noise_specs = [(level, noise_type or spec.env.hole_obs_noise_type) for level in levels]
    levels, types = [float(level) for level, _ in noise_specs], [kind for _, kind in noise_specs]
    if any(kind not in NOISE_KINDS for kind in types):
        raise ValueError(f"noise types must be one of {NOISE_KINDS}, got {types}")
    break_forces = [spec.env.break_force] if break_forces is None else [float(f) for f in break_forces]
    if any(not f > 0 for f in break_forces) or any(not (x >= 0 and math.isfinite(x)) for x in levels):
        raise ValueError(f"break forces must be > 0 and noise levels finite >= 0, got {break_forces}, {levels}")
    run, policies = load_policies(run_dir, checkpoint, spec.env.physics_backend)
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *[(p["params"], p["policy_stats"]) for p in policies])
    hybrid = run.trainer.distribution.num_selections > 0
    env, grid_rollout = _grid_rollout(*evaluation_config(spec.ppo, sized_for_batch(spec.env, episodes)),
                                      mean_action)
    k_episodes, k_noise = jax.random.split(jax.random.PRNGKey(seed))
    keys = jax.random.split(k_episodes, spec.num_seeds * episodes).reshape(spec.num_seeds, episodes, 2)
    shape = (spec.num_seeds, 1, episodes, 3)
    z_gauss = jax.random.normal(k_noise, shape)
    z_uniform = 2.0 * jax.scipy.stats.norm.cdf(z_gauss) - 1.0  # the same draw, mapped to U(-1, 1)
    is_gauss = jnp.asarray([kind == "gaussian" for kind in types])[None, :, None, None]
    z = jnp.where(is_gauss, z_gauss, z_uniform)
    offsets = jnp.asarray(levels)[None, :, None, None] / 1000.0 * z  # (S, L, E, 3), m
    is_shell = jnp.asarray([kind == "shell" for kind in types])[None, :, None, None]
    inner = jnp.asarray([shell_inner_mm(level) for level in levels])[None, :, None] / 1000.0
    u_radius = jax.random.uniform(jax.random.fold_in(k_noise, 1), shape[:-1])  # the same draw at every level
    shells = shell_offsets(z_gauss, u_radius, inner, jnp.asarray(levels)[None, :, None] / 1000.0)
    offsets = jnp.where(is_shell, shells, offsets)
    # Episodes split over the CPU devices (one per core), if they divide evenly.
    mesh = batch_mesh(episodes, spec.env.physics_backend)
    # One (seed, level) per call, `episodes` envs: the control law's batched LAPACK LU splits a large
    # batch over XLA's CPU thread pool, and on 2 cores a 3-seed x 6-level x 200-episode call deadlocked
    # that pool (every thread waiting in lapack_sgetrf's ParallelBatchMap).
    calls = [[jax.device_get(grid_rollout(shard_batch(keys[s:s + 1], 1, mesh),
                                          jax.tree_util.tree_map(lambda x: x[s:s + 1], stacked),
                                          shard_batch(offsets[s:s + 1, li:li + 1], 2, mesh)))
              for li in range(len(levels))] for s in range(spec.num_seeds)]
    traj = {k: np.concatenate([np.concatenate([c[k] for c in row], axis=1) for row in calls], axis=0)
            for k in calls[0][0]}  # (S, L, T, E, ...)
    results = grid_results(traj, spec, noise_specs, break_forces, env.dt, hybrid, str(run_dir), checkpoint,
                           return_trajectories)
    return [{**result, "mean_action": mean_action} for result in results]


def grid_results(traj: dict, spec, noise_specs, break_forces, policy_dt: float, hybrid: bool, run_dir: str,
                 checkpoint: str = "best", return_trajectories: bool = False) -> list[dict]:
    """The result dicts of `evaluate_run_grid` from its unbreakable rollout `traj`, a dict of
    (seeds, levels, T, episodes, ...) arrays (with 'p_force' (..., 3) for hybrid methods): one per
    (noise level, break force), each break threshold applied afterwards under both break samplings."""
    levels, types = [float(level) for level, _ in noise_specs], [kind for _, kind in noise_specs]
    episodes = int(np.shape(traj["success"])[-1])
    results = []
    for li, (level, noise_type) in enumerate(zip(levels, types)):
        for force in break_forces:
            per_seed, seed_trajs = [], []
            for i in range(spec.num_seeds):
                unbroken = {k: v[i, li] for k, v in traj.items()}
                by_sampling = {}  # both samplings on the same episodes; the run's own one is the summary
                for sampling in BREAK_SAMPLINGS if math.isfinite(force) else (spec.env.break_sampling,):
                    broken = apply_break_threshold(unbroken, force, sampling) \
                        if math.isfinite(force) else unbroken
                    by_sampling[sampling] = (broken, summarize(episode_metrics(broken, policy_dt)))
                seed_traj, summary = by_sampling[spec.env.break_sampling]
                seed_trajs.append(seed_traj)
                for s in BREAK_SAMPLINGS:  # unbreakable: one rollout, no break under either sampling
                    summary[f"break_rate_{s}"] = (by_sampling[s][1] if s in by_sampling else summary)["break_rate"]
                summary["seed"] = spec.seed + i
                if not hybrid:  # no selection: the force-selection columns do not apply
                    for column in SELECTION_COLUMNS + AXIS_COLUMNS:
                        summary[column] = float("nan")
                else:
                    summary.update(analysis.contact_selection_rates(
                        seed_traj["in_contact"], seed_traj["p_force"], 1.0 - seed_traj["done_before"]))
                per_seed.append(summary)
            result = {
                "run_dir": run_dir,
                "method": spec.ppo.method,
                "ssl_coef": spec.ppo.ssl_beta,
                "checkpoint": checkpoint,
                "episodes_per_seed": episodes,
                "seeds": spec.num_seeds,
                "noise_mm": level,
                "noise_type": noise_type,
                "break_force_n": force if math.isfinite(force) else None,
                "break_sampling": spec.env.break_sampling,
                "per_seed": per_seed,
                "aggregate": _aggregate(per_seed, hybrid),
            }
            if hybrid:  # the paper's selection figure, over all seeds' episodes
                flat = {k: np.concatenate([t[k] for t in seed_trajs], axis=1)
                        for k in ("phase", "p_force", "done_before")}
                profile = analysis.selection_profile(flat["phase"], flat["p_force"], 1.0 - flat["done_before"])
                result["selection_profile"] = {k: np.asarray(v).tolist() for k, v in profile.items()}
            if return_trajectories:
                result["trajectories"] = seed_trajs
            results.append(result)
    return results


def _aggregate(per_seed: list[dict], hybrid: bool) -> dict:
    columns = COLUMNS + AXIS_COLUMNS + (("p_force_contact", "p_force_free") if hybrid else ())
    out = {}
    for column in columns:
        mean, se = mean_and_standard_error([s[column] for s in per_seed])
        out[column] = {"mean": mean, "se": se}
    return out


def evaluate_run(run_dir: str | pathlib.Path, episodes: int = 100, noise_mm: float | None = None,
                 noise_type: str | None = None, break_force: float | None = None, checkpoint: str = "best",
                 seed: int = 1000, return_trajectories: bool = False, physics_backend: str | None = None,
                 mean_action: str = "tanh") -> dict:
    """Evaluate every seed of a run on `episodes` episodes each; per-seed and mean +- SE metrics.

    noise_mm / noise_type / break_force / physics_backend override the run's settings (None: as trained);
    mean_action: see `evaluate_run_grid`.
    """
    return evaluate_run_grid(run_dir, episodes, None if noise_mm is None else [noise_mm], noise_type,
                             None if break_force is None else [break_force], checkpoint, seed,
                             return_trajectories, physics_backend=physics_backend, mean_action=mean_action)[0]


# eval.py's table: (column, label, scale). The default columns are the headline numbers as the README
# quotes them: time and force by the authors' definitions.
HEADLINE_TABLE = (("success_rate", "success %", 100), ("break_rate", "break %", 100),
                  ("authors_time_to_success_s", "time (s)", 1), ("authors_mean_force_n", "force (N)", 1))
FULL_TABLE = tuple(zip(COLUMNS, ("success %", "break %", "time (s)", "force (N)", "F-sel contact %", "F-sel free %",
                                 "F-sel/axis cont %", "F-sel/axis free %", "auth F-acc %", "auth P-acc %",
                                 "break peak %", "break 15Hz %", "auth time (s)", "auth force (N)"),
                       (100, 100, 1, 1, 100, 100, 100, 100, 100, 100, 100, 100, 1, 1)))
BREAK_CHECKS = {"policy_step": "wrist |F| at 15 Hz", "peak": "peak peg contact |F|"}  # FPiHConfig.break_sampling


def format_result(result: dict, all_columns: bool = False) -> str:
    """A readable table: a title, one row per seed, the mean +- SE row and a one-line legend. By default
    success %, break %, time to success (s) and mean contact force (N), the last two by the authors'
    definitions; all_columns=True: every column of COLUMNS, ours and the authors' (docs/evaluation.md)."""
    head = (f"{result['method']} (ssl {result['ssl_coef']:g}), {result['checkpoint']} checkpoint, "
            f"{result['episodes_per_seed']} episodes x {result['seeds']} seeds, hole noise {result['noise_mm']:g} mm "
            f"({result['noise_type']}), break force {result['break_force_n'] or 'none'}"
            + (", pre-tanh mean actions" if result.get("mean_action") == "pre_tanh" else ""))
    table, width = (FULL_TABLE, 19) if all_columns else (HEADLINE_TABLE, 15)
    lines = [head, "  seed    " + "".join(f"{name:>{width}}" for _, name, _ in table)]
    for s in result["per_seed"]:
        lines.append(f"  {s['seed']:<8}" + "".join(f"{_fmt(s[c] * k):>{width}}" for c, _, k in table))
    agg = result["aggregate"]
    lines.append("  mean+-SE" + "".join(f"{_fmt_mean_se(agg[c]['mean'] * k, agg[c]['se'] * k):>{width}}"
                                        for c, _, k in table))
    if all_columns:
        lines.append(f"  break %: the run's break check ({result['break_sampling']}); auth: the authors' definitions; "
                     "F-sel: force selected; docs/evaluation.md")
    else:
        force = result["break_force_n"]
        check = f"break: {BREAK_CHECKS.get(result['break_sampling'], result['break_sampling'])} > {force:g} N" \
            if force else "no break threshold"
        lines.append(f"  {check}; time to success (s), mean contact force (N): the authors' definitions; "
                     "more: --all-columns")
    return "\n".join(lines)


def _fmt(x: float) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.1f}" if abs(x) >= 10 else f"{x:.2f}"


def _fmt_mean_se(mean: float, se: float) -> str:
    if math.isnan(mean):
        return "-"
    return _fmt(mean) if math.isnan(se) else f"{_fmt(mean)} +- {_fmt(se)}"


def baseline_env(name: str, noise_m: float, noise_type: str = "gaussian", break_force: float = 10.0,
                 **task):
    """The fPiH env a baseline runs in: its controller, the given hole noise (m) and break threshold (N),
    and any other FPiHConfig field from `task` (e.g. break_sampling, randomization)."""
    return FPiHEnv(FPiHConfig(control=baselines.BASELINES[name][0], hole_obs_noise=noise_m,
                              hole_obs_noise_type=noise_type, break_force=break_force, **task))


def evaluate_baseline(name: str, episodes: int, noise_m: float, noise_type: str = "gaussian",
                      break_force: float = 10.0, seed: int = 0, batch: int = 0, **task) -> dict:
    """Run `episodes` episodes of a scripted baseline (`match_jax.envs.baselines`); the `summarize` dict and settings.
    noise_type 'shell': the hole offset lies on the shell out to `noise_m` (`shell_offsets`). `batch` > 0
    runs the episodes in compiled batches of that size (0: all at once); `task`: other FPiHConfig fields."""
    if noise_type not in NOISE_KINDS:
        raise ValueError(f"noise_type must be one of {NOISE_KINDS}, got {noise_type!r}")
    shell = noise_type == "shell"
    # the rollout runs unbreakable; each break sampling's threshold is applied afterwards (`apply_break_threshold`)
    env = baseline_env(name, 0.0 if shell else noise_m, "gaussian" if shell else noise_type, math.inf, **task)
    sampling = env.config.break_sampling
    policy, policy_state = baselines.make_baseline(name, env)
    rollout = jax.jit(make_rollout(env, policy))
    batch = batch or episodes
    keys = jax.random.split(jax.random.PRNGKey(seed), episodes)
    offsets = None
    if shell:
        k_dir, k_radius = jax.random.split(jax.random.PRNGKey(seed + 7919))
        offsets = np.asarray(shell_offsets(jax.random.normal(k_dir, (episodes, 3)),
                                           jax.random.uniform(k_radius, (episodes,)),
                                           shell_inner_mm(noise_m * 1000.0) / 1000.0, noise_m))
    per_episode = []
    for start in range(0, episodes, batch):
        chunk = keys[start:start + batch]
        chunk_offsets = None if offsets is None else offsets[start:start + batch]
        if len(chunk) < batch:  # pad to the compiled batch size, drop the padding afterwards
            chunk = np.concatenate([chunk, keys[: batch - len(chunk)]])
            if offsets is not None:
                chunk_offsets = np.concatenate([chunk_offsets, offsets[: batch - len(chunk_offsets)]])
        states = jax.tree_util.tree_map(lambda x: np.broadcast_to(x, (batch,) + x.shape), policy_state)
        traj = rollout(chunk, states) if offsets is None else rollout(chunk, states, chunk_offsets)
        n = min(batch, episodes - start)
        by_sampling = {}
        for s in BREAK_SAMPLINGS:
            broken = apply_break_threshold(traj, break_force, s) if math.isfinite(break_force) else traj
            by_sampling[s] = {k: v[:n] for k, v in episode_metrics(broken, env.dt).items()}
        per_episode.append(by_sampling)
    merged = {s: {k: np.concatenate([m[s][k] for m in per_episode]) for k in per_episode[0][s]}
              for s in BREAK_SAMPLINGS}
    summary = summarize(merged[sampling])
    for s in BREAK_SAMPLINGS:
        summary[f"break_rate_{s}"] = float(np.mean(merged[s]["broken"]))
    config = dataclasses.replace(env.config, break_force=break_force, hole_obs_noise=noise_m,
                                 hole_obs_noise_type=noise_type if not shell else env.config.hole_obs_noise_type)
    summary.update(baseline=name, noise_mm=noise_m * 1000.0, noise_type=noise_type,
                   break_force_n=break_force if math.isfinite(break_force) else None, break_sampling=sampling,
                   seed=seed, env_config={k: v for k, v in dataclasses.asdict(config).items()
                                          if isinstance(v, (int, float, str))})
    return summary
