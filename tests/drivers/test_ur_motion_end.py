"""drivers/ur.py: when a motion has ended, from RTDE samples whose two streams do not arrive together.

The async operation status comes through the control interface's RTDE stream, the pose through the receive
interface's; the worker reads them in two threads. These tests hand the driver's follower a scripted series of
samples (no controller, no worker process), so each case is exact and fast.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.errors import MotionRejected
from drivers.ur import URRobot
from drivers.ur_worker import Status
from tests.drivers.test_ur_worker import status


def _at(x_m: float, *, running: bool = False, speed_m_s: float = 0.0, progress: int = 0) -> Status:
    X = np.eye(4)
    X[0, 3] = x_m
    return status(
        X_base_tool=X,
        tcp_speed=(speed_m_s, 0.0, 0.0, 0.0, 0.0, 0.0),
        async_running=running,
        async_progress=progress,
    )


class _Scripted(URRobot):
    """A driver whose state comes from ``samples``: (sample, seconds), each returned until that many seconds have
    passed since it was first returned (0: once); the last one repeats. Stop requests are counted."""

    def __init__(self, samples: list[tuple[Status, float]]) -> None:
        super().__init__("127.0.0.1", poll_s=0.001, stale_after_s=0.5)
        self._samples = list(samples)
        self._since: float | None = None
        self.stops = 0

    def _status(self) -> Status:
        now = time.monotonic()
        self._since = now if self._since is None else self._since
        sample, seconds = self._samples[0]
        if len(self._samples) > 1 and now - self._since >= seconds:
            self._samples.pop(0)
            self._since = None
        return sample

    def _request(self, op: str, *args: object, timeout_s: float) -> object:
        assert op == "stop"
        self.stops += 1
        return None


TARGET = np.eye(4)
TARGET[0, 3] = 0.1


@pytest.mark.timeout(10)
def test_a_finished_motion_whose_pose_lags_its_status_ends_on_its_target() -> None:
    # the operation runs, then reads over while the receive stream still shows the arm 1.3 mm short and moving;
    # then the pose arrives at rest on the target
    samples = [
        (_at(0.05, running=True, speed_m_s=0.025), 0.0),
        (_at(0.0987, running=False, speed_m_s=0.025), 0.0),
        (_at(0.0995, running=False, speed_m_s=0.01), 0.0),
        (_at(0.1, running=False), 0.0),
    ]
    robot = _Scripted(samples)
    robot._follow_motion("moveL", TARGET, time.monotonic() + 5.0, n_waypoints=1, on_progress=None)
    assert robot.stops == 0


@pytest.mark.timeout(10)
def test_a_pose_at_rest_off_target_gets_time_to_catch_up_before_the_verdict() -> None:
    # the status says over, the (stale) pose rests 1.3 mm short for 0.1 s, then the fresh one is on target
    samples = [(_at(0.05, running=True, speed_m_s=0.025), 0.0), (_at(0.0987), 0.1), (_at(0.1), 0.0)]
    robot = _Scripted(samples)
    robot._follow_motion("moveL", TARGET, time.monotonic() + 5.0, n_waypoints=1, on_progress=None)


@pytest.mark.timeout(10)
def test_a_motion_stopped_before_it_was_seen_running_is_a_short_move_not_a_wait_for_the_deadline() -> None:
    # a stop came between the command's acceptance and the first sample: the operation never reads running and the
    # arm rests 35 mm short. The verdict comes once the arm has rested stale_after_s (0.5 s), long before the
    # motion's deadline (the daemon's shutdown once waited 52 s on such a path)
    robot = _Scripted([(_at(0.065), 0.0)])
    t0 = time.monotonic()
    with pytest.raises(MotionRejected, match=r"moveL path ended 35\.00 mm and 0\.00 deg from its target"):
        robot._follow_motion("moveL path", TARGET, time.monotonic() + 60.0, n_waypoints=3, on_progress=None)
    assert 0.5 <= time.monotonic() - t0 < 3.0


@pytest.mark.timeout(10)
def test_progress_is_reported_waypoint_by_waypoint_and_a_stop_midway_is_a_short_move() -> None:
    seen: list[int] = []
    samples = [
        (_at(0.01, running=True, speed_m_s=0.02, progress=1), 0.0),
        (_at(0.02, running=True, speed_m_s=0.02, progress=3), 0.0),
        (_at(0.03, running=False, speed_m_s=0.01), 0.0),
        (_at(0.031, running=False), 0.0),
    ]
    robot = _Scripted(samples)
    with pytest.raises(MotionRejected, match=r"ended 69\.00 mm"):
        robot._follow_motion("moveL path", TARGET, time.monotonic() + 5.0, n_waypoints=4, on_progress=seen.append)
    assert seen == [0, 1, 2]
