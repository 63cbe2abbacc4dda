"""Evaluate the policies of a training run: every seed, deterministic actions, one jitted batch.

    from match_jax.run_eval import evaluate_run
    result = evaluate_run("runs/match_cpu", episodes=100)             # at the training noise
    result = evaluate_run("runs/match_cpu", episodes=500, noise_mm=5.0, noise_type="uniform")

The deterministic policy is tanh of the mean, with force control where p_force > 0.5. Metrics are the
paper's Table 1 columns (match_jax.evaluation), per seed and as mean +- standard error over seeds.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib

import jax
import jax.numpy as jnp
import jax.scipy.stats  # noqa: F401
import numpy as np

from match_jax import analysis, evaluation
from match_jax.envs import FPiHEnv
from match_jax.envs.fpih import BREAK_SAMPLINGS
from match_jax.ppo import deterministic_action
from match_jax.training import RunError, batch_mesh, load_policies, load_spec, shard_batch

SELECTION_COLUMNS = ("force_selected_contact", "force_selected_free", "force_selected_contact_per_axis",
                     "force_selected_free_per_axis")
COLUMNS = ("success_rate", "break_rate", "mean_time_to_success_s", "mean_force_n", *SELECTION_COLUMNS,
           "break_rate_peak", "break_rate_policy_step")
AXIS_COLUMNS = tuple(f"force_selected_{where}_{axis}" for where in ("contact", "free") for axis in "xyz")


def make_policy(trainer):
    """policy(obs, (params, policy_stats), key) -> (deterministic action, same state): the parameters
    travel as the policy state, so one compiled rollout serves every seed."""

    def policy(obs, policy_state, key):
        return deterministic_action(trainer, *policy_state, obs["state"]), policy_state

    return policy


def evaluate_run_grid(run_dir: str | pathlib.Path, episodes: int = 100, noise_levels_mm=None,
                      noise_type: str | None = None, break_forces=None, checkpoint: str = "best",
                      seed: int = 1000, return_trajectories: bool = False, noise_specs=None) -> list[dict]:
    """Evaluate every seed of a run at several noise levels and break thresholds in ONE compiled rollout.

    The rollout runs unbreakable; a break threshold is applied afterwards (identical up to the first
    break, see `evaluation.apply_break_threshold`). The hole-position observation error of episode e is
    level x z_e, with z_e the same standard-gaussian (or uniform +-1) draw at every level, so noise
    levels are compared on the same episodes. Defaults: the run's training noise level and type, and
    its break threshold. `noise_specs`, a list of (level mm, 'gaussian' | 'uniform'), replaces
    noise_levels_mm / noise_type to mix noise types in the same compiled rollout. Returns one result
    dict (see `evaluate_run`) per (noise level, break force).
    """
    if not (isinstance(episodes, int) and episodes >= 1):
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    spec = load_spec(run_dir)
    if noise_specs is None:
        levels = [spec.env.hole_obs_noise * 1000.0] if noise_levels_mm is None else [float(x) for x in noise_levels_mm]
        noise_specs = [(level, noise_type or spec.env.hole_obs_noise_type) for level in levels]
    levels, types = [float(level) for level, _ in noise_specs], [kind for _, kind in noise_specs]
    if any(kind not in ("gaussian", "uniform") for kind in types):
        raise ValueError(f"noise types must be 'gaussian' or 'uniform', got {types}")
    break_forces = [spec.env.break_force] if break_forces is None else [float(f) for f in break_forces]
    if any(not f > 0 for f in break_forces) or any(not (x >= 0 and math.isfinite(x)) for x in levels):
        raise ValueError(f"break forces must be > 0 and noise levels finite >= 0, got {break_forces}, {levels}")
    env = FPiHEnv(dataclasses.replace(spec.env, break_force=math.inf))  # breaks are applied afterwards
    run, policies = load_policies(run_dir, checkpoint)
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *[(p["params"], p["policy_stats"]) for p in policies])
    hybrid = run.trainer.distribution.num_selections > 0
    rollout = evaluation.make_rollout(env, make_policy(run.trainer), batched_policy_state=False, record_obs=hybrid)

    def one_level(keys, policy_state, offsets):
        traj = rollout(keys, policy_state, offsets)
        if hybrid:  # probability of force control behind every action, (T, E, 3)
            params, stats = policy_state
            traj["p_force"] = jax.nn.sigmoid(run.trainer.policy_head(params, stats, traj.pop("policy_obs")).logits)
        return traj

    def one_seed(keys, policy_state, offsets):  # offsets (L, E, 3)
        return jax.vmap(one_level, in_axes=(None, None, 0))(keys, policy_state, offsets)

    k_episodes, k_noise = jax.random.split(jax.random.PRNGKey(seed))
    keys = jax.random.split(k_episodes, spec.num_seeds * episodes).reshape(spec.num_seeds, episodes, 2)
    shape = (spec.num_seeds, 1, episodes, 3)
    z_gauss = jax.random.normal(k_noise, shape)
    z_uniform = 2.0 * jax.scipy.stats.norm.cdf(z_gauss) - 1.0  # the same draw, mapped to U(-1, 1)
    is_gauss = jnp.asarray([kind == "gaussian" for kind in types])[None, :, None, None]
    z = jnp.where(is_gauss, z_gauss, z_uniform)
    offsets = jnp.asarray(levels)[None, :, None, None] / 1000.0 * z  # (S, L, E, 3), m
    mesh = batch_mesh(episodes)  # episodes split over the CPU devices (one per core), if they divide evenly
    keys, offsets = shard_batch(keys, 1, mesh), shard_batch(offsets, 2, mesh)
    traj = jax.device_get(jax.jit(jax.vmap(one_seed))(keys, stacked, offsets))  # (S, L, T, E, ...)

    results = []
    for li, (level, noise_type) in enumerate(zip(levels, types)):
        for force in break_forces:
            per_seed, seed_trajs = [], []
            for i in range(spec.num_seeds):
                unbroken = {k: v[i, li] for k, v in traj.items()}
                by_sampling = {}  # both samplings on the same episodes; the run's own one is the summary
                for sampling in BREAK_SAMPLINGS if math.isfinite(force) else (spec.env.break_sampling,):
                    broken = evaluation.apply_break_threshold(unbroken, force, sampling) \
                        if math.isfinite(force) else unbroken
                    by_sampling[sampling] = (broken, evaluation.summarize(evaluation.episode_metrics(broken, env.dt)))
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
                "run_dir": str(run_dir),
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
        mean, se = evaluation.mean_and_standard_error([s[column] for s in per_seed])
        out[column] = {"mean": mean, "se": se}
    return out


def evaluate_run(run_dir: str | pathlib.Path, episodes: int = 100, noise_mm: float | None = None,
                 noise_type: str | None = None, break_force: float | None = None, checkpoint: str = "best",
                 seed: int = 1000, return_trajectories: bool = False) -> dict:
    """Evaluate every seed of a run on `episodes` episodes each; per-seed and mean +- SE metrics.

    noise_mm / noise_type / break_force override the run's task settings (None: as trained).
    """
    return evaluate_run_grid(run_dir, episodes, None if noise_mm is None else [noise_mm], noise_type,
                             None if break_force is None else [break_force], checkpoint, seed,
                             return_trajectories)[0]


def format_result(result: dict) -> str:
    """A readable table: one row per seed and the mean +- SE row."""
    head = (f"{result['method']} (ssl {result['ssl_coef']:g}), {result['checkpoint']} checkpoint, "
            f"{result['episodes_per_seed']} episodes x {result['seeds']} seeds, hole noise {result['noise_mm']:g} mm "
            f"({result['noise_type']}), break force {result['break_force_n'] or 'none'}")
    names = ("success %", "break %", "time (s)", "force (N)", "F-sel contact %", "F-sel free %",
             "F-sel/axis cont %", "F-sel/axis free %", "break peak %", "break 15Hz %")
    scale = (100, 100, 1, 1, 100, 100, 100, 100, 100, 100)
    lines = [head, "  seed    " + "".join(f"{n:>17}" for n in names)]
    for s in result["per_seed"]:
        cells = "".join(f"{_fmt(s[c] * k):>17}" for c, k in zip(COLUMNS, scale))
        lines.append(f"  {s['seed']:<8}" + cells)
    agg = result["aggregate"]
    cells = "".join(f"{_fmt_mean_se(agg[c]['mean'] * k, agg[c]['se'] * k):>17}" for c, k in zip(COLUMNS, scale))
    lines.append("  mean+-SE" + cells)
    return "\n".join(lines)


def _fmt(x: float) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.1f}" if abs(x) >= 10 else f"{x:.2f}"


def _fmt_mean_se(mean: float, se: float) -> str:
    if math.isnan(mean):
        return "-"
    return _fmt(mean) if math.isnan(se) else f"{_fmt(mean)} +- {_fmt(se)}"


def check_run_dir(run_dir: str | pathlib.Path) -> None:
    """RunError unless `run_dir` looks like a training run directory."""
    if not (pathlib.Path(run_dir) / "config.json").exists():
        raise RunError(f"{run_dir} is not a run directory (no config.json)")
