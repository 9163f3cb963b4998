"""The FANUC driver's I/O process: the RMI session, the host heartbeat and every request to the controller.

Why a process (``drivers.ur`` does the same for ur-rtde): the heartbeat (``R[heartbeat_register]`` every 50 ms,
watched by the controller's ``WC_HBEAT`` with a 0.3 s timeout, docs/controller-watchdogs.md) must not depend on the
host's interpreter. In the daemon's process a detection can hold the GIL for longer than the timeout while a motion
is in flight, and the controller then trips its alarm in the middle of a job although the host is alive. Here the
asyncio loop that owns the :class:`~drivers.fanuc_rmi.RMIClient` and writes the heartbeat runs in a process of its
own; :class:`drivers.fanuc.FanucRobot` talks to it over a pipe. When the driver's process dies (even by SIGKILL)
the pipe ends, this process exits, the heartbeat stops and the controller's watchdog makes the cell safe.

The pipe carries pickled tuples:

- driver to worker: ``(rid, op, args)`` runs ``_Session.op_<op>(*args)``; ``(rid, "cancel", ())`` cancels request
  ``rid`` (a motion aborts the program on its way out); ``(0, "exit", ())`` ends the process.
- worker to driver: ``(rid, "ok", value)``, ``(rid, "error", (type name, message, code))``,
  ``(rid, "progress", index)`` (pose ``index`` of motion ``rid`` done) and ``(0, "log", (level, message))`` (a log
  record for the driver's logger); ``(0, "ready", pid)`` once when the process has started.

Units are the controller's (mm, degrees, mm/s): the driver converts to SI.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

from drivers.errors import (
    ConnectionLost,
    DeviceFault,
    DeviceTimeout,
    DriverError,
    EmergencyStop,
    MotionTimeout,
    ProtectiveStop,
    RMIError,
    SystemFault,
)
from drivers.fanuc_protocol import RMIStatus, instructions_for_path
from drivers.fanuc_rmi import RMIClient
from drivers.priority import enter_io_process

logger = logging.getLogger("drivers.fanuc")

MOTION_STATUS_TIMEOUT_S = 0.4
"""A status request during a motion must be answered within this long (see _Session._motion_status)."""

MOVING_SPEED_MM_S = 0.5
"""TCP speeds above this (``FRC_ReadTCPSpeed``) count as moving."""

HEARTBEAT_MAX_COUNT = 30000
"""The heartbeat counts 1..HEARTBEAT_MAX_COUNT and wraps to 1 (0 means disarmed)."""


@dataclass(frozen=True)
class Settings:
    """What the worker needs of the driver's configuration (see :class:`drivers.fanuc.FanucRobot`)."""

    name: str
    host: str
    port: int
    uframe: int
    utool: int
    group_mask: int
    timeout_s: float
    status_poll_s: float
    n_digital_outputs: int
    heartbeat_register: int | None
    heartbeat_period_s: float
    log_level: int = logging.WARNING


