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
import numpy as np

from match_jax import analysis, evaluation
from match_jax.envs import FPiHEnv
from match_jax.training import RunError, load_policy, load_spec

COLUMNS = ("success_rate", "break_rate", "mean_time_to_success_s", "mean_force_n", "force_selected_contact",
           "force_selected_free")


def eval_env_config(spec, noise_mm: float | None = None, noise_type: str | None = None,
                    break_force: float | None = None):
    """The run's task settings with the evaluation's noise and break threshold swapped in."""
    cfg = spec.env
    if noise_mm is not None:
        cfg = dataclasses.replace(cfg, hole_obs_noise=noise_mm / 1000.0)
    if noise_type is not None:
        cfg = dataclasses.replace(cfg, hole_obs_noise_type=noise_type)
    if break_force is not None:
        cfg = dataclasses.replace(cfg, break_force=break_force)
    return cfg


def make_policy(trainer):
    """policy(obs, (params, policy_stats), key) -> (deterministic action, same state)."""
    dist = trainer.distribution

    def policy(obs, policy_state, key):
        params, stats = policy_state
        head = trainer.policy_head(params, stats, obs["state"])
        return dist.to_action(dist.mode(head)), policy_state

    return policy


def evaluate_run(run_dir: str | pathlib.Path, episodes: int = 100, noise_mm: float | None = None,
                 noise_type: str | None = None, break_force: float | None = None, checkpoint: str = "best",
                 seed: int = 1000, return_trajectories: bool = False) -> dict:
    """Evaluate every seed of a run on `episodes` episodes each; returns per-seed and aggregate metrics.

    noise_mm / noise_type / break_force override the run's task settings (None: as trained).
    """
    if not (isinstance(episodes, int) and episodes >= 1):
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    spec = load_spec(run_dir)
    env = FPiHEnv(eval_env_config(spec, noise_mm, noise_type, break_force))
    policies = []
    run = None
    for i in range(spec.num_seeds):
        run, policy = load_policy(run_dir, i, checkpoint)
        policies.append((policy["params"], policy["policy_stats"]))
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *policies)
    hybrid = run.trainer.distribution.num_selections > 0
    rollout = evaluation.make_rollout(env, make_policy(run.trainer), batched_policy_state=False, record_obs=hybrid)

    def rollout_and_p_force(keys, policy_state):
        traj = rollout(keys, policy_state)
        if hybrid:  # probability of force control behind every action, (T, E, 3)
            params, stats = policy_state
            traj["p_force"] = jax.nn.sigmoid(run.trainer.policy_head(params, stats, traj.pop("policy_obs")).logits)
        return traj

    keys = jax.random.split(jax.random.PRNGKey(seed), spec.num_seeds * episodes).reshape(spec.num_seeds, episodes, 2)
    traj = jax.jit(jax.vmap(rollout_and_p_force))(keys, stacked)  # (S, T, E, ...)
    traj = jax.device_get(traj)
    per_seed = []
    for i in range(spec.num_seeds):
        seed_traj = {k: v[i] for k, v in traj.items()}
        metrics = evaluation.episode_metrics(seed_traj, env.dt)
        summary = evaluation.summarize(metrics)
        summary["seed"] = spec.seed + i
        if hybrid:
            alive = 1.0 - seed_traj["done_before"]
            summary.update(analysis.contact_selection_rates(seed_traj["in_contact"], seed_traj["p_force"], alive))
        per_seed.append(summary)
    aggregate = {}
    for column in COLUMNS:
        mean, se = evaluation.mean_and_standard_error([s[column] for s in per_seed])
        aggregate[column] = {"mean": mean, "se": se}
    result = {
        "run_dir": str(run_dir),
        "method": spec.ppo.method,
        "ssl_coef": spec.ppo.ssl_coef,
        "checkpoint": checkpoint,
        "episodes_per_seed": episodes,
        "seeds": spec.num_seeds,
        "noise_mm": env.config.hole_obs_noise * 1000.0,
        "noise_type": env.config.hole_obs_noise_type,
        "break_force_n": env.config.break_force if math.isfinite(env.config.break_force) else None,
        "per_seed": per_seed,
        "aggregate": aggregate,
    }
    if hybrid:  # the paper's selection figure, over all seeds' episodes
        flat = {k: np.concatenate(list(traj[k]), axis=1) for k in ("phase", "p_force", "done_before")}
        profile = analysis.selection_profile(flat["phase"], flat["p_force"], 1.0 - flat["done_before"])
        result["selection_profile"] = {k: np.asarray(v).tolist() for k, v in profile.items()}
        for key in ("p_force_contact", "p_force_free"):
            mean, se = evaluation.mean_and_standard_error([s[key] for s in per_seed])
            result["aggregate"][key] = {"mean": mean, "se": se}
    if return_trajectories:
        result["trajectories"] = traj
    return result


def format_result(result: dict) -> str:
    """A readable table: one row per seed and the mean +- SE row."""
    head = (f"{result['method']} (ssl {result['ssl_coef']:g}), {result['checkpoint']} checkpoint, "
            f"{result['episodes_per_seed']} episodes x {result['seeds']} seeds, hole noise {result['noise_mm']:g} mm "
            f"({result['noise_type']}), break force {result['break_force_n'] or 'none'}")
    names = ("success %", "break %", "time (s)", "force (N)", "F-sel contact %", "F-sel free %")
    scale = (100, 100, 1, 1, 100, 100)
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
