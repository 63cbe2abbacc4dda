"""The paper's experiment suite: train every method, evaluate, sweep noise, analyse selection, report.

    python -m match_jax.experiments --preset cpu --seeds 3 --out results/suite
    python -m match_jax.experiments --smoke --out /tmp/suite_smoke        # every stage, tiny sizes
    python -m match_jax.experiments --only pose,match --out results/suite # a subset

Runs (each with --seeds seeds in one program): Pose, VICES, Hybrid-Basic, MATCH, MATCH with the authors'
force law (no feed-forward, no damping on force-controlled axes), MATCH (no SSL),
Hybrid-Basic (no SSL), Pose trained at 2.5 mm hole noise, and Pose, VICES, Hybrid-Basic and MATCH trained
with an unbreakable peg. Then, per run, one compiled rollout
evaluates every seed at the training noise (Table 1, --episodes per seed) and over the uniform noise
sweep (0, 1, 2.5, 5, 7.5 mm; --sweep-episodes per seed), each with the run's break force and unbreakable.
Resumable: finished runs and evaluations are skipped, interrupted runs resume from their checkpoint.
An exported suite (--export: report, eval JSONs, best actors) copied into OUT counts its runs as trained
(same configuration, full step budget) and evaluated, so a suite continues from its committed results.
Writes OUT/runs/<name>/ (training), OUT/eval/<name>.json, and OUT/REPORT.md with
learning_curves.png, noise_robustness.png and selection_profile.png.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import pathlib
import sys
import time
from typing import NamedTuple

import match_jax  # noqa: F401  (fast XLA CPU flag)

import numpy as np

from match_jax import checkpoints, claims, compile_cache, plots
from match_jax.envs.tasks import TASKS, task_config
from match_jax.presets import get_preset
from match_jax.evaluation import evaluate_run_grid
from match_jax.checkpoints import CheckpointError
from match_jax.training import (ACTORS_DIR, RunError, RunSpec, actor_path, best_record, export_actors, is_exported,
                                load_spec, read_metrics, record_path, train)

class SuiteRun(NamedTuple):
    """One run of the suite: what it trains, with what task settings."""
    label: str
    method: str  # 'pose', 'vices', 'hybrid' or 'match'
    ssl: bool  # the selection loss on (hybrid methods)
    noise_mm: float  # training hole-observation noise (gaussian std, mm)
    break_force: float  # training break force (N); inf = unbreakable
    force_law: str | None  # None: the task's; 'damped' or 'literal' (`ControllerConfig.with_force_law`)


SUITE = {
    "pose": SuiteRun("Pose", "pose", True, 1.0, 10.0, None),
    "vices": SuiteRun("VICES", "vices", True, 1.0, 10.0, None),
    "hybrid": SuiteRun("Hybrid-Basic", "hybrid", True, 1.0, 10.0, None),
    "match": SuiteRun("MATCH", "match", True, 1.0, 10.0, None),
    "match_literal": SuiteRun("MATCH (authors' force law)", "match", True, 1.0, 10.0, "literal"),
    "match_nossl": SuiteRun("MATCH (no SSL)", "match", False, 1.0, 10.0, None),
    "hybrid_nossl": SuiteRun("Hybrid-Basic (no SSL)", "hybrid", False, 1.0, 10.0, None),
    "pose_noise2.5": SuiteRun("Pose (trained at 2.5 mm)", "pose", True, 2.5, 10.0, None),
    "pose_unbreakable": SuiteRun("Pose (unbreakable)", "pose", True, 1.0, math.inf, None),
    "vices_unbreakable": SuiteRun("VICES (unbreakable)", "vices", True, 1.0, math.inf, None),
    "hybrid_unbreakable": SuiteRun("Hybrid-Basic (unbreakable)", "hybrid", True, 1.0, math.inf, None),
    "match_unbreakable": SuiteRun("MATCH (unbreakable)", "match", True, 1.0, math.inf, None),
}
# Table 1 of the paper: success %, break % (mean over 5 seeds x 100 episodes).
PAPER_TABLE1 = {"pose": (95.4, 1.6), "vices": (95.2, 1.4), "hybrid": (98.2, 0.4), "match": (97.0, 0.0),
                "match_nossl": (82.0, 8.2), "hybrid_nossl": (87.0, 2.6)}
SWEEP_MM = (0.0, 1.0, 2.5, 5.0, 7.5)
HYBRID = tuple(name for name, run in SUITE.items() if run.method in ("hybrid", "match"))  # runs with selections


def unbreakable(name: str) -> bool:
    """Whether suite run `name` trains with an unbreakable peg."""
    return math.isinf(SUITE[name].break_force)


@dataclasses.dataclass(frozen=True)
class SuiteConfig:
    out: pathlib.Path
    preset: str = "cpu"
    task: str = "authors"  # task protocol of every run (`match_jax.envs.tasks`)
    seeds: int = 3
    total_steps: int | None = None
    episodes: int = 100
    sweep_episodes: int = 500
    only: tuple[str, ...] = tuple(SUITE)
    smoke: bool = False
    selection_in_ratio: bool = True  # MATCH with SSL: False = the authors' code (selection by the SSL only)
    time_budget_min: float | None = None  # per run and call: stop training after this much wall clock
    skip_training: bool = False  # evaluate and report the checkpoints that exist, train nothing
    train_only: bool = False  # train (or resume) the runs, evaluate and report nothing
    report_only: bool = False  # report (and export) the current evaluations that exist, train and evaluate nothing
    export: pathlib.Path | None = None  # copy the report, evaluations and best actors here (`export_suite`)


def run_spec(name: str, cfg: SuiteConfig) -> RunSpec:
    """The run spec of suite run `name` under the suite settings `cfg`."""
    run = SUITE[name]
    overrides = {"method": run.method}
    if not run.ssl:
        overrides["ssl_coef"] = 0.0
    if run.method == "match" and run.ssl and not cfg.selection_in_ratio:
        # Without the SSL the selection would get no gradient at all out of the ratio, so no-SSL runs
        # always keep it in (the paper's ablation: selection learned by RL alone).
        overrides["selection_in_ratio"] = False
    if cfg.total_steps is not None:
        overrides["total_steps"] = cfg.total_steps
    ppo = get_preset(cfg.preset, **overrides)
    env = task_config(cfg.task, ppo.control, run.force_law, hole_obs_noise=run.noise_mm / 1000.0,
                      break_force=run.break_force)
    return RunSpec(ppo=ppo, env=env, num_seeds=cfg.seeds, preset=cfg.preset)


def train_one(cfg: SuiteConfig, name: str, log=print) -> bool:
    """Train (or resume) suite run `name` for its budget or cfg.time_budget_min; whether it is finished."""
    run_dir = cfg.out / "runs" / name
    spec = run_spec(name, cfg)
    budget = None if cfg.time_budget_min is None else 60.0 * cfg.time_budget_min
    if is_exported(run_dir):
        return _exported_run_is_finished(run_dir, spec, log)
    if checkpoints.latest_step(checkpoints.latest_dir(run_dir)) is None:
        if checkpoints.read_best_record(run_dir, 0) is not None:
            raise RunError(f"{run_dir} holds best policies but no training state to resume (a copied run): "
                           f"evaluate it with --skip-training, or train into another --out")
        log(f"[train] {name}: starting ({spec.ppo.total_steps:,} steps x {spec.num_seeds} seeds)")
        summary = train(spec, run_dir, progress=not cfg.smoke, time_budget_s=budget)
    else:
        if load_spec(run_dir) != spec:
            raise RunError(f"{run_dir} holds a run with another configuration; use another --out")
        summary = train(None, run_dir, resume=True, progress=not cfg.smoke, time_budget_s=budget)
    log(f"[train] {name}: {summary['iterations']} iterations ({summary['env_steps_per_seed']:,} env steps per "
        f"seed{'' if summary['finished'] else ', stopped early: resumable'}), {summary['wall_clock_s']:.0f} s, "
        f"best training success {_rates(summary['best_success_rate'])}")
    return summary["finished"]


def _exported_run_is_finished(run_dir: pathlib.Path, spec: RunSpec, log=print) -> bool:
    """An exported run (best actors, config, metrics; e.g. a committed results folder copied into --out)
    counts as trained when it has this command's configuration and its metrics reach the step budget:
    it cannot resume, so one exported before its budget is an error naming it."""
    if load_spec(run_dir) != spec:
        raise RunError(f"{run_dir} holds an exported run with another configuration than this command's "
                       f"(seeds, steps, preset, ratio): repeat its options or use another --out")
    steps = max((r["env_steps"] for r in read_metrics(run_dir)), default=0)
    if steps < spec.ppo.total_steps:
        raise RunError(f"{run_dir} is an exported run stopped at {steps:,} of {spec.ppo.total_steps:,} env steps "
                       f"per seed: it holds no training state to resume; train it into another --out (or delete "
                       f"it and eval/{run_dir.name}.json)")
    missing = [p.name for i in range(spec.num_seeds) for p in (record_path(run_dir, i), actor_path(run_dir, i))
               if not p.exists()]
    if missing:
        raise RunError(f"{run_dir} is an exported run without {', '.join(missing)} in actors/")
    log(f"[train] {run_dir.name}: exported run, trained ({steps:,} env steps per seed)")
    return True


def _rates(rates) -> str:
    """Per-seed success rates as '[82%, 0%, none]' (none: no episode ended)."""
    return "[" + ", ".join("none" if r is None else f"{100 * r:.0f}%" for r in rates) + "]"


def _best_iterations(run_dir: pathlib.Path, seeds: int) -> list:
    return [(best_record(run_dir, i) or {}).get("iteration") for i in range(seeds)]


def current_evaluation(cfg: SuiteConfig, name: str) -> list[dict] | None:
    """OUT/eval/<name>.json if it evaluated the run's current best checkpoints, else None."""
    path = cfg.out / "eval" / f"{name}.json"
    if not path.exists():
        return None
    grid = json.loads(path.read_text())
    best = _best_iterations(cfg.out / "runs" / name, cfg.seeds)
    return grid if grid and all(r.get("best_iterations") == best for r in grid) else None


