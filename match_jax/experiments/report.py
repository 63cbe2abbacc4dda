"""The experiment suite's report: Table 1 beside the paper's, the noise sweep, unbreakable pegs, force
selection, learning speed, early training, the paper's claims, and the three figures (REPORT.md)."""

from __future__ import annotations

import math
import pathlib

import numpy as np

from match_jax.envs.tasks import reports_authors_metrics
from match_jax.experiments import claims, plots
from match_jax.training.presets import get_preset
from match_jax.experiments.suite import HYBRID, PAPER_TABLE1, SUITE, SWEEP_MM, SuiteConfig, run_spec, unbreakable
from match_jax.training.runs import best_record, read_metrics


SWEEP_TITLES = {"shell": "the authors' spherical shells: radius U[previous level, level] in a random direction",
                "uniform": "uniform hole-position noise, +-level per axis"}


def sweep_type(results) -> str:
    """The noise sweep's type ('shell' or 'uniform') in evaluation grids: one grid, or a dict of them."""
    grids = results.values() if isinstance(results, dict) else [results]
    kinds = {r["noise_type"] for grid in grids for r in grid} - {"gaussian"}
    return kinds.pop() if len(kinds) == 1 else "uniform"


def _level_label(kind: str, level: float) -> str:
    if kind == "shell":
        inner = max([x for x in SWEEP_MM if x < level], default=0.0)
        return f"{inner:g}-{level:g} mm" if level > 0 else "0 mm"
    return f"+-{level:g} mm"


def _table1_row(grid: list[dict]) -> dict:
    """The evaluation at the training noise (gaussian) with the break force the run trained with."""
    gaussian = [r for r in grid if r["noise_type"] == "gaussian"]
    return next((r for r in gaussian if r["break_force_n"] is not None), gaussian[0])


def _fmt(row: dict, key: str, scale: float = 1.0, digits: int = 1) -> str:
    """mean +- 95 % interval half-width over the seeds of an evaluation row ('-' where missing)."""
    if key not in row["aggregate"]:  # an evaluation written before this column existed
        return "-"
    values = [s[key] for s in row["per_seed"] if s.get(key) is not None]
    mean = row["aggregate"][key]["mean"]
    if mean is None or math.isnan(mean):
        return "-"
    half = claims.ci95_halfwidth(values)
    return f"{scale * mean:.{digits}f}" + ("" if math.isnan(half) else f" +- {scale * half:.{digits}f}")


def _time_force_cells(row: dict) -> list[str]:
    """Time to success (s) and mean contact force (N) of an evaluation row, each as ours / the authors'."""
    return [f"{_fmt(row, ours, 1, 2)} / {_fmt(row, authors, 1, 2)}"
            for ours, authors in (("mean_time_to_success_s", "authors_time_to_success_s"),
                                  ("mean_force_n", "authors_mean_force_n"))]


def _row(grid: list[dict], noise_type: str, noise_mm: float | None, breakable: bool) -> dict | None:
    for r in grid:
        if r["noise_type"] == noise_type and (noise_mm is None or r["noise_mm"] == noise_mm) \
                and (r["break_force_n"] is not None) == breakable:
            return r
    return None


# Training metrics kept per seed and iteration for the report (NaN where a row does not have them).
CURVE_KEYS = ("success_rate", "break_rate", "episodes", "contact_fraction", "p_force_free_axis")


def metric_arrays(rows: list[dict], keys) -> dict[str, np.ndarray]:
    """Per-iteration metric rows (one per iteration and seed) as seeds x iterations arrays of `keys`
    (NaN where a row has None), plus 'env_steps': env steps per seed at each iteration."""
    seeds = sorted({int(r["seed_index"]) for r in rows})
    iterations = sorted({int(r["iteration"]) for r in rows})
    arrays = {key: np.full((len(seeds), len(iterations)), np.nan) for key in keys}
    steps = np.zeros(len(iterations))
    for r in rows:
        j = iterations.index(int(r["iteration"]))
        for key in keys:
            arrays[key][int(r["seed_index"]), j] = np.nan if r.get(key) is None else r[key]
        steps[j] = r["env_steps"]
    return {"env_steps": steps, **arrays}


