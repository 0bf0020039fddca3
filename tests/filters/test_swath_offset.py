"""The common offset carried per hypothesis on multibeam pings (``offset_per_hypothesis``)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import small_mission_data
from geofix.errors import ConfigError
from geofix.filters.base import motions, observations
from geofix.filters.loop import FilterSettings, FilterStepper
from geofix.filters.nuisance import (
    GRAVITY_FAST_OFFSET_WALK,
    SWATH_FAST_OFFSET_WALK,
    default_fast_offset_walk,
)
from geofix.maps.grid import Grid
from geofix.methods import parse_method_spec

OFFSET_M = 20.0  # the readings against the map, metres


@pytest.fixture(scope="module")
def offset_swath():
    """A 21-beam multibeam mission on the bundled 1 km grid, the readings 20 m off the map."""
    from geofix.sim.scenario import scenario_from_dict
    from geofix.sim.simulate import prepare_map, simulate_trial

    data = small_mission_data(
        "offset-swath",
        sensor={"type": "multibeam", "beams": 21, "swath_width_m": 4000, "noise_std": 2.0},
        track={"samples": 30},
        ins={"initial_error_m": [0, 0], "initial_error_std_m": 800, "velocity_error_m_s": 0.05},
        seabed={"offset": OFFSET_M},
        trials=1,
        seed=11,
    )
    scen = scenario_from_dict(data)
    grid = prepare_map(scen)
    return grid, simulate_trial(scen, grid, 0)


def _run(spec: str, grid, trial):
    """The stepper after the whole mission, and its end error (metres)."""
    problem = trial.problem(grid)
    stepper = FilterStepper(
        parse_method_spec(spec), grid, FilterSettings(), np.random.default_rng(4)
    )
    stepper.start(problem)
    steps, pings = motions(problem), observations(problem)
    for k in range(problem.n):
        if k:
            stepper.predict(steps[k - 1])
        mean, _ = stepper.update(pings[k], float(problem.times[k]))
    return stepper, float(np.hypot(*(mean - trial.truth[-1])))


@pytest.mark.parametrize("name", ["pmf", "mpf:particles=2000"])
def test_a_swath_carried_per_hypothesis_learns_the_level_the_common_offset_forgets(
    offset_swath, name
):
    grid, trial = offset_swath
    own, own_error = _run(name, grid, trial)
    sep = "," if ":" in name else ":"
    common, common_error = _run(f"{name}{sep}offset_per_hypothesis=false", grid, trial)
    # the common offset marginalises each multibeam ping over its prior: it keeps none
    assert not common.carries_offset and common.offset.mean == 0.0
    # per hypothesis (the default), the offset the posterior holds is the readings' 20 m,
    # within 3 sigma
    assert own.carries_offset
    assert abs(own.offset.mean - OFFSET_M) < 3.0 * np.sqrt(own.offset.var)
    assert np.sqrt(own.offset.var) < 0.25 * OFFSET_M
    # and the position no worse for it (a 1 km map cell)
    assert own_error < max(2.0 * common_error, 0.1 * grid.cell_size)


def test_the_setting_is_read_as_a_bool_and_refused_otherwise():
    assert parse_method_spec("pmf:offset_per_hypothesis=true").offset_per_hypothesis is True
    assert parse_method_spec("pf:offset_per_hypothesis=no").offset_per_hypothesis is False
    assert parse_method_spec("mpf").offset_per_hypothesis is None
    for bad in ("2", "maybe"):
        with pytest.raises(ConfigError, match="offset_per_hypothesis must be true or false"):
            parse_method_spec(f"mpf:offset_per_hypothesis={bad}")


def test_a_method_s_own_setting_is_above_the_stepper_s(offset_swath):
    grid, _ = offset_swath
    for value in (True, False):
        spec = f"pmf:offset_per_hypothesis={str(value).lower()}"
        for settings in (FilterSettings(), FilterSettings(offset_per_hypothesis=not value)):
            stepper = FilterStepper(parse_method_spec(spec), grid, settings)
            assert stepper.settings.offset_per_hypothesis is value
    stepper = FilterStepper(
        parse_method_spec("pmf"), grid, FilterSettings(offset_per_hypothesis=True)
    )
    assert stepper.settings.offset_per_hypothesis is True


def test_the_faster_walk_of_a_depth_map_is_the_swath_s():
    values = np.zeros((8, 8))
    depth = Grid(values=values, x0=0.0, y0=0.0, dx=10.0, dy=10.0)
    gravity = Grid(values=values, x0=0.0, y0=0.0, dx=10.0, dy=10.0, kind="gravity")
    magnetic = Grid(values=values, x0=0.0, y0=0.0, dx=10.0, dy=10.0, kind="magnetic")
    assert default_fast_offset_walk(depth) == 0.0  # a profile
    assert default_fast_offset_walk(depth, 2) == 0.0
    assert default_fast_offset_walk(depth, 3) == SWATH_FAST_OFFSET_WALK == 10.0
    assert default_fast_offset_walk(gravity) == default_fast_offset_walk(gravity, 61)
    assert default_fast_offset_walk(gravity) == GRAVITY_FAST_OFFSET_WALK
    assert default_fast_offset_walk(magnetic, 61) == 0.0