def evaluate_one(cfg: SuiteConfig, name: str, log=print) -> list[dict] | None:
    """The evaluation grid of run `name` (training noise and the uniform sweep, breakable and not): read
    from OUT/eval/<name>.json when it evaluated the run's current best checkpoints, else computed and
    written. None if the run has no checkpoint yet."""
    path, run_dir = cfg.out / "eval" / f"{name}.json", cfg.out / "runs" / name
    if best_record(run_dir, 0) is None:
        log(f"[eval] {name}: no checkpoint yet, skipped")
        return None
    grid = current_evaluation(cfg, name)
    if grid is not None:
        return grid
    if path.exists():
        log(f"[eval] {name}: the best checkpoints changed since {path.name}; evaluating again")
    best = _best_iterations(run_dir, cfg.seeds)
    spec = run_spec(name, cfg)
    start = time.time()
    # Table 1 at the training noise (gaussian) and the uniform sweep share one compiled rollout, so
    # every setting runs max(episodes, sweep_episodes) episodes per seed.
    episodes = max(cfg.episodes, cfg.sweep_episodes)
    specs = [(spec.env.hole_obs_noise * 1000.0, "gaussian")] + [(x, "uniform") for x in SWEEP_MM]
    grid = evaluate_run_grid(run_dir, episodes, noise_specs=specs, break_forces=sorted({spec.env.break_force, math.inf}))
    for row in grid:
        row["best_iterations"] = best
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")  # a report written meanwhile (--report-only) never reads half a file
    tmp.write_text(json.dumps(grid, indent=1, allow_nan=True))
    tmp.replace(path)
    log(f"[eval] {name}: {len(grid)} settings in {time.time() - start:.0f} s")
    return grid