class _Session:
    """The RMI session inside the worker: each ``op_*`` coroutine answers one request of the driver."""

    def __init__(self, settings: Settings) -> None:
        self.s = settings
        self.client: RMIClient | None = None
        self._heartbeat: asyncio.Task[None] | None = None
        self._outputs_on: set[int] = set()  # outputs switched on (and not off since)
        self._motions = 0  # motions in flight
        self._count = 0  # the heartbeat's last count
        # held while the register's next value is chosen and written: a beat that chose 0 (nothing on) must not
        # reach the controller after the count that armed it for an output or a motion
        self._beat_lock: asyncio.Lock | None = None

    def _session(self) -> RMIClient:
        if self.client is None:
            raise ConnectionLost(f"{self.s.name}: not connected to the FANUC controller; call connect() first")
        return self.client

    # ------------------------------------------------------------------------------------------ connection
    async def op_connect(self) -> None:
        old, self.client = self.client, None
        if old is not None:  # a dead or stale session: close it without a goodbye
            with contextlib.suppress(DriverError):
                await asyncio.wait_for(old.close(), timeout=3.0)
        if self._heartbeat is not None:
            self._heartbeat.cancel()
            self._heartbeat = None
        client = RMIClient(self.s.host, self.s.port, timeout_s=self.s.timeout_s)
        await client.connect()
        self.client = client
        self._beat_lock = asyncio.Lock()
        if self.s.heartbeat_register is not None:
            self._heartbeat = asyncio.ensure_future(self._beat(client, self.s.heartbeat_register))

    async def _beat(self, client: RMIClient, register: int) -> None:
        """R[register] = 1, 2, ... 30000, 1, ... every heartbeat_period_s while the session lives."""
        assert self._beat_lock is not None
        while client.connected:
            # armed (counting) while an output is on or a motion is in flight; 0 (disarmed) otherwise, so that
            # pendant work with the host connected and idle is not tripped by a host that pauses
            async with self._beat_lock:
                value = self._next_count() if (self._outputs_on or self._motions) else 0
                try:
                    await client.write_numeric_register(register, value, timeout_s=self.s.timeout_s)
                except DriverError as err:  # the controller's watchdog acts on the silence; say so once per failure
                    logger.warning("%s: heartbeat R[%d] not written: %s", self.s.name, register, err)
            await asyncio.sleep(self.s.heartbeat_period_s)

    def _next_count(self) -> int:
        self._count = self._count % HEARTBEAT_MAX_COUNT + 1
        return self._count

    async def _arm(self, client: RMIClient) -> None:
        """Write the heartbeat's next count and wait for the controller's answer, before an output goes on or a
        motion is sent: the watchdog is idle while the register reads 0, and a host that died between its arc-on
        and its next beat would otherwise leave the arc on with nothing watching (DriverError: not armed, so the
        caller must not go on)."""
        register = self.s.heartbeat_register
        if register is None:
            return
        assert self._beat_lock is not None
        async with self._beat_lock:
            await client.write_numeric_register(register, self._next_count(), timeout_s=self.s.timeout_s)

    async def op_disconnect(self) -> None:
        client, self.client = self.client, None
        if self._heartbeat is not None:
            self._heartbeat.cancel()
            self._heartbeat = None
        if client is None:
            return
        register = self.s.heartbeat_register
        if register is not None and not (self._outputs_on or self._motions):
            # a goodbye with nothing left on disarms the watchdog (a count left standing would trip it, and its
            # STOP.G alarm, 0.3 s later); with an output still on the count stands and the controller switches it off
            with contextlib.suppress(DriverError):
                await client.write_numeric_register(register, 0, timeout_s=1.0)
        with contextlib.suppress(DriverError):
            await client.disconnect(timeout_s=1.0)

    async def op_close(self) -> None:
        """Close the socket without a goodbye (the process is about to end)."""
        client, self.client = self.client, None
        if client is not None:
            await client.close()

    # ------------------------------------------------------------------------------------------ state and I/O
    async def op_state(self) -> dict[str, Any]:
        client = self._session()
        status = await client.get_status()
        position = await client.read_cartesian_position()
        speed_mm_s = await client.read_tcp_speed_mm_s()
        outputs = tuple([await client.read_dout(i + 1) for i in range(self.s.n_digital_outputs)])
        fault = client.system_fault
        return {
            "status": status.raw,
            "xyzwpr_mm_deg": position.xyzwpr_mm_deg,
            "tcp_speed_mm_s": speed_mm_s,
            "digital_outputs": outputs,
            "system_fault": None if fault is None else str(fault),
        }

    async def op_position(self) -> tuple[float, ...]:
        return (await self._session().read_cartesian_position()).xyzwpr_mm_deg

    async def op_write_dout(self, index: int, value: bool) -> None:
        client = self._session()
        if value:
            was_on = index in self._outputs_on
            self._outputs_on.add(index)  # the beats count from here on
            try:
                await self._arm(client)  # and the controller has seen a count before the output goes on
            except BaseException:
                if not was_on:
                    self._outputs_on.discard(index)
                raise
        await client.write_dout(index + 1, value)
        if not value:
            self._outputs_on.discard(index)

    async def op_abort(self) -> None:
        await self._session().abort(ignore_not_running=True)

    async def op_reset(self) -> None:
        await self._session().reset()

    # ------------------------------------------------------------------------------------------ motion
    async def op_motion(
        self,
        targets: list[tuple[float, ...]],
        speed_mm_s: int,
        cnt_value: int,
        timeout_s: float,
        on_complete: Callable[[int], None],
    ) -> None:
        client = self._session()
        self._motions += 1  # the heartbeat is armed while a motion is in flight
        try:
            await self._arm(client)  # before its first instruction is sent
            await self._motion(client, targets, speed_mm_s, cnt_value, timeout_s, on_complete)
        finally:
            self._motions -= 1

    async def _motion(
        self,
        client: RMIClient,
        targets: list[tuple[float, ...]],
        speed_mm_s: int,
        cnt_value: int,
        timeout_s: float,
        on_complete: Callable[[int], None],
    ) -> None:
        status = await client.get_status()
        self._raise_if_unsafe(client, status)
        await self._prepare_program(client, status)
        configuration = dict((await client.read_cartesian_position()).configuration)
        configuration.update({"UFrameNumber": self.s.uframe, "UToolNumber": self.s.utool})
        instructions = instructions_for_path(
            targets, speed_mm_s=speed_mm_s, cnt_value=cnt_value, configuration=configuration
        )
        stream = asyncio.ensure_future(
            client.run_instructions(instructions, timeout_s=timeout_s, on_complete=on_complete)
        )
        try:
            while True:
                done, _ = await asyncio.wait({stream}, timeout=self.s.status_poll_s)
                if done:
                    stream.result()
                    return
                status = await self._motion_status(client)
                error = safety_error(self.s.name, status, client.system_fault) or paused_error(self.s.name, status)
                if error is not None:
                    raise error
        except BaseException as err:
            if not stream.done():
                stream.cancel()
            await asyncio.gather(stream, return_exceptions=True)
            if isinstance(err, ConnectionLost):
                raise
            await self._abort_quietly(client)
            if isinstance(err, RMIError | SystemFault | MotionTimeout):
                # An instruction refused because a safety stop hit is reported as that safety stop.
                safety = await self._safety_error_quietly(client)
                if safety is not None:
                    raise safety from err
            raise

    async def _motion_status(self, client: RMIClient) -> RMIStatus:
        """FRC_GetStatus during a motion, answered within MOTION_STATUS_TIMEOUT_S or the session is given up: a
        controller that stops answering mid-motion is a lost connection now, not after the command timeout."""
        timeout_s = min(self.s.timeout_s, MOTION_STATUS_TIMEOUT_S)
        try:
            return await client.get_status(timeout_s=timeout_s)
        except DeviceTimeout as err:
            reason = f"{self.s.name}: no answer to FRC_GetStatus within {timeout_s:.1f} s during a motion"
            client.abandon(reason)
            raise ConnectionLost(f"{reason}; connect again once it answers") from err

    async def _prepare_program(self, client: RMIClient, status: RMIStatus) -> None:
        """Make sure RMI_MOVE runs, empty, with our sequence counter; (re)initialize it otherwise."""
        if status.rmi_running and client.in_flight == 0 and status.next_sequence_id == client.next_sequence_id:
            return
        if status.rmi_motion_status != 0:
            await client.abort()
        await client.initialize(group_mask=self.s.group_mask)
        await client.set_uframe_utool(uframe=self.s.uframe, utool=self.s.utool)
        logger.debug("%s: RMI_MOVE initialized (UFrame %d, UTool %d)", self.s.name, self.s.uframe, self.s.utool)

    def _raise_if_unsafe(self, client: RMIClient, status: RMIStatus) -> None:
        error = safety_error(self.s.name, status, client.system_fault)
        if error is not None:
            raise error

    async def _safety_error_quietly(self, client: RMIClient) -> DriverError | None:
        try:
            status = await client.get_status(timeout_s=min(self.s.timeout_s, 1.0))
        except DriverError:
            return None
        error = safety_error(self.s.name, status, client.system_fault)
        return error if isinstance(error, EmergencyStop | ProtectiveStop) else None

    async def _abort_quietly(self, client: RMIClient) -> None:
        try:
            await client.abort(timeout_s=min(self.s.timeout_s, 1.0))
        except DriverError as err:
            logger.warning("%s: FRC_Abort after a failed motion did not succeed: %s", self.s.name, err)


