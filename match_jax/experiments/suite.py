"""The experiment suite's runs and settings: which runs it trains, with what task, at which budget, and
the noise sweep it evaluates them on (`match_jax.experiments.pipeline` runs it, `match_jax.experiments.report` reports it)."""

from __future__ import annotations

import dataclasses
import math
import pathlib
from typing import NamedTuple

from match_jax.cli import parse_fields
from match_jax.envs.tasks import TASKS, reports_authors_metrics, task_config
from match_jax.training.presets import get_preset
from match_jax.training.runs import RunSpec


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
    "match_damped": SuiteRun("MATCH (damped force law)", "match", True, 1.0, 10.0, "damped"),
    "match_nossl": SuiteRun("MATCH (no SSL)", "match", False, 1.0, 10.0, None),
    "hybrid_nossl": SuiteRun("Hybrid-Basic (no SSL)", "hybrid", False, 1.0, 10.0, None),
    "pose_noise2.5": SuiteRun("Pose (trained at 2.5 mm)", "pose", True, 2.5, 10.0, None),
    "pose_unbreakable": SuiteRun("Pose (unbreakable)", "pose", True, 1.0, math.inf, None),
    "vices_unbreakable": SuiteRun("VICES (unbreakable)", "vices", True, 1.0, math.inf, None),
    "hybrid_unbreakable": SuiteRun("Hybrid-Basic (unbreakable)", "hybrid", True, 1.0, math.inf, None),
    "match_unbreakable": SuiteRun("MATCH (unbreakable)", "match", True, 1.0, math.inf, None),
}
# Table 1 of the paper: success %, break %, time to success (s), mean force (N); mean over 5 seeds x 100
# episodes, measured with the authors' break check and metrics.
PAPER_TABLE1 = {"pose": (95.4, 1.6, 2.5, 1.9), "vices": (95.2, 1.4, 2.7, 2.0), "hybrid": (98.2, 0.4, 2.4, 3.0),
                "match": (97.0, 0.0, 2.5, 2.7), "match_nossl": (82.0, 8.2, 2.4, 1.7),
                "hybrid_nossl": (87.0, 2.6, 2.6, 1.8)}
SWEEP_MM = (0.0, 1.0, 2.5, 5.0, 7.5)  # noise sweep levels (mm); 0 = the true hole position


def sweep_noise_type(task: str) -> str:
    """The noise sweep of a task protocol: the authors' spherical shells (radius U[previous level, level]
    in a random direction) on their tasks, uniform +-level per axis on the earlier variant."""
    return "shell" if reports_authors_metrics(task) else "uniform"


def suite_runs(task: str) -> tuple[str, ...]:
    """The suite's runs on task protocol `task`: every run but the force-law variant whose law is the
    task's own (on it, that run would be `match` trained twice)."""
    return tuple(name for name, run in SUITE.items() if run.force_law in (None, *_other_laws(task)))


def _other_laws(task: str) -> tuple[str, ...]:
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; choose one of {sorted(TASKS)}")
    return tuple(law for law in ("literal", "damped") if law != TASKS[task]["force_law"])


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
    only: tuple[str, ...] | None = None  # None: every run of the task (`suite_runs`)
    smoke: bool = False
    selection_in_ratio: bool = True  # MATCH with SSL: False = the authors' code (selection by the SSL only)
    time_budget_min: float | None = None  # per run and call: stop training after this much wall clock
    skip_training: bool = False  # evaluate and report the checkpoints that exist, train nothing
    train_only: bool = False  # train (or resume) the runs, evaluate and report nothing
    report_only: bool = False  # report (and export) the current evaluations that exist, train and evaluate nothing
    export: pathlib.Path | None = None  # copy the report, evaluations and best actors here (`export_suite`)
    # Config-field flags applied to every run after its method and task settings, as train.py's are:
    # ('--ppo.learning-rate', '1e-5', '--env.contact-timeconst', '0.05', ...) (`match_jax.cli.parse_fields`).
    config_flags: tuple[str, ...] = ()
    physics_backend: str = "jax"  # 'jax' (MJX) | 'warp' (MuJoCo Warp) for every run's training and evaluation

    @property
    def episodes_per_seed(self) -> int:
        """Episodes per seed and setting of an evaluation: Table 1 at the training noise (gaussian) and the
        noise sweep share one compiled rollout, so every setting runs max(episodes, sweep_episodes)."""
        return max(self.episodes, self.sweep_episodes)

    def __post_init__(self):
        runs = suite_runs(self.task)
        if self.only is None:
            object.__setattr__(self, "only", runs)
        duplicates = [name for name in self.only if name in SUITE and name not in runs]
        if duplicates:
            raise ValueError(f"{', '.join(duplicates)} is match on the {self.task!r} task (its force law is the "
                             f"task's own); the task's suite runs are {list(runs)}")


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
                      break_force=run.break_force, physics_backend=cfg.physics_backend)
    if cfg.config_flags:
        configs = parse_fields({"ppo": ppo, "env": env}, list(cfg.config_flags), "python -m match_jax.experiments")
        ppo, env = configs["ppo"], configs["env"]
    return RunSpec(ppo=ppo, env=env, num_seeds=cfg.seeds, preset=cfg.preset)
