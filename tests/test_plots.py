"""The report's figures: rate intervals clipped to [0, 100] %, the selection profile's grid layout, legends
beside the data (matplotlib only, no MuJoCo)."""

import matplotlib.pyplot as plt
from matplotlib.lines import Line2D
import numpy as np
import pytest

from match_jax.experiments import plots


def test_clip_interval_keeps_rate_intervals_within_0_and_100():
    """Bar lengths below / above the mean: cut where mean -+ half leaves [0, 100], untouched inside, never
    negative, NaN where the mean is NaN."""
    mean = np.array([50.0, 3.0, 98.0, 0.0, 100.0, np.nan])
    half = np.array([10.0, 5.0, 4.0, 0.0, 7.0, 1.0])
    below, above = plots.clip_interval(mean, half)
    np.testing.assert_allclose(below[:5], [10.0, 3.0, 4.0, 0.0, 7.0])
    np.testing.assert_allclose(above[:5], [10.0, 5.0, 2.0, 0.0, 0.0])
    assert np.isnan(below[5]) and np.isnan(above[5])
    assert (mean[:5] - below[:5] >= 0).all() and (mean[:5] + above[:5] <= 100).all()
    np.testing.assert_allclose(plots.clip_interval(0.5, 0.7, 0.0, 1.0), [0.5, 0.5])  # other bounds: fractions


def test_mean_and_ci95_is_the_t_interval_over_seeds():
    values = np.array([[0.0, 10.0], [10.0, 10.0], [20.0, 10.0]])  # 3 seeds x 2 levels
    mean, half = plots.mean_and_ci95(values)
    np.testing.assert_allclose(mean, [10.0, 10.0])
    np.testing.assert_allclose(half, [4.30 * 10.0 / np.sqrt(3), 0.0])


@pytest.mark.parametrize("panels, shape", [(1, (1, 2)), (2, (2, 2)), (3, (2, 2)), (7, (4, 2))])
def test_grid_shape_leaves_one_slot_for_the_legend(panels, shape):
    assert plots.grid_shape(panels) == shape
    rows, columns = plots.grid_shape(panels)
    assert panels < rows * columns <= panels + columns


def _profile(seed=0, bins=4, contact=True):
    rng = np.random.default_rng(seed)
    profile = {"mean": rng.uniform(0, 0.3, (3, bins, 3)).tolist(), "count": np.ones((3, bins)).tolist(),
               "episodes": [10, 9, 8], "bin_centres": ((np.arange(bins) + 0.5) / bins).tolist()}
    if contact:
        profile["force_selected_contact"] = {"per_axis": 0.406, "x": 0.42, "y": 0.195, "z": None}
    return profile


def test_selection_profile_is_a_grid_with_one_panel_per_run():
    """Seven runs: a 4 x 2 grid, seven panels with three lines (x, y, z) each, titled with the in-contact
    force selection where given, and the eighth slot the legend and notes (no axes drawn)."""
    profiles = {f"run {i}": _profile(i, contact=i != 3) for i in range(7)}
    fig = plots.selection_profile_figure(profiles)
    try:
        axes = fig.get_axes()
        assert len(axes) == 8
        assert {ax.get_subplotspec().get_geometry()[:2] for ax in axes} == {(4, 2)}
        panels = [ax for ax in axes if ax.axison]
        assert len(panels) == 7 and all(len(ax.get_lines()) == 3 + 2 for ax in panels)  # x, y, z, 2 phase edges
        assert "force on 41 % of in-contact axis-steps (x 42, y 20, z - %)" in panels[0].get_title()
        assert "\n" not in panels[3].get_title()  # no in-contact rates: the run's name only
        assert panels[0].get_ylabel() == "mean P(force) (%)"
        notes = axes[7]
        assert not notes.axison and notes.get_legend() is not None
        assert [t.get_text() for t in notes.get_legend().get_texts()] == ["x axis", "y axis", "z axis"]
    finally:
        plt.close(fig)


def test_selection_profile_takes_a_bare_profile(tmp_path):
    """One run without in-contact rates (benchmarks/run_figures.py): one panel beside its legend."""
    plots.selection_profile({"MATCH": _profile(contact=False)}, tmp_path / "profile.png")
    assert (tmp_path / "profile.png").stat().st_size > 0


def _sweep(success, breaks, breakable=True):
    levels = (0.0, 1.0, 2.5)
    return [{"noise_mm": x, "noise_type": "shell", "break_force_n": 10.0 if breakable else None,
             "per_seed": [{"success_rate": s, "break_rate": b} for s, b in zip(success, breaks)]} for x in levels]


def test_sweep_figures_clip_bars_and_keep_legends_off_the_data():
    """Seeds at 0 and 100 %: no bar leaves [0, 100]; the legend lies right of the axes; a run trained
    unbreakable is dashed with open markers, and its legend handle shows the dash."""
    sweeps = {"Pose": _sweep([1.0, 0.9, 0.2], [0.0, 0.0, 0.3]) + _sweep([1.0, 1.0, 0.6], [0, 0, 0], False),
              "Pose (unbreakable)": _sweep([1.0, 0.98, 0.99], [0, 0, 0], False)}
    for make in (plots.noise_robustness_figure, plots.unbreakable_robustness_figure):
        fig = make(sweeps)
        try:
            fig.canvas.draw()
            for ax in fig.get_axes():
                for collection in ax.collections:  # the error bars
                    for segment in collection.get_segments():
                        assert -1e-9 <= segment[:, 1].min() and segment[:, 1].max() <= 100 + 1e-9
            legend = fig.get_axes()[0].get_legend()
            renderer = fig.canvas.get_renderer()
            assert legend.get_window_extent(renderer).x0 >= fig.get_axes()[0].get_window_extent(renderer).x1
        finally:
            plt.close(fig)
    fig = plots.unbreakable_robustness_figure(sweeps)
    try:
        ax = fig.get_axes()[0]
        dashed = [line for line in ax.get_lines() if line.get_linestyle() == "--"]
        assert len(dashed) == 1 and dashed[0].get_markerfacecolor() == "white"
        drawn = [(line.get_linestyle(), line.get_marker()) for line in ax.get_legend().findobj(Line2D)]
        assert ("--", "none") in drawn and ("None", "s") in drawn  # the legend shows the dash and open square
    finally:
        plt.close(fig)


def test_report_gives_the_profile_figure_the_in_contact_selection():
    """The report's profile panels carry the Table 1 row's in-contact force selection (means over seeds; None
    where the row lacks a column or it is NaN)."""
    from match_jax.experiments.report import selection_figure_data

    row = {"selection_profile": _profile(contact=False),
           "aggregate": {"force_selected_contact_per_axis": {"mean": 0.406}, "force_selected_contact_x": {"mean": 0.42},
                         "force_selected_contact_y": {"mean": float("nan")}}}
    data = selection_figure_data(row)
    assert data["force_selected_contact"] == {"per_axis": 0.406, "x": 0.42, "y": None, "z": None}
    assert data["episodes"] == [10, 9, 8]
