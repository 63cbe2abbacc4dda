"""Statistics over seeds for the suite's report: 95 % intervals, env steps to a training success rate,
and the paper's qualitative claims checked as differences of per-seed means.

A claim "a is lower than b" *holds* when the 95 % interval of mean(a) - mean(b) (Welch's t, per-seed
values) lies below 0, *does not hold* when it lies above 0, and is *inconclusive* otherwise. "a is as
fast as b" holds when a is not significantly slower and its mean is at most 20 % above b's. Env steps
of a seed that never reached the threshold are a lower bound (censored): a verdict that its true,
larger value could overturn reads inconclusive.
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


def check_claims(values: Callable[[str, str], list], steps: Callable[[str, float], tuple[list, bool]]) -> list[Claim]:
    """The paper's qualitative claims. `values(run, metric)`: per-seed evaluation values of a suite run
    (metric names: 'success', 'break', 'force', 'force_contact', 'force_free', 'success_7.5',
    'success_unbreakable_7.5'); empty if the run is missing. `steps(run, threshold)`: (per-seed env steps to
    that training success, whether any of them is a lower bound: a seed that never reached it, counted at
    the env steps it trained). A claim whose runs are missing reads 'not run'."""
    claims = []

    def lower(text, a_run, b_run, metric, fmt=_pct):
        a, b = values(a_run, metric), values(b_run, metric)
        claims.append(Claim(text, verdict_lower(a, b), f"{fmt(a)} vs {fmt(b)}"))

    def steps_fmt(x, censored):
        return "-" if math.isnan(_mean(x)) else (">= " if censored else "") + f"{_mean(x) / 1e6:.2f}M"

    for hybrid in ("hybrid", "match"):
        lower(f"{'Hybrid-Basic' if hybrid == 'hybrid' else 'MATCH'} breaks less than Pose (10 N, training noise)",
              hybrid, "pose", "break")
    variants = tuple((run, label) for run, label in LAW_VARIANTS if len(values(run, "success")))
    for hybrid, label in (("hybrid", "Hybrid-Basic"), ("match", "MATCH"), *variants):
        a, b = values("pose", "success"), values(hybrid, "success")
        claims.append(Claim(f"{label} succeeds more often than Pose", verdict_lower(a, b), f"{_pct(b)} vs {_pct(a)}"))
    for run, label in (("match", "MATCH"), *variants):
        (a, a_cens), (b, b_cens) = steps(run, 0.8), steps("pose", 0.8)
        claims.append(Claim(f"{label} learns as fast as Pose (env steps to 80 % training success)",
                            verdict_as_fast(a, b, a_cens, b_cens), f"{steps_fmt(a, a_cens)} vs {steps_fmt(b, b_cens)}"))
    (a, a_cens), (b, b_cens) = steps("match", 0.8), steps("hybrid", 0.8)
    claims.append(Claim("Hybrid-Basic learns slower than MATCH (env steps to 80 %)", verdict_lower(a, b, a_cens, b_cens),
                        f"{steps_fmt(b, b_cens)} vs {steps_fmt(a, a_cens)}"))
    for run, label in (("match", "MATCH"), ("hybrid", "Hybrid-Basic")):
        a, b = values(f"{run}_nossl", "success"), values(run, "success")
        claims.append(Claim(f"{label} without the SSL succeeds less often", verdict_lower(a, b),
                            f"{_pct(a)} vs {_pct(b)}"))
    for pose, pose_label in (("pose", "Pose"), ("pose_noise2.5", "Pose trained at 2.5 mm")):
        for hybrid, label in (("match", "MATCH"), ("hybrid", "Hybrid-Basic")):
            a, b = values(pose, "success_7.5"), values(hybrid, "success_7.5")
            claims.append(Claim(f"{label} degrades less with noise than {pose_label} (success at the 7.5 mm noise level)",
                                verdict_lower(a, b), f"{_pct(b)} vs {_pct(a)}"))
    contact, free = values("match", "force_contact"), values("match", "force_free")
    in_contact = MISSING if not len(_finite(contact)) else HOLDS if _mean(contact) > 0.5 else FAILS
    claims.append(Claim("MATCH selects force on most in-contact axes (paper: 84 %)", in_contact, _pct(contact)))
    rarely = MISSING if not len(_finite(free)) else HOLDS if _mean(free) < 0.1 else FAILS
    claims.append(Claim("MATCH rarely selects force on free-space axes (paper: 2.9 %)", rarely, _pct(free)))
    lower("Pose applies less mean contact force than MATCH (Pose vs MATCH)", "pose", "match", "force",
          fmt=lambda x: "-" if math.isnan(_mean(x)) else f"{_mean(x):.2f} N")
    for run, label in (("match_unbreakable", "MATCH"), ("vices_unbreakable", "VICES")):
        a, b = values("pose_unbreakable", "success_unbreakable_7.5"), values(run, "success_unbreakable_7.5")
        claims.append(Claim(f"Trained unbreakable, {label} is more robust to noise than Pose (success at the 7.5 mm noise level)",
                            verdict_lower(a, b), f"{_pct(b)} vs {_pct(a)}"))
    return claims
