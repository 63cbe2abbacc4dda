"""The experiment suite end to end at smoke sizes, and the quickstart notebook's code."""

import match_jax  # noqa: F401

import json
import pathlib

from match_jax import checkpoints, experiments

REPO = pathlib.Path(__file__).resolve().parents[1]


def test_smoke_suite_writes_report_and_plots(tmp_path):
    """Every stage on two of the seven runs (a pose-control and a hybrid one) to keep CI short; the full
    `--smoke` trains and evaluates all seven the same way."""
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
    report = (out / "REPORT.md").read_text()
    for label in ("Pose", "MATCH"):
        assert f"| {label} |" in report
    assert "Smoke run" in report and "95.4" in report  # the paper's numbers beside ours
    assert "steps to 80 %" in report and "| MATCH breaks less than Pose (10 N, training noise) |" in report
    assert (shipped / "REPORT.md").read_text() == report and (shipped / "eval" / "match.json").exists()
    for name in ("pose", "match"):
        assert sorted(p.name for p in (shipped / "runs" / name / "actors").iterdir()) == [
            "seed0.json", "seed0.msgpack", "seed1.json", "seed1.msgpack"]
        assert not (shipped / "runs" / name / "checkpoints").exists()
    for name in ("learning_curves.png", "noise_robustness.png", "selection_profile.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
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


def test_quickstart_notebook_runs(tmp_path, monkeypatch):
    notebook = json.loads((REPO / "notebooks" / "quickstart.ipynb").read_text())
    code = "\n\n".join("".join(cell["source"]) for cell in notebook["cells"] if cell["cell_type"] == "code")
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(compile(code, "quickstart.ipynb", "exec"), namespace)
    assert namespace["summary"]["finished"]
    assert namespace["figure_path"].exists()
    assert namespace["result"]["seeds"] == 2


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
        assert spec.ppo.method == experiments.SUITE[name.removesuffix("_unbreakable")][1]
    assert experiments.run_spec("match", cfg).env.break_force == 10.0 and not experiments.unbreakable("match")


def test_an_evaluation_is_reused_only_for_the_checkpoints_it_evaluated(tmp_path, monkeypatch):
    """evaluate_one reads OUT/eval/<name>.json while the run's best checkpoints are the ones it records,
    and evaluates again (here: a stub that counts calls) when they changed or the record is missing."""
    cfg = experiments.parse_args(["--out", str(tmp_path), "--seeds", "2"])
    run_dir = tmp_path / "runs" / "match"
    calls = []

    def fake_grid(run_dir, episodes, noise_specs, break_forces):
        calls.append(episodes)
        return [{"noise_type": "gaussian", "noise_mm": 1.0, "break_force_n": 10.0}]

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
