"""Generated bad input (hypothesis): scenarios and map files never crash geofix.

Every generated input either works or raises a :class:`~geofix.errors.GeofixError` whose
message is one line: never another exception (which the command line would report as an
internal error), never a hang, never an allocation beyond the memory budget (set low
here, so that sizes are refused rather than allocated). Scenarios are mutations of a
valid small mission (1 to 3 keys replaced by hostile values: NaN, inf, 1e300, negative,
huge integers, text with markup, lists, nothing); each is validated and, when valid, its
map prepared, its trial 0 simulated and TERCOM run on it. Map files are small netCDF
files of generated shapes, types, coordinates and values, or plain garbage bytes.

The examples are derandomised (fixed seeds) and counted in
``docs/RESULTS.md`` by ``benchmarks/sections/reliability.py``.
"""

from __future__ import annotations

import time
from functools import cache

import numpy as np
import pytest
import xarray as xr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from _reliability import MAX_SECONDS, Outcome, record
from conftest import small_mission_data
from geofix.errors import GeofixError, MemoryBudgetError

pytestmark = pytest.mark.slow

SCENARIO_EXAMPLES = 800
MAP_EXAMPLES = 260
FUZZ_BUDGET = "64MB"

_FUZZ_SETTINGS = {
    "deadline": None,
    "derandomize": True,
    "database": None,
    "suppress_health_check": [HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
}

KEYS = {
    "": ["name", "map", "track", "sensor", "ins", "dvl", "trials", "seed", "extra_key"],
    "map": ["path", "variable", "kind", "region", "resample_m"],
    "track": [
        "start_cell",
        "start_m",
        "start_jitter_m",
        "heading_deg",
        "speed_m_s",
        "interval_s",
        "samples",
        "legs",
        "turn_std_deg",
    ],
    "sensor": [
        "type",
        "noise_std",
        "beams",
        "swath_width_m",
        "swath_angle_deg",
        "altitude_m",
        "edge_noise_factor",
        "lag_s",
        "map_error_std",
    ],
    "ins": [
        "initial_error_m",
        "initial_error_std_m",
        "velocity_error_m_s",
        "heading_error_deg",
        "gyro_bias_deg_h",
        "gyro_noise_deg_rt_h",
        "accel_bias_ug",
        "accel_noise_ug_rt_hz",
        "schuler",
        "prior_sigma_m",
    ],
    "dvl": ["noise_std_m_s", "bias_m_s"],
}
SPECIAL_NUMBERS = [0, 1, -1, 2, 0.5, 1e-300, 1e6, 1e9, -1e9, 1e12, 1e300, -1e300]
SPECIAL_TEXT = ["", "[red]x", "[/b]", "multibeam", "gravimeter", "depth", "gravity", "z"]
MAP_PATHS = ["builtin:mb_1km", "builtin:grav_1km", "builtin:nosuch", "none.nc", "[a, b].nc"]

finite_or_not = st.floats(allow_nan=True, allow_infinity=True)
values = st.one_of(
    st.sampled_from(SPECIAL_NUMBERS),
    finite_or_not,
    st.integers(-(10**15), 10**15),
    st.sampled_from(SPECIAL_TEXT),
    st.text(max_size=8),
    st.none(),
    st.booleans(),
    st.lists(st.one_of(st.sampled_from(SPECIAL_NUMBERS), finite_or_not), max_size=5),
    st.dictionaries(st.sampled_from(["a", "path", "type"]), st.integers(-3, 3), max_size=2),
)


@st.composite
def mutation(draw):
    block = draw(st.sampled_from(list(KEYS)))
    key = draw(st.sampled_from(KEYS[block]))
    if (block, key) == ("map", "path"):
        value = draw(st.one_of(st.sampled_from(MAP_PATHS), values))
    else:
        value = draw(values)
    return block, key, value, draw(st.booleans()) and draw(st.booleans())  # 1 in 4 deletes


def _mutated(mutations) -> dict:
    data = small_mission_data("fuzz", trials=1)
    data["map"] = dict(data["map"])
    for block, key, value, delete in mutations:
        target = data
        if block:
            if not isinstance(data.get(block), dict):
                data[block] = {}
            target = data[block]
        if delete:
            target.pop(key, None)
        else:
            target[key] = value
    return data


@cache
def _prepared(map_json: str):
    """Prepared maps, cached by their spec (most mutations keep the 1 km grid)."""
    import json

    from geofix.sim.scenario import MapSpec
    from geofix.sim.simulate import prepare_map

    spec = MapSpec(**json.loads(map_json))
    stub = small_mission_data("fuzz")
    stub["map"] = spec.model_dump()
    from geofix.sim.scenario import scenario_from_dict

    return prepare_map(scenario_from_dict(stub))


def _exercise_scenario(data: dict) -> str:
    """Validate, prepare, simulate trial 0 and run TERCOM; ``"ok"`` or raises."""
    from geofix.evaluate.campaign import check_methods_fit
    from geofix.evaluate.runner import method_rng, run_trial
    from geofix.methods import parse_method_spec
    from geofix.sim.scenario import scenario_from_dict
    from geofix.sim.simulate import simulate_trial

    scenario = scenario_from_dict(data, source="fuzz.yaml")
    grid = _prepared(scenario.map.model_dump_json())
    trial = simulate_trial(scenario, grid, 0)
    method = parse_method_spec("tercom")
    check_methods_fit({"tercom": method}, trial)
    run_trial(method, trial, grid, method_rng(scenario.seed, 0, "tercom"))
    return "ok"


def _judge(case: str, suite: str, fn) -> Outcome:
    """Run ``fn``; a GeofixError is a clean error (one line), anything else a crash."""
    start = time.perf_counter()
    crash, message, code = False, "", 0
    try:
        fn()
    except MemoryBudgetError as exc:
        message, code = f"error: {exc} [memory budget]", 2
    except GeofixError as exc:
        message, code = f"error: {exc}", 2
    except Exception as exc:  # the bug this suite hunts
        crash, message, code = True, f"Traceback: {type(exc).__name__}: {exc}", 1
    outcome = Outcome(case[:300], code, message, time.perf_counter() - start, crash, suite=suite)
    record(outcome)
    return outcome


def _assert_clean(outcome: Outcome) -> None:
    assert not outcome.traceback, (outcome.case, outcome.output)
    assert "\n" not in outcome.output.strip(), outcome.output
    assert len(outcome.output) < 600, outcome.output
    assert outcome.seconds < MAX_SECONDS, (outcome.case, outcome.seconds)


@pytest.fixture
def low_budget(monkeypatch):
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", FUZZ_BUDGET)


@settings(max_examples=SCENARIO_EXAMPLES, **_FUZZ_SETTINGS)
@given(st.lists(mutation(), min_size=1, max_size=3))
def test_fuzzed_scenarios_never_crash(low_budget, mutations):
    data = _mutated(mutations)
    outcome = _judge(repr(mutations), "fuzz-scenario", lambda: _exercise_scenario(data))
    _assert_clean(outcome)


# ---------------------------------------------------------------------- map files
dims_names = st.sampled_from([("y", "x"), ("lat", "lon"), ("x", "y"), ("a", "b"), ("y", "x", "t")])
dtypes = st.sampled_from(["float64", "float32", "int16", "uint8", "str", "bool"])
cells = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32), st.sampled_from([0.0]))


