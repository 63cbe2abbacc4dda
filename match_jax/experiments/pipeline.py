"""The paper's experiment suite: train every method, evaluate, sweep noise, analyse selection, report.

    python -m match_jax.experiments --preset cpu --seeds 3 --out results/suite
    python -m match_jax.experiments --smoke --out /tmp/suite_smoke        # every stage, tiny sizes
    python -m match_jax.experiments --only pose,match --out results/suite # a subset
    python -m match_jax.experiments --total-steps 2500000 --learning-rate 1e-3 --gamma 0.99 --initial-force-z 0 \
        --out runs/suite_authors     # the learning settings of benchmarks/authors_task_runs.sh: reuses its runs

Runs (each with --seeds seeds in one program): Pose, VICES, Hybrid-Basic, MATCH, MATCH with the authors'
force law (no feed-forward, no damping on force-controlled axes), MATCH (no SSL),
Hybrid-Basic (no SSL), Pose trained at 2.5 mm hole noise, and Pose, VICES, Hybrid-Basic and MATCH trained
with an unbreakable peg. Then, per run, one compiled rollout
evaluates every seed at the training noise (Table 1, --episodes per seed) and over the noise sweep
(0, 1, 2.5, 5, 7.5 mm: the authors' spherical shells on their task, uniform +-level per axis on the earlier
variant; --sweep-episodes per seed), each with the run's break force and unbreakable.
Resumable: finished runs and evaluations are skipped, interrupted runs resume from their checkpoint.
An exported suite (--export: report, eval JSONs, best actors) copied into OUT counts its runs as trained
(same configuration, full step budget) and evaluated, so a suite continues from its committed results.
Writes OUT/runs/<name>/ (training), OUT/eval/<name>.json, and OUT/REPORT.md with learning_curves.png,
noise_robustness.png, unbreakable_robustness.png and selection_profile.png (`match_jax.experiments.report`). The runs and their
settings: `match_jax.experiments.suite`. Every --ppo.FIELD and --env.FIELD flag of train.py (its --help
lists them) and its short names (--learning-rate, --gamma, --initial-force-z, --contact-timeconst, ...) apply
to every run, after the run's own settings; the fields that tell the runs apart (method, SSL, break force,
noise, force law) are refused.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time

import match_jax  # noqa: F401  (fast XLA CPU flag)

from match_jax.training import checkpoints
from match_jax import compile_cache
from match_jax.training.checkpoints import CheckpointError
from match_jax.cli import SHORT_NAMES, field_flag, rewrite_short_names
from match_jax.envs.tasks import TASKS
from match_jax.training.evaluation import evaluate_run_grid
from match_jax.experiments.report import (_table1_lines, _unbreakable_lines, early_training, episode_window,  # noqa: F401
                              learning_curves, metric_arrays, write_report)
from match_jax.experiments.suite import (HYBRID, PAPER_TABLE1, SUITE, SWEEP_MM, SuiteConfig, SuiteRun,  # noqa: F401
                             run_spec, suite_runs, sweep_noise_type, unbreakable)
from match_jax.training.runs import (ACTORS_DIR, RunError, RunSpec, actor_path, best_record, export_actors, is_exported,
                                load_spec, read_metrics, record_path, train)

# Config fields that tell the suite's runs apart (method, SSL, break force, noise, force law) or that its own
# flags set: a config-field flag may not replace them for every run.
PER_RUN_FIELDS = ("ppo.method", "ppo.ssl_coef", "ppo.selection_in_ratio", "env.control", "env.break_force",
                  "env.hole_obs_noise", "env.hole_obs_noise_type", "env.physics_backend",
                  "env.controller.force_feedforward", "env.controller.force_damping")


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
    """OUT/eval/<name>.json if it evaluated the run's current best checkpoints with the episodes per seed
    that `cfg` asks for, else None."""
    path = cfg.out / "eval" / f"{name}.json"
    if not path.exists():
        return None
    grid = json.loads(path.read_text())
    best = _best_iterations(cfg.out / "runs" / name, cfg.seeds)
    episodes = cfg.episodes_per_seed
    return grid if grid and all(r.get("best_iterations") == best and r.get("episodes_per_seed") == episodes
                                for r in grid) else None


def evaluate_one(cfg: SuiteConfig, name: str, log=print) -> list[dict] | None:
    """The evaluation grid of run `name` (training noise and the noise sweep, breakable and not): read
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
        log(f"[eval] {name}: {path.name} evaluated other checkpoints or another episode count; evaluating again")
    best = _best_iterations(run_dir, cfg.seeds)
    spec = run_spec(name, cfg)
    start = time.time()
    episodes = cfg.episodes_per_seed
    specs = [(spec.env.hole_obs_noise * 1000.0, "gaussian")] + [(x, sweep_noise_type(cfg.task)) for x in SWEEP_MM]
    grid = evaluate_run_grid(run_dir, episodes, noise_specs=specs,
                             break_forces=sorted({spec.env.break_force, math.inf}))
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
        for name in cfg.only:
            if name not in results and (cfg.out / "eval" / f"{name}.json").exists():
                log(f"[report] {name}: eval/{name}.json evaluated other checkpoints or another episode count than "
                    f"--episodes/--sweep-episodes ask for; left out")
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
            if cfg.export is not None:  # each run's results leave as soon as it is evaluated
                export_suite(cfg, cfg.export, {name: grid}, log)
    return results