def run_suite(cfg: SuiteConfig, command: str, log=print) -> dict[str, list[dict]]:
    """Per run: train (or resume), then evaluate once it is finished and rewrite the report, so an
    interrupted suite leaves a report of what is done and continues with the same command.
    --skip-training evaluates whatever checkpoints exist; --train-only evaluates nothing; --report-only
    reports the current evaluations that exist and runs nothing."""
    for name in cfg.only:
        run_dir = cfg.out / "runs" / name
        if (run_dir / ACTORS_DIR).is_dir() and checkpoints.run_checkpoints_dir(run_dir).exists():
            raise RunError(f"{run_dir} holds both exported actors and checkpoints (an export copied over a "
                           f"run?): keep one of the two")
        if (cfg.skip_training or cfg.report_only) and (run_dir / "config.json").exists() \
                and load_spec(run_dir) != run_spec(name, cfg):
            raise RunError(f"{run_dir} was trained with other settings than this command's (seeds, steps, "
                           f"preset, ratio): repeat the training command's options")
        if is_exported(run_dir) and not (cfg.skip_training or cfg.report_only):
            _exported_run_is_finished(run_dir, run_spec(name, cfg), log=lambda _: None)  # fail before hours of training
    results = {}
    if cfg.report_only:
        grids = {name: current_evaluation(cfg, name) for name in cfg.only}
        results = {name: grid for name, grid in grids.items() if grid is not None}
        log(f"[report] current evaluations: {', '.join(results) or 'none'}")
        return results
    for name in cfg.only:
        finished = cfg.skip_training or train_one(cfg, name, log)
        if cfg.train_only or not finished:
            continue
        grid = evaluate_one(cfg, name, log)
        if grid is not None:
            results[name] = grid
            write_report(cfg, results, command)
    return results


def _table1_row(grid: list[dict]) -> dict:
    """The evaluation at the training noise (gaussian) with the break force the run trained with."""
    gaussian = [r for r in grid if r["noise_type"] == "gaussian"]
    return next((r for r in gaussian if r["break_force_n"] is not None), gaussian[0])


def _fmt(row: dict, key: str, scale: float = 1.0, digits: int = 1) -> str:
    """mean +- 95 % interval half-width over the seeds of an evaluation row ('-' where missing)."""
    if key not in row["aggregate"]:  # an evaluation written before this column existed
        return "-"
    values = [s[key] for s in row["per_seed"] if s.get(key) is not None]
    mean = row["aggregate"][key]["mean"]
    if mean is None or math.isnan(mean):
        return "-"
    half = claims.ci95_halfwidth(values)
    return f"{scale * mean:.{digits}f}" + ("" if math.isnan(half) else f" +- {scale * half:.{digits}f}")


def _row(grid: list[dict], noise_type: str, noise_mm: float | None, breakable: bool) -> dict | None:
    for r in grid:
        if r["noise_type"] == noise_type and (noise_mm is None or r["noise_mm"] == noise_mm) \
                and (r["break_force_n"] is not None) == breakable:
            return r
    return None


# Training metrics kept per seed and iteration for the report (NaN where a row does not have them).
CURVE_KEYS = ("success_rate", "break_rate", "episodes", "contact_fraction", "p_force_free_axis")


