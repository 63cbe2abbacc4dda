"""Table 1 metrics from hand-built trajectories with known outcomes; eval.py's table, usage errors and
output paths."""

import pathlib

import numpy as np
import pytest

from match_jax.training.evaluation import apply_break_threshold, episode_metrics, summarize

T, DT = 6, 1.0 / 15.0


def _traj(B):
    return {
        "success": np.zeros((T, B)), "broken": np.zeros((T, B)), "in_contact": np.zeros((T, B)),
        "mean_force": np.zeros((T, B)), "position_axes": np.ones((T, B, 3)), "done_before": np.zeros((T, B)),
        "contact_axes_before": np.zeros((T, B, 3)), "contact_axes": np.zeros((T, B, 3)), "max_force": np.zeros((T, B)),
        "ee_force": np.zeros((T, B, 3)),
        "done": np.zeros((T, B)),
    }


def test_known_episodes():
    traj = _traj(3)
    # episode 0: contact from step 2 with 2 N, success at step 3, force selected on z while in contact
    traj["in_contact"][2:, 0] = 1
    traj["mean_force"][2:, 0] = 2.0
    traj["success"][3:, 0] = 1
    traj["position_axes"][2:, 0, 2] = 0.0
    traj["position_axes"][0, 0, :] = 0.0  # all three axes force-selected on free step 0
    # episode 1: contact at steps 1-2 (4 N, 6 N), breaks at step 2, later steps belong to no episode
    traj["in_contact"][1:3, 1] = 1
    traj["mean_force"][1:3, 1] = [4.0, 6.0]
    traj["broken"][2, 1] = 1
    traj["done_before"][3:, 1] = 1
    traj["success"][4, 1] = 1  # after the episode ended: must not count
    traj["mean_force"][4, 1] = 100.0
    # episode 2: never touches
    m = episode_metrics(traj, DT)
    np.testing.assert_array_equal(m["success"], [1, 0, 0])
    np.testing.assert_array_equal(m["broken"], [0, 1, 0])
    assert m["time_to_success_s"][0] == pytest.approx(4 * DT)
    assert np.isnan(m["time_to_success_s"][1]) and np.isnan(m["time_to_success_s"][2])
    assert m["mean_force_n"][0] == pytest.approx(2.0)
    assert m["mean_force_n"][1] == pytest.approx(5.0)
    assert np.isnan(m["mean_force_n"][2])
    assert m["force_selected_contact"][0] == pytest.approx(1.0 / 3.0)
    assert m["force_selected_free"][0] == pytest.approx(0.5)  # free steps 0, 1: (1 + 0) / 2
    s = summarize(m)
    assert s["episodes"] == 3
    assert s["success_rate"] == pytest.approx(1 / 3)
    assert s["break_rate"] == pytest.approx(1 / 3)
    assert s["mean_time_to_success_s"] == pytest.approx(4 * DT)
    assert s["mean_force_n"] == pytest.approx(3.5)


def test_per_axis_force_selection_against_hand_count():
    """sum_i [force_i and contact_i] / sum_i contact_i over steps and axes, pooled over episodes; dead
    steps (after an episode ended) never count."""
    traj = _traj(2)
    x, y, z = 0, 1, 2
    # episode 0: z in contact at steps 2-5, x at steps 3-4; force on z at 2-4, on x at 3, on y at 0 (free)
    traj["contact_axes_before"][2:, 0, z] = 1
    traj["contact_axes_before"][3:5, 0, x] = 1
    traj["position_axes"][2:5, 0, z] = 0.0
    traj["position_axes"][3, 0, x] = 0.0
    traj["position_axes"][0, 0, y] = 0.0
    # episode 1: ended after step 2; z in contact at 1-2 (and at dead step 4); force on z at 1, on x at 0
    traj["done_before"][3:, 1] = 1
    traj["contact_axes_before"][1:3, 1, z] = 1
    traj["contact_axes_before"][4, 1, z] = 1
    traj["position_axes"][1, 1, z] = 0.0
    traj["position_axes"][0, 1, x] = 0.0
    traj["position_axes"][4, 1, :] = 0.0
    s = summarize(episode_metrics(traj, DT))
    # in contact: z 4 + 2 axis-steps (3 + 1 forced), x 2 (1 forced), y none
    assert s["force_selected_contact_per_axis"] == pytest.approx(5 / 8)
    assert s["force_selected_contact_x"] == pytest.approx(1 / 2)
    assert np.isnan(s["force_selected_contact_y"])
    assert s["force_selected_contact_z"] == pytest.approx(4 / 6)
    # free: 27 alive axis-steps - 8 in contact = 19; forced: y at ep 0 step 0, x at ep 1 step 0
    assert s["force_selected_free_per_axis"] == pytest.approx(2 / 19)
    assert s["force_selected_free_x"] == pytest.approx(1 / 7)
    assert s["force_selected_free_y"] == pytest.approx(1 / 9)
    assert s["force_selected_free_z"] == pytest.approx(0.0)


