"""The command line: the ``geofix run`` JSON contract, listings, and one-line errors."""

import json
import os
import subprocess
import sys

import pytest
import yaml
from typer.testing import CliRunner

from geofix.cli import app

runner = CliRunner()

SUCCESS_KEYS = {"20", "40", "60", "80", "100", "0.5c", "1c", "2c", "3c"}
METHOD_KEYS = {
    "trials",
    "mean_error_m",
    "std_error_m",
    "median_error_m",
    "max_error_m",
    "mean_track_error_m",
    "max_track_error_m",
    "success_rate",
    "mean_time_s",
    "failures",
}


@pytest.fixture
def scenario_file(tmp_path, small_mission):
    data = small_mission("cli-small", trials=4).model_dump(mode="json", exclude={"base_dir"})
    path = tmp_path / "scen.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_run_json_contract(scenario_file, tmp_path):
    out = tmp_path / "out"
    args = ["run", str(scenario_file), "--method", "tercom", "--method", "tercom:metric=mad"]
    result = runner.invoke(
        app, [*args, "--trials", "3", "--jobs", "1", "--out", str(out), "--json"]
    )
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert payload["scenario"] == "cli-small"
    assert payload["trials"] == 3
    assert set(payload["methods"]) == {"tercom", "tercom:metric=mad"}
    for stats in payload["methods"].values():
        assert set(stats) >= METHOD_KEYS
        assert set(stats["success_rate"]) == SUCCESS_KEYS
        assert stats["trials"] == 3
        assert stats["mean_error_m"] < 1000.0  # a fix, not the 1.8 km INS error
    assert (out / "results.sqlite").exists()


def test_run_valid_bound_lands_in_the_summary_and_the_table(tmp_path, small_mission):
    data = small_mission("cli-valid", trials=2, track={"samples": 8})
    path = tmp_path / "scen.yaml"
    path.write_text(yaml.safe_dump(data.model_dump(mode="json", exclude={"base_dir"})))
    out = tmp_path / "out"
    args = ["run", str(path), "-m", "tercom", "--jobs", "1", "--out", str(out), "--valid-bound"]
    result = runner.invoke(app, args, env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    end, track = summary["valid_bound_m"], summary["valid_bound_track_m"]
    assert end > 0 and track > 0
    assert summary["crlb_m"] > 0 and set(summary["methods"]["tercom"]) >= METHOD_KEYS
    text = " ".join(result.output.split())
    assert f"valid bound: {end:.1f} m at the end, {track:.1f} m along the track" in text
    plain = runner.invoke(app, [*args[:-1], "--json"])  # resumed, the bound not asked for
    assert plain.exit_code == 0, plain.output
    assert "valid_bound_m" not in json.loads(plain.stdout)


def test_json_stdout_is_only_json_in_a_real_process(scenario_file, tmp_path):
    cmd = [sys.executable, "-m", "geofix", "run", str(scenario_file), "--method", "tercom"]
    cmd += ["--trials", "2", "--jobs", "1", "--out", str(tmp_path / "o"), "--json"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["trials"] == 2


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"map": {"path": "nowhere.nc"}}, "nowhere.nc"),
        ({"map": {"path": "builtin:mb_1km", "variable": "bogus"}}, "bogus"),
        (
            {
                "track": {
                    "start_cell": [158, 158],
                    "heading_deg": 45,
                    "speed_m_s": 10,
                    "interval_s": 60,
                    "samples": 20,
                }
            },
            "leaves the map",
        ),
        ({"sensor": {"type": "sonar"}}, "sensor.type"),
        ({"trials": "many"}, "trials"),
        ({"bogus_key": 1}, "bogus_key"),
    ],
)
def test_bad_input_gives_one_clear_line(scenario_file, tmp_path, change, message):
    data = yaml.safe_load(scenario_file.read_text())
    data.update(change)
    scenario_file.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    result = runner.invoke(app, ["run", str(scenario_file), "-m", "tercom", "--out", str(out)])
    assert result.exit_code == 2
    assert "Traceback" not in result.output
    assert message in result.output
    assert not (out / "results.sqlite").exists()


