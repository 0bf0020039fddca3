"""Shared fixtures: seeded generators, a small synthetic map and a small real map."""

from __future__ import annotations

import numpy as np
import pytest

from geofix.maps import Grid, fractal_terrain, load_grid

# Azores central group (Faial, Pico, Sao Jorge): a 200 km x 200 km box, lon/lat degrees.
AZORES_SMALL_REGION = (-29.45, -27.15, 37.7, 39.5)


@pytest.fixture
def rng() -> np.random.Generator:
    """A fresh seeded generator for each test (seed 12345)."""
    return np.random.default_rng(12345)


@pytest.fixture
def rng_factory():
    """Make independent seeded generators: ``rng_factory(seed)``."""
    return lambda seed=0: np.random.default_rng(seed)


@pytest.fixture(scope="session")
def synthetic_grid() -> Grid:
    """A 128 x 128 fractal seabed, 10 m cells, depth std 5 m around -100 m (seed 0)."""
    return fractal_terrain((128, 128), 10.0, rng=np.random.default_rng(0), name="synthetic")


@pytest.fixture(scope="session")
def azores_small() -> Grid:
    """About 200 x 200 cells of the bundled Azores map, projected to 1 km cells."""
    return load_grid(
        "builtin:azores", region=AZORES_SMALL_REGION, resample_m=1000.0, name="azores_small"
    )


def small_mission_data(name: str, **changes) -> dict:
    """A 20-sample single-beam mission on the bundled 1 km grid, as a scenario mapping.

    ``changes`` replace top-level keys; ``track`` updates only the keys it names.
    """
    data = {
        "name": name,
        "map": {"path": "builtin:mb_1km"},
        "track": {
            "start_cell": [60, 60],
            "heading_deg": 45,
            "speed_m_s": 10,
            "interval_s": 60,
            "samples": 20,
        },
        "sensor": {"type": "singlebeam", "noise_std": 2.0},
        "ins": {"initial_error_m": [1500, -1000], "velocity_error_m_s": 0.05},
        "trials": 3,
        "seed": 3,
    }
    data["track"].update(changes.pop("track", {}))
    data.update(changes)
    return data


def gravity_dvl_mission_data(name: str, **changes) -> dict:
    """Source 003's mission, shortened: Gulf of Alaska gravity at 100 m, 50 samples 20 s
    apart, a drifting free INS aided by a DVL; as a scenario mapping.

    ``changes`` replace top-level keys; ``sensor`` updates only the keys it names.
    """
    data = {
        "name": name,
        "map": {
            "path": "builtin:alaska_gravity",
            "kind": "gravity",
            "region": [-138, -136, 53, 55],
            "resample_m": 100,
        },
        "track": {
            "start_cell": [250, 1120],
            "heading_deg": 70,
            "speed_m_s": 10,
            "interval_s": 20,
            "samples": 50,
        },
        "sensor": {"type": "gravimeter", "noise_std": 1.0},
        "ins": {
            "initial_error_m": [300, 300],
            "velocity_error_m_s": 0.04,
            "heading_error_deg": 0.05,
            "accel_bias_ug": 101.97,
        },
        "dvl": {"noise_std_m_s": 0.02, "bias_m_s": 0.02},
        "trials": 4,
        "seed": 3,
    }
    data["sensor"].update(changes.pop("sensor", {}))
    data.update(changes)
    return data


def gravity_map_error_mission(name: str, seabed: dict, seed: int):
    """The ``imperfect_gravity`` benchmark's mission, held in: 110 readings 200 m apart,
    DVL-aided, 500 m initial spread, on a prior map that differs from the field read by
    ``seabed``; ``(scenario, prepared map)``, 12 trials.
    """
    from geofix.sim.scenario import scenario_from_dict
    from geofix.sim.simulate import prepare_map

    data = gravity_dvl_mission_data(
        name,
        track={
            "start_cell": [250, 1120],
            "heading_deg": 70,
            "speed_m_s": 10,
            "interval_s": 20,
            "samples": 110,
            "legs": 1,
            "start_jitter_m": 50,
        },
        ins={
            "mode": "dvl",
            "initial_error_m": [0, 0],
            "initial_error_std_m": 500,
            "heading_error_deg": 0.05,
            "gyro_bias_deg_h": 0.01,
        },
        dvl={"noise_std_m_s": 0.01, "bias_m_s": 0.005, "scale_error": 0.002},
        seabed=seabed,
        trials=12,
        seed=seed,
    )
    scen = scenario_from_dict(data)
    return scen, prepare_map(scen)


def trial_ends(scen, grid, spec: str, indices) -> list[tuple[float, float]]:
    """``(end error m, end NEES)`` of method ``spec`` on each trial of ``indices``.

    Every spec runs on the random stream of ``pmf`` at each trial, so two specs differ
    by their settings alone.
    """
    from geofix.evaluate.runner import method_rng, run_trial
    from geofix.methods import parse_method_spec
    from geofix.sim.simulate import simulate_trial

    out = []
    for index in indices:
        trial = simulate_trial(scen, grid, index)
        rng = method_rng(scen.seed, index, "pmf")
        result = run_trial(parse_method_spec(spec), trial, grid, rng)
        e = result.estimate[-1] - trial.truth[-1]
        out.append((float(np.hypot(*e)), float(e @ np.linalg.solve(result.covariance, e))))
    return out


@pytest.fixture
def small_mission():
    """Factory of :func:`small_mission_data` scenarios (validated)."""
    from geofix.sim.scenario import scenario_from_dict

    return lambda name, **changes: scenario_from_dict(small_mission_data(name, **changes))


def northward_trial(grid, n: int, sigma0: float, start_error, noise: float, rng):
    """A northward single-beam track through the middle of ``grid``, no drift (a Trial).

    ``n`` samples 50 m apart from 30 % of the map's height, readings of ``grid`` with
    white noise ``noise``, the indicated track ``start_error`` off, prior sigma ``sigma0``.
    """
    from geofix.sim.trial import Trial

    ny, nx = grid.values.shape
    x = grid.x0 + 0.5 * (nx - 1) * grid.dx
    y = grid.y0 + 0.3 * (ny - 1) * grid.dy + 50.0 * np.arange(n)
    truth = np.column_stack([np.full(n, x), y])
    measured = grid.sample(truth[:, 0], truth[:, 1])[:, None] + noise * rng.standard_normal((n, 1))
    return Trial(
        truth=truth,
        true_heading=np.zeros(n),
        indicated=truth + np.asarray(start_error, float),
        indicated_heading=np.zeros(n),
        times=10.0 * np.arange(n),
        measured=measured,
        offsets=np.zeros((1, 2)),
        sigma_position=np.full(n, sigma0),
        noise_std=noise,
    )