def test_break_samplings_differ_on_a_force_spike():
    """A 14 N spike inside a policy step that ends at 6 N breaks a 10 N peg by the peak, not by the
    once-per-step reading; a step that ends at 12 N breaks it by both."""
    traj = _traj(2)
    traj["max_force"][2, :] = 14.0
    traj["ee_force"][2, :] = [0.0, 0.0, -6.0]
    traj["max_force"][4, 1] = 12.5
    traj["ee_force"][4, 1] = [0.0, 9.0, -7.5]  # |F| = 11.7 N
    peak = apply_break_threshold(traj, 10.0, "peak")
    step = apply_break_threshold(traj, 10.0, "policy_step")
    np.testing.assert_array_equal(peak["broken"][2], [1, 1])
    np.testing.assert_array_equal(peak["done_before"][3:], np.ones((T - 3, 2)))
    np.testing.assert_array_equal(step["broken"][:, 0], np.zeros(T))
    assert np.nonzero(step["broken"][:, 1])[0][0] == 4
    assert step["done_before"][5, 1] == 1 and step["done_before"][5, 0] == 0
    assert summarize(episode_metrics(peak, DT))["break_rate"] == 1.0
    assert summarize(episode_metrics(step, DT))["break_rate"] == 0.5
    with pytest.raises(ValueError, match="wrist"):
        apply_break_threshold(traj, 10.0, "wrist")


def test_success_after_break_does_not_count():
    traj = _traj(1)
    traj["broken"][1, 0] = 1
    traj["success"][1:, 0] = 1  # same step as the break: the break came first within the step
    m = episode_metrics(traj, DT)
    assert m["success"][0] == 0 and m["broken"][0] == 1


def test_selection_profile_segments_and_normalises_phases():
    from match_jax.training.analysis import contact_selection_rates, selection_profile

    T = 8
    phase = np.array([[0, 0, 1, 1, 1, 1, 2, 2], [0, 0, 0, 0, 1, 1, 1, 1]]).T  # (T, 2)
    alive = np.ones((T, 2))
    alive[6:, 1] = 0  # episode 1 broke after step 5: its last steps belong to no episode
    p = np.zeros((T, 2, 3))
    p[:, 0, 2] = np.arange(T) / 10  # z of episode 0: 0.0 .. 0.7
    p[:, 1, 0] = 1.0  # episode 1 always force on x
    prof = selection_profile(phase, p, alive, bins=2)
    np.testing.assert_array_equal(prof["episodes"], [2, 2, 1])
    # approach: ep0 steps 0,1 (one per bin), ep1 steps 0..3 (two per bin)
    np.testing.assert_array_equal(prof["count"][0], [3, 3])
    np.testing.assert_allclose(prof["mean"][0, :, 2], [0.0, 0.1 / 3])
    np.testing.assert_allclose(prof["mean"][0, :, 0], [2 / 3, 2 / 3])
    # contact: ep0 steps 2..5 -> bins [2,3], [4,5]; ep1 steps 4,5 only (6,7 not alive)
    np.testing.assert_array_equal(prof["count"][1], [3, 3])
    np.testing.assert_allclose(prof["mean"][1, :, 2], [(0.2 + 0.3) / 3, (0.4 + 0.5) / 3])
    # insertion: only ep0 steps 6, 7
    np.testing.assert_allclose(prof["mean"][2, :, 2], [0.6, 0.7])
    rates = contact_selection_rates(phase > 0, p, alive)
    assert rates["contact_steps"] == 8 and rates["free_steps"] == 6
    assert rates["p_force_free"] == pytest.approx((0.1 / 3 + 4 * 1 / 3) / 6)


