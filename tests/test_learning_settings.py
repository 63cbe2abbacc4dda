"""The learning-settings benchmark: the committed summary regenerates from the committed runs."""

import importlib.util
import json
import math
import pathlib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
RESULTS = REPO / "results" / "learning_settings"


def _benchmark():
    spec = importlib.util.spec_from_file_location("learning_settings", REPO / "benchmarks" / "learning_settings.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return a == b


def test_summary_regenerates_from_the_run_list(tmp_path, monkeypatch, capsys):
    """runs.txt names every row of summary.json, and reading those runs again gives the same numbers."""
    monkeypatch.chdir(REPO)  # runs.txt holds paths relative to the repository
    out = tmp_path / "summary.json"
    assert _benchmark().main([f"@{RESULTS / 'runs.txt'}", "--json", str(out)]) == 0
    committed = json.loads((RESULTS / "summary.json").read_text())
    regenerated = json.loads(out.read_text())
    assert list(regenerated["runs"]) == list(committed["runs"])
    assert _same(regenerated, committed)
    assert "| initial force-z 0 N and learning rate 1e-3 | 1.02M | 0.79M / - / 0.90M |" in capsys.readouterr().out


def test_bad_run_argument_is_named(tmp_path, capsys):
    with pytest.raises(SystemExit):
        _benchmark().main(["no-separator"])
    assert "expected LABEL=RUN_DIR, got 'no-separator'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        _benchmark().main([f"x={tmp_path / 'missing'}"])
    assert "does not exist" in capsys.readouterr().err