def safety_error(name: str, status: RMIStatus, system_fault: SystemFault | None) -> DriverError | None:
    """The error a motion must end with in this controller state (None: safe to move)."""
    if status.emergency_stop:
        return EmergencyStop(f"{name}: emergency stop is active; release it, then reset_faults() after acknowledgement")
    if status.protective_stop:
        return ProtectiveStop(
            f"{name}: protective stop is active; clear its cause, then reset_faults() after acknowledgement"
        )
    if system_fault is not None:
        return SystemFault(f"{system_fault} (latched: reset_faults() after acknowledgement)")
    if not status.servo_ready:
        return DeviceFault(
            f"{name}: servo power is off (ServoReady=0): an e-stop, fence or alarm is active; "
            "read the teach pendant, clear the cause, then reset_faults()"
        )
    return None


def paused_error(name: str, status: RMIStatus) -> DriverError | None:
    """During a motion: the RMI program paused (status 2) is a fault now. This driver never pauses it (a stop is an
    FRC_Abort), so the controller did: an alarm of STOP.G severity (the heartbeat program's ``UALM[1]``, a welder's
    fault input) holds the motion with servo power on and the instructions in flight unanswered; waiting for them
    would last until the motion's timeout."""
    if status.rmi_motion_status != 2 and status.program_status != 2:
        return None
    return DeviceFault(
        f"{name}: the controller paused the RMI program during a motion (RMIMotionStatus="
        f"{status.rmi_motion_status}, ProgramStatus={status.program_status}): an alarm stopped it; read the alarm on "
        "the teach pendant, clear its cause, then reset_faults() after acknowledgement"
    )


