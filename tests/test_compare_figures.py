"""The comparison's figures, checked on the drawn artists: one row of axes per law with shared axes,
a slope in the legend only through a power law (r^2 >= 0.99 on log-log, as sweeps), the reason
otherwise, and a unit in every axis label."""

import re

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ftstab_mj.figures.compare_report import accuracy_figure, draw_figures, grid_label, time_figure  # noqa: E402

PERIODS = [5e-4, 1e-3, 2e-3, 4e-3]


def _rows():
    """Three laws: an exact power law (z_1 = 3 h^2, z_2 = h), a bent curve (a floor: r^2 < 0.99) and a
    law with two completed points only."""
    rows = []
    for h in PERIODS:
        rows.append({"label": "power", "status": "completed", "sim.period": h, "final_abs_z1": 3 * h ** 2,
                     "final_abs_z2": h})
        rows.append({"label": "bent", "status": "completed", "sim.period": h,
                     "final_abs_z1": 1e-4 + (h / 4e-3) ** 6, "final_abs_z2": 1e-3 * (1 + (h > 1e-3) * 50)})
        rows.append({"label": "few", "status": "completed" if h < 2e-3 else "diverged", "sim.period": h,
                     "final_abs_z1": h, "final_abs_z2": h})
    return rows


def _legend(ax):
    return [t.get_text() for t in ax.get_legend().get_texts()]


def test_accuracy_legend_states_a_slope_only_through_a_power_law():
    fig = accuracy_figure("c", _rows(), "sim.period")
    try:
        (a1, a2) = fig.axes
        for ax, slope in ((a1, "2.00"), (a2, "1.00")):
            power, bent, few = _legend(ax)
            assert power == f"power: slope {slope}"
            assert "slope" not in bent.replace("no slope", "") and "r^2 = " in bent and "< 0.99" in bent
            assert not re.search(r"slope -?\d", few) and "2 points" in few
        # the numbers behind the bent line: r^2 really is below 0.99
        x, y = np.log10(PERIODS), np.log10([1e-4 + (h / 4e-3) ** 6 for h in PERIODS])
        res = y - np.polyval(np.polyfit(x, y, 1), x)
        assert 1 - np.sum(res ** 2) / np.sum((y - y.mean()) ** 2) < 0.99
        for ax in fig.axes:  # units in every label, the legend outside the data area (below the axes)
            assert re.search(r"\(.*s\)", ax.get_xlabel()) and re.search(r"\(.+\)$", ax.get_ylabel())
            assert ax.get_legend().get_bbox_to_anchor().y0 < ax.get_window_extent().y0
    finally:
        plt.close(fig)


def test_time_figure_is_one_row_per_law_with_shared_axes_and_units():
    t = np.linspace(0.0, 1.0, 200)
    series = {name: {"t": t, "u": scale * np.sin(20 * t), "z1": np.exp(-k * t)}
              for name, scale, k in (("robust", 1.0, 3.0), ("plestan_adaptive", 15.0, 5.0), ("twisting", 9.0, 8.0))}
    fig = time_figure("c", series, r=2)
    try:
        axes = np.array(fig.axes).reshape(3, 2)
        assert [row[0].get_title(loc="left") for row in axes] == list(series)
        for col in range(2):  # one scale per column: the laws are compared, none hides another
            lims = {axes[i, col].get_ylim() for i in range(3)}
            assert len(lims) == 1
            assert len({axes[i, col].get_xlim() for i in range(3)}) == 1
        for ax in fig.axes:
            assert re.search(r"\(.+\)$", ax.get_ylabel()), ax.get_ylabel()
            assert len(ax.lines) == 1  # one law per panel
        assert axes[-1, 0].get_xlabel() == "t (s)" and axes[0, 0].get_ylabel() == "u (m/s^2)"
        assert axes[0, 1].get_ylabel() == "|z_1| (m)"
    finally:
        plt.close(fig)


def test_grid_labels_have_units():
    assert grid_label("sim.period") == "sim.period (control period, s)"
    assert "chain units" in grid_label("loops.cart.disturbance.amplitude")


def test_draw_figures_writes_both_pngs(tmp_path):
    t = np.linspace(0.0, 1.0, 50)
    paths = draw_figures("c", _rows(), "sim.period", PERIODS, {"a": {"t": t, "u": t, "z1": t + 1e-3}}, tmp_path)
    assert [p.name for p in paths] == ["c_accuracy.png", "c_time.png"]
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
