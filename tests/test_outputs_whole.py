"""Outputs are whole or absent: a full disk, a refused permission or a kill never leaves a
truncated file under an output's name, and a replay's outputs carry one run id.

Disk-full and permission errors are injected into the writers (the file is half written,
then the write fails as the operating system would fail it); kills are real SIGKILLs of
``python -m geofix`` at several points of its run.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr
import yaml
from PIL import Image
from typer.testing import CliRunner

from _reliability import assert_clean_error, run_cli
from conftest import small_mission_data
from geofix._atomic import PART_SUFFIX, write_atomic, write_text_atomic
from geofix.cli import app
from geofix.errors import OutputError
from geofix.maps import load_grid
from geofix.maps.gridding import load_map_error
from geofix.replay import OUTPUT_NAMES, output_run_ids

FAILURES = {
    errno.ENOSPC: "disk full",
    errno.EACCES: "permission denied",
    errno.EROFS: "read-only file system",
}


def _parts(folder: Path) -> list[Path]:
    return sorted(folder.rglob(f"*{PART_SUFFIX}"))


def _failing_writer(code: int):
    """A writer that writes half a file, then fails with ``code`` as the system would."""

    def write(part: Path) -> None:
        part.write_bytes(b"x" * 4096)
        raise OSError(code, os.strerror(code), str(part))

    return write


@pytest.fixture(scope="module")
def ex1811_map(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("whole") / "ex1811_100m.nc"
    result = CliRunner().invoke(
        app, ["grid", "builtin:ex1811", "--cell-m", "100", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    return out


# ---------------------------------------------------------------------- the helper
@pytest.mark.parametrize(("code", "reason"), list(FAILURES.items()), ids=list(FAILURES.values()))
def test_a_failed_write_keeps_the_old_file_and_leaves_no_part(tmp_path, code, reason):
    path = tmp_path / "out.txt"
    path.write_text("the old file")
    with pytest.raises(OutputError, match=f"cannot write {path}: {reason}"):
        write_atomic(path, _failing_writer(code))
    assert path.read_text() == "the old file"
    assert _parts(tmp_path) == []


def test_a_library_error_is_one_output_error_naming_the_path(tmp_path):
    def write(part: Path) -> None:
        part.write_bytes(b"half")
        raise RuntimeError("NetCDF: HDF error\nmore lines")

    with pytest.raises(OutputError, match=r"cannot write .*map\.nc: NetCDF: HDF error$"):
        write_atomic(tmp_path / "map.nc", write)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("target", ["folder", "/dev/null"])
def test_a_target_that_is_not_a_regular_file_is_refused(tmp_path, target):
    path = tmp_path if target == "folder" else Path(target)
    if not path.exists():
        pytest.skip(f"{target} does not exist here")
    with pytest.raises(OutputError, match=r"it is (a folder|not a regular file)"):
        write_text_atomic(path, "text")


def test_a_successful_write_replaces_the_file_whole(tmp_path):
    path = tmp_path / "a" / "b.txt"
    assert write_text_atomic(path, "first") == path
    write_text_atomic(path, "second")
    assert path.read_text() == "second" and _parts(tmp_path) == []


# ---------------------------------------------------------------------- commands
def _fail_netcdf(monkeypatch, code: int) -> None:
    """Make every netCDF write of xarray write half a file and then fail with ``code``."""

    def to_netcdf(self, path=None, *args, **kwargs):
        _failing_writer(code)(Path(path))

    monkeypatch.setattr(xr.Dataset, "to_netcdf", to_netcdf)


@pytest.mark.parametrize(("code", "reason"), list(FAILURES.items()), ids=list(FAILURES.values()))
def test_grid_on_a_full_disk_keeps_the_old_map_whole(
    ex1811_map, tmp_path, monkeypatch, code, reason
):
    out = tmp_path / "map.nc"
    out.write_bytes(ex1811_map.read_bytes())
    _fail_netcdf(monkeypatch, code)
    args = ["grid", "builtin:ex1811", "--cell-m", "50", "--out", str(out)]
    assert_clean_error(run_cli(f"grid {reason}", args), str(out), reason)
    monkeypatch.undo()
    assert load_grid(out).dx == 100.0 and load_map_error(out) is not None  # the old map
    assert _parts(tmp_path) == []


def test_grid_on_a_full_disk_leaves_no_map(tmp_path, monkeypatch):
    _fail_netcdf(monkeypatch, errno.ENOSPC)
    out = tmp_path / "map.nc"
    args = ["grid", "builtin:ex1811", "--cell-m", "100", "--out", str(out)]
    outcome = run_cli("grid disk full", args)
    assert_clean_error(outcome, f"cannot write {out}: disk full")
    assert len(outcome.lines) == 1
    assert list(tmp_path.iterdir()) == []


def _replay_args(ex1811_map: Path, out: Path) -> list[str]:
    args = ["replay", "builtin:ex1811", "--map", str(ex1811_map), "-m", "pmf"]
    return [*args, "--ins-initial-error-m", "300", "--out", str(out)]


def test_replay_outputs_share_one_run_id_and_replace_an_earlier_replay(ex1811_map, tmp_path):
    out = tmp_path / "replay"
    first = run_cli("replay 1", _replay_args(ex1811_map, out))
    assert first.exit_code == 0, first.output
    ids = output_run_ids(out)
    assert set(ids) == set(OUTPUT_NAMES) and len(set(ids.values())) == 1
    assert next(iter(ids.values())) is not None
    second = run_cli("replay 2", _replay_args(ex1811_map, out))
    assert second.exit_code == 0, second.output
    again = output_run_ids(out)
    assert len(set(again.values())) == 1 and set(again.values()) != set(ids.values())
    frame = pd.read_csv(out / "estimates.csv")
    with xr.open_dataset(out / "estimates.nc") as ds:
        assert ds.attrs["run_id"] == frame["run_id"].iloc[0]
        assert json.loads(ds.attrs["summary_json"])["pings"] == 50  # existing keys kept
    assert {"method", "ping", "x", "y", "status"} <= set(frame.columns)


def test_replay_failing_at_its_figure_leaves_no_output_of_the_earlier_replay(
    ex1811_map, tmp_path, monkeypatch
):
    from matplotlib.figure import Figure

    out = tmp_path / "replay"
    assert run_cli("replay old", _replay_args(ex1811_map, out)).exit_code == 0
    old_id = output_run_ids(out)["replay.png"]

    def full_disk(fig, part, **kwargs):
        _failing_writer(errno.ENOSPC)(Path(part))

    monkeypatch.setattr(Figure, "savefig", full_disk)
    outcome = run_cli("replay disk full", _replay_args(ex1811_map, out))
    monkeypatch.undo()
    assert_clean_error(outcome, f"cannot write {out / 'replay.png'}: disk full")
    ids = output_run_ids(out)
    assert "replay.png" not in ids, ids  # the old figure is gone, the new one never came
    assert set(ids) == {"estimates.csv", "estimates.nc"} and len(set(ids.values())) == 1
    assert old_id not in ids.values()
    assert _parts(tmp_path) == []


@pytest.mark.parametrize(("code", "reason"), list(FAILURES.items()), ids=list(FAILURES.values()))
def test_report_on_a_full_disk_keeps_the_old_page(tmp_path, monkeypatch, code, reason):
    scenario = tmp_path / "scen.yaml"
    scenario.write_text(yaml.safe_dump(small_mission_data("whole", trials=2)))
    folder = tmp_path / "campaign"
    run = ["run", str(scenario), "-m", "tercom", "--jobs", "1", "--out", str(folder), "--json"]
    assert run_cli("run", run).exit_code == 0
    page = folder / "report.html"
    page.write_text("<html>the old page</html>")
    real = Path.write_text

    def write_text(self, data, *args, **kwargs):
        if self.name.startswith(".report.html."):
            real(self, data[: len(data) // 2], *args, **kwargs)
            raise OSError(code, os.strerror(code), str(self))
        return real(self, data, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", write_text)
    outcome = run_cli(f"report {reason}", ["report", str(folder)])
    monkeypatch.undo()
    assert_clean_error(outcome, f"cannot write {page}: {reason}")
    assert page.read_text() == "<html>the old page</html>" and _parts(tmp_path) == []


def test_run_on_a_full_disk_writes_no_half_summary(tmp_path, monkeypatch):
    scenario = tmp_path / "scen.yaml"
    scenario.write_text(yaml.safe_dump(small_mission_data("whole-run", trials=2)))
    folder = tmp_path / "campaign"
    real = Path.write_text

    def write_text(self, data, *args, **kwargs):
        if self.name.startswith(".summary.json."):
            real(self, data[:10], *args, **kwargs)
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return real(self, data, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", write_text)
    run = ["run", str(scenario), "-m", "tercom", "--jobs", "1", "--out", str(folder), "--json"]
    outcome = run_cli("run disk full", run)
    monkeypatch.undo()
    assert_clean_error(outcome, f"cannot write {folder / 'summary.json'}: disk full")
    assert not (folder / "summary.json").exists() and _parts(tmp_path) == []
    again = run_cli("run again", run)  # the stored trials resume
    assert again.exit_code == 0, again.output
    assert json.loads((folder / "summary.json").read_text())["trials"] == 2


# ---------------------------------------------------------------------- kills
def _env() -> dict:
    src = str(Path(__file__).resolve().parents[1] / "src")
    path = os.pathsep.join(p for p in (src, os.environ.get("PYTHONPATH")) if p)
    return {**os.environ, "PYTHONPATH": path, "NUMBA_NUM_THREADS": "1"}


def _run_killed(args: list[str], delay_s: float) -> bool:
    """Run ``python -m geofix ARGS``; SIGKILL it after ``delay_s``. True if it had ended."""
    cmd = [sys.executable, "-m", "geofix", *args]
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + delay_s
    while time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.01)
    ended = proc.poll() is not None
    if not ended:
        proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    return ended


def _timed(args: list[str]) -> float:
    start = time.monotonic()
    subprocess.run(
        [sys.executable, "-m", "geofix", *args], env=_env(), check=True, capture_output=True
    )
    return time.monotonic() - start


def _replay_outputs_whole(out: Path) -> None:
    """Every replay output present loads, and they share one run id."""
    ids = output_run_ids(out)
    assert None not in ids.values(), ids
    assert len(set(ids.values())) <= 1, ids
    if "estimates.csv" in ids:
        assert len(pd.read_csv(out / "estimates.csv")) == 50
    if "estimates.nc" in ids:
        with xr.open_dataset(out / "estimates.nc") as ds:
            assert ds["x"].shape == (1, 50) and np.isfinite(ds["x"].values).all()
    if "replay.png" in ids:
        with Image.open(out / "replay.png") as image:
            image.load()


@pytest.mark.slow
def test_killed_replays_leave_whole_outputs_of_one_run(ex1811_map, tmp_path):
    out = tmp_path / "replay"
    args = _replay_args(ex1811_map, out)
    full = _timed(args)
    _replay_outputs_whole(out)
    for share in (0.5, 0.8, 0.9, 0.97):
        _run_killed(args, share * full)
        _replay_outputs_whole(out)
        assert _parts(out) == [] or all(p.name.startswith(".") for p in _parts(out))
    run_cli("replay after kills", args)  # clears what the kills left
    assert _parts(out) == []
    _replay_outputs_whole(out)


@pytest.mark.slow
def test_killed_grids_leave_a_whole_map_or_none(tmp_path):
    out = tmp_path / "map.nc"
    args = ["grid", "builtin:ex1811", "--cell-m", "20", "--out", str(out)]
    full = _timed(args)
    out.unlink()
    for share in (0.6, 0.85, 0.95, 0.99):
        _run_killed(args, share * full)
        if out.exists():
            grid = load_grid(out)
            assert grid.dx == 20.0 and load_map_error(out) is not None
            out.unlink()


@pytest.mark.slow
def test_killed_reports_leave_the_old_page_or_a_whole_new_one(tmp_path):
    scenario = tmp_path / "scen.yaml"
    scenario.write_text(yaml.safe_dump(small_mission_data("whole-report", trials=2)))
    folder = tmp_path / "campaign"
    run = ["run", str(scenario), "-m", "tercom", "--jobs", "1", "--out", str(folder), "--json"]
    assert run_cli("run", run).exit_code == 0
    page = folder / "report.html"
    args = ["report", str(folder)]
    full = _timed(args)
    whole = page.read_text()
    assert whole.rstrip().endswith("</html>")
    for share in (0.3, 0.6, 0.85, 0.95):
        page.write_text("<html>the old page</html>")
        _run_killed(args, share * full)
        text = page.read_text()
        # the old page, or a whole new one (closed, about as long as the uninterrupted
        # run's: a truncated page would be shorter)
        assert text == "<html>the old page</html>" or (
            text.rstrip().endswith("</html>") and abs(len(text) - len(whole)) < 0.01 * len(whole)
        ), (share, len(text), len(whole))
        assert [p for p in _parts(tmp_path) if not p.name.startswith(".")] == []
