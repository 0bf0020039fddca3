"""Bad input to ``grid``, ``replay``, ``report`` and ``serve`` gives one plain line.

Each case runs the command line in this process (as :mod:`test_bad_inputs` does for
``run``) and asserts exit code 2, no traceback, at most 3 lines, no "internal error", and
that the message names the option, file, key or column at fault.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import netCDF4
import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from _reliability import assert_clean_error, run_cli
from conftest import small_mission_data
from geofix.cli import app
from geofix.errors import MapError
from geofix.maps import Grid, load_grid
from geofix.maps.io import save_grid


@pytest.fixture(scope="module")
def ex1811_map(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("faces") / "ex1811_100m.nc"
    result = CliRunner().invoke(
        app, ["grid", "builtin:ex1811", "--cell-m", "100", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def campaign_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("campaign")
    scenario = folder / "scen.yaml"
    scenario.write_text(yaml.safe_dump(small_mission_data("faces", trials=2)))
    args = ["run", str(scenario), "-m", "tercom", "--jobs", "1", "--out", str(folder / "out")]
    result = CliRunner().invoke(app, [*args, "--json"])
    assert result.exit_code == 0, result.output
    return folder / "out"


def _clean(outcome, *names: str) -> None:
    assert_clean_error(outcome, *names)
    assert "internal error" not in outcome.output, outcome.output


def _replay(ex1811_map: Path, tmp_path: Path, *extra: str) -> list[str]:
    args = ["replay", "builtin:ex1811", "--map", str(ex1811_map), "-m", "pmf"]
    return [*args, "--out", str(tmp_path / "replay"), *extra]


# ---------------------------------------------------------------------- grid tables
@pytest.mark.parametrize(
    ("columns", "names"),
    [
        ({"x": [1.0, 2, 3], "y": [1.0, 2, 3], "value": ["abc", 1, 2]}, ["'value'", "'abc'"]),
        ({"x": ["a", "b", "c"], "y": [1.0, 2, 3], "value": [1.0, 2, 3]}, ["'x'", "row 1"]),
        ({"lon": [500.0, 501, 502], "lat": [100.0, 101, 100], "value": [1.0, 2, 3]}, ["lat 100"]),
        ({"x": [1e300, -1e300, 0], "y": [1e300, 0, 1e300], "value": [1.0, 2, 3]}, ["4e+07 m"]),
    ],
    ids=["text-value", "text-x", "lonlat-out-of-range", "coordinates-1e300"],
)
@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_grid_bad_soundings_table(tmp_path, columns, names, suffix):
    path = tmp_path / f"soundings{suffix}"
    table = pd.DataFrame(columns)
    if suffix == ".csv":
        table.to_csv(path, index=False)
    else:
        table.astype({c: str for c in table if table[c].dtype == object}).to_parquet(path)
    out = tmp_path / "map.nc"
    outcome = run_cli(
        f"grid table {names}", ["grid", str(path), "--cell-m", "10", "--out", str(out)]
    )
    _clean(outcome, path.name, *names)
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "names"),
    [
        (["--cell-m", "inf"], ["cell size must be positive and finite", "inf"]),
        (["--cell-m", "nan"], ["cell size must be positive and finite"]),
        (["--cell-m", "100", "--out", "/dev/null"], ["/dev/null", "not a regular file"]),
    ],
    ids=["cell-inf", "cell-nan", "out-dev-null"],
)
def test_grid_bad_option(tmp_path, args, names):
    if "--out" not in args:
        args = [*args, "--out", str(tmp_path / "map.nc")]
    outcome = run_cli(f"grid {args}", ["grid", "builtin:ex1811", *args])
    _clean(outcome, *names)
    assert not (tmp_path / "map.nc").exists()


def test_grid_refuses_to_write_a_map_with_infinite_cells(tmp_path):
    values = np.zeros((4, 4))
    values[1, 2] = np.inf
    grid = Grid(values, 0.0, 0.0, 10.0, 10.0)
    with pytest.raises(MapError, match="1 cells are infinite"):
        save_grid(grid, tmp_path / "inf.nc")
    assert not (tmp_path / "inf.nc").exists()
    save_grid(grid, tmp_path / "layer.nc", infinite_ok=True)  # a CRLB layer may hold inf
    assert np.isinf(load_grid(tmp_path / "layer.nc").values).sum() == 1


def test_load_grid_refuses_a_saved_map_with_infinite_cells(tmp_path):
    path = tmp_path / "map.nc"
    save_grid(Grid(np.zeros((4, 4)), 0.0, 0.0, 10.0, 10.0), path)
    with netCDF4.Dataset(path, "a") as ds:
        ds["z"][2, 3] = -np.inf
    with pytest.raises(MapError, match=r"1 cells are infinite \(first at row 2, column 3\)"):
        load_grid(path)


# ---------------------------------------------------------------------- maps
def _edit_map(src: Path, dst: Path, **attrs) -> str:
    shutil.copy(src, dst)
    with netCDF4.Dataset(dst, "a") as ds:
        for key, value in attrs.items():
            ds.setncattr(key, value)
    return str(dst)


@pytest.mark.parametrize(
    ("attrs", "names"),
    [
        ({"dx": "abc"}, ["attribute dx is not a number"]),
        ({"x0": "nan"}, ["attribute x0 = nan"]),
        ({"dy": -5.0}, ["attribute dy = -5"]),
        ({"geofix_grid": "yes"}, ["attribute geofix_grid is not a number"]),
        ({"meta_json": "{not json"}, ["meta_json is not valid JSON"]),
        ({"meta_json": "[1, 2]"}, ["meta_json is not a JSON object"]),
        ({"kind": "<lava>"}, ["attribute kind"]),
    ],
    ids=["dx-text", "x0-nan", "dy-negative", "marker-text", "meta-bad-json", "meta-list", "kind"],
)
def test_geofix_map_with_bad_metadata(ex1811_map, tmp_path, attrs, names):
    path = _edit_map(ex1811_map, tmp_path / "bad.nc", **attrs)
    args = ["replay", "builtin:ex1811", "--map", path, "-m", "pmf", "--out", str(tmp_path)]
    outcome = run_cli(f"map {attrs}", args)
    _clean(outcome, "bad.nc", *names)
    outcome = run_cli(f"suitability {attrs}", ["suitability", path, "--out", str(tmp_path / "s")])
    _clean(outcome, "bad.nc", *names)


def test_geofix_map_without_z(ex1811_map, tmp_path):
    import xarray as xr

    with xr.open_dataset(ex1811_map) as ds:
        ds.load().drop_vars("z").to_netcdf(tmp_path / "noz.nc")
    outcome = run_cli("map without z", ["suitability", str(tmp_path / "noz.nc")])
    _clean(outcome, "noz.nc", "without its variable 'z'")


def test_map_with_a_projection_proj_rejects(ex1811_map, tmp_path):
    meta = json.dumps({"projection": "+proj=bogus +x=1"})
    path = _edit_map(ex1811_map, tmp_path / "badproj.nc", meta_json=meta)
    args = ["replay", "builtin:ex1811", "--map", path, "-m", "pmf", "--out", str(tmp_path)]
    _clean(run_cli("bad PROJ", args), "badproj.nc", "PROJ rejects", "+proj=bogus")


def test_a_file_that_is_not_a_map_is_not_echoed(tmp_path):
    path = tmp_path / "secret.nc"
    path.write_bytes(b"PASSWORD=hunter2\n" * 10)
    outcome = run_cli("not a map", ["suitability", str(path), "--out", str(tmp_path / "s")])
    _clean(outcome, "not a netCDF / GeoTIFF / BAG file", "secret.nc")
    assert "PASS" not in outcome.output and "hunter2" not in outcome.output


# ---------------------------------------------------------------------- replay, serve
@pytest.mark.parametrize(
    ("extra", "names"),
    [
        (["--seed", "-1"], ["--seed", "-1"]),
        (["--noise-std", "1e-300"], ["--noise-std", "1e-300"]),
        (["--noise-std", "1e300"], ["--noise-std", "1e+300"]),
        (["--noise-std", "nan"], ["--noise-std", "nan"]),
        (["-m", "ins"], ["'ins' cannot run ping by ping", "pmf"]),
        (["-m", "tercom"], ["'tercom' is a batch matcher"]),
    ],
    ids=["seed-negative", "noise-tiny", "noise-huge", "noise-nan", "method-ins", "batch"],
)
def test_replay_bad_option(ex1811_map, tmp_path, extra, names):
    outcome = run_cli(f"replay {extra}", _replay(ex1811_map, tmp_path, *extra))
    _clean(outcome, *names)
    assert not (tmp_path / "replay" / "estimates.csv").exists()


def test_replay_out_is_a_device(ex1811_map, tmp_path):
    args = [*_replay(ex1811_map, tmp_path)[:-2], "--out", "/dev/null"]
    _clean(run_cli("replay --out /dev/null", args), "/dev/null", "not a folder")


@pytest.mark.parametrize(
    ("extra", "names"),
    [
        (["--seed", "-1"], ["--seed"]),
        (["--noise-std", "1e300"], ["--noise-std"]),
        (["-m", "ins"], ["serve: method 'ins'"]),
    ],
    ids=["seed", "noise", "ins"],
)
def test_serve_bad_option_before_listening(extra, names):
    args = ["serve", "--map", "builtin:mb_1km", "--port", "0", *extra]
    outcome = run_cli(f"serve {extra}", args)
    _clean(outcome, *names)
    assert "serving" not in outcome.output


# ---------------------------------------------------------------------- scenarios
def _yaml(tmp_path: Path, text: str, name: str = "scen.yaml") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _deep_yaml(levels: int) -> str:
    return "name: x\nmap: " + "{a: " * levels + "1" + "}" * levels + "\n"


@pytest.mark.parametrize(
    ("text", "names"),
    [
        (_deep_yaml(5000), ["nested too deeply"]),
        ("name: x\nmap: " + "[" * 5000 + "]" * 5000 + "\n", ["nested too deeply"]),
        ("name: x\ntrials: " + "9" * 5000 + "\n", ["too many digits"]),
    ],
    ids=["deep-mapping", "deep-list", "5000-digits"],
)
def test_hostile_yaml(ex1811_map, tmp_path, text, names):
    path = _yaml(tmp_path, text)
    _clean(run_cli("yaml run", ["run", path, "-m", "tercom", "--out", str(tmp_path)]), *names)
    outcome = run_cli("yaml replay", _replay(ex1811_map, tmp_path, "--ins", path))
    _clean(outcome, "scen.yaml", *names)


@pytest.mark.parametrize(
    "ins",
    [
        {"velocity_error_m_s": 1e300},
        {"gyro_bias_deg_h": 1e300},
        {"heading_error_deg": 1e300},
        {"accel_noise_ug_rt_hz": 1e300},
    ],
    ids=["velocity", "gyro", "heading", "accel-noise"],
)
def test_ins_numbers_of_1e300(ex1811_map, tmp_path, ins):
    key = next(iter(ins))
    path = _yaml(tmp_path, yaml.safe_dump(small_mission_data("ins-1e300", ins=ins)))
    outcome = run_cli("ins run", ["run", path, "-m", "ins", "--jobs", "1", "--out", str(tmp_path)])
    _clean(outcome, f"ins.{key}")
    _clean(run_cli("ins replay", _replay(ex1811_map, tmp_path, "--ins", path)), f"ins.{key}")


def test_trials_beyond_the_cap_are_refused_before_starting(tmp_path):
    path = _yaml(tmp_path, yaml.safe_dump(small_mission_data("many")))
    args = ["run", path, "-m", "tercom", "--trials", str(10**20), "--out", str(tmp_path / "o")]
    _clean(run_cli("trials 1e20", args), "--trials", "at most 1000000")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("how", ["env", "option"])
def test_memory_budget_beyond_any_float(tmp_path, how):
    if how == "env":
        args = ["suitability", "builtin:mb_1km", "--out", str(tmp_path)]
        outcome = run_cli("budget env", args, env={"GEOFIX_MEMORY_BUDGET": "1e400"})
    else:
        outcome = run_cli("budget option", ["--memory-budget", "1e400", "maps"])
    _clean(outcome, "'1e400'", "not a finite size")


# ---------------------------------------------------------------------- report
@pytest.mark.parametrize(
    ("summary", "names"),
    [
        ("null", ["is not a JSON object"]),
        ("42", ["is not a JSON object"]),
        ('{"scenario": "x", "trials": 2, "methods": [1, 2]}', ["methods is not an object"]),
        ('{"scenario": 5, "trials": 2, "methods": {}}', ["scenario is not a string"]),
        ('{"scenario": "x", "trials": "2", "methods": {}}', ["trials is not a count"]),
        (
            '{"scenario": "x", "trials": 2, "methods": {"t": {"trials": "<script>"}}}',
            ["methods.t.trials is not a count"],
        ),
        (
            '{"scenario": "x", "trials": 2, "methods": {"t": {"trials": 2, "max_error_m": "a"}}}',
            ["methods.t.max_error_m is not a number"],
        ),
        ("[" * 100_000 + "]" * 100_000, ["summary.json"]),
    ],
    ids=["null", "number", "methods-list", "scenario", "trials", "method-trials", "value", "deep"],
)
def test_report_on_a_bad_summary(campaign_dir, tmp_path, summary, names):
    folder = tmp_path / "campaign"
    shutil.copytree(campaign_dir, folder)
    (folder / "summary.json").write_text(summary)
    outcome = run_cli("report summary", ["report", str(folder)])
    _clean(outcome, "summary.json", *names)
    assert not (folder / "report.html").exists()


def test_report_escapes_the_summary_strings():
    from geofix.report import _accuracy_table

    table = _accuracy_table({"<script>alert(1)</script>": {"trials": 2, "failures": 0}})
    assert "<script>" not in table and "&lt;script&gt;alert(1)&lt;/script&gt;" in table


@pytest.mark.parametrize("page", [0, 1])
@pytest.mark.parametrize("command", ["report", "run"])
def test_corrupted_results_store(campaign_dir, tmp_path, page, command):
    folder = tmp_path / "campaign"
    shutil.copytree(campaign_dir, folder)
    store = folder / "results.sqlite"
    data = bytearray(store.read_bytes())
    size = int.from_bytes(data[16:18], "big")
    start = page * size + (100 if page == 0 else 0)
    data[start : start + 60] = b"\xab" * 60
    store.write_bytes(data)
    if command == "report":
        args = ["report", str(folder)]
    else:
        scenario = _yaml(tmp_path, yaml.safe_dump(small_mission_data("faces", trials=2)))
        args = ["run", scenario, "-m", "tercom", "--jobs", "1", "--out", str(folder)]
    _clean(run_cli(f"{command} corrupted store", args), "results.sqlite", "malformed")


# ---------------------------------------------------------------------- Ctrl-C
_INTERRUPT = """
import sys
import geofix.{module} as target

def interrupted(*args, **kwargs):
    raise KeyboardInterrupt

target.{function} = interrupted
sys.argv = ["geofix", *{args!r}]
from geofix.cli import main
main()
"""


@pytest.mark.parametrize(
    ("module", "function", "args", "resumes"),
    [
        ("logs.gridmap", "grid_log", ["grid", "builtin:ex1811", "--cell-m", "100"], False),
        ("replay", "replay_log", ["replay", "builtin:ex1811", "-m", "pmf"], False),
        ("evaluate.campaign", "run_campaign", ["run", "builtin:azores_demo", "-m", "ins"], True),
    ],
    ids=["grid", "replay", "run"],
)
def test_ctrl_c_says_resume_only_where_it_resumes(tmp_path, module, function, args, resumes):
    args = [*args, "--out", str(tmp_path / "out.nc")]
    code = _INTERRUPT.format(module=module, function=function, args=args)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 130, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("interrupted:"), proc.stderr
    assert ("run the same command to resume" in lines[0]) is resumes, lines[0]
