"""The UR's controller-side host watchdog (docs/controller-watchdogs.md) with the real ur-rtde client and the fake.

The fake is the independent reader: its own snapshot and event log (controller clock) say when the arc output went
low and the program stopped, whatever the driver believes.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rtde_control", reason="ur-rtde is not installed")

from drivers.ur import URRobot
from sim_fakes.fake_ur import FakeURController
from sim_fakes.loopback import free_loopback_host
from tests.drivers.robot_contract import offset

HOST = free_loopback_host()  # this test session's own (the UR ports are fixed)
ARC = 0
HEARTBEAT_TIMEOUT_S = 0.3
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def fake():
    with FakeURController(HOST, program_stop_outputs_low=(ARC,)) as controller:
        yield controller


@pytest.fixture
def robot(fake):
    fake.reset()
    robot = URRobot(HOST, name="ur-wd", heartbeat_timeout_s=HEARTBEAT_TIMEOUT_S)
    robot.connect()
    try:
        yield robot
    finally:
        robot.disconnect()


def _wait_arc_off(fake: FakeURController, t_from: float, limit_s: float = 3.0) -> float:
    """Seconds from ``t_from`` (time.monotonic) until the fake reports the arc output low."""
    while time.monotonic() - t_from < limit_s:
        if not fake.snapshot()["digital_outputs"][ARC]:
            return time.monotonic() - t_from
        time.sleep(0.005)
    raise AssertionError(f"the arc output still reads on {limit_s} s later")


@pytest.mark.timeout(60)
def test_the_heartbeat_keeps_the_program_running_and_the_watchdog_is_armed(robot, fake) -> None:
    robot.set_digital_output(ARC, True)
    time.sleep(1.5)  # five watchdog periods
    snap = fake.snapshot()
    assert snap["program_running"] and snap["digital_outputs"][ARC]
    events = fake.events()
    armed = [e for e in events if e["kind"] == "set_watchdog"]
    assert armed and armed[-1]["min_frequency_hz"] == pytest.approx(1.0 / HEARTBEAT_TIMEOUT_S)
    assert armed[-1]["variable"] == "input_int_register_0" and armed[-1]["action"] == "stop"
    assert not [e for e in events if e["kind"] == "rtde_watchdog"]


@pytest.mark.timeout(60)
def test_a_dropped_link_stops_the_program_and_the_arc_within_the_heartbeat_timeout(robot, fake) -> None:
    robot.set_digital_output(ARC, True)
    X0 = robot.get_X_base_tool()
    import threading

    mover = threading.Thread(
        target=lambda: _swallow(lambda: robot.move_linear(offset(X0, dx=0.15), speed_m_s=0.05, timeout_s=20)),
        daemon=True,
    )
    mover.start()
    time.sleep(0.5)
    t_drop = time.monotonic()
    fake.inject("drop_connection")
    latency = _wait_arc_off(fake, t_drop)
    assert latency < 1.0, latency
    events = fake.events()
    trip = next(e for e in events if e["kind"] == "rtde_watchdog")
    dropped = next(e for e in events if e["kind"] == "fault" and e["fault"] == "drop_connection")
    arc_off = next(e for e in events if e["kind"] == "digital_output" and e.get("cause"))
    # controller clock: the watchdog fired one timeout (plus a cycle or two) after the last heartbeat
    assert HEARTBEAT_TIMEOUT_S < trip["silent_s"] < HEARTBEAT_TIMEOUT_S + 0.1
    assert 0.0 <= arc_off["t"] - dropped["t"] < HEARTBEAT_TIMEOUT_S + 0.15
    time.sleep(0.3)
    snap = fake.snapshot()
    assert not snap["program_running"] and not snap["moving"]
    fake.clear_faults()
    mover.join(10)


def _swallow(fn) -> None:
    with contextlib.suppress(Exception):  # the move ends in an error when the link drops: that is the point
        fn()


@pytest.mark.timeout(60)
def test_a_killed_host_process_stops_the_arm_and_the_arc_within_one_second(fake) -> None:
    fake.reset()
    script = textwrap.dedent(
        f"""
        import sys, time
        from drivers.ur import URRobot
        from tests.drivers.robot_contract import offset
        if __name__ == "__main__":
            robot = URRobot({HOST!r}, name="ur-victim", heartbeat_timeout_s={HEARTBEAT_TIMEOUT_S})
            robot.connect()
            robot.set_digital_output({ARC}, True)
            X0 = robot.get_X_base_tool()
            print("moving", flush=True)
            robot.move_linear(offset(X0, dx=0.15), speed_m_s=0.05, timeout_s=20)
        """
    )
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, env=env, cwd=REPO)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == b"moving"
        time.sleep(0.5)
        assert fake.snapshot()["moving"] and fake.snapshot()["digital_outputs"][ARC]
        t_kill = time.monotonic()
        os.kill(proc.pid, signal.SIGKILL)
        latency = _wait_arc_off(fake, t_kill)
        assert latency < 1.0, latency
        X_a = np.asarray(fake.snapshot()["X_base_tool"])
        time.sleep(0.5)
        snap = fake.snapshot()
        assert not snap["moving"] and not snap["program_running"]
        assert np.linalg.norm(np.asarray(snap["X_base_tool"])[:3, 3] - X_a[:3, 3]) < 0.005  # it stopped there
    finally:
        proc.kill()
        proc.wait(10)


@pytest.mark.timeout(60)
def test_a_path_upload_holds_the_arm_until_the_arc_output_is_back_on(robot, fake) -> None:
    X0 = robot.get_X_base_tool()
    robot.set_digital_output(ARC, True)
    path = [offset(X0, dx=0.01 * (k + 1)) for k in range(5)]
    robot.stream_path(path, speed_m_s=0.05, blend_m=0.001, timeout_s=20)
    assert fake.snapshot()["digital_outputs"][ARC]
    events = fake.events()
    i_path = next(i for i, e in enumerate(events) if e["kind"] == "path")
    after = events[max(0, i_path - 12) :]
    kinds = [(e["kind"], e.get("index"), e.get("value"), e.get("fraction")) for e in after]
    # slider to 0, the new script's program stop switches the arc off, the path starts, the arc is back on,
    # and only then the slider lets the arm move
    i_hold = kinds.index(("speed_slider", None, None, 0.0))
    i_off = next(i for i, e in enumerate(after) if e["kind"] == "digital_output" and e.get("cause"))
    i_start = next(i for i, e in enumerate(after) if e["kind"] == "path")
    i_on = next(i for i, k in enumerate(kinds) if k[:3] == ("digital_output", ARC, True) and i > i_off)
    i_go = next(i for i, k in enumerate(kinds) if k == ("speed_slider", None, None, 1.0) and i > i_hold)
    assert i_hold < i_start < i_on < i_go
    assert i_off < i_on
    armed = [e for e in events if e["kind"] == "set_watchdog"]
    assert armed[-1]["t"] > after[i_off]["t"]  # the path's script was armed too
