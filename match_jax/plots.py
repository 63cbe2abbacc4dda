"""Matplotlib figures of the paper's experiments (PNG files; the Agg backend, no display needed).

- learning curves: training success rate vs env steps per method, mean and 95 % CI over seeds;
- noise robustness: success and break rate vs hole-observation noise (breakable), and success with an
  unbreakable peg;
- selection profile: probability of force control per axis over the phase-normalised episode.
"""

from __future__ import annotations

import pathlib
import re
import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from match_jax.analysis import PHASES  # noqa: E402

DODGE_MM = 0.08  # x offset between runs' points in the noise figures (mm)
T_975 = {1: 12.71, 2: 4.30, 3: 3.18, 4: 2.78, 5: 2.57, 6: 2.45, 7: 2.36, 8: 2.31, 9: 2.26}  # t quantiles, df


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
        mean, half = mean_and_ci95(rates)
        ax.plot(steps, 100 * mean, label=f"{name} ({rates.shape[0]} seeds)", **styles[name])
        ax.fill_between(steps, 100 * (mean - half), 100 * (mean + half), alpha=0.12, color=styles[name]["color"])
    ax.set_xlabel("env steps per seed")
    ax.set_ylabel("training success rate (%)")
    ax.set_ylim(-2, 102)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title("Learning curves (mean, 95% CI over seeds)")
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")  # the legend sits right of the axes
    plt.close(fig)


def _sweep_lines(ax, sweeps: dict[str, list[dict]], column: str, unbreakable: bool, styles: dict) -> None:
    """One panel: `column` (%) vs the sweep's level for every run's evaluations with (unbreakable=False) or
    without a break force; mean and 95 % t-interval over the seeds' values, runs dodged along x so their
    intervals stay apart. The y axis spans 0-100 %, or 0 to just above the highest interval when under 50 %."""
    top = 0.0
    plotted = {name: sorted((r for r in results if (r["break_force_n"] is None) == unbreakable),
                            key=lambda r: r["noise_mm"]) for name, results in sweeps.items()}
    plotted = {name: rows for name, rows in plotted.items() if rows}
    for i, (name, rows) in enumerate(plotted.items()):
        per_seed = np.array([[np.nan if s.get(column) is None else s[column] for s in r["per_seed"]] for r in rows]).T
        mean, half = mean_and_ci95(100 * per_seed)
        dodge = DODGE_MM * (i - (len(plotted) - 1) / 2)
        ax.errorbar([r["noise_mm"] + dodge for r in rows], mean, yerr=half, marker="o", capsize=3, label=name,
                    **styles[name])
        top = max(top, float(np.nanmax(mean + half, initial=0.0)))
    shell = any(r["noise_type"] == "shell" for results in sweeps.values() for r in results)
    ax.set_xlabel("hole-position error, shell outer radius (mm)" if shell else "hole-position noise, uniform +- (mm)")
    ax.set_ylim(-1, 102 if top >= 50 else max(10.0, 1.1 * top))
    ax.grid(alpha=0.3)


def noise_robustness(sweeps: dict[str, list[dict]], path: str | pathlib.Path) -> None:
    """The paper's noise figure: success (top) and break rate (bottom) vs the noise sweep's level, evaluated
    with the break force, mean and 95 % interval over seeds. sweeps: name -> eval results (noise_mm,
    break_force_n, per_seed) from evaluate_run_grid."""
    fig, axes = plt.subplots(2, 1, figsize=(7, 7), sharex=True)
    styles = line_styles(sweeps)
    for ax, (column, ylabel) in zip(axes, (("success_rate", "success (%)"), ("break_rate", "break rate (%)"))):
        _sweep_lines(ax, sweeps, column, False, styles)
        ax.set_ylabel(ylabel)
    axes[0].set_xlabel("")
    axes[0].set_title("breakable peg (10 N)")
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def unbreakable_robustness(sweeps: dict[str, list[dict]], path: str | pathlib.Path) -> None:
    """The paper's unbreakable figure: success vs the noise sweep's level evaluated with an unbreakable peg,
    mean and 95 % interval over seeds; runs trained unbreakable dashed in their method's color."""
    fig, ax = plt.subplots(figsize=(7, 4))
    _sweep_lines(ax, sweeps, "success_rate", True, line_styles(sweeps))
    ax.set_ylabel("success, unbreakable (%)")
    ax.set_title("unbreakable peg")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def selection_profile(profiles: dict[str, dict], path: str | pathlib.Path) -> None:
    """profiles: name -> selection_profile dict (mean (3, bins, 3), bin_centres, episodes)."""
    fig, axes = plt.subplots(1, max(len(profiles), 1), figsize=(6 * max(len(profiles), 1), 3.8), squeeze=False)
    for ax, (name, prof) in zip(axes[0], profiles.items()):
        mean = np.asarray(prof["mean"], np.float64)
        centres = np.asarray(prof["bin_centres"])
        for axis, label in enumerate("xyz"):
            xs, ys = [], []
            for k in range(len(PHASES)):
                xs.extend(k + centres)
                ys.extend(100 * mean[k, :, axis])
            ax.plot(xs, ys, label=f"{label}")
        for k in range(1, len(PHASES)):
            ax.axvline(k, color="gray", lw=0.8)
        ax.set_xticks([0.5, 1.5, 2.5])
        ax.set_xticklabels([f"{p}\n(n={n})" for p, n in zip(PHASES, prof["episodes"])])
        ax.set_ylabel("P(force control) (%)")
        ax.set_ylim(-2, 102)
        ax.set_title(f"{name}: force selection by phase")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
