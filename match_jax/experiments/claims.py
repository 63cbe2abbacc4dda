"""Statistics over seeds for the suite's report: 95 % intervals, env steps to a training success rate,
and the paper's qualitative claims checked as differences of per-seed means.

A claim "a is lower than b" *holds* when the 95 % interval of mean(a) - mean(b) (Welch's t, per-seed
values) lies below 0, *does not hold* when it lies above 0, and is *inconclusive* otherwise. "a is as
fast as b" holds when a is not significantly slower and its mean is at most 20 % above b's. Env steps
of a seed that never reached the threshold are a lower bound (censored): a verdict that its true,
larger value could overturn reads inconclusive. "a and b are alike" (the paper's "no significant
difference") holds when that interval contains 0. Claims on MATCH's selection profile compare means
pooled over seeds (the profile is not kept per seed): no interval.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple, Sequence

import numpy as np
import scipy.stats

HOLDS, FAILS, INCONCLUSIVE, MISSING = "holds", "does not hold", "inconclusive", "not run"
AS_FAST_MARGIN = 0.2  # "as fast as": mean at most 20 % more env steps


def _finite(values) -> np.ndarray:
    return np.asarray([v for v in values if v is not None and not math.isnan(v)], np.float64)


def ci95_halfwidth(values) -> float:
    """Half-width of the 95 % t-interval of the mean of `values` (NaN with fewer than 2)."""
    x = _finite(values)
    if len(x) < 2:
        return float("nan")
    return float(scipy.stats.t.ppf(0.975, len(x) - 1) * np.std(x, ddof=1) / np.sqrt(len(x)))


def difference_ci(a, b) -> tuple[float, float, float]:
    """mean(a) - mean(b) and its 95 % Welch interval (lo, hi); NaN bounds with fewer than 2 values each."""
    a, b = _finite(a), _finite(b)
    if len(a) == 0 or len(b) == 0:
        return float("nan"), float("nan"), float("nan")
    diff = float(a.mean() - b.mean())
    if len(a) < 2 or len(b) < 2:
        return diff, float("nan"), float("nan")
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    se = math.sqrt(va + vb)
    if se == 0.0:
        return diff, diff, diff
    dof = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    half = float(scipy.stats.t.ppf(0.975, dof) * se)
    return diff, diff - half, diff + half


def verdict_lower(a, b, a_censored: bool = False, b_censored: bool = False) -> str:
    """Whether per-seed values `a` are lower than `b` (see the module docstring). `x_censored`: some of x's
    values are lower bounds (a seed that never reached the threshold), so "holds" needs `a` exact and
    "does not hold" needs `b` exact; otherwise the verdict is inconclusive."""
    diff, lo, hi = difference_ci(a, b)
    if math.isnan(diff):
        return MISSING
    if hi < 0 and not a_censored:
        return HOLDS
    if lo > 0 and not b_censored:
        return FAILS
    return INCONCLUSIVE


def verdict_as_fast(a, b, a_censored: bool = False, b_censored: bool = False) -> str:
    """Whether env steps `a` are no more than b's (not significantly more, mean within 20 %); with
    censored values (lower bounds) as in `verdict_lower`."""
    diff, lo, _ = difference_ci(a, b)
    if math.isnan(diff):
        return MISSING
    if math.isnan(lo):  # one seed: no interval
        return INCONCLUSIVE
    if lo > 0:
        return INCONCLUSIVE if b_censored else FAILS
    if a_censored:
        return INCONCLUSIVE
    return HOLDS if diff <= AS_FAST_MARGIN * float(np.mean(_finite(b))) else INCONCLUSIVE


def paired_difference_ci(a, b) -> tuple[float, float, float]:
    """mean(a - b) over the seeds both have and its 95 % t-interval (lo, hi): `a` and `b` are two
    measurements of the same seeds. NaN bounds with fewer than 2 pairs."""
    pairs = [(x, y) for x, y in zip(a, b) if len(_finite([x, y])) == 2]
    if not pairs:
        return float("nan"), float("nan"), float("nan")
    d = np.array([x - y for x, y in pairs], np.float64)
    half = ci95_halfwidth(d)
    return float(d.mean()), float(d.mean() - half), float(d.mean() + half)


def verdict_alike(a, b, paired: bool = False) -> str:
    """Whether per-seed values `a` and `b` do not differ significantly: the 95 % interval of the difference
    of means (Welch; `paired`: of the per-seed differences, a and b measured on the same seeds) contains 0
    (holds) or not (does not hold); inconclusive without an interval (one seed)."""
    diff, lo, hi = (paired_difference_ci if paired else difference_ci)(a, b)
    if math.isnan(diff):
        return MISSING
    if math.isnan(lo):
        return INCONCLUSIVE
    return HOLDS if lo <= 0.0 <= hi else FAILS


def steps_to(env_steps: Sequence[float], success_rate: Sequence[float], threshold: float, window: int) -> float:
    """The first env-step count at which the mean training success of the last `window` iterations
    (NaN iterations skipped) reaches `threshold`; NaN if it never does."""
    rate = np.asarray(success_rate, np.float64)
    for j in range(len(rate)):
        recent = rate[max(0, j - window + 1):j + 1]
        recent = recent[~np.isnan(recent)]
        if j + 1 >= window and len(recent) and recent.mean() >= threshold:
            return float(env_steps[j])
    return float("nan")


class Claim(NamedTuple):
    text: str
    verdict: str
    numbers: str


def _mean(values) -> float:
    x = _finite(values)
    return float(x.mean()) if len(x) else float("nan")


def _pct(values) -> str:
    return "-" if math.isnan(_mean(values)) else f"{100 * _mean(values):.1f} %"


# Suite runs training MATCH with the force law that is not their task's own: claims on them appear when
# they are evaluated (the earlier task's suite has match_literal, the authors' task's match_damped).
LAW_VARIANTS = (("match_literal", "MATCH with the authors' force law"),  # no feed-forward, no damping
                ("match_damped", "MATCH with the damped force law"))  # feed-forward and force-axis damping


PROFILE_APPROACH_MAX = 0.05  # "near 0 probability of force control" in the approach: below 5 % on every axis


def check_claims(values: Callable[[str, str], list], steps: Callable[[str, float], tuple[list, bool]],
                 profile: Callable[[str], np.ndarray | None] = lambda run: None) -> list[Claim]:
    """The paper's qualitative claims, in its order. `values(run, metric)`: per-seed values of a suite run,
    empty if the run is missing; metrics: at the training noise 'success', 'break', 'force',
    'force_contact', 'force_free'; on the shells 'success_1' and 'success_7.5' (the 0-1 and 5-7.5 mm
    shells), 'break_1' and 'break_7.5', 'break_shells' (mean over the shells); evaluated unbreakable
    'success_unbreakable_7.5'; means over the second half of training 'contact_training' (fraction of env
    steps in contact) and 'p_force_free_training' (P(force) on free-space axes). `steps(run, threshold)`:
    (per-seed env steps to that training success, whether any of them is a lower bound: a seed that never
    reached it, counted at the env steps it trained). `profile(run)`: P(force) per phase (approach, contact,
    insertion) and axis (x, y, z), pooled over seeds and time, or None. A claim whose runs are missing reads
    'not run'."""
    claims = []

    def newton(x):
        return "-" if math.isnan(_mean(x)) else f"{_mean(x):.2f} N"

    def lower(text, a_run, b_run, metric, fmt=_pct):
        a, b = values(a_run, metric), values(b_run, metric)
        claims.append(Claim(text, verdict_lower(a, b), f"{fmt(a)} vs {fmt(b)}"))

    def higher(text, a_run, b_run, metric):
        """a_run's values above b_run's (printed in that order)."""
        a, b = values(a_run, metric), values(b_run, metric)
        claims.append(Claim(text, verdict_lower(b, a), f"{_pct(a)} vs {_pct(b)}"))

    def alike(text, a_run, b_run, metric_a, metric_b=None):
        a, b = values(a_run, metric_a), values(b_run, metric_b or metric_a)
        claims.append(Claim(text, verdict_alike(a, b, paired=a_run == b_run), f"{_pct(a)} vs {_pct(b)}"))

    def lowest(text, a_run, others, metric, fmt):
        """a_run's values below each of `others`': holds when every comparison holds, does not hold when
        one does not, inconclusive otherwise."""
        a = values(a_run, metric)
        verdicts = [verdict_lower(a, values(b, metric)) for b in others]
        verdict = MISSING if MISSING in verdicts else FAILS if FAILS in verdicts else \
            HOLDS if all(v == HOLDS for v in verdicts) else INCONCLUSIVE
        claims.append(Claim(text, verdict, f"{fmt(a)} vs " + " / ".join(fmt(values(b, metric)) for b in others)))

    def steps_fmt(x, censored):
        return "-" if math.isnan(_mean(x)) else (">= " if censored else "") + f"{_mean(x) / 1e6:.2f}M"

    hybrids = (("hybrid", "Hybrid-Basic"), ("match", "MATCH"))
    # How effective are hybrid control policies (Table 1, training noise)?
    for other, other_label in (("pose", "Pose"), ("vices", "VICES")):
        for hybrid, label in hybrids:
            lower(f"{label} breaks less than {other_label} (10 N, training noise)", hybrid, other, "break")
    variants = tuple((run, label) for run, label in LAW_VARIANTS if len(values(run, "success")))
    for other, other_label in (("pose", "Pose"), ("vices", "VICES")):
        for hybrid, label in (*hybrids, *(variants if other == "pose" else ())):
            higher(f"{label} succeeds more often than {other_label}", hybrid, other, "success")
    breaks = _finite(values("match", "break"))
    claims.append(Claim("MATCH never breaks the peg at the training noise (paper: 0 of 500 episodes)",
                        MISSING if not len(breaks) else HOLDS if not breaks.any() else FAILS, _pct(breaks)))
    for other, other_label in (("pose", "Pose"), ("vices", "VICES")):
        for hybrid, label in hybrids:
            lower(f"{other_label} applies less mean contact force than {label}", other, hybrid, "force", newton)
    # Does MATCH improve learning efficiency?
    for run, label in (("match", "MATCH"), ("vices", "VICES"), *variants):
        (a, a_cens), (b, b_cens) = steps(run, 0.8), steps("pose", 0.8)
        claims.append(Claim(f"{label} learns as fast as Pose (env steps to 80 % training success)",
                            verdict_as_fast(a, b, a_cens, b_cens), f"{steps_fmt(a, a_cens)} vs {steps_fmt(b, b_cens)}"))
    for threshold, what in ((0.5, "begins learning later than MATCH (env steps to 50 %)"),
                            (0.8, "learns slower than MATCH (env steps to 80 %)")):
        (a, a_cens), (b, b_cens) = steps("match", threshold), steps("hybrid", threshold)
        claims.append(Claim(f"Hybrid-Basic {what}", verdict_lower(a, b, a_cens, b_cens),
                            f"{steps_fmt(b, b_cens)} vs {steps_fmt(a, a_cens)}"))
    # What effect does the supervised selection loss have?
    for run, label in (("match", "MATCH"), ("hybrid", "Hybrid-Basic")):
        nossl = f"{run}_nossl"
        a, b = values(nossl, "success"), values(run, "success")
        gap = "15" if run == "match" else "11.2"
        claims.append(Claim(f"{label} without the SSL succeeds less often (paper: {gap} points)", verdict_lower(a, b),
                            f"{_pct(a)} vs {_pct(b)}"))
        lower(f"{label} breaks less often than without the SSL (paper: {'8.2' if run == 'match' else '2.2'} points)",
              run, nossl, "break")
        lowest(f"{label} without the SSL applies less mean contact force than {label}, Pose and VICES (paper: "
               "the ablations apply the lowest)", nossl, (run, "pose", "vices"), "force", newton)
        (a, a_cens), (b, b_cens) = steps(run, 0.8), steps(nossl, 0.8)
        claims.append(Claim(f"{label} without the SSL learns slower (env steps to 80 %)",
                            verdict_lower(a, b, a_cens, b_cens), f"{steps_fmt(b, b_cens)} vs {steps_fmt(a, a_cens)}"))
        lower(f"{label} without the SSL is in contact less during training (second half; paper: 3x less)", nossl, run,
              "contact_training")
        p_free = _finite(values(nossl, "p_force_free_training"))
        claims.append(Claim(f"{label} without the SSL selects force below 0.1 % during training (second half, "
                            "free-space axes)",
                            MISSING if not len(p_free) else HOLDS if _mean(p_free) < 0.001 else FAILS,
                            "-" if not len(p_free) else f"{100 * _mean(p_free):.2f} %"))
    # Does MATCH learn a meaningful selection policy?
    contact, free = values("match", "force_contact"), values("match", "force_free")
    in_contact = MISSING if not len(_finite(contact)) else HOLDS if _mean(contact) > 0.5 else FAILS
    claims.append(Claim("MATCH selects force on most in-contact axes (paper: 84 %)", in_contact, _pct(contact)))
    rarely = MISSING if not len(_finite(free)) else HOLDS if _mean(free) < 0.1 else FAILS
    claims.append(Claim("MATCH rarely selects force on free-space axes (paper: 2.9 %)", rarely, _pct(free)))
    claims += _profile_claims(profile("match"))
    # How robust are hybrid control policies to noise?
    for pose, pose_label in (("pose", "Pose"), ("pose_noise2.5", "Pose trained at 2.5 mm")):
        for hybrid, label in (("match", "MATCH"), ("hybrid", "Hybrid-Basic")):
            higher(f"{label} degrades less with noise than {pose_label} (success at the 7.5 mm noise level)",
                   hybrid, pose, "success_7.5")
    for hybrid, label in hybrids:
        lower(f"{label} breaks less than Pose under noise (break %, mean over the shells; paper: less than half)",
              hybrid, "pose", "break_shells")
    for hybrid, label in hybrids:
        alike(f"VICES and {label} succeed alike at the 7.5 mm noise level (no significant difference)",
              "vices", hybrid, "success_7.5")
        alike(f"VICES and {label} break alike under noise (mean over the shells; no significant difference)",
              "vices", hybrid, "break_shells")
    for run, label in (("pose", "Pose"), ("vices", "VICES"), *hybrids, ("pose_noise2.5", "Pose trained at 2.5 mm")):
        a, b = values(run, "success_7.5"), values(run, "success_1")
        claims.append(Claim(f"{label} deteriorates with noise (success, last shell below the first)",
                            verdict_lower(a, b), f"{_pct(a)} vs {_pct(b)}"))
        alike(f"{label}'s break rate is about constant with noise (first vs last shell, paired over seeds; no "
              "significant difference)", run, run, "break_1", "break_7.5")
    # How are hybrid control policies on unconstrained tasks?
    for run, label, gain in (("match_unbreakable", "MATCH", "17.1"), ("vices_unbreakable", "VICES", "21.1")):
        higher(f"Trained unbreakable, {label} is more robust to noise than Pose (success at the 7.5 mm noise level; "
               f"paper: +{gain} points)", run, "pose_unbreakable", "success_unbreakable_7.5")
        higher(f"Trained unbreakable, {label} is more robust to noise than Hybrid-Basic (7.5 mm; paper: MATCH and "
               "VICES perform best)", run, "hybrid_unbreakable", "success_unbreakable_7.5")
    return claims


def _profile_claims(p: np.ndarray | None) -> list[Claim]:
    """The shape of MATCH's selection profile `p` (phase x axis P(force), pooled over seeds): near 0 in the
    approach, a rise on z after contact, a decline on z for insertion, x and y below z in contact."""
    texts = ("MATCH hardly selects force in the approach (P(force) below 5 % on every axis; paper: near 0)",
             "MATCH selects force on z more in contact than in the approach (paper: a spike, most on z)",
             "MATCH selects force on z less in insertion than in contact (paper: declines)",
             "In contact, MATCH selects force on x and y less than on z (paper: xy largely pose)")
    if p is None:
        return [Claim(t, MISSING, "-") for t in texts]
    p = 100 * np.asarray(p, np.float64)
    (approach, contact, insertion), z = p, 2
    if np.isnan(p).any():  # a phase no evaluated episode reached
        return [Claim(t, INCONCLUSIVE, "a phase without steps") for t in texts]
    checks = ((approach.max() < 100 * PROFILE_APPROACH_MAX, f"max {approach.max():.1f} %"),
              (contact[z] > approach[z], f"{contact[z]:.1f} % vs {approach[z]:.1f} %"),
              (insertion[z] < contact[z], f"{insertion[z]:.1f} % vs {contact[z]:.1f} %"),
              (contact[:z].max() < contact[z], f"x {contact[0]:.1f} %, y {contact[1]:.1f} % vs z {contact[z]:.1f} %"))
    return [Claim(t, HOLDS if ok else FAILS, numbers) for t, (ok, numbers) in zip(texts, checks)]
