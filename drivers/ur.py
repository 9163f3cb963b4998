"""Universal Robots arm (UR5 / CB3 and e-Series) through ur-rtde, implementing :class:`drivers.protocols.Robot`.

ur-rtde (modules ``rtde_receive``, ``rtde_control``, ``rtde_io``) is imported lazily; without it :meth:`connect`
raises :class:`drivers.errors.DriverNotInstalled` with the install hint.

Why a worker process: ur-rtde's C++ calls hold the GIL while they wait, and several of them wait without a bound
(the RTDE handshake, "wait for the first state", the control script re-upload before a path, a command whose
"done" never comes from a hung controller). A thread cannot time such a call out, so every ur-rtde object lives in
a child process and this driver talks to it over a pipe with a deadline on each request: when a deadline passes
the child is killed and :class:`drivers.errors.DeviceTimeout` is raised; :meth:`URRobot.connect` starts a fresh one.
What runs in the child lives in :mod:`drivers.ur_worker`. :meth:`URRobot.state` and :meth:`URRobot.get_X_base_tool`
use a second pipe to the worker, answered by a thread there, so that a state read does not wait behind a path's
upload or a command's handshake on the first.

Motions are sent asynchronously (``moveL(..., asynchronous=True)``) and followed by polling the RTDE state every
controller cycle, so a protective stop (safety status bit 2), an emergency stop (bits 5-7), a lost connection or a
stalled data stream end the wait with the matching error instead of a hang. Frames and units: ``X_base_tool`` is
the 4x4 tool pose in the robot base frame in metres; speeds m/s, accelerations m/s², times s. Poses cross to
ur-rtde as UR pose vectors ``[x, y, z, rx, ry, rz]`` (m, rotation vector in rad) in :func:`_ur_pose` only.

The worker is started with multiprocessing's "spawn" method, so a script that connects at import time needs the
usual ``if __name__ == "__main__":`` guard.

ur-rtde 1.6 always connects its RTDE interfaces to port 30004 and uploads its control script to port 30003; only
the dashboard port (used by :meth:`URRobot.reset_faults` and :meth:`URRobot.unlock_protective_stop`) can differ from
the standard.

Recovering after a safety stop (:meth:`URRobot.reset_faults`: dashboard ``close safety popup``, ``unlock protective
stop`` again until a CB3 accepts it 5 s after the stop, ``power on`` and ``brake release`` after an emergency stop, a
fresh worker if a stop during a path's upload made it give its control interface up, then the control script
uploaded again and its watchdog armed) and the controller-side watchdog (``heartbeat_timeout_s``: every control
script this driver starts is told ``setWatchdog(1 / heartbeat_timeout_s)``; a path's upload restarts the program, so
the arm is held with the speed slider at 0 until the outputs the restart switched off are on again) are described,
with what the integrator installs on the controller, in docs/controller-watchdogs.md.
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import socket
import threading
import time
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from typing import Any, NoReturn

import numpy as np

from drivers.errors import (
    ConnectionLost,
    DeviceFault,
    DeviceTimeout,
    DriverError,
    EmergencyStop,
    MotionRejected,
    MotionTimeout,
    ProtectiveStop,
)
from drivers.protocols import FloatArray, RobotState
from drivers.ur_protocol import (
    DASHBOARD_PORT,
    REPLY_BRAKE_RELEASING,
    REPLY_POWERING_ON,
    REPLY_UNLOCK_TOO_EARLY,
    REPLY_UNLOCKED,
    ROBOT_MODE_BOOTING,
    ROBOT_MODE_IDLE,
    ROBOT_MODE_NAMES,
    ROBOT_MODE_POWER_OFF,
    ROBOT_MODE_POWER_ON,
    ROBOT_MODE_RUNNING,
    RTDE_PORT,
)
from drivers.ur_worker import Status, StatusChannel, import_ur_rtde, worker_main
from perception.transforms import TransformError, check_X, rotation_angle_rad, ur_pose_from_X

log = logging.getLogger(__name__)


# limits ur-rtde checks before sending (rtde_control_interface.h)
TOOL_SPEED_MAX_M_S = 3.0
TOOL_ACCEL_MAX_M_S2 = 150.0
BLEND_MAX_M = 2.0

# the robot modes the dashboard can bring to RUNNING (booting and idle are on the way)
_RECOVERABLE_MODES = frozenset(
    {ROBOT_MODE_BOOTING, ROBOT_MODE_POWER_OFF, ROBOT_MODE_POWER_ON, ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING}
)

_UNLOCK_RETRY_S = 0.25


class URRTDEError(Exception):
    """An exception ur-rtde raised in the worker process; the message keeps its type name and text."""


def _ur_pose(X_base_tool: FloatArray) -> list[float]:
    """UR pose vector of a 4x4 pose: the one place where poses change representation for ur-rtde."""
    return [float(v) for v in ur_pose_from_X(X_base_tool)]


class URRobot:
    """A UR arm driven through ur-rtde (see the module docstring for the worker process).

    ``host``: the controller's address. ``rtde_port``: must be 30004 (ur-rtde 1.6 has no other); it is checked
    before the worker starts so that a wrong address fails fast. ``dashboard_port``: the dashboard server.
    ``connect_timeout_s``: bound on :meth:`connect` (ur-rtde waits up to 5 s for its control script to start).
    ``command_timeout_s``: bound on every other request to the controller. ``stale_after_s``: the RTDE stream
    counts as lost (:class:`ConnectionLost`, as the Robot protocol asks of ``state()``) when its timestamp has not
    moved for this long. ``heartbeat_timeout_s``: the controller-side watchdog (None: off): the control script stops
    its program (the arm stops; the installation drives the arc output low) when this driver's heartbeat has been
    missing for this long (docs/controller-watchdogs.md).
    ``stop_decel_m_s2``: tool deceleration of :meth:`stop`. ``arrive_tol_m`` / ``arrive_tol_rad``: how close a
    finished motion must end to its target before it counts as arrived.
    """

    def __init__(
        self,
        host: str,
        *,
        name: str = "ur",
        rtde_port: int = RTDE_PORT,
        dashboard_port: int = DASHBOARD_PORT,
        connect_timeout_s: float = 15.0,
        command_timeout_s: float = 5.0,
        stale_after_s: float = 0.5,
        heartbeat_timeout_s: float | None = 0.3,
        stop_decel_m_s2: float = 2.0,
        arrive_tol_m: float = 5e-4,
        arrive_tol_rad: float = math.radians(0.5),
        poll_s: float = 0.008,
    ) -> None:
        if not host:
            raise ValueError("URRobot needs the controller's host address, got an empty string")
        if rtde_port != RTDE_PORT:
            raise ValueError(f"ur-rtde 1.6 connects RTDE to port {RTDE_PORT} only; got rtde_port={rtde_port}")
        if heartbeat_timeout_s is not None and not 0.05 <= heartbeat_timeout_s <= 5.0:
            raise ValueError(f"heartbeat_timeout_s must be 0.05..5 s (or None), got {heartbeat_timeout_s}")
        self.name = name
        self.host = host
        self.rtde_port = rtde_port
        self.dashboard_port = dashboard_port
        self.connect_timeout_s = connect_timeout_s
        self.command_timeout_s = command_timeout_s
        self.stale_after_s = stale_after_s
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.stop_decel_m_s2 = stop_decel_m_s2
        self.arrive_tol_m = arrive_tol_m
        self.arrive_tol_rad = arrive_tol_rad
        self.poll_s = poll_s
        self._proc: multiprocessing.process.BaseProcess | None = None
        self._conn: Connection | None = None
        self._lock = threading.RLock()
        self._channel: StatusChannel | None = None  # the worker's status channel (state(), get_X_base_tool())
        self._status_lock = threading.Lock()
        self._last_timestamp = math.nan
        self._last_change = 0.0

    def __repr__(self) -> str:
        return f"URRobot(name={self.name!r}, host={self.host!r}, connected={self._proc is not None})"

    # ------------------------------------------------------------------ connection
    def connect(self) -> None:
        """Connect (again): a fresh worker with fresh ur-rtde interfaces; ConnectionLost when unreachable."""
        import_ur_rtde()
        with self._lock:
            self.disconnect()
            self._preflight()
            ctx = multiprocessing.get_context("spawn")
            parent, child = ctx.Pipe()
            status_parent, status_child = ctx.Pipe()
            proc = ctx.Process(
                target=worker_main,
                args=(child, status_child, self.host, self.dashboard_port, self.heartbeat_timeout_s),
                name=f"ur-rtde-{self.name}-{self.host}",
                daemon=True,
            )
            proc.start()
            child.close()
            status_child.close()
            self._proc, self._conn = proc, parent
            with self._status_lock:
                self._channel = StatusChannel(status_parent, f"{self.name}: the ur-rtde worker for {self.host}")
            log.debug("%s: connecting to %s (RTDE receive, control and IO interfaces)", self.name, self.host)
            try:
                raw = self._request("connect", timeout_s=self.connect_timeout_s)
            except DeviceTimeout:
                raise
            except DriverError as err:
                self._kill_worker()
                raise ConnectionLost(
                    f"{self.name}: could not connect to the UR controller at {self.host}: {err}; "
                    "check that it is powered, in remote control and reachable"
                ) from err
            self._last_timestamp = math.nan
            self._status_from(raw)
            log.info("%s: connected to UR controller at %s", self.name, self.host)

    def _preflight(self) -> None:
        try:
            with socket.create_connection((self.host, self.rtde_port), timeout=min(self.connect_timeout_s, 3.0)):
                pass
        except OSError as err:
            raise ConnectionLost(
                f"{self.name}: no RTDE server at {self.host}:{self.rtde_port} ({err}); "
                "check the controller's address and that it is switched on"
            ) from err

    def disconnect(self) -> None:
        """Stop the control script and close the connections; safe to call twice."""
        with self._lock:
            if self._proc is None:
                return
            try:
                self._request("close", timeout_s=3.0)
            except DriverError as err:
                log.debug("%s: closing the worker: %s", self.name, err)
            self._kill_worker(grace_s=1.0)
            log.info("%s: disconnected from %s", self.name, self.host)

    def _kill_worker(self, *, grace_s: float = 0.0) -> None:
        """End the worker: wait ``grace_s`` for it to exit by itself, then kill it."""
        proc, conn = self._proc, self._conn
        self._proc = self._conn = None
        if conn is not None:
            conn.close()
        channel, self._channel = self._channel, None
        if channel is not None:
            channel.close()  # a state() waiting on it sees the channel end
        if proc is not None:
            proc.join(grace_s)
            if proc.is_alive():
                proc.kill()
                proc.join(2.0)

    def _request(self, op: str, *args: Any, timeout_s: float) -> Any:
        """Run ``op`` in the worker; kill it and raise DeviceTimeout when it takes longer than ``timeout_s``."""
        with self._lock:
            conn = self._conn
            if conn is None:
                raise ConnectionLost(f"{self.name}: not connected to {self.host}; call connect() first")
            try:
                conn.send((op, args))
                answered = conn.poll(max(timeout_s, 0.0))
                reply = conn.recv() if answered else None
            except (EOFError, OSError) as err:
                self._kill_worker()
                raise ConnectionLost(
                    f"{self.name}: the ur-rtde worker for {self.host} ended during {op!r}; call connect() again"
                ) from err
            if reply is None:
                self._kill_worker()
                raise DeviceTimeout(
                    f"{self.name}: the UR controller at {self.host} did not complete {op!r} within {timeout_s:.1f} s; "
                    "the connection was closed, check the controller and call connect() again"
                )
        if reply[0] == "ok":
            return reply[1]
        self._raise_reply(op, reply[1], reply[2])

    def _raise_reply(self, op: str, kind: str, message: str) -> NoReturn:
        """Raise the driver's error for an exception ``kind: message`` that ``op`` raised in the worker."""
        cause = URRTDEError(f"{kind}: {message}")
        if kind == "SafetyStopDuringUpload":
            stop_error = EmergencyStop if message.startswith("emergency") else ProtectiveStop
            raise stop_error(
                f"{self.name}: {message} at {self.host}; the arm did not start the path. Inspect the cause, then "
                "reset_faults()"
            ) from cause
        if kind == "ConnectionLost" or "connect" in message.lower() or "socket" in message.lower():
            raise ConnectionLost(f"{self.name}: connection to {self.host} lost during {op!r}: {message}") from cause
        raise DeviceFault(f"{self.name}: ur-rtde failed in {op!r} at {self.host}: {kind}: {message}") from cause

    # ------------------------------------------------------------------ state
    def _status(self) -> Status:
        return self._status_from(self._request("state", timeout_s=self.command_timeout_s))

    def _channel_status(self) -> Status:
        """The state through the worker's status channel (:class:`drivers.ur_worker.StatusChannel`): a path's
        upload or a command's handshake on the request pipe does not hold it up."""
        with self._status_lock:
            channel = self._channel
            if channel is None:
                raise ConnectionLost(f"{self.name}: not connected to {self.host}; call connect() first")
            reply = channel.read(self.command_timeout_s)
        if reply[0] != "ok":
            self._raise_reply("state", reply[2], reply[3])
        return self._status_from(reply[2])

    def _status_from(self, raw: dict[str, Any]) -> Status:
        now = time.monotonic()
        if raw["timestamp"] != self._last_timestamp:
            self._last_timestamp = raw["timestamp"]
            self._last_change = now
        # as this process sees it, or as the worker does (it reads the stream during a path upload too)
        stood_s = max(now - self._last_change, float(raw["stamp_age_s"]))
        if stood_s > self.stale_after_s:
            raise ConnectionLost(
                f"{self.name}: the RTDE data from {self.host} stopped {stood_s:.2f} s ago "
                f"(controller timestamp {raw['timestamp']:.3f} s); the controller does not answer, "
                "check it and call connect() again"
            )
        if not raw["control_connected"]:
            raise ConnectionLost(f"{self.name}: the RTDE control connection to {self.host} closed; call connect()")
        return Status.from_raw(raw)

    def state(self) -> RobotState:
        return self._channel_status().robot_state()

    def get_X_base_tool(self) -> FloatArray:
        return self._channel_status().X_base_tool

    # ------------------------------------------------------------------ motion
    def move_linear(
        self, X_base_tool: FloatArray, *, speed_m_s: float, accel_m_s2: float = 0.5, timeout_s: float = 60.0
    ) -> None:
        X_target = self._checked_pose(X_base_tool, "X_base_tool")
        self._check_motion(speed_m_s, accel_m_s2, timeout_s)
        deadline = time.monotonic() + timeout_s
        self._ready_for_motion(deadline)
        pose = _ur_pose(X_target)
        log.debug(
            "%s: moveL to [%.4f, %.4f, %.4f] m, rotvec [%.4f, %.4f, %.4f] rad at %.3f m/s, %.3f m/s^2",
            self.name,
            *pose,
            speed_m_s,
            accel_m_s2,
        )
        accepted = self._request("move_linear", pose, speed_m_s, accel_m_s2, timeout_s=self._budget(deadline))
        if not accepted:
            self._raise_refused("moveL", X_target)
        self._follow_motion("moveL", X_target, deadline, n_waypoints=1, on_progress=None)

    def stream_path(
        self,
        X_base_tool_path: Sequence[FloatArray],
        *,
        speed_m_s: float,
        blend_m: float = 0.0,
        accel_m_s2: float = 0.5,
        timeout_s: float = 300.0,
        on_progress: Callable[[int], None] | None = None,
    ) -> None:
        """Send the whole path as one blended ``moveL(path)``; ``on_progress(i)`` as waypoint ``i`` is passed.

        ur-rtde writes the path into its control script with 6 significant digits, so waypoints are rounded to
        about 5 µm and 5 µrad on the controller.
        """
        targets = [self._checked_pose(X, f"X_base_tool_path[{i}]") for i, X in enumerate(X_base_tool_path)]
        if not targets:
            log.debug("%s: empty path, nothing to move", self.name)
            return
        self._check_motion(speed_m_s, accel_m_s2, timeout_s)
        if not 0.0 <= blend_m <= BLEND_MAX_M:
            raise MotionRejected(f"{self.name}: blend_m={blend_m} m is outside [0, {BLEND_MAX_M}] m")
        deadline = time.monotonic() + timeout_s
        self._ready_for_motion(deadline)
        path = [[*_ur_pose(X), speed_m_s, accel_m_s2, blend_m] for X in targets]
        path[-1][8] = 0.0  # the path must end with a stop on its last pose
        log.debug(
            "%s: moveL path of %d poses from [%.4f, %.4f, %.4f] m to [%.4f, %.4f, %.4f] m "
            "at %.3f m/s, %.3f m/s^2, blend %.4f m",
            self.name,
            len(path),
            *path[0][:3],
            *path[-1][:3],
            speed_m_s,
            accel_m_s2,
            blend_m,
        )
        budget = self._budget(deadline)
        # the worker gives up waiting for the path's script to start a little before this driver gives up on it,
        # and on a controller whose data stands still as soon as state() would
        accepted = self._request(
            "move_path", path, max(budget - 1.0, 0.5 * budget), self.stale_after_s, timeout_s=budget
        )
        if not accepted:
            self._raise_refused("moveL path", targets[-1])
        self._follow_motion("moveL path", targets[-1], deadline, n_waypoints=len(path), on_progress=on_progress)

    def stop(self) -> None:
        """Decelerate at ``stop_decel_m_s2`` now; a no-op when not connected or when no program can move the arm."""
        with self._lock:
            if self._conn is None:
                log.debug("%s: stop while not connected: nothing to stop through this driver", self.name)
                return
            st = self._status()
            if not st.program_running or st.emergency_stop or st.protective_stop or st.control_lost:
                log.debug("%s: stop: no control script running, the arm is not being moved", self.name)
                return
            log.debug("%s: stopL at %.2f m/s^2", self.name, self.stop_decel_m_s2)
            self._request("stop", self.stop_decel_m_s2, timeout_s=self.command_timeout_s)

    def set_digital_output(self, index: int, value: bool, *, timeout_s: float = 1.0) -> None:
        """Set standard digital output ``index`` (0-7) and wait until the controller reports it set."""
        if not 0 <= index <= 7:
            raise ValueError(f"{self.name}: standard digital outputs are 0-7, got {index}")
        log.debug("%s: set standard digital output %d to %s", self.name, index, value)
        # a controller whose data stands still does not answer the write either (ur-rtde's IO interface then waits):
        # say so at once, so that an arc-off after a lost controller does not hold the fault up
        self._status()
        if not self._request("set_digital_output", index, bool(value), timeout_s=self.command_timeout_s):
            raise ConnectionLost(f"{self.name}: ur-rtde could not send digital output {index} to {self.host}")
        deadline = time.monotonic() + timeout_s
        while True:
            if bool(self._status().digital_output_bits >> index & 1) == bool(value):
                return
            if time.monotonic() > deadline:
                raise DeviceTimeout(
                    f"{self.name}: digital output {index} did not read back {value} within {timeout_s} s"
                )
            time.sleep(self.poll_s)

    def unlock_protective_stop(self, *, timeout_s: float = 10.0) -> None:
        """Release a protective stop through the dashboard and restart the control script.

        A CB3 refuses the unlock until 5 s after the stop: it is asked again until then (within ``timeout_s``).
        Inspect the cause first.
        """
        deadline = time.monotonic() + timeout_s
        self._dashboard("close safety popup")
        self._unlock(deadline)
        self._ready_for_motion(deadline)

    def reset_faults(self, *, timeout_s: float = 30.0) -> None:
        """Bring the arm back after a safety stop whose cause an operator has cleared (see the module docstring).

        Does nothing but check the control script when the arm is running without a stop. Raises EmergencyStop
        while the emergency stop is still engaged, ProtectiveStop when the controller refuses the unlock,
        DeviceFault for a robot mode that needs the pendant (backdrive, confirm safety...), DeviceTimeout when the
        arm is not running with the control script within ``timeout_s``.
        """
        deadline = time.monotonic() + timeout_s
        st = self._status()
        stopped = st.emergency_stop or st.protective_stop or st.robot_mode != ROBOT_MODE_RUNNING
        if stopped:
            log.info(
                "%s: recovering (robot mode %s, safety mode %d)",
                self.name,
                ROBOT_MODE_NAMES.get(st.robot_mode, str(st.robot_mode)),
                st.safety_mode,
            )
            self._dashboard("close safety popup")
        if st.emergency_stop or st.robot_mode != ROBOT_MODE_RUNNING:
            st = self._power_up(st, deadline)
        if st.protective_stop:
            st = self._unlock(deadline)
        if st.robot_mode != ROBOT_MODE_RUNNING:  # the arm idled while it stood in the stop
            st = self._power_up(st, deadline)
        self._ready_for_motion(deadline)
        if stopped:
            log.info("%s: running again with the control script", self.name)

    # ------------------------------------------------------------------ recovery
    def _dashboard(self, command: str) -> str:
        """Send one dashboard command and return the controller's reply."""
        log.debug("%s: dashboard: %s", self.name, command)
        reply: str = self._request("dashboard", [command], timeout_s=self.command_timeout_s)[0]
        log.debug("%s: dashboard replied %r", self.name, reply)
        return reply

    def _unlock(self, deadline: float) -> Status:
        """``unlock protective stop``, asked again while the controller says it is too early; wait until released."""
        while True:
            reply = self._dashboard("unlock protective stop")
            if reply.startswith(REPLY_UNLOCKED):
                break
            if not reply.startswith(REPLY_UNLOCK_TOO_EARLY) or time.monotonic() + _UNLOCK_RETRY_S > deadline:
                raise ProtectiveStop(f"{self.name}: the controller refused to unlock the protective stop: {reply!r}")
            time.sleep(_UNLOCK_RETRY_S)  # a CB3 refuses the unlock until 5 s after the stop
        return self._wait_for(
            lambda st: not st.protective_stop, deadline, "the protective stop is still active after unlocking"
        )

    def _power_up(self, st: Status, deadline: float) -> Status:
        """Power on (a powered-off arm, or after an emergency stop), release the brakes, wait for RUNNING."""
        powered = (ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING)
        if st.emergency_stop or st.robot_mode == ROBOT_MODE_POWER_OFF:
            reply = self._dashboard("power on")
            if not reply.startswith(REPLY_POWERING_ON):
                if st.emergency_stop:
                    raise EmergencyStop(
                        f"{self.name}: the controller refused to power on ({reply!r}): the emergency stop is still "
                        "engaged; release it, then acknowledge again"
                    )
                raise DeviceFault(f"{self.name}: the controller refused to power on: {reply!r}")
        if st.robot_mode != ROBOT_MODE_RUNNING:
            # a released emergency stop resets as the arm powers on: one still engaged a moment later is pressed
            st = self._wait_for(
                lambda s: s.robot_mode in powered and not s.emergency_stop,
                deadline,
                "the arm did not power on",
                estop_deadline=min(deadline, time.monotonic() + self.command_timeout_s),
            )
        if st.robot_mode == ROBOT_MODE_IDLE:
            reply = self._dashboard("brake release")
            if not reply.startswith(REPLY_BRAKE_RELEASING):
                raise DeviceFault(f"{self.name}: the controller refused to release the brakes: {reply!r}")
            st = self._wait_for(lambda s: s.robot_mode == ROBOT_MODE_RUNNING, deadline, "the brakes were not released")
        return st

    def _wait_for(
        self, done: Callable[[Status], bool], deadline: float, what: str, *, estop_deadline: float | None = None
    ) -> Status:
        """Poll the state until ``done(state)``. Raises EmergencyStop when the emergency stop is still engaged past
        ``estop_deadline`` (or ``deadline``), DeviceFault when the robot mode needs the pendant, DeviceTimeout
        (saying ``what``) past ``deadline``."""
        estop_deadline = deadline if estop_deadline is None else estop_deadline
        while True:
            st = self._status()
            if done(st):
                return st
            now = time.monotonic()
            robot_mode = ROBOT_MODE_NAMES.get(st.robot_mode, str(st.robot_mode))
            if st.emergency_stop and now > estop_deadline:
                raise EmergencyStop(
                    f"{self.name}: the emergency stop is still engaged (robot mode {robot_mode}); release it, then "
                    "acknowledge again"
                )
            if st.robot_mode not in _RECOVERABLE_MODES:
                raise DeviceFault(
                    f"{self.name}: robot mode {robot_mode} cannot be recovered from here; bring the arm to RUNNING "
                    "at the teach pendant"
                )
            if now > deadline:
                raise DeviceTimeout(
                    f"{self.name}: {what} within the time allowed (robot mode {robot_mode}, safety mode "
                    f"{st.safety_mode})"
                )
            time.sleep(self.poll_s)

    # ------------------------------------------------------------------ helpers
    def _checked_pose(self, X: FloatArray, name: str) -> FloatArray:
        try:
            return check_X(X, name=name)
        except TransformError as err:
            raise MotionRejected(f"{self.name}: {err}") from err

    def _check_motion(self, speed_m_s: float, accel_m_s2: float, timeout_s: float) -> None:
        if not 0.0 < speed_m_s <= TOOL_SPEED_MAX_M_S:
            raise MotionRejected(f"{self.name}: speed_m_s={speed_m_s} is outside (0, {TOOL_SPEED_MAX_M_S}] m/s")
        if not 0.0 < accel_m_s2 <= TOOL_ACCEL_MAX_M_S2:
            raise MotionRejected(f"{self.name}: accel_m_s2={accel_m_s2} is outside (0, {TOOL_ACCEL_MAX_M_S2}] m/s^2")
        if not timeout_s > 0.0:
            raise MotionRejected(f"{self.name}: timeout_s={timeout_s} must be positive")

    def _budget(self, deadline: float) -> float:
        """Time allowed for one request: the command timeout, but never past the motion's deadline."""
        return max(0.0, min(self.command_timeout_s, deadline - time.monotonic()))

    def _raise_if_stopped(self, st: Status, what: str) -> None:
        here = np.round(st.X_base_tool[:3, 3], 4).tolist()
        if st.emergency_stop:
            raise EmergencyStop(
                f"{self.name}: emergency stop active {what} (tool at {here} m); release it, then reset_faults() "
                "(powers the arm on and releases the brakes)"
            )
        if st.protective_stop:
            raise ProtectiveStop(
                f"{self.name}: protective stop {what} (tool at {here} m); inspect the cause, then reset_faults()"
            )

    def _ready_for_motion(self, deadline: float) -> Status:
        st = self._status()
        if st.control_lost:  # a safety stop came during a path upload: a fresh worker, fresh control interface
            log.info("%s: reconnecting the control interface (%s)", self.name, st.control_lost)
            self.connect()
            st = self._status()
        self._raise_if_stopped(st, "before the motion")
        if st.robot_mode != ROBOT_MODE_RUNNING:
            robot_mode = ROBOT_MODE_NAMES.get(st.robot_mode, str(st.robot_mode))
            raise DeviceFault(f"{self.name}: robot mode is {robot_mode}; power the arm on and release its brakes")
        if not st.program_running:
            log.info("%s: the ur-rtde control script is not running on %s; uploading it again", self.name, self.host)
            self._request("reupload", timeout_s=self._budget(deadline))
        # the control interface has its own RTDE stream: wait until it, too, sees the script running (it refuses
        # commands otherwise), which may be a cycle or two after the receive interface does
        limit = min(deadline, time.monotonic() + self.command_timeout_s)
        while not (st.program_running and st.control_ready):
            if time.monotonic() > limit:
                raise DeviceFault(
                    f"{self.name}: the ur-rtde control script is not running on {self.host} "
                    f"(runtime state {st.runtime_state}); check the controller's log"
                )
            time.sleep(self.poll_s)
            st = self._status()
            self._raise_if_stopped(st, "while restarting the control script")
        return st

    def _raise_refused(self, what: str, X_target: FloatArray) -> None:
        # a safety stop that made the controller refuse can reach the receive stream a sample after the
        # refusal: the stream is read until two fresh samples have come (within its staleness bound) before
        # the refusal is put down to the target
        st = self._status()
        stamp, fresh = self._last_timestamp, 0
        limit = time.monotonic() + self.stale_after_s
        while fresh < 2 and time.monotonic() < limit:
            self._raise_if_stopped(st, f"when {what} was sent")
            time.sleep(self.poll_s)
            st = self._status()
            if self._last_timestamp != stamp:
                stamp, fresh = self._last_timestamp, fresh + 1
        self._raise_if_stopped(st, f"when {what} was sent")
        target = np.round(X_target[:3, 3], 4).tolist()
        if not st.program_running:
            raise MotionRejected(
                f"{self.name}: the controller refused {what} to {target} m and stopped its control script "
                "(unreachable pose or invalid parameters); check the target"
            )
        raise MotionRejected(f"{self.name}: the controller did not accept {what} to {target} m")

    def _arrived(self, st: Status, X_target: FloatArray) -> tuple[bool, float, float]:
        dist = float(np.linalg.norm(st.X_base_tool[:3, 3] - X_target[:3, 3]))
        angle = rotation_angle_rad(st.X_base_tool, X_target)
        return dist <= self.arrive_tol_m and angle <= self.arrive_tol_rad, dist, angle

    def _follow_motion(
        self,
        what: str,
        X_target: FloatArray,
        deadline: float,
        *,
        n_waypoints: int,
        on_progress: Callable[[int], None] | None,
    ) -> None:
        """Poll until the asynchronous motion ends; raise on safety stops, lost data or the deadline.

        The controller's async operation status comes through the control interface's RTDE stream, the pose and the
        speed through the receive interface's: two connections read by two threads of the worker, which a loaded
        host runs tens of milliseconds apart (a soak saw a finished move "end 1.3 mm short" of its target: the pose
        was older than the status). So the motion has started once either shows it (the operation running, the arm
        moving); it has ended once the operation is over and the arm rests on its target; an arm that rests away
        from its target (stopped short, or stopped before the operation was ever seen running) is judged only after
        ``stale_after_s`` at rest, time for the receive stream to catch up (a stream further behind counts as lost).
        """
        sent = time.monotonic()
        started = False
        resting_since: float | None = None  # when the arm was first seen at rest, the operation over, off target
        reported = -1

        def report(upto: int) -> None:
            nonlocal reported
            while on_progress is not None and reported < min(upto, n_waypoints - 1):
                reported += 1
                on_progress(reported)

        try:
            while True:
                st = self._status()
                self._raise_if_stopped(st, f"during {what}")
                if not st.program_running:
                    raise DeviceFault(
                        f"{self.name}: the control script stopped during {what}; see the controller's log"
                    )
                now = time.monotonic()
                if st.async_running or st.moving:
                    started, resting_since = True, None
                    if st.async_running:
                        report(st.async_progress - 1)
                else:
                    arrived, _, _ = self._arrived(st, X_target)
                    if arrived and (started or now - sent > 0.1):
                        break
                    if not arrived:
                        resting_since = now if resting_since is None else resting_since
                        if now - resting_since > self.stale_after_s:
                            break
                if now > deadline:
                    self._stop_quietly()
                    raise MotionTimeout(
                        f"{self.name}: {what} did not finish before its timeout; stopped at "
                        f"{np.round(st.X_base_tool[:3, 3], 4).tolist()} m"
                    )
                time.sleep(self.poll_s)
            arrived, dist, angle = self._arrived(st, X_target)
            if not arrived:
                raise MotionRejected(
                    f"{self.name}: {what} ended {dist * 1e3:.2f} mm and {math.degrees(angle):.2f} deg from its "
                    f"target {np.round(X_target[:3, 3], 4).tolist()} m"
                )
            report(n_waypoints - 1)
        except DriverError:
            raise  # the robot is stopped already, or cannot be reached
        except BaseException:
            self._stop_quietly()  # an on_progress callback failed or the caller was interrupted: do not keep moving
            raise

    def _stop_quietly(self) -> None:
        try:
            self._request("stop", self.stop_decel_m_s2, timeout_s=min(self.command_timeout_s, 2.0))
        except DriverError as err:
            log.warning("%s: stop after a motion timeout failed: %s", self.name, err)
