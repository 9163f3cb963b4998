"""cell.factory: drivers from the config, simulators started and stopped, fault switches only for simulated cells.

Nothing here connects to a device or starts a fake robot controller (those are the daemon's and the wizard's
tests); the one simulator started is a fake track, on a loopback port another socket already holds.
"""

from __future__ import annotations

import socket
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cell.config import CellConfig, config_from_dict, load_config
from cell.errors import ConfigError
from cell.factory import Cell, DeviceLine, Simulators, build_cell, real_devices, start_simulators
from drivers.errors import DriverError
from drivers.fanuc import FanucRobot
from drivers.track import ModbusTrack
from drivers.ur import URRobot
from sim_fakes.board_render import RenderParams
from sim_fakes.fake_camera import FakeCamera

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def example(name: str, **tables: dict[str, Any]) -> CellConfig:
    """An example config with some of its tables' keys replaced."""
    data = tomllib.loads((EXAMPLES / name).read_text(encoding="utf-8"))
    for table, keys in tables.items():
        data[table] = {**data.get(table, {}), **keys}
    return config_from_dict(data, source=EXAMPLES / name)


def test_the_fanuc_example_builds_its_drivers_unconnected_with_the_configured_addresses() -> None:
    cell = build_cell(load_config(EXAMPLES / "sim-cell-fanuc.toml"))
    assert isinstance(cell.robot, FanucRobot) and isinstance(cell.track, ModbusTrack)
    assert isinstance(cell.camera, FakeCamera) and cell.simulators is None and cell.X_tool_camera is not None
    assert [role for role, _ in cell.devices()] == ["robot", "track", "camera"]
    assert cell.camera.describe() == "scene ribs, 640x360, noise stereo"
    cell.close()  # nothing was connected: closing is harmless


def test_the_ur_calibration_example_shows_the_configured_board_to_the_fake_camera() -> None:
    config = load_config(EXAMPLES / "sim-calib.toml")
    cell = build_cell(config)
    assert isinstance(cell.robot, URRobot) and isinstance(cell.camera, FakeCamera)
    assert config.hand_eye is not None and config.hand_eye.calibration is not None
    board = config.hand_eye.calibration.board.spec()
    assert cell.camera.board is not None and cell.camera.board.board == board
    np.testing.assert_allclose(cell.camera.board.X_base_board, config.camera.X_base_board)
    assert cell.camera.board.imaging == RenderParams(blur_sigma_px=0.6, noise_sigma=2.0)  # the example's keys
    assert cell.camera.describe().startswith(f"scene charuco ({board.squares_x}x{board.squares_y} board), 640x360")


def test_a_track_of_kind_none_builds_no_driver() -> None:
    cell = build_cell(example("sim-cell-fanuc.toml", track={"kind": "none"}))
    assert cell.track is None and [role for role, _ in cell.devices()] == ["robot", "camera"]


def test_port_0_cannot_be_reached_from_another_process() -> None:
    with pytest.raises(ConfigError, match=r"port 0 .* cannot be reached from another process"):
        build_cell(example("sim-cell-fanuc.toml", robot={"port": 0}))
    with pytest.raises(ConfigError, match=r"track\.port.*port 0"):
        build_cell(example("sim-cell-fanuc.toml", track={"port": 0}))


def test_real_devices_are_named_with_their_kind() -> None:
    assert real_devices(load_config(EXAMPLES / "sim-cell-fanuc.toml")) == []
    real = example("sim-cell-fanuc.toml", robot={"kind": "fanuc"}, track={"kind": "modbus"})
    assert real_devices(real) == ["robot.kind = 'fanuc'", "track.kind = 'modbus'"]


def test_fault_switches_are_refused_for_real_hardware_and_for_simulators_in_another_process() -> None:
    real = build_cell(example("sim-cell-fanuc.toml", robot={"kind": "fanuc"}))
    with pytest.raises(ConfigError, match=r"simulated cells only, and robot\.kind = 'fanuc' is real hardware"):
        real.fault_injectors()
    elsewhere = build_cell(load_config(EXAMPLES / "sim-cell-fanuc.toml"))
    with pytest.raises(ConfigError, match="needs the simulators in this process"):
        elsewhere.fault_injectors()


def test_the_simulators_listing_names_every_device_and_its_address() -> None:
    config = load_config(EXAMPLES / "sim-cell-fanuc.toml")
    sims = Simulators(config, robot_address=("127.0.0.1", 16001), track_address=("127.0.0.1", 5020))
    assert [line.format() for line in sims.devices()] == [
        "robot   fake-fanuc  127.0.0.1:16001  (FANUC RMI)",
        "track   fake        127.0.0.1:5020  (Modbus TCP, unit 1)",
        "camera  fake        in-process  (scene ribs, 640x360, noise stereo; each client renders from the live "
        "robot pose)",
    ]
    nothing_started = Simulators(config)
    assert nothing_started.devices()[0] == DeviceLine(
        "robot", "fake-fanuc", "127.0.0.1:16001", "real controller, not simulated"
    )
    ur = Simulators(load_config(EXAMPLES / "sim-cell.toml"), robot_address=("127.0.0.41", 30004))
    assert ur.devices()[0].format().startswith("robot   fake-ur     127.0.0.41:30004  (30004 (RTDE), 29999")


def test_a_simulator_that_cannot_start_is_a_driver_error_naming_the_config() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        config = example("sim-cell-fanuc.toml", robot={"kind": "fanuc"}, track={"port": port})
        with pytest.raises(DriverError, match=r"cannot start the simulators of .*sim-cell-fanuc\.toml"):
            start_simulators(config)


class Device:
    def __init__(self, name: str, log: list[str], *, fails: bool = False) -> None:
        self.name, self.log, self.fails = name, log, fails

    def connect(self) -> None:
        self.log.append(f"connect {self.name}")

    def disconnect(self) -> None:
        self.log.append(f"disconnect {self.name}")
        if self.fails:
            raise OSError(f"{self.name} would not let go")


def test_close_releases_every_device_camera_first_even_when_one_fails_and_stops_the_simulators() -> None:
    log: list[str] = []
    sims = Simulators(load_config(EXAMPLES / "sim-cell-fanuc.toml"))
    sims._stops.extend([lambda: log.append("stop robot fake"), lambda: log.append("stop track fake")])
    cell = Cell(sims.config, Device("robot", log), Device("track", log, fails=True), Device("camera", log),  # type: ignore[arg-type]
                None, sims)  # fmt: skip
    cell.connect()
    cell.close()
    assert log == [
        "connect robot",
        "connect track",
        "connect camera",
        "disconnect camera",
        "disconnect track",
        "disconnect robot",
        "stop track fake",  # last started first
        "stop robot fake",
    ]
    sims.stop()  # a second stop does nothing
    assert len(log) == 8