def metric_arrays(rows: list[dict], keys) -> dict[str, np.ndarray]:
    """Per-iteration metric rows (one per iteration and seed) as seeds x iterations arrays of `keys`
    (NaN where a row has None), plus 'env_steps': env steps per seed at each iteration."""
    seeds = sorted({int(r["seed_index"]) for r in rows})
    iterations = sorted({int(r["iteration"]) for r in rows})
    arrays = {key: np.full((len(seeds), len(iterations)), np.nan) for key in keys}
    steps = np.zeros(len(iterations))
    for r in rows:
        j = iterations.index(int(r["iteration"]))
        for key in keys:
            arrays[key][int(r["seed_index"]), j] = np.nan if r.get(key) is None else r[key]
        steps[j] = r["env_steps"]
    return {"env_steps": steps, **arrays}


def episode_window(spec) -> int:
    """Iterations that span one episode per env: the window training success is smoothed over."""
    return math.ceil(spec.env.episode_steps / spec.ppo.rollout_steps)


def learning_curves(cfg: SuiteConfig) -> dict[str, dict]:
    """Per run name: the CURVE_KEYS metrics (seeds x iterations), env steps per iteration, the smoothing
    window (iterations spanning one episode per env), the step budget and each seed's best checkpoint
    (env steps; None where its record does not say)."""
    curves = {}
    for name in cfg.only:
        rows = read_metrics(cfg.out / "runs" / name)
        if not rows:
            continue
        logged = metric_arrays(rows, CURVE_KEYS)
        spec = run_spec(name, cfg)
        best = [best_record(cfg.out / "runs" / name, i) or {} for i in range(logged["success_rate"].shape[0])]
        curves[name] = {**logged, "budget": spec.ppo.total_steps,
                        "window": episode_window(spec),
                        "best_env_steps": [b.get("env_steps") for b in best]}
    return curves


STEPS_TO = (0.5, 0.8, 0.9)


def steps_to(curve: dict, threshold: float) -> list[float]:
    """Per seed: env steps to `threshold` training success (smoothed over one episode per env); NaN if never."""
    return [claims.steps_to(curve["env_steps"], seed_rate, threshold, curve["window"])
            for seed_rate in curve["success_rate"]]


_CLAIM_METRICS = {"success": ("gaussian", None, True, "success_rate"), "break": ("gaussian", None, True, "break_rate"),
                  "force": ("gaussian", None, True, "mean_force_n"),
                  "force_contact": ("gaussian", None, True, "force_selected_contact_per_axis"),
                  "force_free": ("gaussian", None, True, "force_selected_free_per_axis"),
                  "success_7.5": ("uniform", 7.5, True, "success_rate"),
                  "success_unbreakable_7.5": ("uniform", 7.5, False, "success_rate")}


def suite_claims(results: dict[str, list[dict]], curves: dict[str, dict]) -> list[claims.Claim]:
    """The paper's qualitative claims on this suite's per-seed evaluations and learning curves."""
    def values(name, metric):
        if name not in results:
            return []
        noise_type, noise_mm, breakable, key = _CLAIM_METRICS[metric]
        row = _table1_row(results[name]) if noise_type == "gaussian" else _row(results[name], noise_type, noise_mm,
                                                                               breakable and not unbreakable(name))
        return [] if row is None else [s.get(key) for s in row["per_seed"]]

    def steps(name, threshold):
        if name not in curves:
            return [], False
        trained = float(curves[name]["env_steps"][-1])  # a seed that never reached it: at least this many
        values = steps_to(curves[name], threshold)
        return [trained if math.isnan(x) else x for x in values], any(math.isnan(x) for x in values)

    return claims.check_claims(values, steps)


def _table1_lines(results: dict[str, list[dict]]) -> list[str]:
    """Table 1 analogue: the breakable runs at the training noise beside the paper's numbers."""
    lines = [
        "## Table 1 analogue (mean +- 95 % interval over seeds; 10 N break)", "",
        "Break % counts a break when the peak contact force over a policy step's physics steps reaches 10 N (the "
        "default); the 15 Hz column reads the force once per policy step, as the authors' code does, on the same "
        "episodes.", "",
        "| method | success % | break % | break % (15 Hz reading) | time to success (s) | mean contact force (N) "
        "| paper success % | paper break % |",
        "|---|---|---|---|---|---|---|---|",
    ]
    breakable = {n: g for n, g in results.items() if not unbreakable(n)}
    noise = {name: _table1_row(grid)["noise_mm"] for name, grid in breakable.items()}
    usual = max(set(noise.values()), key=list(noise.values()).count, default=None)
    others = [f"{SUITE[n].label} at {x:g} mm" for n, x in noise.items() if x != usual]
    if usual is not None:
        lines[2:2] = [f"Each run is evaluated at its training noise: gaussian hole-position noise of std {usual:g} mm"
                      + (f" ({', '.join(others)})" if others else "") + ".", ""]
    for name, grid in breakable.items():
        row = _table1_row(grid)
        paper = PAPER_TABLE1.get(name)
        lines.append(f"| {SUITE[name].label} | {_fmt(row, 'success_rate', 100)} | {_fmt(row, 'break_rate', 100)} | "
                     f"{_fmt(row, 'break_rate_policy_step', 100)} | "
                     f"{_fmt(row, 'mean_time_to_success_s', 1, 2)} | {_fmt(row, 'mean_force_n', 1, 2)} | "
                     f"{paper[0] if paper else '-'} | {paper[1] if paper else '-'} |")
    return lines


