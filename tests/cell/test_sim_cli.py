"""``weldcell sim up`` with the FANUC example runs its simulators in the foreground and stops on SIGINT/SIGTERM;
``weldcell devices check`` against it passes, and fails with a reason when the track is unreachable."""

from __future__ import annotations

import json
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.config_text import free_port, replace_each_once

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "sim-cell-fanuc.toml"


def example_with(tmp_path: Path, name: str, *, robot_port: int, track_port: int) -> Path:
    """The FANUC example on free ports (a developer may be running the example itself) and a small image."""
    text = replace_each_once(
        EXAMPLE.read_text(encoding="utf-8"),
        (
            ("port = 16001", f"port = {robot_port}"),
            ("port = 5020", f"port = {track_port}"),
            ("resolution = [640, 360]", "resolution = [160, 90]"),
        ),
    )
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def weldcell(*args: str) -> list[str]:
    return [sys.executable, "-m", "cell.cli", *args]


def run_weldcell(*args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(weldcell(*args), cwd=REPO, capture_output=True, text=True, timeout=timeout_s)


class SimUp:
    """``weldcell sim up`` as a child process, its stdout read line by line."""

    def __init__(self, config: Path) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen(
            weldcell("sim", "up", "--config", str(config)),
            cwd=REPO,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.reader = threading.Thread(target=self._read, name="sim-up-reader", daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def read_until(self, marker: str, timeout_s: float) -> list[str]:
        out: list[str] = []
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                if self.proc.poll() is not None and self.lines.empty():
                    break
                continue
            out.append(line)
            if marker in line:
                return out
        stderr = self.proc.stderr.read() if self.proc.poll() is not None and self.proc.stderr else ""
        raise AssertionError(f"no line with {marker!r} within {timeout_s} s; got {out}, stderr {stderr!r}")

    def stop(self, sig: signal.Signals, timeout_s: float) -> tuple[int, float]:
        t0 = time.monotonic()
        self.proc.send_signal(sig)
        code = self.proc.wait(timeout=timeout_s)
        self.reader.join(timeout=2.0)
        return code, time.monotonic() - t0

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=5)
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None:
                stream.close()
        self.reader.join(timeout=2.0)


@pytest.fixture
def ports() -> tuple[int, int]:
    return free_port(), free_port()


@pytest.fixture
def sim(tmp_path: Path, ports: tuple[int, int]) -> Iterator[tuple[SimUp, Path]]:
    config = example_with(tmp_path, "cell.toml", robot_port=ports[0], track_port=ports[1])
    up = SimUp(config)
    try:
        yield up, config
    finally:
        up.kill()


@pytest.mark.timeout(60)
def test_sim_up_prints_its_devices_passes_the_check_and_stops_on_sigint(
    sim: tuple[SimUp, Path], ports: tuple[int, int], tmp_path: Path
) -> None:
    up, config = sim
    lines = up.read_until("running", timeout_s=30)
    assert lines == [
        f"robot   fake-fanuc  127.0.0.1:{ports[0]}  (FANUC RMI)",
        f"track   fake        127.0.0.1:{ports[1]}  (Modbus TCP, unit 1)",
        "camera  fake        in-process  (scene ribs, 160x90, noise stereo; "
        "each client renders from the live robot pose)",
        f"weldcell sim up: {config} running; Ctrl-C or SIGTERM stops it",
    ]

    check = run_weldcell("devices", "check", "--config", str(config))
    assert check.returncode == 0, check.stderr
    out = check.stdout.splitlines()
    assert [line.split()[:4] for line in out] == [
        ["robot", "fake-fanuc", f"127.0.0.1:{ports[0]}", "ok"],
        ["track", "fake", f"127.0.0.1:{ports[1]}", "ok"],
        ["camera", "fake", "in-process", "ok"],
    ]
    assert "mode=idle tool at (0.5000, 0.0000, 0.4000) m" in out[0]
    assert "position=0.0000 m enabled=no moving=no in_position=no fault=no" in out[1]
    assert "frame 160x90, valid depth" in out[2]

    nowhere = free_port()
    broken = example_with(tmp_path, "no-track.toml", robot_port=ports[0], track_port=nowhere)
    check = run_weldcell("devices", "check", "--config", str(broken))
    assert check.returncode == 1
    reason = check.stderr.strip().splitlines()
    assert len(reason) == 1
    assert reason[0].startswith(f"weldcell devices check: track (fake at 127.0.0.1:{nowhere}): unreachable: ")
    assert f"cannot connect to the track's Modbus TCP server at 127.0.0.1:{nowhere}" in reason[0]
    assert check.stdout.splitlines()[0].split()[3] == "ok"  # the robot was still checked, and fine
    assert check.stdout.splitlines()[1].split()[3] == "FAIL"

    code, took_s = up.stop(signal.SIGINT, timeout_s=10)
    assert code == 0
    assert took_s < 5.0
    assert up.read_until("stopped", timeout_s=2) == [
        "weldcell sim up: SIGINT received, stopping",
        "weldcell sim up: stopped",
    ]
    # the ports are free again: nothing was left listening
    for port in ports:
        with socket.socket() as sock:
            sock.bind(("127.0.0.1", port))


@pytest.mark.timeout(60)
def test_sim_up_stops_on_sigterm(sim: tuple[SimUp, Path]) -> None:
    up, _ = sim
    up.read_until("running", timeout_s=30)
    code, took_s = up.stop(signal.SIGTERM, timeout_s=10)
    assert code == 0 and took_s < 5.0
    assert up.read_until("stopped", timeout_s=2)[0] == "weldcell sim up: SIGTERM received, stopping"


@pytest.mark.timeout(60)
def test_devices_check_with_its_own_simulators(tmp_path: Path) -> None:
    config = example_with(tmp_path, "cell.toml", robot_port=free_port(), track_port=free_port())
    check = run_weldcell("devices", "check", "--config", str(config), "--with-sims", "--json")
    assert check.returncode == 0, check.stderr
    report = json.loads(check.stdout)
    assert report["ok"] is True
    assert [(d["role"], d["ok"]) for d in report["devices"]] == [("robot", True), ("track", True), ("camera", True)]
    camera = report["devices"][2]["state"]
    assert (camera["width"], camera["height"]) == (160, 90)
    assert camera["valid_depth_share"] > 0.9
    track = report["devices"][1]["state"]
    assert track == {
        "position_m": 0.0,
        "enabled": False,
        "moving": False,
        "in_position": False,
        "fault": False,
        "fault_code": 0,
    }


@pytest.mark.timeout(30)
def test_bad_config_exits_2_with_the_reason(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text('[robot]\nkind = "fake-fanuc"\nhost = "127.0.0.1"\nhots = 1\n[camera]\nkind = "fake"\n')
    result = run_weldcell("sim", "up", "--config", str(path))
    assert result.returncode == 2
    assert result.stderr.strip() == (
        f"weldcell sim: {path}: robot.hots: unknown key (allowed: kind, name, host, port, dashboard_port, "
        "timeout_s, connect_timeout_s, speed_m_s, max_speed_m_s, accel_m_s2, heartbeat_timeout_s, heartbeat_register)"
    )


# ---------------------------------------------------------------------------------------------- the factory
def _threads(prefixes: tuple[str, ...]) -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith(prefixes)]


@pytest.mark.timeout(60)
def test_factory_builds_a_working_simulated_fanuc_cell_in_process(tmp_path: Path) -> None:
    from cell.config import load_config
    from cell.factory import build_cell
    from drivers.fanuc import FanucRobot
    from drivers.track import ModbusTrack
    from sim_fakes.fake_camera import FakeCamera

    # port 0: the simulators pick free ports and the drivers are pointed at them
    config = load_config(example_with(tmp_path, "cell.toml", robot_port=0, track_port=0))
    with build_cell(config, start_simulators=True) as cell:
        assert isinstance(cell.robot, FanucRobot) and isinstance(cell.track, ModbusTrack)
        assert isinstance(cell.camera, FakeCamera)
        assert cell.simulators is not None
        assert cell.track.port == cell.simulators.track.port != 0
        cell.connect()
        X0 = cell.robot.get_X_base_tool()
        cell.track.enable()
        cell.track.move_to(0.05, speed_m_s=0.3, timeout_s=10)
        assert cell.simulators.track.position_m() == 0.05
        cap = cell.camera.capture(timeout_s=5)
        assert cap.shape == (90, 160)
        assert cell.X_tool_camera is not None and cell.X_tool_camera[0, 3] == 0.032
        assert [d.role for d in cell.simulators.devices()] == ["robot", "track", "camera"]
        assert X0.shape == (4, 4)
    assert _threads(("fake-track", "fake-fanuc", "fanuc-rmi")) == []


@pytest.mark.timeout(10)
def test_factory_refuses_port_0_without_its_simulators(tmp_path: Path) -> None:
    from cell.config import load_config
    from cell.errors import ConfigError
    from cell.factory import build_cell

    path = example_with(tmp_path, "cell.toml", robot_port=0, track_port=free_port())
    with pytest.raises(ConfigError, match=r"robot\.port: port 0"):
        build_cell(load_config(path))
    path = example_with(tmp_path, "cell.toml", robot_port=free_port(), track_port=free_port())
    text = path.read_text().replace('scene = "ribs"', 'scene = "spaceship"')
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"camera\.scene: unknown scene 'spaceship'"):
        build_cell(load_config(path))


@pytest.mark.timeout(60)
def test_factory_builds_a_simulated_ur_cell(tmp_path: Path) -> None:
    pytest.importorskip("rtde_control", reason="the UR driver needs ur-rtde")
    from cell.config import load_config
    from cell.factory import build_cell
    from drivers.ur import URRobot
    from sim_fakes.fake_ur import FakeURController
    from sim_fakes.loopback import free_loopback_host

    text = (REPO / "examples" / "sim-cell.toml").read_text(encoding="utf-8")
    host = free_loopback_host()
    text = text.replace('host = "127.0.0.41"', f'host = "{host}"').replace("port = 5020", f"port = {free_port()}")
    text = text.replace("resolution = [640, 360]", "resolution = [160, 90]")
    path = tmp_path / "ur.toml"
    path.write_text(text, encoding="utf-8")
    with build_cell(load_config(path), start_simulators=True) as cell:
        assert cell.simulators is not None
        assert isinstance(cell.robot, URRobot) and isinstance(cell.simulators.robot, FakeURController)
        cell.connect()
        assert cell.robot.state().healthy
        cap = cell.camera.capture(timeout_s=10)  # the scene sits under the UR's home pose in this example
        assert (cap.depth_m == cap.depth_m).mean() > 0.9
    with socket.socket() as sock, pytest.raises(ConnectionRefusedError):  # the fake UR's process is gone
        sock.connect((host, 30004))
