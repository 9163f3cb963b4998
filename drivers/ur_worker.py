"""The UR driver's worker process (:mod:`drivers.ur`): every ur-rtde object lives here, behind a pipe.

ur-rtde's C++ calls hold the GIL while they wait, several without a bound; :class:`drivers.ur.URRobot` sends each
request over the pipe with a deadline and kills this process when one passes. This module holds what runs in it
(``Worker``, ``worker_main``, the heartbeat thread that kicks the controller's watchdog) and :class:`Status`, one
RTDE state sample as the driver reads it. Units: metres, radians, seconds; poses are UR pose vectors.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from types import ModuleType
from typing import Any

from drivers.errors import ConnectionLost, DeviceTimeout, DriverNotInstalled
from drivers.priority import enter_io_process
from drivers.protocols import FloatArray, RobotMode, RobotState
from drivers.ur_protocol import (
    ESTOP_MASK,
    PROTECTIVE_MASK,
    ROBOT_MODE_NAMES,
    ROBOT_MODE_RUNNING,
    RUNTIME_PLAYING,
    SAFETY_BIT_FAULT,
    SAFETY_BIT_VIOLATION,
)
from perception.transforms import X_from_ur_pose

INSTALL_HINT = "ur-rtde is not installed: pip install 'ur-rtde>=1.5.8,<2' (it provides rtde_control, rtde_receive)"

# what the receive interface streams for this driver (a small recipe keeps the controller's load low)
RECEIVE_VARIABLES = (
    "timestamp",
    "actual_TCP_pose",
    "actual_TCP_speed",
    "robot_mode",
    "safety_mode",
    "safety_status_bits",
    "runtime_state",
    "actual_digital_output_bits",
    "target_speed_fraction",
)

_MOVING_SPEED_M_S = 1e-4
_MOVING_SPEED_RAD_S = 1e-3
_UPLOAD_POLL_S = 0.004


class SafetyStopDuringUpload(Exception):
    """A protective or emergency stop came while ur-rtde waited for a path's control script to start.

    ur-rtde's ``moveL(path)`` waits without a bound for the uploaded script to run, and a controller in a safety
    stop never runs it; the waiting call is abandoned (with the control interface, see
    :meth:`Worker.abandon_control`) and the driver reconnects on :meth:`drivers.ur.URRobot.reset_faults`."""


def import_ur_rtde() -> tuple[ModuleType, ModuleType, ModuleType, ModuleType]:
    try:
        import dashboard_client
        import rtde_control
        import rtde_io
        import rtde_receive
    except ImportError as err:
        raise DriverNotInstalled(f"{INSTALL_HINT} ({err})") from err
    return rtde_receive, rtde_control, rtde_io, dashboard_client


# --------------------------------------------------------------------------------------------- worker process


class Worker:
    """Owns the ur-rtde interfaces inside the worker process; each ``op_*`` answers one request.

    ``heartbeat_timeout_s`` (None: no watchdog): the control script is told (``setWatchdog``) to stop its program
    when the host's heartbeat is missing for that long, and a thread of this process sends the heartbeat
    (``kickWatchdog``) six times per timeout. Every ur-rtde call, the heartbeat's included, holds :attr:`lock`: the
    control interface's register handshake must not interleave.
    """

    def __init__(self, host: str, dashboard_port: int, heartbeat_timeout_s: float | None) -> None:
        self.host = host
        self.dashboard_port = dashboard_port
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.receive: Any = None
        self.control: Any = None
        self.io: Any = None
        self.lock = threading.Lock()
        self.control_lost = ""  # why the control interface was given up ('' while it is in use)
        self._stamp: float | None = None  # the controller's last RTDE timestamp seen here, and when it last changed
        self._stamp_changed = time.monotonic()
        self._heartbeat: threading.Thread | None = None
        # the control interface's part of the last full state read (see receive_state)
        self._control_view: dict[str, Any] = {
            "control_connected": True,
            "control_lost": "",
            "control_ready": False,
            "async_running": False,
            "async_progress": 0,
        }

    def op_connect(self) -> dict[str, Any]:
        rtde_receive, rtde_control, rtde_io, _ = import_ur_rtde()
        self.receive = rtde_receive.RTDEReceiveInterface(self.host, -1.0, list(RECEIVE_VARIABLES))
        flags = rtde_control.RTDEControlInterface.Flags
        if self._safety_stop() or self.receive.getRobotMode() != ROBOT_MODE_RUNNING:
            # a controller in a safety stop (or with the arm not running) does not start the control script, and
            # ur-rtde's constructor fails after waiting 5 s for it: connect without the upload;
            # reset_faults unlocks the stop, then uploads the script (reuploadScript) and arms its watchdog
            self.control = rtde_control.RTDEControlInterface(self.host, -1.0, flags.FLAG_NO_WAIT)
        else:
            self.control = rtde_control.RTDEControlInterface(self.host)
        self.io = rtde_io.RTDEIOInterface(self.host)
        # a path upload holds the arm with the speed slider at 0 (op_move_path); a link lost or a worker killed in
        # that moment leaves it there on the controller, and every later motion would stand still
        self.io.setSpeedSlider(1.0)
        if self.control.isProgramRunning():  # not after a safety stop: reset_faults uploads and arms it then
            self._arm_watchdog()
        if self.heartbeat_timeout_s is not None and self._heartbeat is None:
            self._heartbeat = threading.Thread(target=self._beat, name="ur-heartbeat", daemon=True)
            self._heartbeat.start()
        return self.op_state()

    def _arm_watchdog(self) -> None:
        """Tell the (new) control script to stop its program when the heartbeat stops: a program start removes
        the watchdogs of the one before (URScript ``rtde_set_watchdog``), so this follows every upload."""
        if self.heartbeat_timeout_s is None:
            return
        # a script that stopped meanwhile (a refused target) is reported by the motion's own checks
        if not self.control.setWatchdog(1.0 / self.heartbeat_timeout_s) and self.control.isProgramRunning():
            raise ConnectionLost("the running control script did not accept setWatchdog")

    def _safety_stop(self) -> str:
        """'protective' or 'emergency' while the receive interface shows that safety stop, else ''."""
        bits = int(self.receive.getSafetyStatusBits())
        if bits & ESTOP_MASK:
            return "emergency"
        return "protective" if bits & PROTECTIVE_MASK else ""

    def _stamp_age_s(self, stamp: float | None) -> float:
        """How long the controller's RTDE timestamp has stood still, as seen in this process (``stamp`` None: the
        stream closed)."""
        now = time.monotonic()
        if stamp is not None and stamp != self._stamp:
            self._stamp, self._stamp_changed = stamp, now
        return now - self._stamp_changed

    def abandon_control(self, reason: str) -> None:
        """Give up the control interface (a call into it is stuck): every later control request fails, the state
        comes from the receive interface alone, and the interface is disconnected in a thread of its own (ur-rtde
        sleeps 0.5 s there) so that the stuck call can never see a program start and send its command."""
        control, self.control_lost = self.control, reason
        threading.Thread(target=control.disconnect, name="ur-control-abandoned", daemon=True).start()

    def _control(self) -> Any:
        if self.control_lost:
            raise ConnectionLost(f"the control interface was given up ({self.control_lost}); reconnect")
        return self.control

    def _beat(self) -> None:
        period = (self.heartbeat_timeout_s or 1.0) / 6.0
        while True:
            time.sleep(period)
            with self.lock:
                control = None if self.control_lost else self.control
                if control is not None and control.isConnected() and control.isProgramRunning():
                    control.kickWatchdog()

    def op_state(self) -> dict[str, Any]:
        receive = self._receive_state()
        c, lost = self.control, self.control_lost
        status = None if lost else c.getAsyncOperationProgressEx()
        view = {
            "control_connected": bool(lost) or c.isConnected(),
            "control_lost": lost,
            "control_ready": not lost and c.isProgramRunning(),
            "async_running": status is not None and status.isAsyncOperationRunning(),
            "async_progress": status.progress() if status is not None else 0,
        }
        self._control_view = view
        return {**receive, **view}

    def receive_state(self) -> dict[str, Any]:
        """The state for the driver's status channel (:func:`_serve_status`), answered while a request holds the
        control interface (a path's upload, a command's handshake): the receive interface's fields now; the
        control interface's as of the last full read, or now when no request holds it."""
        if self.lock.acquire(blocking=False):
            try:
                return self.op_state()
            finally:
                self.lock.release()
        return {**self._receive_state(), **self._control_view}

    def _receive_state(self) -> dict[str, Any]:
        r = self.receive
        if r is None:
            raise ConnectionLost("not connected yet")
        if not r.isConnected():
            raise ConnectionLost("the RTDE receive connection closed")
        stamp = r.getTimestamp()
        return {
            "timestamp": stamp,
            "stamp_age_s": self._stamp_age_s(stamp),
            "pose": list(r.getActualTCPPose()),
            "speed": list(r.getActualTCPSpeed()),
            "robot_mode": r.getRobotMode(),
            "safety_mode": r.getSafetyMode(),
            "safety_status_bits": r.getSafetyStatusBits(),
            "runtime_state": r.getRuntimeState(),
            "digital_output_bits": r.getActualDigitalOutputBits(),
        }

    def op_move_linear(self, pose: list[float], speed: float, accel: float) -> bool:
        return bool(self._control().moveL(pose, speed, accel, True))

    def op_move_path(self, path: list[list[float]], upload_timeout_s: float, stale_after_s: float) -> bool:
        """ur-rtde uploads a new control script carrying the path, and a program stop drives the outputs that the
        installation sets low at a program stop (the arc) low. So: hold the arm with the speed slider at 0 while
        the new script starts the path, arm the new script's watchdog, switch back on what the upload switched
        off, then let the arm go.

        ur-rtde waits without a bound for the uploaded script to start, which a controller in a safety stop never
        does, and neither does one that stopped answering: the upload runs in a thread (ur-rtde releases the GIL
        there) watched from here, and a safety stop seen meanwhile, a receive stream that closed or stood still for
        ``stale_after_s``, or ``upload_timeout_s`` without a start, abandons it (:meth:`abandon_control`)."""
        self._control()
        stop = self._safety_stop()
        if stop:
            raise SafetyStopDuringUpload(f"{stop} stop before the path upload")
        bits_before = int(self.receive.getActualDigitalOutputBits())
        self.io.setSpeedSlider(0.0)
        try:
            deadline = time.monotonic() + 1.0
            while self.receive.getTargetSpeedFraction() > 0.0:  # held before the program restarts
                if time.monotonic() > deadline:
                    raise ConnectionLost("the speed slider did not read back 0 before the path upload")
                time.sleep(0.004)
            accepted = self._watched(
                lambda: self._upload_and_restore(path, bits_before), upload_timeout_s, stale_after_s
            )
        finally:
            self.io.setSpeedSlider(1.0)
        return accepted

    def _upload_and_restore(self, path: list[list[float]], bits_before: int) -> bool:
        """The path's upload, its watchdog armed and kicked (the heartbeat thread waits for this request), and the
        outputs the program stop switched off back on (read back)."""
        control = self.control
        if not control.moveL(path, True):
            return False
        self._arm_watchdog()
        kicked = time.monotonic()
        time.sleep(0.02)  # two controller cycles: the receive stream shows what the program stop did
        dropped = bits_before & ~int(self.receive.getActualDigitalOutputBits())
        for index in range(8):
            if dropped >> index & 1:
                self.io.setStandardDigitalOut(index, True)
        deadline = time.monotonic() + 1.0
        while dropped & ~int(self.receive.getActualDigitalOutputBits()):
            if time.monotonic() > deadline:
                raise ConnectionLost(f"outputs {dropped:#x} did not read back on after the path upload")
            if self.heartbeat_timeout_s is not None and time.monotonic() - kicked > self.heartbeat_timeout_s / 6.0:
                control.kickWatchdog()
                kicked = time.monotonic()
            time.sleep(0.004)
        return True

    def _watched(self, work: Callable[[], bool], timeout_s: float, stale_after_s: float) -> bool:
        """Run ``work`` (ur-rtde calls that wait on the controller) in a thread and watch the receive stream."""
        receive = self.receive
        result: list[bool] = []
        errors: list[BaseException] = []

        def run() -> None:
            try:
                result.append(work())
            except BaseException as err:  # handed to the request's answer below
                errors.append(err)

        upload = threading.Thread(target=run, name="ur-path-upload", daemon=True)
        upload.start()
        deadline = time.monotonic() + timeout_s
        while True:
            upload.join(_UPLOAD_POLL_S)
            if not upload.is_alive():
                if errors:
                    raise errors[0]
                return result[0]
            now = time.monotonic()
            stamp = receive.getTimestamp() if receive.isConnected() else None
            age_s = self._stamp_age_s(stamp)
            if stamp is None or age_s > stale_after_s:
                lost = "closed" if stamp is None else f"stood still for {age_s:.2f} s"
                self.abandon_control(f"the RTDE stream {lost} during the path upload")
                raise ConnectionLost(f"the controller's RTDE stream {lost} during the path upload")
            stop = self._safety_stop()
            if stop:
                self.abandon_control(f"{stop} stop during the path upload")
                raise SafetyStopDuringUpload(f"{stop} stop during the path upload")
            if now > deadline:
                self.abandon_control(f"the path's control script did not start within {timeout_s:.1f} s")
                raise ConnectionLost(f"the path's control script did not start within {timeout_s:.1f} s")

    def op_stop(self, decel: float) -> None:
        self._control().stopL(decel, False)

    def op_reupload(self) -> bool:
        ok = bool(self._control().reuploadScript())
        if ok:
            self._arm_watchdog()
        return ok

    def op_set_digital_output(self, index: int, value: bool) -> bool:
        return bool(self.io.setStandardDigitalOut(index, value))  # the IO interface: works while control is lost

    def op_dashboard(self, commands: list[str]) -> list[str]:
        _, _, _, dashboard_client = import_ur_rtde()
        client = dashboard_client.DashboardClient(self.host, self.dashboard_port)
        client.connect()
        replies = []
        for command in commands:
            client.send(command + "\n")
            replies.append(client.receive())
        client.disconnect()
        return replies

    def op_close(self) -> None:
        control = None if self.control_lost else self.control
        if control is not None and control.isConnected() and control.isProgramRunning():
            control.stopScript()