def _noise_lines(results: dict[str, list[dict]]) -> list[str]:
    """Success / break % over the uniform noise sweep, breakable and unbreakable, of the breakable runs."""
    breakable = {n: g for n, g in results.items() if not unbreakable(n)}
    lines = ["", "## Noise robustness (uniform hole-position noise; success % / break %)", "",
              "| method | " + " | ".join(f"+-{x:g} mm" for x in SWEEP_MM) + " | unbreakable: " +
              " | ".join(f"+-{x:g}" for x in SWEEP_MM) + " |",
              "|---|" + "---|" * (2 * len(SWEEP_MM))]
    for name, grid in breakable.items():
        cells = [f"{_fmt(r, 'success_rate', 100)} / {_fmt(r, 'break_rate', 100)}"
                 for r in (_row(grid, "uniform", x, True) for x in SWEEP_MM) if r is not None]
        cells_unb = [_fmt(r, "success_rate", 100) for r in (_row(grid, "uniform", x, False) for x in SWEEP_MM)
                     if r is not None]
        lines.append(f"| {SUITE[name].label} | " + " | ".join(cells) + " | " + " | ".join(cells_unb) + " |")
    return lines


def _unbreakable_lines(results: dict[str, list[dict]]) -> list[str]:
    """Success % evaluated unbreakable over the noise sweep, every run (empty without unbreakable-trained runs)."""
    lines = []
    if any(unbreakable(n) for n in results):
        lines += ["", "## Unbreakable pegs (evaluated unbreakable; success % under uniform hole-position noise)", "",
                  "The last three columns: at the run's training noise (gaussian), as in Table 1.", "",
                  "| method | trained | " + " | ".join(f"+-{x:g} mm" for x in SWEEP_MM)
                  + " | success % at training noise | time to success (s) | mean contact force (N) |",
                  "|---|---|" + "---|" * (len(SWEEP_MM) + 3)]
        for name, grid in results.items():
            cells = [_fmt(r, "success_rate", 100) for r in (_row(grid, "uniform", x, False) for x in SWEEP_MM)
                     if r is not None]
            at_training = _row(grid, "gaussian", None, False)
            if at_training is not None:
                cells += [_fmt(at_training, "success_rate", 100), _fmt(at_training, "mean_time_to_success_s", 1, 2),
                          _fmt(at_training, "mean_force_n", 1, 2)]
            trained = "unbreakable" if unbreakable(name) else f"{SUITE[name].break_force:g} N"
            lines.append(f"| {SUITE[name].label} | {trained} | " + " | ".join(cells) + " |")
    return lines


def _selection_lines(results: dict[str, list[dict]]) -> list[str]:
    """Per-axis force selection in contact and in free space of the hybrid runs."""
    lines = ["", "## Force selection (hybrid methods, training noise, deterministic policy)", "",
              "Per axis: sum over axes i of [force selected on i and i in contact] / sum of [i in contact], pooled over "
              "steps and episodes (the paper's 84 %), with x, y, z apart. An axis is in contact when the peg's contact "
              "force along that world axis exceeds 1 N at the start of the step (the contact the action was chosen "
              "in; the selection loss's label). Free space: the same over axes not in contact. The last two columns "
              "are the older summary: P(force), mean over the 3 axes, on steps with / without any contact.", "",
              "| method | per axis, in contact % | x / y / z in contact % | per axis, free % | x / y / z free % "
              "| P(force) contact % | P(force) free % | paper (MATCH) |", "|---|---|---|---|---|---|---|---|"]
    for name, grid in results.items():
        if name in HYBRID:
            row = _table1_row(grid)
            xyz = {w: " / ".join(_fmt(row, f"force_selected_{w}_{a}", 100, 0) for a in "xyz") for w in ("contact", "free")}
            lines.append(f"| {SUITE[name].label} | {_fmt(row, 'force_selected_contact_per_axis', 100)} | {xyz['contact']} "
                         f"| {_fmt(row, 'force_selected_free_per_axis', 100)} | {xyz['free']} "
                         f"| {_fmt(row, 'p_force_contact', 100)} | {_fmt(row, 'p_force_free', 100)} "
                         f"| {'84 +- 10.8 / 2.9 +- 2.1' if name == 'match' else ''} |")
    return lines


def _at_budget(curve: dict) -> bool:
    """Whether a run's training metrics reach its step budget."""
    return curve["env_steps"][-1] >= curve["budget"]


def _status_lines(cfg: SuiteConfig, results: dict[str, list[dict]], curves: dict[str, dict]) -> list[str]:
    """Which of the suite's runs this report covers (empty when every run is evaluated)."""
    pending = [n for n in cfg.only if n not in results]
    if not pending:
        return []
    training = [f"{SUITE[n].label} ({int(curves[n]['env_steps'][-1]):,} of {curves[n]['budget']:,} env steps per seed)"
                for n in pending if n in curves and not _at_budget(curves[n])]
    unevaluated = [SUITE[n].label for n in pending if n in curves and _at_budget(curves[n])]
    waiting = [SUITE[n].label for n in pending if n not in curves]
    return ["## Runs in this report", "",
            f"{len(results)} of {len(cfg.only)} runs are trained and evaluated"
            + (f": {', '.join(SUITE[n].label for n in results)}." if results else ".")
            + (f" Trained, not yet evaluated: {', '.join(unevaluated)}." if unevaluated else "")
            + (f" Training: {'; '.join(training)}." if training else "")
            + (f" Not started: {', '.join(waiting)}." if waiting else "")
            + " Runs not yet evaluated appear in the learning-speed and early-training tables only, marked (training) "
              "or (not evaluated), and no claim uses them. Running the suite's command again continues it.", ""]


