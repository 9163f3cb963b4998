"""drivers/track_registers.py: the track's register map and 32-bit register pairs (high word first)."""

from __future__ import annotations

import pytest

from drivers import track_registers as reg


def test_32_bit_values_are_two_registers_high_word_first() -> None:
    assert reg.registers_from_uint32(0x12345678) == [0x1234, 0x5678]
    assert reg.registers_from_int32(-2) == [0xFFFF, 0xFFFE]
    assert reg.int32_from_registers([0xFFFF, 0xFFFE]) == -2
    assert reg.uint32_from_registers([0xFFFF, 0xFFFE]) == 0xFFFFFFFE
    for value in (0, 1, 2**31 - 1, -(2**31), -123456789):
        assert reg.int32_from_registers(reg.registers_from_int32(value)) == value
    with pytest.raises(ValueError, match="signed 32-bit"):
        reg.registers_from_int32(2**31)
    with pytest.raises(ValueError, match="unsigned 32-bit"):
        reg.registers_from_uint32(-1)


def test_counts_are_rounded_at_the_wire() -> None:
    assert reg.counts_from_m(1.234567, 100000) == 123457
    assert reg.counts_from_m(-0.000004, 100000) == 0
    assert reg.m_from_counts(250000, 100000) == 2.5


def test_the_map_leaves_room_for_its_32_bit_pairs() -> None:
    pairs = [reg.IR_ACTUAL_POSITION, reg.IR_ACTUAL_SPEED, reg.IR_COUNTS_PER_METRE, reg.IR_SOFT_LIMIT_MIN,
             reg.IR_SOFT_LIMIT_MAX, reg.IR_MAX_SPEED, reg.IR_MAX_ACCEL]  # fmt: skip
    singles = [reg.IR_STATUS_WORD, reg.IR_FAULT_CODE, reg.IR_IN_POSITION_WINDOW]
    used = [a for p in pairs for a in (p, p + 1)] + singles
    assert sorted(used) == list(range(reg.N_INPUT_REGISTERS)) == list(range(17))
    holding = [a for p in (reg.HR_PROFILE_SPEED, reg.HR_PROFILE_ACCEL, reg.HR_TARGET_POSITION) for a in (p, p + 1)]
    assert sorted(holding) == list(range(reg.N_HOLDING_REGISTERS))
    bits = (reg.STATUS_ENABLED, reg.STATUS_MOVING, reg.STATUS_IN_POSITION, reg.STATUS_FAULT)
    assert bits == (1, 2, 4, 8)
    assert reg.EXCEPTION_NAMES[reg.EXC_SERVER_DEVICE_BUSY] == "SERVER DEVICE BUSY" and reg.MODBUS_TCP_PORT == 502