@st.composite
def map_files(draw):
    dims = draw(dims_names)
    shape = tuple(draw(st.integers(1, 7)) for _ in dims)
    dtype = draw(dtypes)
    flat = draw(st.lists(cells, min_size=int(np.prod(shape)), max_size=int(np.prod(shape))))
    values = np.asarray(flat, dtype=float).reshape(shape)
    if dtype == "str":
        values = values.astype(str)
    elif dtype != "float64" and dtype != "float32":
        values = np.nan_to_num(values, nan=0, posinf=0, neginf=0).clip(-100, 100).astype(dtype)
    coords = {}
    for name, n in zip(dims, shape, strict=True):
        start = draw(st.sampled_from([0.0, -180.0, 10.0, 1e12]))
        step = draw(st.sampled_from([1.0, 0.01, -1.0, 0.0, 1000.0]))
        coords[name] = start + step * np.arange(n)
    units = draw(st.sampled_from([None, "m", "degrees_east", "mGal"]))
    return {
        "dims": dims,
        "values": values,
        "coords": coords,
        "units": units,
        "variable": draw(st.sampled_from([None, "z", "nosuch"])),
        "resample_m": draw(st.sampled_from([None, 1.0, 1e-6, 5000.0])),
        "garbage": draw(st.sampled_from([None, None, None, b"", b"CDF\x01", b"\x89HDF\r\n"])),
    }


def _write_map(path, spec) -> None:
    if spec["garbage"] is not None:
        path.write_bytes(spec["garbage"])
        return
    da = xr.DataArray(spec["values"], dims=spec["dims"], coords=spec["coords"], name="z")
    if spec["units"]:
        for name in spec["dims"][:2]:
            da[name].attrs["units"] = spec["units"]
    da.to_dataset().to_netcdf(path)


def _load_map(path, spec) -> str:
    from geofix.maps.io import load_grid

    load_grid(path, variable=spec["variable"], resample_m=spec["resample_m"])
    return "ok"


@settings(max_examples=MAP_EXAMPLES, **_FUZZ_SETTINGS)
@given(map_files())
def test_fuzzed_map_files_never_crash(low_budget, tmp_path_factory, spec):
    path = tmp_path_factory.mktemp("fuzzmap") / "map.nc"
    _write_map(path, spec)
    values = spec["values"]
    case = f"{spec['dims']} {values.shape} {values.dtype} garbage={spec['garbage']!r}"
    outcome = _judge(case, "fuzz-map", lambda: _load_map(path, spec))
    _assert_clean(outcome)