def test_unknown_method_and_missing_scenario(scenario_file, tmp_path):
    result = runner.invoke(app, ["run", str(scenario_file), "-m", "nosuch", "--out", str(tmp_path)])
    assert result.exit_code == 2
    assert "unknown method" in result.output
    result = runner.invoke(app, ["run", str(tmp_path / "none.yaml"), "-m", "tercom"])
    assert result.exit_code == 2
    assert "cannot read scenario" in result.output


def test_methods_lists_every_method_in_one_line_each():
    from geofix.methods import available_methods

    result = runner.invoke(app, ["methods"], terminal_width=200)
    assert result.exit_code == 0
    lines = result.output.splitlines()
    for name in available_methods():
        assert sum(f"│ {name} " in line for line in lines) == 1, name
    assert len(lines) < 2 * len(available_methods()) + 10


def test_methods_name_describes_every_setting():
    from geofix.methods import method_settings, setting_descriptions

    result = runner.invoke(app, ["methods", "tercom"], terminal_width=250)
    assert result.exit_code == 0
    assert "window_sigma" in result.output and "'msd'" in result.output
    assert "Half-side of the" in result.output
    for cls_name in ("Tercom", "TercomIcp", "Pmf", "GaSca"):
        import geofix

        notes = setting_descriptions(getattr(geofix, cls_name))
        assert set(notes) == {row[0] for row in method_settings(getattr(geofix, cls_name))}
        assert all(notes.values()), cls_name  # every setting documented
    result = runner.invoke(app, ["methods", "nosuch"])
    assert result.exit_code == 2 and "unknown method 'nosuch'" in result.output


def test_every_setting_of_every_method_has_a_real_description():
    from geofix.methods import available_methods, method_summary, setting_descriptions

    for name, cls in available_methods().items():
        summary = method_summary(cls)
        assert summary and ":class:" not in summary and "settings" not in summary, name
        for setting, note in setting_descriptions(cls).items():
            assert note.strip(" .") and "..." not in note, f"{name}:{setting} {note!r}"
            assert "``" not in note and ":class:" not in note, f"{name}:{setting}"


def test_parameter_parser_reads_name_lists_and_continued_entries():
    import dataclasses

    from geofix.methods import setting_descriptions

    @dataclasses.dataclass(frozen=True)
    class Fake:
        """A fake method.

        Parameters
        ----------
        tolerance_m, tolerance_rad : float
            Stop when a step moves less than these (metres, radians).
        first : int
            Go on when the count is above this...
        second : float
            ... or the share is below this.
        """

        tolerance_m: float = 1.0
        tolerance_rad: float = 0.1
        first: int = 1
        second: float = 0.5

    notes = setting_descriptions(Fake)
    assert (
        notes["tolerance_m"]
        == notes["tolerance_rad"]
        == ("Stop when a step moves less than these (metres, radians).")
    )
    assert notes["first"] == "Go on when the count is above this."
    assert notes["second"] == "Go on when the count is above this, or the share is below this."


@pytest.mark.parametrize(
    ("spec", "hint"),
    [
        ("pfm", "did you mean 'pmf'?"),
        ("tercm", "did you mean 'tercom'?"),
        ("sitanbank", "did you mean 'sitan-bank'?"),
        ("PMF", "did you mean 'pmf'?"),
        ("tercom:metrc=mad", "did you mean 'metric'?"),
        ("pf:particle=50", "did you mean 'particles'?"),
    ],
)
def test_a_misspelt_method_or_setting_gets_the_closest_name(spec, hint):
    from geofix.errors import ConfigError
    from geofix.methods import parse_method_spec

    with pytest.raises(ConfigError, match=hint):
        parse_method_spec(spec)


