"""A FANUC arm through the Remote Motion Interface: ``drivers.protocols.Robot`` over ``drivers.fanuc_rmi``.

Threading: the asyncio :class:`~drivers.fanuc_rmi.RMIClient` lives on an event loop in one background thread
(``fanuc-rmi-<name>``) between :meth:`FanucRobot.connect` and :meth:`FanucRobot.disconnect`; every public
method submits a coroutine to it and blocks, with a timeout, for the result. Methods may be called from
several threads (``stop()`` from a watchdog while ``move_linear`` blocks in another). ``on_progress`` callbacks
run in the thread that called ``stream_path``.

Units: SI at this API (metres, m/s, ``X_base_tool`` 4x4); millimetres and degrees exist only on the wire and
are converted here, once, with :func:`perception.transforms.xyzwpr_mm_deg_from_X` and its inverse.
The base frame is the controller's user frame ``uframe`` (0 = world) and the tool frame is ``utool``.

Safety: a protective or emergency stop is read from ``FRC_GetStatus`` (polled every ``status_poll_s`` during
motion) and raised as :class:`ProtectiveStop` / :class:`EmergencyStop`; both stay latched until the cause is
cleared and :meth:`FanucRobot.reset_faults` (FRC_Reset) is called, which the cell does only after an
operator's acknowledgement. An unsolicited ``FRC_SystemFault`` raises :class:`SystemFault` and latches the
same way.

Host heartbeat (``heartbeat_register``, docs/controller-watchdogs.md): while connected, a task on the I/O thread
writes ``R[heartbeat_register]`` every ``heartbeat_period_s``: a changing count (1..30000) while a digital output
this driver switched on is on or a motion is in flight, 0 (the watchdog disarmed) when there is nothing to make
safe (a host busy with detection holds the GIL for seconds; that must not trip the controller). The integrator's
``WC_HBEAT`` program on the controller switches the arc output off and stops the motion (user alarm, STOP.G)
when that register stands still for its timeout: a dropped link, a hung or killed host.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import queue
import threading
import time
from collections.abc import Callable, Coroutine, Sequence
from typing import Any, TypeVar

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
    RMIError,
    SystemFault,
)
from drivers.fanuc_rmi import (
    RMI_CONNECT_PORT,
    RMIClient,
    RMIStatus,
    instructions_for_path,
)
from drivers.protocols import FloatArray, RobotMode, RobotState
from perception.transforms import TransformError, X_from_xyzwpr_mm_deg, check_X, xyzwpr_mm_deg_from_X

logger = logging.getLogger(__name__)

T = TypeVar("T")

CNT100_BLEND_M = 0.010
"""The blend radius mapped to CNT100. FANUC's CNT value is a corner-rounding percentage, not a distance; the
mapping ``CNT = 100 * blend_m / CNT100_BLEND_M`` (clamped to 1..100) is weldcell's convention."""

MOTION_STATUS_TIMEOUT_S = 0.4
"""A status request during a motion must be answered within this long (see FanucRobot._motion_status)."""

MOVING_SPEED_MM_S = 0.5
"""TCP speeds above this (``FRC_ReadTCPSpeed``) count as moving."""


