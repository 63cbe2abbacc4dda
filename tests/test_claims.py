"""Statistics of the suite's report: intervals, steps to a success rate, and the claim verdicts."""

import math

import numpy as np
import pytest
import scipy.stats

from match_jax.experiments import claims


def test_ci95_halfwidth_is_the_t_interval():
    assert claims.ci95_halfwidth([1.0, 2.0, 3.0]) == pytest.approx(scipy.stats.t.ppf(0.975, 2) / math.sqrt(3))
    assert claims.ci95_halfwidth([1.0, 2.0, None, float("nan"), 3.0]) == pytest.approx(2.4841, abs=1e-3)
    assert math.isnan(claims.ci95_halfwidth([1.0]))


def test_difference_interval_is_welchs():
    a, b = [1.0, 2.0, 3.0], [5.0, 7.0, 9.0, 11.0]
    diff, lo, hi = claims.difference_ci(a, b)
    va, vb = np.var(a, ddof=1) / 3, np.var(b, ddof=1) / 4
    dof = (va + vb) ** 2 / (va ** 2 / 2 + vb ** 2 / 3)
    half = scipy.stats.t.ppf(0.975, dof) * math.sqrt(va + vb)
    assert diff == pytest.approx(-6.0) and lo == pytest.approx(-6.0 - half) and hi == pytest.approx(-6.0 + half)
    assert claims.difference_ci([], b)[0] != claims.difference_ci([], b)[0]  # NaN


@pytest.mark.parametrize("a, b, verdict", [
    ([0.0, 0.01, 0.0], [0.2, 0.25, 0.3], claims.HOLDS),
    ([0.2, 0.25, 0.3], [0.0, 0.01, 0.0], claims.FAILS),
    ([0.0, 0.5, 0.1], [0.2, 0.0, 0.3], claims.INCONCLUSIVE),
    ([], [0.2, 0.0, 0.3], claims.MISSING),
])
def test_verdict_lower(a, b, verdict):
    assert claims.verdict_lower(a, b) == verdict


def test_verdict_as_fast():
    pose = [1.0e6, 1.1e6, 0.9e6]
    assert claims.verdict_as_fast([1.05e6, 0.95e6, 1.1e6], pose) == claims.HOLDS  # within 20 %
    assert claims.verdict_as_fast([2.0e6, 2.1e6, 1.9e6], pose) == claims.FAILS  # significantly slower
    assert claims.verdict_as_fast([0.9e6, 1.9e6, 1.2e6], pose) == claims.INCONCLUSIVE  # 33 % slower, not significant
    assert claims.verdict_as_fast([1.0e6], [1.0e6]) == claims.INCONCLUSIVE  # one seed each: no interval


def test_censored_values_never_make_a_claim_hold_that_they_could_break():
    """A seed that never reached the threshold is a lower bound: 'a < b' cannot hold on censored a, cannot
    fail on censored b; neither run reaching 80 % (both at their trained steps) is inconclusive."""
    low, high = [1.0, 1.1, 0.9], [3.0, 3.1, 2.9]
    assert claims.verdict_lower(low, high, a_censored=True) == claims.INCONCLUSIVE
    assert claims.verdict_lower(low, high, b_censored=True) == claims.HOLDS
    assert claims.verdict_lower(high, low, b_censored=True) == claims.INCONCLUSIVE
    assert claims.verdict_lower(high, low, a_censored=True) == claims.FAILS
    never = [1.2e6, 1.2e6, 1.2e6]
    assert claims.verdict_as_fast(never, never, True, True) == claims.INCONCLUSIVE
    assert claims.verdict_as_fast([1.0e6, 1.05e6, 0.95e6], never, False, True) == claims.HOLDS
    assert claims.verdict_as_fast(never, [0.3e6, 0.31e6, 0.29e6], True, False) == claims.FAILS
    assert claims.verdict_as_fast(never, [0.3e6, 0.31e6, 0.29e6], True, True) == claims.INCONCLUSIVE


def test_steps_to_smooths_over_the_window():
    steps = [100, 200, 300, 400, 500]
    rate = [0.0, 0.9, 0.5, 0.9, 0.9]
    assert claims.steps_to(steps, rate, 0.8, window=1) == 200
    assert claims.steps_to(steps, rate, 0.8, window=2) == 500  # (0.5 + 0.9) / 2 = 0.7 at 400
    assert claims.steps_to(steps, [0.9, float("nan"), 0.9], 0.8, window=2) == 200  # NaN iterations skipped
    assert math.isnan(claims.steps_to(steps, rate, 0.95, window=1))