def _label(name: str, results: dict[str, list[dict]], curves: dict[str, dict]) -> str:
    """A run's label in the learning table and curve, marked while it is not evaluated yet: (training) below
    its step budget, (not evaluated) at it."""
    if name in results:
        return SUITE[name].label
    return SUITE[name].label + (" (not evaluated)" if _at_budget(curves[name]) else " (training)")


def _learning_lines(curves: dict[str, dict], results: dict[str, list[dict]]) -> list[str]:
    """Env steps to 50 / 80 / 90 % training success, final and best success, per run; runs not in
    `results` are marked as still training."""
    lines = ["", "## Learning speed (training success, smoothed over one episode per env; mean +- 95 % interval "
              "over the seeds that reached it)", "",
              "Best checkpoints: where each seed's evaluated policy (highest training success of a chunk) was "
              "saved; one at the end of the budget means that seed was still improving when training stopped.", "",
              "| method | env steps per seed | " + " | ".join(f"steps to {100 * t:g} %" for t in STEPS_TO)
              + " | final success % | best success % | best checkpoints (env steps, per seed) |",
              "|---|---|" + "---|" * len(STEPS_TO) + "---|---|---|"]
    for name, c in curves.items():
        rate = c["success_rate"]
        cells = []
        for t in STEPS_TO:
            reached = [x for x in steps_to(c, t) if not math.isnan(x)]
            if not reached:
                cells.append(f"not reached (0/{len(rate)})")
                continue
            half = claims.ci95_halfwidth(reached)
            cells.append(f"{np.mean(reached) / 1e6:.2f}M" + ("" if math.isnan(half) else f" +- {half / 1e6:.2f}M")
                         + ("" if len(reached) == len(rate) else f" ({len(reached)}/{len(rate)} seeds)"))
        last = rate[:, -c["window"]:]
        tail = float(np.nanmean(last)) if np.isfinite(last).any() else float("nan")  # NaN: no episode ended yet
        best = float(np.nanmax(rate)) if np.isfinite(rate).any() else float("nan")
        kept = " / ".join("-" if x is None else f"{x / 1e6:.2f}M" if x >= 1e5 else f"{x:,}"
                          for x in c.get("best_env_steps", []))
        lines.append(f"| {_label(name, results, curves)} | {int(c['env_steps'][-1]):,} | " + " | ".join(cells)
                     + f" | {100 * tail:.1f} | {100 * best:.1f} | {kept} |")
    return lines


EARLY_STEPS = (250_000, 500_000, 1_000_000)  # env steps per seed at which the early-training table reads
EARLY_BREAK_STEPS = 100_000  # the first env steps per seed whose episodes' breaks it counts


def early_training(curve: dict) -> dict:
    """What a run met in its first env steps, mean over seeds: the fraction of episodes ending in its first
    EARLY_BREAK_STEPS that broke the peg; the fraction of env steps in contact and P(force) on free-space
    axes (training rollouts), averaged over the one-episode window ending at each of EARLY_STEPS (NaN
    past the steps trained); P(force) on free axes in the first iteration."""
    steps, window = curve["env_steps"], curve["window"]
    first = steps <= max(EARLY_BREAK_STEPS, steps[0])
    breaks = np.nansum(curve["break_rate"][:, first] * curve["episodes"][:, first], axis=1)
    episodes = np.nansum(curve["episodes"][:, first], axis=1)

    def at(key, n):
        if steps[-1] < n:
            return float("nan")
        j = int(np.searchsorted(steps, n, side="right"))  # iterations [j - window, j) end at or before n
        block = curve[key][:, max(j - window, 0):max(j, 1)]
        return float(np.nanmean(block)) if np.isfinite(block).any() else float("nan")

    per_seed = np.where(episodes > 0, breaks / np.where(episodes > 0, episodes, 1.0), np.nan)
    return {"break_rate": float(np.nanmean(per_seed)) if np.isfinite(per_seed).any() else float("nan"),
            "contact_fraction": [at("contact_fraction", n) for n in EARLY_STEPS],
            "p_force_free_start": float(np.nanmean(curve["p_force_free_axis"][:, 0]))
            if np.isfinite(curve["p_force_free_axis"][:, 0]).any() else float("nan"),
            "p_force_free": [at("p_force_free_axis", n) for n in EARLY_STEPS]}


