"""Matplotlib figures of the paper's experiments (PNG files; the Agg backend, no display needed).

- learning curves: training success rate vs env steps per method, mean and 95 % CI over seeds;
- success and breaks: training success and break rate vs env steps per run, side by side;
- noise robustness: success and break rate vs hole-observation noise (breakable), and success with an
  unbreakable peg;
- selection profile: the policy's probability of force control per axis over the phase-normalised
  episode, one panel per run in a grid, each titled with the run's force selection on in-contact axes.

Intervals over seeds are Student-t 95 % intervals of the seeds' mean; for a rate they are clipped to
[0, 100] % (`clip_interval`), the range a rate can take.
"""

from __future__ import annotations

import math
import pathlib
import re
import textwrap
import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import FuncFormatter  # noqa: E402

from match_jax.training.analysis import PHASES  # noqa: E402

DODGE_MM = 0.08  # x offset between runs' points in the noise figures (mm)
T_975 = {1: 12.71, 2: 4.30, 3: 3.18, 4: 2.78, 5: 2.57, 6: 2.45, 7: 2.36, 8: 2.31, 9: 2.26}  # t quantiles, df
PROFILE_COLUMNS = 2  # selection-profile panels per row
INTERVAL_NOTE = "bars: 95 % t-interval over seeds, clipped to [0, 100] %"


def mean_and_ci95(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and half-width of the 95 % t-interval over axis 0 (NaN-aware; 0 width for one seed)."""
    values = np.asarray(values, np.float64)
    n = np.sum(~np.isnan(values), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns (no episode ended) stay NaN
        mean = np.nanmean(values, axis=0)
        sd = np.nanstd(values, axis=0, ddof=1) if values.shape[0] > 1 else np.zeros_like(mean)
        t = np.array([T_975.get(int(k) - 1, 1.96) if k > 1 else 0.0 for k in np.ravel(n)]).reshape(np.shape(n))
        half = np.where(n > 1, t * sd / np.sqrt(np.maximum(n, 1)), 0.0)
    return mean, half


def clip_interval(mean, half, low: float = 0.0, high: float = 100.0) -> np.ndarray:
    """Error-bar lengths (2, N) below and above `mean` of the interval mean +- half clipped to [low, high]
    (a rate's interval never leaves 0-100 %): matplotlib's asymmetric `yerr`. Lengths are >= 0; NaN where
    mean or half is NaN."""
    mean, half = np.broadcast_arrays(np.asarray(mean, np.float64), np.asarray(half, np.float64))
    with np.errstate(invalid="ignore"):
        below = mean - np.clip(mean - half, low, high)
        above = np.clip(mean + half, low, high) - mean
        return np.stack([np.maximum(below, 0.0), np.maximum(above, 0.0)]) + 0.0 * (mean + half)


def line_styles(names) -> dict[str, dict]:
    """Matplotlib color and line style per curve name: distinct colors per method, and a run trained
    unbreakable dashed in its method's color (names compared without '(unbreakable)', '(training)' and
    '(not evaluated)')."""
    palette = plt.get_cmap("tab10").colors + plt.get_cmap("Dark2").colors
    styles, colors = {}, {}
    for name in names:
        method = re.sub(r" \((unbreakable|training|not evaluated)\)", "", name)
        color = colors.setdefault(method, palette[len(colors) % len(palette)])
        styles[name] = {"color": color, "linestyle": "--" if "(unbreakable)" in name else "-"}
    return styles


def _millions(x, _pos) -> str:
    return f"{x / 1e6:g}M" if x else "0"


def _mean_with_band(ax, steps, rates: np.ndarray, label: str | None, style: dict) -> None:
    """The seeds' mean rate (rates: (seeds, I) in [0, 1]) in %, with its clipped 95 % t-interval as a band."""
    mean, half = mean_and_ci95(rates)
    ax.plot(steps, 100 * mean, label=label, **style)
    below, above = clip_interval(100 * mean, 100 * half)
    ax.fill_between(steps, 100 * mean - below, 100 * mean + above, alpha=0.12, color=style["color"])


def _rate_axes(ax, ylabel: str) -> None:
    """A rate (%) panel over env steps per seed."""
    ax.set_xlabel("env steps per seed")
    ax.xaxis.set_major_formatter(FuncFormatter(_millions))
    ax.set_ylabel(ylabel)
    ax.set_ylim(-2, 102)
    ax.grid(alpha=0.3)


def learning_curves(curves: dict[str, dict], path: str | pathlib.Path, smooth: int = 5) -> None:
    """curves: name -> {'env_steps': (I,), 'success_rate': (seeds, I)}; moving average over `smooth`."""
    fig, ax = plt.subplots(figsize=(10, 4.2))
    styles = line_styles(curves)
    for name, c in curves.items():
        rates = np.asarray(c["success_rate"], np.float64)
        if smooth > 1 and rates.shape[1] >= smooth:
            kernel = np.ones(smooth) / smooth
            rates = np.stack([np.convolve(np.nan_to_num(r), kernel, mode="valid") for r in rates])
            steps = np.asarray(c["env_steps"])[smooth - 1:]
        else:
            steps = np.asarray(c["env_steps"])
        _mean_with_band(ax, steps, rates, f"{name} ({rates.shape[0]} seeds)", styles[name])
    _rate_axes(ax, "training success rate (%)")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), handlelength=3)
    ax.set_title("Learning curves (mean over seeds, band: 95 % t-interval clipped to [0, 100] %)")
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")  # the legend sits right of the axes
    plt.close(fig)