def test_check_claims_reads_the_right_runs_and_metrics():
    table = {("pose", "break"): [0.2, 0.25, 0.3], ("match", "break"): [0.0, 0.0, 0.01],
             ("hybrid", "break"): [0.2, 0.3, 0.25], ("match", "force_contact"): [0.8, 0.9, 0.85],
             ("match", "force_free"): [0.3, 0.2, 0.25], ("pose", "success"): [0.9, 0.88, 0.86],
             ("match_literal", "success"): [0.97, 0.98, 0.96], ("match", "success_7.5"): [0.4, 0.38, 0.42],
             ("pose_noise2.5", "success_7.5"): [0.1, 0.15, 0.05]}
    speed = {"match": [1e6, 1.1e6, 0.9e6], "pose": [1e6, 1.05e6, 0.95e6], "hybrid": [3e6, 3e6, 2.9e6],
             "match_literal": [2e6, 2.1e6, 2.2e6]}
    found = {c.text: c for c in claims.check_claims(lambda run, metric: table.get((run, metric), []),
                                                    lambda run, threshold: (speed.get(run, []), False))}
    assert found["MATCH breaks less than Pose (10 N, training noise)"].verdict == claims.HOLDS
    assert found["Hybrid-Basic breaks less than Pose (10 N, training noise)"].verdict == claims.INCONCLUSIVE
    assert found["MATCH learns as fast as Pose (env steps to 80 % training success)"].verdict == claims.HOLDS
    assert found["Hybrid-Basic learns slower than MATCH (env steps to 80 %)"].verdict == claims.HOLDS
    assert found["MATCH selects force on most in-contact axes (paper: 84 %)"].verdict == claims.HOLDS
    assert found["MATCH rarely selects force on free-space axes (paper: 2.9 %)"].verdict == claims.FAILS
    assert found["MATCH without the SSL succeeds less often (paper: 15 points)"].verdict == claims.MISSING
    # MATCH with the authors' force law is read from its own run, against Pose
    literal = found["MATCH with the authors' force law succeeds more often than Pose"]
    assert literal.verdict == claims.HOLDS and literal.numbers == "97.0 % vs 88.0 %"
    assert found["MATCH succeeds more often than Pose"].verdict == claims.MISSING
    slower = found["MATCH with the authors' force law learns as fast as Pose (env steps to 80 % training success)"]
    assert slower.verdict == claims.FAILS and slower.numbers == "2.10M vs 1.00M"
    assert not any("damped force law" in text for text in found)  # that variant's run is not evaluated
    assert found["MATCH breaks less than Pose (10 N, training noise)"].numbers == "0.3 % vs 25.0 %"
    # the noise claim against Pose trained at 2.5 mm reads that run's sweep, not Pose's
    wide = found["MATCH degrades less with noise than Pose trained at 2.5 mm (success at the 7.5 mm noise level)"]
    assert wide.verdict == claims.HOLDS and wide.numbers == "40.0 % vs 10.0 %"
    assert found["MATCH degrades less with noise than Pose (success at the 7.5 mm noise level)"].verdict == claims.MISSING


def test_suite_claims_read_the_mean_force_of_the_task_protocol():
    """The force claim compares the authors' mean force on their task and ours on the earlier variant."""
    from match_jax.experiments import report

    def grid(ours, authors):
        seeds = [{"mean_force_n": f, "authors_mean_force_n": g} for f, g in zip(ours, authors)]
        return [{"noise_type": "gaussian", "noise_mm": 1.0, "break_force_n": 10.0, "per_seed": seeds}]

    results = {"pose": grid([0.7, 0.7, 0.7], [1.0, 1.1, 0.9]), "match": grid([0.7, 0.7, 0.7], [3.0, 3.1, 2.9])}
    text = "Pose applies less mean contact force than MATCH"
    authors = {c.text: c for c in report.suite_claims(results, {}, task="authors")}[text]
    earlier = {c.text: c for c in report.suite_claims(results, {}, task="earlier")}[text]
    assert authors.verdict == claims.HOLDS and authors.numbers == "1.00 N vs 3.00 N"
    assert earlier.verdict == claims.INCONCLUSIVE and earlier.numbers == "0.70 N vs 0.70 N"
    randomised = {c.text: c for c in report.suite_claims(results, {}, task="authors_dr")}[text]
    assert randomised.numbers == "1.00 N vs 3.00 N"  # the authors' randomised task reports their metric


