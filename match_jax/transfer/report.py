"""The stand-in protocol's report: per method, its best seed's success, breaks, mean and max force and
energy on the MuJoCo C stand-in at each noise level, beside the same policy in the training simulator
(the transfer gap) and the paper's real-robot numbers; the figure; the paper's real-robot claims.

    python -m match_jax.transfer.report STANDIN.json --sim pose=POSE_EVAL.json,match=MATCH_EVAL.json --out DIR
    python -m match_jax.transfer.report STANDIN.json --sim match=SWEEP.json,match=NOISELESS.json --out DIR

STANDIN.json is written by `benchmarks/standin_protocol.py` (noiseless trials of every seed, then the best
seed on the noise shells). Each EVAL.json is the training simulator's evaluation of the same run (eval.py
`--json` with `--noise-sweep 0,1,2.5,5,7.5`, or a suite's eval file): its row for the stand-in's best seed
at each level is the sim column. Writes DIR/TRANSFER.md and DIR/transfer.png.

Verdicts compare trials (per-trial 0/1 outcomes or per-trial forces) with the 95 % Welch interval of the
difference of means, as the suite's claims compare seeds: "a below b" holds when the interval lies below 0,
does not hold when above, and is inconclusive otherwise. "About as often" holds when the interval lies
within +-`EQUIVALENCE_MARGIN`, does not hold when it excludes 0. "At most the margin below" (transfer
without noise) holds when the interval lies above -`EQUIVALENCE_MARGIN`, does not hold when below it.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
from typing import NamedTuple

import numpy as np

from match_jax.experiments import claims
from match_jax.transfer.standin import StandInConfig

LABELS = {"pose": "Pose", "vices": "VICES", "hybrid": "Hybrid-Basic", "match": "MATCH"}
# The paper's real-robot success at the 7.5 mm level, the two numbers its text gives (its figure has the rest).
PAPER_REAL_ROBOT_SUCCESS_7_5 = {"match": 0.68, "pose": 0.33}
EQUIVALENCE_MARGIN = 0.15  # "about as often": the difference's 95 % interval within +-15 points
HIGH_NOISE_MM = 7.5
STANDIN_BREAK_N = StandInConfig().break_force  # the protocol runs the stand-in's default break


class Level(NamedTuple):
    """One noise level of a method's protocol: the seed run there (its policy file's stem), the stand-in's
    summary (`standin.summarize`) and its trials (empty in a file written before trials were kept)."""
    level_mm: float
    seed: str
    summary: dict
    trials: list


def protocol_levels(entry: dict) -> list[Level]:
    """A method's protocol entry as levels: 0 mm (its best seed's noiseless trials), then each shell."""
    best = entry["best_seed"]
    noiseless = entry["noiseless"][best]
    levels = [Level(0.0, best, noiseless, noiseless.get("trial_rows", []))]
    for key in sorted(entry["shells"], key=float):
        shell = entry["shells"][key]
        levels.append(Level(float(key), best, shell, shell.get("trial_rows", [])))
    return levels


def seed_index(seed: str) -> int:
    """'policy_seed2' -> 2."""
    if not seed.startswith("policy_seed") or not seed[len("policy_seed"):].isdigit():
        raise ValueError(f"expected a policy file stem 'policy_seed<i>', got {seed!r}")
    return int(seed[len("policy_seed"):])


def sim_rows(doc) -> list[dict]:
    """The evaluation rows of an eval.py JSON (one row, or {'noise_sweep': rows}) or of a suite eval file (rows)."""
    if isinstance(doc, dict):
        return list(doc["noise_sweep"]) if "noise_sweep" in doc else [doc]
    return list(doc)


def sim_at(rows: list[dict], level_mm: float, seed: int) -> dict | None:
    """The training simulator's per-seed result of seed index `seed` at `level_mm` with the peg breakable:
    at 0 mm any noise type, otherwise a shell; None if it was not evaluated."""
    for row in rows:
        breakable = row.get("break_force_n") is not None
        kind_ok = level_mm == 0.0 or row.get("noise_type") == "shell"
        if breakable and kind_ok and math.isclose(row["noise_mm"], level_mm) and seed < len(row["per_seed"]):
            return row["per_seed"][seed]
    return None


def _outcomes(rate: float, n: int) -> np.ndarray:
    """0/1 outcomes with `rate` of n ones (a summary's rate back to trials)."""
    k = int(round(rate * n))
    return np.concatenate([np.ones(k), np.zeros(n - k)])


def standin_outcomes(level: Level, key: str) -> np.ndarray:
    """Per-trial 0/1 of 'success' or 'broken' on the stand-in at one level."""
    return _outcomes(level.summary[f"{key}_rate"], level.summary["trials"])


def standin_values(levels: list[Level], key: str) -> np.ndarray:
    """Per-trial values of a trial metric ('mean_force_n', 'max_force_n', ...) pooled over levels."""
    return np.asarray([t[key] for lv in levels for t in lv.trials if t.get(key) is not None], np.float64)


def _level(levels: list[Level], level_mm: float) -> Level | None:
    return next((lv for lv in levels if math.isclose(lv.level_mm, level_mm)), None)


def _pct(x) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.0f} %"


