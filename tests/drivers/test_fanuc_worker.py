"""drivers/fanuc_worker.py: the FANUC driver's I/O process (RMI session and heartbeat) beside a busy host.

The fake controller runs in this test process; the driver runs in a child process that holds its GIL for longer
than the controller's watchdog timeout, as a detection can (a killed host: tests/drivers/test_fanuc_watchdog.py).
The fake's register, outputs and events are the independent reader.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from drivers.errors import ConnectionLost, DriverError, RMIError
from drivers.fanuc import FanucRobot, _error_from
from drivers.fanuc_rmi import ErrorID, RMIMotionRejected
from sim_fakes.fake_fanuc import FakeFanucController, HeartbeatProgram

REPO = Path(__file__).resolve().parents[2]
REGISTER = 90
TIMEOUT_S = 0.3


@pytest.fixture
def fake() -> Iterator[FakeFanucController]:
    with FakeFanucController(heartbeat=HeartbeatProgram(REGISTER, TIMEOUT_S, (1,))) as controller:
        yield controller


def host_script(fake: FakeFanucController, body: str) -> subprocess.Popen[str]:
    """A host process: FanucRobot connected to ``fake`` with the heartbeat, DO[1] on, then ``body``."""
    script = textwrap.dedent(
        f"""
        import os, sys, threading, time
        from drivers.fanuc import FanucRobot
        robot = FanucRobot({fake.host!r}, port={fake.port}, heartbeat_register={REGISTER})
        robot.connect()
        robot.set_digital_output(0, True)
        print(robot._worker.proc.pid, flush=True)
        """
    ) + textwrap.dedent(body)
    return subprocess.Popen(
        [sys.executable, "-c", script],
        stdout=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        cwd=REPO,
    )


@pytest.mark.timeout(60)
def test_the_heartbeat_keeps_counting_while_the_host_holds_its_gil_past_the_watchdog_timeout(fake) -> None:
    # the host moves the arm with the arc on, then holds the GIL for 1.5 s (5 watchdog timeouts): with the switch
    # interval raised, no other thread of that process runs until the loop ends
    proc = host_script(
        fake,
        """
        X = robot.get_X_base_tool()
        X[0, 3] += 0.1
        mover = threading.Thread(target=robot.move_linear, args=(X,), kwargs={"speed_m_s": 0.05, "timeout_s": 30})
        mover.start()
        time.sleep(0.3)
        sys.setswitchinterval(30.0)
        print("holding", flush=True)
        t_end = time.monotonic() + 1.5
        while time.monotonic() < t_end:
            pass
        sys.setswitchinterval(0.005)
        print("released", flush=True)
        robot.stop()
        mover.join()
        robot.set_digital_output(0, False)
        robot.disconnect()
        """,
    )
    try:
        assert proc.stdout is not None
        int(proc.stdout.readline())
        assert proc.stdout.readline().strip() == "holding"
        t_marks = [fake.now_s()]
        seen, t_end = set(), time.monotonic() + 1.2
        while time.monotonic() < t_end:  # sampled while the host's interpreter is held
            seen.add(fake.register(REGISTER))
            time.sleep(0.01)
        assert proc.stdout.readline().strip() == "released"
        t_marks.append(fake.now_s())
        assert fake.digital_output(1)  # still on: the controller saw a live host
        assert proc.wait(timeout=20) == 0
        t_marks.append(fake.now_s())
    finally:
        proc.kill()
        proc.wait(10)
    assert not [e for e in fake.events() if e["kind"] == "heartbeat_lost"], (fake.events(), t_marks, fake.now_s())
    # 1.2 s at one beat per 50 ms: about 24 values; well over half of them even on a loaded machine
    assert len(seen - {0.0}) >= 12, sorted(seen)


def test_disconnect_ends_the_io_process_and_connect_starts_one_again(fake) -> None:
    robot = FanucRobot(fake.host, port=fake.port, heartbeat_register=REGISTER)
    robot.connect()
    worker = robot._worker
    assert worker is not None and worker.alive
    robot.disconnect()
    assert worker.proc.poll() is not None and robot._worker is None
    with pytest.raises(ConnectionLost, match="not connected"):
        robot.state()
    robot.connect()
    try:
        assert robot._worker is not None and robot._worker.proc.pid != worker.proc.pid
        assert robot.state().digital_outputs == (False,) * 8
    finally:
        robot.disconnect()


def test_an_io_process_that_dies_is_a_lost_connection_and_connect_replaces_it(fake) -> None:
    robot = FanucRobot(fake.host, port=fake.port)
    robot.connect()
    try:
        assert robot._worker is not None
        robot._worker.proc.kill()
        robot._worker.proc.wait(5)
        with pytest.raises(ConnectionLost, match="FANUC I/O process"):
            robot.state()
        robot.connect()
        assert robot.state().mode.value in ("idle", "moving")
    finally:
        robot.disconnect()


def test_errors_cross_the_pipe_with_their_type_message_and_code() -> None:
    err = _error_from("fanuc: motion", "RMIMotionRejected", "refused (code 2556939)", int(ErrorID.INVALID_SPEED_VALUE))
    assert isinstance(err, RMIMotionRejected) and isinstance(err, RMIError)
    assert (str(err), err.code) == ("refused (code 2556939)", ErrorID.INVALID_SPEED_VALUE)
    lost = _error_from("fanuc: state", "ConnectionLost", "socket closed", None)
    assert type(lost) is ConnectionLost and str(lost) == "socket closed"
    odd = _error_from("fanuc: state", "KeyError", "'Position'", None)
    assert type(odd) is DriverError and str(odd) == "fanuc: state: KeyError in the FANUC I/O process: 'Position'"