# ---------------------------------------------------------------------------------------------- the process
class _PipeLogHandler(logging.Handler):
    """Log records of this process go to the driver, which logs them under its own logger."""

    def __init__(self, send: Callable[[tuple[int, str, Any]], None]) -> None:
        super().__init__()
        self._send = send

    def emit(self, record: logging.LogRecord) -> None:
        with contextlib.suppress(Exception):
            self._send((0, "log", (record.levelno, record.getMessage())))


class _Server:
    """Runs requests of the driver as tasks on this process's loop and sends their replies."""

    def __init__(self, conn: Connection, settings: Settings) -> None:
        self.conn = conn
        self.session = _Session(settings)
        self.tasks: dict[int, asyncio.Task[Any]] = {}
        self.exited = asyncio.Event()
        self._send_lock = threading.Lock()

    def send(self, msg: tuple[int, str, Any]) -> None:
        # the driver gone (OSError/ValueError): the pipe reader ends the process
        with self._send_lock, contextlib.suppress(OSError, ValueError):
            self.conn.send(msg)

    def dispatch(self, msg: tuple[int, str, tuple[Any, ...]]) -> None:
        rid, op, args = msg
        if op == "exit":
            self.exited.set()
        elif op == "cancel":
            task = self.tasks.get(rid)
            if task is not None:
                task.cancel()
        else:
            self.tasks[rid] = asyncio.ensure_future(self._run(rid, op, args))

    async def _run(self, rid: int, op: str, args: tuple[Any, ...]) -> None:
        try:
            if op == "motion":
                targets, speed_mm_s, cnt_value, timeout_s = args
                await self.session.op_motion(
                    targets, speed_mm_s, cnt_value, timeout_s, lambda i: self.send((rid, "progress", i))
                )
                result = None
            else:
                result = await getattr(self.session, f"op_{op}")(*args)
        except asyncio.CancelledError:
            self.send((rid, "error", ("CancelledError", f"{op} cancelled", None)))
        except Exception as err:
            self.send((rid, "error", (type(err).__name__, str(err), getattr(err, "code", None))))
        else:
            self.send((rid, "ok", result))
        finally:
            self.tasks.pop(rid, None)

    async def serve(self) -> None:
        await self.exited.wait()
        for task in list(self.tasks.values()):
            task.cancel()
        with contextlib.suppress(Exception):
            await asyncio.wait_for(self.session.op_close(), timeout=2.0)


def main(fd: int) -> None:
    """``python -c "...main(fd)"``: the driver's end of the socket pair is ``fd``; the first message is the
    :class:`Settings`."""
    conn = Connection(fd)
    try:
        settings = conn.recv()
    except (EOFError, OSError):
        os._exit(0)
    worker_main(conn, settings)


def worker_main(conn: Connection, settings: Settings) -> None:
    """Entry point of the I/O process: serve the driver until it says exit or its pipe ends."""
    enter_io_process()  # it writes the heartbeat register: before any thread starts, they inherit its priority
    loop = asyncio.new_event_loop()
    asyncio.set_event_loop(loop)
    server = _Server(conn, settings)
    handler = _PipeLogHandler(server.send)
    logger.addHandler(handler)
    logger.setLevel(settings.log_level)
    logger.propagate = False
    for name in ("drivers.fanuc_rmi", "drivers.fanuc_worker"):
        logging.getLogger(name).addHandler(handler)
        logging.getLogger(name).setLevel(settings.log_level)
        logging.getLogger(name).propagate = False

    def read_pipe() -> None:
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                os._exit(0)  # the driver's process is gone: so is the heartbeat, and the controller acts
            loop.call_soon_threadsafe(server.dispatch, msg)
            if msg[1] == "exit":
                return

    threading.Thread(target=read_pipe, name="fanuc-worker-pipe", daemon=True).start()
    server.send((0, "ready", os.getpid()))
    loop.run_until_complete(server.serve())
    conn.close()
    os._exit(0)