def episode_window(spec) -> int:
    """Iterations that span one episode per env: the window training success is smoothed over."""
    return math.ceil(spec.env.episode_steps / spec.ppo.rollout_steps)


def learning_curves(cfg: SuiteConfig) -> dict[str, dict]:
    """Per run name: the CURVE_KEYS metrics (seeds x iterations), env steps per iteration, the smoothing
    window (iterations spanning one episode per env), the step budget and each seed's best checkpoint
    (env steps; None where its record does not say)."""
    curves = {}
    for name in cfg.only:
        rows = read_metrics(cfg.out / "runs" / name)
        if not rows:
            continue
        logged = metric_arrays(rows, CURVE_KEYS)
        spec = run_spec(name, cfg)
        best = [best_record(cfg.out / "runs" / name, i) or {} for i in range(logged["success_rate"].shape[0])]
        curves[name] = {**logged, "budget": spec.ppo.total_steps,
                        "window": episode_window(spec),
                        "best_env_steps": [b.get("env_steps") for b in best]}
    return curves


STEPS_TO = (0.5, 0.8, 0.9)


def steps_to(curve: dict, threshold: float) -> list[float]:
    """Per seed: env steps to `threshold` training success (smoothed over one episode per env); NaN if never."""
    return [claims.steps_to(curve["env_steps"], seed_rate, threshold, curve["window"])
            for seed_rate in curve["success_rate"]]


_CLAIM_METRICS = {"success": ("gaussian", None, True, "success_rate"), "break": ("gaussian", None, True, "break_rate"),
                  "force": ("gaussian", None, True, "mean_force_n"),
                  "force_contact": ("gaussian", None, True, "force_selected_contact_per_axis"),
                  "force_free": ("gaussian", None, True, "force_selected_free_per_axis"),
                  "success_1": ("sweep", 1.0, True, "success_rate"),
                  "success_7.5": ("sweep", 7.5, True, "success_rate"),
                  "break_1": ("sweep", 1.0, True, "break_rate"), "break_7.5": ("sweep", 7.5, True, "break_rate"),
                  "success_unbreakable_7.5": ("sweep", 7.5, False, "success_rate")}
_CLAIM_TRAINING = {"contact_training": "contact_fraction", "p_force_free_training": "p_force_free_axis"}
SHELLS_MM = tuple(x for x in SWEEP_MM if x > 0)


def pooled_profile(profile: dict) -> np.ndarray:
    """P(force) per phase (approach, contact, insertion) and axis from an evaluation's selection profile,
    pooled over its time bins (weighted by their steps); NaN for a phase without steps."""
    mean, count = np.asarray(profile["mean"], np.float64), np.asarray(profile["count"], np.float64)
    weights = count[..., None]
    total = weights.sum(axis=1)
    pooled = np.nansum(np.nan_to_num(mean) * weights, axis=1) / np.maximum(total, 1.0)
    return np.where(total > 0, pooled, np.nan)  # a phase no episode reached: NaN


def selection_figure_data(row: dict) -> dict:
    """An evaluation row's selection profile with its force selection on in-contact axis-steps (mean over
    seeds, pooled over axes and per axis; None where the row lacks it) as 'force_selected_contact'."""
    def mean(key):
        value = row["aggregate"].get(key, {}).get("mean")
        return None if value is None or math.isnan(value) else value

    keys = {"per_axis": "force_selected_contact_per_axis", **{a: f"force_selected_contact_{a}" for a in "xyz"}}
    return {**row["selection_profile"], "force_selected_contact": {k: mean(v) for k, v in keys.items()}}