def success_and_breaks_figure(curves: dict[str, dict]):
    """Two panels over env steps per seed: training success and episodes broken (%), one line per run.

    curves: name -> {'env_steps': (I,), 'success_rate': (seeds, I), 'break_rate': (seeds, I)}, rates in
    [0, 1] already smoothed (NaN where not yet defined); drawn as the mean over seeds with a 95 % band.
    """
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.2), sharex=True)
    styles = line_styles(curves)
    for name, c in curves.items():
        steps = np.asarray(c["env_steps"])
        for ax, key in zip(axes, ("success_rate", "break_rate")):
            rates = np.asarray(c[key], np.float64)
            label = f"{name} ({rates.shape[0]} seeds)" if ax is axes[1] else None
            _mean_with_band(ax, steps, rates, label, styles[name])
    for ax, title in zip(axes, ("training success (%)", "episodes broken (%)")):
        _rate_axes(ax, title)
    axes[1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), handlelength=3)
    fig.suptitle("Training success and breaks, mean over seeds (band: 95 % t-interval clipped to [0, 100] %)")
    fig.tight_layout()
    return fig


def success_and_breaks(curves: dict[str, dict], path: str | pathlib.Path) -> None:
    """`success_and_breaks_figure` written to a PNG file."""
    fig = success_and_breaks_figure(curves)
    fig.savefig(path, dpi=120, bbox_inches="tight")  # the legend sits right of the axes
    plt.close(fig)


def _seeds(sweeps: dict[str, list[dict]]) -> str:
    """'3 seeds' (or '2-3 seeds') over every evaluation of the sweeps."""
    counts = sorted({len(r["per_seed"]) for results in sweeps.values() for r in results})
    if not counts:
        return "seeds"
    return f"{counts[0]}{'' if len(counts) == 1 else f'-{counts[-1]}'} seed{'' if counts == [1] else 's'}"


