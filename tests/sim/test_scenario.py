"""Scenario files: loading, validation messages naming the bad key, simulation from YAML."""

from pathlib import Path

import numpy as np
import pytest

from geofix.errors import ConfigError
from geofix.maps.grid import Grid
from geofix.sim import load_scenario, simulate_trial

VALID = """\
name: yaml-case
map: {path: maps/field.nc, variable: z, kind: depth, resample_m: 20}
track: {start_m: [1000, 1200], heading_deg: 300, speed_m_s: 3, interval_s: 4,
        samples: 15, legs: 2, turn_std_deg: 5}
sensor: {type: multibeam, beams: 5, swath_width_m: 60, noise_std: 0.3}
ins: {initial_error_m: [30, 30], gyro_bias_deg_h: 0.04, gyro_noise_deg_rt_h: 0.002,
      accel_bias_ug: 100, accel_noise_ug_rt_hz: 50}
dvl: {noise_std_m_s: 0.02}
trials: 4
seed: 9
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "case.yaml"
    path.write_text(text)
    return path


def test_valid_scenario_loads_with_defaults_and_resolves_the_map(tmp_path):
    sc = load_scenario(write(tmp_path, VALID))
    assert sc.name == "yaml-case" and sc.trials == 4 and sc.seed == 9
    assert sc.track.legs == 2 and sc.track.start_m == (1000.0, 1200.0)
    assert sc.sensor.edge_noise_factor == 2.0 and sc.ins.schuler is True
    assert sc.dvl is not None and sc.dvl.bias_m_s == 0.0
    assert Path(sc.map_path()) == tmp_path / "maps" / "field.nc"


def test_scenario_from_yaml_simulates(tmp_path):
    sc = load_scenario(write(tmp_path, VALID))
    x = np.arange(150) * 20.0
    xx, yy = np.meshgrid(x, x)
    grid = Grid(-40.0 + 3.0 * np.sin(xx / 90.0) * np.cos(yy / 70.0), 0.0, 0.0, 20.0, 20.0)
    trial = simulate_trial(sc, grid, 3)
    assert trial.measured.shape == (30, 5)
    assert trial.dvl_velocity.shape == (30, 2)
    assert np.all(np.isfinite(trial.measured))


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ("speed_m_s: 3", "speed_m_s: -3", "track.speed_m_s"),
        ("samples: 15", "samples: 1", "track.samples"),
        ("noise_std: 0.3}", "noise_std: 0.3, bogus: 1}", "sensor.bogus"),
        ("type: multibeam", "type: sidescan", "sensor.type"),
        ("accel_bias_ug: 100", "accel_bias_ug: -1", "ins.accel_bias_ug"),
        ("trials: 4", "trials: 0", "trials"),
        ("name: yaml-case", "name: ' '", "name"),
    ],
)
def test_validation_errors_name_the_bad_key(tmp_path, old, new, key):
    assert old in VALID
    path = write(tmp_path, VALID.replace(old, new))
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    message = str(info.value)
    assert message.startswith(str(path))
    assert f"{key}:" in message
    assert "\n" not in message


def test_unknown_key_is_called_unknown(tmp_path):
    path = write(tmp_path, VALID.replace("noise_std: 0.3}", "noise_std: 0.3, bogus: 1}"))
    with pytest.raises(ConfigError, match=r"sensor\.bogus: unknown key"):
        load_scenario(path)


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ("noise_std: 0.3}", "noise_std: 0.3, nois_std: 1}", r"sensor\.nois_std: .*'noise_std'"),
        ("trials: 4", "trials: 4\ntrails: 4", r"trails: unknown key \(did you mean 'trials'\?\)"),
        ("trials: 4", "trials: 4\nseabed: {ofset: 2.0}", r"seabed\.ofset: .*'offset'"),
    ],
)
def test_a_misspelt_key_gets_the_closest_known_key(tmp_path, old, new, expected):
    path = write(tmp_path, VALID.replace(old, new))
    with pytest.raises(ConfigError, match=expected):
        load_scenario(path)


def test_an_unknown_key_far_from_every_known_key_gets_no_suggestion(tmp_path):
    path = write(tmp_path, VALID.replace("trials: 4", "trials: 4\nzzzz: 1"))
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    assert "zzzz: unknown key" in str(info.value)
    assert "did you mean" not in str(info.value)


def test_missing_file_bad_yaml_and_non_mapping(tmp_path):
    with pytest.raises(ConfigError, match="cannot read scenario"):
        load_scenario(tmp_path / "absent.yaml")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_scenario(write(tmp_path, "name: [unclosed"))
    with pytest.raises(ConfigError, match="mapping"):
        load_scenario(write(tmp_path, "- a\n- b\n"))
