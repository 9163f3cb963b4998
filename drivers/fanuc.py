"""A FANUC arm through the Remote Motion Interface: ``drivers.protocols.Robot`` over ``drivers.fanuc_rmi``.

Threading: every public method blocks, with a timeout, for its answer from the I/O process (below). Methods may
be called from several threads (``stop()`` from a watchdog while ``move_linear`` blocks in another).
``on_progress`` callbacks run in the thread that called ``stream_path``.

Units: SI at this API (metres, m/s, ``X_base_tool`` 4x4); millimetres and degrees exist only on the wire and
are converted here, once, with :func:`perception.transforms.xyzwpr_mm_deg_from_X` and its inverse.
The base frame is the controller's user frame ``uframe`` (0 = world) and the tool frame is ``utool``.

Safety: a protective or emergency stop is read from ``FRC_GetStatus`` (polled every ``status_poll_s`` during
motion) and raised as :class:`ProtectiveStop` / :class:`EmergencyStop`; both stay latched until the cause is
cleared and :meth:`FanucRobot.reset_faults` (FRC_Reset) is called, which the cell does only after an
operator's acknowledgement. An unsolicited ``FRC_SystemFault`` raises :class:`SystemFault` and latches the
same way.

Host heartbeat (``heartbeat_register``, docs/controller-watchdogs.md): while connected, the I/O process writes
``R[heartbeat_register]`` every ``heartbeat_period_s``: a changing count (1..30000) while a digital output this
driver switched on is on or a motion is in flight, 0 (the watchdog disarmed) when there is nothing to make safe;
a count is written and answered before an output goes on or a motion is sent, so nothing dangerous starts disarmed.
The integrator's ``WC_HBEAT`` program on the controller switches the arc output off and stops the motion (user
alarm, STOP.G) when that register stands still for its timeout: a dropped link, a hung or killed host.

Process: the RMI session, the heartbeat and every request live in a child process (:mod:`drivers.fanuc_worker`,
a fresh interpreter started at the first :meth:`FanucRobot.connect`), so that a host busy with
detection (holding the GIL for longer than the watchdog's timeout) cannot silence the heartbeat while a motion is
in flight. This module validates and converts, sends each request over a pipe and waits for its answer with a
deadline; a thread (``fanuc-rmi-<name>``) reads the answers. The child exits when its pipe ends: a killed host
takes its heartbeat with it.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import queue
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from drivers import errors
from drivers.errors import ConnectionLost, DeviceTimeout, DriverError, MotionRejected, MotionTimeout
from drivers.fanuc_protocol import RMI_CONNECT_PORT, RMIMotionRejected, RMIStatus
from drivers.fanuc_worker import MOTION_STATUS_TIMEOUT_S, MOVING_SPEED_MM_S, Settings
from drivers.protocols import FloatArray, RobotMode, RobotState
from perception.transforms import TransformError, X_from_xyzwpr_mm_deg, check_X, xyzwpr_mm_deg_from_X

logger = logging.getLogger(__name__)

__all__ = ["CNT100_BLEND_M", "MOTION_STATUS_TIMEOUT_S", "MOVING_SPEED_MM_S", "FanucRobot"]

CNT100_BLEND_M = 0.010
"""The blend radius mapped to CNT100. FANUC's CNT value is a corner-rounding percentage, not a distance; the
mapping ``CNT = 100 * blend_m / CNT100_BLEND_M`` (clamped to 1..100) is weldcell's convention."""

_PACKAGE_ROOT = str(Path(__file__).resolve().parents[1])
_WORKER_CODE = "import sys; from drivers.fanuc_worker import main; main(int(sys.argv[1]))"

WORKER_START_TIMEOUT_S = 30.0
"""How long a new I/O process may take to start (a spawned interpreter importing the driver, on a loaded host)."""

_ERROR_TYPES: dict[str, type[BaseException]] = {
    **{name: obj for name, obj in vars(errors).items() if isinstance(obj, type) and issubclass(obj, DriverError)},
    "RMIMotionRejected": RMIMotionRejected,
    "TimeoutError": TimeoutError,
    "ValueError": ValueError,
}


