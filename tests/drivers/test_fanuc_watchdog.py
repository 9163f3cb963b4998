"""The FANUC's controller-side heartbeat watchdog (``WC_HBEAT``, docs/controller-watchdogs.md): FanucRobot writes
the heartbeat register, the fake runs the watchdog program; the fake's own DO state and clock are the
independent reader."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from drivers.fanuc import FanucRobot
from sim_fakes.fake_fanuc import FakeFanucController, HeartbeatProgram

ARC_PORT = 1  # DO[1]: the driver's output index 0
REGISTER = 90
TIMEOUT_S = 0.3
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def fake():
    with FakeFanucController(heartbeat=HeartbeatProgram(REGISTER, TIMEOUT_S, (ARC_PORT,))) as controller:
        yield controller


def exited(pid: int) -> bool:
    """The process has exited (a zombie nobody has reaped yet counts: an orphan waits for init to reap it)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as f:
            return f.read().rsplit(")", 1)[1].split()[0] in ("Z", "X")
    except FileNotFoundError:
        return True


def _wait_arc_off(fake: FakeFanucController, t_from: float, limit_s: float = 3.0) -> float:
    while time.monotonic() - t_from < limit_s:
        if not fake.digital_output(ARC_PORT):
            return time.monotonic() - t_from
        time.sleep(0.005)
    raise AssertionError(f"DO[{ARC_PORT}] still reads on {limit_s} s later")


def test_the_heartbeat_counts_and_keeps_the_arc_on(fake) -> None:
    robot = FanucRobot(fake.host, port=fake.port, heartbeat_register=REGISTER, heartbeat_period_s=0.05)
    robot.connect()
    try:
        robot.set_digital_output(0, True)
        first = fake.register(REGISTER)
        time.sleep(1.0)
        assert fake.register(REGISTER) != first and fake.register(REGISTER) > 0
        assert fake.digital_output(ARC_PORT)
        assert not [e for e in fake.events() if e["kind"] == "heartbeat_lost"]
    finally:
        robot.disconnect()


def test_a_silent_register_is_ignored_until_the_host_has_written_one(fake) -> None:
    robot = FanucRobot(fake.host, port=fake.port)  # no heartbeat: the watchdog stays disarmed
    robot.connect()
    try:
        robot.set_digital_output(0, True)
        time.sleep(4 * TIMEOUT_S)
        assert fake.digital_output(ARC_PORT)
    finally:
        robot.disconnect()


def test_a_dropped_link_switches_the_arc_off_within_the_timeout(fake) -> None:
    robot = FanucRobot(fake.host, port=fake.port, heartbeat_register=REGISTER)
    robot.connect()
    try:
        robot.set_digital_output(0, True)
        time.sleep(0.3)
        t_drop = time.monotonic()
        fake.inject("drop_connection")
        latency = _wait_arc_off(fake, t_drop)
        assert latency < 1.0, latency
        events = fake.events()
        trip = next(e for e in events if e["kind"] == "heartbeat_lost")
        dropped = next(e for e in events if e["kind"] == "fault")
        assert TIMEOUT_S <= trip["silent_s"] < TIMEOUT_S + 0.1  # (rounded to 0.1 ms by the fake)
        assert trip["t"] - dropped["t"] < TIMEOUT_S + 0.1  # the last beat came at most one period before the drop
    finally:
        fake.clear_faults()
        robot.disconnect()


@pytest.mark.parametrize(("period_s", "idle_s", "on_s"), [(0.05, 0.0, 0.3), (0.2, 0.5, 0.0)])
def test_no_answer_switches_the_arc_off_within_the_timeout(fake, period_s: float, idle_s: float, on_s: float) -> None:
    """The controller cut off with the arc on for a while; or idle (the host writes 0: disarmed) and cut off right
    after the arc went on, before the next beat: the output must not go on before a count has reached the
    controller, or a host dying in that moment leaves the arc on with the watchdog off."""
    robot = FanucRobot(fake.host, port=fake.port, heartbeat_register=REGISTER, heartbeat_period_s=period_s,
                       timeout_s=0.5)  # fmt: skip
    robot.connect()
    try:
        time.sleep(idle_s)
        assert idle_s == 0.0 or fake.register(REGISTER) == 0.0
        robot.set_digital_output(0, True)
        time.sleep(on_s)
        t0 = time.monotonic()
        fake.inject("no_answer")
        assert _wait_arc_off(fake, t0) < 1.0
    finally:
        fake.clear_faults()
        robot.disconnect()


@pytest.mark.timeout(60)
def test_a_killed_host_process_stops_the_motion_and_the_arc_within_one_second(fake) -> None:
    script = textwrap.dedent(
        f"""
        import numpy as np
        from drivers.fanuc import FanucRobot
        if __name__ == "__main__":
            robot = FanucRobot({fake.host!r}, port={fake.port}, heartbeat_register={REGISTER})
            robot.connect()
            robot.set_digital_output(0, True)
            X = robot.get_X_base_tool()
            X[0, 3] += 0.3
            print(robot._worker.proc.pid, flush=True)  # the driver's I/O process
            print("moving", flush=True)
            robot.move_linear(X, speed_m_s=0.05, timeout_s=30)
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, env=dict(os.environ, PYTHONPATH=str(REPO)), cwd=REPO
    )
    try:
        assert proc.stdout is not None
        worker_pid = int(proc.stdout.readline())
        assert proc.stdout.readline().strip() == b"moving"
        time.sleep(0.5)
        x_before = fake.xyzwpr_mm_deg()[0]
        assert fake.digital_output(ARC_PORT)
        t_kill = time.monotonic()
        os.kill(proc.pid, signal.SIGKILL)
        assert _wait_arc_off(fake, t_kill) < 1.0
        assert exited(worker_pid)  # the I/O process (and its heartbeat) went with the host
        x_stop = fake.xyzwpr_mm_deg()[0]
        time.sleep(0.5)
        assert fake.xyzwpr_mm_deg()[0] == pytest.approx(x_stop, abs=0.01)  # stopped
        assert x_stop - x_before < 0.05 * 1000 * 1.5  # it moved at most until the watchdog (1.5 s at 50 mm/s)
    finally:
        proc.kill()
        proc.wait(10)


def test_the_watchdog_is_armed_before_an_output_goes_on_and_before_a_motion_is_sent(fake) -> None:
    robot = FanucRobot(fake.host, port=fake.port, heartbeat_register=REGISTER, heartbeat_period_s=0.2)
    robot.connect()
    try:
        time.sleep(0.5)
        robot.set_digital_output(0, True)
        robot.set_digital_output(0, False)
        time.sleep(0.5)  # disarmed again
        X = robot.get_X_base_tool()
        X[0, 3] += 0.002
        robot.move_linear(X, speed_m_s=0.05, timeout_s=10)
        events = fake.events()
        dout_on = next(e for e in events if e["kind"] == "dout" and e["value"])
        armed = [e["t"] for e in events if e["kind"] == "heartbeat_armed"]
        first_motion_s = fake.accepted_records()[0].received_s
        assert len(armed) >= 2
        assert armed[0] < dout_on["t"]
        assert any(dout_on["t"] < t < first_motion_s for t in armed)  # re-armed after the idle spell, before moving
    finally:
        robot.disconnect()
