"""The stand-in protocol's report: the sim rows it pairs with, the claims' verdicts, the files it writes."""

import importlib.util
import json
import math
import pathlib

import numpy as np
import pytest

from match_jax.experiments import claims
from match_jax.transfer import report as transfer_report
from match_jax.transfer.standin import summarize


def _trials(n, successes, broken=0, force=2.0, max_force=8.0, rng=None):
    rng = rng or np.random.default_rng(0)
    return [{"success": i < successes, "broken": successes <= i < successes + broken,
             "time_to_success_s": 3.0 if i < successes else None,
             "mean_force_n": float(force + 0.1 * rng.standard_normal()),
             "max_force_n": float(max_force + 0.5 * rng.standard_normal()),
             "energy_j": 1.0} for i in range(n)]


def _level(trials):
    return {**summarize(trials), "trial_rows": trials}


def _entry(success_by_level, best="policy_seed1", force=2.0, max_force=8.0):
    """A method's protocol entry: noiseless trials of seeds 0 and 1, shells for the best one."""
    noiseless = {f"policy_seed{i}": _level(_trials(30, success_by_level[0] - 5 * (f"policy_seed{i}" != best),
                                                   force=force, max_force=max_force)) for i in (0, 1)}
    shells = {f"{lv:g}": _level(_trials(50, k, force=force, max_force=max_force))
              for lv, k in zip((1.0, 2.5, 5.0, 7.5), success_by_level[1:])}
    return {"noiseless": noiseless, "shells": shells, "best_seed": best}


def _sim_row(level, noise_type, success_by_seed, break_force=10.0):
    return {"noise_mm": level, "noise_type": noise_type, "break_force_n": break_force,
            "per_seed": [{"episodes": 200, "success_rate": s, "break_rate": 0.05, "authors_mean_force_n": 2.5}
                         for s in success_by_seed]}


def test_the_sim_column_is_the_same_seed_at_the_same_level_with_the_peg_breakable():
    rows = [_sim_row(7.5, "shell", [0.1, 0.2]), _sim_row(7.5, "shell", [0.9, 0.9], break_force=None),
            _sim_row(7.5, "gaussian", [0.5, 0.5]), _sim_row(0.0, "gaussian", [0.7, 0.8])]
    assert transfer_report.sim_at(rows, 7.5, 1)["success_rate"] == 0.2
    assert transfer_report.sim_at(rows, 0.0, 1)["success_rate"] == 0.8  # noiseless: any noise type
    assert transfer_report.sim_at(rows, 5.0, 0) is None
    assert transfer_report.sim_at(rows, 7.5, 2) is None  # a seed the sim did not evaluate
    assert transfer_report.sim_rows({"noise_sweep": rows}) == rows
    assert transfer_report.sim_rows(rows[0]) == [rows[0]]
    with pytest.raises(ValueError, match="'best'"):
        transfer_report.seed_index("best")


def test_the_claims_read_the_trials():
    protocol = {"pose": transfer_report.protocol_levels(_entry([28, 45, 35, 20, 10], force=3.0, max_force=9.0)),
                "match": transfer_report.protocol_levels(_entry([29, 48, 44, 40, 38], force=2.0, max_force=7.0))}
    sims = {"match": [_sim_row(0.0, "shell", [0.5, 0.95])], "pose": [_sim_row(0.0, "shell", [0.95, 0.2])]}
    verdicts = {c.text.split(" (")[0]: c for c in transfer_report.transfer_claims(protocol, sims)}
    assert verdicts["MATCH succeeds more often than Pose at 7.5 mm"].verdict == claims.HOLDS
    assert verdicts["MATCH succeeds more often than Pose at 7.5 mm"].numbers == "76 % vs 20 %"
    assert verdicts["MATCH succeeds more often than Hybrid-Basic at 7.5 mm"].verdict == claims.MISSING
    assert verdicts["MATCH applies less mean contact force than VICES"].verdict == claims.MISSING
    assert verdicts["Pose reaches a lower max force than VICES"].verdict == claims.MISSING
    # noiseless: MATCH's best seed (1) succeeds 29/30 on the stand-in and 95 % in the sim; Pose's best
    # seed (1) 28/30 against 20 % in the sim (better on the stand-in)
    transfers = " transfers without noise: stand-in success at most 15 points below the training simulator's"
    assert verdicts["MATCH" + transfers].verdict == claims.HOLDS
    assert verdicts["Pose" + transfers].verdict == claims.HOLDS
    worse = {"match": [_sim_row(0.0, "shell", [0.5, 1.0])], "pose": [_sim_row(0.0, "shell", [0.5, 0.96])]}
    low = {"match": transfer_report.protocol_levels(_entry([12, 48, 44, 40, 38])),  # 12/30 against 100 %
           "pose": transfer_report.protocol_levels(_entry([26, 45, 35, 20, 10]))}  # 26/30 against 96 %
    verdicts = {c.text: c.verdict for c in transfer_report.transfer_claims(low, worse)}
    assert verdicts["MATCH" + transfers] == claims.FAILS
    assert verdicts["Pose" + transfers] == claims.INCONCLUSIVE
    swapped = {"pose": protocol["match"], "match": protocol["pose"]}
    flipped = {c.text.split(" (")[0]: c.verdict for c in transfer_report.transfer_claims(swapped, {})}
    assert flipped["MATCH succeeds more often than Pose at 7.5 mm"] == claims.FAILS
    even = {"pose": protocol["pose"], "match": protocol["pose"]}
    same = {c.text.split(" (")[0]: c.verdict for c in transfer_report.transfer_claims(even, {})}
    assert same["MATCH succeeds more often than Pose at 7.5 mm"] == claims.INCONCLUSIVE