def _rate_ci(summary: dict, key: str) -> str:
    lo, hi = (max(0.0, x) for x in summary[f"{key}_rate_ci95"])  # Wilson's 0 can round to -0
    return f"{100 * summary[f'{key}_rate']:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}]"


def _mean_ci(summary: dict, key: str, digits: int = 2) -> str:
    m = summary[key]
    if m["n"] == 0 or math.isnan(m["mean"]):
        return "-"
    lo, hi = m["ci95"]
    return f"{m['mean']:.{digits}f}" + ("" if math.isnan(lo) else f" +- {0.5 * (hi - lo):.{digits}f}")


def transfer_claims(protocol: dict[str, list[Level]], sims: dict[str, list[dict]]) -> list[claims.Claim]:
    """The paper's real-robot claims on the stand-in. Success comparisons at 7.5 mm, force and break
    comparisons over all of a best seed's protocol trials, transfer at low noise against the training
    simulator's success of the same seed without noise."""
    out = []

    def at(method, level_mm, key):
        lv = _level(protocol.get(method, []), level_mm)
        return np.zeros(0) if lv is None else standin_outcomes(lv, key)

    def pooled(method, key):
        if key in ("success", "broken"):
            return np.concatenate([standin_outcomes(lv, key) for lv in protocol.get(method, [])] or [np.zeros(0)])
        return standin_values(protocol.get(method, []), key)

    def lower(text, a, b, fmt=lambda x: _pct(claims._mean(x))):
        """a below b; the numbers read 'a vs b'."""
        out.append(claims.Claim(text, claims.verdict_lower(a, b), f"{fmt(a)} vs {fmt(b)}"))

    def higher(text, a, b):
        """a above b; the numbers read 'a vs b'."""
        out.append(claims.Claim(text, claims.verdict_lower(b, a),
                                f"{_pct(claims._mean(a))} vs {_pct(claims._mean(b))}"))

    def about(text, a, b):
        diff, lo, hi = claims.difference_ci(a, b)
        verdict = (claims.MISSING if math.isnan(diff) else claims.FAILS if lo > 0 or hi < 0 else
                   claims.HOLDS if -EQUIVALENCE_MARGIN <= lo and hi <= EQUIVALENCE_MARGIN else claims.INCONCLUSIVE)
        out.append(claims.Claim(text, verdict, f"{_pct(claims._mean(a))} vs {_pct(claims._mean(b))}"))

    def not_below(text, a, b):
        diff, lo, hi = claims.difference_ci(a, b)
        verdict = (claims.MISSING if math.isnan(diff) else claims.HOLDS if lo > -EQUIVALENCE_MARGIN else
                   claims.FAILS if hi < -EQUIVALENCE_MARGIN else claims.INCONCLUSIVE)
        out.append(claims.Claim(text, verdict, f"{_pct(claims._mean(a))} vs {_pct(claims._mean(b))}"))

    high = f"{HIGH_NOISE_MM:g} mm"
    higher(f"MATCH succeeds more often than Pose at {high} (robot: 68 vs 33 %)",
           at("match", HIGH_NOISE_MM, "success"), at("pose", HIGH_NOISE_MM, "success"))
    higher(f"MATCH succeeds more often than Hybrid-Basic at {high}",
           at("match", HIGH_NOISE_MM, "success"), at("hybrid", HIGH_NOISE_MM, "success"))
    about(f"MATCH succeeds about as often as VICES at {high} (within {100 * EQUIVALENCE_MARGIN:g} points)",
          at("match", HIGH_NOISE_MM, "success"), at("vices", HIGH_NOISE_MM, "success"))
    newton = lambda x: "-" if not len(claims._finite(x)) else f"{claims._mean(x):.2f} N"  # noqa: E731
    lower("MATCH applies less mean contact force than VICES (robot: up to ~30 % less)",
          pooled("match", "mean_force_n"), pooled("vices", "mean_force_n"), newton)
    lower("MATCH breaks the peg less often than Pose (robot: Pose's 1 break in 100 trials was the only one)",
          pooled("match", "broken"), pooled("pose", "broken"))
    for other in ("match", "hybrid", "pose"):
        lower(f"{LABELS[other]} reaches a lower max force than VICES",
              pooled(other, "max_force_n"), pooled("vices", "max_force_n"), newton)
    for method in protocol:
        lv = _level(protocol[method], 0.0)
        sim = sim_at(sims.get(method, []), 0.0, seed_index(lv.seed)) if lv else None
        sim_success = np.zeros(0) if sim is None else _outcomes(sim["success_rate"], sim["episodes"])
        not_below(f"{LABELS.get(method, method)} transfers without noise: stand-in success at most "
                  f"{100 * EQUIVALENCE_MARGIN:g} points below the training simulator's",
                  at(method, 0.0, "success"), sim_success)
    return out