def test_a_name_far_from_every_method_gets_no_guess(scenario_file, tmp_path):
    from geofix.errors import ConfigError
    from geofix.methods import parse_method_spec

    with pytest.raises(ConfigError) as info:
        parse_method_spec("kalman-smoother")
    assert "did you mean" not in str(info.value)
    result = runner.invoke(app, ["methods", "pfm"])
    assert result.exit_code == 2 and "did you mean 'pmf'?" in result.output
    args = ["run", str(scenario_file), "-m", "pfm", "--out", str(tmp_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 2 and "did you mean 'pmf'?" in result.output


@pytest.mark.parametrize("args", [["methods"], ["methods", "pmf"], ["methods", "iccp"], ["maps"]])
def test_piped_tables_fit_80_columns(args):
    env = {k: v for k, v in os.environ.items() if k != "COLUMNS"}
    cmd = [sys.executable, "-m", "geofix", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=60, check=True)
    lines = proc.stdout.splitlines()
    assert len(lines) > 5
    assert max(map(len, lines)) <= 80, max(lines, key=len)


def test_version():
    import geofix

    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0
    assert result.output.strip() == f"geofix {geofix.__version__}"


def test_maps_lists_bundled_maps_with_provenance():
    result = runner.invoke(app, ["maps"])
    assert result.exit_code == 0
    for name in ("azores", "alaska_gravity", "navo_flat"):
        assert name in result.output


def test_progress_phases_print_at_once_without_a_thread(capsys, monkeypatch):
    import threading

    from geofix.console import ProgressBar

    with ProgressBar("piped") as bar:
        bar.phase("preparing the map")  # not a terminal: stderr stays quiet
    assert "preparing" not in capsys.readouterr().err
    monkeypatch.setenv("FORCE_COLOR", "1")  # rich then draws as on a terminal
    before = threading.active_count()
    with ProgressBar("demo") as bar:
        bar.phase("preparing the map")
        assert threading.active_count() == before  # a campaign may still fork its workers
        bar(0, 4)
        bar.phase("late")  # once the bar runs, phases are not printed
        bar(4, 4)
    err = capsys.readouterr().err
    assert "demo" in err and ": preparing the map..." in err and "late" not in err


def test_summary_table_shows_the_crlb_beside_the_rms_error():
    import io

    from rich.console import Console

    from geofix.console import summary_table
    from geofix.evaluate.summary import CampaignSummary, MethodStats

    stats = MethodStats(trials=4, mean_error_m=50.0, rms_error_m=61.25, success_rate={"100": 1})
    summary = CampaignSummary("s", 4, crlb_m=12.5, crlb_track_m=30.0, methods={"pmf": stats})
    console = Console(file=io.StringIO(), width=80)
    console.print(summary_table(summary, width=80))
    text = console.file.getvalue()
    assert "CRLB on the RMS error: 12.5 m at the end, 30.0 m along the track" in " ".join(
        text.split()
    )
    assert "rms" in text and "61.2" in text
    no_bound = CampaignSummary("s", 4, methods={"pmf": stats})
    assert "CRLB" not in str(summary_table(no_bound).title)


def test_replay_table_carries_the_nees_of_converged_beside_the_end_error(monkeypatch):
    import io

    from rich.console import Console

    from geofix import cli

    monkeypatch.setattr(cli, "_out", Console(file=io.StringIO(), width=120))
    row = {"end_error_m": 7.64, "mean_error_m": 9.6, "max_error_m": 33.6, "reinits": 0}
    summary = {
        "pings": 50,
        "methods": {
            "pmf": {**row, "converged_at_s": 137.3, "converged_nees": 1.305},
            "pf": {**row, "converged_at_s": None, "converged_nees": None},
        },
    }
    cli._print_replay(summary)
    text = " ".join(cli._out.file.getvalue().split())
    assert "┃ method ┃ end error m ┃ converged NEES ┃ mean error m ┃" in text
    assert "│ pmf │ 7.6 │ 1.3 │ 9.6 │ 33.6 │ 137.3 │ 0 │" in text
    assert "│ pf │ 7.6 │ - │ 9.6 │ 33.6 │ - │ 0 │" in text