def export_suite(cfg: SuiteConfig, dest: pathlib.Path, results: dict[str, list[dict]], log=print) -> pathlib.Path:
    """Copy what the report shows to `dest` (e.g. a results folder under version control): REPORT.md, the
    figures and, per run in `results` (the evaluated runs), its eval JSON, config, metrics and best actors
    (`runs.export_actors`: no critic, no optimizer state), so `python eval.py DEST/runs/<name>`
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
    from match_jax.cli import Parser

    parser = Parser(prog="python -m match_jax.experiments", short_usage="--out DIR [options]", description=__doc__,
                    formatter_class=argparse.RawDescriptionHelpFormatter, allow_abbrev=False)
    parser.add_argument("--out", type=pathlib.Path, required=True)
    parser.add_argument("--preset", choices=["cpu", "paper", "tiny"], default="cpu")
    parser.add_argument("--task", choices=sorted(TASKS), default="authors",
                        help="task protocol of every run: the authors' (default), the authors' as their randomised "
                             "runs train it (authors_dr) or this project's earlier variant (earlier)")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--total-steps", type=int, default=None)
    parser.add_argument("--episodes", type=int, default=100,
                        help="Table 1 episodes per seed (every setting runs max(--episodes, --sweep-episodes))")
    parser.add_argument("--sweep-episodes", type=int, default=500, help="noise-sweep episodes per seed")
    parser.add_argument("--only", default=None,
                        help=f"comma-separated subset of {list(SUITE)} (default: every run of the --task; "
                             "match_literal on the earlier task, match_damped on the authors')")
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
                        help="copy the report, its figures and, per evaluated run (as soon as it is evaluated), "
                             "its evaluation, config, metrics and best actors (no critic or optimizer state) "
                             "to this folder")
    parser.add_argument("--physics-backend", choices=["jax", "warp"], default="jax",
                        help="physics of every run: MJX's JAX backend or MuJoCo Warp (pip install 'match_jax[warp]')")
    parser.add_argument("--smoke", action="store_true", help="tiny preset, 2 seeds, 2 episodes: every stage, fast")
    parser.add_argument("--selection-not-in-ratio", action="store_true",
                        help="MATCH (with SSL) leaves the selection term out of the PPO ratio (the authors' code); "
                             "MATCH no-SSL keeps it, as its selection has no other training signal")
    args, config_flags = parser.parse_known_args(argv)
    only = suite_runs(args.task) if args.only is None else tuple(x for x in args.only.split(",") if x)
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
    config_flags = rewrite_short_names(config_flags, SHORT_NAMES)
    fixed = [t.split("=")[0] for t in config_flags if t.split("=")[0] in map(field_flag, PER_RUN_FIELDS)]
    if fixed:
        parser.error(f"{fixed[0]}: the suite sets it per run (method, SSL, break force, noise, force law) or with "
                     "its own flag (--physics-backend, --selection-not-in-ratio)")
    if args.physics_backend == "warp":
        from match_jax.envs import sim

        if not sim.warp_installed():
            parser.error(f"--physics-backend warp {sim.WARP_MISSING}")
    common = dict(out=args.out, export=args.export, only=only, selection_in_ratio=not args.selection_not_in_ratio,
                  task=args.task, physics_backend=args.physics_backend,
                  time_budget_min=args.time_budget_min, skip_training=args.skip_training,
                  train_only=args.train_only, report_only=args.report_only)
    sizes = (dict(preset="tiny", seeds=2, total_steps=None, episodes=2, sweep_episodes=2, smoke=True) if args.smoke
             else dict(preset=args.preset, seeds=args.seeds, total_steps=args.total_steps, episodes=args.episodes,
                       sweep_episodes=args.sweep_episodes))
    try:
        cfg = SuiteConfig(**sizes, **common, config_flags=tuple(config_flags))
    except ValueError as err:  # a run that duplicates another on this task (SuiteConfig's check)
        parser.error(f"--only: {err}")
    try:  # every run's configs accept the config-field flags, before any work
        for name in cfg.only:
            run_spec(name, cfg)
    except ValueError as err:
        parser.error(str(err))
    return cfg


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
            if cfg.export is not None:  # the final report; the runs' own results were exported as they finished
                export_suite(cfg, cfg.export, results if cfg.report_only else {})
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