def test_break_threshold_from_an_unbreakable_rollout():
    from match_jax.training.evaluation import apply_break_threshold

    traj = _traj(2)
    traj["done"] = np.zeros((T, 2))
    traj["done"][-1] = 1  # time-out at the end
    traj["max_force"] = np.zeros((T, 2))
    traj["max_force"][2, 0] = 12.0  # would break at 10 N on step 2 ...
    traj["success"][4:, 0] = 1  # ... so the later success must not count
    traj["max_force"][3, 1] = 9.0  # below the threshold
    traj["success"][5, 1] = 1
    unbreakable = episode_metrics(traj, DT)
    np.testing.assert_array_equal(unbreakable["success"], [1, 1])
    broken = apply_break_threshold(traj, 10.0)
    np.testing.assert_array_equal(broken["done_before"][:, 0], [0, 0, 0, 1, 1, 1])
    m = episode_metrics(broken, DT)
    np.testing.assert_array_equal(m["success"], [0, 1])
    np.testing.assert_array_equal(m["broken"], [1, 0])
    assert episode_metrics(apply_break_threshold(traj, 15.0), DT)["broken"].sum() == 0


def test_runs_differing_in_break_force_noise_or_ssl_share_one_evaluation_program():
    """The evaluation rollout is unbreakable and sets every episode's hole-observation offset, so the
    suite's MATCH, MATCH (no SSL), MATCH (unbreakable) and Hybrid-Basic runs evaluate with one compiled
    program; another action space, network or env gets its own."""
    import dataclasses
    import math

    from match_jax.rl.distributions import make_distribution
    from match_jax.envs import FPiHConfig
    from match_jax.training.evaluation import _grid_rollout, evaluation_config
    from match_jax.rl.networks import NetworkConfig
    from match_jax.rl.ppo import PPOConfig

    hybrid = FPiHConfig(control="hybrid")
    match = evaluation_config(PPOConfig(method="match"), hybrid)
    for ppo, env in [(PPOConfig(method="match", ssl_coef=0.0, learning_rate=1e-5, total_steps=10), hybrid),
                     (PPOConfig(method="match"), dataclasses.replace(hybrid, break_force=math.inf)),
                     (PPOConfig(method="match", selection_in_ratio=False),
                      dataclasses.replace(hybrid, hole_obs_noise=0.0025, hole_obs_noise_type="uniform"))]:
        assert evaluation_config(ppo, env) == match
    assert _grid_rollout(*evaluation_config(PPOConfig(method="match", ssl_coef=0.0), hybrid)) is _grid_rollout(*match)
    # Hybrid-Basic's deterministic policy is MATCH's (same head, mode and action mapping)
    assert evaluation_config(PPOConfig(method="hybrid", ssl_coef=0.0), hybrid) == match
    for name in ("mode", "to_action"):
        assert getattr(type(make_distribution("hybrid")), name) is getattr(type(make_distribution("match")), name)
    for ppo, env in [(PPOConfig(method="match", network=NetworkConfig(64, 1, 64, 1)), hybrid),
                     (PPOConfig(method="match"), dataclasses.replace(hybrid, episode_steps=100))]:
        assert evaluation_config(ppo, env) != match
    assert evaluation_config(PPOConfig(method="pose"), FPiHConfig(control="pose")) != match


def _result(hybrid=True):
    from match_jax.training.evaluation import AXIS_COLUMNS, COLUMNS

    per_seed = []
    for i in range(2):
        row = {c: 0.25 for c in COLUMNS + AXIS_COLUMNS}
        row.update(seed=i, success_rate=0.9 - 0.1 * i, break_rate=0.05, mean_time_to_success_s=7.77,
                   authors_time_to_success_s=4.44, mean_force_n=8.88, authors_mean_force_n=2.22)
        per_seed.append(row)
    aggregate = {c: {"mean": float(np.mean([r[c] for r in per_seed])), "se": 0.01} for c in per_seed[0] if c != "seed"}
    return dict(method="match", ssl_coef=0.3, checkpoint="best", episodes_per_seed=100, seeds=2, noise_mm=1.0,
                noise_type="gaussian", break_force_n=10.0, break_sampling="policy_step", per_seed=per_seed,
                aggregate=aggregate)


