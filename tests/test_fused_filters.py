"""Recursive filters over several fields: the update adds every field's log-likelihood."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from geofix.evaluate.runner import method_rng, run_trial
from geofix.filters import _grid_ops as ops
from geofix.filters.base import observations
from geofix.maps.grid import Grid
from geofix.methods import parse_method_spec
from geofix.sim import scenario_from_dict, simulate_trial
from geofix.sim import simulate as simulate_module

CELL = 100.0
SHAPE = (110, 110)


def across_x() -> Grid:
    """A depth field that changes along x only: it tells nothing of y."""
    _, x = np.indices(SHAPE) * CELL
    return Grid(-2000.0 + 60.0 * np.sin(x / 600.0), 0.0, 0.0, CELL, CELL, kind="depth")


def across_y() -> Grid:
    """A gravity field that changes along y only: it tells nothing of x."""
    y, _ = np.indices(SHAPE) * CELL
    values = 8.0 * np.sin(y / 700.0)
    return Grid(values, 0.0, 0.0, CELL, CELL, kind="gravity", units="mGal")


def scenario(kinds: tuple[str, ...], monkeypatch) -> object:
    grids = {"depth": across_x(), "gravity": across_y()}
    sensors = {
        "depth": {"map": {"path": "depth.nc", "kind": "depth"},
                  "sensor": {"type": "singlebeam", "noise_std": 2.0}},
        "gravity": {"map": {"path": "gravity.nc", "kind": "gravity"},
                    "sensor": {"type": "gravimeter", "noise_std": 0.3}},
    }  # fmt: skip
    monkeypatch.setattr(
        simulate_module,
        "prepare_field_maps",
        lambda scen: tuple(grids[f.map.kind] for f in scen.fields[1:]),
    )
    scen = scenario_from_dict(
        {
            "name": "fused-planes",
            "sensors": [sensors[k] for k in kinds],
            "track": {
                "start_m": [3000.0, 3000.0],
                "heading_deg": 45.0,
                "speed_m_s": 5.0,
                "interval_s": 20.0,
                "samples": 50,
            },
            "ins": {
                "initial_error_m": [0, 0],
                "initial_error_std_m": 400.0,
                "velocity_error_m_s": 0.01,
            },
            "trials": 4,
            "seed": 8,
        }
    )
    return scen, grids[kinds[0]]


@pytest.mark.parametrize("spec", ["pmf", "pf", "mpf", "pmf:model=errstate"])
def test_two_fields_fix_what_neither_fixes_alone(spec, monkeypatch):
    """Each plane alone leaves one axis open (flagged ambiguous); both close it."""
    ends, flagged = {}, {}
    for kinds in (("depth",), ("gravity",), ("depth", "gravity")):
        scen, grid = scenario(kinds, monkeypatch)
        errors, flags = [], []
        for i in range(2):
            trial = simulate_trial(scen, grid, i)
            result = run_trial(parse_method_spec(spec), trial, grid, method_rng(8, i, spec))
            errors.append(result.error[-1])
            flags.append(result.ambiguous)
        ends[kinds] = float(np.sqrt(np.mean(np.square(errors))))
        flagged[kinds] = flags
    # where each single field is flagged ambiguous, the fused fix is not
    assert all(flagged[("depth",)]) and all(flagged[("gravity",)]), flagged
    assert not any(flagged[("depth", "gravity")]), flagged
    fused = ends[("depth", "gravity")]
    assert fused < 40.0, ends
    assert fused < 0.5 * min(ends[("depth",)], ends[("gravity",)]), ends


def test_sitan_uses_the_primary_field_only(monkeypatch):
    scen, grid = scenario(("depth", "gravity"), monkeypatch)
    trial = simulate_trial(scen, grid, 0)
    alone = dataclasses.replace(trial, fields=())
    method = parse_method_spec("sitan")
    a = run_trial(method, trial, grid, method_rng(8, 0, "sitan"))
    b = run_trial(method, alone, grid, method_rng(8, 0, "sitan"))
    assert np.array_equal(a.estimate, b.estimate)


def test_a_pmf_update_with_a_field_is_the_two_updates_in_turn(monkeypatch):
    scen, grid = scenario(("depth", "gravity"), monkeypatch)
    trial = simulate_trial(scen, grid, 0)
    problem = trial.problem(grid)
    pmf = parse_method_spec("pmf:map_model=exact")
    rng = np.random.default_rng(0)
    state = pmf.initialize(problem, rng)
    depth_obs = observations(problem)[3]
    field = problem.fields[0]
    gravity_obs = observations(
        dataclasses.replace(
            problem, grid=field.grid, measured=field.measured, offsets=field.offsets,
            noise_std=field.noise_std, beam_noise_std=field.beam_noise_std, fields=(),
        )
    )[3]  # fmt: skip
    fused = pmf.update(state, depth_obs, grid, rng, fields=((gravity_obs, field.grid),))
    in_turn = pmf.update(pmf.update(state, depth_obs, grid, rng), gravity_obs, field.grid, rng)
    np.testing.assert_allclose(fused.log_weight, in_turn.log_weight, atol=1e-9)
    ll_gravity, _ = pmf.likelihood.nodes(field.grid, gravity_obs, state)
    assert np.ptp(ll_gravity) > 1.0  # the gravity ping does weigh the nodes
    assert np.isclose(ops.normalise(fused.log_weight).max(), fused.log_weight.max())


def test_a_field_on_a_coarser_grid_of_its_own_is_read_at_the_node_positions(monkeypatch):
    coarse = Grid(
        8.0 * np.sin((np.indices((45, 45))[0] * 250.0) / 700.0),
        0.0, 0.0, 250.0, 250.0, kind="gravity", units="mGal",
    )  # fmt: skip
    scen, grid = scenario(("depth", "gravity"), monkeypatch)
    monkeypatch.setattr(simulate_module, "prepare_field_maps", lambda scen: (coarse,))
    errors = []
    for i in range(2):
        trial = simulate_trial(scen, grid, i)
        assert trial.fields[0].grid.cell_size == 250.0
        result = run_trial(parse_method_spec("pmf"), trial, grid, method_rng(8, i, "pmf"))
        errors.append(result.error[-1])
    assert float(np.sqrt(np.mean(np.square(errors)))) < 30.0, errors
