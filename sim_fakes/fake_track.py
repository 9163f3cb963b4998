"""A fake ground-track drive: a real pymodbus Modbus TCP server on loopback simulating one linear axis.

It serves the register map of :mod:`drivers.track` (docs/track-modbus.md) with pymodbus's own server
(``ModbusTcpServer`` over a ``SimDevice`` whose ``action`` hook sees every request), so the real client code
is tested against a real Modbus stack. The axis has speed and acceleration limits (a trapezoidal profile,
integrated on every access in steps of ``tick_s``), soft limits (a target outside them is refused with
exception 3, ILLEGAL DATA VALUE, and nothing moves), an in-position window, a fault bit with a fault code,
and an enable. Device units throughout (counts, counts/s, counts/s²); the constructor takes SI values and
converts them once, with ``counts_per_m``, as a drive's commissioning tool would.

Faults (:class:`sim_fakes.faults.FaultInjectable`):

- ``"drop_connection"``: close every client connection now; new connections are accepted and closed at once
  until cleared.
- ``"no_answer"``: connections stay open but requests are swallowed (a hung drive).
- ``"modbus_exception"`` (``code``: 1-11): every request is answered with that exception code until cleared.
- ``"track_fault"`` (``code``: 1-65535): the drive faults now: the axis halts, is disabled, FAULT is set and
  FAULT_CODE = code. The fault stays latched after :meth:`FakeTrack.clear_faults` until a client writes
  FAULT_RESET, as on a real drive.

Usage::

    with FakeTrack(soft_limits_m=(0.0, 2.0)) as fake:      # binds 127.0.0.1 on a free port
        track = ModbusTrack("127.0.0.1", port=fake.port, counts_per_m=fake.counts_per_m)
        fake.inject("track_fault", code=0x2310)
"""

from __future__ import annotations

import concurrent.futures
import ipaddress
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from drivers.track_registers import (
    COIL_ENABLE,
    COIL_FAULT_RESET,
    COIL_STOP,
    EXC_ILLEGAL_DATA_VALUE,
    EXC_SERVER_DEVICE_BUSY,
    EXCEPTION_NAMES,
    HR_PROFILE_ACCEL,
    HR_PROFILE_SPEED,
    HR_TARGET_POSITION,
    IR_ACTUAL_POSITION,
    IR_ACTUAL_SPEED,
    IR_COUNTS_PER_METRE,
    IR_FAULT_CODE,
    IR_IN_POSITION_WINDOW,
    IR_MAX_ACCEL,
    IR_MAX_SPEED,
    IR_SOFT_LIMIT_MAX,
    IR_SOFT_LIMIT_MIN,
    IR_STATUS_WORD,
    N_COILS,
    N_DISCRETE_INPUTS,
    N_HOLDING_REGISTERS,
    N_INPUT_REGISTERS,
    STATUS_ENABLED,
    STATUS_FAULT,
    STATUS_IN_POSITION,
    STATUS_MOVING,
    int32_from_registers,
    registers_from_int32,
    registers_from_uint32,
    uint32_from_registers,
)
from sim_fakes.loop_thread import LoopThreadFake

logger = logging.getLogger(__name__)

T = TypeVar("T")

FC_READ_COILS = 1
FC_READ_DISCRETE_INPUTS = 2
FC_READ_HOLDING = 3
FC_READ_INPUT = 4
FC_WRITE_COIL = 5
FC_WRITE_REGISTER = 6
FC_WRITE_COILS = 15
FC_WRITE_REGISTERS = 16


@dataclass(frozen=True)
class MoveRecord:
    """A move the fake accepted, in device units, with the time it arrived (monotonic seconds)."""

    target_counts: int
    speed_counts_s: int
    accel_counts_s2: int
    start_counts: float
    received_s: float


