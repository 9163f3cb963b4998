"""Asyncio client for the FANUC Remote Motion Interface (option R912, manual B-84184EN).

Wire format: one JSON object per packet, terminated by ``"\\r\\n"``. The client opens TCP port 16001, sends
``{"Communication": "FRC_Connect"}`` and the reply's ``PortNumber`` names the session port every later packet
uses. Three kinds of packet travel on the session socket:

- *Communication* packets (``FRC_Disconnect``; from the controller, unsolicited, ``FRC_SystemFault`` and
  ``FRC_Terminate``);
- *Command* packets (``FRC_GetStatus``, ``FRC_Abort``...), answered at once and in order, matched here by name;
- *Instruction* packets (``FRC_LinearMotion``...), lines of the ``RMI_MOVE`` TP program, each with a consecutive
  ``SequenceID``, answered with that id when the line *completes*. At most 8 may be outstanding: a 9th is
  refused with RMIT-028; a gap in the ids is refused with RMIT-029 and puts RMI in HOLD.

Units are the controller's: millimetres, degrees, mm/s. Conversion to SI lives in :mod:`drivers.fanuc`.
Every await that depends on the controller has a timeout (:class:`DeviceTimeout` / :class:`MotionTimeout`);
a closed socket becomes :class:`ConnectionLost`; a non-zero ``ErrorID`` becomes ``RMIError(code=ErrorID)``;
an ``FRC_SystemFault`` packet becomes :class:`SystemFault` for every outstanding instruction and stays latched
until :meth:`RMIClient.reset` succeeds.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from drivers.errors import (
    ConnectionLost,
    DeviceTimeout,
    DriverError,
    MotionAborted,
    MotionTimeout,
    RMIError,
    SystemFault,
)
from drivers.fanuc_protocol import (
    DEFAULT_CONFIGURATION,
    MAX_INSTRUCTIONS_IN_FLIGHT,
    MAX_PACKET_BYTES,
    REJECTION_CODES,
    RMI_CONNECT_PORT,
    TERMINATOR,
    CartesianPosition,
    ErrorID,
    LinearMotion,
    Packet,
    RMIMotionRejected,
    RMIStatus,
    TermType,
    describe_error_id,
    instructions_for_path,
)

logger = logging.getLogger(__name__)

__all__ = [  # the wire format lives in drivers.fanuc_protocol; these names stay importable from here
    "DEFAULT_CONFIGURATION",
    "MAX_INSTRUCTIONS_IN_FLIGHT",
    "RMI_CONNECT_PORT",
    "TERMINATOR",
    "CartesianPosition",
    "ErrorID",
    "LinearMotion",
    "Packet",
    "RMIClient",
    "RMIMotionRejected",
    "RMIStatus",
    "TermType",
    "describe_error_id",
    "instructions_for_path",
]


def _consume_exception(fut: asyncio.Future[Any]) -> None:
    # Futures nobody awaits any more (abandoned after a timeout) must not log "exception never retrieved".
    if not fut.cancelled():
        fut.exception()


def _check_reply(name: str, reply: Mapping[str, Any]) -> None:
    code = int(reply.get("ErrorID", 0))
    if code == 0:
        return
    message = f"{name} refused by the controller: {describe_error_id(code)}"
    if code in REJECTION_CODES:
        raise RMIMotionRejected(message, code=code)
    raise RMIError(message, code=code)


class RMIClient:
    """One RMI session with a FANUC controller (or ``sim_fakes.fake_fanuc``), on the caller's event loop.

    ``timeout_s`` is the default for every request; each method accepts its own. Not thread-safe: use it from
    one event loop (``drivers.fanuc.FanucRobot`` runs it in a background thread).
    """

    def __init__(
        self,
        host: str,
        port: int = RMI_CONNECT_PORT,
        *,
        timeout_s: float = 2.0,
        max_in_flight: int = MAX_INSTRUCTIONS_IN_FLIGHT,
    ) -> None:
        if not 1 <= max_in_flight <= MAX_INSTRUCTIONS_IN_FLIGHT:
            raise ValueError(f"max_in_flight must be 1..{MAX_INSTRUCTIONS_IN_FLIGHT}, got {max_in_flight}")
        self.host = host
        self.port = port
        self.timeout_s = timeout_s
        self.max_in_flight = max_in_flight
        self.session_port: int | None = None
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._read_task: asyncio.Task[None] | None = None
        self._lost: ConnectionLost | None = ConnectionLost("RMI client is not connected; call connect() first")
        self._command_lock: asyncio.Lock | None = None
        self._window_changed: asyncio.Event | None = None
        # Replies to commands come back in order, so a FIFO per name matches them. A future whose caller timed
        # out stays in its queue (cancelled) so that the late reply is swallowed and not given to the next caller.
        self._pending_commands: dict[str, deque[asyncio.Future[Packet]]] = {}
        self._pending_instructions: dict[int, asyncio.Future[Packet]] = {}
        self._next_sequence_id = 1
        self._aborts = 0  # FRC_Abort requests so far: a stream that sees this change was aborted
        self._system_fault: SystemFault | None = None

    # ----------------------------------------------------------------------------------------- properties
    @property
    def connected(self) -> bool:
        return self._lost is None

    @property
    def in_flight(self) -> int:
        """Instructions sent and not yet answered."""
        return len(self._pending_instructions)

    @property
    def next_sequence_id(self) -> int:
        return self._next_sequence_id

    @property
    def system_fault(self) -> SystemFault | None:
        """The latched ``FRC_SystemFault`` (None when there is none); cleared by :meth:`reset`."""
        return self._system_fault

    # ----------------------------------------------------------------------------------------- connection
    async def connect(self, *, timeout_s: float | None = None) -> Packet:
        """Handshake on the connect port, then open the session socket. Returns the FRC_Connect reply.

        Raises ConnectionLost when the controller is unreachable, refuses, or does not answer in time.
        RMIT-026 (another session still open, e.g. the controller has not yet noticed our previous socket
        closing) is retried until the timeout.
        """
        if self.connected:
            raise DriverError("RMI client is already connected; disconnect() first")
        t = self.timeout_s if timeout_s is None else timeout_s
        where = f"{self.host}:{self.port}"
        try:
            async with asyncio.timeout(t):
                while True:
                    reply = await self._handshake()
                    code = int(reply.get("ErrorID", 0))
                    if code != ErrorID.ALREADY_CONNECTED:
                        break
                    await asyncio.sleep(0.05)
                _check_reply("FRC_Connect", reply)
                session_port = int(reply["PortNumber"])
                reader, writer = await asyncio.open_connection(self.host, session_port, limit=MAX_PACKET_BYTES)
        except TimeoutError as err:
            raise ConnectionLost(
                f"FANUC RMI at {where} did not complete the FRC_Connect handshake within {t} s; "
                "check the address and that RMI (R912) is enabled"
            ) from err
        except (OSError, asyncio.IncompleteReadError) as err:
            raise ConnectionLost(f"cannot reach FANUC RMI at {where} ({err}); check cabling, IP and port") from err
        except (KeyError, ValueError) as err:
            raise ConnectionLost(f"FRC_Connect reply from {where} is malformed ({err!r})") from err
        self.session_port = session_port
        self._reader, self._writer = reader, writer
        self._lost = None
        self._command_lock = asyncio.Lock()
        self._window_changed = asyncio.Event()
        self._pending_commands.clear()
        self._pending_instructions.clear()
        self._read_task = asyncio.get_running_loop().create_task(self._read_loop(), name="rmi-reader")
        logger.info("RMI session open with %s (session port %d)", where, session_port)
        return reply

    async def _handshake(self) -> Packet:
        reader, writer = await asyncio.open_connection(self.host, self.port, limit=MAX_PACKET_BYTES)
        try:
            writer.write(json.dumps({"Communication": "FRC_Connect"}).encode() + TERMINATOR)
            await writer.drain()
            line = await reader.readuntil(TERMINATOR)
        finally:
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()
        reply: Packet = json.loads(line)
        return reply

    async def disconnect(self, *, timeout_s: float | None = None) -> None:
        """Send FRC_Disconnect (best effort) and close the session. Safe to call twice."""
        t = self.timeout_s if timeout_s is None else timeout_s
        if self.connected:
            try:
                await self.communicate("FRC_Disconnect", timeout_s=t)
            except DriverError as err:
                logger.debug("FRC_Disconnect not acknowledged (%s); closing anyway", err)
        await self.close()

    async def close(self) -> None:
        """Close the socket without a goodbye and fail everything outstanding."""
        self._mark_lost(ConnectionLost("RMI session closed by the client"))
        task, self._read_task = self._read_task, None
        if task is not None and task is not asyncio.current_task():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await asyncio.wait_for(task, timeout=1.0)
        writer, self._writer = self._writer, None
        self._reader = None
        if writer is not None:
            writer.close()
            with contextlib.suppress(OSError, TimeoutError):
                await asyncio.wait_for(writer.wait_closed(), timeout=1.0)

    def _mark_lost(self, err: ConnectionLost) -> None:
        if self._lost is not None:
            return
        self._lost = err
        for queue in self._pending_commands.values():
            for fut in queue:
                if not fut.done():
                    fut.set_exception(ConnectionLost(str(err)))
        self._pending_commands.clear()
        for fut in self._pending_instructions.values():
            if not fut.done():
                fut.set_exception(ConnectionLost(str(err)))
        self._pending_instructions.clear()
        self._notify_window()
        if self._writer is not None:
            self._writer.close()

    def abandon(self, reason: str) -> None:
        """Give the session up (a controller that stopped answering): every waiter and later request gets
        ConnectionLost at once; connect again with a new client."""
        self._mark_lost(ConnectionLost(reason))

    def _raise_if_lost(self) -> None:
        if self._lost is not None:
            raise ConnectionLost(str(self._lost))

    # ----------------------------------------------------------------------------------------- reading
    async def _read_loop(self) -> None:
        # This is the one await without a timeout: it is a listener. A hung controller shows up as a request
        # timeout, a closed socket as EOF here.
        assert self._reader is not None
        reader = self._reader
        try:
            while True:
                line = await reader.readuntil(TERMINATOR)
                try:
                    msg = json.loads(line)
                except json.JSONDecodeError:
                    logger.warning("RMI: ignoring a packet that is not JSON: %r", line[:200])
                    continue
                if isinstance(msg, dict):
                    self._dispatch(msg)
                else:
                    logger.warning("RMI: ignoring a packet that is not a JSON object: %r", line[:200])
        except asyncio.IncompleteReadError:
            self._mark_lost(ConnectionLost(f"FANUC controller at {self.host} closed the RMI session"))
        except asyncio.LimitOverrunError:
            self._mark_lost(ConnectionLost(f"FANUC controller at {self.host} sent an unterminated packet"))
        except OSError as err:
            self._mark_lost(ConnectionLost(f"RMI session with {self.host} failed: {err}"))

    def _dispatch(self, msg: Packet) -> None:
        if "Instruction" in msg:
            seq = int(msg.get("SequenceID", -1))
            fut = self._pending_instructions.pop(seq, None)
            if fut is None:
                logger.debug("RMI: reply for SequenceID %d that nobody waits for: %s", seq, msg)
            elif not fut.done():
                fut.set_result(msg)
            self._notify_window()
        elif "Command" in msg:
            self._resolve_named(str(msg["Command"]), msg)
        elif "Communication" in msg:
            name = str(msg["Communication"])
            if name == "FRC_SystemFault":
                self._on_system_fault(msg)
            elif name == "FRC_Terminate":
                self._mark_lost(ConnectionLost(f"FANUC controller at {self.host} terminated the RMI session"))
            else:
                self._resolve_named(name, msg)
        else:
            logger.warning("RMI: ignoring a packet of unknown kind: %s", msg)

    def _resolve_named(self, name: str, msg: Packet) -> None:
        queue = self._pending_commands.get(name)
        if not queue:
            logger.debug("RMI: unsolicited reply %s", msg)
            return
        fut = queue.popleft()
        if not fut.done():
            fut.set_result(msg)

    def _on_system_fault(self, msg: Packet) -> None:
        seq = int(msg.get("SequenceID", 0))
        fault = SystemFault(
            f"FANUC controller at {self.host} reported FRC_SystemFault at SequenceID {seq}; "
            "read the alarm on the teach pendant, fix its cause, then reset"
        )
        logger.error("%s", fault)
        self._system_fault = fault
        for fut in self._pending_instructions.values():
            if not fut.done():
                fut.set_exception(SystemFault(str(fault)))
        self._pending_instructions.clear()
        self._notify_window()

    def _notify_window(self) -> None:
        if self._window_changed is not None:
            self._window_changed.set()

    # ----------------------------------------------------------------------------------------- sending
    async def _send(self, msg: Packet, *, timeout_s: float) -> None:
        self._raise_if_lost()
        assert self._writer is not None
        logger.debug("RMI -> %s", msg)
        try:
            self._writer.write(json.dumps(msg).encode() + TERMINATOR)
            await asyncio.wait_for(self._writer.drain(), timeout_s)
        except TimeoutError as err:
            self._mark_lost(ConnectionLost(f"RMI send to {self.host} blocked for {timeout_s} s"))
            raise DeviceTimeout(f"FANUC controller at {self.host} is not reading (send blocked {timeout_s} s)") from err
        except OSError as err:
            self._mark_lost(ConnectionLost(f"RMI send to {self.host} failed: {err}"))
            raise ConnectionLost(f"RMI send to {self.host} failed: {err}") from err

    async def _request(self, kind: str, name: str, fields: Mapping[str, Any] | None, timeout_s: float) -> Packet:
        self._raise_if_lost()
        assert self._command_lock is not None
        msg: Packet = {kind: name, **(fields or {})}
        loop = asyncio.get_running_loop()
        try:
            async with asyncio.timeout(timeout_s):
                # One command at a time: the controller answers RMIT-027 to a command sent while one is busy.
                async with self._command_lock:
                    self._raise_if_lost()
                    fut: asyncio.Future[Packet] = loop.create_future()
                    fut.add_done_callback(_consume_exception)
                    self._pending_commands.setdefault(name, deque()).append(fut)
                    await self._send(msg, timeout_s=timeout_s)
                    reply = await fut
        except TimeoutError as err:
            raise DeviceTimeout(
                f"FANUC controller at {self.host} did not answer {name} within {timeout_s} s; "
                "is it powered, and is RMI running?"
            ) from err
        logger.debug("RMI <- %s", reply)
        return reply

    async def command(
        self, name: str, fields: Mapping[str, Any] | None = None, *, timeout_s: float | None = None, check: bool = True
    ) -> Packet:
        """Send ``{"Command": name, **fields}`` and return the reply; ``check`` raises RMIError on ErrorID != 0."""
        reply = await self._request("Command", name, fields, self.timeout_s if timeout_s is None else timeout_s)
        if check:
            _check_reply(name, reply)
        return reply

    async def communicate(self, name: str, *, timeout_s: float | None = None) -> Packet:
        """Send ``{"Communication": name}`` on the session socket and return the reply."""
        reply = await self._request("Communication", name, None, self.timeout_s if timeout_s is None else timeout_s)
        _check_reply(name, reply)
        return reply

    # ----------------------------------------------------------------------------------------- commands
    async def get_status(self, *, timeout_s: float | None = None) -> RMIStatus:
        return RMIStatus.from_reply(await self.command("FRC_GetStatus", timeout_s=timeout_s))

    async def initialize(self, *, group_mask: int = 1, timeout_s: float | None = None) -> Packet:
        """Start ``RMI_MOVE``; sequence ids restart at 1 (a fresh TP program)."""
        reply = await self.command("FRC_Initialize", {"GroupMask": group_mask}, timeout_s=timeout_s)
        self._next_sequence_id = 1
        return reply

    async def abort(self, *, timeout_s: float | None = None, ignore_not_running: bool = True) -> None:
        """Stop ``RMI_MOVE`` now and discard its queued instructions (they fail with MotionAborted)."""
        self._aborts += 1
        reply = await self.command("FRC_Abort", timeout_s=timeout_s, check=False)
        self._fail_instructions(MotionAborted("motion aborted (FRC_Abort): the remaining instructions were dropped"))
        code = int(reply.get("ErrorID", 0))
        if code != 0 and not (ignore_not_running and code == ErrorID.NOT_RUNNING):
            _check_reply("FRC_Abort", reply)

    def _fail_instructions(self, err: DriverError) -> None:
        for fut in self._pending_instructions.values():
            if not fut.done():
                fut.set_exception(type(err)(str(err)))
        self._pending_instructions.clear()
        self._notify_window()

    async def reset(self, *, timeout_s: float | None = None) -> None:
        """FRC_Reset: clear controller alarms and HOLD; on success the latched system fault is cleared too."""
        await self.command("FRC_Reset", timeout_s=timeout_s)
        self._system_fault = None

    async def read_cartesian_position(self, *, group: int = 1, timeout_s: float | None = None) -> CartesianPosition:
        reply = await self.command("FRC_ReadCartesianPosition", {"Group": group}, timeout_s=timeout_s)
        return CartesianPosition.from_reply(reply)

    async def read_tcp_speed_mm_s(self, *, timeout_s: float | None = None) -> float:
        reply = await self.command("FRC_ReadTCPSpeed", timeout_s=timeout_s)
        return float(reply.get("Speed", 0.0))

    async def set_uframe_utool(
        self, *, uframe: int, utool: int, group: int = 1, timeout_s: float | None = None
    ) -> None:
        fields = {"UFrameNumber": uframe, "UToolNumber": utool, "Group": group}
        await self.command("FRC_SetUFrameUTool", fields, timeout_s=timeout_s)

    async def write_dout(self, port_number: int, value: bool, *, timeout_s: float | None = None) -> None:
        """FRC_WriteDOUT: set ``DO[port_number]`` (1-based, as on the teach pendant)."""
        fields = {"PortNumber": int(port_number), "PortValue": "ON" if value else "OFF"}
        await self.command("FRC_WriteDOUT", fields, timeout_s=timeout_s)

    async def write_numeric_register(self, number: int, value: int, *, timeout_s: float | None = None) -> None:
        """FRC_WriteNumericRegister: ``R[number] = value``."""
        fields = {"RegisterNumber": int(number), "RegisterValue": int(value)}
        await self.command("FRC_WriteNumericRegister", fields, timeout_s=timeout_s)

    async def read_dout(self, port_number: int, *, timeout_s: float | None = None) -> bool:
        """FRC_ReadIOPort with PortType "DO": the state of ``DO[port_number]``."""
        reply = await self.command(
            "FRC_ReadIOPort", {"PortType": "DO", "PortNumber": int(port_number)}, timeout_s=timeout_s
        )
        return bool(int(reply.get("PortValue", 0)))

    # ----------------------------------------------------------------------------------------- instructions
    async def submit(
        self,
        instruction: LinearMotion | Mapping[str, Any],
        *,
        sequence_id: int | None = None,
        respect_window: bool = True,
        timeout_s: float | None = None,
    ) -> tuple[int, asyncio.Future[Packet]]:
        """Send one TP instruction; return its SequenceID and a future of the controller's reply.

        ``respect_window`` waits (up to ``timeout_s``) until fewer than ``max_in_flight`` are outstanding; pass
        False only to exercise the controller's own RMIT-028 check. ``sequence_id`` overrides the counter (to
        exercise RMIT-029); by default the next consecutive id is used. A mapping is sent as given with the
        SequenceID filled in.
        """
        self._raise_if_lost()
        if self._system_fault is not None:
            raise SystemFault(f"{self._system_fault} (still latched: reset before sending motion)")
        t = self.timeout_s if timeout_s is None else timeout_s
        if respect_window:
            await self.wait_for_window(timeout_s=t)
        seq = self._next_sequence_id if sequence_id is None else int(sequence_id)
        if isinstance(instruction, LinearMotion):
            msg = instruction.packet(seq)
        else:
            msg = {**instruction, "SequenceID": seq}
        if seq in self._pending_instructions:
            raise DriverError(f"SequenceID {seq} is already outstanding; refusing to send it twice")
        fut: asyncio.Future[Packet] = asyncio.get_running_loop().create_future()
        fut.add_done_callback(_consume_exception)
        self._pending_instructions[seq] = fut
        try:
            await self._send(msg, timeout_s=t)
        except DriverError:
            self._pending_instructions.pop(seq, None)
            raise
        if sequence_id is None:
            self._next_sequence_id = seq + 1
        return seq, fut

    async def wait_for_window(self, *, timeout_s: float | None = None) -> None:
        """Block until fewer than ``max_in_flight`` instructions are outstanding."""
        t = self.timeout_s if timeout_s is None else timeout_s
        changed = self._window_changed
        assert changed is not None
        try:
            async with asyncio.timeout(t):
                while self._lost is None and self.in_flight >= self.max_in_flight:
                    changed.clear()
                    await changed.wait()
        except TimeoutError as err:
            raise MotionTimeout(
                f"no instruction of {self.in_flight} in flight completed within {t} s; is the robot moving?"
            ) from err
        self._raise_if_lost()

    @staticmethod
    async def wait_instruction(seq: int, fut: asyncio.Future[Packet], *, timeout_s: float) -> Packet:
        """Wait for the reply to instruction ``seq``; RMIError on a non-zero ErrorID, MotionTimeout on time."""
        try:
            reply = await asyncio.wait_for(asyncio.shield(fut), timeout_s)
        except TimeoutError as err:
            raise MotionTimeout(f"instruction {seq} did not complete within {timeout_s} s") from err
        _check_reply(f"instruction {seq} ({reply.get('Instruction')})", reply)
        return reply

    async def run_instructions(
        self,
        instructions: Sequence[LinearMotion],
        *,
        timeout_s: float,
        on_complete: Callable[[int], None] | None = None,
    ) -> None:
        """Stream ``instructions`` keeping at most ``max_in_flight`` outstanding, sending the next one as each
        completes, and return when the last is answered.

        ``on_complete(i)`` is called, in order, as instruction ``i`` (index into ``instructions``) completes.
        Raises RMIError for the first non-zero ErrorID, SystemFault, ConnectionLost, MotionAborted, or
        MotionTimeout when the whole sequence takes longer than ``timeout_s``.
        """
        deadline = time.monotonic() + timeout_s
        outstanding: deque[tuple[int, int, asyncio.Future[Packet]]] = deque()  # (index, seq, future)
        next_index = 0
        aborts = self._aborts
        try:
            while next_index < len(instructions) or outstanding:
                while next_index < len(instructions) and self.in_flight < self.max_in_flight:
                    if self._aborts != aborts:  # never send on after an abort
                        raise MotionAborted("motion aborted (FRC_Abort) while streaming: the rest was not sent")
                    seq, fut = await self.submit(instructions[next_index], timeout_s=self._remaining(deadline))
                    outstanding.append((next_index, seq, fut))
                    next_index += 1
                remaining = self._remaining(deadline)
                done, _ = await asyncio.wait(
                    [f for _, _, f in outstanding], timeout=remaining, return_when=asyncio.FIRST_COMPLETED
                )
                if not done:
                    raise MotionTimeout(
                        f"{len(instructions)} instructions did not complete within {timeout_s} s "
                        f"({next_index - len(outstanding)} done)"
                    )
                # Replies come in order; an error reply (RMIT-028/029...) may overtake, so check all done ones.
                for index, seq, fut in list(outstanding):
                    if not fut.done():
                        continue
                    reply = fut.result()  # raises SystemFault / ConnectionLost / MotionAborted
                    if self._aborts != aborts and int(reply.get("ErrorID", 0)) == ErrorID.NOT_RUNNING:
                        # an instruction that crossed the abort on the wire: the abort's doing, not a refusal
                        raise MotionAborted(f"motion aborted (FRC_Abort): instruction {seq} arrived after it")
                    _check_reply(f"instruction {seq} (path index {index})", reply)
                while outstanding and outstanding[0][2].done():
                    index, _, _ = outstanding.popleft()
                    if on_complete is not None:
                        on_complete(index)
        finally:
            for _, _, fut in outstanding:
                if not fut.done():
                    fut.cancel()

    @staticmethod
    def _remaining(deadline: float) -> float:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise MotionTimeout("motion deadline passed before the next instruction could be sent")
        return remaining