def _sweep_lines(ax, sweeps: dict[str, list[dict]], column: str, unbreakable: bool, styles: dict) -> None:
    """One panel: `column` (%) vs the sweep's level for every run's evaluations with (unbreakable=False) or
    without a break force; mean over the seeds' values and their 95 % t-interval clipped to [0, 100] %,
    runs dodged along x so their intervals stay apart, runs trained unbreakable dashed with open square
    markers. The y axis spans 0-100 %, or 0 to just above the highest interval when under 50 %."""
    top = 0.0
    plotted = {name: sorted((r for r in results if (r["break_force_n"] is None) == unbreakable),
                            key=lambda r: r["noise_mm"]) for name, results in sweeps.items()}
    plotted = {name: rows for name, rows in plotted.items() if rows}
    for i, (name, rows) in enumerate(plotted.items()):
        per_seed = np.array([[np.nan if s.get(column) is None else s[column] for s in r["per_seed"]] for r in rows]).T
        mean, half = mean_and_ci95(100 * per_seed)
        yerr = clip_interval(mean, half)
        dodge = DODGE_MM * (i - (len(plotted) - 1) / 2)
        dashed = styles[name]["linestyle"] == "--"
        ax.errorbar([r["noise_mm"] + dodge for r in rows], mean, yerr=yerr, marker="s" if dashed else "o",
                    markerfacecolor="white" if dashed else styles[name]["color"], markersize=5, capsize=3,
                    elinewidth=1.0, label=name, **styles[name])
        top = max(top, float(np.nanmax(mean + yerr[1], initial=0.0)))
    shell = any(r["noise_type"] == "shell" for results in sweeps.values() for r in results)
    ax.set_xlabel("hole-position error, shell outer radius (mm)" if shell else "hole-position noise, uniform +- (mm)")
    ax.set_ylim(-1, 101 if top >= 50 else max(10.0, 1.1 * top))
    ax.grid(alpha=0.3)


def _legend_right(ax) -> None:
    """The legend right of the axes (never over the data), long handles so dashed lines show as dashed."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), handlelength=3.2, borderaxespad=0.0)


def noise_robustness_figure(sweeps: dict[str, list[dict]]):
    """The figure of `noise_robustness` (open; the caller saves and closes it)."""
    fig, axes = plt.subplots(2, 1, figsize=(9.5, 7), sharex=True)
    styles = line_styles(sweeps)
    for ax, (column, ylabel) in zip(axes, (("success_rate", "success rate (%)"), ("break_rate", "break rate (%)"))):
        _sweep_lines(ax, sweeps, column, False, styles)
        ax.set_ylabel(ylabel)
    axes[0].set_xlabel("")
    axes[0].set_title(f"Breakable peg (10 N): mean over {_seeds(sweeps)}; {INTERVAL_NOTE}", fontsize=10)
    _legend_right(axes[0])
    fig.tight_layout()
    return fig


def noise_robustness(sweeps: dict[str, list[dict]], path: str | pathlib.Path) -> None:
    """The paper's noise figure: success (top) and break rate (bottom) vs the noise sweep's level, evaluated
    with the break force, mean and 95 % t-interval over seeds clipped to [0, 100] %. sweeps: name -> eval
    results (noise_mm, break_force_n, per_seed) from evaluate_run_grid."""
    fig = noise_robustness_figure(sweeps)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def unbreakable_robustness_figure(sweeps: dict[str, list[dict]]):
    """The figure of `unbreakable_robustness` (open; the caller saves and closes it)."""
    fig, ax = plt.subplots(figsize=(9.5, 4.6))
    _sweep_lines(ax, sweeps, "success_rate", True, line_styles(sweeps))
    ax.set_ylabel("success rate, unbreakable peg (%)")
    ax.set_title(f"Unbreakable peg: mean over {_seeds(sweeps)}; {INTERVAL_NOTE}\n"
                 "dashed, open squares: trained unbreakable; solid, dots: trained with the 10 N break", fontsize=9.5)
    _legend_right(ax)
    fig.tight_layout()
    return fig


def unbreakable_robustness(sweeps: dict[str, list[dict]], path: str | pathlib.Path) -> None:
    """The paper's unbreakable figure: success vs the noise sweep's level evaluated with an unbreakable peg,
    mean and 95 % t-interval over seeds clipped to [0, 100] %; runs trained unbreakable dashed in their
    method's color, with open square markers."""
    fig = unbreakable_robustness_figure(sweeps)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def grid_shape(panels: int, columns: int = PROFILE_COLUMNS) -> tuple[int, int]:
    """(rows, columns) of a grid holding `panels` panels and one more slot for the legend and notes."""
    if panels < 1:
        raise ValueError(f"panels must be >= 1, got {panels}")
    columns = min(columns, panels + 1)
    return math.ceil((panels + 1) / columns), columns


