"""The measurement model's nuisance states: representation error, common offset, scale."""

from __future__ import annotations

import numpy as np
import pytest

from geofix.errors import ConfigError
from geofix.filters.base import Observation
from geofix.filters.nuisance import (
    MAX_PINGS_PER_ERROR,
    REPRESENTATION_SHARE,
    CommonOffset,
    PointReads,
    ResidualScale,
    check_map_model,
    correlated_share,
    read_at_points,
    representation_std,
    unscented_points,
)
from geofix.maps.grid import Grid
from geofix.methods import parse_method_spec
from geofix.navigator import NavigatorSettings


def _grid(values: np.ndarray, cell: float = 10.0) -> Grid:
    return Grid(values=values, x0=0.0, y0=0.0, dx=cell, dy=cell, kind="depth", units="m")


def _ramp(n: int = 60, cell: float = 10.0) -> Grid:
    y, x = np.mgrid[0:n, 0:n] * cell
    return _grid(-1000.0 + 0.05 * x + 0.02 * y, cell)


def test_a_plane_has_no_representation_error_and_a_parabola_its_known_one():
    assert np.abs(representation_std(_ramp()).values).max() < 1e-6
    # z = u^2 (u in cells): a 3 x 3 plane fit leaves residuals of rms sqrt(2/9) everywhere
    u = np.arange(40, dtype=float)
    parabola = _grid(np.tile(u**2, (40, 1)))
    inner = representation_std(parabola).values[5:-5, 5:-5]
    assert inner == pytest.approx(REPRESENTATION_SHARE * np.sqrt(2.0 / 9.0), rel=1e-9)


def test_beams_closer_than_a_cell_share_one_map_error():
    offsets = np.column_stack([np.linspace(-100.0, 100.0, 61), np.zeros(61)])
    assert correlated_share(offsets, 50.0) == pytest.approx(61 / 5)
    assert correlated_share(offsets, 1.0) == pytest.approx(1.0)  # at most one per beam
    assert correlated_share(np.zeros((1, 2)), 50.0) == 1.0
    # pings 10 m apart on 50 m cells read the same map error five times
    assert correlated_share(offsets, 50.0, step_m=10.0) == pytest.approx(5 * 61 / 5)
    # a vehicle at rest counts one map error at most MAX_PINGS_PER_ERROR times
    assert correlated_share(np.zeros((1, 2)), 50.0, step_m=0.0) == MAX_PINGS_PER_ERROR
    assert correlated_share(np.zeros((1, 2)), 500.0, step_m=10.0) == 50.0


def _ping(grid: Grid, position, values_shift: float, rng, noise: float) -> Observation:
    offsets = np.column_stack([np.linspace(-30.0, 30.0, 7), np.zeros(7)])
    from geofix.measurement import predict_measurements

    clean = predict_measurements(grid, np.asarray(position, float)[None], 0.0, offsets)[0]
    values = clean + values_shift + rng.normal(0.0, noise, clean.shape)
    return Observation(values, np.asarray(position, float), 0.0, offsets, noise**2, 0)


def test_the_offset_state_recovers_a_constant_offset_at_a_known_position(rng):
    grid = _ramp()
    offset = CommonOffset.prior(10.0, 0.0, 0.0)
    for _ in range(40):
        obs = offset.relative(_ping(grid, (300.0, 300.0), 3.0, rng, 0.5))
        reads = read_at_points(grid, np.array([300.0, 300.0]), np.eye(2) * 1e-6, obs)
        offset = offset.updated(reads, obs.bias_var)
    # 40 pings x 7 beams of sd 0.5: the offset's sd is 0.5 / sqrt(280) = 0.03
    assert offset.mean == pytest.approx(3.0, abs=4 * 0.5 / np.sqrt(280))
    assert offset.std == pytest.approx(0.5 / np.sqrt(280), rel=0.05)
    assert offset.predicted(100.0).var == pytest.approx(offset.var)  # no walk


def test_an_uncertain_position_on_a_slope_leaves_the_offset_uncertain(rng):
    grid = _ramp()
    offset = CommonOffset.prior(10.0, 0.0, 0.0)
    obs = offset.relative(_ping(grid, (300.0, 300.0), 3.0, rng, 0.1))
    sure = offset.updated(read_at_points(grid, np.full(2, 300.0), np.eye(2) * 1e-6, obs), 100.0)
    unsure = offset.updated(read_at_points(grid, np.full(2, 300.0), np.eye(2) * 400.0, obs), 100.0)
    # slope 0.054 along the gradient, position sd 20 m: the offset's sd about 1.1 m
    assert sure.std < 0.1 < 0.8 < unsure.std < 1.5


