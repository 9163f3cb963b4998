"""The ground track over Modbus TCP: ``drivers.protocols.Track`` with pymodbus's synchronous client.

The register map below is the contract between this driver and the track's drive (and the simulator,
``sim_fakes.fake_track``); its numbers live in :mod:`drivers.track_registers`, which both import, and
docs/track-modbus.md carries the same table. Addresses are 0-based PDU
addresses. 32-bit values occupy two consecutive registers, **high word first** (big-endian words).

Coils (FC 1 read, FC 5 / FC 15 write)

| addr | name          | access | meaning                                                                      |
|------|---------------|--------|------------------------------------------------------------------------------|
| 0    | ENABLE        | R/W    | 1 = power stage on; 0 = off (a moving axis halts at once). Writing 1 while a |
|      |               |        | fault is latched is refused with exception 6                                 |
| 1    | STOP          | W      | every write of 1 decelerates the axis to rest at the profile acceleration;   |
|      |               |        | the stop point becomes the goal (so IN_POSITION comes back at rest)          |
| 2    | FAULT_RESET   | W      | every write of 1 clears a latched fault; the axis stays disabled until       |
|      |               |        | ENABLE is written 1 again                                                    |
| 3-15 | (reserved)    |        | reading STOP / FAULT_RESET returns the last value written, with no meaning   |

Discrete inputs (FC 2): 0 ENABLED, 1 MOVING, 2 IN_POSITION, 3 FAULT (the bits of STATUS_WORD).

Holding registers (FC 3 read, FC 6 / FC 16 write)

| addr | name            | type   | unit       | meaning                                                  |
|------|-----------------|--------|------------|----------------------------------------------------------|
| 0-1  | PROFILE_SPEED   | uint32 | counts/s   | cruise speed of the next move, 1..MAX_SPEED              |
| 2-3  | PROFILE_ACCEL   | uint32 | counts/s²  | acceleration and deceleration of the next move,          |
|      |                 |        |            | 1..MAX_ACCEL                                             |
| 4-5  | TARGET_POSITION | int32  | counts     | a write that includes register 5 starts a move there     |

Input registers (FC 4, read only)

| addr  | name               | type   | unit      | meaning                                            |
|-------|--------------------|--------|-----------|----------------------------------------------------|
| 0-1   | ACTUAL_POSITION    | int32  | counts    | position from the track's home                     |
| 2-3   | ACTUAL_SPEED       | int32  | counts/s  | signed                                             |
| 4     | STATUS_WORD        | uint16 | bits      | 0 ENABLED, 1 MOVING, 2 IN_POSITION, 3 FAULT        |
| 5     | FAULT_CODE         | uint16 | -         | the drive's code of the latched fault, 0 = none    |
| 6-7   | COUNTS_PER_METRE   | uint32 | counts/m  | encoder scaling                                    |
| 8-9   | SOFT_LIMIT_MIN     | int32  | counts    | lowest target accepted                             |
| 10-11 | SOFT_LIMIT_MAX     | int32  | counts    | highest target accepted                            |
| 12-13 | MAX_SPEED          | uint32 | counts/s  | highest PROFILE_SPEED accepted                     |
| 14-15 | MAX_ACCEL          | uint32 | counts/s² | highest PROFILE_ACCEL accepted                     |
| 16    | IN_POSITION_WINDOW | uint16 | counts    | IN_POSITION: enabled, no fault, at rest, within    |
|       |                    |        |           | this many counts of the goal                       |

Exception responses

| code | name                  | when                                                                          |
|------|-----------------------|-------------------------------------------------------------------------------|
| 2    | ILLEGAL DATA ADDRESS  | an address outside the map                                                    |
| 3    | ILLEGAL DATA VALUE    | a target outside [SOFT_LIMIT_MIN, SOFT_LIMIT_MAX], a speed or acceleration of |
|      |                       | 0 or above its maximum; the whole write is refused and nothing moves          |
| 4    | SERVER DEVICE FAILURE | a request addressed to another unit id                                        |
| 6    | SERVER DEVICE BUSY    | a move while not enabled or while a fault is latched; ENABLE=1 while a fault  |
|      |                       | is latched                                                                    |

**Soft limits are enforced by refusal (exception 3), not by the fault bit**: a target outside them never
starts a move and leaves FAULT clear. This driver checks targets against the device's limits (read at
:meth:`ModbusTrack.connect`, narrowed by the configured ``soft_limits_m``) before sending and raises
:class:`MotionRejected`; an exception response that still comes back raises :class:`ModbusExceptionResponse`.

A fault (FAULT bit, FAULT_CODE) halts the axis at once and disables it; it stays latched until FAULT_RESET.

Units: metres, m/s and m/s² at this API; counts exist only on the wire and are converted here, in
:func:`counts_from_m` and :func:`m_from_counts`, with the unit in every name that carries them.

Errors: an exception response -> :class:`ModbusExceptionResponse` (a :class:`ModbusError` with its ``code``);
the fault bit -> :class:`TrackFault` with ``code`` = FAULT_CODE; a refused or closed connection ->
:class:`ConnectionLost`; no answer within ``timeout_s`` -> :class:`DeviceTimeout`. After ConnectionLost or
DeviceTimeout the socket is closed (a late answer must never be read as the reply to the next request) and
every call raises ConnectionLost until :meth:`ModbusTrack.connect` is called again.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers.errors import (
    ConnectionLost,
    DeviceTimeout,
    DriverError,
    ModbusError,
    MotionAborted,
    MotionRejected,
    MotionTimeout,
    TrackFault,
)
from drivers.protocols import TrackStatus
from drivers.track_registers import (
    COIL_ENABLE,
    COIL_FAULT_RESET,
    COIL_STOP,
    DI_ENABLED,
    DI_FAULT,
    DI_IN_POSITION,
    DI_MOVING,
    EXC_ILLEGAL_DATA_ADDRESS,
    EXC_ILLEGAL_DATA_VALUE,
    EXC_SERVER_DEVICE_BUSY,
    EXC_SERVER_DEVICE_FAILURE,
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
    MODBUS_TCP_PORT,
    N_COILS,
    N_DISCRETE_INPUTS,
    N_HOLDING_REGISTERS,
    N_INPUT_REGISTERS,
    STATUS_ENABLED,
    STATUS_FAULT,
    STATUS_IN_POSITION,
    STATUS_MOVING,
    counts_from_m,
    int32_from_registers,
    m_from_counts,
    registers_from_int32,
    registers_from_uint32,
    uint32_from_registers,
)

logger = logging.getLogger(__name__)

__all__ = [  # the register map and its wire helpers live in drivers.track_registers; they stay importable here
    "COIL_ENABLE",
    "COIL_FAULT_RESET",
    "COIL_STOP",
    "DI_ENABLED",
    "DI_FAULT",
    "DI_IN_POSITION",
    "DI_MOVING",
    "EXCEPTION_NAMES",
    "EXC_ILLEGAL_DATA_ADDRESS",
    "EXC_ILLEGAL_DATA_VALUE",
    "EXC_SERVER_DEVICE_BUSY",
    "EXC_SERVER_DEVICE_FAILURE",
    "HR_PROFILE_ACCEL",
    "HR_PROFILE_SPEED",
    "HR_TARGET_POSITION",
    "IR_ACTUAL_POSITION",
    "IR_ACTUAL_SPEED",
    "IR_COUNTS_PER_METRE",
    "IR_FAULT_CODE",
    "IR_IN_POSITION_WINDOW",
    "IR_MAX_ACCEL",
    "IR_MAX_SPEED",
    "IR_SOFT_LIMIT_MAX",
    "IR_SOFT_LIMIT_MIN",
    "IR_STATUS_WORD",
    "MODBUS_TCP_PORT",
    "N_COILS",
    "N_DISCRETE_INPUTS",
    "N_HOLDING_REGISTERS",
    "N_INPUT_REGISTERS",
    "STATUS_ENABLED",
    "STATUS_FAULT",
    "STATUS_IN_POSITION",
    "STATUS_MOVING",
    "ModbusExceptionResponse",
    "ModbusTrack",
    "TrackDeviceParameters",
    "counts_from_m",
    "int32_from_registers",
    "m_from_counts",
    "registers_from_int32",
    "registers_from_uint32",
    "uint32_from_registers",
]


class ModbusExceptionResponse(ModbusError):
    """The device answered with a Modbus exception response.

    ``code``: the exception code (3 = ILLEGAL DATA VALUE...); ``function_code``: the request's function code.
    """

    def __init__(self, message: str, *, code: int, function_code: int) -> None:
        self.code = code
        self.function_code = function_code
        name = EXCEPTION_NAMES.get(code, "unknown")
        super().__init__(f"{message}: Modbus exception {code} ({name}) to function code {function_code}")


@dataclass(frozen=True)
class TrackDeviceParameters:
    """What the drive reports about itself (input registers 6-16), in its own units."""

    counts_per_m: int
    soft_limit_min_counts: int
    soft_limit_max_counts: int
    max_speed_counts_s: int
    max_accel_counts_s2: int
    in_position_window_counts: int


@dataclass(frozen=True)
class _RawStatus:
    position_counts: int
    speed_counts_s: int
    status_word: int
    fault_code: int


class ModbusTrack:
    """A linear ground track driven over Modbus TCP (see the register map in this module's docstring).

    ``host``/``port``/``unit_id``: the drive's address (from the cell config; no default host).
    ``counts_per_m``: the configured encoder scaling; :meth:`connect` refuses a drive that reports another
    value (None trusts the drive). ``soft_limits_m``: (min, max) in metres, narrowing the drive's own limits.
    ``timeout_s``: per request. ``speed_m_s``/``accel_m_s2``: the profile of a move when none is given.
    ``poll_s``: how often status is read while waiting for a move or a state change.
    Methods may be called from several threads (``stop()`` while ``move_to`` blocks in another).
    """

    def __init__(
        self,
        host: str,
        *,
        port: int = MODBUS_TCP_PORT,
        unit_id: int = 1,
        counts_per_m: float | None = None,
        soft_limits_m: tuple[float, float] | None = None,
        name: str = "track",
        timeout_s: float = 1.0,
        speed_m_s: float = 0.2,
        accel_m_s2: float = 0.5,
        poll_s: float = 0.02,
        settle_grace_s: float = 0.25,
    ) -> None:
        if timeout_s <= 0 or poll_s <= 0:
            raise ValueError(f"timeout_s and poll_s must be > 0, got {timeout_s}, {poll_s}")
        if not 0 <= unit_id <= 247:
            raise ValueError(f"a Modbus unit id is 0..247, got {unit_id}")
        if counts_per_m is not None and not counts_per_m > 0:
            raise ValueError(f"counts_per_m must be > 0, got {counts_per_m}")
        if soft_limits_m is not None and not soft_limits_m[0] < soft_limits_m[1]:
            raise ValueError(f"soft_limits_m must be (min, max) with min < max, got {soft_limits_m}")
        if not (speed_m_s > 0 and accel_m_s2 > 0):
            raise ValueError(f"speed_m_s and accel_m_s2 must be > 0, got {speed_m_s}, {accel_m_s2}")
        self.name = name
        self.host = host
        self.port = port
        self.unit_id = unit_id
        self.counts_per_m = counts_per_m
        self.soft_limits_m = soft_limits_m
        self.timeout_s = timeout_s
        self.speed_m_s = speed_m_s
        self.accel_m_s2 = accel_m_s2
        self.poll_s = poll_s
        self.settle_grace_s = settle_grace_s
        self._client: Any = None  # pymodbus.client.ModbusTcpClient while connected
        self._params: TrackDeviceParameters | None = None
        self._io_lock = threading.Lock()  # one request on the wire at a time
        self._lifecycle_lock = threading.Lock()

    # ============================================================================== connection
    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    @property
    def device_parameters(self) -> TrackDeviceParameters:
        """The drive's scaling and limits as read at :meth:`connect`."""
        if self._params is None:
            raise ConnectionLost(f"{self.name}: not connected to the track at {self.address}; call connect() first")
        return self._params

    def connect(self) -> None:
        """Open (or re-open) the connection and read the drive's scaling and limits.

        Raises ConnectionLost when the drive is unreachable, DriverError when it reports a different
        counts-per-metre than configured.
        """
        from pymodbus.client import ModbusTcpClient

        with self._lifecycle_lock:
            self._close()
            client = ModbusTcpClient(
                self.host, port=self.port, timeout=self.timeout_s, retries=0, name=f"track-{self.name}"
            )
            if not client.connect():
                client.close()
                raise ConnectionLost(
                    f"{self.name}: cannot connect to the track's Modbus TCP server at {self.address} "
                    f"(within {self.timeout_s:.1f} s); check the drive's power, cable and the [track] host/port"
                )
            self._client = client
            try:
                params = self._read_parameters()
            except DriverError:
                self._close()
                raise
            if self.counts_per_m is not None and params.counts_per_m != round(self.counts_per_m):
                self._close()
                raise DriverError(
                    f"{self.name}: the drive reports {params.counts_per_m} counts/m but the config says "
                    f"{self.counts_per_m:g}; fix [track] counts_per_m (positions would be wrong by "
                    f"{params.counts_per_m / self.counts_per_m:.4f}x)"
                )
            self._params = params
            logger.info(
                "%s: connected to Modbus TCP %s unit %d (%d counts/m, soft limits %.4f..%.4f m)",
                self.name,
                self.address,
                self.unit_id,
                params.counts_per_m,
                m_from_counts(params.soft_limit_min_counts, params.counts_per_m),
                m_from_counts(params.soft_limit_max_counts, params.counts_per_m),
            )

    def disconnect(self) -> None:
        """Close the connection; safe to call twice. The axis is left as it is (a drive is not stopped)."""
        with self._lifecycle_lock:
            was_open = self._client is not None
            self._close()
            if was_open:
                logger.info("%s: disconnected", self.name)

    def _close(self) -> None:
        client, self._client = self._client, None
        self._params = None
        if client is not None:
            with contextlib.suppress(Exception):
                client.close()

    def _drop(self, client: Any) -> None:
        """Forget a connection that failed (only if it is still the current one)."""
        if self._client is client:
            self._client = None
            self._params = None
        with contextlib.suppress(Exception):
            client.close()

    # ============================================================================== requests
    def _request(self, what: str, call: Callable[[Any], Any]) -> Any:
        """Run one Modbus request and translate every failure into the driver's exceptions."""
        from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

        with self._io_lock:
            client = self._client
            if client is None:
                raise ConnectionLost(f"{self.name}: not connected to the track at {self.address}; call connect() first")
            try:
                response = call(client)
            except ConnectionException as err:
                self._drop(client)
                raise ConnectionLost(f"{self.name}: connection to {self.address} lost during {what}: {err}") from err
            except ModbusIOException as err:
                self._drop(client)
                raise DeviceTimeout(
                    f"{self.name}: no valid answer to {what} from {self.address} within {self.timeout_s:.1f} s; "
                    "the connection was closed, call connect() to retry"
                ) from err
            except ModbusException as err:
                raise ModbusError(f"{self.name}: {what} failed: {err}") from err
            except OSError as err:
                self._drop(client)
                raise ConnectionLost(f"{self.name}: connection to {self.address} lost during {what}: {err}") from err
        if response.isError():
            raise ModbusExceptionResponse(
                f"{self.name}: {what} refused by the drive",
                code=int(response.exception_code),
                function_code=int(response.function_code) & 0x7F,
            )
        return response

    def _read_input_registers(self, address: int, count: int, what: str) -> list[int]:
        response = self._request(what, lambda c: c.read_input_registers(address, count=count, device_id=self.unit_id))
        registers = list(response.registers)
        if len(registers) < count:
            raise ModbusError(f"{self.name}: {what}: asked for {count} registers, got {len(registers)}")
        return registers[:count]

    def _write_coil(self, address: int, value: bool, what: str) -> None:
        logger.debug("%s: coil %d <- %d (%s)", self.name, address, int(value), what)
        self._request(what, lambda c: c.write_coil(address, value, device_id=self.unit_id))

    def _read_parameters(self) -> TrackDeviceParameters:
        regs = self._read_input_registers(
            IR_COUNTS_PER_METRE, N_INPUT_REGISTERS - IR_COUNTS_PER_METRE, "read the drive's scaling and limits"
        )

        def at(address: int) -> list[int]:
            i = address - IR_COUNTS_PER_METRE
            return regs[i : i + 2]

        params = TrackDeviceParameters(
            counts_per_m=uint32_from_registers(at(IR_COUNTS_PER_METRE)),
            soft_limit_min_counts=int32_from_registers(at(IR_SOFT_LIMIT_MIN)),
            soft_limit_max_counts=int32_from_registers(at(IR_SOFT_LIMIT_MAX)),
            max_speed_counts_s=uint32_from_registers(at(IR_MAX_SPEED)),
            max_accel_counts_s2=uint32_from_registers(at(IR_MAX_ACCEL)),
            in_position_window_counts=regs[IR_IN_POSITION_WINDOW - IR_COUNTS_PER_METRE],
        )
        if params.counts_per_m <= 0:
            raise ModbusError(f"{self.name}: the drive reports {params.counts_per_m} counts/m; it is not configured")
        return params

    def _read_raw_status(self) -> _RawStatus:
        regs = self._read_input_registers(IR_ACTUAL_POSITION, IR_FAULT_CODE + 1, "read status")
        return _RawStatus(
            position_counts=int32_from_registers(regs[IR_ACTUAL_POSITION : IR_ACTUAL_POSITION + 2]),
            speed_counts_s=int32_from_registers(regs[IR_ACTUAL_SPEED : IR_ACTUAL_SPEED + 2]),
            status_word=regs[IR_STATUS_WORD],
            fault_code=regs[IR_FAULT_CODE],
        )

    # ============================================================================== state
    def status(self) -> TrackStatus:
        raw = self._read_raw_status()
        return self._status_from_raw(raw)

    def _status_from_raw(self, raw: _RawStatus) -> TrackStatus:
        return TrackStatus(
            position_m=m_from_counts(raw.position_counts, self.device_parameters.counts_per_m),
            enabled=bool(raw.status_word & STATUS_ENABLED),
            moving=bool(raw.status_word & STATUS_MOVING),
            in_position=bool(raw.status_word & STATUS_IN_POSITION),
            fault=bool(raw.status_word & STATUS_FAULT),
            fault_code=raw.fault_code,
        )

    def position_m(self) -> float:
        regs = self._read_input_registers(IR_ACTUAL_POSITION, 2, "read position")
        return m_from_counts(int32_from_registers(regs), self.device_parameters.counts_per_m)

    @property
    def limits_m(self) -> tuple[float, float]:
        """The targets this driver accepts: the drive's soft limits narrowed by the configured ones."""
        p = self.device_parameters
        lo = m_from_counts(p.soft_limit_min_counts, p.counts_per_m)
        hi = m_from_counts(p.soft_limit_max_counts, p.counts_per_m)
        if self.soft_limits_m is not None:
            lo, hi = max(lo, self.soft_limits_m[0]), min(hi, self.soft_limits_m[1])
        return lo, hi

    # ============================================================================== commands
    def enable(self, on: bool = True) -> None:
        """Switch the power stage on (or off) and wait until the drive reports it."""
        if on:
            st = self.status()
            if st.fault:
                raise TrackFault(
                    f"{self.name}: cannot enable while a fault is latched; call reset_fault() after the cause "
                    "is cleared",
                    code=st.fault_code,
                )
        self._write_coil(COIL_ENABLE, on, "enable" if on else "disable")
        self._wait_for(lambda st: st.enabled == on, what="enable" if on else "disable")

    def stop(self) -> None:
        """Decelerate to rest at the profile acceleration; harmless on an axis at rest."""
        self._write_coil(COIL_STOP, True, "stop")

    def reset_fault(self) -> None:
        """Clear a latched fault (the axis stays disabled: call :meth:`enable` afterwards)."""
        self._write_coil(COIL_FAULT_RESET, True, "reset fault")
        st = self._wait_for(lambda s: not s.fault, what="reset fault", raise_on_fault=False)
        if st.fault:
            raise TrackFault(f"{self.name}: the fault is still latched after a reset", code=st.fault_code)

    def _wait_for(self, done: Callable[[TrackStatus], bool], *, what: str, raise_on_fault: bool = True) -> TrackStatus:
        deadline = time.monotonic() + self.timeout_s
        while True:
            st = self.status()
            if done(st):
                return st
            if raise_on_fault and st.fault:
                raise TrackFault(f"{self.name}: {what}: the drive reports a fault", code=st.fault_code)
            if time.monotonic() > deadline:
                if not raise_on_fault:
                    return st
                raise DeviceTimeout(f"{self.name}: {what}: the drive did not confirm within {self.timeout_s:.1f} s")
            time.sleep(self.poll_s)

    def move_to(self, position_m: float, *, speed_m_s: float | None = None, timeout_s: float = 60.0) -> None:
        """Move to ``position_m`` (metres from home) and block until the drive reports it in position.

        Raises MotionRejected (outside the soft limits, bad speed, not enabled), TrackFault (fault bit, with
        the drive's code), MotionAborted (stopped before arriving), MotionTimeout, ConnectionLost.
        """
        p = self.device_parameters
        speed = self.speed_m_s if speed_m_s is None else speed_m_s
        if not math.isfinite(position_m):
            raise MotionRejected(f"{self.name}: target {position_m} m is not a number")
        lo, hi = self.limits_m
        if not lo <= position_m <= hi:
            raise MotionRejected(
                f"{self.name}: target {position_m:.4f} m is outside the soft limits [{lo:.4f}, {hi:.4f}] m"
            )
        target_counts = counts_from_m(position_m, p.counts_per_m)
        speed_counts_s = counts_from_m(speed, p.counts_per_m)
        accel_counts_s2 = counts_from_m(self.accel_m_s2, p.counts_per_m)
        if not 1 <= speed_counts_s <= p.max_speed_counts_s:
            raise MotionRejected(
                f"{self.name}: speed {speed} m/s is {speed_counts_s} counts/s; the drive accepts "
                f"1..{p.max_speed_counts_s} ({m_from_counts(p.max_speed_counts_s, p.counts_per_m):.3f} m/s)"
            )
        if not 1 <= accel_counts_s2 <= p.max_accel_counts_s2:
            raise MotionRejected(
                f"{self.name}: acceleration {self.accel_m_s2} m/s² is {accel_counts_s2} counts/s²; the drive "
                f"accepts 1..{p.max_accel_counts_s2}"
            )
        st = self.status()
        if st.fault:
            raise TrackFault(f"{self.name}: a fault is latched; reset_fault() then enable()", code=st.fault_code)
        if not st.enabled:
            raise MotionRejected(f"{self.name}: the track is not enabled; call enable() first")

        values = (
            registers_from_uint32(speed_counts_s)
            + registers_from_uint32(accel_counts_s2)
            + registers_from_int32(target_counts)
        )
        logger.debug(
            "%s: move to %d counts (%.4f m) at %d counts/s (%.3f m/s), %d counts/s²",
            self.name,
            target_counts,
            position_m,
            speed_counts_s,
            speed,
            accel_counts_s2,
        )
        self._request(
            f"move to {position_m:.4f} m",
            lambda c: c.write_registers(HR_PROFILE_SPEED, values, device_id=self.unit_id),
        )
        self._wait_for_arrival(target_counts, position_m=position_m, timeout_s=timeout_s)

    def _wait_for_arrival(self, target_counts: int, *, position_m: float, timeout_s: float) -> None:
        window = self.device_parameters.in_position_window_counts
        t0 = time.monotonic()
        seen_moving = False
        while True:
            raw = self._read_raw_status()
            st = self._status_from_raw(raw)
            if st.fault:
                raise TrackFault(
                    f"{self.name}: the drive faulted during the move to {position_m:.4f} m "
                    f"(stopped at {st.position_m:.4f} m)",
                    code=st.fault_code,
                )
            if not st.enabled:
                raise MotionAborted(
                    f"{self.name}: the drive was disabled during the move to {position_m:.4f} m "
                    f"(stopped at {st.position_m:.4f} m)"
                )
            near = abs(raw.position_counts - target_counts) <= window
            if near and st.in_position and not st.moving:
                return
            seen_moving = seen_moving or st.moving
            elapsed = time.monotonic() - t0
            if not st.moving and not near and (seen_moving or elapsed > self.settle_grace_s):
                raise MotionAborted(
                    f"{self.name}: the axis stopped at {st.position_m:.4f} m before reaching {position_m:.4f} m "
                    "(a stop was commanded)"
                )
            if elapsed > timeout_s:
                with contextlib.suppress(DriverError):
                    self.stop()
                raise MotionTimeout(
                    f"{self.name}: not in position at {position_m:.4f} m within {timeout_s:.1f} s "
                    f"(at {st.position_m:.4f} m); the axis was told to stop"
                )
            time.sleep(self.poll_s)