PROFILE_NOTE = ("Lines: the policy's probability of force control on each axis (sigmoid of its selection "
                "logit), averaged over every live step of the phase, whether the axis is in contact or not, "
                "at each phase-normalised time; episodes at the training noise, seeds pooled; n: episodes that "
                "reached the phase. The deterministic policy selects force where it is above 50 %.\n\n"
                "Panel titles: force selected on in-contact axis-steps (sum over axes of [force on the axis and "
                "the axis in contact] / sum of [axis in contact]; the paper's 84 % for MATCH), mean over seeds, "
                "pooled and per axis.")


def _contact_title(selected: dict | None) -> str:
    """'force on 41 % of in-contact axis-steps (x 42, y 20, z 43 %)' from the per-axis in-contact rates
    (fractions); '' without them."""
    if not selected or selected.get("per_axis") is None:
        return ""
    axes = ", ".join(f"{a} {'-' if selected.get(a) is None else f'{100 * selected[a]:.0f}'}" for a in "xyz")
    return f"\nforce on {100 * selected['per_axis']:.0f} % of in-contact axis-steps ({axes} %)"


def selection_profile_figure(profiles: dict[str, dict]):
    """The figure of `selection_profile` (open; the caller saves and closes it): one panel per run in a
    grid of PROFILE_COLUMNS columns, the last slot the legend and what is plotted."""
    rows, columns = grid_shape(max(len(profiles), 1))
    fig, axes = plt.subplots(rows, columns, figsize=(5.2 * columns, 0.6 + 2.9 * rows), squeeze=False,
                             sharey=True)
    flat = axes.ravel()
    peak = 0.0
    for ax, (name, prof) in zip(flat, profiles.items()):
        mean = np.asarray(prof["mean"], np.float64)
        centres = np.asarray(prof["bin_centres"])
        for axis, label in enumerate("xyz"):
            xs, ys = [], []
            for k in range(len(PHASES)):
                xs.extend(k + centres)
                ys.extend(100 * mean[k, :, axis])
            ax.plot(xs, ys, label=f"{label} axis", lw=1.6)
            peak = max(peak, float(np.nanmax(np.asarray(ys, np.float64), initial=0.0)))
        for k in range(1, len(PHASES)):
            ax.axvline(k, color="gray", lw=0.8)
        ax.set_xlim(0, len(PHASES))
        ax.set_xticks([k + 0.5 for k in range(len(PHASES))])
        ax.set_xticklabels([f"{p} (n={n})" for p, n in zip(PHASES, prof["episodes"])], fontsize=8)
        ax.set_title(name + _contact_title(prof.get("force_selected_contact")), fontsize=9)
        ax.grid(alpha=0.3, axis="y")
    for ax in axes[:, 0]:
        ax.set_ylabel("mean P(force) (%)")
    top = 100.0 if peak > 80 else max(10.0, 10 * math.ceil(1.1 * peak / 10))
    flat[0].set_ylim(-1, top)
    notes = flat[len(profiles)]
    handles, labels = flat[0].get_legend_handles_labels()
    for ax in flat[len(profiles):]:
        ax.set_axis_off()
    notes.legend(handles, labels, loc="upper left", fontsize=9, ncol=3, frameon=False)
    text = "\n\n".join(textwrap.fill(part, 92) for part in PROFILE_NOTE.split("\n\n"))
    notes.text(0.0, 0.8, text, transform=notes.transAxes, va="top", fontsize=7.5)
    fig.suptitle("Force selection over the phase-normalised episode (approach | contact | insertion)", fontsize=11)
    fig.tight_layout()
    return fig


def selection_profile(profiles: dict[str, dict], path: str | pathlib.Path) -> None:
    """profiles: name -> selection_profile dict (mean (3, bins, 3), bin_centres, episodes) and optionally
    'force_selected_contact': {'per_axis', 'x', 'y', 'z'} (fractions of in-contact axis-steps with force
    selected, mean over seeds), shown in the panel's title."""
    fig = selection_profile_figure(profiles)
    fig.savefig(path, dpi=120)
    plt.close(fig)