def table_lines(method: str, levels: list[Level], sim: list[dict], deployment: str = "deterministic") -> list[str]:
    """One method's table: stand-in and training simulator per level; `deployment` of the stand-in's policy.
    For hybrid policies whose trials counted it, a last column: the share of in-contact axis-steps on force
    control, stand-in / training simulator (whole episodes, per axis)."""
    selection = any("selection" in lv.summary for lv in levels)
    lines = [f"### {LABELS.get(method, method)} ({levels[0].seed}, the best of the noiseless trials; "
             f"{deployment} on the stand-in)", "",
             "| noise (mm) | trials | success [95 %] | breaks | mean force (N) | max force (N) | energy (J) "
             "| sim success | sim breaks | sim mean force (N) | gap (points) |"
             + (" force control in contact, stand-in / sim |" if selection else ""),
             "|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if selection else "")]
    for lv in levels:
        s = lv.summary
        row = sim_at(sim, lv.level_mm, seed_index(lv.seed))
        gap = "-" if row is None else f"{100 * (s['success_rate'] - row['success_rate']):+.0f}"
        sim_cells = ("-", "-", "-") if row is None else (
            _pct(row["success_rate"]), _pct(row["break_rate"]), f"{row['authors_mean_force_n']:.2f}")
        lines.append(f"| {lv.level_mm:g} | {s['trials']} | {_rate_ci(s, 'success')} | {_rate_ci(s, 'broken')} | "
                     f"{_mean_ci(s, 'mean_force_n')} | {_mean_ci(s, 'max_force_n')} | {_mean_ci(s, 'energy_j')} | "
                     + " | ".join(sim_cells) + f" | {gap} |"
                     + (f" {_selection_cell(s, row)} |" if selection else ""))
    return lines


def _selection_cell(summary: dict, sim_row: dict | None) -> str:
    """'stand-in % (hits / axis-steps) / sim %' of in-contact axis-steps on force control."""
    def pct(x):
        return "-" if x is None or math.isnan(x) else f"{100 * x:.1f} %"

    counts = summary.get("selection")
    ours = "-" if counts is None else (
        f"{pct(counts['force_selected_contact_per_axis'])} "
        f"({counts['force_selected_contact_axis_steps']} / {counts['contact_axis_steps']})")
    sim = "-" if sim_row is None else pct(sim_row.get("force_selected_contact_per_axis"))
    return f"{ours} / {sim}"


def plot(protocol: dict[str, list[Level]], sims: dict[str, list[dict]], path: pathlib.Path) -> None:
    """Success, mean force and max force against noise per method (95 % intervals), the stand-in solid,
    the training simulator dashed, the paper's real-robot success at 7.5 mm as stars."""
    from match_jax.experiments.plots import line_styles, plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    styles = line_styles([LABELS.get(m, m) for m in protocol])
    for method, levels in protocol.items():
        style = styles[LABELS.get(method, method)]
        x = np.asarray([lv.level_mm for lv in levels])
        rate = np.asarray([lv.summary["success_rate"] for lv in levels])
        ci = np.asarray([lv.summary["success_rate_ci95"] for lv in levels]).T
        axes[0].errorbar(x, 100 * rate, yerr=100 * np.abs(ci - rate), marker="o", capsize=3,
                         label=f"{LABELS.get(method, method)}, stand-in", **style)
        for ax, key in ((axes[1], "mean_force_n"), (axes[2], "max_force_n")):
            mean = np.asarray([lv.summary[key]["mean"] for lv in levels])
            half = np.asarray([0.5 * (lv.summary[key]["ci95"][1] - lv.summary[key]["ci95"][0]) for lv in levels])
            ax.errorbar(x, mean, yerr=np.nan_to_num(half), marker="o", capsize=3, **style)
        rows = [sim_at(sims.get(method, []), lv.level_mm, seed_index(lv.seed)) for lv in levels]
        have = [i for i, r in enumerate(rows) if r is not None]
        if have:
            sim_style = {**style, "linestyle": ":"}
            axes[0].plot(x[have], [100 * rows[i]["success_rate"] for i in have], marker="s", fillstyle="none",
                         label=f"{LABELS.get(method, method)}, training sim", **sim_style)
            axes[1].plot(x[have], [rows[i]["authors_mean_force_n"] for i in have], marker="s", fillstyle="none",
                         **sim_style)
        if method in PAPER_REAL_ROBOT_SUCCESS_7_5:
            axes[0].plot([HIGH_NOISE_MM], [100 * PAPER_REAL_ROBOT_SUCCESS_7_5[method]], marker="*", markersize=14,
                         linestyle="none", color=style["color"], label=f"{LABELS[method]}, paper's robot")
    for ax, ylabel in zip(axes, ("success (%)", "mean contact force (N)",
                                    f"max force (N; dashed: the {STANDIN_BREAK_N:g} N break)")):
        ax.set_xlabel("hole-position noise (mm; 0 = noiseless, then shells)")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[0].set_ylim(-2, 102)
    axes[2].axhline(STANDIN_BREAK_N, color="k", linewidth=0.8, linestyle="--")
    fig.legend(*axes[0].get_legend_handles_labels(), fontsize=8, loc="upper center", ncol=4,
               bbox_to_anchor=(0.5, 0.0))
    fig.suptitle("Stand-in (solid, 95 % intervals over trials) vs training simulator (dotted), best seed per method")
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")  # the legend sits below the axes
    plt.close(fig)


def write_report(standin: dict, sims: dict[str, list[dict]], out: pathlib.Path, command: str) -> pathlib.Path:
    """OUT/TRANSFER.md and OUT/transfer.png from a protocol file's content and the sim evaluation rows."""
    protocol = {m: protocol_levels(e) for m, e in standin.items() if m != "config" and e.get("best_seed")}
    if not protocol:
        raise ValueError("the protocol file holds no method with a best seed (noiseless trials not run)")
    out.mkdir(parents=True, exist_ok=True)
    plot(protocol, sims, out / "transfer.png")
    perturbed = not standin.get("config", {}).get("no_perturbation", False)
    lines = ["# Sim-to-sim transfer: the real-robot protocol on the MuJoCo C stand-in", "",
             f"Generated by `{command}`.", "",
             f"Stand-in {'with its perturbations' if perturbed else 'without perturbations'}; the peg breaks at "
             f"{STANDIN_BREAK_N:g} N "
             "of the filtered force estimate. Per method, the seed with the most noiseless successes is run on the "
             "noise shells. Stochastic: the policy samples its action with the std scaled as exported (the paper's "
             "robot ran Pose and Hybrid-Basic at 5 %); the training simulator's columns are deterministic. "
             "Intervals: Wilson for rates, normal for means over trials. Sim columns: the same seed "
             "in the training simulator (breaks at 10 N on the wrist sensor; mean force: the authors' definition); "
             "gap: stand-in minus sim success.", "", "![transfer](transfer.png)", ""]
    for method, levels in protocol.items():
        deployment = standin[method].get("deployment", "deterministic")
        lines += table_lines(method, levels, sims.get(method, []), deployment) + [""]
    lines += ["## The paper's real-robot claims on the stand-in", "",
              "Verdicts: the 95 % Welch interval of the difference of per-trial means (see "
              "`match_jax.transfer.report`). A method that was not run reads 'not run'.", "",
              "| claim | verdict | ours |", "|---|---|---|"]
    lines += [f"| {c.text} | {c.verdict} | {c.numbers} |" for c in transfer_claims(protocol, sims)]
    path = out / "TRANSFER.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def _sims(text: str) -> dict[str, list[pathlib.Path]]:
    out = {}
    for item in filter(None, text.split(",")):
        name, _, path = item.partition("=")
        if not name or not path:
            raise argparse.ArgumentTypeError(f"expected METHOD=EVAL.json[,...], got {item!r}")
        out.setdefault(name, []).append(pathlib.Path(path).expanduser())
    return out


def main(argv=None) -> int:
    import json

    parser = argparse.ArgumentParser(prog="python -m match_jax.transfer.report", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("standin", type=pathlib.Path, help="the protocol's JSON (benchmarks/standin_protocol.py)")
    parser.add_argument("--sim", type=_sims, default={}, metavar="METHOD=EVAL.json,...",
                        help="training-simulator evaluations of the same runs (a method named twice: both files)")
    parser.add_argument("--out", type=pathlib.Path, required=True)
    args = parser.parse_args(argv)
    for path in [args.standin, *(p for paths in args.sim.values() for p in paths)]:
        if not path.is_file():
            parser.error(f"no such file: {path}")
    sims = {m: [row for p in paths for row in sim_rows(json.loads(p.read_text()))] for m, paths in args.sim.items()}
    try:
        path = write_report(json.loads(args.standin.read_text()), sims, args.out,
                            "python -m match_jax.transfer.report " + " ".join(sys.argv[1:] if argv is None else argv))
    except ValueError as err:
        parser.error(str(err))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