class StatusChannel:
    """The driver's end of the status channel (:func:`_serve_status` answers at the other): a second pipe to the
    worker, so that a state read never waits behind a request on the first (a path's upload, a command's
    handshake: tenths of a second on a loaded host, which the job watchdog's status deadline took for a controller
    that does not answer). ``what`` names the worker in errors."""

    def __init__(self, conn: Connection, what: str) -> None:
        self._conn = conn
        self._what = what
        self._seq = 0

    def read(self, timeout_s: float) -> tuple[Any, ...]:
        """``("ok", seq, state)`` or ``("error", seq, kind, message)``; DeviceTimeout after ``timeout_s``,
        ConnectionLost when the channel ended. Not thread-safe: the driver holds a lock around it."""
        self._seq += 1
        deadline = time.monotonic() + timeout_s
        try:
            self._conn.send(self._seq)
            while True:  # an answer to an earlier read that timed out comes first: dropped
                left = deadline - time.monotonic()
                if left <= 0.0 or not self._conn.poll(left):
                    raise DeviceTimeout(f"{self._what} did not answer a state read within {timeout_s:.1f} s")
                reply: tuple[Any, ...] = self._conn.recv()
                if reply[1] == self._seq:
                    return reply
        except (EOFError, OSError) as err:
            raise ConnectionLost(f"{self._what} ended during a state read; call connect() again") from err

    def close(self) -> None:
        self._conn.close()


