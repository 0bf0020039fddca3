"""``replay.png``: the tracks on the map, and the error of the INS and every filter with
its 3-sigma band against time."""

from types import SimpleNamespace

import numpy as np
import pytest

from geofix.maps.synthetic import fractal_terrain
from geofix.replay import RUN_ID_KEY, replay_figure


def _replay(truth_known: bool):
    """A replay of 30 pings by two filters, as :func:`replay_figure` reads it."""
    t = np.arange(30.0) * 10
    truth = np.column_stack([2000 + 5 * t, 3000 + 2 * t])
    indicated = truth + np.column_stack([0.5 * t + 300, 0.2 * t])
    estimates = {}
    for k, spec in enumerate(("pmf", "pf")):
        shrink = np.linspace(300, 20 + 10 * k, t.size)
        estimates[spec] = [
            SimpleNamespace(t=ti, position=p + s / 3, covariance=np.diag([s**2, (s / 2) ** 2]))
            for ti, p, s in zip(t, truth, shrink, strict=True)
        ]
    inputs = SimpleNamespace(truth=truth if truth_known else None, indicated=indicated)
    mission = SimpleNamespace(times=t, name="m")
    return SimpleNamespace(mission=mission, inputs=inputs, estimates=estimates, run_id="r1")


@pytest.mark.parametrize("truth_known", [True, False])
def test_replay_figure_has_the_map_and_the_error_with_3_sigma_bands(
    tmp_path, monkeypatch, truth_known
):
    import geofix.plot.figures as figures

    drawn = []
    save = figures.save_figure
    monkeypatch.setattr(
        figures, "save_figure", lambda fig, *a, **k: drawn.append(fig) or save(fig, *a, **k)
    )
    grid = fractal_terrain((80, 80), cell_m=100.0, rng=np.random.default_rng(0))
    path = replay_figure(_replay(truth_known), grid, tmp_path / "replay.png")
    assert path.stat().st_size > 20_000
    from PIL import Image

    assert Image.open(path).text[RUN_ID_KEY] == "r1"
    (fig,) = drawn
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert len(panels) == 2
    ax_map, ax_err = panels
    assert ax_map.get_xlabel() == "east (km)" and ax_map.get_ylabel() == "north (km)"
    map_labels = {line.get_label() for line in ax_map.get_lines()}
    assert {"INS indicated", "pmf", "pf"} <= map_labels
    assert ("true" in map_labels) == truth_known
    assert ax_err.get_ylabel() == "position error (m)" and ax_err.get_yscale() == "log"
    assert ax_err.get_xlabel().startswith("time since the first ping")
    err_labels = {line.get_label() for line in ax_err.get_lines()}
    assert {"pmf 3σ", "pf 3σ"} <= err_labels
    expected = {"INS", "pmf error", "pf error"}
    assert expected <= err_labels if truth_known else not expected & err_labels
    assert len(ax_err.collections) == 2  # one shaded 3-sigma band per filter
    band = next(line for line in ax_err.get_lines() if line.get_label() == "pmf 3σ")
    np.testing.assert_allclose(band.get_ydata()[0], 900.0)  # 3 x the largest axis' sigma
