"""Bad input gives one clean line, never a traceback, never the machine.

Each case runs the command line as a user would (in this process, ``--trials 1 --jobs 1``)
and asserts: exit code 2, no traceback, at most 3 lines, the message names the key, value
or path at fault, under 30 s; size refusals also stay under the memory budget (peak of
the allocations tracemalloc sees, numpy's included).
"""

from __future__ import annotations

import contextlib
import os
import sqlite3

import numpy as np
import pytest
import xarray as xr
import yaml

from _reliability import assert_clean_error, run_cli
from conftest import small_mission_data
from geofix.maps import Grid
from geofix.maps.io import save_grid


def _write(tmp_path, data: dict, name: str = "scen.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _mission(tmp_path, **changes):
    return _write(tmp_path, small_mission_data("bad-input", **changes))


def _run(tmp_path, scenario, *extra, method="tercom", case="run", env=None, trace=False):
    args = ["run", str(scenario), "-m", method, "--trials", "1", "--jobs", "1"]
    args += ["--out", str(tmp_path / "out"), *extra]
    return run_cli(case, args, env=env, trace=trace)


def _nc(tmp_path, name: str, **variables) -> str:
    """A netCDF file of the given variables (numpy arrays with dims y, x or others)."""
    data = {}
    for var, values in variables.items():
        values = np.asarray(values)
        dims = ("y", "x", "t")[: values.ndim] if values.ndim <= 3 else None
        data[var] = (dims, values)
    ny = max((np.shape(v)[0] for v in variables.values() if np.ndim(v) >= 1), default=1)
    nx = max((np.shape(v)[1] for v in variables.values() if np.ndim(v) >= 2), default=1)
    ds = xr.Dataset(data, coords={"x": np.arange(nx) * 100.0, "y": np.arange(ny) * 100.0})
    ds["x"].attrs["units"] = "m"
    ds["y"].attrs["units"] = "m"
    path = tmp_path / name
    ds.to_netcdf(path)
    return str(path)


def _map_mission(tmp_path, map_path: str, **map_keys):
    track = {"start_cell": [5, 5], "samples": 4, "interval_s": 10}
    return _mission(tmp_path, map={"path": map_path, **map_keys}, track=track)


# ---------------------------------------------------------------------- scenario numbers
@pytest.mark.parametrize(
    ("changes", "names"),
    [
        ({"seed": -1}, ["seed", "greater than or equal to 0"]),
        ({"ins": {"prior_sigma_m": float("inf")}}, ["ins.prior_sigma_m", "finite"]),
        ({"ins": {"gyro_noise_deg_rt_h": float("inf")}}, ["ins.gyro_noise_deg_rt_h", "finite"]),
        ({"ins": {"velocity_error_m_s": float("nan")}}, ["ins.velocity_error_m_s", "finite"]),
        ({"sensor": {"type": "gravimeter", "noise_std": 1.0}}, ["gravimeter", "map.kind"]),
        ({"track": {"speed_m_s": 1e300}}, ["leaves the map", "e+"]),
    ],
    ids=["seed", "prior-inf", "gyro-inf", "velocity-nan", "gravimeter-on-depth", "speed-1e300"],
)
def test_bad_scenario_number(tmp_path, changes, names):
    outcome = _run(tmp_path, _mission(tmp_path, **changes), case=f"scenario {changes}")
    assert_clean_error(outcome, *names)
    assert len(outcome.output) < 300  # no 300-digit coordinates
    assert not (tmp_path / "out" / "results.sqlite").exists()


def test_negative_seed_option_of_run_and_export(tmp_path):
    scenario = _mission(tmp_path)
    assert_clean_error(_run(tmp_path, scenario, "--seed", "-1", case="--seed -1"), "--seed", "-1")
    outcome = run_cli(
        "export --seed -1",
        ["export", str(scenario), "--out", str(tmp_path / "t.nc"), "--seed", "-1"],
    )
    assert_clean_error(outcome, "--seed", "-1")


def test_yaml_syntax_error_is_one_line_with_file_line_and_column(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("name: x\nmap: {path: builtin:mb_1km\ntrack: [1, 2\n")
    outcome = _run(tmp_path, path, case="yaml syntax")
    assert_clean_error(outcome, "broken.yaml:3:", "not valid YAML")
    assert len(outcome.lines) == 1


# ---------------------------------------------------------------------- method specs
@pytest.mark.parametrize(
    ("spec", "names"),
    [
        ("tercom:window_sigma=nan", ["window_sigma", "finite", "nan"]),
        ("tercom:window_m=inf", ["window_m", "finite", "inf"]),
        ("tercom:metric=mad,metric=msd", ["metric", "twice"]),
        ("tercom:metric", ["metric", "no value"]),
        ("[/b]", ["[/b]", "unknown method"]),
        ("icp", ["icp", "beams"]),
        # settings joined by ':' instead of ',': an optional number told so, not a numpy error
        ("pmf:offset_walk=0:fast_offset_walk=0", ["offset_walk", "cannot read", "as float"]),
        ("pf:student_dof=four", ["student_dof", "'four'", "as float"]),
    ],
    ids=[
        "nan",
        "inf",
        "repeated",
        "no-equals",
        "markup",
        "icp-single-beam",
        "colon-joined",
        "optional-word",
    ],
)
def test_bad_method_spec(tmp_path, spec, names):
    outcome = _run(tmp_path, _mission(tmp_path), method=spec, case=f"method {spec}")
    assert_clean_error(outcome, *names)
    assert len(outcome.lines) == 1


def test_messages_are_plain_text_and_never_wrapped(tmp_path):
    folder = tmp_path / "[red]maps [a, b]"
    folder.mkdir()
    scenario = _map_mission(tmp_path, str(folder / "none.nc"))
    outcome = run_cli(
        "markup path",
        ["run", str(scenario), "-m", "tercom", "--out", str(tmp_path / "o")],
        env={"COLUMNS": "30"},
    )
    assert_clean_error(outcome, "[red]maps [a, b]/none.nc")
    assert len(outcome.lines) == 1


# ---------------------------------------------------------------------- maps
def test_map_of_strings(tmp_path):
    path = _nc(tmp_path, "text.nc", z=np.full((6, 6), "abc"))
    assert_clean_error(
        _run(tmp_path, _map_mission(tmp_path, path), case="string map"), "'z'", "not numbers"
    )


@pytest.mark.parametrize(
    ("values", "names"),
    [
        (np.ones((1, 1)), ["no 2-D variable", "z (y=1 x x=1)"]),
        (np.ones((4, 5, 3)), ["no 2-D variable", "t=3"]),
    ],
    ids=["1x1", "3-D"],
)
def test_map_variable_of_wrong_shape(tmp_path, values, names):
    path = _nc(tmp_path, "shape.nc", z=values)
    assert_clean_error(_run(tmp_path, _map_mission(tmp_path, path), case="map shape"), *names)
    outcome = _run(tmp_path, _map_mission(tmp_path, path, variable="z"), case="map shape named")
    assert_clean_error(outcome, "'z'", "not a 2-D grid")


def test_map_with_infinite_cells(tmp_path):
    values = np.random.default_rng(0).normal(size=(12, 12))
    values[3, 4] = np.inf
    path = _nc(tmp_path, "inf.nc", z=values)
    outcome = _run(tmp_path, _map_mission(tmp_path, path), case="+inf cells")
    assert_clean_error(outcome, "inf.nc", "1 cells are infinite", "row 3, column 4")


@pytest.mark.parametrize(
    ("content", "names"), [(b"", ["is empty"]), (b"x" * 100, ["not a netCDF / GeoTIFF / BAG file"])]
)
def test_empty_or_foreign_map_file(tmp_path, content, names):
    path = tmp_path / "map.nc"
    path.write_bytes(content)
    outcome = _run(tmp_path, _map_mission(tmp_path, str(path)), case="empty/foreign map")
    assert_clean_error(outcome, "map.nc", *names)


# ---------------------------------------------------------------------- output folder and store
def test_summary_json_folder_is_refused_before_any_trial(tmp_path):
    (tmp_path / "out" / "summary.json").mkdir(parents=True)
    outcome = _run(tmp_path, _mission(tmp_path), case="summary.json folder")
    assert_clean_error(outcome, "summary.json", "folder")
    assert not (tmp_path / "out" / "results.sqlite").exists()


def test_foreign_results_store(tmp_path):
    (tmp_path / "out").mkdir()
    with sqlite3.connect(tmp_path / "out" / "results.sqlite") as db:
        db.execute("CREATE TABLE trials (id INTEGER, name TEXT)")
    outcome = _run(tmp_path, _mission(tmp_path), case="foreign store")
    assert_clean_error(outcome, "results.sqlite", "not a geofix results store")


def test_export_out_is_a_folder(tmp_path):
    outcome = run_cli("export folder", ["export", str(_mission(tmp_path)), "--out", str(tmp_path)])
    assert_clean_error(outcome, str(tmp_path), "is a folder")


# ---------------------------------------------------------------------- Dask
@pytest.mark.parametrize(
    ("address", "names"),
    [("notaurl", ["notaurl"]), ("tcp://127.0.0.1:1", ["127.0.0.1:1", "Timed out"])],
    ids=["not-a-url", "nothing-listening"],
)
def test_bad_scheduler(tmp_path, address, names):
    outcome = _run(
        tmp_path,
        _mission(tmp_path),
        "--scheduler",
        address,
        case=f"scheduler {address}",
        env={"GEOFIX_DASK_TIMEOUT": "2"},
    )
    assert_clean_error(outcome, "Dask scheduler", *names)


def test_losing_every_dask_worker_is_one_error(small_mission):
    import time

    from distributed import LocalCluster

    from geofix.errors import GeofixError
    from geofix.evaluate.campaign import _run_dask
    from geofix.methods import parse_method_spec
    from geofix.sim.simulate import prepare_map, simulate_trial

    scenario = small_mission("dask-lost", trials=6)
    grid = prepare_map(scenario)
    tasks = [(i, [("tercom", parse_method_spec("tercom"))]) for i in range(6)]

    def slow_trial(s, g, i):
        time.sleep(0.2)
        return simulate_trial(s, g, i)

    cluster = LocalCluster(
        n_workers=1, processes=False, threads_per_worker=1, dashboard_address=None
    )
    results = _run_dask(cluster.scheduler_address, slow_trial, scenario, grid, tasks)
    try:
        with pytest.raises(GeofixError, match="lost the campaign's workers") as info:
            for k, _ in enumerate(results):
                if k == 0:
                    cluster.close()
    finally:
        _forget_default_dask_client()
    assert "\n" not in str(info.value)


def _forget_default_dask_client() -> None:
    """Leave no default Dask client behind a test whose cluster vanished under it."""
    import dask
    from distributed import default_client

    with contextlib.suppress(ValueError):
        default_client().close()
    dask.config.set(scheduler=None)


# ---------------------------------------------------------------------- suitability
def _flat_map(tmp_path) -> str:
    grid = Grid(np.full((40, 40), -100.0), 0.0, 0.0, 50.0, 50.0, name="flat")
    return str(save_grid(grid, tmp_path / "flat.nc"))


def test_suitability_on_a_flat_map(tmp_path):
    outcome = run_cli(
        "suitability flat", ["suitability", _flat_map(tmp_path), "--out", str(tmp_path / "s")]
    )
    assert_clean_error(outcome, "'flat'", "flat within every 21-cell window")


def test_suitability_window_larger_than_the_map(tmp_path):
    args = ["suitability", "builtin:mb_1km", "--window-cells", "100000", "--out", str(tmp_path)]
    assert_clean_error(run_cli("suitability window", args, trace=True), "--window-cells 100000")


def test_suitability_unwritable_out():
    args = ["suitability", "builtin:mb_1km", "--out", "/proc/x"]
    assert_clean_error(run_cli("suitability /proc", args), "/proc/x")


# ---------------------------------------------------------------------- memory budget
@pytest.mark.parametrize(
    ("changes", "spec", "names"),
    [
        (
            {"map": {"path": "builtin:mb_1km", "resample_m": 0.5}},
            "tercom",
            ["resample_m 0.5", "TiB"],
        ),
        ({}, "tercom:window_sigma=1e9", ["tercom search window", "window_sigma 1e+09"]),
        ({"ins": {"velocity_error_m_s": 1e6}}, "tercom", ["tercom search window", "ins."]),
        ({"ins": {"heading_error_deg": -1e9}}, "tercom", ["tercom search window", "ins."]),
        (
            {"sensor": {"type": "multibeam", "beams": 1_000_000_000, "swath_width_m": 500}},
            "tercom",
            ["sensor.beams", "1000000000 beams"],
        ),
        ({"ins": {"velocity_error_m_s": 1e6}}, "ioap", ["ioap end-point rings", "ins."]),
    ],
    ids=[
        "resample",
        "tercom-window",
        "velocity-error",
        "heading-error",
        "beams",
        "ioap-rings",
    ],
)
def test_sizes_that_would_not_fit_are_refused_before_allocation(tmp_path, changes, spec, names):
    scenario = _mission(tmp_path, **changes)
    outcome = _run(tmp_path, scenario, method=spec, case=f"memory {spec} {changes}", trace=True)
    assert_clean_error(outcome, "would need", "memory budget", *names)


def test_suitability_of_a_map_beyond_the_budget(tmp_path):
    grid = Grid(np.random.default_rng(1).normal(size=(600, 600)), 0.0, 0.0, 10.0, 10.0, name="big")
    path = save_grid(grid, tmp_path / "big.nc")
    args = ["suitability", str(path), "--out", str(tmp_path / "s")]
    outcome = run_cli("suitability budget", args, env={"GEOFIX_MEMORY_BUDGET": "50MB"}, trace=True)
    assert_clean_error(outcome, "suitability of map 'big'", "600 x 600", "memory budget 47.7 MiB")


def test_memory_budget_option(tmp_path):
    scenario = _mission(tmp_path)
    before = os.environ.get("GEOFIX_MEMORY_BUDGET")
    args = ["--memory-budget", "100KB", "run", str(scenario), "-m", "tercom", "--jobs", "1"]
    outcome = run_cli("--memory-budget 100KB", [*args, "--out", str(tmp_path / "o")])
    assert_clean_error(outcome, "reading variable 'z'", "memory budget 97.7 KiB")
    assert os.environ.get("GEOFIX_MEMORY_BUDGET") == before
    outcome = run_cli("--memory-budget bad", ["--memory-budget", "lots", "maps"])
    assert_clean_error(outcome, "'lots'", "not a size")


# ---------------------------------------------------------------------- adjusted, not refused
def test_jobs_above_the_cores_warn_in_one_line_and_are_capped(tmp_path):
    from geofix.evaluate.campaign import usable_cores

    outcome = _run(tmp_path, _mission(tmp_path), "--jobs", "999", "--json", case="--jobs 999")
    assert outcome.exit_code == 0 and not outcome.traceback, outcome.output
    warning = [line for line in outcome.lines if line.startswith("warning:")]
    assert warning == [
        f"warning: --jobs 999 is more than the {usable_cores()} usable cores; "
        f"using {usable_cores()}"
    ]


# ---------------------------------------------------------------------- honest caches, terminal
def test_map_replaced_by_other_values_of_the_same_size_is_recomputed(tmp_path):
    from geofix.evaluate.store import scenario_hash
    from geofix.sim.scenario import load_scenario

    rng = np.random.default_rng(4)
    path = tmp_path / "m.nc"
    save_grid(Grid(rng.normal(size=(30, 30)), 0.0, 0.0, 100.0, 100.0, name="m"), path)
    scenario = load_scenario(_map_mission(tmp_path, str(path)))
    first = scenario_hash(scenario)
    size = path.stat().st_size
    save_grid(Grid(rng.normal(size=(30, 30)), 0.0, 0.0, 100.0, 100.0, name="m"), path)
    assert path.stat().st_size == size
    assert scenario_hash(scenario) != first
    assert scenario_hash(scenario) == scenario_hash(scenario)


def test_summary_table_fits_80_columns_without_cutting_numbers():
    import io

    from rich.console import Console

    from geofix.console import _TABLE_COLUMNS, summary_table
    from geofix.evaluate.summary import CampaignSummary, MethodStats

    stats = MethodStats(
        trials=1000,
        failures=12,
        mean_error_m=123456.7,
        std_error_m=23456.7,
        median_error_m=3456.7,
        max_error_m=987654.3,
        mean_track_error_m=45678.9,
        success_rate={"100": 0.5, "1c": 0.25, "3c": 0.75},
        mean_time_s=12.345678,
    )
    specs = ["tercom:metric=mad,window_sigma=4", "pmf", "iccp-multipath:max_iterations=30"]
    summary = CampaignSummary("wide", 1000, methods=dict.fromkeys(specs, stats))
    console = Console(file=io.StringIO(), width=80)
    console.print(summary_table(summary, width=80))
    text = console.file.getvalue()
    assert max(len(line) for line in text.splitlines()) <= 80
    assert "…" not in text
    for number in ("123456.7", "3456.7", "12345.68", "50%"):
        assert number in text
    assert "left out to fit" in text
    full = Console(file=io.StringIO(), width=250)
    full.print(summary_table(summary))
    assert all(head in full.file.getvalue() for head, _ in _TABLE_COLUMNS)


@pytest.mark.parametrize(
    ("args", "names"),
    [
        (["run", "s.yaml", "-m", "tercom", "--trials", "many"], ["--trials", "valid integer"]),
        (["run"], ["Missing argument", "scenario"]),
        (["nosuch"], ["No such command", "nosuch"]),
        (["suitability", "builtin:mb_1km", "--window-cells", "x"], ["--window-cells"]),
    ],
    ids=["bad-int", "missing-argument", "unknown-command", "bad-window"],
)
def test_usage_errors_are_one_line(args, names):
    outcome = run_cli(f"usage {' '.join(args)}", args)
    assert_clean_error(outcome, *names)
    assert len(outcome.lines) == 1


def test_pmf_with_a_huge_ins_error_finishes_instead_of_hanging(tmp_path):
    scenario = _mission(tmp_path, ins={"velocity_error_m_s": 1e6})
    outcome = _run(tmp_path, scenario, "--json", method="pmf", case="pmf velocity 1e6")
    assert outcome.exit_code == 0 and not outcome.traceback, outcome.output
    assert outcome.seconds < 30


def test_motion_kernel_wider_than_the_grid_keeps_its_central_taps():
    from geofix.filters import _grid_ops as ops

    full = ops.motion_kernel(30.0)
    cut = ops.motion_kernel(30.0, 20)
    middle = full.size // 2
    ratio = cut / full[middle - 20 : middle + 21]
    assert cut.size == 41
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-3)
    np.testing.assert_array_equal(ops.motion_kernel(3.0, 20), ops.motion_kernel(3.0))