def _error_from(what: str, kind: str, message: str, code: int | str | None) -> BaseException:
    """The exception the I/O process raised, rebuilt here (same type, message and vendor code)."""
    cls = _ERROR_TYPES.get(kind)
    if cls is None:
        return DriverError(f"{what}: {kind} in the FANUC I/O process: {message}")
    err = cls.__new__(cls)
    BaseException.__init__(err, message)
    if isinstance(err, errors.DeviceFault):
        err.code = code
    return err


class _Request:
    """One request in flight: its answers (progress, then one final) arrive on :attr:`answers`."""

    def __init__(self) -> None:
        self.answers: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()


class _Worker:
    """The I/O process (:func:`drivers.fanuc_worker.worker_main`), its pipe and the thread reading answers."""

    def __init__(self, settings: Settings) -> None:
        self.name = settings.name
        # A plain child interpreter on one end of a socket pair (not multiprocessing's spawn, which would import
        # the host's __main__ module, the whole daemon, into it first): it imports the worker module only.
        ours, theirs = socket.socketpair()
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (_PACKAGE_ROOT, env.get("PYTHONPATH", "")) if p)
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _WORKER_CODE, str(theirs.fileno())],
            pass_fds=(theirs.fileno(),),
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
        )
        theirs.close()
        self.conn = Connection(ours.detach())
        self._send_lock = threading.Lock()
        self._pending: dict[int, _Request] = {}
        self._ids = itertools.count(1)
        self._ready = threading.Event()
        self._gone: str | None = None
        self._reader = threading.Thread(target=self._read, name=f"fanuc-rmi-{settings.name}", daemon=True)
        self._reader.start()
        with contextlib.suppress(ConnectionLost):
            self.conn.send(settings)
        if not self._ready.wait(WORKER_START_TIMEOUT_S) or self._gone is not None:
            self.stop(grace_s=0.0)
            raise ConnectionLost(
                f"{self.name}: the FANUC I/O process did not start within {WORKER_START_TIMEOUT_S:.0f} s"
            )

    @property
    def alive(self) -> bool:
        return self._gone is None and self.proc.poll() is None

    def _read(self) -> None:
        while True:
            try:
                rid, kind, value = self.conn.recv()
            except (EOFError, OSError):
                break
            if kind == "ready":
                self._ready.set()
            elif kind == "log":
                level, message = value
                logger.log(level, "%s", message)
            else:
                request = self._pending.get(rid)
                if request is not None:
                    request.answers.put((kind, value))
        self._gone = f"{self.name}: the FANUC I/O process ended"
        self._ready.set()
        for request in list(self._pending.values()):
            request.answers.put(("error", ("ConnectionLost", f"{self._gone}; call connect() again", None)))

    def send(self, rid: int, op: str, args: tuple[Any, ...] = ()) -> None:
        with self._send_lock:
            try:
                self.conn.send((rid, op, args))
            except (OSError, ValueError) as err:
                raise ConnectionLost(f"{self.name}: the FANUC I/O process is gone ({err}); call connect()") from err

    def open(self, op: str, args: tuple[Any, ...]) -> tuple[int, _Request]:
        """Send ``op`` and return its id and the queue its answers arrive on (close it with :meth:`close`)."""
        if self._gone is not None:
            raise ConnectionLost(f"{self._gone}; call connect() again")
        rid, request = next(self._ids), _Request()
        self._pending[rid] = request
        try:
            self.send(rid, op, args)
        except BaseException:
            self._pending.pop(rid, None)
            raise
        if self._gone is not None:  # ended between the check and the registration: nobody will answer
            request.answers.put(("error", ("ConnectionLost", f"{self._gone}; call connect() again", None)))
        return rid, request

    def close(self, rid: int) -> None:
        self._pending.pop(rid, None)

    def call(self, op: str, *args: Any, timeout_s: float, what: str) -> Any:
        """Run ``op`` in the I/O process and return its result; DeviceTimeout (and cancel it) after timeout_s."""
        rid, request = self.open(op, args)
        try:
            try:
                kind, value = request.answers.get(timeout=timeout_s)
            except queue.Empty:
                with contextlib.suppress(ConnectionLost):
                    self.send(rid, "cancel")
                raise DeviceTimeout(f"{what}: no result within {timeout_s:.1f} s") from None
        finally:
            self.close(rid)
        return result_of(kind, value, what)

    def stop(self, *, grace_s: float = 2.0) -> None:
        """Ask the process to exit; kill it after ``grace_s``; join the reader."""
        with contextlib.suppress(ConnectionLost):
            self.send(0, "exit")
        try:
            self.proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(2.0)
        self.conn.close()
        self._reader.join(timeout=2.0)


