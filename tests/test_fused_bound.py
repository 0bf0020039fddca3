"""The Cramér–Rao bound of several fields: their information adds."""

from __future__ import annotations

import dataclasses

import numpy as np

from geofix.evaluate.crlb import (
    field_information,
    imperfect_map_crlb,
    trial_crlb,
    trial_information,
)
from geofix.maps.grid import Grid
from geofix.sim import scenario_from_dict, simulate_trial
from geofix.sim import simulate as simulate_module

CELL = 100.0
SHAPE = (90, 90)


def plane(a: float, b: float, kind: str, units: str) -> Grid:
    """``a x + b y`` (map units per metre) on one 100 m grid."""
    y, x = np.indices(SHAPE) * CELL
    return Grid(a * x + b * y - 500.0, 0.0, 0.0, CELL, CELL, kind=kind, units=units)


DEPTH = plane(0.05, 0.01, "depth", "m")
GRAVITY = plane(-0.002, 0.006, "gravity", "mGal")


def fused_trial(monkeypatch):
    monkeypatch.setattr(simulate_module, "prepare_field_maps", lambda scen: (GRAVITY,))
    scen = scenario_from_dict(
        {
            "name": "fused-planes",
            "sensors": [
                {"map": {"path": "d.nc", "kind": "depth"},
                 "sensor": {"type": "singlebeam", "noise_std": 3.0}},
                {"map": {"path": "g.nc", "kind": "gravity"},
                 "sensor": {"type": "gravimeter", "noise_std": 0.5}},
            ],
            "track": {"start_m": [1500.0, 2000.0], "heading_deg": 60.0, "speed_m_s": 4.0,
                      "interval_s": 30.0, "samples": 40},
            "ins": {"initial_error_m": [0, 0], "initial_error_std_m": 300.0,
                    "velocity_error_m_s": 0.02},
        }
    )  # fmt: skip
    return simulate_trial(scen, DEPTH, 0)


def gravity_alone(trial):
    """The same mission with the gravimeter as its only field."""
    (field,) = trial.fields
    return dataclasses.replace(
        trial,
        measured=field.measured,
        offsets=field.offsets,
        noise_std=field.noise_std,
        beam_noise_std=field.beam_noise_std,
        sensor=field.sensor,
        fields=(),
    )


def test_on_planes_the_fused_information_is_the_sum_of_the_fields(monkeypatch):
    trial = fused_trial(monkeypatch)
    depth = trial_information(dataclasses.replace(trial, fields=()), DEPTH)
    gravity = trial_information(gravity_alone(trial), GRAVITY)
    fused = trial_information(trial, DEPTH)
    np.testing.assert_allclose(fused, depth + gravity, rtol=1e-12, atol=0)
    # each plane's sample information is its gradient's outer product over its variance
    g = np.array([-0.002, 0.006])
    np.testing.assert_allclose(gravity[7], np.outer(g, g) / 0.5**2, rtol=1e-9)
    np.testing.assert_allclose(field_information(trial, trial.fields[0]), gravity, rtol=1e-12)
    assert np.array_equal(trial_information(trial, DEPTH, fields=False), depth)


def test_on_planes_the_fused_bound_is_below_each_single_field_bound(monkeypatch):
    trial = fused_trial(monkeypatch)
    fused = trial_crlb(trial, DEPTH)
    depth = trial_crlb(dataclasses.replace(trial, fields=()), DEPTH)
    gravity = trial_crlb(gravity_alone(trial), GRAVITY)
    assert fused.recursive_var_m2 < min(depth.recursive_var_m2, gravity.recursive_var_m2)
    # one plane along a straight track tells one direction only: no rigid fix alone
    assert np.isinf(depth.batch_var_m2) and np.isinf(gravity.batch_var_m2)
    j = trial_information(trial, DEPTH).sum(axis=0)
    assert np.isclose(fused.batch_var_m2, np.trace(np.linalg.inv(j)), rtol=1e-9)


def test_the_prior_map_bound_adds_the_fields_too(monkeypatch):
    trial = fused_trial(monkeypatch)
    fused = imperfect_map_crlb(trial, DEPTH, offset_var=0.0)
    assert np.isclose(fused.recursive_var_m2, trial_crlb(trial, DEPTH).recursive_var_m2)
    alone = imperfect_map_crlb(dataclasses.replace(trial, fields=()), DEPTH, offset_var=0.0)
    assert fused.recursive_var_m2 < alone.recursive_var_m2