def _serve_status(conn: Connection, worker: Worker) -> None:
    """The status channel: answer each request ``seq`` with ``("ok", seq, state)`` or ``("error", seq, kind,
    message)`` from a thread of its own, so that a state read never waits behind a request on the main pipe (ur-rtde
    releases the GIL in its calls; its constructors, in connect, do not)."""
    while True:
        try:
            seq = conn.recv()
        except (EOFError, OSError):
            return
        try:
            reply: tuple[Any, ...] = ("ok", seq, worker.receive_state())
        except Exception as err:
            reply = ("error", seq, type(err).__name__, str(err))
        try:
            conn.send(reply)
        except (OSError, ValueError):
            return


def worker_main(
    conn: Connection, status_conn: Connection, host: str, dashboard_port: int, heartbeat_timeout_s: float | None
) -> None:
    """Entry point of the worker process: answer requests until told to close or the driver goes away; state reads
    on ``status_conn`` are answered beside them (:func:`_serve_status`).

    When the driver's process dies (even by SIGKILL) the pipe ends, this process exits and the heartbeat stops with
    it: the controller's watchdog then stops the program (arm stopped, arc output low)."""
    # the driver handles Ctrl-C (and stops the arm through this worker); before any thread starts, they inherit the
    # priority (the heartbeat, ur-rtde's receive threads)
    enter_io_process()
    worker = Worker(host, dashboard_port, heartbeat_timeout_s)
    threading.Thread(target=_serve_status, args=(status_conn, worker), name="ur-status", daemon=True).start()
    while True:
        try:
            op, args = conn.recv()
        except (EOFError, OSError):
            os._exit(0)
        try:
            with worker.lock:
                result = getattr(worker, f"op_{op}")(*args)
            conn.send(("ok", result))
        except Exception as err:
            conn.send(("error", type(err).__name__, str(err)))
        if op == "close":
            conn.close()
            # ur-rtde's disconnect() sleeps 0.5 s per interface; ending the process closes the sockets just as well
            os._exit(0)


