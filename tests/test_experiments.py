"""The experiment suite end to end at smoke sizes, its run specs and its evaluation reuse."""

import match_jax  # noqa: F401

import dataclasses
import json
import math
import pathlib

import jax
import numpy as np
import pytest

from match_jax.training import checkpoints, evaluation, runs as training
from match_jax.experiments import pipeline as experiments

def _check_report_and_export(out, shipped):
    """The report of a pose + MATCH suite beside the paper's numbers, its figures, and its export."""
    report = (out / "REPORT.md").read_text()
    for label in ("Pose", "MATCH"):
        assert f"| {label} |" in report
    assert "Smoke run" in report and "95.4" in report  # the paper's numbers beside ours
    assert "steps to 80 %" in report and "| MATCH breaks less than Pose (10 N, training noise) |" in report
    assert (shipped / "REPORT.md").read_text() == report and (shipped / "eval" / "match.json").exists()
    for name in ("learning_curves.png", "noise_robustness.png", "unbreakable_robustness.png", "selection_profile.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name


@pytest.mark.slow
def test_smoke_suite_writes_report_and_plots(tmp_path):
    """Every stage on two of the twelve runs (a pose-control and a hybrid one), trained and evaluated on
    the MJX env at tiny sizes; the full `--smoke` trains and evaluates all twelve the same way. The
    default run checks the same stages with stand-ins for training and the rollout (below)."""
    out = tmp_path / "suite"
    # --train-only trains and stops: no evaluation, no report; the next call finds the run finished
    assert experiments.main(["--smoke", "--out", str(out), "--only", "pose", "--train-only"]) == 0
    assert (out / "runs" / "pose" / "metrics.csv").exists()
    assert not (out / "eval").exists() and not (out / "REPORT.md").exists()
    # a run stopped by its time budget is not evaluated yet; the finished one is, and the report says so
    assert experiments.main(["--smoke", "--out", str(out), "--only", "pose,match", "--time-budget-min", "1e-4"]) == 0
    assert (out / "eval" / "pose.json").exists() and not (out / "eval" / "match.json").exists()
    table1 = (out / "REPORT.md").read_text().split("## Noise robustness")[0]
    assert "| Pose |" in table1 and "| MATCH |" not in table1  # MATCH's curve is in the learning table already
    # the same command without the budget finishes MATCH, evaluates it, and exports the suite
    shipped = tmp_path / "shipped"
    assert experiments.main(["--smoke", "--out", str(out), "--only", "pose,match", "--export", str(shipped)]) == 0
    _check_report_and_export(out, shipped)
    assert "## Runs in this report" not in (out / "REPORT.md").read_text()  # every run evaluated
    for name in ("pose", "match"):
        assert sorted(p.name for p in (shipped / "runs" / name / "actors").iterdir()) == [
            "seed0.json", "seed0.msgpack", "seed1.json", "seed1.msgpack"]
        assert not (shipped / "runs" / name / "checkpoints").exists()
    grid = json.loads((out / "eval" / "match.json").read_text())
    assert len(grid) == 2 * (1 + len(experiments.SWEEP_MM))  # (training noise + sweep) x (break, unbreakable)
    assert {r["break_force_n"] for r in grid} == {10.0, None}
    best = [checkpoints.read_best_record(out / "runs" / "match", i)["iteration"] for i in range(2)]
    assert all(r["best_iterations"] == best for r in grid)  # which checkpoints it evaluated
    # resumable: a second call skips finished training and evaluation
    mtime = (out / "eval" / "match.json").stat().st_mtime
    assert experiments.main(["--smoke", "--out", str(out), "--only", "match"]) == 0
    assert (out / "eval" / "match.json").stat().st_mtime == mtime
    # --skip-training reports what exists: a run never trained is skipped, not an error
    assert experiments.main(["--smoke", "--out", str(out), "--only", "pose,match,vices", "--skip-training"]) == 0
    assert not (out / "runs" / "vices").exists() and "| VICES |" not in (out / "REPORT.md").read_text()


def test_suite_selection_not_in_ratio_applies_to_match_only(tmp_path):
    cfg = experiments.parse_args(["--out", str(tmp_path), "--selection-not-in-ratio"])
    assert experiments.run_spec("match", cfg).ppo.selection_in_ratio is False
    # no SSL: the ratio is the selection's only training signal, so it stays in
    assert experiments.run_spec("match_nossl", cfg).ppo.selection_in_ratio is True
    assert experiments.run_spec("hybrid", cfg).ppo.selection_in_ratio is True
    default = experiments.parse_args(["--out", str(tmp_path)])
    assert experiments.run_spec("match", default).ppo.selection_in_ratio is True


def test_suite_unbreakable_runs_train_without_breaks(tmp_path):
    import math

    cfg = experiments.parse_args(["--out", str(tmp_path)])
    for name in ("pose_unbreakable", "vices_unbreakable", "hybrid_unbreakable", "match_unbreakable"):
        spec = experiments.run_spec(name, cfg)
        assert math.isinf(spec.env.break_force) and experiments.unbreakable(name)
        assert spec.ppo.method == experiments.SUITE[name.removesuffix("_unbreakable")].method
    assert experiments.run_spec("match", cfg).env.break_force == 10.0 and not experiments.unbreakable("match")


def test_suite_force_law_variant_is_the_law_the_task_does_not_use(tmp_path):
    """Each task's suite trains MATCH once more with the force law that is not the task's own, and nothing
    else differs: match_damped on the authors' task (literal law), match_literal on the earlier one."""
    authors = experiments.parse_args(["--out", str(tmp_path)])
    assert authors.task == "authors" and "match_damped" in authors.only and "match_literal" not in authors.only
    for name in ("match", "pose"):
        controller = experiments.run_spec(name, authors).env.controller
        assert not controller.force_feedforward and controller.force_damping == (0.0, 0.0, 0.0)
    assert experiments.run_spec("match", authors).env.force_sensor == "wrist"
    damped = experiments.run_spec("match_damped", authors)
    assert damped.env.controller.force_feedforward and damped.env.controller.force_damping == (20.0, 20.0, 20.0)
    cfg = experiments.parse_args(["--out", str(tmp_path), "--task", "earlier"])
    assert "match_literal" in cfg.only and "match_damped" not in cfg.only and len(cfg.only) == len(authors.only)
    literal = experiments.run_spec("match_literal", cfg)
    assert literal.ppo.method == "match" and not literal.env.controller.force_feedforward
    assert literal.env.controller.force_damping == (0.0, 0.0, 0.0)
    default = experiments.run_spec("match", cfg)
    assert default.env.controller.force_feedforward and default.env.controller.force_damping == (20.0, 20.0, 20.0)
    assert dataclasses.replace(literal.env, controller=default.env.controller) == default.env  # nothing else differs
    assert dataclasses.replace(damped.env, controller=experiments.run_spec("match", authors).env.controller) \
        == experiments.run_spec("match", authors).env
    # asking for the run that would train match twice is a one-line error
    with pytest.raises(SystemExit):
        experiments.parse_args(["--out", str(tmp_path), "--only", "match,match_literal"])
    with pytest.raises(ValueError, match="match_literal is match on the 'authors' task"):
        experiments.SuiteConfig(out=tmp_path, only=("match_literal",))
    randomised = experiments.parse_args(["--out", str(tmp_path), "--task", "authors_dr"])
    assert randomised.only == authors.only and experiments.sweep_noise_type("authors_dr") == "shell"
    assert experiments.sweep_noise_type("earlier") == "uniform"
    assert experiments.run_spec("pose", randomised).env.randomization.dynamics


def test_an_evaluation_is_reused_only_for_the_checkpoints_it_evaluated(tmp_path, monkeypatch):
    """evaluate_one reads OUT/eval/<name>.json while the run's best checkpoints are the ones it records,
    and evaluates again (here: a stub that counts calls) when they changed or the record is missing."""
    cfg = experiments.parse_args(["--out", str(tmp_path), "--seeds", "2"])
    run_dir = tmp_path / "runs" / "match"
    calls = []

    def fake_grid(run_dir, episodes, noise_specs, break_forces):
        calls.append(episodes)
        return [{"noise_type": "gaussian", "noise_mm": 1.0, "break_force_n": 10.0, "episodes_per_seed": episodes}]

    monkeypatch.setattr(experiments, "evaluate_run_grid", fake_grid)
    assert experiments.evaluate_one(cfg, "match", log=lambda _: None) is None and calls == []  # no checkpoint yet
    for seed, iteration in ((0, 5), (1, 7)):
        checkpoints.best_dir(run_dir, seed).mkdir(parents=True)
        checkpoints.write_best_record(run_dir, seed, {"iteration": iteration})
    grid = experiments.evaluate_one(cfg, "match", log=lambda _: None)
    assert calls == [500] and grid[0]["best_iterations"] == [5, 7]
    assert experiments.evaluate_one(cfg, "match", log=lambda _: None) == grid and calls == [500]  # reused
    checkpoints.write_best_record(run_dir, 1, {"iteration": 9})  # a new best for seed 1
    assert experiments.evaluate_one(cfg, "match", log=lambda _: None)[0]["best_iterations"] == [5, 9]
    assert calls == [500, 500]
    path = tmp_path / "eval" / "match.json"
    path.write_text(json.dumps([{"noise_type": "gaussian"}]))  # written before the record existed
    experiments.evaluate_one(cfg, "match", log=lambda _: None)
    assert calls == [500, 500, 500]


def _fake_train(calls):
    """A stand-in for training.train: one 'iteration' per call under a time budget, else all of them;
    writes what a real run leaves (config, metrics rows, best records, a latest checkpoint)."""

    def fake_train(spec, run_dir, resume=False, progress=True, time_budget_s=None, max_chunks=None):
        run_dir = pathlib.Path(run_dir)
        if resume:
            spec, done = training.load_spec(run_dir), checkpoints.latest_step(checkpoints.latest_dir(run_dir))
        else:
            run_dir.mkdir(parents=True)
            (run_dir / "config.json").write_text(spec.to_json())
            done = 0
        per_iteration = spec.ppo.num_envs * spec.ppo.rollout_steps
        total = math.ceil(spec.ppo.total_steps / per_iteration)
        stop = min(total, done + 1) if time_budget_s is not None else total
        with open(run_dir / "metrics.jsonl", "a") as f:
            for it in range(done + 1, stop + 1):
                for i in range(spec.num_seeds):
                    row = {key: 0.1 for key in training.LOGGED}
                    row.update(iteration=it, env_steps=it * per_iteration, seed_index=i, seed=spec.seed + i,
                               success_rate=it / total, wall_clock_s=1.0)
                    f.write(json.dumps(row) + "\n")
        for i in range(spec.num_seeds):
            checkpoints.best_dir(run_dir, i).mkdir(parents=True, exist_ok=True)
            checkpoints.write_best_record(run_dir, i, {"iteration": stop, "success_rate": stop / total,
                                                       "env_steps": stop * per_iteration})
        if stop > done:
            checkpoints.save(checkpoints.latest_dir(run_dir), stop, {"iteration": np.asarray(stop)})
        calls.append((run_dir.name, resume, stop))
        return {"finished": stop == total, "iterations": stop, "env_steps_per_seed": stop * per_iteration,
                "wall_clock_s": 1.0, "best_success_rate": [0.5, None]}

    return fake_train


def _fake_grid(calls):
    """A stand-in for evaluate_run_grid: the real `evaluation.grid_results` on a hand-made rollout (6 steps:
    episode 0 succeeds at step 3, episode 1 rams the hole with a 12 N spike at step 2 and never succeeds)."""

    def fake_grid(run_dir, episodes, noise_specs, break_forces):
        spec = training.load_spec(run_dir)
        S, L, T, E = spec.num_seeds, len(noise_specs), 6, episodes
        traj = {key: np.zeros((S, L, T, E)) for key in ("success", "engaged", "broken", "in_contact", "mean_force",
                                                        "max_force", "truncation", "done_before", "done")}
        traj.update(phase=np.zeros((S, L, T, E), np.int32), position_axes=np.ones((S, L, T, E, 3)),
                    contact_axes=np.zeros((S, L, T, E, 3)), contact_axes_before=np.zeros((S, L, T, E, 3)),
                    ee_force=np.zeros((S, L, T, E, 3)))
        traj["success"][:, :, 3:, 0] = 1.0
        traj["in_contact"][:, :, 2:, :] = 1.0
        traj["mean_force"][:, :, 2:, :] = 3.0
        traj["max_force"][:, :, 2:, :] = 4.0
        traj["max_force"][:, :, 2, 1] = 12.0
        traj["ee_force"][:, :, 2, 1, 2] = -12.0  # the end-of-step reading of the same spike
        traj["phase"][:, :, 2:, :] = 1
        traj["done"][:, :, -1, :] = 1.0
        hybrid = spec.ppo.method in ("hybrid", "match")
        if hybrid:
            traj["p_force"] = np.where(traj["in_contact"][..., None] > 0, 0.8, 0.05) * np.ones(3)
        calls.append(run_dir.name)
        return evaluation.grid_results(traj, spec, noise_specs, break_forces, 1.0 / 15.0, hybrid, str(run_dir))

    return fake_grid


def test_suite_stages_with_stand_ins_for_training_and_rollouts(tmp_path, monkeypatch, capsys):
    """The suite's stages as the slow smoke test runs them (train-only, time budget, evaluation of finished
    runs only, report, export, resume, --skip-training), with training and the MJX rollout replaced by
    stand-ins: everything from the trajectories on (metrics, report, claims, figures) is the real code."""
    trained, evaluated, exported = [], [], []
    monkeypatch.setattr(experiments, "train", _fake_train(trained))
    monkeypatch.setattr(experiments, "evaluate_run_grid", _fake_grid(evaluated))

    def fake_export(run_dir, out):
        exported.append(pathlib.Path(run_dir).name)
        (pathlib.Path(out) / "actors").mkdir(parents=True)
        return pathlib.Path(out)

    monkeypatch.setattr(experiments, "export_actors", fake_export)
    out, shipped = tmp_path / "suite", tmp_path / "shipped"
    smoke = ["--smoke", "--out", str(out)]
    assert experiments.main(smoke + ["--only", "pose", "--train-only"]) == 0
    assert trained == [("pose", False, 2)] and evaluated == []  # tiny preset: 64 steps of 32 per iteration
    assert "best training success [50%, none]" in capsys.readouterr().out  # none: no episode ended
    assert not (out / "eval").exists() and not (out / "REPORT.md").exists()
    # a budget stops MATCH after its first iteration: pose (finished) is evaluated, MATCH is not
    early = tmp_path / "early"  # a finished run's results are exported as soon as it is evaluated
    assert experiments.main(smoke + ["--only", "pose,match", "--time-budget-min", "1e-4", "--export", str(early)]) == 0
    assert trained[1:] == [("pose", True, 2), ("match", False, 1)] and evaluated == ["pose"]  # pose: nothing left
    assert exported == ["pose"] and sorted(p.name for p in (early / "eval").iterdir()) == ["pose.json"]
    report = (out / "REPORT.md").read_text()
    table1 = report.split("## Noise robustness")[0]
    assert "| Pose |" in table1 and "| MATCH |" not in table1
    assert "1 of 2 runs are trained and evaluated: Pose. Training: MATCH (32 of 64 env steps per seed)." in report
    assert "| MATCH (training) | 32 |" in report  # its learning curve so far, marked
    assert "| 75.0 | 100.0 | 64 / 64 |" in report  # Pose: final, best success and where each seed's best is
    assert "| MATCH learns as fast as Pose (env steps to 80 % training success) | not run |" in report
    assert "| Pose | 10.0 | - / - / - | 10.0 | - / - / - |" in report  # early training: 64 steps trained
    assert not (out / "selection_profile.png").exists() and "selection_profile" not in report  # no hybrid run yet
    # the same command without the budget resumes MATCH, finishes and evaluates it, and exports the suite
    assert experiments.main(smoke + ["--only", "pose,match", "--export", str(shipped)]) == 0
    assert trained[3:] == [("pose", True, 2), ("match", True, 2)]
    assert evaluated == ["pose", "match"] and exported[1:] == ["pose", "match"]  # pose's evaluation is reused
    _check_report_and_export(out, shipped)
    assert "## Runs in this report" not in (out / "REPORT.md").read_text()  # every run evaluated
    grid = json.loads((out / "eval" / "match.json").read_text())
    assert len(grid) == 2 * (1 + len(experiments.SWEEP_MM))  # (training noise + sweep) x (break, unbreakable)
    assert {r["break_force_n"] for r in grid} == {10.0, None} and all(r["best_iterations"] == [2, 2] for r in grid)
    breakable = next(r for r in grid if r["noise_type"] == "gaussian" and r["break_force_n"] == 10.0)
    unbreakable = next(r for r in grid if r["noise_type"] == "gaussian" and r["break_force_n"] is None)
    assert breakable["aggregate"]["break_rate"]["mean"] == pytest.approx(1 / 2)  # the 12 N spike, 2 episodes
    assert unbreakable["aggregate"]["break_rate"]["mean"] == 0.0
    assert breakable["aggregate"]["success_rate"]["mean"] == pytest.approx(1 / 2)
    # resumable: a second call trains and evaluates nothing
    mtime = (out / "eval" / "match.json").stat().st_mtime
    assert experiments.main(smoke + ["--only", "match"]) == 0
    assert trained[5:] == [("match", True, 2)] and evaluated == ["pose", "match"]
    assert (out / "eval" / "match.json").stat().st_mtime == mtime
    # --report-only rewrites the report from the current evaluations and trains and evaluates nothing
    (out / "REPORT.md").unlink()
    assert experiments.main(smoke + ["--only", "pose,match,vices", "--report-only"]) == 0
    assert len(trained) == 6 and evaluated == ["pose", "match"]
    report = (out / "REPORT.md").read_text()
    assert "| MATCH |" in report.split("## Noise robustness")[0] and "--report-only" not in report
    with pytest.raises(SystemExit):
        experiments.parse_args(smoke + ["--report-only", "--skip-training"])
    # --skip-training reports what exists: a run never trained is skipped, not an error
    assert experiments.main(smoke + ["--only", "pose,match,vices", "--skip-training"]) == 0
    assert len(trained) == 6 and not (out / "runs" / "vices").exists()
    assert "| VICES |" not in (out / "REPORT.md").read_text()
    # a stale evaluation (a new best checkpoint since) is left out of --report-only's report and export
    checkpoints.write_best_record(out / "runs" / "match", 1, {"iteration": 1, "success_rate": 0.9, "env_steps": 32})
    again = tmp_path / "again"
    assert experiments.main(smoke + ["--only", "pose,match", "--report-only", "--export", str(again)]) == 0
    report = (out / "REPORT.md").read_text()
    table1 = report.split("## Noise robustness")[0]
    assert "| Pose |" in table1 and "| MATCH |" not in table1 and evaluated == ["pose", "match"]
    assert "Pose. Trained, not yet evaluated: MATCH. Runs not yet evaluated" in report  # finished, not training
    assert "| MATCH (not evaluated) | 64 |" in report
    assert sorted(p.name for p in (again / "eval").iterdir()) == ["pose.json"] and exported[-1] == "pose"
    # --report-only checks the runs' settings against the command's: a one-line error, exit 2
    assert experiments.main(smoke + ["--only", "match", "--report-only", "--selection-not-in-ratio"]) == 2
    assert f"error: {out / 'runs' / 'match'} was trained with other settings" in capsys.readouterr().err
    # another episode count is another evaluation: evaluated again, and left out of a report for the old count
    cfg = experiments.parse_args(smoke + ["--only", "pose"])
    assert experiments.current_evaluation(cfg, "pose") is not None
    more = dataclasses.replace(cfg, sweep_episodes=3)
    assert experiments.current_evaluation(more, "pose") is None
    grid = experiments.evaluate_one(more, "pose", log=lambda _: None)
    assert evaluated[-1] == "pose" and {r["episodes_per_seed"] for r in grid} == {3}
    assert experiments.main(smoke + ["--only", "pose", "--report-only"]) == 0
    assert "[report] pose: eval/pose.json evaluated other checkpoints or another episode count" in capsys.readouterr().out


def test_early_training_reads_breaks_contact_and_free_space_force_selection():
    """Breaks are pooled over the episodes of the first 0.1M steps per seed; contact and P(force) are
    window means ending at each mark, NaN past the steps trained and for a run without selections."""
    steps = np.arange(1, 13) * 50_000.0  # 12 iterations of 50k env steps: 0.05M ... 0.6M
    nan = np.full((2, 12), np.nan)
    curve = {"env_steps": steps, "window": 2, "episodes": np.full((2, 12), 10.0), "break_rate": np.zeros((2, 12)),
             "contact_fraction": np.stack([np.arange(12) / 100, np.arange(12) / 50]), "p_force_free_axis": nan}
    curve["episodes"][:, :2] = [[10.0, 30.0], [0.0, 10.0]]
    curve["break_rate"][:, :2] = [[0.5, 0.0], [np.nan, 1.0]]  # seed 1 ended no episode in its first iteration
    curve["break_rate"][:, 2:] = 1.0  # after the first 0.1M steps: not counted
    early = experiments.early_training(curve)
    assert early["break_rate"] == pytest.approx((5 / 40 + 10 / 10) / 2)
    at_250k, at_500k, at_1m = early["contact_fraction"]  # iterations 4-5 (0.2M, 0.25M), 9-10 (0.45M, 0.5M)
    assert at_250k == pytest.approx((0.03 + 0.04 + 0.06 + 0.08) / 4)
    assert at_500k == pytest.approx((0.08 + 0.09 + 0.16 + 0.18) / 4)
    assert math.isnan(at_1m) and math.isnan(early["p_force_free_start"])
    curve["p_force_free_axis"] = np.full((2, 12), 0.02)
    curve["p_force_free_axis"][:, 0] = 0.06
    early = experiments.early_training(curve)
    assert early["p_force_free_start"] == pytest.approx(0.06) and early["p_force_free"][1] == pytest.approx(0.02)


def test_suite_usage_error_is_a_short_usage_line_then_the_error(tmp_path, capsys):
    with pytest.raises(SystemExit):
        experiments.parse_args(["--out", str(tmp_path), "--only", "nope"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == ["usage: python -m match_jax.experiments --out DIR [options] (see --help)",
                     f"python -m match_jax.experiments: error: --only takes names from {list(experiments.SUITE)}, "
                     "got 'nope'"]


def test_an_interrupted_suite_says_how_to_continue(tmp_path, monkeypatch, capsys):
    """Ctrl-C or SIGTERM during training: one line naming the run directory and the way on, exit 130."""
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt("signal 15")

    monkeypatch.setattr(experiments, "train", interrupted)
    assert experiments.main(["--smoke", "--out", str(tmp_path / "suite"), "--only", "pose"]) == 130
    out = capsys.readouterr().out
    assert f"interrupted: finished runs, evaluations and checkpoints in {tmp_path / 'suite'} are kept" in out
    assert "run the same command to continue" in out


SHIPPED = pathlib.Path(__file__).resolve().parents[1] / "results" / "suite_cpu"
# The learning settings results/suite_cpu was trained with (the cpu preset's before the measured ones).
EARLIER_SUITE_LEARNING = ["--learning-rate", "3e-4", "--gamma", "0.995", "--initial-force-z", "-1"]


SHIPPED_RUNS = sorted(p.name for p in (SHIPPED / "runs").iterdir())
# MATCH and Pose by default; the other ten runs with -m slow (each compiles its own policy: ~10 s).
SHIPPED_DEFAULT = ("match", "pose")


def test_the_shipped_suite_has_every_run():
    assert set(SHIPPED_DEFAULT) <= set(SHIPPED_RUNS) and len(SHIPPED_RUNS) == 12


@pytest.mark.parametrize("name", [n if n in SHIPPED_DEFAULT else pytest.param(n, marks=pytest.mark.slow)
                                  for n in SHIPPED_RUNS])
def test_shipped_suite_policies_load(name):
    """A committed suite run's best actors load as their config says (no critic, no optimizer state),
    one per seed, each the checkpoint its evaluation used, and act: a finite env action, seeds distinct."""
    from match_jax.rl.ppo import deterministic_action

    run, policies = training.load_policies(SHIPPED / "runs" / name)
    grid = json.loads((SHIPPED / "eval" / f"{name}.json").read_text())
    records = [json.loads((SHIPPED / "runs" / name / "actors" / f"seed{i}.json").read_text())
               for i in range(run.spec.num_seeds)]
    assert len(policies) == run.spec.num_seeds == grid[0]["seeds"] == 3, name
    assert [r["iteration"] for r in records] == grid[0]["best_iterations"], name
    obs = jax.numpy.zeros((4,) + run.env.observation_size["state"])
    actions = [np.asarray(deterministic_action(run.trainer, p["params"], p["policy_stats"], obs))
               for p in policies]
    for policy, action in zip(policies, actions):
        assert set(policy) == {"params", "policy_stats"} and set(policy["params"]) == {"actor"}, name
        assert action.shape == (4, run.env.action_size) and np.all(np.isfinite(action)), name
    assert not np.array_equal(actions[0], actions[1]), name  # trained seeds, not copies


def test_a_suite_continues_from_its_exported_results(tmp_path, monkeypatch, capsys):
    """The committed results folder copied into --out: its exported runs count as trained and evaluated
    (nothing trains, nothing is evaluated again, the report reads their numbers); an exported run with
    another configuration, or exported before its step budget, is a one-line error naming it."""
    import shutil

    def must_not_run(*args, **kwargs):
        raise AssertionError("an exported run was trained or evaluated again")

    monkeypatch.setattr(experiments, "train", must_not_run)
    monkeypatch.setattr(experiments, "evaluate_run_grid", must_not_run)
    out = tmp_path / "suite"
    shutil.copytree(SHIPPED / "runs" / "pose", out / "runs" / "pose")
    shutil.copytree(SHIPPED / "eval", out / "eval")
    command = ["--out", str(out), "--preset", "cpu", "--task", "earlier", "--seeds", "3", "--total-steps", "2500000",
               "--episodes", "200", "--sweep-episodes", "200", "--only", "pose", *EARLIER_SUITE_LEARNING]
    shipped = tmp_path / "shipped"
    assert experiments.main(command + ["--export", str(shipped)]) == 0
    assert "[train] pose: exported run, trained (2,534,400 env steps per seed)" in capsys.readouterr().out
    for path in [*(SHIPPED / "runs" / "pose" / "actors").iterdir(), SHIPPED / "eval" / "pose.json"]:
        again = shipped / path.relative_to(SHIPPED)  # exported again: the same actors, records and evaluation
        assert again.read_bytes() == path.read_bytes(), path.name
    assert sorted(p.name for p in (shipped / "eval").iterdir()) == ["pose.json"]  # only the runs reported
    committed = next(r for r in json.loads((SHIPPED / "eval" / "pose.json").read_text())
                     if r["noise_type"] == "gaussian" and r["break_force_n"] == 10.0)
    success = 100 * committed["aggregate"]["success_rate"]["mean"]
    assert f"| Pose | {success:.1f} +- " in (out / "REPORT.md").read_text().split("## Noise robustness")[0]
    assert experiments.main([("3000000" if x == "2500000" else x) for x in command]) == 2  # another step budget
    assert f"error: {out / 'runs' / 'pose'} holds an exported run with another configuration" in capsys.readouterr().err
    actor = out / "runs" / "pose" / "actors" / "seed2.msgpack"
    actor.rename(actor.with_suffix(".bak"))
    assert experiments.main(command) == 2
    assert "is an exported run without seed2.msgpack in actors/" in capsys.readouterr().err
    actor.with_suffix(".bak").rename(actor)
    metrics = out / "runs" / "pose" / "metrics.jsonl"
    metrics.write_text("".join(metrics.read_text().splitlines(keepends=True)[:30]))  # exported after 10 iterations
    assert experiments.main(command) == 2
    assert "is an exported run stopped at 192,000 of 2,500,000 env steps per seed" in capsys.readouterr().err


@pytest.mark.slow
def test_shipped_match_policies_reproduce_their_evaluation():
    """The committed MATCH actors, evaluated afresh (other episodes, 60 per seed) at the training noise,
    succeed and break at the rates of their committed 200-episode evaluation, within sampling error."""
    committed = next(r for r in json.loads((SHIPPED / "eval" / "match.json").read_text())
                     if r["noise_type"] == "gaussian" and r["break_force_n"] == 10.0)
    fresh = evaluation.evaluate_run_grid(SHIPPED / "runs" / "match", 60, seed=7)[0]
    for key, tolerance in (("success_rate", 0.15), ("break_rate", 0.05)):
        assert abs(fresh["aggregate"][key]["mean"] - committed["aggregate"][key]["mean"]) < tolerance, key


def test_table1_names_each_runs_evaluation_noise():
    """Table 1 evaluates each run at its own training noise; a run trained at another noise is named."""
    def grid(noise_mm):
        return [{"noise_type": "gaussian", "noise_mm": noise_mm, "break_force_n": 10.0, "per_seed": [],
                 "aggregate": {}}]

    lines = experiments._table1_lines({"pose": grid(1.0), "match": grid(1.0), "pose_noise2.5": grid(2.5)})
    assert ("Each run is evaluated at its training noise: gaussian hole-position noise of std 1 mm "
            "(Pose (trained at 2.5 mm) at 2.5 mm).") in lines
    assert sum(line.startswith("| Pose") for line in lines) == 2
    lines = experiments._table1_lines({"pose": grid(1.0)})
    assert "Each run is evaluated at its training noise: gaussian hole-position noise of std 1 mm." in lines


def test_table1_row_holds_both_break_checks_the_authors_metrics_and_the_papers():
    """A Table 1 row: success, the run's break rate, peak / 15 Hz break rates, our / the authors' time and
    force, then the paper's four numbers; a run the paper does not report gets dashes there."""
    values = {"success_rate": 0.9, "break_rate": 0.02, "break_rate_peak": 0.1, "break_rate_policy_step": 0.02,
              "mean_time_to_success_s": 5.25, "authors_time_to_success_s": 4.5, "mean_force_n": 0.5,
              "authors_mean_force_n": 2.25}
    grid = [{"noise_type": "gaussian", "noise_mm": 1.0, "break_force_n": 10.0, "per_seed": [values] * 3,
             "aggregate": {k: {"mean": v} for k, v in values.items()}}]
    lines = experiments._table1_lines({"match": grid, "pose_noise2.5": grid})
    row = next(line for line in lines if line.startswith("| MATCH |"))
    assert row == ("| MATCH | 90.0 +- 0.0 | 2.0 +- 0.0 | 10.0 +- 0.0 / 2.0 +- 0.0 | 5.25 +- 0.00 / 4.50 +- 0.00 "
                   "| 0.50 +- 0.00 / 2.25 +- 0.00 | 97.0 | 0.0 | 2.5 | 2.7 |")
    other = next(line for line in lines if line.startswith("| Pose (trained at 2.5 mm) |"))
    assert other.endswith("| - | - | - | - |")
    header = next(line for line in lines if line.startswith("| method |"))
    assert header.count("|") == row.count("|")


def test_plot_styles_keep_methods_apart_and_dash_unbreakable_runs():
    """Every method of the suite gets its own color; a run trained unbreakable is dashed in its method's."""
    from match_jax.experiments import plots

    names = [spec.label for spec in experiments.SUITE.values()] + ["Hybrid-Basic (unbreakable) (training)"]
    styles = plots.line_styles(names)
    methods = [n for n in names if "(unbreakable)" not in n]
    assert len({styles[n]["color"] for n in methods}) == len(methods)
    assert {styles[n]["linestyle"] for n in methods} == {"-"}
    assert styles["Pose (unbreakable)"] == {"color": styles["Pose"]["color"], "linestyle": "--"}
    assert styles["Hybrid-Basic (unbreakable) (training)"]["color"] == styles["Hybrid-Basic"]["color"]


def test_unbreakable_table_reads_each_runs_unbreakable_evaluations():
    """The unbreakable table: every run's success evaluated unbreakable over the sweep, then success, time to
    success and force (ours / the authors') at its training noise; the 10 N evaluations are never read."""
    def row(noise_type, noise_mm, break_force, success, time_s=5.0, force=1.0):
        seeds = [{"success_rate": success, "mean_time_to_success_s": time_s, "mean_force_n": force,
                  "authors_time_to_success_s": time_s - 0.25, "authors_mean_force_n": 3 * force}] * 3
        aggregate = {k: {"mean": v} for k, v in seeds[0].items()}
        return {"noise_type": noise_type, "noise_mm": noise_mm, "break_force_n": break_force, "per_seed": seeds,
                "aggregate": aggregate}

    def grid(success, time_s):
        rows = [row("gaussian", 1.0, None, success, time_s)] + [row("uniform", x, None, success / (1 + x))
                                                                  for x in experiments.SWEEP_MM]
        return rows + [row(r["noise_type"], r["noise_mm"], 10.0, 0.01, 9.9, 9.9) for r in rows]

    assert experiments._unbreakable_lines({"pose": grid(0.9, 7.0)}) == []  # no unbreakable-trained run
    lines = experiments._unbreakable_lines({"pose": grid(0.9, 7.0), "pose_unbreakable": grid(0.8, 3.5)})
    assert "| Pose | 10 N | 90.0 +- 0.0 | 45.0 +- 0.0 | 25.7 +- 0.0 | 15.0 +- 0.0 | 10.6 +- 0.0 | 90.0 +- 0.0 " \
           "| 7.00 +- 0.00 / 6.75 +- 0.00 | 1.00 +- 0.00 / 3.00 +- 0.00 |" in lines
    assert "| Pose (unbreakable) | unbreakable | 80.0 +- 0.0 | 40.0 +- 0.0 | 22.9 +- 0.0 | 13.3 +- 0.0 " \
           "| 9.4 +- 0.0 | 80.0 +- 0.0 | 3.50 +- 0.00 / 3.25 +- 0.00 | 1.00 +- 0.00 / 3.00 +- 0.00 |" in lines