def test_the_printed_table_defaults_to_the_headline_columns_with_a_legend():
    """Success, break, time and force (the authors' time and force, as the README quotes them), a legend
    line, and narrow; every column with all_columns=True."""
    from match_jax.training.evaluation import format_result

    lines = format_result(_result()).splitlines()
    assert lines[1].split() == ["seed", "success", "%", "break", "%", "time", "(s)", "force", "(N)"]
    assert lines[2].split() == ["0", "90.0", "5.00", "4.44", "2.22"]  # the authors' time and force, not ours
    assert lines[4].startswith("  mean+-SE   ") and "85.0 +- 1.00" in lines[4]
    assert lines[5] == ("  break: wrist |F| at 15 Hz > 10 N; time to success (s), mean contact force (N): the "
                        "authors' definitions; more: --all-columns")
    assert len(lines) == 6 and max(len(line) for line in lines) <= 130
    unbreakable = format_result({**_result(), "break_force_n": None}).splitlines()[-1]
    assert unbreakable.startswith("  no break threshold;")
    full = format_result(_result(), all_columns=True).splitlines()
    for label in ("auth F-acc %", "break peak %", "break 15Hz %", "auth time (s)", "auth force (N)", "F-sel free %"):
        assert label in full[1]
    assert "7.77" in full[2] and "8.88" in full[2] and "4.44" in full[2]
    assert "auth: the authors' definitions" in full[-1]


def test_eval_cli_usage_error_is_short_and_all_columns_is_a_flag(tmp_path, capsys):
    import eval as eval_cli

    assert eval_cli.parse_args([str(tmp_path), "--all-columns"]).all_columns
    assert not eval_cli.parse_args([str(tmp_path)]).all_columns
    with pytest.raises(SystemExit):
        eval_cli.parse_args([])
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2 and lines[0].startswith("usage: eval.py RUN_DIR") and lines[0].endswith("(see --help)")
    assert lines[1] == "eval.py: error: give either a RUN_DIR or --baseline spiral|pose"


def test_eval_cli_checks_its_output_paths_before_the_work_and_keeps_a_result_it_cannot_write(
        tmp_path, monkeypatch, capsys):
    """--json or --render where nothing can be written: one line before any work. A --json write that
    fails anyway prints the results and saves them in the temp directory, named in the one-line error."""
    import json
    import tempfile

    import eval as eval_cli

    def no_work(args):
        raise AssertionError("evaluated before checking the output paths")

    monkeypatch.setattr(eval_cli, "evaluate_run_dir", no_work)
    (tmp_path / "afile").write_text("")
    blocked = tmp_path / "afile" / "out"
    for flags, message in ((["--json", f"{blocked}.json"], f"error: --json {blocked}.json: {tmp_path / 'afile'} is a "
                                                          "file, not a directory"),
                           (["--json", str(tmp_path)], f"error: --json {tmp_path}: {tmp_path} is a directory"),
                           (["--render", f"{blocked}.png"], f"error: --render {blocked}.png: {tmp_path / 'afile'} is")):
        assert eval_cli.main([str(tmp_path / "run")] + flags) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(message), err
    # the path passed the check, then the write failed: the results are printed and saved elsewhere
    monkeypatch.setattr(eval_cli, "evaluate_run_dir", lambda args: {"success_rate": 0.5})
    monkeypatch.setattr(eval_cli, "output_problems", lambda args: [])
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    assert eval_cli.main([str(tmp_path / "run"), "--json", f"{blocked}.json"]) == 1
    captured = capsys.readouterr()
    assert json.loads(captured.out)["success_rate"] == 0.5
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: cannot write --json {blocked}.json (")
    fallback = pathlib.Path(err[0].rsplit(" saved to ", 1)[1])
    assert fallback.parent == tmp_path and json.loads(fallback.read_text())["success_rate"] == 0.5
