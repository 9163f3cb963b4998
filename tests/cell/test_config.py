"""The cell config: the examples load; every kind of mistake is a ConfigError naming the file and the key."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cell.config import CellConfig, config_from_dict, load_config
from cell.errors import ConfigError

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

X_TOOL_CAMERA = [[0.0, -1.0, 0.0, 0.032], [1.0, 0.0, 0.0, -0.061], [0.0, 0.0, 1.0, 0.045], [0.0, 0.0, 0.0, 1.0]]

MINIMAL = """\
[robot]
kind = "fanuc"
host = "192.0.2.10"

[camera]
kind = "oakd"
"""


def write(tmp_path: Path, text: str, name: str = "cell.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def error_of(path: Path) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    return str(info.value)


# ---------------------------------------------------------------------------------------------- valid files
def test_ur_example_loads() -> None:
    config = load_config(EXAMPLES / "sim-cell.toml")
    assert isinstance(config, CellConfig)
    assert (config.robot.kind, config.robot.host, config.robot.port) == ("fake-ur", "127.0.0.41", None)
    assert (config.track.kind, config.track.port, config.track.counts_per_m) == ("fake", 5020, 100_000)
    assert config.track.soft_limits_m == (0.0, 2.5)
    assert (config.camera.kind, config.camera.scene, config.camera.size) == ("fake", "ribs", (640, 360))
    assert config.camera.X_base_world is not None
    assert np.array_equal(np.asarray(config.X_tool_camera()), np.array(X_TOOL_CAMERA))
    assert config.source == EXAMPLES / "sim-cell.toml"


def test_fanuc_example_loads() -> None:
    config = load_config(EXAMPLES / "sim-cell-fanuc.toml")
    assert (config.robot.kind, config.robot.host, config.robot.rmi_port) == ("fake-fanuc", "127.0.0.1", 16001)
    assert (config.robot.timeout_s, config.robot.speed_m_s, config.robot.max_speed_m_s) == (2.0, 0.1, 0.5)
    assert (config.track.unit_id, config.track.timeout_s, config.track.in_position_window_m) == (1, 1.0, 0.0002)
    assert config.camera.X_base_world is None
    assert np.array_equal(np.asarray(config.X_tool_camera()), np.array(X_TOOL_CAMERA))


def test_minimal_config_takes_defaults_and_no_track(tmp_path: Path) -> None:
    config = load_config(write(tmp_path, MINIMAL))
    assert config.track.kind == "none"
    assert config.robot.rmi_port == 16001
    assert config.camera.size == (1280, 720)
    assert config.X_tool_camera() is None
    with pytest.raises(ConfigError):
        _ = config.track.soft_limits_m


def test_hand_eye_file_is_read_relative_to_the_config(tmp_path: Path) -> None:
    (tmp_path / "calib").mkdir()
    document = {"format": "weldcell-hand-eye/1", "X_tool_camera": X_TOOL_CAMERA, "rms_mm": 0.4}
    (tmp_path / "calib" / "hand_eye.json").write_text(json.dumps(document))
    config = load_config(write(tmp_path, MINIMAL + '\n[hand_eye]\npath = "calib/hand_eye.json"\n'))
    assert np.array_equal(np.asarray(config.X_tool_camera()), np.array(X_TOOL_CAMERA))


# ---------------------------------------------------------------------------------------------- mistakes
def test_unknown_key_names_file_key_and_allowed_keys(tmp_path: Path) -> None:
    path = write(tmp_path, MINIMAL.replace('host = "192.0.2.10"', 'host = "192.0.2.10"\nhots = "x"'))
    message = error_of(path)
    assert message.startswith(f"{path}: robot.hots: unknown key (allowed: kind, name, host, port,")


def test_unknown_section_is_refused(tmp_path: Path) -> None:
    path = write(tmp_path, MINIMAL + "\n[welder]\ncurrent_a = 180\n")
    assert error_of(path) == (
        f"{path}: welder: unknown key (allowed: robot, track, camera, hand_eye, home, fixture, safety, welding, "
        "detection, daemon)"
    )


def test_wrong_type_names_file_key_and_value(tmp_path: Path) -> None:
    path = write(tmp_path, MINIMAL.replace('kind = "fanuc"', 'kind = "fanuc"\nport = "16001"'))
    assert error_of(path) == f"{path}: robot.port: Input should be a valid integer (got '16001')"
    path = write(tmp_path, MINIMAL.replace('kind = "oakd"', 'kind = "oakd"\nresolution = [1280, "720"]'))
    assert error_of(path) == f"{path}: camera.resolution[1]: Input should be a valid integer (got '720')"
    path = write(tmp_path, MINIMAL.replace('kind = "fanuc"', 'kind = "kuka"'))
    assert error_of(path) == (
        f"{path}: robot.kind: Input should be 'ur', 'fanuc', 'fake-ur' or 'fake-fanuc' (got 'kuka')"
    )


def test_every_mistake_of_a_file_is_listed(tmp_path: Path) -> None:
    path = write(tmp_path, '[robot]\nkind = "fanuc"\ntimeout_s = -1\n\n[track]\nkind = "modbus"\n')
    message = error_of(path)
    assert message == (
        f"{path}: robot.host: required key is missing; "
        "robot.timeout_s: Input should be greater than 0 (got -1); "
        "track: kind = 'modbus' needs host, counts_per_m, soft_limit_min_m, soft_limit_max_m; "
        "camera: required key is missing"
    )


def test_missing_file_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "nowhere.toml"
    assert error_of(path) == f"{path}: config file does not exist"


def test_malformed_toml_names_file_line_and_key(tmp_path: Path) -> None:
    path = write(tmp_path, MINIMAL.replace('host = "192.0.2.10"', "host = 192.0.2.10"))
    message = error_of(path)
    assert message.startswith(f"{path}: malformed TOML: ")
    assert message.endswith("; robot.host (line 3: 'host = 192.0.2.10')")
    path = write(tmp_path, MINIMAL + "\n[track\nkind = 'none'\n")
    message = error_of(path)
    assert message.startswith(f"{path}: malformed TOML: ") and "(line 8: '[track')" in message


def test_kind_specific_rules(tmp_path: Path) -> None:
    cases = {
        'kind = "fake-fanuc"\nhost = "192.0.2.10"': "robot: a fake-fanuc simulator binds a loopback address",
        'kind = "ur"\nhost = "192.0.2.10"\nport = 30004': "robot: UR controllers use fixed RTDE/script ports",
        'kind = "fanuc"\nhost = "192.0.2.10"\nspeed_m_s = 0.6': "robot: speed_m_s=0.6 exceeds max_speed_m_s=0.5",
    }
    for robot, expected in cases.items():
        path = write(tmp_path, f'[robot]\n{robot}\n\n[camera]\nkind = "fake"\n')
        assert error_of(path).startswith(f"{path}: {expected}")
    limits = '[track]\nkind = "fake"\nhost = "127.0.0.1"\ncounts_per_m = 1000\nsoft_limit_min_m = 1.0\n'
    path = write(tmp_path, MINIMAL + limits + "soft_limit_max_m = 0.5\n")
    assert error_of(path) == f"{path}: track: soft_limit_min_m (1.0) must be below soft_limit_max_m (0.5)"
    path = write(tmp_path, MINIMAL.replace('kind = "oakd"', 'kind = "oakd"\nresolution = [1000, 720]'))
    assert "camera: an OAK-D's aligned depth needs a width that is a multiple of 16" in error_of(path)


def test_hand_eye_mistakes(tmp_path: Path) -> None:
    path = write(tmp_path, MINIMAL + "\n[hand_eye]\nX_tool_camera = [[1.0, 0.0], [0.0, 1.0]]\n")
    assert error_of(path) == f"{path}: hand_eye: X_tool_camera: expected shape (4, 4), got (2, 2)"
    path = write(tmp_path, MINIMAL + '\n[hand_eye]\npath = "he.json"\nX_tool_camera = []\n')
    assert error_of(path) == f"{path}: hand_eye: give exactly one of 'path' and 'X_tool_camera'"
    config = load_config(write(tmp_path, MINIMAL + '\n[hand_eye]\npath = "missing.json"\n'))
    with pytest.raises(ConfigError, match=r"cell\.toml: hand_eye\.path: cannot read the hand-eye file"):
        config.X_tool_camera()
    (tmp_path / "bad.json").write_text('{"format": "weldcell-hand-eye/1", "X_base_tool": []}')
    config = load_config(write(tmp_path, MINIMAL + '\n[hand_eye]\npath = "bad.json"\n'))
    with pytest.raises(ConfigError, match=r"cell\.toml: hand_eye\.path: the hand-eye file .* no 'X_tool_camera' key"):
        config.X_tool_camera()
    # a capture's pose.json is not a result file: the format is checked
    (tmp_path / "pose.json").write_text(json.dumps({"X_tool_camera": X_TOOL_CAMERA}))
    config = load_config(write(tmp_path, MINIMAL + '\n[hand_eye]\npath = "pose.json"\n'))
    with pytest.raises(ConfigError, match=r"hand_eye\.path: the hand-eye file .*pose\.json has no 'format' key"):
        config.X_tool_camera()


def test_playback_folders_resolve_and_must_exist(tmp_path: Path) -> None:
    for name in ("b", "a"):
        (tmp_path / "shots" / name).mkdir(parents=True)
        (tmp_path / "shots" / name / "camera.json").write_text("{}")
    fake = MINIMAL.replace('kind = "oakd"', 'kind = "fake"\nplayback = ["shots", "shots/b"]')
    config = load_config(write(tmp_path, fake))
    assert config.playback_folders() == [tmp_path / "shots/a", tmp_path / "shots/b", tmp_path / "shots/b"]
    config = load_config(write(tmp_path, MINIMAL.replace('kind = "oakd"', 'kind = "fake"\nplayback = ["gone"]')))
    with pytest.raises(ConfigError, match=r"camera\.playback\[0\]: .*gone does not exist"):
        config.playback_folders()


def test_config_from_dict_without_a_file() -> None:
    with pytest.raises(ConfigError) as info:
        config_from_dict({"robot": {"kind": "fanuc", "host": "192.0.2.10"}})
    assert str(info.value) == "camera: required key is missing"