def test_verdict_alike_holds_when_the_interval_contains_zero():
    assert claims.verdict_alike([0.1, 0.2, 0.15], [0.12, 0.18, 0.2]) == claims.HOLDS
    assert claims.verdict_alike([0.1, 0.11, 0.12], [0.3, 0.31, 0.29]) == claims.FAILS
    assert claims.verdict_alike([0.1], [0.3]) == claims.INCONCLUSIVE  # one seed each: no interval
    assert claims.verdict_alike([], [0.3, 0.2]) == claims.MISSING


def _found(table, profile=None):
    return {c.text: c for c in claims.check_claims(lambda run, metric: table.get((run, metric), []),
                                                   lambda run, threshold: ([], False),
                                                   lambda run: profile if run == "match" else None)}


def test_zero_break_claim_needs_every_seed_at_zero():
    text = "MATCH never breaks the peg at the training noise (paper: 0 of 500 episodes)"
    assert _found({("match", "break"): [0.0, 0.0, 0.0]})[text].verdict == claims.HOLDS
    assert _found({("match", "break"): [0.0, 0.002, 0.0]})[text].verdict == claims.FAILS
    assert _found({})[text].verdict == claims.MISSING


def test_ssl_claims_compare_each_method_with_its_ablation():
    table = {("match", "break"): [0.0, 0.01, 0.0], ("match_nossl", "break"): [0.2, 0.25, 0.3],
             ("match", "contact_training"): [0.3, 0.32, 0.31], ("match_nossl", "contact_training"): [0.1, 0.11, 0.09],
             ("match_nossl", "p_force_free_training"): [0.0005, 0.0002, 0.0003],
             ("hybrid_nossl", "p_force_free_training"): [0.01, 0.02, 0.01]}
    speed = {"match": [1e6, 1.1e6, 0.9e6], "match_nossl": [2.5e6, 2.5e6, 2.5e6]}  # no-SSL never reached 80 %
    found = {c.text: c for c in claims.check_claims(lambda run, metric: table.get((run, metric), []),
                                                    lambda run, t: (speed.get(run, []), run == "match_nossl"))}
    slower = found["MATCH without the SSL learns slower (env steps to 80 %)"]
    assert slower.verdict == claims.HOLDS and slower.numbers == ">= 2.50M vs 1.00M"
    assert found["MATCH breaks less often than without the SSL (paper: 8.2 points)"].verdict == claims.HOLDS
    contact = found["MATCH without the SSL is in contact less during training (second half; paper: 3x less)"]
    assert contact.verdict == claims.HOLDS and contact.numbers == "10.0 % vs 31.0 %"
    selects = "without the SSL selects force below 0.1 % during training (second half, free-space axes)"
    assert found[f"MATCH {selects}"].verdict == claims.HOLDS
    assert found[f"Hybrid-Basic {selects}"].verdict == claims.FAILS
    assert found["Hybrid-Basic breaks less often than without the SSL (paper: 2.2 points)"].verdict == claims.MISSING


def test_noise_claims_read_shell_breaks_and_no_difference():
    table = {("pose", "break_shells"): [0.2, 0.25, 0.3], ("match", "break_shells"): [0.05, 0.06, 0.04],
             ("vices", "break_shells"): [0.05, 0.07, 0.05], ("vices", "success_7.5"): [0.4, 0.1, 0.3],
             ("match", "success_7.5"): [0.35, 0.3, 0.2], ("pose", "break_1"): [0.1, 0.12, 0.11],
             ("pose", "break_7.5"): [0.3, 0.31, 0.29]}
    found = _found(table)
    assert found["MATCH breaks less than Pose under noise (break %, mean over the shells; paper: less than half)"]\
        .verdict == claims.HOLDS
    assert found["VICES and MATCH succeed alike at the 7.5 mm noise level (no significant difference)"]\
        .verdict == claims.HOLDS
    constant = "break rate is about constant with noise (first vs last shell, paired over seeds; no significant " \
        "difference)"
    assert found[f"Pose's {constant}"].verdict == claims.FAILS
    assert found["Pose deteriorates with noise (success, last shell below the first)"].verdict == claims.MISSING


