"""Cramér–Rao bounds: hand-computed information, batch and recursive bounds, campaign keys."""

import json

import numpy as np
import pandas as pd
import pytest

from geofix.evaluate import run_campaign
from geofix.evaluate.crlb import (
    batch_bound,
    error_state_bound,
    process_variances,
    recursive_bound,
    rms_bound,
    trial_crlb,
)
from geofix.evaluate.metrics import end_mahalanobis, summarize
from geofix.evaluate.summary import CampaignSummary
from geofix.maps.grid import Grid
from geofix.maps.synthetic import planar_grid
from geofix.measurement import beam_gradients, inverse_trace, sample_information
from geofix.sim.trial import Trial


def _bowl(a=0.02, cell=10.0, n=101):
    """``z = a (x^2 + y^2) / 2`` centred on the grid: the bilinear read's gradient is
    ``(a x, a y)`` exactly at cell centres (a secant of a parabola)."""
    c = cell * (np.arange(n) - n // 2)
    values = 0.5 * a * (c[None, :] ** 2 + c[:, None] ** 2)
    return Grid(values, x0=c[0], y0=c[0], dx=cell, dy=cell, name="bowl")


def test_plane_information_is_beams_times_outer_product_of_slope():
    grid = planar_grid((60, 60), 10.0, slope_x=0.3, slope_y=-0.1)
    track = np.column_stack([np.linspace(100, 400, 7), np.full(7, 300.0)])
    offsets = np.array([[-20.0, 0.0], [0.0, 0.0], [20.0, 0.0]])
    gx, gy = beam_gradients(grid, track, np.full(7, 0.7), offsets)
    np.testing.assert_allclose(gx, 0.3)
    np.testing.assert_allclose(gy, -0.1)
    var = np.array([4.0, 1.0, 4.0])
    info = sample_information(gx, gy, var)
    g = np.array([0.3, -0.1])
    np.testing.assert_allclose(info, np.broadcast_to(1.5 * np.outer(g, g), (7, 2, 2)))
    # a plane says nothing along its contours: the batch bound is infinite
    assert np.isinf(inverse_trace(info.sum(axis=0)))
    assert np.isinf(batch_bound(info)).all()


def test_batch_bound_on_a_bowl_matches_the_hand_computed_inverse():
    a, var = 0.02, 0.25
    grid = _bowl(a)
    # mid-cell points: there the bilinear interpolant's slope equals the bowl's
    track = np.array([[105.0, 5.0], [5.0, 155.0], [-125.0, -65.0], [55.0, 75.0]])
    gx, gy = beam_gradients(grid, track, np.zeros(4), np.zeros((1, 2)))
    info = sample_information(gx, gy, var)
    x, y = track.T
    j = a**2 / var * np.array([[np.sum(x * x), np.sum(x * y)], [np.sum(x * y), np.sum(y * y)]])
    np.testing.assert_allclose(info.sum(axis=0), j, rtol=1e-9)
    np.testing.assert_allclose(batch_bound(info), np.linalg.inv(j), rtol=1e-9)
    assert inverse_trace(j) == pytest.approx(np.trace(np.linalg.inv(j)))


def test_missing_measurements_carry_no_information():
    gx = np.ones((3, 2))
    gy = np.zeros((3, 2))
    valid = np.array([[True, False], [False, False], [True, True]])
    info = sample_information(gx, gy, 2.0, valid=valid)
    np.testing.assert_allclose(info[:, 0, 0], [0.5, 0.0, 1.0])


def test_recursive_bound_equals_the_scalar_kalman_variance_when_isotropic():
    i, q, p0, n = 0.04, 3.0, 400.0, 60
    info = np.broadcast_to(i * np.eye(2), (n, 2, 2))
    bounds = recursive_bound(info, np.full(n - 1, q), p0)
    p = 1.0 / (1.0 / p0 + i)
    expected = [p]
    for _ in range(n - 1):
        p = 1.0 / (1.0 / (p + q) + i)
        expected.append(p)
    np.testing.assert_allclose(bounds[:, 0, 0], expected, rtol=1e-12)
    np.testing.assert_allclose(bounds[:, 1, 1], expected, rtol=1e-12)
    np.testing.assert_allclose(bounds[:, 0, 1], 0.0, atol=1e-12)
    steady = 0.5 * (-q + np.sqrt(q * q + 4.0 * q / i))  # P^2 + qP - q/i = 0
    assert bounds[-1, 0, 0] == pytest.approx(steady, rel=1e-9)


def test_recursive_bound_without_information_is_the_prior_grown_by_the_ins():
    sigma = np.sqrt(100.0 + 4.0 * np.arange(20.0) ** 2)
    info = np.zeros((20, 2, 2))
    info[:, 0, 0] = 0.5  # a plane sloping along x only
    bounds = recursive_bound(info, process_variances(sigma), sigma[0] ** 2)
    np.testing.assert_allclose(bounds[:, 1, 1], sigma**2, rtol=1e-12)
    assert np.all(bounds[1:, 0, 0] < 2.0)


def _trial_on(grid, n=30, beams=1):
    t = np.arange(n) * 10.0
    truth = np.column_stack([-145.0 + 10.0 * t / 10, 45.0 + 0 * t])  # mid-cells
    offsets = np.column_stack([np.linspace(-30, 30, beams), np.zeros(beams)])
    return Trial(
        truth=truth,
        true_heading=np.full(n, np.pi / 2),
        indicated=truth + 50.0,
        indicated_heading=np.full(n, np.pi / 2),
        times=t,
        measured=np.zeros((n, beams)),
        offsets=offsets if beams > 1 else np.zeros((1, 2)),
        sigma_position=np.sqrt(50.0**2 + 0.5 * t),
        leg_starts=(0, n // 2),
        noise_std=0.5,
    )


def test_trial_crlb_batch_uses_the_last_leg_and_recursive_the_whole_mission():
    a = 0.02
    trial = _trial_on(_bowl(a))
    bound = trial_crlb(trial, _bowl(a))
    x, y = trial.truth[15:].T
    j = a**2 / 0.25 * np.array([[np.sum(x * x), np.sum(x * y)], [np.sum(x * y), np.sum(y * y)]])
    assert bound.batch_var_m2 == pytest.approx(np.trace(np.linalg.inv(j)), rel=1e-9)
    assert bound.batch_m == pytest.approx(np.sqrt(bound.batch_var_m2))
    # the recursive bound keeps the prior and all samples: finite, below the prior
    assert 0 < bound.recursive_var_m2 < 2 * trial.sigma_position[-1] ** 2
    # a flat map gives nothing: the recursive bound is the prior, the batch one infinite
    flat = trial_crlb(trial, planar_grid((101, 101), 10.0, x0=-500.0, y0=-500.0))
    assert flat.recursive_var_m2 == pytest.approx(2 * trial.sigma_position[-1] ** 2)
    assert np.isinf(flat.batch_var_m2)


def test_rms_bound_averages_variances_then_takes_the_root():
    assert rms_bound([9.0, 16.0, np.nan]) == pytest.approx(np.sqrt(12.5))
    assert rms_bound([1.0, np.inf]) is None
    assert rms_bound([]) is None


def test_mahalanobis_distance_and_the_false_fix_rule():
    cov = np.array([[100.0, 0.0], [0.0, 25.0]])
    assert end_mahalanobis([30.0, 0.0], cov) == pytest.approx(3.0)
    assert end_mahalanobis([0.0, 20.0], cov) == pytest.approx(4.0)
    assert np.isnan(end_mahalanobis([1.0, 1.0], None))
    assert np.isnan(end_mahalanobis([1.0, 1.0], np.zeros((2, 2))))
    rows = pd.DataFrame(
        {
            "method": ["m"] * 4,
            "trial": range(4),
            "end_error_m": [200.0, 200.0, 200.0, 10.0],
            "mean_track_error_m": 0.0,
            "max_track_error_m": 0.0,
            "leg_errors_m": [[0.0]] * 4,
            "time_s": 0.1,
            "n_calls": 1,
            "evaluations": 1,
            "ambiguous": [False, False, True, False],
            # inside its 3-sigma ellipse, outside it, flagged, close
            "end_mahalanobis": [2.0, 5.0, 9.0, np.nan],
            "failed": False,
        }
    )
    assert summarize(rows, cell_m=50.0)["m"].false_fix_rate == pytest.approx(0.25)
    no_cov = rows.assign(end_mahalanobis=np.nan)
    assert summarize(no_cov, cell_m=50.0)["m"].false_fix_rate == pytest.approx(0.5)


def test_campaign_reports_the_bounds_and_refills_them_for_an_old_store(tmp_path, small_mission):
    import sqlite3

    scen = small_mission("crlb-small")
    result = run_campaign(scen, ["tercom"], jobs=1, out_dir=tmp_path, progress=None)
    summary = CampaignSummary.from_json(json.loads((tmp_path / "summary.json").read_text()))
    assert summary.crlb_m == pytest.approx(result.summary.crlb_m)
    assert 0 < summary.crlb_m < 1500.0
    assert summary.crlb_batch_m > 0
    per_trial = result.frame["crlb_m"].to_numpy()
    assert summary.crlb_m == pytest.approx(np.sqrt(np.mean(per_trial**2)))
    assert "false_fix_rate" in summary.methods["tercom"].to_json()
    assert summary.crlb_track_m > 0 and summary.crlb_rw_m > 0
    stats = summary.methods["tercom"]
    end = result.frame["end_error_m"].to_numpy()
    assert stats.rms_error_m == pytest.approx(np.sqrt(np.mean(end**2)))
    maha = result.frame["end_mahalanobis"].to_numpy()
    assert stats.nees == pytest.approx(np.mean(maha**2))
    assert stats.track_rms_error_m >= stats.mean_track_error_m > 0
    assert result.frame["end_mahalanobis"].notna().all()  # tercom gives a covariance
    with sqlite3.connect(tmp_path / "results.sqlite") as db:
        db.execute("DROP TABLE trial_bounds")
    again = run_campaign(scen, ["tercom"], jobs=1, out_dir=tmp_path, progress=None)
    assert again.computed == 0
    assert again.summary.crlb_m == pytest.approx(result.summary.crlb_m)
    # a store of the earlier schema (no track / random-walk columns) is refilled
    with sqlite3.connect(tmp_path / "results.sqlite") as db:
        db.execute("DROP TABLE trial_bounds")
        db.execute(
            "CREATE TABLE trial_bounds (scenario_hash TEXT NOT NULL, trial INTEGER NOT NULL, "
            "crlb_var_m2 REAL, crlb_batch_var_m2 REAL, truth_end_x REAL NOT NULL, "
            "truth_end_y REAL NOT NULL, PRIMARY KEY (scenario_hash, trial))"
        )
    old = run_campaign(scen, ["tercom"], jobs=1, out_dir=tmp_path, progress=None)
    assert old.summary.crlb_rw_m == pytest.approx(result.summary.crlb_rw_m)
    assert old.summary.crlb_m == pytest.approx(result.summary.crlb_m)


def test_exact_gradient_matches_finite_differences_of_the_bilinear_read():
    rng = np.random.default_rng(3)
    cell = 25.0
    c = cell * np.arange(80)
    values = (
        np.sin(c[None, :] / 173.0) * np.cos(c[:, None] / 97.0) * 40.0
        + np.exp(-((c[None, :] - 900) ** 2 + (c[:, None] - 1100) ** 2) / 2e5) * 30.0
    )
    grid = Grid(values, x0=0.0, y0=0.0, dx=cell, dy=cell, name="wavy")
    # points away from cell edges (the interpolant's slope jumps across them)
    cells = rng.integers(1, 77, (200, 2)) + rng.uniform(0.1, 0.9, (200, 2))
    x, y = cells[:, 0] * cell, cells[:, 1] * cell
    _, gx, gy = grid.sample_gradient(x, y)
    h = 1e-3
    fx = (grid.sample(x + h, y) - grid.sample(x - h, y)) / (2 * h)
    fy = (grid.sample(x, y + h) - grid.sample(x, y - h)) / (2 * h)
    np.testing.assert_allclose(gx, fx, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(gy, fy, rtol=1e-6, atol=1e-9)
    # the old central difference over two cells is not the interpolant's slope
    assert (
        np.abs(
            gx - np.gradient(values, cell, axis=1)[cells[:, 1].astype(int), cells[:, 0].astype(int)]
        ).max()
        > 1e-3
    )
    assert np.isnan(grid.sample_gradient(np.array([-5.0]), np.array([10.0]))[1]).all()


def test_error_state_bound_on_a_plane_is_a_kalman_filter_covariance():
    from geofix.nav.errstate import InsErrorModel, error_state
    from geofix.nav.spec import DvlSpec, InsSpec
    from geofix.nav.trajectory import true_trajectory

    slope = np.array([0.05, -0.02])
    true = true_trajectory((0.0, 0.0), 60.0, 5.0, 10.0, 30, 2, 40.0, np.random.default_rng(0))
    spec = InsSpec(
        initial_error_std_m=50.0,
        velocity_error_m_s=0.1,
        accel_bias_ug=30.0,
        gyro_bias_deg_h=0.01,
        heading_error_deg=0.2,
        accel_noise_ug_rt_hz=10.0,
        latitude_deg=30.0,
    )
    es = error_state(
        InsErrorModel.from_specs(spec, DvlSpec(noise_std_m_s=0.05)), true.times, true.positions
    )
    beam_var = np.array([0.5, 2.0, 0.5])
    info = np.broadcast_to(np.outer(slope, slope) * np.sum(1 / beam_var), (true.n, 2, 2))
    bound = error_state_bound(es, info)
    # a textbook Kalman filter: three beams on the plane, h = -slope . (H x), plus the DVL
    c = np.vstack([np.tile(-slope @ es.position_map, (3, 1)), es.velocity_map])
    r = np.diag([*beam_var, 0.05**2, 0.05**2])
    p = es.prior_cov
    for k in range(true.n):
        if k:
            p = es.transitions[k - 1] @ p @ es.transitions[k - 1].T + es.process_cov[k - 1]
        gain = p @ c.T @ np.linalg.inv(c @ p @ c.T + r)
        p = (np.eye(es.dim) - gain @ c) @ p
        np.testing.assert_allclose(bound[k], p, rtol=1e-6, atol=1e-9 * np.abs(p).max())
    # along the contour the plane says nothing: that axis is bounded by the INS alone
    pos = es.position_cov(bound[-1])
    along = np.array([slope[1], -slope[0]]) / np.hypot(*slope)
    assert along @ pos @ along > 10 * (slope @ pos @ slope) / (slope @ slope)


def test_bound_differentiates_the_read_the_simulator_draws_the_truth_with():
    from dataclasses import replace

    from geofix.evaluate.crlb import trial_information
    from geofix.problem import footprint_xy
    from geofix.sensors.spec import SensorSpec
    from geofix.sim.sensing import TRUTH_READ, measure

    cell = 10.0
    c = cell * (np.arange(101) - 50)
    values = 30.0 * np.sin(c[None, :] / 61.0) * np.cos(c[:, None] / 47.0)
    linear = Grid(values, x0=-500.0, y0=-500.0, dx=cell, dy=cell)
    cubic = replace(linear, interpolation="bicubic")
    trial = _trial_on(linear, beams=3)
    # the simulator's clean readings are the TRUTH_READ (bilinear) read on either grid
    spec = SensorSpec(type="singlebeam")  # noiseless
    rng = np.random.default_rng(0)
    clean = measure(cubic, trial.truth, trial.true_heading, trial.offsets, spec, rng)
    x, y = footprint_xy(trial.truth, trial.true_heading, trial.offsets)
    assert TRUTH_READ == "bilinear"
    np.testing.assert_array_equal(clean, linear.sample(x, y))
    assert np.abs(clean - cubic.sample(x, y)).max() > 1e-3
    # beam_gradients follows the grid's interpolation ...
    gx, gy = beam_gradients(cubic, trial.truth, trial.true_heading, trial.offsets)
    _, cx, cy = cubic.sample_gradient(x, y, method="bicubic")
    np.testing.assert_array_equal(gx, cx)
    np.testing.assert_array_equal(gy, cy)
    bx, _ = beam_gradients(linear, trial.truth, trial.true_heading, trial.offsets)
    assert np.abs(bx - gx).max() > 1e-3
    # ... while the bound takes the simulator's read on either grid
    np.testing.assert_array_equal(trial_information(trial, cubic), trial_information(trial, linear))


def test_the_simulator_prior_keeps_only_the_spread_of_the_start_offset():
    from geofix.nav.errstate import InsErrorModel, error_state
    from geofix.nav.spec import InsSpec
    from geofix.nav.trajectory import true_trajectory

    true = true_trajectory((0.0, 0.0), 60.0, 5.0, 10.0, 30, 2, 40.0, np.random.default_rng(0))
    info = np.broadcast_to(np.diag([2e-4, 1e-4]), (true.n, 2, 2))
    bounds = {}
    for std in (0.0, 40.0):
        spec = InsSpec(
            initial_error_m=(300.0, -200.0),
            initial_error_std_m=std,
            velocity_error_m_s=0.1,
            accel_bias_ug=30.0,
        )
        es = error_state(InsErrorModel.from_specs(spec), true.times, true.positions)
        told = es.with_simulator_position_prior()
        # the start position: the spread alone (0 for a fixed offset) against the
        # second moments offset^2 + spread^2; every other state unchanged
        np.testing.assert_allclose(np.diag(told.position_cov(told.prior_cov)), [std**2] * 2)
        np.testing.assert_allclose(
            np.diag(es.position_cov(es.prior_cov)), np.array([300.0, 200.0]) ** 2 + std**2
        )
        np.testing.assert_allclose(told.prior_cov[2:, 2:], es.prior_cov[2:, 2:])
        bounds[std] = [
            np.trace(e.position_cov(error_state_bound(e, info)), axis1=1, axis2=2)
            for e in (es, told)
        ]
    # a narrower prior can only lower the bound; told a fixed offset, nothing is left at
    # the start but the INS drift grows it afterwards
    for moments, told in bounds.values():
        assert (told <= moments * (1 + 1e-9)).all()
    fixed = bounds[0.0][1]
    assert fixed[0] < 1e-9 and fixed[-1] > 1.0
    assert bounds[40.0][1][0] == pytest.approx(2 * 40.0**2, rel=0.2)