class _LoopThread:
    """An asyncio event loop in a daemon thread; :meth:`run` submits a coroutine and blocks with a timeout."""

    def __init__(self, name: str) -> None:
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._main, name=name, daemon=True)
        self._thread.start()

    def _main(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_forever()
        finally:
            self.loop.close()

    def submit(self, coro: Coroutine[Any, Any, T]) -> concurrent.futures.Future[T]:
        return asyncio.run_coroutine_threadsafe(coro, self.loop)

    def run(self, coro: Coroutine[Any, Any, T], *, timeout_s: float, what: str) -> T:
        fut = self.submit(coro)
        try:
            return fut.result(timeout=timeout_s)
        except TimeoutError as err:
            if fut.done():
                raise  # the coroutine's own TimeoutError, not ours
            fut.cancel()
            raise DeviceTimeout(f"{what}: no result within {timeout_s:.1f} s") from err

    def stop(self) -> None:
        async def cancel_all() -> None:
            current = asyncio.current_task()
            tasks = [t for t in asyncio.all_tasks() if t is not current]
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

        if self._thread.is_alive():
            with contextlib.suppress(TimeoutError, RuntimeError):
                self.submit(cancel_all()).result(timeout=2.0)
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(timeout=5.0)


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
        self.name = name
        self.host = host
        self.port = port
        self.uframe = uframe
        self.utool = utool
        self.group_mask = group_mask
        self.timeout_s = timeout_s
        self.status_poll_s = status_poll_s
        self.n_digital_outputs = n_digital_outputs
        if heartbeat_register is not None and heartbeat_register < 1:
            raise ValueError(f"heartbeat_register is R[n] with n >= 1, got {heartbeat_register}")
        self.heartbeat_register = heartbeat_register
        self.heartbeat_period_s = heartbeat_period_s
        self._heartbeat: concurrent.futures.Future[None] | None = None
        self._outputs_on: set[int] = set()  # outputs this driver switched on (and not off since)
        self._motions = 0  # motions in flight
        self._io: _LoopThread | None = None
        self._client: RMIClient | None = None
        self._lifecycle_lock = threading.Lock()

    # ============================================================================== connection
    def connect(self) -> None:
        """Open (or re-open) the RMI session. Raises ConnectionLost when the controller is unreachable."""
        with self._lifecycle_lock:
            if self._io is None:
                self._io = _LoopThread(f"fanuc-rmi-{self.name}")
            io = self._io
            old, self._client = self._client, None
            if old is not None:  # a dead or stale session: close it without a goodbye
                with contextlib.suppress(DriverError):
                    io.run(old.close(), timeout_s=3.0, what=f"{self.name}: close old RMI session")
            client = RMIClient(self.host, self.port, timeout_s=self.timeout_s)
            try:
                io.run(client.connect(), timeout_s=self.timeout_s + 2.0, what=f"{self.name}: connect")
            except BaseException:
                io.stop()
                self._io = None
                raise
            self._client = client
            if self._heartbeat is not None:
                self._heartbeat.cancel()
                self._heartbeat = None
            if self.heartbeat_register is not None:
                self._heartbeat = io.submit(self._beat(client, self.heartbeat_register))
            logger.info("%s: connected to FANUC RMI at %s:%d", self.name, self.host, self.port)

    async def _beat(self, client: RMIClient, register: int) -> None:
        """R[register] = 1, 2, ... 30000, 1, ... every heartbeat_period_s while the session lives."""
        count = 0
        while client.connected:
            # armed (counting) while an output is on or a motion is in flight; 0 (disarmed) otherwise, so that a
            # host busy with detection for a while does not trip the controller with nothing to make safe
            if self._outputs_on or self._motions:
                count = count % 30000 + 1
                value = count
            else:
                value = 0
            try:
                await client.write_numeric_register(register, value, timeout_s=self.timeout_s)
            except DriverError as err:  # the controller's watchdog acts on the silence; say so once per failure
                logger.warning("%s: heartbeat R[%d] not written: %s", self.name, register, err)
            await asyncio.sleep(self.heartbeat_period_s)

    def disconnect(self) -> None:
        """Say FRC_Disconnect (the controller aborts RMI_MOVE), close, stop the I/O thread. Safe twice."""
        with self._lifecycle_lock:
            client, self._client = self._client, None
            io, self._io = self._io, None
            if self._heartbeat is not None:
                self._heartbeat.cancel()
                self._heartbeat = None
            if io is None:
                return
            if client is not None:
                with contextlib.suppress(DriverError):
                    io.run(client.disconnect(timeout_s=1.0), timeout_s=4.0, what=f"{self.name}: disconnect")
            io.stop()
            logger.info("%s: disconnected", self.name)

    def _session(self) -> tuple[_LoopThread, RMIClient]:
        io, client = self._io, self._client
        if io is None or client is None:
            raise ConnectionLost(f"{self.name}: not connected to the FANUC controller; call connect() first")
        return io, client

    def _run(self, coro_fn: Callable[[RMIClient], Coroutine[Any, Any, T]], *, n_requests: int, what: str) -> T:
        io, client = self._session()
        return io.run(coro_fn(client), timeout_s=n_requests * self.timeout_s + 1.0, what=f"{self.name}: {what}")

    # ============================================================================== state
    def state(self) -> RobotState:
        return self._run(self._read_state, n_requests=3 + self.n_digital_outputs, what="state")

    async def _read_state(self, client: RMIClient) -> RobotState:
        status = await client.get_status()
        position = await client.read_cartesian_position()
        speed_mm_s = await client.read_tcp_speed_mm_s()
        outputs = tuple([await client.read_dout(i + 1) for i in range(self.n_digital_outputs)])
        moving = speed_mm_s > MOVING_SPEED_MM_S
        if status.emergency_stop:
            mode = RobotMode.EMERGENCY_STOP
        elif status.protective_stop:
            mode = RobotMode.PROTECTIVE_STOP
        elif client.system_fault is not None or not status.servo_ready:
            mode = RobotMode.FAULT
        else:
            mode = RobotMode.MOVING if moving else RobotMode.IDLE
        message = (
            f"servo_ready={int(status.servo_ready)} tp_mode={status.tp_mode} "
            f"rmi_motion_status={status.rmi_motion_status} next_sequence_id={status.next_sequence_id} "
            f"tcp_speed_mm_s={speed_mm_s:.1f}"
        )
        if client.system_fault is not None:
            message += f"; {client.system_fault}"
        return RobotState(
            mode=mode,
            X_base_tool=X_from_xyzwpr_mm_deg(position.xyzwpr_mm_deg),
            is_moving=moving,
            protective_stop=status.protective_stop,
            emergency_stop=status.emergency_stop,
            digital_outputs=outputs,
            message=message,
        )

    def get_X_base_tool(self) -> FloatArray:
        position = self._run(lambda c: c.read_cartesian_position(), n_requests=1, what="read position")
        return X_from_xyzwpr_mm_deg(position.xyzwpr_mm_deg)

    # ============================================================================== I/O and stops
    def set_digital_output(self, index: int, value: bool) -> None:
        if index < 0:
            raise ValueError(f"digital output index must be >= 0 (DO[index + 1]), got {index}")
        logger.debug("%s: DO[%d] <- %s", self.name, index + 1, value)
        if value:
            self._outputs_on.add(index)  # armed before the output goes on
        self._run(lambda c: c.write_dout(index + 1, bool(value)), n_requests=1, what=f"write DO[{index + 1}]")
        if not value:
            self._outputs_on.discard(index)

    def stop(self) -> None:
        """FRC_Abort: stop now and drop the queued instructions (a blocked move raises MotionAborted)."""
        self._run(lambda c: c.abort(ignore_not_running=True), n_requests=1, what="abort")

    def reset_faults(self) -> None:
        """FRC_Reset: clear controller alarms, HOLD and the latched system fault; safety stops clear only once
        their cause is gone (RMIError RMIT-012 otherwise). Call after an operator acknowledged the fault."""
        self._run(lambda c: c.reset(), n_requests=1, what="reset")

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
        io, client = self._session()
        progress: queue.SimpleQueue[int] = queue.SimpleQueue()
        logger.debug(
            "%s: %d linear target(s) at %d mm/s, CNT %d, timeout %.1f s",
            self.name,
            len(targets),
            speed_mm_s,
            cnt_value,
            timeout_s,
        )
        holder: list[asyncio.Task[Any]] = []

        async def motion() -> None:
            task = asyncio.current_task()
            assert task is not None
            holder.append(task)
            self._motions += 1  # the heartbeat is armed while a motion is in flight
            try:
                await self._motion(
                    client,
                    targets,
                    speed_mm_s=speed_mm_s,
                    cnt_value=cnt_value,
                    timeout_s=timeout_s,
                    on_complete=progress.put,
                )
            finally:
                self._motions -= 1

        def cancel_motion() -> None:  # on the loop; the motion coroutine aborts the program on its way out
            if holder:
                holder[0].cancel()
            else:
                fut.cancel()  # not started yet: nothing has moved

        fut = io.submit(motion())
        # Grace for the preparation requests and a best-effort abort on the way out.
        deadline = time.monotonic() + timeout_s + 6.0 * self.timeout_s + 1.0
        try:
            while not fut.done():
                if time.monotonic() > deadline:
                    raise MotionTimeout(f"{self.name}: motion did not finish within {timeout_s} s")
                with contextlib.suppress(queue.Empty):
                    index = progress.get(timeout=0.02)
                    if on_progress is not None:
                        on_progress(index)
            while not progress.empty():
                index = progress.get_nowait()
                if on_progress is not None:
                    on_progress(index)
        except BaseException:
            io.loop.call_soon_threadsafe(cancel_motion)
            with contextlib.suppress(BaseException):
                fut.result(timeout=2.0 * self.timeout_s + 1.0)  # let the abort go out before returning
            raise
        fut.result()

    async def _motion(
        self,
        client: RMIClient,
        targets: list[tuple[float, ...]],
        *,
        speed_mm_s: int,
        cnt_value: int,
        timeout_s: float,
        on_complete: Callable[[int], None],
    ) -> None:
        status = await client.get_status()
        self._raise_if_unsafe(client, status)
        await self._prepare_program(client, status)
        configuration = dict((await client.read_cartesian_position()).configuration)
        configuration.update({"UFrameNumber": self.uframe, "UToolNumber": self.utool})
        instructions = instructions_for_path(
            targets, speed_mm_s=speed_mm_s, cnt_value=cnt_value, configuration=configuration
        )
        stream = asyncio.ensure_future(
            client.run_instructions(instructions, timeout_s=timeout_s, on_complete=on_complete)
        )
        try:
            while True:
                done, _ = await asyncio.wait({stream}, timeout=self.status_poll_s)
                if done:
                    stream.result()
                    return
                self._raise_if_unsafe(client, await self._motion_status(client))
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
        timeout_s = min(self.timeout_s, MOTION_STATUS_TIMEOUT_S)
        try:
            return await client.get_status(timeout_s=timeout_s)
        except DeviceTimeout as err:
            reason = f"{self.name}: no answer to FRC_GetStatus within {timeout_s:.1f} s during a motion"
            client.abandon(reason)
            raise ConnectionLost(f"{reason}; connect again once it answers") from err

    async def _prepare_program(self, client: RMIClient, status: RMIStatus) -> None:
        """Make sure RMI_MOVE runs, empty, with our sequence counter; (re)initialize it otherwise."""
        if status.rmi_running and client.in_flight == 0 and status.next_sequence_id == client.next_sequence_id:
            return
        if status.rmi_motion_status != 0:
            await client.abort()
        await client.initialize(group_mask=self.group_mask)
        await client.set_uframe_utool(uframe=self.uframe, utool=self.utool)
        logger.debug("%s: RMI_MOVE initialized (UFrame %d, UTool %d)", self.name, self.uframe, self.utool)

    def _raise_if_unsafe(self, client: RMIClient, status: RMIStatus) -> None:
        error = self._safety_error(client, status)
        if error is not None:
            raise error

    def _safety_error(self, client: RMIClient, status: RMIStatus) -> DriverError | None:
        if status.emergency_stop:
            return EmergencyStop(
                f"{self.name}: emergency stop is active; release it, then reset_faults() after acknowledgement"
            )
        if status.protective_stop:
            return ProtectiveStop(
                f"{self.name}: protective stop is active; clear its cause, then reset_faults() after acknowledgement"
            )
        if client.system_fault is not None:
            return SystemFault(f"{client.system_fault} (latched: reset_faults() after acknowledgement)")
        if not status.servo_ready:
            return DeviceFault(
                f"{self.name}: servo power is off (ServoReady=0): an e-stop, fence or alarm is active; "
                "read the teach pendant, clear the cause, then reset_faults()"
            )
        return None

    async def _safety_error_quietly(self, client: RMIClient) -> DriverError | None:
        try:
            status = await client.get_status(timeout_s=min(self.timeout_s, 1.0))
        except DriverError:
            return None
        error = self._safety_error(client, status)
        return error if isinstance(error, EmergencyStop | ProtectiveStop) else None

    async def _abort_quietly(self, client: RMIClient) -> None:
        try:
            await client.abort(timeout_s=min(self.timeout_s, 1.0))
        except DriverError as err:
            logger.warning("%s: FRC_Abort after a failed motion did not succeed: %s", self.name, err)
