"""The job runner's device watchdog, and the devices' last readings for the operator page.

While a job runs, :class:`DeviceWatchdog` polls the robot and the track every ``period_s`` and turns a protective
stop, an emergency stop, a track fault or an unreachable device into ``fault_now`` (which stops motion and turns the
arc off at once, from its thread). While the robot moves (:data:`MOTION_STATES`) a device whose status has not come
back within ``answer_timeout_s`` is a fault too: the poll runs in a thread of its own, so a device that hangs cannot
hold the watchdog up. Each poll's readings are kept (:attr:`DeviceWatchdog.last`) for the status view; between jobs
:meth:`DeviceWatchdog.read` takes a fresh one on demand, in a thread of its own: a status request never waits for a
device that does not answer.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from cell.factory import Cell
from cell.machine import CellState
from drivers.errors import DriverError
from drivers.protocols import RobotMode, RobotState, TrackStatus

logger = logging.getLogger(__name__)

S = CellState

FINAL_STATES = (S.DONE, S.FAULT, S.IDLE)
MOTION_STATES = (S.HOMING, S.MOVING_TO_CAPTURE, S.WELDING, S.RETRACTING)
"""States whose work moves the robot (or has the arc on): the watchdog's answer deadline applies in these."""


@dataclass(frozen=True)
class DeviceReadings:
    """One poll of the robot and the track: their states (None: not read), the errors reading them raised, and
    the ``time.time()`` of the poll."""

    time_s: float
    robot: RobotState | None
    robot_error: str | None
    track: TrackStatus | None
    track_error: str | None

    def problem(self, robot_name: str, track_name: str | None) -> str | None:
        """Why the cell must stop now, or None."""
        st = self.robot
        if st is None:
            return f"{robot_name} unreachable: {self.robot_error}"
        if st.emergency_stop:
            return f"{robot_name}: emergency stop ({st.message})"
        if st.protective_stop:
            return f"{robot_name}: protective stop ({st.message})"
        if st.mode is RobotMode.FAULT:
            return f"{robot_name}: fault ({st.message})"
        if track_name is None:
            return None
        status = self.track
        if status is None:
            return f"{track_name} unreachable: {self.track_error}"
        if status.fault:
            return f"{track_name}: fault latched (code {status.fault_code}) at {status.position_m:.4f} m"
        return None


def read_devices(cell: Cell) -> DeviceReadings:
    """The robot's and the track's state now (the track is not read when the robot cannot be: the fault is
    already known)."""
    robot, track = cell.robot, cell.track
    track_status: TrackStatus | None = None
    track_error: str | None = None
    try:
        st: RobotState | None = robot.state()
        robot_error = None
    except DriverError as err:
        st, robot_error = None, f"{type(err).__name__}: {err}"
    if track is not None and st is not None:
        try:
            track_status = track.status()
        except DriverError as err:
            track_error = f"{type(err).__name__}: {err}"
    return DeviceReadings(time.time(), st, robot_error, track_status, track_error)


class DeviceWatchdog:
    """Polls ``cell``'s robot and track while a job runs (between :meth:`start` and :meth:`stop`) and calls
    ``fault_now(reason)`` once when one must stop the cell; ``state()`` is the machine's state."""

    def __init__(
        self,
        cell: Cell,
        *,
        state: Callable[[], CellState],
        fault_now: Callable[[str], None],
        period_s: float,
        answer_timeout_s: float,
    ) -> None:
        self.cell = cell
        self.period_s = period_s
        self.answer_timeout_s = answer_timeout_s
        self._state = state
        self._fault_now = fault_now
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._fired = False
        self._read_lock = threading.Lock()
        self._pending: threading.Thread | None = None
        self.last: DeviceReadings | None = None
        """The last readings taken (by the watchdog's poll or :meth:`read`)."""

    def start(self) -> None:
        self._stop.clear()
        self._fired = False
        self._thread = threading.Thread(target=self._watch, name="cell-watchdog", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=10.0)

    def read(self, max_age_s: float = 0.5, *, wait_s: float = 0.25) -> DeviceReadings | None:
        """Readings at most ``max_age_s`` old if there are any, never blocking for longer than ``wait_s``: while a job
        runs and the watchdog polls, its own last poll (none beside it); otherwise (between jobs, paused) a fresh
        poll in a thread of its own (one at a time). A device that does not answer in time leaves the last
        readings (their ``time_s`` says how old) or None."""
        last = self.last
        if last is not None and time.time() - last.time_s <= max_age_s:
            return last
        if self._thread is not None and self._state() not in (*FINAL_STATES, S.PAUSED) and not self._fired:
            return last  # the watchdog itself polls now: nothing beside it
        with self._read_lock:
            pending = self._pending
            if pending is None or not pending.is_alive():
                pending = self._pending = threading.Thread(target=self._fresh, name="cell-device-read", daemon=True)
                pending.start()
        pending.join(wait_s)
        return self.last

    def _fresh(self) -> None:
        self.last = read_devices(self.cell)

    def _poll(self) -> str | None:
        readings = read_devices(self.cell)
        self.last = readings
        track = self.cell.track
        return readings.problem(self.cell.robot.name, track.name if track is not None else None)

    def _watch(self) -> None:
        poll: _Poll | None = None
        while not self._stop.wait(self.period_s):
            state = self._state()
            if state in (*FINAL_STATES, S.PAUSED) or self._fired:
                continue
            # the deadline applies while something moves or the arc may be on; while capturing, detecting or
            # planning this process's own computing can hold the GIL for longer than that (the drivers' own
            # timeouts still end a poll that gets no answer)
            limit = self.answer_timeout_s if state in MOTION_STATES else None
            if poll is None or poll.done.is_set():  # a poll still stuck in a driver is waited for, not doubled
                poll = _Poll(self._poll)
            if poll.done.wait(limit):
                problem = poll.problem
            else:
                problem = f"no status from the robot or the track within {self.answer_timeout_s:.1f} s"
            if problem is not None and not self._stop.is_set():
                self._fired = True
                logger.error("watchdog: %s", problem)
                self._fault_now(f"watchdog: {problem}")


class _Poll:
    """One poll of the devices in a daemon thread of its own: a driver that hangs holds neither the watchdog nor,
    at exit, the interpreter (a pool's worker threads are joined without a bound when the process exits)."""

    def __init__(self, poll: Callable[[], str | None]) -> None:
        self.problem: str | None = None
        self.done = threading.Event()
        self._poll = poll
        threading.Thread(target=self._run, name="cell-device-poll", daemon=True).start()

    def _run(self) -> None:
        try:
            self.problem = self._poll()
        except Exception as err:  # a bug in a driver's status path must still stop the cell
            self.problem = f"device status failed: {type(err).__name__}: {err}"
        finally:
            self.done.set()