def suite_claims(results: dict[str, list[dict]], curves: dict[str, dict], task: str = "authors") -> list[claims.Claim]:
    """The paper's qualitative claims on this suite's per-seed evaluations and learning curves of finished
    runs. Mean force is the authors' definition on their tasks (`tasks.reports_authors_metrics`), ours on the earlier
    variant."""
    def values(name, metric):
        if name not in results:
            return []
        if metric in _CLAIM_TRAINING:  # per seed, mean over the second half of training (after the start)
            if name not in curves:
                return []
            logged = curves[name][_CLAIM_TRAINING[metric]]
            return list(np.nanmean(logged[:, logged.shape[1] // 2:], axis=1))
        breakable = not unbreakable(name)
        if metric == "break_shells":
            rows = [_row(results[name], sweep_type(results[name]), x, breakable) for x in SHELLS_MM]
            if not breakable or any(r is None for r in rows):
                return []
            per_seed = [[np.nan if s.get("break_rate") is None else s["break_rate"] for s in r["per_seed"]]
                        for r in rows]
            if len({len(x) for x in per_seed}) != 1:
                return []
            return list(np.nanmean(np.array(per_seed, np.float64), axis=0))
        noise_type, noise_mm, breakable_metric, key = _CLAIM_METRICS[metric]
        if metric == "force" and reports_authors_metrics(task):
            key = "authors_mean_force_n"
        row = _table1_row(results[name]) if noise_type == "gaussian" else _row(
            results[name], sweep_type(results[name]), noise_mm, breakable_metric and breakable)
        return [] if row is None else [s.get(key) for s in row["per_seed"]]

    def steps(name, threshold):
        if name not in curves:
            return [], False
        trained = float(curves[name]["env_steps"][-1])  # a seed that never reached it: at least this many
        values = steps_to(curves[name], threshold)
        return [trained if math.isnan(x) else x for x in values], any(math.isnan(x) for x in values)

    def profile(name):
        row = _table1_row(results[name]) if name in results else {}
        return pooled_profile(row["selection_profile"]) if row.get("selection_profile") else None

    return claims.check_claims(values, steps, profile)


def _table1_lines(results: dict[str, list[dict]]) -> list[str]:
    """Table 1 analogue: the breakable runs at the training noise beside the paper's numbers, with both
    break checks and both definitions of time to success and mean force."""
    lines = [
        "## Table 1 analogue (mean +- 95 % interval over seeds; 10 N break)", "",
        "Break %: the run's own break check, which ended the episodes. Beside it, on the same episodes, the two "
        "checks: the peak contact force over a policy step's physics steps (peak) and the force signal read once at "
        "the end of each policy step (15 Hz, the authors'). Time and force: ours (time to success over successful "
        "episodes; mean contact force per episode) / the authors' (first success step at 15 Hz; end-of-step force "
        "signal pooled over every step with some axis in contact). The paper's columns were measured the authors' "
        "way.", "",
        "| method | success % | break % | break % peak / 15 Hz | time to success (s), ours / authors' "
        "| mean force (N), ours / authors' | paper success % | paper break % | paper time (s) | paper force (N) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    breakable = {n: g for n, g in results.items() if not unbreakable(n)}
    noise = {name: _table1_row(grid)["noise_mm"] for name, grid in breakable.items()}
    usual = max(set(noise.values()), key=list(noise.values()).count, default=None)
    others = [f"{SUITE[n].label} at {x:g} mm" for n, x in noise.items() if x != usual]
    if usual is not None:
        lines[2:2] = [f"Each run is evaluated at its training noise: gaussian hole-position noise of std {usual:g} mm"
                      + (f" ({', '.join(others)})" if others else "") + ".", ""]
    for name, grid in breakable.items():
        row = _table1_row(grid)
        paper = PAPER_TABLE1.get(name, ("-",) * 4)
        lines.append(f"| {SUITE[name].label} | {_fmt(row, 'success_rate', 100)} | {_fmt(row, 'break_rate', 100)} | "
                     f"{_fmt(row, 'break_rate_peak', 100)} / {_fmt(row, 'break_rate_policy_step', 100)} | "
                     + " | ".join(_time_force_cells(row)) + " | "
                     + " | ".join(str(x) for x in paper) + " |")
    return lines


def _noise_lines(results: dict[str, list[dict]]) -> list[str]:
    """Success / break % over the noise sweep, breakable and unbreakable, of the breakable runs."""
    breakable = {n: g for n, g in results.items() if not unbreakable(n)}
    kind = sweep_type(results)
    labels = [_level_label(kind, x) for x in SWEEP_MM]
    lines = ["", f"## Noise robustness ({SWEEP_TITLES[kind]}; success % / break %)", "",
              "| method | " + " | ".join(labels) + " | unbreakable: " + " | ".join(labels) + " |",
              "|---|" + "---|" * (2 * len(SWEEP_MM))]
    for name, grid in breakable.items():
        cells = [f"{_fmt(r, 'success_rate', 100)} / {_fmt(r, 'break_rate', 100)}"
                 for r in (_row(grid, kind, x, True) for x in SWEEP_MM) if r is not None]
        cells_unb = [_fmt(r, "success_rate", 100) for r in (_row(grid, kind, x, False) for x in SWEEP_MM)
                     if r is not None]
        lines.append(f"| {SUITE[name].label} | " + " | ".join(cells) + " | " + " | ".join(cells_unb) + " |")
    return lines


def _unbreakable_lines(results: dict[str, list[dict]]) -> list[str]:
    """Success % evaluated unbreakable over the noise sweep, every run (empty without unbreakable-trained runs)."""
    lines = []
    if any(unbreakable(n) for n in results):
        kind = sweep_type(results)
        lines += ["", f"## Unbreakable pegs (evaluated unbreakable; success % under {SWEEP_TITLES[kind]})", "",
                  "The last three columns: at the run's training noise (gaussian), as in Table 1 (time and force: "
                  "ours / the authors' definitions).", "",
                  "| method | trained | " + " | ".join(_level_label(kind, x) for x in SWEEP_MM)
                  + " | success % at training noise | time to success (s), ours / authors' "
                  "| mean force (N), ours / authors' |",
                  "|---|---|" + "---|" * (len(SWEEP_MM) + 3)]
        for name, grid in results.items():
            cells = [_fmt(r, "success_rate", 100) for r in (_row(grid, kind, x, False) for x in SWEEP_MM)
                     if r is not None]
            at_training = _row(grid, "gaussian", None, False)
            if at_training is not None:
                cells += [_fmt(at_training, "success_rate", 100)] + _time_force_cells(at_training)
            trained = "unbreakable" if unbreakable(name) else f"{SUITE[name].break_force:g} N"
            lines.append(f"| {SUITE[name].label} | {trained} | " + " | ".join(cells) + " |")
    return lines


def _selection_lines(results: dict[str, list[dict]]) -> list[str]:
    """Per-axis force selection in contact and in free space of the hybrid runs."""
    lines = ["", "## Force selection (hybrid methods, training noise, deterministic policy)", "",
              "Per axis: sum over axes i of [force selected on i and i in contact] / sum of [i in contact], pooled "
              "over steps and episodes (the paper's 84 %), with x, y, z apart. An axis is in contact when the peg's "
              "contact force along that world axis exceeds 1 N at the start of the step (the contact the action was "
              "chosen in; the selection loss's label). Free space: the same over axes not in contact. The last two "
              "columns are the older summary: P(force), mean over the 3 axes, on steps with / without any contact.", "",
              "| method | per axis, in contact % | x / y / z in contact % | per axis, free % | x / y / z free % "
              "| P(force) contact % | P(force) free % | paper (MATCH) |", "|---|---|---|---|---|---|---|---|"]
    for name, grid in results.items():
        if name in HYBRID:
            row = _table1_row(grid)
            xyz = {w: " / ".join(_fmt(row, f"force_selected_{w}_{a}", 100, 0) for a in "xyz")
                   for w in ("contact", "free")}
            lines.append(f"| {SUITE[name].label} | {_fmt(row, 'force_selected_contact_per_axis', 100)} "
                         f"| {xyz['contact']} "
                         f"| {_fmt(row, 'force_selected_free_per_axis', 100)} | {xyz['free']} "
                         f"| {_fmt(row, 'p_force_contact', 100)} | {_fmt(row, 'p_force_free', 100)} "
                         f"| {'84 +- 10.8 / 2.9 +- 2.1' if name == 'match' else ''} |")
    return lines


def _at_budget(curve: dict) -> bool:
    """Whether a run's training metrics reach its step budget."""
    return curve["env_steps"][-1] >= curve["budget"]


def _status_lines(cfg: SuiteConfig, results: dict[str, list[dict]], curves: dict[str, dict]) -> list[str]:
    """Which of the suite's runs this report covers (empty when every run is evaluated)."""
    pending = [n for n in cfg.only if n not in results]
    if not pending:
        return []
    training = [f"{SUITE[n].label} ({int(curves[n]['env_steps'][-1]):,} of {curves[n]['budget']:,} env steps per seed)"
                for n in pending if n in curves and not _at_budget(curves[n])]
    unevaluated = [SUITE[n].label for n in pending if n in curves and _at_budget(curves[n])]
    waiting = [SUITE[n].label for n in pending if n not in curves]
    return ["## Runs in this report", "",
            f"{len(results)} of {len(cfg.only)} runs are trained and evaluated"
            + (f": {', '.join(SUITE[n].label for n in results)}." if results else ".")
            + (f" Trained, not yet evaluated: {', '.join(unevaluated)}." if unevaluated else "")
            + (f" Training: {'; '.join(training)}." if training else "")
            + (f" Not started: {', '.join(waiting)}." if waiting else "")
            + " Runs not yet evaluated appear in the learning-speed and early-training tables only, marked (training) "
              "or (not evaluated), and no claim uses them. Running the suite's command again continues it.", ""]


def _label(name: str, results: dict[str, list[dict]], curves: dict[str, dict]) -> str:
    """A run's label in the learning table and curve, marked while it is not evaluated yet: (training) below
    its step budget, (not evaluated) at it."""
    if name in results:
        return SUITE[name].label
    return SUITE[name].label + (" (not evaluated)" if _at_budget(curves[name]) else " (training)")


def _learning_lines(curves: dict[str, dict], results: dict[str, list[dict]]) -> list[str]:
    """Env steps to 50 / 80 / 90 % training success, final and best success, per run; runs not in
    `results` are marked as still training."""
    lines = ["", "## Learning speed (training success, smoothed over one episode per env; mean +- 95 % interval "
              "over the seeds that reached it)", "",
              "Best checkpoints: where each seed's evaluated policy (highest training success of a chunk) was "
              "saved; one at the end of the budget means that seed was still improving when training stopped.", "",
              "| method | env steps per seed | " + " | ".join(f"steps to {100 * t:g} %" for t in STEPS_TO)
              + " | final success % | best success % | best checkpoints (env steps, per seed) |",
              "|---|---|" + "---|" * len(STEPS_TO) + "---|---|---|"]
    for name, c in curves.items():
        rate = c["success_rate"]
        cells = []
        for t in STEPS_TO:
            reached = [x for x in steps_to(c, t) if not math.isnan(x)]
            if not reached:
                cells.append(f"not reached (0/{len(rate)})")
                continue
            half = claims.ci95_halfwidth(reached)
            cells.append(f"{np.mean(reached) / 1e6:.2f}M" + ("" if math.isnan(half) else f" +- {half / 1e6:.2f}M")
                         + ("" if len(reached) == len(rate) else f" ({len(reached)}/{len(rate)} seeds)"))
        last = rate[:, -c["window"]:]
        tail = float(np.nanmean(last)) if np.isfinite(last).any() else float("nan")  # NaN: no episode ended yet
        best = float(np.nanmax(rate)) if np.isfinite(rate).any() else float("nan")
        kept = " / ".join("-" if x is None else f"{x / 1e6:.2f}M" if x >= 1e5 else f"{x:,}"
                          for x in c.get("best_env_steps", []))
        lines.append(f"| {_label(name, results, curves)} | {int(c['env_steps'][-1]):,} | " + " | ".join(cells)
                     + f" | {100 * tail:.1f} | {100 * best:.1f} | {kept} |")
    return lines


EARLY_STEPS = (250_000, 500_000, 1_000_000)  # env steps per seed at which the early-training table reads
EARLY_BREAK_STEPS = 100_000  # the first env steps per seed whose episodes' breaks it counts


def early_training(curve: dict) -> dict:
    """What a run met in its first env steps, mean over seeds: the fraction of episodes ending in its first
    EARLY_BREAK_STEPS that broke the peg; the fraction of env steps in contact and P(force) on free-space
    axes (training rollouts), averaged over the one-episode window ending at each of EARLY_STEPS (NaN
    past the steps trained); P(force) on free axes in the first iteration."""
    steps, window = curve["env_steps"], curve["window"]
    first = steps <= max(EARLY_BREAK_STEPS, steps[0])
    breaks = np.nansum(curve["break_rate"][:, first] * curve["episodes"][:, first], axis=1)
    episodes = np.nansum(curve["episodes"][:, first], axis=1)

    def at(key, n):
        if steps[-1] < n:
            return float("nan")
        j = int(np.searchsorted(steps, n, side="right"))  # iterations [j - window, j) end at or before n
        block = curve[key][:, max(j - window, 0):max(j, 1)]
        return float(np.nanmean(block)) if np.isfinite(block).any() else float("nan")

    per_seed = np.where(episodes > 0, breaks / np.where(episodes > 0, episodes, 1.0), np.nan)
    return {"break_rate": float(np.nanmean(per_seed)) if np.isfinite(per_seed).any() else float("nan"),
            "contact_fraction": [at("contact_fraction", n) for n in EARLY_STEPS],
            "p_force_free_start": float(np.nanmean(curve["p_force_free_axis"][:, 0]))
            if np.isfinite(curve["p_force_free_axis"][:, 0]).any() else float("nan"),
            "p_force_free": [at("p_force_free_axis", n) for n in EARLY_STEPS]}


def _early_lines(curves: dict[str, dict], results: dict[str, list[dict]]) -> list[str]:
    """The early-training table: breaks met at the start, and how soon each run reaches the block."""
    def pct(x):
        return "-" if math.isnan(x) else f"{100 * x:.1f}"

    marks = " / ".join(f"{n / 1e6:g}M" for n in EARLY_STEPS)
    lines = ["", "## Early training (training rollouts, mean over seeds)", "",
             f"Breaks: episodes that broke the peg among those ending in the first {EARLY_BREAK_STEPS:,} env steps "
             f"per seed. Contact and P(force) on free-space axes: averaged over the one-episode window ending at "
             f"{marks} env steps ('-': not trained that far).", "",
             f"| method | breaks %, first {EARLY_BREAK_STEPS / 1e6:g}M steps | env steps in contact % at {marks} "
             f"| P(force) on free axes %, first iteration | P(force) on free axes % at {marks} |",
             "|---|---|---|---|---|"]
    for name, c in curves.items():
        e = early_training(c)
        lines.append(f"| {_label(name, results, curves)} | {pct(e['break_rate'])} | "
                     + " / ".join(pct(x) for x in e["contact_fraction"]) + f" | {pct(e['p_force_free_start'])} | "
                     + ("-" if math.isnan(e["p_force_free_start"]) else " / ".join(pct(x) for x in e["p_force_free"]))
                     + " |")
    return lines


def _claims_lines(results: dict[str, list[dict]], curves: dict[str, dict], task: str) -> list[str]:
    """The paper's claims with their verdicts at this suite's seeds."""
    lines = ["", "## The paper's claims at this suite's seeds", "",
              "A claim holds when the 95 % interval (Welch) of the difference of the seeds' means lies on its side "
              "of 0, does not hold when it lies on the other side, and is inconclusive otherwise; 'as fast as' "
              f"holds when not significantly slower and within {100 * claims.AS_FAST_MARGIN:g} % in mean. A seed "
              "that never reached the threshold counts at the env steps it trained (shown as >=): a lower bound, so "
              "a verdict it could overturn reads inconclusive. 'Alike' (the paper's 'no significant difference') "
              "holds when the interval contains 0. The selection-profile claims compare MATCH's phase means pooled "
              "over seeds (no interval); 'the shells': the mean of the four shells' break rates per seed. Mean "
              "force: "
              + ("the authors' definition (end-of-step force signal pooled over every step with some axis in "
                 "contact)." if reports_authors_metrics(task) else "ours (mean contact force per episode)."), "",
              "| claim | verdict | ours |", "|---|---|---|"]
    lines += [f"| {c.text} | {c.verdict} | {c.numbers} |" for c in suite_claims(results, curves, task)]
    return lines


def write_report(cfg: SuiteConfig, results: dict[str, list[dict]], command: str) -> pathlib.Path:
    """OUT/REPORT.md and its three figures from the evaluated runs `results` and every run's training metrics."""
    out = cfg.out
    curves = learning_curves(cfg)
    plots.learning_curves({_label(n, results, curves): c for n, c in curves.items()}, out / "learning_curves.png",
                          smooth=1 if cfg.smoke else 5)
    kind = sweep_type(results)
    sweeps = {SUITE[n].label: [r for r in g if r["noise_type"] == kind] for n, g in results.items()}
    plots.noise_robustness(sweeps, out / "noise_robustness.png")
    plots.unbreakable_robustness(sweeps, out / "unbreakable_robustness.png")
    profiles = {SUITE[n].label: selection_figure_data(_table1_row(g)) for n, g in results.items() if n in HYBRID}
    stale_profile = out / "selection_profile.png"
    if profiles:
        plots.selection_profile(profiles, stale_profile)
    elif stale_profile.exists():
        stale_profile.unlink()  # no hybrid run evaluated: an earlier figure would describe other runs

    preset = get_preset(cfg.preset)
    lines = [
        "# match_jax experiment report", "",
        f"Command: `{command}`", "",
        f"Preset `{cfg.preset}`: {preset.num_envs} envs per seed, {cfg.total_steps or preset.total_steps:,} env steps "
        f"per seed, {cfg.seeds} seeds per method. Evaluation: best checkpoint per seed (highest training success "
        f"rate), deterministic policy, {cfg.episodes_per_seed} episodes per seed at the training "
        f"noise (gaussian) and at each level of the noise sweep ({SWEEP_TITLES[kind]}). MATCH's selection term is "
        + ("in the PPO ratio (paper's equation)." if cfg.selection_in_ratio else
           "left out of the PPO ratio (authors' code; selection trained by the SSL only); MATCH (no SSL) keeps it "
           "in the ratio, its selection's only training signal.")
        + (" **Smoke run: tiny sizes, the numbers mean nothing.**" if cfg.smoke else ""), "",
    ]
    lines += _status_lines(cfg, results, curves)
    lines += _table1_lines(results) + _noise_lines(results) + _unbreakable_lines(results) + _selection_lines(results)
    # Learning-speed claims compare finished runs only: a run still training has not had its budget.
    finished = {n: c for n, c in curves.items() if n in results}
    lines += _learning_lines(curves, results) + _early_lines(curves, results)
    lines += _claims_lines(results, finished, cfg.task)
    lines += ["", "## Figures", "",
              "- `learning_curves.png`: training success vs env steps, mean and 95% CI over seeds",
              "- `noise_robustness.png`: success (top) and break rate (bottom) vs the noise sweep's level, breakable "
              "peg; mean and 95 % interval over seeds (clipped to 0-100 %)",
              "- `unbreakable_robustness.png`: success vs the noise sweep's level, unbreakable peg (runs trained "
              "unbreakable dashed); mean and 95 % interval over seeds (clipped to 0-100 %)"]
    if profiles:
        lines += ["- `selection_profile.png`: per hybrid run, the mean probability of force control per axis over "
                  "all steps of approach / contact / insertion (time-normalised), titled with its force selection "
                  "on in-contact axis-steps (the per-axis in-contact column above)"]
    lines += [""]
    path = out / "REPORT.md"
    path.write_text("\n".join(lines))
    return path
