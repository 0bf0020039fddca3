"""Suitability layers: the CRLB of a standard track against a hand computation, files."""

import numpy as np
import pytest

from geofix.errors import ConfigError
from geofix.evaluate.suitability import (
    local_roughness,
    save_suitability,
    suitability,
    track_crlb_traces,
    track_shifts,
)
from geofix.maps.grid import Grid
from geofix.maps.io import load_grid
from geofix.maps.synthetic import planar_grid
from geofix.plot.suitability import save_suitability_figure


def _bowl(a=0.02, cell=10.0, n=81):
    c = cell * (np.arange(n) - n // 2)
    values = 0.5 * a * (c[None, :] ** 2 + c[:, None] ** 2)
    return Grid(values, x0=c[0], y0=c[0], dx=cell, dy=cell, name="bowl")


def test_track_shifts_run_along_the_heading():
    grid = planar_grid((10, 10), 5.0)
    np.testing.assert_array_equal(track_shifts(3, 90.0, grid), [[0, -1], [0, 0], [0, 1]])
    np.testing.assert_array_equal(track_shifts(3, 0.0, grid), [[-1, 0], [0, 0], [1, 0]])
    np.testing.assert_array_equal(track_shifts(3, 45.0, grid)[2], [1, 1])


def test_track_bound_on_a_bowl_matches_the_hand_computed_information():
    a, noise, cell, samples = 0.02, 0.5, 10.0, 7
    grid = _bowl(a, cell)
    traces = track_crlb_traces(grid, samples, noise, headings_deg=(90.0, 0.0))
    row, col = 50, 30  # cell centre (x, y) = (-100, 100) m
    x = -100.0 + cell * (np.arange(samples) - 3)  # eastward track through it
    y = np.full(samples, 100.0)
    j = a**2 / noise**2 * np.array([[x @ x, x @ y], [x @ y, y @ y]])
    assert traces[0, row, col] == pytest.approx(np.trace(np.linalg.inv(j)), rel=1e-9)
    # northward track through the same cell: the roles of x and y swap
    y2 = 100.0 + cell * (np.arange(samples) - 3)
    x2 = np.full(samples, -100.0)
    j2 = a**2 / noise**2 * np.array([[x2 @ x2, x2 @ y2], [x2 @ y2, y2 @ y2]])
    assert traces[1, row, col] == pytest.approx(np.trace(np.linalg.inv(j2)), rel=1e-9)


def test_a_plane_is_unmatchable_and_relief_helps():
    plane = suitability(planar_grid((40, 40), 10.0, slope_x=0.1), window_cells=5)
    assert np.isinf(plane.crlb.values).all()
    np.testing.assert_allclose(plane.roughness.values[5:-5, 5:-5], 0.5, rtol=1e-9)  # (1+0)/2
    rough = suitability(_bowl(0.08), window_cells=5).crlb.values
    smooth = suitability(_bowl(0.02), window_cells=5).crlb.values
    inner = (slice(10, -10), slice(10, -10))
    finite = np.isfinite(smooth[inner])  # a track through the bowl's centre is singular
    assert finite.mean() > 0.9
    assert np.all(rough[inner][finite] < smooth[inner][finite])
    np.testing.assert_allclose(rough[inner], smooth[inner] / 4, rtol=1e-6)  # g scales with a


def test_roughness_skips_no_data():
    values = np.arange(36.0).reshape(6, 6)
    values[2, 3] = np.nan
    r = local_roughness(Grid(values, 0, 0, 1, 1), 3)
    assert np.isnan(r[2, 3])
    assert np.isfinite(r[2, 2])
    assert r[0, 0] == pytest.approx((1 + 6) / 2 * 1.0, rel=0.2)


def test_bad_settings_raise():
    with pytest.raises(ConfigError, match="window_cells"):
        suitability(_bowl(), window_cells=1)
    with pytest.raises(ConfigError, match="noise_std"):
        suitability(_bowl(), noise_std=0.0)


def test_save_writes_grids_that_load_back_and_a_figure(tmp_path):
    result = suitability(_bowl(), window_cells=5, noise_std=0.5)
    paths = save_suitability(result, tmp_path)
    paths["figure"] = save_suitability_figure(result, tmp_path)
    assert paths["figure"].stat().st_size > 10_000
    back = load_grid(paths["crlb"])
    np.testing.assert_array_equal(back.values, result.crlb.values)
    assert back.units == "m"
    assert back.meta["noise_std"] == 0.5


def test_cli_writes_the_layers_and_the_figure(tmp_path):
    from typer.testing import CliRunner

    from geofix.cli import app

    args = ["suitability", "builtin:mb_1km", "--window-cells", "9", "--noise-std", "5"]
    result = CliRunner().invoke(app, [*args, "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "suitability.png").exists()
    crlb = load_grid(tmp_path / "suitability_crlb.nc")
    assert crlb.shape == (160, 160)
    assert np.nanmedian(crlb.values) > 0
    bad = CliRunner().invoke(app, ["suitability", "builtin:nowhere", "--out", str(tmp_path)])
    assert bad.exit_code == 2