def result_of(kind: str, value: Any, what: str) -> Any:
    """The value of a final answer, or its error raised."""
    if kind == "ok":
        return value
    raise _error_from(what, *value)


class FanucRobot:
    """A FANUC arm (R-30iB with R912 RMI) as a :class:`drivers.protocols.Robot`.

    ``host``/``port``: the controller's address and RMI connect port (from the cell config; no default host).
    ``timeout_s``: per-request timeout for commands. ``status_poll_s``: how often safety state is read during
    motion. ``n_digital_outputs``: how many of ``DO[1..]`` appear in :attr:`RobotState.digital_outputs`
    (``index`` i of this API is the controller's ``DO[i + 1]``). ``heartbeat_register``: ``R[n]`` rewritten every
    ``heartbeat_period_s`` for the controller's watchdog program (None: no heartbeat).
    """

    def __init__(
        self,
        host: str,
        *,
        port: int = RMI_CONNECT_PORT,
        name: str = "fanuc",
        uframe: int = 0,
        utool: int = 1,
        group_mask: int = 1,
        timeout_s: float = 2.0,
        status_poll_s: float = 0.05,
        n_digital_outputs: int = 8,
        heartbeat_register: int | None = None,
        heartbeat_period_s: float = 0.05,
    ) -> None:
        if timeout_s <= 0 or status_poll_s <= 0:
            raise ValueError(f"timeout_s and status_poll_s must be > 0, got {timeout_s}, {status_poll_s}")
        if heartbeat_register is not None and heartbeat_register < 1:
            raise ValueError(f"heartbeat_register is R[n] with n >= 1, got {heartbeat_register}")
        self.name = name
        self.host = host
        self.port = port
        self.uframe = uframe
        self.utool = utool
        self.group_mask = group_mask
        self.timeout_s = timeout_s
        self.status_poll_s = status_poll_s
        self.n_digital_outputs = n_digital_outputs
        self.heartbeat_register = heartbeat_register
        self.heartbeat_period_s = heartbeat_period_s
        self._worker: _Worker | None = None
        self._connected = False
        self._lifecycle_lock = threading.Lock()

    def _settings(self) -> Settings:
        return Settings(
            name=self.name,
            host=self.host,
            port=self.port,
            uframe=self.uframe,
            utool=self.utool,
            group_mask=self.group_mask,
            timeout_s=self.timeout_s,
            status_poll_s=self.status_poll_s,
            n_digital_outputs=self.n_digital_outputs,
            heartbeat_register=self.heartbeat_register,
            heartbeat_period_s=self.heartbeat_period_s,
            log_level=logger.getEffectiveLevel(),
        )

    # ============================================================================== connection
    def connect(self) -> None:
        """Open (or re-open) the RMI session. Raises ConnectionLost when the controller is unreachable."""
        with self._lifecycle_lock:
            self._connected = False
            worker = self._worker
            if worker is None or not worker.alive:
                if worker is not None:
                    worker.stop(grace_s=0.0)
                self._worker = None
                worker = _Worker(self._settings())
                self._worker = worker
            try:
                worker.call("connect", timeout_s=self.timeout_s + 2.0, what=f"{self.name}: connect")
            except BaseException:
                worker.stop()
                self._worker = None
                raise
            self._connected = True
            logger.info("%s: connected to FANUC RMI at %s:%d", self.name, self.host, self.port)

    def disconnect(self) -> None:
        """Say FRC_Disconnect (the controller aborts RMI_MOVE), close, end the I/O process. Safe twice."""
        with self._lifecycle_lock:
            worker, self._worker = self._worker, None
            self._connected = False
            if worker is None:
                return
            with contextlib.suppress(DriverError):
                worker.call("disconnect", timeout_s=4.0, what=f"{self.name}: disconnect")
            worker.stop()
            logger.info("%s: disconnected", self.name)

    def _session(self) -> _Worker:
        worker = self._worker
        if worker is None or not self._connected:
            raise ConnectionLost(f"{self.name}: not connected to the FANUC controller; call connect() first")
        return worker

    def _run(self, op: str, *args: Any, n_requests: int, what: str) -> Any:
        return self._session().call(op, *args, timeout_s=n_requests * self.timeout_s + 1.0, what=f"{self.name}: {what}")

    # ============================================================================== state
    def state(self) -> RobotState:
        raw = self._run("state", n_requests=3 + self.n_digital_outputs, what="state")
        status = RMIStatus.from_reply(raw["status"])
        speed_mm_s, fault = float(raw["tcp_speed_mm_s"]), raw["system_fault"]
        moving = speed_mm_s > MOVING_SPEED_MM_S
        if status.emergency_stop:
            mode = RobotMode.EMERGENCY_STOP
        elif status.protective_stop:
            mode = RobotMode.PROTECTIVE_STOP
        elif fault is not None or not status.servo_ready:
            mode = RobotMode.FAULT
        else:
            mode = RobotMode.MOVING if moving else RobotMode.IDLE
        message = (
            f"servo_ready={int(status.servo_ready)} tp_mode={status.tp_mode} "
            f"rmi_motion_status={status.rmi_motion_status} next_sequence_id={status.next_sequence_id} "
            f"tcp_speed_mm_s={speed_mm_s:.1f}"
        )
        if fault is not None:
            message += f"; {fault}"
        return RobotState(
            mode=mode,
            X_base_tool=X_from_xyzwpr_mm_deg(raw["xyzwpr_mm_deg"]),
            is_moving=moving,
            protective_stop=status.protective_stop,
            emergency_stop=status.emergency_stop,
            digital_outputs=tuple(raw["digital_outputs"]),
            message=message,
        )

    def get_X_base_tool(self) -> FloatArray:
        return X_from_xyzwpr_mm_deg(self._run("position", n_requests=1, what="read position"))

    # ============================================================================== I/O and stops
    def set_digital_output(self, index: int, value: bool) -> None:
        if index < 0:
            raise ValueError(f"digital output index must be >= 0 (DO[index + 1]), got {index}")
        logger.debug("%s: DO[%d] <- %s", self.name, index + 1, value)
        self._run("write_dout", index, bool(value), n_requests=1, what=f"write DO[{index + 1}]")

    def stop(self) -> None:
        """FRC_Abort: stop now and drop the queued instructions (a blocked move raises MotionAborted)."""
        self._run("abort", n_requests=1, what="abort")

    def reset_faults(self) -> None:
        """FRC_Reset: clear controller alarms, HOLD and the latched system fault; safety stops clear only once
        their cause is gone (RMIError RMIT-012 otherwise). Call after an operator acknowledged the fault."""
        self._run("reset", n_requests=1, what="reset")

    # ============================================================================== motion
    def move_linear(
        self, X_base_tool: FloatArray, *, speed_m_s: float, accel_m_s2: float = 0.5, timeout_s: float = 60.0
    ) -> None:
        """Straight line to ``X_base_tool`` ((4, 4), metres), FINE, blocking until the controller reports it done.

        ``accel_m_s2`` is checked but not sent: RMI's ACC is a percentage of the arm's tuned profile, not an
        acceleration, so the controller's default (ACC100) applies.
        """
        target = self._xyzwpr_target(X_base_tool, "X_base_tool")
        self._check_accel(accel_m_s2)
        self._run_motion([target], speed_mm_s=self._speed_mm_s(speed_m_s), cnt_value=0, timeout_s=timeout_s)

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
        """Every pose in order, CNT-blended (``blend_m`` > 0) with FINE at the last, at most 8 in flight.

        ``on_progress(i)`` runs in the calling thread, in order, as the controller reports pose ``i`` done.
        """
        targets = [self._xyzwpr_target(X, f"X_base_tool_path[{i}]") for i, X in enumerate(X_base_tool_path)]
        self._check_accel(accel_m_s2)
        if blend_m < 0:
            raise MotionRejected(f"blend_m must be >= 0, got {blend_m}")
        if not targets:
            return
        cnt = 0 if blend_m == 0 else int(np.clip(round(100.0 * blend_m / CNT100_BLEND_M), 1, 100))
        self._run_motion(
            targets, speed_mm_s=self._speed_mm_s(speed_m_s), cnt_value=cnt, timeout_s=timeout_s, on_progress=on_progress
        )

    @staticmethod
    def _xyzwpr_target(X: FloatArray, name: str) -> tuple[float, ...]:
        try:
            X_checked = check_X(X, name=name)
        except TransformError as err:
            raise MotionRejected(f"refusing to move to an invalid pose: {err}") from err
        return tuple(float(v) for v in xyzwpr_mm_deg_from_X(X_checked))

    @staticmethod
    def _speed_mm_s(speed_m_s: float) -> int:
        speed_mm_s = round(float(speed_m_s) * 1000.0)
        if not 1 <= speed_mm_s <= 65535:
            raise MotionRejected(
                f"speed_m_s={speed_m_s} is {speed_mm_s} mm/s on the wire; RMI needs an integer 1..65535 mm/s"
            )
        return speed_mm_s

    @staticmethod
    def _check_accel(accel_m_s2: float) -> None:
        if not accel_m_s2 > 0:
            raise MotionRejected(f"accel_m_s2 must be > 0, got {accel_m_s2}")

    def _run_motion(
        self,
        targets: list[tuple[float, ...]],
        *,
        speed_mm_s: int,
        cnt_value: int,
        timeout_s: float,
        on_progress: Callable[[int], None] | None = None,
    ) -> None:
        worker = self._session()
        logger.debug(
            "%s: %d linear target(s) at %d mm/s, CNT %d, timeout %.1f s",
            self.name,
            len(targets),
            speed_mm_s,
            cnt_value,
            timeout_s,
        )
        what = f"{self.name}: motion"
        rid, request = worker.open("motion", (targets, speed_mm_s, cnt_value, timeout_s))
        # Grace for the preparation requests and a best-effort abort on the way out.
        deadline = time.monotonic() + timeout_s + 6.0 * self.timeout_s + 1.0
        final: tuple[str, Any] | None = None
        try:
            while final is None:
                if time.monotonic() > deadline:
                    raise MotionTimeout(f"{self.name}: motion did not finish within {timeout_s} s")
                try:
                    kind, value = request.answers.get(timeout=0.02)
                except queue.Empty:
                    continue
                if kind != "progress":
                    final = (kind, value)
                elif on_progress is not None:
                    on_progress(int(value))
        except BaseException:
            # still running (a timeout, a callback that raised, Ctrl-C): cancel it; the motion aborts the program on
            # its way out, and that abort goes out before this returns
            with contextlib.suppress(ConnectionLost):
                worker.send(rid, "cancel")
            end = time.monotonic() + 2.0 * self.timeout_s + 1.0
            with contextlib.suppress(queue.Empty):
                while request.answers.get(timeout=max(end - time.monotonic(), 0.0))[0] == "progress":
                    pass
            raise
        finally:
            worker.close(rid)
        result_of(*final, what)
