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
