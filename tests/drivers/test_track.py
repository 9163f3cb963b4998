"""ModbusTrack against the fake track drive (a real pymodbus Modbus TCP server on loopback), the Track contract,
and the register map as the drive enforces it."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from typing import Any

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.errors import ConnectionLost, DriverError, MotionRejected
from drivers.track import (
    COIL_ENABLE,
    EXC_ILLEGAL_DATA_VALUE,
    EXC_SERVER_DEVICE_BUSY,
    HR_PROFILE_SPEED,
    HR_TARGET_POSITION,
    IR_ACTUAL_POSITION,
    IR_COUNTS_PER_METRE,
    N_INPUT_REGISTERS,
    ModbusExceptionResponse,
    ModbusTrack,
    counts_from_m,
    int32_from_registers,
    m_from_counts,
    registers_from_int32,
    registers_from_uint32,
    uint32_from_registers,
)
from sim_fakes.fake_track import FakeTrack
from sim_fakes.faults import FaultInjectable
from tests.drivers.track_contract import (
    LIMIT_MAX_M,
    LIMIT_MIN_M,
    POSITION_TOL_M,
    REQUEST_TIMEOUT_S,
    START_M,
    TrackContract,
)
from tests.leftovers import assert_no_threads_left

COUNTS_PER_M = 100_000
OUR_THREAD_PREFIXES = ("fake-track", "contract-watcher")


@pytest.fixture(autouse=True)
def no_leftover_threads() -> Iterator[None]:
    yield
    assert_no_threads_left(OUR_THREAD_PREFIXES)


@pytest.fixture
def fake() -> Iterator[FakeTrack]:
    with FakeTrack(
        counts_per_m=COUNTS_PER_M,
        soft_limits_m=(LIMIT_MIN_M, LIMIT_MAX_M),
        max_speed_m_s=0.5,
        max_accel_m_s2=2.0,
        in_position_window_m=POSITION_TOL_M,
        start_position_m=START_M,
    ) as drive:
        yield drive


@pytest.fixture
def track(fake: FakeTrack) -> Iterator[ModbusTrack]:
    driver = ModbusTrack(
        "127.0.0.1",
        port=fake.port,
        counts_per_m=COUNTS_PER_M,
        timeout_s=REQUEST_TIMEOUT_S,
        speed_m_s=0.3,
        accel_m_s2=1.0,
    )
    driver.connect()
    try:
        yield driver
    finally:
        driver.disconnect()


class TestModbusTrackContract(TrackContract):
    @pytest.fixture
    def track_and_fake(self, track: ModbusTrack, fake: FakeTrack) -> Iterator[tuple[ModbusTrack, Any]]:
        assert isinstance(fake, FaultInjectable)
        yield track, fake


@pytest.fixture
def raw(fake: FakeTrack) -> Iterator[ModbusTcpClient]:
    client = ModbusTcpClient("127.0.0.1", port=fake.port, timeout=1.0, retries=0)
    assert client.connect()
    try:
        yield client
    finally:
        client.close()


# ---------------------------------------------------------------------------------------------- wire format
def test_32_bit_values_travel_high_word_first() -> None:
    assert registers_from_int32(-1) == [0xFFFF, 0xFFFF]
    assert registers_from_int32(-2) == [0xFFFF, 0xFFFE]
    assert registers_from_int32(123_456) == [0x0001, 0xE240]
    assert registers_from_uint32(0xDEADBEEF) == [0xDEAD, 0xBEEF]
    assert int32_from_registers([0x8000, 0x0000]) == -(2**31)
    assert int32_from_registers([0x7FFF, 0xFFFF]) == 2**31 - 1
    assert uint32_from_registers([0xDEAD, 0xBEEF]) == 0xDEADBEEF
    for value in (-(2**31), -250_001, -1, 0, 1, 250_001, 2**31 - 1):
        assert int32_from_registers(registers_from_int32(value)) == value
    with pytest.raises(ValueError):
        registers_from_int32(2**31)
    with pytest.raises(ValueError):
        registers_from_uint32(-1)


def test_counts_and_metres_convert_at_one_place() -> None:
    assert counts_from_m(0.123456, COUNTS_PER_M) == 12346
    assert counts_from_m(-0.000004, COUNTS_PER_M) == 0
    assert counts_from_m(2.5, 8192) == 20480
    assert m_from_counts(12346, COUNTS_PER_M) == 0.12346
    assert m_from_counts(-20480, 8192) == -2.5


# ---------------------------------------------------------------------------------------------- the driver
@pytest.mark.timeout(20)
def test_device_parameters_come_from_the_input_registers(track: ModbusTrack) -> None:
    p = track.device_parameters
    assert (p.counts_per_m, p.soft_limit_min_counts, p.soft_limit_max_counts) == (100_000, 0, 100_000)
    assert (p.max_speed_counts_s, p.max_accel_counts_s2, p.in_position_window_counts) == (50_000, 200_000, 20)
    assert track.limits_m == (0.0, 1.0)


@pytest.mark.timeout(20)
def test_what_goes_on_the_wire_is_counts(track: ModbusTrack, fake: FakeTrack) -> None:
    track.enable()
    track.move_to(0.123456, speed_m_s=0.15, timeout_s=10)
    move = fake.moves()[-1]
    assert (move.target_counts, move.speed_counts_s, move.accel_counts_s2) == (12_346, 15_000, 100_000)
    assert move.start_counts == 10_000.0
    assert fake.snapshot()["position_counts"] == 12_346.0
    assert track.position_m() == 0.12346  # back in metres, rounded to the count


@pytest.mark.timeout(20)
def test_move_follows_the_trapezoid_profile(track: ModbusTrack, fake: FakeTrack) -> None:
    track.enable()
    track.accel_m_s2 = 0.5
    t0 = time.monotonic()
    track.move_to(START_M + 0.2, speed_m_s=0.2, timeout_s=10)
    elapsed = time.monotonic() - t0
    # 0.2 m at 0.2 m/s with 0.5 m/s² up and down: d/v + v/a = 1.0 + 0.4 = 1.4 s (the fake integrates in 2 ms
    # steps, exact to one step); the driver polls every 20 ms, and a loaded machine delays the poll a little
    assert 1.4 - 0.002 <= elapsed < 1.4 + 0.3
    assert fake.snapshot()["position_counts"] == 30_000.0


@pytest.mark.timeout(20)
def test_configured_soft_limits_narrow_the_drives(fake: FakeTrack) -> None:
    driver = ModbusTrack("127.0.0.1", port=fake.port, soft_limits_m=(0.05, 0.5), timeout_s=REQUEST_TIMEOUT_S)
    driver.connect()
    try:
        assert driver.limits_m == (0.05, 0.5)
        driver.enable()
        with pytest.raises(MotionRejected, match=r"outside the soft limits \[0.0500, 0.5000\]"):
            driver.move_to(0.6)
        with pytest.raises(MotionRejected, match="counts/s"):
            driver.move_to(0.2, speed_m_s=0.6)  # above the drive's 0.5 m/s
        assert fake.moves() == []
    finally:
        driver.disconnect()


@pytest.mark.timeout(10)
def test_counts_per_metre_mismatch_is_refused_at_connect(fake: FakeTrack) -> None:
    driver = ModbusTrack("127.0.0.1", port=fake.port, counts_per_m=8192, timeout_s=REQUEST_TIMEOUT_S)
    with pytest.raises(DriverError, match="100000 counts/m but the config says 8192"):
        driver.connect()
    with pytest.raises(ConnectionLost):
        driver.status()


@pytest.mark.timeout(10)
def test_connect_to_nothing_raises_connection_lost() -> None:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        free_port = sock.getsockname()[1]
    driver = ModbusTrack("127.0.0.1", port=free_port, timeout_s=REQUEST_TIMEOUT_S)
    with pytest.raises(ConnectionLost, match=f"127.0.0.1:{free_port}"):
        driver.connect()
    with pytest.raises(ConnectionLost):
        driver.position_m()
    driver.disconnect()
    driver.disconnect()


@pytest.mark.timeout(20)
def test_modbus_exception_code_is_kept(track: ModbusTrack, fake: FakeTrack) -> None:
    fake.inject("modbus_exception", code=6)
    with pytest.raises(ModbusExceptionResponse) as info:
        track.position_m()
    assert (info.value.code, info.value.function_code) == (6, 4)
    assert "SERVER DEVICE BUSY" in str(info.value)


# ---------------------------------------------------------------------------------------------- the drive
@pytest.mark.timeout(20)
def test_drive_refuses_a_target_outside_the_soft_limits_with_exception_3(fake: FakeTrack, raw: Any) -> None:
    assert not raw.write_coil(COIL_ENABLE, True).isError()
    values = registers_from_uint32(20_000) + registers_from_uint32(50_000) + registers_from_int32(100_001)
    response = raw.write_registers(HR_PROFILE_SPEED, values)
    assert response.isError() and response.exception_code == EXC_ILLEGAL_DATA_VALUE
    assert fake.moves() == [] and fake.snapshot()["moving"] is False
    # the whole write was refused: the profile speed kept its old value
    assert raw.read_holding_registers(HR_PROFILE_SPEED, count=2).registers == registers_from_uint32(10_000)
    # a speed above the drive's maximum is refused the same way
    response = raw.write_registers(HR_PROFILE_SPEED, registers_from_uint32(50_001))
    assert response.isError() and response.exception_code == EXC_ILLEGAL_DATA_VALUE
    # inside the limits the same write starts a move
    values[4:6] = registers_from_int32(100_000)
    assert not raw.write_registers(HR_PROFILE_SPEED, values).isError()
    assert [m.target_counts for m in fake.moves()] == [100_000]
    assert fake.refused() == [(16, 3), (16, 3)]


@pytest.mark.timeout(20)
def test_drive_refuses_moves_while_disabled_or_faulted_with_exception_6(fake: FakeTrack, raw: Any) -> None:
    response = raw.write_registers(HR_TARGET_POSITION, registers_from_int32(20_000))
    assert response.isError() and response.exception_code == EXC_SERVER_DEVICE_BUSY
    fake.inject("track_fault", code=7)
    response = raw.write_coil(COIL_ENABLE, True)
    assert response.isError() and response.exception_code == EXC_SERVER_DEVICE_BUSY
    regs = raw.read_input_registers(IR_ACTUAL_POSITION, count=N_INPUT_REGISTERS).registers
    assert regs[4] == 0b1000 and regs[5] == 7  # FAULT, code 7
    assert uint32_from_registers(regs[IR_COUNTS_PER_METRE : IR_COUNTS_PER_METRE + 2]) == COUNTS_PER_M
    assert raw.read_discrete_inputs(0, count=4).bits[:4] == [False, False, False, True]
    # a target for another unit id is not answered as if it were ours
    assert raw.read_input_registers(IR_ACTUAL_POSITION, count=2, device_id=9).isError()


@pytest.mark.timeout(10)
def test_fake_refuses_unknown_faults_bad_codes_and_non_loopback_hosts(fake: FakeTrack) -> None:
    with pytest.raises(ValueError):
        fake.inject("meteor_strike")
    with pytest.raises(ValueError):
        fake.inject("track_fault")  # needs code=
    with pytest.raises(ValueError):
        fake.inject("modbus_exception", code=9)  # not an exception code
    with pytest.raises(ValueError):
        fake.inject("no_answer", code=1)
    with pytest.raises(ValueError):
        FakeTrack(host="10.0.0.5")
    with pytest.raises(ValueError):
        FakeTrack(soft_limits_m=(0.0, 1.0), start_position_m=2.0)
