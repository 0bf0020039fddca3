"""The campaign figure: three panels, every track drawn, the bound where given."""

import numpy as np

from geofix.maps.synthetic import fractal_terrain
from geofix.plot.figures import campaign_figure, save_figure


def test_campaign_figure_draws_every_track_and_the_bound(tmp_path):
    grid = fractal_terrain((80, 80), cell_m=100.0, rng=np.random.default_rng(0))
    t = np.arange(20.0) * 30
    truth = np.column_stack([2000 + 10 * t / 3, 3000 + 5 * t / 3])
    estimates = {"tercom": truth + 50.0, "pmf": truth + 50.0}  # on one another
    errors = {"tercom": np.full(10, 70.0), "pmf": np.linspace(5, 90, 10), "ins": np.full(10, 1e3)}
    bound = np.linspace(200, 20, 20)
    fig = campaign_figure(
        grid, truth, truth + 300.0, estimates, errors, "t", times=t, bound_track=bound, bound_m=25
    )
    ax_map, ax_err, ax_cdf = fig.axes[:3]
    labels = [line.get_label() for line in ax_map.get_lines()]
    assert {"true", "INS indicated", "tercom", "pmf"} <= set(labels)
    lines = {ln.get_label(): ln for ln in ax_map.get_lines()}
    widths = {name: line.get_linewidth() for name, line in lines.items()}
    assert widths["tercom"] > widths["pmf"] > widths["true"]  # overlapping tracks stay visible
    order = [lines[name].get_zorder() for name in ("tercom", "pmf", "INS indicated", "true")]
    assert order == sorted(order) and len(set(order)) == 4  # each narrower one on top
    legend = ax_map.get_legend()
    entries = {
        text.get_text(): handle
        for text, handle in zip(legend.get_texts(), legend.legend_handles, strict=True)
    }
    for name in ("true", "INS indicated", "tercom", "pmf"):
        assert entries[name].get_marker() not in (None, "None", ""), name  # end marker shown
    assert len({entries[n].get_marker() for n in ("true", "INS indicated", "tercom", "pmf")}) == 4
    colour_bar = next(ax for ax in fig.axes if ax.get_label() == "<colorbar>")
    assert colour_bar.get_ylabel() == "seabed elevation (m, negative below sea level)"
    np.testing.assert_allclose(
        next(ln for ln in ax_err.get_lines() if ln.get_label() == "CRLB (RMS)").get_ydata(), bound
    )
    cdf_labels = [ln.get_label() for ln in ax_cdf.get_lines()]
    assert any(lbl.startswith("ins (RMS 1000 m)") for lbl in cdf_labels)
    assert any("CRLB" in lbl for lbl in cdf_labels)
    assert not ax_cdf.patches  # step curves, no filled bars blending into each other
    assert save_figure(fig, tmp_path / "f.png").stat().st_size > 20_000