class FakeTrack(LoopThreadFake):
    """The fake drive and its control handle (implements ``sim_fakes.faults.FaultInjectable``).

    ``host`` must be a loopback address; ``port`` 0 picks a free port (read it back from :attr:`port`).
    ``unit_id``: the only unit id answered (others get exception 4). Limits are given in SI and stored in
    counts. Runs its own event loop in a background thread (``fake-track``) between :meth:`start` and
    :meth:`stop`.
    """

    supported_faults: frozenset[str] = frozenset({"drop_connection", "no_answer", "modbus_exception", "track_fault"})

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        unit_id: int = 1,
        counts_per_m: int = 100_000,
        soft_limits_m: tuple[float, float] = (0.0, 3.0),
        max_speed_m_s: float = 0.5,
        max_accel_m_s2: float = 1.0,
        in_position_window_m: float = 0.0002,
        start_position_m: float = 0.0,
        enabled: bool = False,
        tick_s: float = 0.002,
    ) -> None:
        if host != "localhost" and not ipaddress.ip_address(host).is_loopback:
            raise ValueError(f"the fake track binds loopback only, got host={host!r}")
        if not (isinstance(counts_per_m, int) and 0 < counts_per_m <= 0xFFFFFFFF):
            raise ValueError(f"counts_per_m must be a positive integer, got {counts_per_m!r}")
        if not soft_limits_m[0] < soft_limits_m[1]:
            raise ValueError(f"soft_limits_m must be (min, max) with min < max, got {soft_limits_m}")
        if not soft_limits_m[0] <= start_position_m <= soft_limits_m[1]:
            raise ValueError(f"start_position_m={start_position_m} lies outside the soft limits {soft_limits_m}")
        if not (max_speed_m_s > 0 and max_accel_m_s2 > 0 and in_position_window_m >= 0 and tick_s > 0):
            raise ValueError("max_speed_m_s, max_accel_m_s2 and tick_s must be > 0, in_position_window_m >= 0")
        self.host = host
        self._requested_port = port
        super().__init__()
        self.unit_id = unit_id
        self.counts_per_m = counts_per_m
        # SI -> counts, once (the fake is the device side of the boundary).
        self.soft_limit_min_counts = round(soft_limits_m[0] * counts_per_m)
        self.soft_limit_max_counts = round(soft_limits_m[1] * counts_per_m)
        self.max_speed_counts_s = round(max_speed_m_s * counts_per_m)
        self.max_accel_counts_s2 = round(max_accel_m_s2 * counts_per_m)
        self.in_position_window_counts = round(in_position_window_m * counts_per_m)
        for value in (self.soft_limit_min_counts, self.soft_limit_max_counts):
            registers_from_int32(value)  # raises ValueError when a limit does not fit its register pair
        self._tick_s = tick_s

        # Axis state, touched only on the fake's event loop; floats in counts.
        self._position_counts = float(round(start_position_m * counts_per_m))
        self._velocity_counts_s = 0.0
        self._goal_counts = self._position_counts
        self._moving = False
        self._enabled = enabled
        self._fault_code = 0
        self._profile_speed_counts_s = min(self.max_speed_counts_s, max(1, round(0.1 * counts_per_m)))
        self._profile_accel_counts_s2 = min(self.max_accel_counts_s2, max(1, round(0.5 * counts_per_m)))
        self._move_speed_counts_s = float(self._profile_speed_counts_s)
        self._move_accel_counts_s2 = float(self._profile_accel_counts_s2)
        self._t_last = time.monotonic()
        self._dropped = False
        self._no_answer = False
        self._exception_code: int | None = None
        self._moves: list[MoveRecord] = []
        self._refused: list[tuple[int, int]] = []  # (function code, exception code)

        self._server: Any = None

    # ================================================================================== lifecycle
    fake_name = "fake track"

    def start(self) -> FakeTrack:
        super().start()
        logger.info("fake track Modbus TCP listening on %s:%d (unit %d)", self.host, self.port, self.unit_id)
        return self

    async def _setup(self, ready: concurrent.futures.Future[int]) -> None:
        from pymodbus.simulator import DataType, SimData, SimDevice

        device = SimDevice(
            id=self.unit_id,
            simdata=(
                [SimData(0, values=[False] * N_COILS, datatype=DataType.BITS)],
                [SimData(0, values=[False] * N_DISCRETE_INPUTS, datatype=DataType.BITS)],
                [SimData(0, values=self._holding_registers(), datatype=DataType.REGISTERS)],
                [SimData(0, values=[0] * N_INPUT_REGISTERS, datatype=DataType.REGISTERS)],
            ),
            action=self._action,
        )
        server = _make_server(self, device, (self.host, self._requested_port))
        if not await server.listen():
            raise OSError(
                f"fake track cannot listen on {self.host}:{self._requested_port} (address in use or not available)"
            )
        self._server = server
        ready.set_result(int(server.transport.sockets[0].getsockname()[1]))

    def stop(self) -> None:
        super().stop()
        self._server = None

    async def _close_servers(self) -> None:
        server = self._server
        if server is not None:
            for conn in list(server.active_connections.values()):
                conn.close()
            server.close()

    # ================================================================================== control handle
    def inject(self, fault: str, **params: Any) -> None:
        """Switch ``fault`` on; ``"modbus_exception"`` and ``"track_fault"`` need ``code=``."""
        if fault not in self.supported_faults:
            raise ValueError(f"fake track does not support fault {fault!r}; supported: {sorted(self.supported_faults)}")
        allowed = {"code"} if fault in ("modbus_exception", "track_fault") else set()
        unknown = set(params) - allowed
        if unknown:
            raise ValueError(f"fault {fault!r} takes no parameters {sorted(unknown)}")
        if allowed and "code" not in params:
            raise ValueError(f"fault {fault!r} needs code=")
        if fault == "modbus_exception" and int(params["code"]) not in EXCEPTION_NAMES:
            raise ValueError(
                f"code={params['code']} is not a Modbus exception code; use one of {sorted(EXCEPTION_NAMES)}"
            )
        if fault == "track_fault" and not 1 <= int(params["code"]) <= 0xFFFF:
            raise ValueError(f"a drive fault code is 1..65535 (0 means no fault), got {params['code']}")
        self._call(lambda: self._apply_fault(fault, params))

    def clear_faults(self) -> None:
        """Lift the network faults and the exception fault; a drive fault stays latched until FAULT_RESET."""

        def clear() -> None:
            self._dropped = False
            self._no_answer = False
            self._exception_code = None

        self._call(clear)

    def position_m(self) -> float:
        """The true axis position (not through Modbus)."""
        return self._call(lambda: self._advance_and(lambda: self._position_counts)) / self.counts_per_m

    def snapshot(self) -> dict[str, Any]:
        """The axis state in device units: position, velocity, goal, enabled, moving, fault code."""

        def snap() -> dict[str, Any]:
            self._advance()
            return {
                "position_counts": self._position_counts,
                "velocity_counts_s": self._velocity_counts_s,
                "goal_counts": self._goal_counts,
                "enabled": self._enabled,
                "moving": self._moving,
                "fault_code": self._fault_code,
                "profile_speed_counts_s": self._profile_speed_counts_s,
                "profile_accel_counts_s2": self._profile_accel_counts_s2,
            }

        return self._call(snap)

    def moves(self) -> list[MoveRecord]:
        """Every move the fake accepted, in order."""
        return self._call(lambda: list(self._moves))

    def refused(self) -> list[tuple[int, int]]:
        """Every request refused with an exception response, as (function code, exception code)."""
        return self._call(lambda: list(self._refused))

    # ================================================================================== axis model
    def _advance_and(self, fn: Callable[[], T]) -> T:
        self._advance()
        return fn()

    def _advance(self) -> None:
        now = time.monotonic()
        dt_total = now - self._t_last
        self._t_last = now
        while self._moving and dt_total > 0:
            dt = min(self._tick_s, dt_total)
            dt_total -= dt
            self._step(dt)
        if not self._moving:
            self._velocity_counts_s = 0.0

    def _step(self, dt: float) -> None:
        """One step of a trapezoidal profile towards the goal (decelerating in time to stop on it)."""
        a = self._move_accel_counts_s2
        d = self._goal_counts - self._position_counts
        if d == 0.0 and abs(self._velocity_counts_s) <= a * dt:
            self._finish()
            return
        direction = 1.0 if d > 0 else -1.0
        # The highest speed after this step from which braking at ``a`` still stops on the goal, counting the
        # distance covered during the step itself (v_new² / 2a + v_new dt / 2 = d - v dt / 2); with it the
        # discrete profile takes the analytic trapezoid's time to within one tick.
        v_along = self._velocity_counts_s * direction
        slack = max(abs(d) - v_along * dt / 2.0, 0.0)
        v_brake = (-a * dt + math.sqrt(a * a * dt * dt + 8.0 * a * slack)) / 2.0
        v_wanted = direction * min(self._move_speed_counts_s, v_brake)
        dv = max(-a * dt, min(a * dt, v_wanted - self._velocity_counts_s))
        v_new = self._velocity_counts_s + dv
        self._position_counts += 0.5 * (self._velocity_counts_s + v_new) * dt
        self._velocity_counts_s = v_new
        if (self._goal_counts - self._position_counts) * direction <= 0.0:
            self._finish()  # reached or crossed the goal within this step

    def _finish(self) -> None:
        self._position_counts = self._goal_counts
        self._velocity_counts_s = 0.0
        self._moving = False

    def _halt(self) -> None:
        """Stop dead where the axis is (disable, fault)."""
        self._goal_counts = self._position_counts
        self._velocity_counts_s = 0.0
        self._moving = False

    def _status_word(self) -> int:
        word = 0
        if self._enabled:
            word |= STATUS_ENABLED
        if self._moving:
            word |= STATUS_MOVING
        at_rest = not self._moving and self._velocity_counts_s == 0.0
        near_goal = abs(self._position_counts - self._goal_counts) <= self.in_position_window_counts
        if self._enabled and not self._fault_code and at_rest and near_goal:
            word |= STATUS_IN_POSITION
        if self._fault_code:
            word |= STATUS_FAULT
        return word

    def _input_registers(self) -> list[int]:
        regs = [0] * N_INPUT_REGISTERS
        regs[IR_ACTUAL_POSITION : IR_ACTUAL_POSITION + 2] = registers_from_int32(round(self._position_counts))
        regs[IR_ACTUAL_SPEED : IR_ACTUAL_SPEED + 2] = registers_from_int32(round(self._velocity_counts_s))
        regs[IR_STATUS_WORD] = self._status_word()
        regs[IR_FAULT_CODE] = self._fault_code
        regs[IR_COUNTS_PER_METRE : IR_COUNTS_PER_METRE + 2] = registers_from_uint32(self.counts_per_m)
        regs[IR_SOFT_LIMIT_MIN : IR_SOFT_LIMIT_MIN + 2] = registers_from_int32(self.soft_limit_min_counts)
        regs[IR_SOFT_LIMIT_MAX : IR_SOFT_LIMIT_MAX + 2] = registers_from_int32(self.soft_limit_max_counts)
        regs[IR_MAX_SPEED : IR_MAX_SPEED + 2] = registers_from_uint32(self.max_speed_counts_s)
        regs[IR_MAX_ACCEL : IR_MAX_ACCEL + 2] = registers_from_uint32(self.max_accel_counts_s2)
        regs[IR_IN_POSITION_WINDOW] = min(self.in_position_window_counts, 0xFFFF)
        return regs

    def _holding_registers(self) -> list[int]:
        regs = [0] * N_HOLDING_REGISTERS
        regs[HR_PROFILE_SPEED : HR_PROFILE_SPEED + 2] = registers_from_uint32(self._profile_speed_counts_s)
        regs[HR_PROFILE_ACCEL : HR_PROFILE_ACCEL + 2] = registers_from_uint32(self._profile_accel_counts_s2)
        regs[HR_TARGET_POSITION : HR_TARGET_POSITION + 2] = registers_from_int32(round(self._goal_counts))
        return regs

    # ================================================================================== requests
    def _apply_fault(self, fault: str, params: dict[str, Any]) -> None:
        logger.info("fake track: inject %s %s", fault, params)
        if fault == "drop_connection":
            self._dropped = True
            server = self._server
            if server is not None:
                for conn in list(server.active_connections.values()):
                    conn.close()
        elif fault == "no_answer":
            self._no_answer = True
        elif fault == "modbus_exception":
            self._exception_code = int(params["code"])
        elif fault == "track_fault":
            self._advance()
            self._halt()
            self._enabled = False
            self._fault_code = int(params["code"])

    async def _action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> Any:
        """pymodbus's hook, called before every read and write: update, refuse, or act on the request."""
        from pymodbus.constants import ExcCodes

        code = self._handle(function_code, start_address, address, registers, set_values)
        if code is None:
            return None
        self._refused.append((function_code, code))
        logger.debug("fake track: FC %d at %d refused with exception %d", function_code, address, code)
        return ExcCodes(code)

    def _handle(
        self,
        function_code: int,
        start_address: int,
        address: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> int | None:
        if self._exception_code is not None:
            return self._exception_code
        self._advance()
        if set_values is None:  # a read (or the read-back of a single write): refresh what is read
            if function_code == FC_READ_INPUT:
                registers[:N_INPUT_REGISTERS] = self._input_registers()
            elif function_code == FC_READ_DISCRETE_INPUTS:
                registers[0] = self._status_word()
            elif function_code in (FC_READ_COILS, FC_WRITE_COIL):
                registers[0] = (registers[0] & ~1) | int(self._enabled)  # ENABLE reflects the drive
            return None
        if function_code in (FC_WRITE_COIL, FC_WRITE_COILS):
            return self._write_coils(address, [bool(v) for v in set_values], set_values)
        if function_code in (FC_WRITE_REGISTER, FC_WRITE_REGISTERS):
            return self._write_holding(start_address, address, registers, [int(v) for v in set_values])
        return None

    def _write_coils(self, address: int, values: list[bool], set_values: list[int] | list[bool]) -> int | None:
        coils = dict(zip(range(address, address + len(values)), values, strict=True))
        if coils.get(COIL_ENABLE) and not self._enabled and self._fault_code:
            return EXC_SERVER_DEVICE_BUSY
        if COIL_ENABLE in coils:
            if coils[COIL_ENABLE] and not self._enabled:
                self._enabled = True
                self._goal_counts = self._position_counts
            elif not coils[COIL_ENABLE] and self._enabled:
                self._enabled = False
                self._halt()
        if coils.get(COIL_STOP) and self._moving:
            v = self._velocity_counts_s
            stop_distance = v * abs(v) / (2.0 * self._move_accel_counts_s2)
            self._goal_counts = self._position_counts + stop_distance
            if stop_distance == 0.0:
                self._halt()
        if coils.get(COIL_FAULT_RESET) and self._fault_code:
            logger.info("fake track: fault %d reset", self._fault_code)
            self._fault_code = 0
        return None

    def _write_holding(self, start_address: int, address: int, registers: list[int], values: list[int]) -> int | None:
        # The registers as they would be after this write (the write is applied only if accepted).
        after = list(registers[:N_HOLDING_REGISTERS])  # registers[0] is the block's start_address
        offset = address - start_address
        after[offset : offset + len(values)] = values
        speed = uint32_from_registers(after[HR_PROFILE_SPEED : HR_PROFILE_SPEED + 2])
        accel = uint32_from_registers(after[HR_PROFILE_ACCEL : HR_PROFILE_ACCEL + 2])
        target = int32_from_registers(after[HR_TARGET_POSITION : HR_TARGET_POSITION + 2])
        written = range(address, address + len(values))
        if (HR_PROFILE_SPEED in written or HR_PROFILE_SPEED + 1 in written) and not (
            1 <= speed <= self.max_speed_counts_s
        ):
            return EXC_ILLEGAL_DATA_VALUE
        if (HR_PROFILE_ACCEL in written or HR_PROFILE_ACCEL + 1 in written) and not (
            1 <= accel <= self.max_accel_counts_s2
        ):
            return EXC_ILLEGAL_DATA_VALUE
        starts_move = HR_TARGET_POSITION + 1 in written
        if starts_move:
            if not self.soft_limit_min_counts <= target <= self.soft_limit_max_counts:
                return EXC_ILLEGAL_DATA_VALUE
            if not (1 <= speed <= self.max_speed_counts_s and 1 <= accel <= self.max_accel_counts_s2):
                return EXC_ILLEGAL_DATA_VALUE
            if self._fault_code or not self._enabled:
                return EXC_SERVER_DEVICE_BUSY
        self._profile_speed_counts_s = speed
        self._profile_accel_counts_s2 = accel
        if starts_move:
            self._moves.append(MoveRecord(target, speed, accel, self._position_counts, time.monotonic()))
            self._goal_counts = float(target)
            self._move_speed_counts_s = float(speed)
            self._move_accel_counts_s2 = float(accel)
            self._moving = True
            logger.debug("fake track: move to %d counts at %d counts/s, %d counts/s²", target, speed, accel)
        return None


def _make_server(fake: FakeTrack, device: Any, address: tuple[str, int]) -> Any:
    """A pymodbus ``ModbusTcpServer`` whose connections obey the fake's network faults."""
    from pymodbus.server import ModbusTcpServer
    from pymodbus.server.requesthandler import ServerRequestHandler

    class Handler(ServerRequestHandler):
        def callback_connected(self) -> None:
            super().callback_connected()
            if fake._dropped:  # refused while the fault is on: accept, then close at once
                self.close()

        def callback_data(self, data: bytes, addr: tuple[Any, ...] | None = None) -> int:
            if fake._no_answer:
                return len(data)  # swallowed: a hung drive
            return int(super().callback_data(data, addr))

    class Server(ModbusTcpServer):
        def callback_new_connection(self) -> Any:
            return Handler(self, self.trace_packet, self.trace_pdu, self.trace_connect)

    return Server(device, address=address)
