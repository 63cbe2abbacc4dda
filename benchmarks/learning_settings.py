"""Env steps per learned policy under different learning settings, read from training runs.

    python benchmarks/learning_settings.py "cpu preset=results/suite_cpu/runs/match" \
        "lr 1e-3=runs/match_lr1e-3" --up-to 1000000 --json results/learning_settings/summary.json

    python benchmarks/learning_settings.py @results/learning_settings/runs.txt --json results/learning_settings/summary.json

Each argument is LABEL=RUN_DIR, a train.py run directory or an exported run (a run still training
is read as far as it got), or @FILE, a file holding one such argument per line. Per run, from its
per-iteration training metrics, up to the iteration that crosses `--up-to` env steps per seed:
- each seed's env steps to 50 / 80 / 90 % training success, smoothed over one episode per env (the
  suite report's definition; '-' where not reached);
- each seed's best and last smoothed training success;
- the fraction of env steps in contact and the fraction of episodes that broke the peg, mean over
  seeds, averaged over the one-episode window ending at the first iteration reaching 0.25M / 0.5M /
  1M env steps;
- training throughput: env steps of all seeds per second of wall clock, compilation included ('-'
  for a resumed run, whose logged clock restarts; only meaningful for a run alone on the cores).
Prints a markdown table; `--json` also writes the numbers; `--plot FILE.png` draws every run's smoothed
training success and break rate (mean over seeds) against env steps, in one figure.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import pathlib

import numpy as np

from match_jax.experiments import plots
from match_jax.experiments.claims import steps_to
from match_jax.experiments.pipeline import episode_window, metric_arrays
from match_jax.training.runs import load_spec, read_metrics

THRESHOLDS = (0.5, 0.8, 0.9)
READ_AT = (250_000, 500_000, 1_000_000)


def metric_rows(run_dir: pathlib.Path) -> list[dict]:
    """A run's per-iteration metrics: metrics.jsonl, or metrics.csv where only that was kept."""
    if (run_dir / "metrics.jsonl").exists() or not (run_dir / "metrics.csv").exists():
        return read_metrics(run_dir)
    with open(run_dir / "metrics.csv", newline="") as f:
        return [{k: float(v) if v not in ("", None) else None for k, v in row.items()} for row in csv.DictReader(f)]


def run_curves(run_dir: pathlib.Path, up_to: float) -> dict:
    """Seeds x iterations arrays of a run's metrics up to `up_to` env steps per seed, with its config."""
    rows = metric_rows(run_dir)
    per_iteration = min((r["env_steps"] for r in rows), default=0)
    rows = [r for r in rows if r["env_steps"] - per_iteration < up_to]  # the iteration crossing up_to is kept
    if not rows:
        raise SystemExit(f"{run_dir}: no training metrics up to {up_to:g} env steps")
    spec = load_spec(run_dir)
    curves = metric_arrays(rows, ("success_rate", "break_rate", "contact_fraction", "wall_clock_s"))
    return {"window": episode_window(spec), "spec": spec, **curves}


def smoothed(rate: np.ndarray, window: int) -> np.ndarray:
    """Per seed, the mean of the last `window` iterations at each iteration (NaN before a full window)."""
    out = np.full(rate.shape, np.nan)
    for j in range(window - 1, rate.shape[1]):
        out[:, j] = np.nanmean(rate[:, j - window + 1:j + 1], axis=1)
    return out


def smoothed_curves(curves: dict) -> dict:
    """A run's success and break rates smoothed as the table reads them, for the figure."""
    window = curves["window"]
    return {"env_steps": curves["env_steps"], "success_rate": smoothed(curves["success_rate"], window),
            "break_rate": smoothed(curves["break_rate"], window)}