@dataclass(frozen=True)
class Status:
    """One RTDE state sample as the driver uses it."""

    X_base_tool: FloatArray
    tcp_speed: tuple[float, ...]
    robot_mode: int
    safety_mode: int
    safety_status_bits: int
    runtime_state: int
    digital_output_bits: int
    async_running: bool
    async_progress: int
    control_ready: bool  # the control interface's own view of the script: running
    control_lost: str = ""  # why the worker gave its control interface up ('' while in use): reconnect first

    @classmethod
    def from_raw(cls, raw: dict[str, Any]) -> Status:
        """The sample of the worker's answer to ``state`` (:meth:`Worker.op_state`)."""
        return cls(
            X_base_tool=X_from_ur_pose(raw["pose"]),
            tcp_speed=tuple(raw["speed"]),
            robot_mode=int(raw["robot_mode"]),
            safety_mode=int(raw["safety_mode"]),
            safety_status_bits=int(raw["safety_status_bits"]),
            runtime_state=int(raw["runtime_state"]),
            digital_output_bits=int(raw["digital_output_bits"]),
            async_running=bool(raw["async_running"]),
            async_progress=int(raw["async_progress"]),
            control_ready=bool(raw["control_ready"]),
            control_lost=str(raw["control_lost"]),
        )

    def robot_state(self) -> RobotState:
        """What this sample says as the Robot protocol's state (the first of: emergency stop, protective stop, a
        safety fault or violation, a robot mode other than RUNNING; else moving or idle)."""
        bits = self.safety_status_bits
        if self.emergency_stop:
            mode, message = RobotMode.EMERGENCY_STOP, f"emergency stop (safety mode {self.safety_mode})"
        elif self.protective_stop:
            mode, message = RobotMode.PROTECTIVE_STOP, f"protective stop (safety mode {self.safety_mode})"
        elif bits & ((1 << SAFETY_BIT_FAULT) | (1 << SAFETY_BIT_VIOLATION)):
            mode, message = RobotMode.FAULT, f"safety fault or violation (safety status bits {bits:#x})"
        elif self.robot_mode != ROBOT_MODE_RUNNING:
            robot_mode = ROBOT_MODE_NAMES.get(self.robot_mode, str(self.robot_mode))
            mode, message = RobotMode.FAULT, f"robot mode {robot_mode}: power the arm on and release its brakes"
        else:
            mode, message = (RobotMode.MOVING if self.moving else RobotMode.IDLE), ""
        return RobotState(
            mode=mode,
            X_base_tool=self.X_base_tool,
            is_moving=self.moving,
            protective_stop=self.protective_stop,
            emergency_stop=self.emergency_stop,
            digital_outputs=tuple(bool(self.digital_output_bits >> i & 1) for i in range(8)),
            message=message,
        )

    @property
    def emergency_stop(self) -> bool:
        return bool(self.safety_status_bits & ESTOP_MASK)

    @property
    def protective_stop(self) -> bool:
        return bool(self.safety_status_bits & PROTECTIVE_MASK)

    @property
    def moving(self) -> bool:
        v = self.tcp_speed
        return math.hypot(v[0], v[1], v[2]) > _MOVING_SPEED_M_S or math.hypot(v[3], v[4], v[5]) > _MOVING_SPEED_RAD_S

    @property
    def program_running(self) -> bool:
        return self.runtime_state == RUNTIME_PLAYING
