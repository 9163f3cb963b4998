"""The ground track's Modbus register map and its 32-bit wire helpers: one home for the driver
(:mod:`drivers.track`) and the simulated drive (:mod:`sim_fakes.fake_track`).

The table of what each coil, input and register means is in :mod:`drivers.track`'s docstring and
docs/track-modbus.md. Addresses are 0-based PDU addresses; 32-bit values occupy two consecutive registers, high word
first. Counts exist only here and at the wire: :func:`counts_from_m` / :func:`m_from_counts` convert.
"""

from __future__ import annotations

from collections.abc import Sequence

MODBUS_TCP_PORT = 502
"""The registered Modbus TCP port (the protocol's default, not an address of any cell)."""

COIL_ENABLE = 0
COIL_STOP = 1
COIL_FAULT_RESET = 2
N_COILS = 16

DI_ENABLED = 0
DI_MOVING = 1
DI_IN_POSITION = 2
DI_FAULT = 3
N_DISCRETE_INPUTS = 16

HR_PROFILE_SPEED = 0
HR_PROFILE_ACCEL = 2
HR_TARGET_POSITION = 4
N_HOLDING_REGISTERS = 6

IR_ACTUAL_POSITION = 0
IR_ACTUAL_SPEED = 2
IR_STATUS_WORD = 4
IR_FAULT_CODE = 5
IR_COUNTS_PER_METRE = 6
IR_SOFT_LIMIT_MIN = 8
IR_SOFT_LIMIT_MAX = 10
IR_MAX_SPEED = 12
IR_MAX_ACCEL = 14
IR_IN_POSITION_WINDOW = 16
N_INPUT_REGISTERS = 17

STATUS_ENABLED = 1 << 0
STATUS_MOVING = 1 << 1
STATUS_IN_POSITION = 1 << 2
STATUS_FAULT = 1 << 3

EXC_ILLEGAL_DATA_ADDRESS = 2
EXC_ILLEGAL_DATA_VALUE = 3
EXC_SERVER_DEVICE_FAILURE = 4
EXC_SERVER_DEVICE_BUSY = 6

EXCEPTION_NAMES = {
    1: "ILLEGAL FUNCTION",
    2: "ILLEGAL DATA ADDRESS",
    3: "ILLEGAL DATA VALUE",
    4: "SERVER DEVICE FAILURE",
    5: "ACKNOWLEDGE",
    6: "SERVER DEVICE BUSY",
    7: "NEGATIVE ACKNOWLEDGE",
    8: "MEMORY PARITY ERROR",
    10: "GATEWAY PATH UNAVAILABLE",
    11: "GATEWAY TARGET DEVICE FAILED TO RESPOND",
}


# ------------------------------------------------------------------------------------------- wire helpers
def registers_from_uint32(value: int) -> list[int]:
    """Two registers, high word first, of an unsigned 32-bit value."""
    if not 0 <= value <= 0xFFFFFFFF:
        raise ValueError(f"{value} does not fit an unsigned 32-bit register pair")
    return [(value >> 16) & 0xFFFF, value & 0xFFFF]


def registers_from_int32(value: int) -> list[int]:
    """Two registers, high word first, of a signed 32-bit value (two's complement)."""
    if not -(2**31) <= value < 2**31:
        raise ValueError(f"{value} does not fit a signed 32-bit register pair")
    return registers_from_uint32(value & 0xFFFFFFFF)


def uint32_from_registers(registers: Sequence[int]) -> int:
    """The unsigned 32-bit value of two registers, high word first."""
    hi, lo = int(registers[0]), int(registers[1])
    return ((hi & 0xFFFF) << 16) | (lo & 0xFFFF)


def int32_from_registers(registers: Sequence[int]) -> int:
    """The signed 32-bit value of two registers, high word first."""
    value = uint32_from_registers(registers)
    return value - 2**32 if value >= 2**31 else value


def counts_from_m(value_m: float, counts_per_m: float) -> int:
    """Metres (or m/s, m/s²) to the nearest whole count (counts/s, counts/s²)."""
    return round(float(value_m) * counts_per_m)


def m_from_counts(value_counts: int | float, counts_per_m: float) -> float:
    """Counts (counts/s, counts/s²) to metres (m/s, m/s²)."""
    return float(value_counts) / counts_per_m
