"""``geofix replay --field depth --field gravity``: MGD77T channels in one filter.

The track is the bundled EW0112 excerpt's (real positions, times and quirks). No gravity
prior is bundled, and the bundled ETOPO1 crop (10 arc-minutes, 17 km cells) is too
coarse a depth prior to judge a fusion by, so the maps are synthetic fields on 1 km cells
in the ETOPO1 crop's frame, and the file's depths and free-air anomalies are rewritten
as those maps read at the ship's positions plus seeded noise: each field then agrees
with its map as a good prior would.
"""

import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from geofix.cli import app
from geofix.errors import ConfigError, GeofixWarning
from geofix.logs.mgd77 import field_segments, joint_segments
from geofix.maps import load_grid
from geofix.maps.grid import Grid
from geofix.maps.io import save_grid
from geofix.maps.project import frame_proj
from geofix.replay import replay, replay_log, screen_mission, window_mission

runner = CliRunner()
DATA = Path(__file__).parents[1] / "data" / "mgd77"
EXCERPT = DATA / "ew0112_excerpt.m77t"
ETOPO = DATA / "etopo1_10min_ew0112.nc"
RECORDS = 400  # the first 6.7 h of the excerpt
NOISE = {"depth": 5.0, "gravity": 1.0}  # m, mGal


def quiet(fn, *args, **kwargs):
    """Call ``fn`` with the excerpt's time-placement warning silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeofixWarning)
        return fn(*args, **kwargs)


def smooth_field(gx, gy, seed: int, base: float, amplitude: float) -> np.ndarray:
    """Twelve plane waves of 15-60 km wavelength in random directions (seeded)."""
    rng = np.random.default_rng(seed)
    values = np.full_like(gx, base)
    for _ in range(12):
        k = rng.uniform(2 * np.pi / 60e3, 2 * np.pi / 15e3)
        angle, phase = rng.uniform(0, 2 * np.pi, 2)
        wave = np.sin(k * (np.cos(angle) * gx + np.sin(angle) * gy) + phase)
        values += amplitude * rng.uniform(0.5, 1.0) * wave
    return values


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """``(log, {kind: map path})``: the excerpt's first records on synthetic maps."""
    out = tmp_path_factory.mktemp("fields")
    frame = load_grid(ETOPO).meta["projection"]
    lines = EXCERPT.read_text(encoding="latin-1").splitlines()[: RECORDS + 1]
    header = lines[0].split("\t")
    at = {name: header.index(name) for name in ("LAT", "LON", "CORR_DEPTH", "FREEAIR")}
    table = [line.split("\t") + [""] * len(header) for line in lines[1:]]
    lon = np.array([float(cells[at["LON"]]) for cells in table])
    lat = np.array([float(cells[at["LAT"]]) for cells in table])
    x, y = frame_proj(frame)(lon, lat)
    low = np.array([x.min(), y.min()]) - 40e3
    high = np.array([x.max(), y.max()]) + 40e3
    cell = 1000.0
    nx, ny = (np.ceil((high - low) / cell)).astype(int) + 1
    gx, gy = np.meshgrid(low[0] + cell * np.arange(nx), low[1] + cell * np.arange(ny))
    maps = {
        "depth": Grid(smooth_field(gx, gy, 1, -4000.0, 40.0), *low, cell, cell, kind="depth",
                      name="synthetic_depth", meta={"projection": frame}),
        "gravity": Grid(smooth_field(gx, gy, 2, 0.0, 6.0), *low, cell, cell, kind="gravity",
                        units="mGal", name="synthetic_gravity", meta={"projection": frame}),
    }  # fmt: skip
    paths = {kind: str(save_grid(grid, out / f"{kind}.nc")) for kind, grid in maps.items()}
    rng = np.random.default_rng(7)
    depth = -maps["depth"].sample(x, y) + rng.normal(0, NOISE["depth"], x.size)
    gravity = maps["gravity"].sample(x, y) + rng.normal(0, NOISE["gravity"], x.size)
    rows = [lines[0]]
    for k, cells in enumerate(table):
        cells = cells[: len(header)]
        if cells[at["CORR_DEPTH"]].strip():  # a record without a depth keeps none
            cells[at["CORR_DEPTH"]] = f"{depth[k]:.0f}"
        cells[at["FREEAIR"]] = f"{gravity[k]:.1f}" if (k + 1) % 50 else ""  # some blank
        rows.append("\t".join(cells))
    log = out / "synthetic.m77t"
    log.write_text("\n".join(rows) + "\n", encoding="latin-1")
    return log, paths


@pytest.fixture(scope="module")
def runs(synthetic, tmp_path_factory):
    """The replays of depth alone, gravity alone (library) and both (the command)."""
    log, paths = synthetic
    common = {"initial_error_m": 3000.0, "seed": 3, "hours": 1.5}
    summaries = {}
    for kind in ("depth", "gravity"):
        result, _ = quiet(
            replay_log, log, paths[kind], ["pmf"], settings={"noise_std": NOISE[kind]},
            field_name=kind, **common,
        )  # fmt: skip
        summaries[kind] = result.summary
    args = ["replay", str(log), "-m", "pmf", "--field", "depth", "--field", "gravity"]
    args += ["--map", paths["depth"], "--map", paths["gravity"], "--seed", "3", "--json"]
    args += ["--noise-std", "5", "--noise-std", "1", "--ins-initial-error-m", "3000"]
    args += ["--hours", "1.5", "--out", str(tmp_path_factory.mktemp("o"))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeofixWarning)
        result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    summaries["both"] = json.loads(result.stdout)
    return summaries


