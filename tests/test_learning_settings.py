"""The learning-settings benchmark: the committed summary regenerates from the committed runs."""

import importlib.util
import pathlib

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
RESULTS = REPO / "results" / "learning_settings"


def _benchmark():
    spec = importlib.util.spec_from_file_location("learning_settings", REPO / "benchmarks" / "learning_settings.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_summary_regenerates_from_the_run_list(tmp_path, monkeypatch, capsys):
    """runs.txt names every row of summary.json, and reading those runs again gives the same numbers."""
    monkeypatch.chdir(REPO)  # runs.txt holds paths relative to the repository
    out = tmp_path / "summary.json"
    assert _benchmark().main([f"@{RESULTS / 'runs.txt'}", "--json", str(out)]) == 0
    assert out.read_text() == (RESULTS / "summary.json").read_text()  # byte for byte, row order and NaNs included
    assert "| initial force-z 0 N and learning rate 1e-3 | 1.02M | 0.79M / - / 0.90M |" in capsys.readouterr().out


def test_training_docs_table_is_the_printed_table(monkeypatch, capsys):
    """docs/training.md shows the table the benchmark prints for runs.txt, row for row."""
    monkeypatch.chdir(REPO)
    assert _benchmark().main([f"@{RESULTS / 'runs.txt'}"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("|")]
    assert len(rows) == 2 + len((RESULTS / "runs.txt").read_text().splitlines())  # header, rule, one per run
    docs = (REPO / "docs" / "training.md").read_text().splitlines()
    missing = [row for row in rows if row not in docs]
    assert not missing, f"docs/training.md lacks {missing}"


def test_bad_run_argument_is_named(tmp_path, capsys):
    with pytest.raises(SystemExit):
        _benchmark().main(["no-separator"])
    assert "expected LABEL=RUN_DIR, got 'no-separator'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        _benchmark().main([f"x={tmp_path / 'missing'}"])
    assert "does not exist" in capsys.readouterr().err


def test_plot_draws_each_runs_success_and_breaks(tmp_path, monkeypatch, capsys):
    """--plot writes one figure; each panel has one line per run, at 100 x the seeds' mean smoothed rate."""
    from match_jax.experiments import plots

    monkeypatch.chdir(REPO)
    bench = _benchmark()
    runs = {"forcez": "results/learning_screen/forcez", "gae": "results/learning_screen/gae"}
    out = tmp_path / "screen.png"
    assert bench.main([f"{k}={v}" for k, v in runs.items()] + ["--plot", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    curves = {k: bench.smoothed_curves(bench.run_curves(pathlib.Path(v), 1e6)) for k, v in runs.items()}
    fig = plots.success_and_breaks_figure(curves)
    for ax, key in zip(fig.axes, ("success_rate", "break_rate")):
        assert len(ax.get_lines()) == len(runs)
        for line, c in zip(ax.get_lines(), curves.values()):
            np.testing.assert_allclose(line.get_ydata(), 100 * np.nanmean(c[key], axis=0), equal_nan=True)
    with pytest.raises(SystemExit):
        bench.main([f"forcez={runs['forcez']}", "--plot", str(tmp_path / "screen.pdf")])
    assert "--plot must name a .png file, got" in capsys.readouterr().err
