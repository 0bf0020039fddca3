"""The plain filter loop: the filter, its state and the measurement model stepped together."""

from dataclasses import dataclass, replace

import numpy as np
import pytest

from geofix.filters.base import Observation, RecursiveFilter
from geofix.filters.loop import FilterSettings, FilterStepper


@dataclass(frozen=True)
class _State:
    mean: np.ndarray


class _Shift(RecursiveFilter):
    """A filter whose update moves its mean by the first reading (NaN poisons it)."""

    name = "shift"

    def initialize(self, problem, rng):
        return _State(np.asarray(problem.indicated[0], dtype=float))

    def predict(self, state, motion, rng):
        return _State(state.mean + motion.displacement)

    def update(self, state, obs, grid, rng):
        return _State(state.mean + float(obs.values[0]))

    def estimate(self, state):
        return state.mean, np.eye(2)


def _ping(value: float) -> Observation:
    return Observation(np.array([value]), np.zeros(2), 0.0, np.zeros((1, 2)), 1.0, 0)


@pytest.fixture
def stepper(synthetic_grid):
    from geofix.navigator import start_problem

    loop = FilterStepper(_Shift(), synthetic_grid)
    loop.start(start_problem(synthetic_grid, 0.0, (640.0, 640.0), 50.0, 0.0))
    return loop


def test_a_ping_is_folded_in(stepper):
    mean, cov = stepper.update(_ping(3.0), 1.0)
    np.testing.assert_array_equal(mean, [643.0, 643.0])
    np.testing.assert_array_equal(cov, np.eye(2))


def test_a_step_that_leaves_a_non_finite_estimate_is_refused(stepper):
    stepper.update(_ping(1e308), 1.0)  # still finite
    before = stepper.state
    with np.errstate(over="ignore"):
        mean, _ = stepper.update(_ping(1e308), 2.0)  # would overflow: the state is kept
    assert stepper.state is before and np.isfinite(mean).all()


def test_a_ping_without_a_valid_beam_leaves_the_state(stepper):
    before = stepper.state
    stepper.update(_ping(np.nan), 1.0)
    assert stepper.state is before


def test_the_map_model_switches_the_nuisance_on_once(synthetic_grid):
    imperfect = FilterSettings().for_map_model("imperfect")
    assert imperfect.representation_error and imperfect.adaptive_noise
    assert imperfect.depth_bias_std is None
    assert imperfect.for_map_model("imperfect") == imperfect
    assert FilterSettings().for_map_model("exact") == FilterSettings()
    bicubic = FilterStepper(_Shift(), synthetic_grid, replace(imperfect, interpolation="bicubic"))
    assert bicubic.grid.interpolation == "bicubic"


class _Follow(RecursiveFilter):
    """A filter that follows the INS and keeps each ping's variance as it was handed."""

    name = "follow"

    def __init__(self):
        self.variances: list[np.ndarray] = []

    def initialize(self, problem, rng):
        return _State(np.asarray(problem.indicated[0], dtype=float))

    def predict(self, state, motion, rng):
        return _State(state.mean + motion.displacement)

    def update(self, state, obs, grid, rng):
        self.variances.append(np.asarray(obs.noise_var, dtype=float).copy())
        return state

    def estimate(self, state):
        return state.mean, 25.0 * np.eye(2)


def _variances_along_a_track(grid, noise_std: float, rng) -> list[np.ndarray]:
    """Single beams told 1 m, read on the map itself with ``noise_std`` of white noise."""
    from geofix.filters.base import Motion
    from geofix.navigator import start_problem

    follow = _Follow()
    settings = replace(FilterSettings().for_map_model("imperfect"), adaptive_noise=False)
    loop = FilterStepper(follow, grid, settings)
    start = np.array([100.0, 640.0])
    loop.start(start_problem(grid, 0.0, tuple(start), 5.0, np.pi / 2))
    step = np.array([2.0, 0.0])  # m per ping: 20 pings per 4 cells of 10 m
    for k in range(400):
        here = start + k * step
        if k:
            loop.predict(Motion(step, 1.0, 1e-6))
        reading = float(grid.sample(*here)) + rng.normal(0.0, noise_std)
        loop.update(Observation(np.array([reading]), here, np.pi / 2, np.zeros((1, 2)), 1.0, k), k)
    return follow.variances


def test_a_beam_takes_the_readings_white_scatter_where_it_dwarfs_the_declared_noise(
    synthetic_grid, monkeypatch
):
    from geofix.filters import loop as loop_module

    # told 1 m^2, the readings scatter by 10 m about the map: once the roughness window
    # has filled, every ping weighs at least about half that scatter (over 4 seeds the
    # least was 89-101 m^2), where without the floor some pings weigh the declared 1 m^2
    noisy = np.concatenate(_variances_along_a_track(synthetic_grid, 10.0, _seeded(0)))
    quiet = np.concatenate(_variances_along_a_track(synthetic_grid, 1.0, _seeded(1)))
    monkeypatch.setattr(loop_module, "WHITE_EXCESS", np.inf)
    unfloored = np.concatenate(_variances_along_a_track(synthetic_grid, 10.0, _seeded(0)))
    assert noisy[100:].min() > 50.0
    assert unfloored[100:].min() < 5.0
    # scattering as declared, no beam is raised
    quiet_unfloored = _variances_along_a_track(synthetic_grid, 1.0, _seeded(1))
    np.testing.assert_array_equal(quiet, np.concatenate(quiet_unfloored))


def _seeded(seed: int) -> np.random.Generator:
    return np.random.default_rng(seed)


def test_on_a_map_that_is_the_seabed_no_beam_takes_the_white_scatter(monkeypatch, tmp_path):
    from geofix.evaluate.campaign import run_campaign
    from geofix.filters import loop as loop_module
    from geofix.sim.scenario import builtin_scenario_path, load_scenario

    seen = {"pings": 0, "filled": 0, "raised": 0}
    floored = loop_module.FilterStepper._white_floored

    def spy(self, declared):
        out = floored(self, declared)
        seen["pings"] += 1
        seen["filled"] += self.roughness.den > 0
        seen["raised"] += out is not declared
        return out

    monkeypatch.setattr(loop_module.FilterStepper, "_white_floored", spy)
    # the demo's single beam reads its 1 km map every 120 m: the roughness window fills, and
    # the white part it measures is the sensor's noise (at most 1.6 times the declared
    # variance over 8 trials of pmf, pf and mpf), below WHITE_EXCESS
    demo = load_scenario(builtin_scenario_path("azores_demo"))
    run_campaign(demo, ["pmf", "pf"], trials=2, jobs=1, out_dir=tmp_path)
    assert seen["filled"] > 0.5 * seen["pings"]
    assert seen["raised"] == 0


def test_a_method_s_own_offset_walk_replaces_the_settings_walk(synthetic_grid):
    from geofix.errors import ConfigError
    from geofix.filters.pf import Pf
    from geofix.filters.pmf import Pmf

    declared = FilterSettings(depth_bias_walk=5e-3)
    still = FilterStepper(Pmf(offset_walk=0.0), synthetic_grid, declared)
    assert still.settings.depth_bias_walk == 0.0 and still.offset.walk == 0.0
    assert FilterStepper(Pf(offset_walk=2e-4), synthetic_grid, declared).offset.walk == 2e-4
    assert FilterStepper(Pmf(), synthetic_grid, declared).offset.walk == 5e-3
    for bad in (-1e-3, float("inf")):
        with pytest.raises(ConfigError, match="offset_walk"):
            Pf(offset_walk=bad)