def summarize(curves: dict) -> dict:
    """The numbers of one row of the table (see the module docstring)."""
    steps, window = curves["env_steps"], curves["window"]
    success = smoothed(curves["success_rate"], window)

    def at(key, n):  # the window ending at the first iteration that reaches n env steps
        j = int(np.searchsorted(steps, n, side="left"))
        if j == len(steps):
            return None
        return float(np.nanmean(curves[key][:, max(j - window + 1, 0):j + 1]))

    ppo = curves["spec"].ppo
    clock = np.nanmax(curves["wall_clock_s"], axis=0)
    seconds = float(clock[-1]) if np.all(np.diff(clock) >= 0) else float("nan")  # a resumed run restarts its clock
    return {
        "env_steps_per_seed": float(steps[-1]), "seeds": int(success.shape[0]),
        "settings": {"rollout_steps": ppo.rollout_steps, "epochs": ppo.epochs, "minibatches": ppo.minibatches,
                     "learning_rate": ppo.learning_rate, "learning_rate_end": ppo.learning_rate_end,
                     "gamma": ppo.gamma, "gae_lambda": ppo.gae_lambda, "num_envs": ppo.num_envs,
                     "network": [ppo.network.actor_hidden, ppo.network.actor_blocks,
                                 ppo.network.critic_hidden, ppo.network.critic_blocks],
                     "initial_p_position": ppo.network.initial_p_position,
                     "initial_force_z": ppo.network.initial_force_z},
        "steps_to": {f"{t:g}": [steps_to(steps, seed, t, window) for seed in curves["success_rate"]]
                     for t in THRESHOLDS},
        "best_success": [float(np.nanmax(s)) if np.isfinite(s).any() else float("nan") for s in success],
        "last_success": [float(s[-1]) for s in success],
        "contact_fraction_at": {str(n): at("contact_fraction", n) for n in READ_AT},
        "break_rate_at": {str(n): at("break_rate", n) for n in READ_AT},
        "env_steps_per_s": float(steps[-1]) * success.shape[0] / seconds if seconds > 0 else float("nan"),
    }


def _steps(values) -> str:
    return " / ".join("-" if math.isnan(v) else f"{v / 1e6:.2f}M" for v in values)


def _pct(values) -> str:
    return " / ".join("-" if v is None or math.isnan(v) else f"{100 * v:.0f}" for v in values)


def table(rows: dict[str, dict]) -> str:
    head = ("| run | env steps per seed | to 50 % (per seed) | to 80 % | to 90 % | best / last success % (per seed) "
            "| in contact % at 0.25 / 0.5 / 1M | breaks % at 0.25 / 0.5 / 1M | env steps/s |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for label, r in rows.items():
        best = " / ".join(f"{100 * b:.0f}-{100 * s:.0f}" for b, s in zip(r["best_success"], r["last_success"]))
        lines.append(f"| {label} | {r['env_steps_per_seed'] / 1e6:.2f}M | {_steps(r['steps_to']['0.5'])} "
                     f"| {_steps(r['steps_to']['0.8'])} | {_steps(r['steps_to']['0.9'])} | {best} "
                     f"| {_pct(r['contact_fraction_at'].values())} | {_pct(r['break_rate_at'].values())} "
                     f"| {'-' if math.isnan(r['env_steps_per_s']) else format(r['env_steps_per_s'], ',.0f')} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], fromfile_prefix_chars="@")
    parser.add_argument("runs", nargs="+", help="LABEL=RUN_DIR")
    parser.add_argument("--up-to", type=float, default=1_000_000, help="env steps per seed read (default 1M)")
    parser.add_argument("--json", type=pathlib.Path, default=None, help="also write the numbers here")
    parser.add_argument("--plot", type=pathlib.Path, default=None, help="also draw the curves into this PNG")
    args = parser.parse_args(argv)
    if not args.up_to > 0:
        parser.error(f"--up-to must be > 0 env steps, got {args.up_to:g}")
    if args.plot is not None and args.plot.suffix != ".png":
        parser.error(f"--plot must name a .png file, got {str(args.plot)!r}")
    rows, curves = {}, {}
    for item in args.runs:
        label, sep, path = item.partition("=")
        if not sep or not label or not path:
            parser.error(f"expected LABEL=RUN_DIR, got {item!r}")
        if not pathlib.Path(path).is_dir():
            parser.error(f"run directory {path!r} does not exist")
        curves[label] = run_curves(pathlib.Path(path), args.up_to)
        rows[label] = summarize(curves[label])
    print(table(rows))
    if args.plot:
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plots.success_and_breaks({label: smoothed_curves(c) for label, c in curves.items()}, args.plot)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"up_to": args.up_to, "runs": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
