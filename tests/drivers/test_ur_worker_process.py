"""The UR driver's worker process (drivers/ur_worker.py) against the fake UR (sim_fakes/fake_ur/): its status
channel answers while a request holds the control interface, and it (like the fake) ends on SIGTERM even when
started by a parent that ignored the signal (weldcell serve does while its devices start).
"""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rtde_control", reason="ur-rtde is not installed")

from drivers.protocols import RobotMode
from drivers.ur import URRobot
from sim_fakes.fake_ur import FakeURController
from sim_fakes.loopback import free_loopback_host
from tests.drivers.robot_contract import offset

HOST = free_loopback_host()


@pytest.mark.timeout(60)
def test_state_answers_while_a_paths_upload_holds_the_worker() -> None:
    # the path's script starts 1.5 s after it arrives: the upload request holds the worker's request pipe that long
    with FakeURController(HOST, program_start_delay_s=1.5) as fake:
        robot = URRobot(HOST, name="ur-status")
        robot.connect()
        try:
            X0 = robot.get_X_base_tool()
            path = [offset(X0, dx=0.002 * i) for i in range(1, 6)]
            streamer = threading.Thread(target=robot.stream_path, args=(path,), kwargs={"speed_m_s": 0.05})
            streamer.start()
            time.sleep(0.5)  # the upload is under way
            took = []
            for _ in range(5):
                t0 = time.monotonic()
                st = robot.state()
                took.append(time.monotonic() - t0)
                assert st.mode is RobotMode.IDLE and not st.is_moving  # held at the start while the script starts
                np.testing.assert_allclose(st.X_base_tool, fake.X_base_tool(), atol=1e-6)
                time.sleep(0.1)
            assert streamer.is_alive(), "the upload was not held: the test measured nothing"
            assert max(took) < 0.3, took  # through the request pipe each read waited for the upload (about 1 s)
            streamer.join(20.0)
            np.testing.assert_allclose(robot.get_X_base_tool(), path[-1], atol=1e-5)
        finally:
            robot.disconnect()


@pytest.mark.timeout(60)
def test_the_fake_and_the_worker_end_on_sigterm_though_started_with_it_ignored() -> None:
    previous = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        fake = FakeURController(HOST).start()
        robot = URRobot(HOST, name="ur-sigterm")
        robot.connect()
    finally:
        signal.signal(signal.SIGTERM, previous)
    try:
        procs = [fake._proc, robot._proc]
        assert all(p is not None and p.is_alive() for p in procs)
        # both asked for a better priority (nice -10) where this OS lets this user have it
        want = -10 if _may_raise_priority() else 0
        assert [_nice(p.pid) for p in procs if p is not None and p.pid is not None] == [want, want]
        for p in procs:
            assert p is not None and p.pid is not None
            os.kill(p.pid, signal.SIGTERM)
        for p in procs:
            assert p is not None
            p.join(5.0)
            assert p.exitcode == -signal.SIGTERM  # ignored before: multiprocessing's exit then waited for ever
    finally:
        robot.disconnect()
        fake.stop()


def _nice(pid: int) -> int:
    with open(f"/proc/{pid}/stat") as f:
        return int(f.read().rsplit(")", 1)[1].split()[16])  # field 19, counted after the command name


def _may_raise_priority() -> bool:
    granted: list[bool] = []

    def attempt() -> None:  # in a thread of its own: on Linux a thread's nice level is its own
        from drivers.priority import raise_own_priority

        granted.append(raise_own_priority(-10) and os.getpriority(os.PRIO_PROCESS, 0) == -10)

    thread = threading.Thread(target=attempt)
    thread.start()
    thread.join()
    return granted[0]