def _early_lines(curves: dict[str, dict], results: dict[str, list[dict]]) -> list[str]:
    """The early-training table: breaks met at the start, and how soon each run reaches the block."""
    def pct(x):
        return "-" if math.isnan(x) else f"{100 * x:.1f}"

    marks = " / ".join(f"{n / 1e6:g}M" for n in EARLY_STEPS)
    lines = ["", "## Early training (training rollouts, mean over seeds)", "",
             f"Breaks: episodes that broke the peg among those ending in the first {EARLY_BREAK_STEPS:,} env steps "
             f"per seed. Contact and P(force) on free-space axes: averaged over the one-episode window ending at "
             f"{marks} env steps ('-': not trained that far).", "",
             f"| method | breaks %, first {EARLY_BREAK_STEPS / 1e6:g}M steps | env steps in contact % at {marks} "
             f"| P(force) on free axes %, first iteration | P(force) on free axes % at {marks} |",
             "|---|---|---|---|---|"]
    for name, c in curves.items():
        e = early_training(c)
        lines.append(f"| {_label(name, results, curves)} | {pct(e['break_rate'])} | "
                     + " / ".join(pct(x) for x in e["contact_fraction"]) + f" | {pct(e['p_force_free_start'])} | "
                     + ("-" if math.isnan(e["p_force_free_start"]) else " / ".join(pct(x) for x in e["p_force_free"]))
                     + " |")
    return lines


def _claims_lines(results: dict[str, list[dict]], curves: dict[str, dict]) -> list[str]:
    """The paper's claims with their verdicts at this suite's seeds."""
    lines = ["", "## The paper's claims at this suite's seeds", "",
              "A claim holds when the 95 % interval (Welch) of the difference of the seeds' means lies on its side "
              "of 0, does not hold when it lies on the other side, and is inconclusive otherwise; 'as fast as' "
              f"holds when not significantly slower and within {100 * claims.AS_FAST_MARGIN:g} % in mean. A seed "
              "that never reached 80 % counts at the env steps it trained (shown as >=): a lower bound, so a "
              "verdict it could overturn reads inconclusive.", "",
              "| claim | verdict | ours |", "|---|---|---|"]
    lines += [f"| {c.text} | {c.verdict} | {c.numbers} |" for c in suite_claims(results, curves)]
    return lines


def write_report(cfg: SuiteConfig, results: dict[str, list[dict]], command: str) -> pathlib.Path:
    """OUT/REPORT.md and its three figures from the evaluated runs `results` and every run's training metrics."""
    out = cfg.out
    curves = learning_curves(cfg)
    plots.learning_curves({_label(n, results, curves): c for n, c in curves.items()}, out / "learning_curves.png",
                          smooth=1 if cfg.smoke else 5)
    plots.noise_robustness({SUITE[n].label: [r for r in g if r["noise_type"] == "uniform"] for n, g in results.items()},
                           out / "noise_robustness.png")
    profiles = {SUITE[n].label: _table1_row(g)["selection_profile"] for n, g in results.items() if n in HYBRID}
    plots.selection_profile(profiles, out / "selection_profile.png")

    preset = get_preset(cfg.preset)
    lines = [
        "# match_jax experiment report", "",
        f"Command: `{command}`", "",
        f"Preset `{cfg.preset}`: {preset.num_envs} envs per seed, {cfg.total_steps or preset.total_steps:,} env steps "
        f"per seed, {cfg.seeds} seeds per method. Evaluation: best checkpoint per seed (highest training success "
        f"rate), deterministic policy, {max(cfg.episodes, cfg.sweep_episodes)} episodes per seed at the training "
        f"noise (gaussian) and at each level of the uniform noise sweep. MATCH's selection term is "
        + ("in the PPO ratio (paper's equation)." if cfg.selection_in_ratio else
           "left out of the PPO ratio (authors' code; selection trained by the SSL only); MATCH (no SSL) keeps it "
           "in the ratio, its selection's only training signal.")
        + (" **Smoke run: tiny sizes, the numbers mean nothing.**" if cfg.smoke else ""), "",
    ]
    lines += _status_lines(cfg, results, curves)
    lines += _table1_lines(results) + _noise_lines(results) + _unbreakable_lines(results) + _selection_lines(results)
    # Learning-speed claims compare finished runs only: a run still training has not had its budget.
    lines += _learning_lines(curves, results) + _early_lines(curves, results) + _claims_lines(results, {n: c for n, c in curves.items() if n in results})
    lines += ["", "## Figures", "", "- `learning_curves.png`: training success vs env steps, mean and 95% CI over seeds",
              "- `noise_robustness.png`: success and break rate vs uniform noise, breakable and unbreakable (error bars: "
              "standard error over seeds)",
              "- `selection_profile.png`: P(force) per axis over approach / contact / insertion (time-normalised)", ""]
    path = out / "REPORT.md"
    path.write_text("\n".join(lines))
    return path


def export_suite(cfg: SuiteConfig, dest: pathlib.Path, results: dict[str, list[dict]], log=print) -> pathlib.Path:
    """Copy what the report shows to `dest` (e.g. a results folder under version control): REPORT.md, the
    figures and, per run in `results` (the evaluated runs), its eval JSON, config, metrics and best actors
    (`training.export_actors`: no critic, no optimizer state), so `python eval.py DEST/runs/<name>`
    evaluates the shipped policies. Other runs already in `dest` are left as they are."""
    dest.mkdir(parents=True, exist_ok=True)
    for path in [cfg.out / "REPORT.md", *sorted(cfg.out.glob("*.png"))]:
        if path.exists():
            (dest / path.name).write_bytes(path.read_bytes())
    (dest / "eval").mkdir(exist_ok=True)
    for name in results:  # a run still training, or with a stale evaluation, has no final best actors yet
        (dest / "eval" / f"{name}.json").write_bytes((cfg.out / "eval" / f"{name}.json").read_bytes())
        export_actors(cfg.out / "runs" / name, dest / "runs" / name)
    log(f"[export] {dest}")
    return dest