def test_the_residual_scale_finds_an_underdeclared_noise_and_keeps_a_right_one(rng):
    grid = _ramp()
    for true_sd, expected in ((2.0, 16.0), (0.5, 1.0)):
        scale = ResidualScale.prior(0.98)
        for _ in range(300):
            obs = _ping(grid, (300.0, 300.0), 0.0, rng, true_sd)
            obs = Observation(obs.values, obs.indicated, 0.0, obs.offsets, 0.25, 0)
            reads = read_at_points(grid, np.full(2, 300.0), np.eye(2) * 1e-6, obs)
            scale = scale.updated(reads, 0.0)
        # a memory of 50 pings x 7 beams: the factor's sampling sd is about 8 %
        assert scale.factor == pytest.approx(expected, rel=0.25)
        assert float(np.asarray(scale.scaled(obs).noise_var)) == pytest.approx(0.25 * scale.factor)


def _consistent_single_beams(rng, true_factor: float, sd_position: float) -> list[float]:
    """The factor over 1500 one-beam pings on a slope, truth drawn from the posterior."""
    slope, cov = np.array([0.05, 0.02]), np.eye(2) * sd_position**2
    points, weights = unscented_points(np.zeros(2), cov)
    scale, factors = ResidualScale.prior(0.98), []
    for _ in range(1500):
        truth = rng.multivariate_normal(np.zeros(2), cov)
        value = truth @ slope + rng.normal(0.0, np.sqrt(0.25 * true_factor))
        reads = PointReads((points @ slope)[:, None], weights, np.array([value]), np.array([0.25]))
        scale = scale.updated(reads, 0.0)
        factors.append(scale.factor)
    return factors[500:]


def test_pings_a_wide_posterior_explains_leave_the_residual_scale_alone(rng):
    # the position's spread explains 29 map units^2 of each innovation, the noise 1: such
    # pings say nothing of the noise (the per-ping clipped sum drove the factor to ~60)
    wide = _consistent_single_beams(rng, 4.0, 100.0)
    assert max(wide) < 1.5
    # a posterior narrower than the noise: the factor is found (sampling sd about 0.5)
    assert np.mean(_consistent_single_beams(rng, 4.0, 1.0)) == pytest.approx(4.0, rel=0.15)


def test_bad_nuisance_settings_are_config_errors():
    with pytest.raises(ConfigError, match="map_model"):
        check_map_model("pmf", "perfect")
    with pytest.raises(ConfigError, match="map_model"):
        parse_method_spec("pf:map_model=wrong")
    with pytest.raises(ConfigError, match="forgetting"):
        ResidualScale.prior(1.5)
    with pytest.raises(ConfigError, match="std"):
        CommonOffset.prior(-1.0, 0.0, 0.0)
    with pytest.raises(ConfigError, match="noise_forgetting"):
        NavigatorSettings(noise_forgetting=0.0)


def test_the_map_models_switch_their_parts_on():
    settings = NavigatorSettings.passive().for_map_model("imperfect")
    assert settings.depth_bias_std is None and settings.adaptive_noise
    assert settings.representation_error and settings.swath_modes
    adaptive = NavigatorSettings.passive().for_map_model("adaptive")
    assert adaptive.depth_bias_std == 0 and adaptive.adaptive_noise
    assert adaptive.representation_error and adaptive.swath_modes
    assert not NavigatorSettings().swath_modes
    assert NavigatorSettings().for_map_model("exact") == NavigatorSettings()
    told = NavigatorSettings(depth_bias_std=2.0).for_map_model("imperfect")
    assert told.depth_bias_std == 2.0


def _offset_mission(tmp_path, offset: float):
    from geofix.maps.io import save_grid
    from geofix.maps.synthetic import fractal_terrain
    from geofix.sim.scenario import scenario_from_dict

    grid = fractal_terrain((160, 160), 10.0, rng=np.random.default_rng(4), std=8.0, hurst=0.8)
    path = save_grid(grid, tmp_path / "seabed.nc")
    data = {
        "name": "offset-mission",
        "map": {"path": str(path), "kind": "depth"},
        "track": {
            "start_m": [500.0, 500.0],
            "heading_deg": 45.0,
            "speed_m_s": 2.0,
            "interval_s": 10.0,
            "samples": 40,
            "start_jitter_m": 50.0,
        },
        "sensor": {"type": "multibeam", "beams": 15, "swath_width_m": 100.0, "noise_std": 0.3},
        "ins": {
            "initial_error_m": [0.0, 0.0],
            "initial_error_std_m": 40.0,
            "velocity_error_m_s": 0.03,
        },
        "seabed": {"offset": offset},
        "trials": 6,
        "seed": 3,
    }
    return scenario_from_dict(data), grid


