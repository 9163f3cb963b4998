"""A fake FANUC controller that speaks RMI (R912) JSON on loopback, with fault injection.

It enforces the rules a real controller enforces, so the real client (``drivers.fanuc_rmi``) is tested against
them: the FRC_Connect handshake hands out a session port; at most 8 TP instructions in flight (a 9th gets
RMIT-028); SequenceIDs must be consecutive (a gap gets RMIT-029 and puts RMI in HOLD until FRC_Reset or
FRC_Abort); a CNT instruction is not answered until the next instruction has arrived (the controller cannot
blend into nothing); errors travel as ``ErrorID`` codes. Motion is integrated at the commanded speed on a fixed
tick, so positions change over time; a safety stop halts it where it is.

Status fields: ``FRC_GetStatus`` carries the real fields (ServoReady, TPMode, RMIMotionStatus, ProgramStatus,
NextSequenceID...) plus two that a real controller does not send: ``"EmergencyStop"`` and ``"ProtectiveStop"``
(0/1, latched until FRC_Reset succeeds after the cause is cleared).

Units are the controller's: mm, degrees (W, P, R fixed-axis x-y-z, as in ``perception.transforms``), mm/s.
Digital outputs are ``DO[1..N_DOUT]``, read back with ``FRC_ReadIOPort`` ``PortType "DO"``.

Host heartbeat (what a real controller does with the watchdog program of docs/controller-watchdogs.md, when
``heartbeat`` is given): the program ``WC_HBEAT`` runs as a background task and watches the numeric register
``R[register]`` that the host rewrites (``FRC_WriteNumericRegister``) with a changing count. Once the host has
written a non-zero value, a register that has not changed for ``timeout_s`` switches the arc output(s) ``DO[..]``
OFF, raises the user alarm ``UALM[1]`` (severity STOP.G: motion stops where it is, the RMI program pauses, until
FRC_Reset) and writes 0 to the register (disarmed until the host writes again). ``events()`` records each trip
with the fake's clock.

Usage::

    with FakeFanucController() as fake:        # binds 127.0.0.1 on a free port
        robot = FanucRobot("127.0.0.1", port=fake.port)
        fake.inject("protective_stop")
        fake.records()                          # every instruction received, in order
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import ipaddress
import json
import logging
import time
from collections import deque
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.fanuc_protocol import (
    DEFAULT_CONFIGURATION,
    MAX_INSTRUCTIONS_IN_FLIGHT,
    POSITION_KEYS,
    TERMINATOR,
    ErrorID,
    Packet,
)
from sim_fakes.fanuc_program import HeartbeatProgram, InstructionRecord, Segment, instruction_record, parse_packet
from sim_fakes.loop_thread import LoopThreadFake

logger = logging.getLogger(__name__)

__all__ = ["DEFAULT_START_XYZWPR_MM_DEG", "FakeFanucController", "HeartbeatProgram", "InstructionRecord"]

T = TypeVar("T")

N_DOUT = 64
N_UFRAME = 9
N_UTOOL = 10
N_REGISTERS = 200
DEFAULT_START_XYZWPR_MM_DEG = (500.0, 0.0, 400.0, 180.0, 0.0, 0.0)
"""Tool pointing down (tool z along base -z) 0.5 m in front of the base, 0.4 m up: reachable, no faults."""


class _Session:
    def __init__(self, writer: asyncio.StreamWriter) -> None:
        self.writer = writer
        self.closing = False


class FakeFanucController(LoopThreadFake):
    """The fake controller and its control handle (implements ``sim_fakes.faults.FaultInjectable``).

    ``host`` must be a loopback address; ``port`` 0 picks a free port (read it back from :attr:`port`).
    Runs its own event loop in a background thread between :meth:`start` and :meth:`stop`.
    """

    supported_faults: frozenset[str] = frozenset(
        {"drop_connection", "no_answer", "protective_stop", "emergency_stop", "rmi_error", "system_fault", "alarm"}
    )

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        start_xyzwpr_mm_deg: tuple[float, ...] = DEFAULT_START_XYZWPR_MM_DEG,
        tick_s: float = 0.004,
        max_speed_mm_s: float = 2000.0,
        max_rotation_speed_deg_s: float = 180.0,
        reach_mm: float = 1800.0,
        heartbeat: HeartbeatProgram | None = None,
    ) -> None:
        if host != "localhost" and not ipaddress.ip_address(host).is_loopback:
            raise ValueError(f"the fake FANUC controller binds loopback only, got host={host!r}")
        if len(start_xyzwpr_mm_deg) != 6:
            raise ValueError(f"start_xyzwpr_mm_deg needs 6 values, got {start_xyzwpr_mm_deg}")
        self.host = host
        self._requested_port = port
        super().__init__()
        self._tick_s = tick_s
        self._max_speed_mm_s = max_speed_mm_s
        self._max_rotation_speed_deg_s = max_rotation_speed_deg_s
        self._reach_mm = reach_mm
        if heartbeat is not None and not (
            1 <= heartbeat.register <= N_REGISTERS and all(1 <= p <= N_DOUT for p in heartbeat.arc_ports)
        ):
            raise ValueError(f"heartbeat program: R[1..{N_REGISTERS}] and DO[1..{N_DOUT}] only, got {heartbeat}")
        self._heartbeat = heartbeat
        self._registers: dict[int, float] = {}
        self._hb_seen: float = 0.0
        self._hb_seen_at = 0.0
        self._cycle_s = 0.0  # the controller's running time: the sum of its motion ticks' steps, each at most 50 ms
        self._alarm: str | None = None  # a user alarm (UALM) latched until FRC_Reset
        self._events: list[dict[str, Any]] = []

        # Controller state, touched only on the fake's event loop.
        self._p_mm = np.asarray(start_xyzwpr_mm_deg[:3], dtype=np.float64)
        self._R = Rotation.from_euler("xyz", start_xyzwpr_mm_deg[3:], degrees=True)
        self._tcp_speed_mm_s = 0.0
        self._running = False  # RMI_MOVE initialized
        self._paused = False
        self._hold = False
        self._next_seq = 1
        self._last_completed_seq = 0
        self._queue: deque[Segment] = deque()
        self._uframe = 0
        self._utool = 1
        self._dout = [False] * (N_DOUT + 1)  # index 0 unused: ports are 1-based
        self._estop_input = False
        self._estop_latched = False
        self._pstop_input = False
        self._pstop_latched = False
        self._dropped = False
        self._no_answer = False
        self._next_error: int | None = None
        self._session: _Session | None = None
        self._writers: set[asyncio.StreamWriter] = set()
        self._records: list[InstructionRecord] = []
        self._max_in_flight = 0
        self._t0 = time.monotonic()

        self._server: asyncio.Server | None = None
        self._session_servers: set[asyncio.Server] = set()
        self._motion_task: asyncio.Task[None] | None = None

    # ================================================================================== lifecycle
    fake_name = "fake FANUC controller"

    def start(self) -> FakeFanucController:
        super().start()
        logger.info("fake FANUC RMI listening on %s:%d", self.host, self.port)
        return self

    async def _setup(self, ready: concurrent.futures.Future[int]) -> None:
        self._server = await asyncio.start_server(self._on_connect_client, self.host, self._requested_port)
        self._motion_task = asyncio.get_running_loop().create_task(self._motion_loop(), name="fake-fanuc-motion")
        ready.set_result(int(self._server.sockets[0].getsockname()[1]))

    async def _close_servers(self) -> None:
        for server in [self._server, *self._session_servers]:
            if server is not None:
                server.close()
        self._session_servers.clear()
        for writer in list(self._writers):
            writer.close()

    # ================================================================================== control handle
    def inject(self, fault: str, **params: Any) -> None:
        """Switch ``fault`` on (see ``sim_fakes.faults``); ``"rmi_error"`` needs ``code=<ErrorID>``.

        ``"alarm"`` (optional ``text=``): a STOP.G alarm from controller-side logic other than RMI (a welder's fault
        input, the heartbeat program): motion stops where it is and the RMI program pauses (RMIMotionStatus 2) with
        servo power on, its instructions unanswered; FRC_Continue is refused until FRC_Reset clears the alarm."""
        if fault not in self.supported_faults:
            raise ValueError(f"fake FANUC does not support fault {fault!r}; supported: {sorted(self.supported_faults)}")
        if fault == "rmi_error" and ("code" not in params or int(params["code"]) == 0):
            raise ValueError("fault 'rmi_error' needs a non-zero code=<ErrorID>, e.g. code=2556964")
        allowed = {"rmi_error": {"code"}, "alarm": {"text"}}.get(fault, set())
        unknown = set(params) - allowed
        if unknown:
            raise ValueError(f"fault {fault!r} takes no parameters {sorted(unknown)}")
        self._call(lambda: self._apply_fault(fault, params))

    def clear_faults(self) -> None:
        """Switch every fault off. Safety stops stay latched until the driver sends FRC_Reset."""

        def clear() -> None:
            self._dropped = False
            self._no_answer = False
            self._next_error = None
            self._estop_input = False
            self._pstop_input = False

        self._call(clear)

    def records(self) -> list[InstructionRecord]:
        """Every instruction received so far, in arrival order (accepted and refused)."""
        return self._call(lambda: list(self._records))

    def accepted_records(self) -> list[InstructionRecord]:
        """The instructions accepted into the buffer (``error_id == 0``), in arrival order."""
        return [r for r in self.records() if r.error_id == 0]

    def max_in_flight(self) -> int:
        """The largest number of instructions ever outstanding at once."""
        return self._call(lambda: self._max_in_flight)

    def xyzwpr_mm_deg(self) -> tuple[float, ...]:
        """The current tool pose in controller units."""
        return self._call(self._xyzwpr)

    def digital_output(self, port_number: int) -> bool:
        return self._call(lambda: self._dout[port_number])

    def in_flight(self) -> int:
        return self._call(lambda: len(self._queue))

    def events(self) -> list[dict[str, Any]]:
        """Controller-side happenings with the fake's clock ``t`` (s): ``heartbeat_lost`` trips, ``heartbeat_armed`` and
        ``heartbeat_disarmed`` (the host wrote the register non-zero after 0, or 0 after a count), digital output
        writes (``dout``: the host's with the tool position ``xyz_mm`` at that instant, the watchdog's with its
        ``cause``), faults injected."""
        return self._call(lambda: list(self._events))

    def now_s(self) -> float:
        """The fake's clock (seconds since it was created), the clock of :meth:`events`."""
        return time.monotonic() - self._t0

    def register(self, number: int) -> float:
        return self._call(lambda: self._registers.get(number, 0.0))

    def _event(self, kind: str, **data: Any) -> None:
        self._events.append({"kind": kind, "t": round(time.monotonic() - self._t0, 4), **data})

    # ================================================================================== faults
    def _apply_fault(self, fault: str, params: dict[str, Any]) -> None:
        logger.info("fake FANUC: inject %s %s", fault, params)
        self._event("fault", fault=fault)
        if fault == "drop_connection":
            self._dropped = True
            self._session = None
            for writer in list(self._writers):
                writer.close()
            self._abort_program()
        elif fault == "no_answer":
            self._no_answer = True
        elif fault == "protective_stop":
            self._pstop_input = self._pstop_latched = True
            self._halt()
        elif fault == "emergency_stop":
            self._estop_input = self._estop_latched = True
            self._halt()
        elif fault == "rmi_error":
            self._next_error = int(params["code"])
        elif fault == "alarm":
            self._alarm = str(params.get("text", "UALM[2] alarm raised by controller-side logic"))
            self._halt()
        elif fault == "system_fault":
            seq = self._queue[0].seq if self._queue else self._last_completed_seq
            self._halt()
            self._send({"Communication": "FRC_SystemFault", "SequenceID": seq})

    def _halt(self) -> None:
        # Motion stops where it is and the TP program pauses with its queue intact (FRC_Abort discards it).
        self._tcp_speed_mm_s = 0.0
        if self._running:
            self._paused = True

    def _abort_program(self) -> None:
        self._running = False
        self._paused = False
        self._hold = False
        self._queue.clear()
        self._tcp_speed_mm_s = 0.0

    @property
    def _servo_ready(self) -> bool:
        return not (self._estop_latched or self._pstop_latched)

    # ================================================================================== sockets
    def _send(self, msg: Packet) -> None:
        session = self._session
        if session is None or self._no_answer or session.writer.is_closing():
            return
        logger.debug("fake FANUC -> %s", msg)
        session.writer.write(json.dumps(msg).encode() + TERMINATOR)

    async def _on_connect_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """The well-known port: FRC_Connect only."""
        self._writers.add(writer)
        try:
            if self._dropped:
                return
            while True:
                line = await reader.readuntil(TERMINATOR)
                if self._no_answer:
                    continue
                msg = parse_packet(line)
                if msg is None or msg.get("Communication") != "FRC_Connect":
                    name = "Unknown" if msg is None else str(msg.get("Communication", msg.get("Command", "Unknown")))
                    reply: Packet = {"Communication": name, "ErrorID": int(ErrorID.INVALID_COMMAND)}
                elif self._session is not None:
                    reply = {"Communication": "FRC_Connect", "ErrorID": int(ErrorID.ALREADY_CONNECTED)}
                else:
                    port = await self._open_session_listener()
                    reply = {
                        "Communication": "FRC_Connect",
                        "ErrorID": 0,
                        "PortNumber": port,
                        "MajorVersion": 1,
                        "MinorVersion": 0,
                    }
                writer.write(json.dumps(reply).encode() + TERMINATOR)
                await writer.drain()
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError):
            pass
        finally:
            self._writers.discard(writer)
            writer.close()

    async def _open_session_listener(self) -> int:
        server: asyncio.Server | None = None

        async def on_session(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            assert server is not None
            server.close()  # one session per handshake
            self._session_servers.discard(server)
            if self._session is not None or self._dropped:
                writer.close()
                return
            await self._serve_session(reader, writer)

        server = await asyncio.start_server(on_session, self.host, 0)
        self._session_servers.add(server)

        def expire(srv: asyncio.Server = server) -> None:  # nobody connected in time
            srv.close()
            self._session_servers.discard(srv)

        asyncio.get_running_loop().call_later(5.0, expire)
        return int(server.sockets[0].getsockname()[1])

    async def _serve_session(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        session = _Session(writer)
        self._session = session
        self._writers.add(writer)
        try:
            while not session.closing:
                line = await reader.readuntil(TERMINATOR)
                if self._no_answer:
                    continue
                msg = parse_packet(line)
                if msg is None:
                    logger.warning("fake FANUC: ignoring a packet that is not a JSON object: %r", line[:200])
                    continue
                logger.debug("fake FANUC <- %s", msg)
                self._handle(session, msg)
                await writer.drain()
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError):
            pass
        finally:
            self._writers.discard(writer)
            if self._session is session:
                # A real controller aborts RMI_MOVE when its client goes away.
                self._session = None
                self._abort_program()
            writer.close()

    # ================================================================================== packets
    def _handle(self, session: _Session, msg: Packet) -> None:
        if "Communication" in msg:
            name = str(msg["Communication"])
            if name == "FRC_Disconnect":
                self._send({"Communication": name, "ErrorID": 0})
                session.closing = True
            else:
                self._send({"Communication": name, "ErrorID": int(ErrorID.INVALID_COMMAND)})
        elif "Command" in msg:
            name = str(msg["Command"])
            handler = self._commands().get(name)
            if handler is None:
                reply: Packet = {"ErrorID": int(ErrorID.INVALID_COMMAND)}
            else:
                reply = handler(msg)
            self._send({"Command": name, "ErrorID": 0, **reply})
        elif "Instruction" in msg:
            self._on_instruction(msg)
        else:
            self._send({"Command": "Unknown", "ErrorID": int(ErrorID.INVALID_COMMAND)})

    def _commands(self) -> dict[str, Callable[[Packet], Packet]]:
        return {
            "FRC_Initialize": self._cmd_initialize,
            "FRC_Abort": self._cmd_abort,
            "FRC_Pause": self._cmd_pause,
            "FRC_Continue": self._cmd_continue,
            "FRC_Reset": self._cmd_reset,
            "FRC_GetStatus": self._cmd_get_status,
            "FRC_ReadCartesianPosition": self._cmd_read_cartesian,
            "FRC_ReadTCPSpeed": self._cmd_read_tcp_speed,
            "FRC_SetUFrameUTool": self._cmd_set_uframe_utool,
            "FRC_GetUFrameUTool": lambda msg: {"UFrameNumber": self._uframe, "UToolNumber": self._utool, "Group": 1},
            "FRC_WriteDOUT": self._cmd_write_dout,
            "FRC_ReadIOPort": self._cmd_read_io_port,
            "FRC_ReadDIN": lambda msg: {"PortNumber": msg.get("PortNumber", 0), "PortValue": 0},
            "FRC_WriteNumericRegister": self._cmd_write_numeric_register,
            "FRC_ReadNumericRegister": self._cmd_read_numeric_register,
        }

    def _cmd_initialize(self, msg: Packet) -> Packet:
        if self._running or self._alarm is not None:
            return {"ErrorID": int(ErrorID.INVALID_CONTROLLER_STATE)}
        if not self._servo_ready:
            return {"ErrorID": int(ErrorID.SERVO_OFF)}
        if int(msg.get("GroupMask", 1)) != 1:
            return {"ErrorID": int(ErrorID.INVALID_GROUP_MASK)}
        self._abort_program()
        self._running = True
        self._next_seq = 1
        return {"GroupMask": 1}

    def _cmd_abort(self, msg: Packet) -> Packet:
        if not self._running:
            return {"ErrorID": int(ErrorID.NOT_RUNNING)}
        self._abort_program()
        return {}

    def _cmd_pause(self, msg: Packet) -> Packet:
        if not self._running:
            return {"ErrorID": int(ErrorID.NOT_RUNNING)}
        self._halt()
        return {}

    def _cmd_continue(self, msg: Packet) -> Packet:
        if not self._running:
            return {"ErrorID": int(ErrorID.NOT_RUNNING)}
        if not self._servo_ready or self._alarm is not None:
            return {"ErrorID": int(ErrorID.CANNOT_RESUME)}
        self._paused = False
        return {}

    def _cmd_reset(self, msg: Packet) -> Packet:
        if self._estop_input or self._pstop_input:
            return {"ErrorID": int(ErrorID.CANNOT_RESET)}  # the cause is still there
        self._estop_latched = self._pstop_latched = False
        self._hold = False
        self._alarm = None
        return {}

    def _cmd_write_numeric_register(self, msg: Packet) -> Packet:
        number, value = msg.get("RegisterNumber"), msg.get("RegisterValue")
        if not isinstance(number, int) or not 1 <= number <= N_REGISTERS:
            return {"ErrorID": int(ErrorID.INVALID_VALUE)}
        if isinstance(value, bool) or not isinstance(value, int | float):
            return {"ErrorID": int(ErrorID.INVALID_VALUE)}
        hb = self._heartbeat
        if hb is not None and number == hb.register and (self._registers.get(number, 0.0) == 0.0) != (value == 0):
            # the watchdog program's arming changes: a trace an integrator can read off the register's history
            self._event("heartbeat_disarmed" if value == 0 else "heartbeat_armed", register=number)
        self._registers[number] = float(value)
        return {}

    def _cmd_read_numeric_register(self, msg: Packet) -> Packet:
        number = msg.get("RegisterNumber")
        if not isinstance(number, int) or not 1 <= number <= N_REGISTERS:
            return {"ErrorID": int(ErrorID.INVALID_VALUE)}
        value = self._registers.get(number, 0.0)
        return {"RegisterNumber": number, "RegisterValue": int(value) if value.is_integer() else value}

    def _watch_heartbeat(self) -> None:
        """One scan of ``WC_HBEAT`` (docs/controller-watchdogs.md), timed by the controller's running time: a real
        controller takes each register write as it comes, while this fake's process, not scheduled for a while on
        a loaded host, reads the host's writes of that while from its socket only after this scan; wall time would
        count its own stall as the host's silence and stop a healthy weld (as the fake UR's RTDE watchdog did)."""
        hb = self._heartbeat
        if hb is None:
            return
        now = self._cycle_s
        value = self._registers.get(hb.register, 0.0)
        if value != self._hb_seen:
            self._hb_seen, self._hb_seen_at = value, now
            return
        if value == 0.0 or now - self._hb_seen_at <= hb.timeout_s:
            return
        silent_s = now - self._hb_seen_at
        for port in hb.arc_ports:
            if self._dout[port]:
                self._dout[port] = False
                self._event("dout", port=port, value=False, cause="heartbeat lost")
        self._event("heartbeat_lost", register=hb.register, silent_s=round(silent_s, 4))
        self._alarm = f"UALM[1] host heartbeat R[{hb.register}] lost for {silent_s:.3f} s"
        self._halt()
        self._registers[hb.register] = 0.0
        self._hb_seen, self._hb_seen_at = 0.0, now

    def _cmd_get_status(self, msg: Packet) -> Packet:
        rmi_status = (2 if self._paused else 1) if self._running else 0
        return {
            "ServoReady": int(self._servo_ready),
            "TPMode": 0,
            "RMIMotionStatus": rmi_status,
            "ProgramStatus": rmi_status,
            "SingleStepMode": 0,
            "NumberUTool": N_UTOOL,
            "NextSequenceID": self._next_seq,
            "NumberUFrame": N_UFRAME,
            "Override": 100,
            # weldcell extensions (not sent by a real controller)
            "EmergencyStop": int(self._estop_latched),
            "ProtectiveStop": int(self._pstop_latched),
        }

    def _cmd_read_cartesian(self, msg: Packet) -> Packet:
        position = dict(zip(POSITION_KEYS, self._xyzwpr(), strict=True))
        position.update({"Ext1": 0.0, "Ext2": 0.0, "Ext3": 0.0})
        return {
            "TimeTag": self._time_tag(),
            "Configuration": self._configuration(),
            "Position": position,
            "Group": int(msg.get("Group", 1)),
        }

    def _cmd_read_tcp_speed(self, msg: Packet) -> Packet:
        return {"TimeTag": self._time_tag(), "Speed": round(self._tcp_speed_mm_s, 3)}

    def _cmd_set_uframe_utool(self, msg: Packet) -> Packet:
        try:
            uframe, utool = int(msg["UFrameNumber"]), int(msg["UToolNumber"])
        except (KeyError, TypeError, ValueError):
            return {"ErrorID": int(ErrorID.INVALID_VALUE)}
        if not 0 <= uframe <= N_UFRAME:
            return {"ErrorID": int(ErrorID.INVALID_UFRAME_NUMBER)}
        if not 1 <= utool <= N_UTOOL:
            return {"ErrorID": int(ErrorID.INVALID_UTOOL_NUMBER)}
        if self._queue:
            return {"ErrorID": int(ErrorID.INVALID_CONTROLLER_STATE)}  # never while moving
        self._uframe, self._utool = uframe, utool
        return {"Group": int(msg.get("Group", 1))}

    def _cmd_write_dout(self, msg: Packet) -> Packet:
        port = msg.get("PortNumber")
        if not isinstance(port, int) or not 1 <= port <= N_DOUT:
            return {"ErrorID": int(ErrorID.INVALID_PORT_NUMBER)}
        value = msg.get("PortValue")
        if value not in ("ON", "OFF"):
            return {"ErrorID": int(ErrorID.INVALID_VALUE)}
        self._dout[port] = value == "ON"
        self._event("dout", port=port, value=value == "ON", xyz_mm=[float(v) for v in self._p_mm])
        return {}

    def _cmd_read_io_port(self, msg: Packet) -> Packet:
        port = msg.get("PortNumber")
        port_type = msg.get("PortType")
        if port_type != "DO":
            return {"ErrorID": int(ErrorID.INVALID_VALUE)}  # the fake only models digital outputs
        if not isinstance(port, int) or not 1 <= port <= N_DOUT:
            return {"ErrorID": int(ErrorID.INVALID_PORT_NUMBER)}
        return {"PortType": "DO", "PortNumber": port, "PortValue": int(self._dout[port])}

    # ================================================================================== instructions
    def _on_instruction(self, msg: Packet) -> None:
        name = str(msg["Instruction"])
        try:
            seq = int(msg.get("SequenceID", -1))
        except (TypeError, ValueError):
            seq = -1
        error, segment = self._admit(name, seq, msg)
        if error == 0:
            assert segment is not None
            self._queue.append(segment)
            self._next_seq = seq + 1
            self._max_in_flight = max(self._max_in_flight, len(self._queue))
        self._records.append(instruction_record(name, seq, msg, error, len(self._queue), time.monotonic() - self._t0))
        if error != 0:
            self._send({"Instruction": name, "ErrorID": error, "SequenceID": seq})

    def _admit(self, name: str, seq: int, msg: Packet) -> tuple[int, Segment | None]:
        """The ErrorID the instruction is refused with (0 = accepted), in the order a controller checks."""
        if not self._running:
            return int(ErrorID.NOT_RUNNING), None
        if self._hold:
            return int(ErrorID.HOLD), None
        if len(self._queue) >= MAX_INSTRUCTIONS_IN_FLIGHT:
            return int(ErrorID.WAIT_FOR_INSTRUCTION_DONE), None
        if seq != self._next_seq:
            self._hold = True
            return int(ErrorID.INVALID_SEQUENCE_ID), None
        # From here on the id is consumed: the next instruction must carry seq + 1.
        if self._next_error is not None:
            code, self._next_error = self._next_error, None
            self._next_seq = seq + 1
            return code, None
        error, segment = self._parse_motion(name, seq, msg)
        if error == 0 and not self._servo_ready:
            error = int(ErrorID.SERVO_OFF)
        if error != 0:
            self._next_seq = seq + 1
        return error, segment

    def _parse_motion(self, name: str, seq: int, msg: Packet) -> tuple[int, Segment | None]:
        if name != "FRC_LinearMotion":
            return int(ErrorID.INVALID_INSTRUCTION), None
        try:
            pos = msg["Position"]
            xyzwpr = np.array([float(pos[k]) for k in POSITION_KEYS])
        except (KeyError, TypeError, ValueError):
            return int(ErrorID.INVALID_POSITION_DATA), None
        if not np.all(np.isfinite(xyzwpr)):
            return int(ErrorID.INVALID_POSITION_DATA), None
        if msg.get("SpeedType") != "mmSec":
            return int(ErrorID.INVALID_SPEED_TYPE), None
        speed = msg.get("Speed")
        if not isinstance(speed, int | float) or not 0 < speed <= self._max_speed_mm_s:
            return int(ErrorID.INVALID_SPEED_VALUE), None
        term_type = msg.get("TermType")
        if term_type not in ("FINE", "CNT"):
            return int(ErrorID.INVALID_TERM_TYPE), None
        term_value = msg.get("TermValue")
        if not isinstance(term_value, int) or not 0 <= term_value <= 100:
            return int(ErrorID.INVALID_TERM_VALUE), None
        if np.linalg.norm(xyzwpr[:3]) > self._reach_mm:
            return int(ErrorID.INVALID_DESTINATION), None
        segment = Segment(
            seq=seq,
            instruction=name,
            p_target_mm=xyzwpr[:3],
            R_target=Rotation.from_euler("xyz", xyzwpr[3:], degrees=True),
            speed_mm_s=float(speed),
            term_type=str(term_type),
        )
        return 0, segment

    # ================================================================================== motion
    async def _motion_loop(self) -> None:
        last = time.monotonic()
        while True:
            await asyncio.sleep(self._tick_s)
            now = time.monotonic()
            self._advance(now - last)
            last = now

    def _advance(self, dt: float) -> None:
        self._cycle_s += min(dt, 0.05)
        self._watch_heartbeat()
        p_before = self._p_mm.copy()
        if self._running and not self._paused and self._servo_ready:
            budget = dt
            while self._queue:
                seg = self._queue[0]
                if seg.p_start_mm is None:
                    seg.begin(self._p_mm, self._R, max_rotation_speed_deg_s=self._max_rotation_speed_deg_s)
                left = seg.duration_s - seg.elapsed_s
                if left > budget:
                    seg.elapsed_s += budget
                    self._p_mm, self._R = seg.pose_at(seg.elapsed_s / seg.duration_s)
                    break
                budget -= left
                seg.elapsed_s = seg.duration_s
                self._p_mm, self._R = seg.p_target_mm.copy(), seg.R_target
                if seg.term_type == "CNT" and len(self._queue) == 1:
                    break  # CNT cannot finish before the controller knows where to blend to
                self._queue.popleft()
                self._last_completed_seq = seg.seq
                self._send({"Instruction": seg.instruction, "ErrorID": 0, "SequenceID": seg.seq})
        self._tcp_speed_mm_s = float(np.linalg.norm(self._p_mm - p_before)) / dt if dt > 0 else 0.0

    # ================================================================================== helpers
    def _xyzwpr(self) -> tuple[float, ...]:
        wpr = self._R.as_euler("xyz", degrees=True)
        return tuple(float(v) for v in (*self._p_mm, *wpr))

    def _configuration(self) -> dict[str, int]:
        # the simulated arm stands in the wire format's default configuration, with its active frames
        return {**DEFAULT_CONFIGURATION, "UToolNumber": self._utool, "UFrameNumber": self._uframe}

    def _time_tag(self) -> int:
        return int((time.monotonic() - self._t0) * 1000.0)