def parse_args(argv=None) -> SuiteConfig:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                     allow_abbrev=False)
    parser.add_argument("--out", type=pathlib.Path, required=True)
    parser.add_argument("--preset", choices=["cpu", "paper", "tiny"], default="cpu")
    parser.add_argument("--task", choices=sorted(TASKS), default="authors",
                        help="task protocol of every run: the authors' (default) or this project's earlier variant")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--total-steps", type=int, default=None)
    parser.add_argument("--episodes", type=int, default=100, help="Table 1 episodes per seed (every setting runs max(--episodes, --sweep-episodes))")
    parser.add_argument("--sweep-episodes", type=int, default=500, help="noise-sweep episodes per seed")
    parser.add_argument("--only", default=",".join(SUITE), help=f"comma-separated subset of {list(SUITE)}")
    parser.add_argument("--time-budget-min", type=float, default=None,
                        help="per run: stop training after the chunk that ends past this many minutes (resumable)")
    parser.add_argument("--skip-training", action="store_true",
                        help="train nothing: evaluate and report the checkpoints that exist")
    parser.add_argument("--train-only", action="store_true",
                        help="train (or resume) the runs; no evaluation and no report (e.g. training on a GPU, "
                             "evaluating later with --skip-training)")
    parser.add_argument("--report-only", action="store_true",
                        help="train and evaluate nothing: write the report (and --export) from the evaluations that "
                             "exist and are current, e.g. while the suite trains other runs in another process")
    parser.add_argument("--export", type=pathlib.Path, default=None,
                        help="after the report, copy it, its figures and, per evaluated run, its evaluation, config, "
                             "metrics and best actors (no critic or optimizer state) to this folder")
    parser.add_argument("--smoke", action="store_true", help="tiny preset, 2 seeds, 2 episodes: every stage, fast")
    parser.add_argument("--selection-not-in-ratio", action="store_true",
                        help="MATCH (with SSL) leaves the selection term out of the PPO ratio (the authors' code); "
                             "MATCH no-SSL keeps it, as its selection has no other training signal")
    args = parser.parse_args(argv)
    only = tuple(x for x in args.only.split(",") if x)
    unknown = [x for x in only if x not in SUITE]
    if unknown or not only:
        parser.error(f"--only takes names from {list(SUITE)}, got {args.only!r}")
    for name in ("seeds", "episodes", "sweep_episodes", "total_steps"):
        value = getattr(args, name)
        if value is not None and value < 1:
            parser.error(f"--{name.replace('_', '-')} must be a positive integer, got {value}")
    if args.time_budget_min is not None and not (args.time_budget_min > 0 and math.isfinite(args.time_budget_min)):
        parser.error(f"--time-budget-min must be a positive number of minutes, got {args.time_budget_min}")
    modes = [f"--{m.replace('_', '-')}" for m in ("train_only", "skip_training", "report_only") if getattr(args, m)]
    if len(modes) > 1:
        parser.error(f"{' and '.join(modes)} exclude each other")
    if args.train_only and args.export is not None:
        parser.error("--export needs the report: it does not go with --train-only")
    common = dict(out=args.out, export=args.export, only=only, selection_in_ratio=not args.selection_not_in_ratio,
                  task=args.task,
                  time_budget_min=args.time_budget_min, skip_training=args.skip_training,
                  train_only=args.train_only, report_only=args.report_only)
    if args.smoke:
        return SuiteConfig(preset="tiny", seeds=2, total_steps=None, episodes=2, sweep_episodes=2, smoke=True,
                           **common)
    return SuiteConfig(preset=args.preset, seeds=args.seeds, total_steps=args.total_steps,
                       episodes=args.episodes, sweep_episodes=args.sweep_episodes, **common)


def main(argv=None) -> int:
    cfg = parse_args(argv)
    compile_cache.enable()
    cfg.out.mkdir(parents=True, exist_ok=True)
    # The report names the command that trains and evaluates it: --report-only only rewrites it.
    command = "python -m match_jax.experiments " + " ".join(
        x for x in (sys.argv[1:] if argv is None else argv) if x != "--report-only")
    try:
        results = run_suite(cfg, command)
        if not cfg.train_only:
            path = write_report(cfg, results, command)
            print(f"wrote {path}")
            if cfg.export is not None:
                export_suite(cfg, cfg.export, results)
    except (RunError, CheckpointError) as err:  # a run directory that does not fit the command
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM (training turns it into KeyboardInterrupt after its chunk)
        print(f"interrupted: finished runs, evaluations and checkpoints in {cfg.out} are kept; run the same "
              "command to continue")
        return 130
    if cfg.train_only:
        print("--train-only: no evaluation, no report")
    return 0


if __name__ == "__main__":
    sys.exit(main())