def test_the_imperfect_model_keeps_its_covariance_on_an_offset_map(tmp_path):
    """Readings 3 m deeper than the map: the exact model is lost with confidence."""
    from geofix.evaluate.runner import method_rng, run_trial
    from geofix.sim.simulate import simulate_trial

    scen, grid = _offset_mission(tmp_path, 3.0)
    nees = {"pf:particles=1500,map_model=exact": [], "pf:particles=1500,map_model=imperfect": []}
    errors = {spec: [] for spec in nees}
    for index in range(scen.trials):
        trial = simulate_trial(scen, grid, index)
        for spec in nees:
            result = run_trial(parse_method_spec(spec), trial, grid, method_rng(3, index, spec))
            e = result.estimate[-1] - trial.truth[-1]
            errors[spec].append(float(np.hypot(*e)))
            nees[spec].append(float(e @ np.linalg.solve(result.covariance, e)))
    exact, imperfect = nees
    assert np.median(nees[exact]) > 20.0  # the exact model: confident and wrong
    # 6 trials of a chi-square(2): the median is below 5 with probability 0.98
    assert np.median(nees[imperfect]) < 5.0
    assert max(errors[imperfect]) < 3 * 10.0 < np.median(errors[exact])


def _share_after(excess_std: float, layer_std: float, rng, pings: int = 200) -> float:
    """The representation share after ``pings`` 7-beam pings read at a known position."""
    from geofix.filters.nuisance import RepresentationShare

    grid = _ramp()
    share = RepresentationShare.prior(0.98)
    declared = np.full(7, 0.25)
    extra = np.full(7, layer_std**2)
    for _ in range(pings):
        obs = _ping(grid, (300.0, 300.0), 0.0, rng, 0.5)
        obs = Observation(
            obs.values + rng.normal(0.0, excess_std, 7) if excess_std else obs.values,
            obs.indicated,
            obs.heading,
            obs.offsets,
            declared + share.value * extra,
            0,
        )
        reads = read_at_points(grid, np.full(2, 300.0), np.eye(2) * 1e-6, obs)
        share = share.updated(reads, declared, extra, 0.0)
    return share.value


def test_the_representation_share_follows_what_the_innovations_support(rng):
    # a map that is the seabed: the layer (1 m) is not in the residuals, the share leaves it
    assert _share_after(0.0, 1.0, rng) < 0.2
    # residuals with the layer's 1 m in them: the share stays near one (about 50 pings of
    # 7 beams in its memory: a few tenths of spread)
    assert 0.6 < _share_after(1.0, 1.0, rng) < 1.5
    # twice the layer's error in the residuals: a share of about four
    assert 2.5 < _share_after(2.0, 1.0, rng) <= 4.0


def _multibeam_share_path(shares, rng, counted: float = 12.2) -> list[float]:
    """The share after each 61-beam ping whose residuals hold ``c`` of a 30 m^2 layer.

    Read at a known position (the five points agree): each beam's excess is
    ``c * 30`` m^2 beyond the declared 0.25 m^2; ``counted`` beams share one map error.
    """
    from geofix.filters.nuisance import PointReads, RepresentationShare

    beams, declared, layer = 61, 0.25, 30.0
    share = RepresentationShare.prior(0.98)
    path = []
    for c in shares:
        predicted = np.tile(rng.normal(0.0, 10.0, beams), (5, 1))
        values = predicted[0] + rng.normal(0.0, np.sqrt(declared + c * layer), beams)
        reads = PointReads(
            predicted, np.full(5, 0.2), values, np.full(beams, declared), np.ones(beams, bool)
        )
        variances = (np.full(beams, declared), np.full(beams, layer))
        share = share.updated(reads, *variances, 0.0, counted)
        path.append(share.value)
    return path


def test_a_few_quiet_pings_do_not_hold_the_share_down(rng):
    """Four pings whose residuals barely show the layer, then sixty that show half of it.

    Weighed at the share of the moment, the quiet pings (then the next ones too) would
    weigh thousands of times the rest once the share is near zero, and the sixty pings
    leave it near 0.3 (0.26-0.31 over eight seeds); weighed no sharper than the prior's
    share and counted once per independent map error across the swath, it ends near one
    half (0.46-0.50 over the same seeds).
    """
    path = _multibeam_share_path([0.02] * 4 + [0.5] * 60, rng)
    assert 0.4 < path[-1] < 0.65
    # one ping of 61 beams is worth about five independent map errors: it moves the
    # share, it does not set it (weighed beam by beam, one such ping took it to 0.09)
    assert path[0] > 0.3