def test_the_report_and_its_figure(tmp_path):
    standin = {"config": {"no_perturbation": False},
               "match": _entry([29, 48, 44, 40, 38]), "vices": _entry([27, 47, 42, 39, 36], force=3.0, max_force=14.0)}
    standin["vices"]["deployment"] = "stochastic"  # a file written before deployments were recorded: deterministic
    sim = tmp_path / "match_sim.json"
    sim.write_text(json.dumps({"noise_sweep": [_sim_row(lv, "shell", [0.9, 0.8]) for lv in (1.0, 2.5)]}))
    noiseless = tmp_path / "match_sim_noiseless.json"  # a second file for the same method
    noiseless.write_text(json.dumps(_sim_row(0.0, "gaussian", [0.9, 0.7])))
    (tmp_path / "standin.json").write_text(json.dumps(standin))
    assert transfer_report.main([str(tmp_path / "standin.json"), "--sim", f"match={sim},match={noiseless}",
                                 "--out", str(tmp_path / "out")]) == 0
    text = (tmp_path / "out" / "TRANSFER.md").read_text()
    assert (tmp_path / "out" / "transfer.png").stat().st_size > 10_000
    assert "| 2.5 | 50 | 88 % [76, 94] |" in text  # 44 / 50 on the stand-in
    assert "### MATCH (policy_seed1, the best of the noiseless trials; deterministic on the stand-in)" in text
    assert "### VICES (policy_seed1, the best of the noiseless trials; stochastic on the stand-in)" in text
    assert text.count("| 80 % | 5 % | 2.50 | +8 |") == 1  # the sim's seed 1 at 2.5 mm, and the gap
    assert "| 0 | 30 | 97 % [83, 99] | 0 % [0, 11] |" in text and "| 70 % | 5 % | 2.50 | +27 |" in text
    assert "| MATCH applies less mean contact force than VICES (robot: up to ~30 % less) | holds |" in text
    with pytest.raises(SystemExit):
        transfer_report.main([str(tmp_path / "missing.json"), "--out", str(tmp_path / "out")])


def test_a_hybrid_table_shows_its_force_selection_beside_the_sims():
    trials = _trials(30, 20)
    counts = dict.fromkeys(("contact_axis_steps", "free_axis_steps", "force_selected_contact_axis_steps",
                            "force_selected_free_axis_steps", "before_success_contact_axis_steps",
                            "before_success_free_axis_steps", "before_success_force_selected_contact_axis_steps",
                            "before_success_force_selected_free_axis_steps"), 0)
    for i, trial in enumerate(trials):
        trial["selection"] = {**counts, "contact_axis_steps": 10, "force_selected_contact_axis_steps": i % 2}
    summary = summarize(trials)
    assert summary["selection"]["force_selected_contact_per_axis"] == pytest.approx(15 / 300)
    assert math.isnan(summary["selection"]["force_selected_free_per_axis"])  # no free axis-step counted
    level = transfer_report.Level(0.0, "policy_seed0", summary, trials)
    sim = [_sim_row(0.0, "gaussian", [0.8])]
    sim[0]["per_seed"][0]["force_selected_contact_per_axis"] = 0.32
    lines = transfer_report.table_lines("match", [level], sim)
    assert lines[2].endswith("| force control in contact, stand-in / sim |")
    assert lines[4].endswith("| 5.0 % (15 / 300) / 32.0 % |")
    plain = transfer_report.table_lines("pose", [level._replace(summary=summarize(_trials(30, 20)))], sim)
    assert "force control" not in plain[2] and plain[4].endswith("| -13 |")


def _protocol_script():
    path = pathlib.Path(__file__).resolve().parents[1] / "benchmarks" / "standin_protocol.py"
    spec = importlib.util.spec_from_file_location("standin_protocol", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_protocol_samples_only_stochastic_exports(tmp_path, capsys):
    """Pose is sampled by default (the paper's deployment): an export without the stochastic output, a
    misspelt method, or a resume with another deployment is a one-line error before any trial runs."""
    protocol = _protocol_script()
    folder = tmp_path / "pose"
    folder.mkdir()
    (folder / "policy_seed0.onnx").write_bytes(b"not run")
    (folder / "policy_seed0.json").write_text(json.dumps({"stochastic": None}))
    out = tmp_path / "standin.json"
    for extra, message in (([], "exported without --stochastic"),
                           (["--stochastic", "Pose"], "names no method: 'Pose'")):
        with pytest.raises(SystemExit):
            protocol.main(["--policies", f"pose={folder}", "--out", str(out), *extra])
        assert message in capsys.readouterr().err
    out.write_text(json.dumps({"pose": {"deployment": "deterministic", "noiseless": {}, "shells": {}}}))
    (folder / "policy_seed0.json").write_text(json.dumps({"stochastic": {"std_scale": 0.05}}))
    with pytest.raises(SystemExit):
        protocol.main(["--policies", f"pose={folder}", "--out", str(out)])
    assert "holds pose run deterministic, not stochastic" in capsys.readouterr().err