def test_paired_alike_uses_the_per_seed_differences():
    """Seeds far apart but each one alike at both levels: Welch's interval is wide, the paired one narrow."""
    first, last = [0.05, 0.2, 0.35], [0.06, 0.21, 0.36]
    assert claims.verdict_alike(first, last) == claims.HOLDS
    assert claims.verdict_alike(first, last, paired=True) == claims.FAILS  # 1 point lower on every seed
    assert claims.verdict_alike([0.05, 0.2, 0.35], [0.06, 0.19, 0.35], paired=True) == claims.HOLDS


def test_lowest_force_needs_every_comparison():
    table = {("match_nossl", "force"): [1.0, 1.1, 0.9], ("match", "force"): [3.0, 3.1, 2.9],
             ("pose", "force"): [2.0, 2.1, 1.9], ("vices", "force"): [1.0, 1.2, 0.8]}
    text = "MATCH without the SSL applies less mean contact force than MATCH, Pose and VICES (paper: the ablations " \
        "apply the lowest)"
    found = _found(table)[text]
    assert found.verdict == claims.INCONCLUSIVE and found.numbers == "1.00 N vs 3.00 N / 2.00 N / 1.00 N"
    table[("vices", "force")] = [2.0, 2.2, 1.8]
    assert _found(table)[text].verdict == claims.HOLDS
    table[("pose", "force")] = [0.5, 0.4, 0.6]
    assert _found(table)[text].verdict == claims.FAILS


def test_profile_claims_read_the_phase_shape():
    """Rows: approach, contact, insertion; columns x, y, z. The paper's shape holds; a flat profile
    with force in the approach fails three of the four."""
    paper_like = np.array([[0.01, 0.01, 0.02], [0.1, 0.1, 0.6], [0.05, 0.05, 0.2]])
    assert all(_found({}, paper_like)[t].verdict == claims.HOLDS for t in _PROFILE_TEXTS)
    flat = np.full((3, 3), 0.3)
    assert [_found({}, flat)[t].verdict for t in _PROFILE_TEXTS] == [claims.FAILS] * 4
    assert all(_found({})[t].verdict == claims.MISSING for t in _PROFILE_TEXTS)
    unreached = paper_like.copy()
    unreached[2] = np.nan  # no episode reached insertion
    assert all(_found({}, unreached)[t].verdict == claims.INCONCLUSIVE for t in _PROFILE_TEXTS)


_PROFILE_TEXTS = ("MATCH hardly selects force in the approach (P(force) below 5 % on every axis; paper: near 0)",
                  "MATCH selects force on z more in contact than in the approach (paper: a spike, most on z)",
                  "MATCH selects force on z less in insertion than in contact (paper: declines)",
                  "In contact, MATCH selects force on x and y less than on z (paper: xy largely pose)")


def test_suite_claims_pool_the_profile_and_average_the_shells():
    """report.suite_claims: the selection profile is pooled over time bins weighted by their steps; the
    shell break metric is the per-seed mean over the four shells."""
    from match_jax.experiments import report
    profile = {"mean": [[[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]], [[0.0, 0.0, 0.5]] * 2, [[0.0, 0.0, 0.1]] * 2],
               "count": [[3, 1], [2, 2], [1, 1]]}
    pooled = report.pooled_profile(profile)
    assert pooled[0].tolist() == pytest.approx([0.0, 0.0, 0.25]) and pooled[1][2] == pytest.approx(0.5)
    assert np.isnan(report.pooled_profile({**profile, "count": [[3, 1], [2, 2], [0, 0]]})[2]).all()
    shells = [{"noise_type": "shell", "noise_mm": x, "break_force_n": 10.0,
               "per_seed": [{"break_rate": x / 10, "success_rate": 0.5}, {"break_rate": 0.0, "success_rate": 0.5}]}
              for x in report.SHELLS_MM]
    gaussian = {"noise_type": "gaussian", "noise_mm": 1.0, "break_force_n": 10.0, "selection_profile": profile,
                "per_seed": [{"break_rate": 0.0}, {"break_rate": 0.0}]}
    found = {c.text: c for c in report.suite_claims({"match": [gaussian, *shells]}, {})}
    mean_shells = 100 * sum(report.SHELLS_MM) / 10 / len(report.SHELLS_MM) / 2
    assert found["MATCH breaks less than Pose under noise (break %, mean over the shells; paper: less than half)"]\
        .numbers == f"{mean_shells:.1f} % vs -"
    assert found[_PROFILE_TEXTS[0]].verdict == claims.FAILS and found[_PROFILE_TEXTS[0]].numbers == "max 25.0 %"