def test_joint_read_holds_every_field_with_nan_where_one_is_missing():
    label, missions = quiet(joint_segments, EXCERPT, ["depth", "gravity", "magnetic"])
    assert label == "depth+gravity+magnetic" and len(missions) == 1
    mission = missions[0]
    assert mission.name == "ew0112_excerpt-depth+gravity+magnetic-0"
    assert mission.kind == "depth" and list(mission.fields) == ["gravity", "magnetic"]
    # every record has a gravity value, two lack a depth and 102 a magnetic residual
    assert mission.n == 2400
    assert mission.meta["field_pings"] == {"depth": 2398, "gravity": 2400, "magnetic": 2298}
    assert int(np.isnan(mission.beams[:, 0, 2]).sum()) == 2
    assert int(np.isnan(mission.fields["magnetic"][:, 0, 2]).sum()) == 102
    # the depths are those of the depth mission, at the same times
    _, alone = quiet(field_segments, EXCERPT, "depth")
    has = np.isfinite(mission.beams[:, 0, 2])
    np.testing.assert_array_equal(mission.beams[has], alone[0].beams)
    np.testing.assert_array_equal(mission.times[has] - mission.times[has][0], alone[0].times)


def test_windows_and_screening_cut_and_blank_the_further_fields_too():
    mission = quiet(joint_segments, EXCERPT, ["depth", "gravity"])[1][0]
    window = window_mission(mission, start_h=1.0, hours=1.0)
    assert window.fields["gravity"].shape == (window.n, 1, 3)
    first = int(np.flatnonzero(mission.times >= 3600.0)[0])
    np.testing.assert_array_equal(window.fields["gravity"][0], mission.fields["gravity"][first])
    gravity = mission.fields["gravity"].copy()
    gravity[5, 0, 2] = 5000.0  # beyond any free-air anomaly
    with pytest.warns(GeofixWarning, match="1 pings with beams dropped"):
        screened = screen_mission(replace(mission, fields={"gravity": gravity}), "depth")
    assert np.isnan(screened.fields["gravity"][5, 0, 2])
    assert np.isfinite(screened.fields["gravity"][6, 0, 2])


def test_fused_replay_beats_each_field_alone_and_the_ins(runs):
    rows = {kind: runs[kind]["methods"]["pmf"] for kind in ("depth", "gravity", "both")}
    # every record with a depth or a gravity value: the blank gravity value of the window
    # leaves the depth of its record
    assert runs["both"]["pings"] == runs["depth"]["pings"] == 91
    assert runs["gravity"]["pings"] == 90
    ins = rows["both"]["ins_end_error_m"]
    assert ins > 5000.0  # from 3 km, the free INS drifts for an hour and a half
    for row in rows.values():
        assert row["end_error_m"] < ins / 4
    # the two fields together: a smaller mean error than either alone (seeded)
    assert rows["both"]["mean_error_m"] < min(rows["depth"]["mean_error_m"],
                                              rows["gravity"]["mean_error_m"])  # fmt: skip


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--field", "depth", "--field", "gravity", "--map", "D"], "one --map per --field"),
        (["--field", "depth", "--map", "D", "--map", "G"], "several --map need an MGD77T"),
        (["--field", "depth", "--field", "gravity", "--map", "D", "--map", "D"],
         "is a depth map like an earlier --map"),
        (["--field", "depth", "--field", "gravity", "--map", "D", "--map", "G",
          "--noise-std", "1", "--noise-std", "2", "--noise-std", "3"], "one per --field"),
        (["--field", "depth", "--field", "depth", "--map", "D", "--map", "G"],
         "names a channel twice"),
        (["--field", "gravity", "--field", "depth", "--map", "D", "--map", "G"],
         "--field depth needs a depth map"),
        (["--field", "depth", "--field", "gravity", "--map", "D", "--map", "G",
          "--noise-std", "5", "--noise-std", "0"], "--noise-std of the gravity field"),
    ],
)  # fmt: skip
def test_bad_field_and_map_pairs_end_in_one_error_line(synthetic, extra, message, tmp_path):
    log, paths = synthetic
    names = {"D": paths["depth"], "G": paths["gravity"]}
    extra = [names.get(a, a) for a in extra]
    result = runner.invoke(app, ["replay", str(log), "-m", "pmf", *extra, "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output


def test_a_map_without_its_field_in_the_log_is_refused(synthetic):
    log, paths = synthetic
    mission = quiet(joint_segments, log, ["depth", "gravity"])[1][0]
    grid = load_grid(paths["depth"])
    with pytest.raises(ConfigError, match="gravity field has no map"):
        replay(mission, grid, ["pmf"])
    alone = replace(mission, fields={})
    with pytest.raises(ConfigError, match="a gravity map but no gravity field"):
        replay(alone, grid, ["pmf"], field_grids=[load_grid(paths["gravity"])])
