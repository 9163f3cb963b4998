"""The fake track drive's device side (sim_fakes/fake_track.py) without the network: the requests pymodbus hands
its hook, the register image, the trapezoid on a clock the test holds, faults latched until FAULT_RESET.
(tests/drivers/test_track.py drives the same fake through pymodbus and the driver.)"""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from drivers.track_registers import (
    COIL_ENABLE,
    COIL_FAULT_RESET,
    COIL_STOP,
    EXC_ILLEGAL_DATA_VALUE,
    EXC_SERVER_DEVICE_BUSY,
    HR_PROFILE_ACCEL,
    HR_TARGET_POSITION,
    IR_ACTUAL_POSITION,
    IR_COUNTS_PER_METRE,
    IR_FAULT_CODE,
    IR_IN_POSITION_WINDOW,
    IR_MAX_ACCEL,
    IR_MAX_SPEED,
    IR_SOFT_LIMIT_MAX,
    IR_SOFT_LIMIT_MIN,
    IR_STATUS_WORD,
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
from sim_fakes import fake_track
from sim_fakes.fake_track import (
    FC_READ_INPUT,
    FC_WRITE_COIL,
    FC_WRITE_REGISTERS,
    FakeTrack,
)


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> Clock:
    c = Clock()
    monkeypatch.setattr(fake_track, "time", SimpleNamespace(monotonic=c))  # the fake's clock only
    return c


def drive(**kw: object) -> FakeTrack:
    args: dict[str, object] = dict(counts_per_m=100_000, soft_limits_m=(0.0, 2.0), max_speed_m_s=0.5,
                                   max_accel_m_s2=1.0, in_position_window_m=0.0002, tick_s=0.002)  # fmt: skip
    return FakeTrack(**{**args, **kw})  # type: ignore[arg-type]


def inputs(d: FakeTrack) -> list[int]:
    regs = [0] * N_INPUT_REGISTERS
    assert d._handle(FC_READ_INPUT, 0, 0, regs, None) is None
    return regs


def position(d: FakeTrack) -> int:
    """ACTUAL_POSITION as a client reads it (each request advances the axis to now)."""
    return int32_from_registers(inputs(d)[IR_ACTUAL_POSITION : IR_ACTUAL_POSITION + 2])


def write_coil(d: FakeTrack, coil: int, value: bool) -> int | None:
    return d._handle(FC_WRITE_COIL, 0, coil, [0], [value])


def move(d: FakeTrack, target: int, speed: int, accel: int) -> int | None:
    values = [*registers_from_uint32(speed), *registers_from_uint32(accel), *registers_from_int32(target)]
    return d._handle(FC_WRITE_REGISTERS, 0, 0, d._holding_registers(), values)


def test_the_si_limits_are_counts_in_the_input_registers_once_and_for_all(clock: Clock) -> None:
    d = drive(start_position_m=0.25)
    regs = inputs(d)
    assert int32_from_registers(regs[IR_ACTUAL_POSITION : IR_ACTUAL_POSITION + 2]) == 25_000
    assert uint32_from_registers(regs[IR_COUNTS_PER_METRE : IR_COUNTS_PER_METRE + 2]) == 100_000
    assert int32_from_registers(regs[IR_SOFT_LIMIT_MIN : IR_SOFT_LIMIT_MIN + 2]) == 0
    assert int32_from_registers(regs[IR_SOFT_LIMIT_MAX : IR_SOFT_LIMIT_MAX + 2]) == 200_000
    assert uint32_from_registers(regs[IR_MAX_SPEED : IR_MAX_SPEED + 2]) == 50_000
    assert uint32_from_registers(regs[IR_MAX_ACCEL : IR_MAX_ACCEL + 2]) == 100_000
    assert regs[IR_IN_POSITION_WINDOW] == 20 and regs[IR_FAULT_CODE] == 0
    assert regs[IR_STATUS_WORD] == 0  # disabled: not in position either
    # the default profile is 0.1 m/s and 0.5 m/s² within the limits
    assert d._holding_registers()[HR_PROFILE_ACCEL : HR_PROFILE_ACCEL + 2] == registers_from_uint32(50_000)
    assert int32_from_registers(d._holding_registers()[HR_TARGET_POSITION:]) == 25_000


def test_a_move_runs_the_trapezoid_in_the_analytic_time(clock: Clock) -> None:
    d = drive()
    assert write_coil(d, COIL_ENABLE, True) is None
    assert inputs(d)[IR_STATUS_WORD] == STATUS_ENABLED | STATUS_IN_POSITION
    # 50,000 counts at 10,000 counts/s and 50,000 counts/s²: 0.2 s up (1,000 counts), 4.8 s cruise, 0.2 s down
    assert move(d, 50_000, 10_000, 50_000) is None
    [record] = d._moves
    assert (record.target_counts, record.speed_counts_s, record.accel_counts_s2, record.start_counts) == (
        50_000, 10_000, 50_000, 0.0,
    )  # fmt: skip
    assert record.received_s == 1000.0
    clock.t += 0.1  # accelerating: s = a t^2 / 2
    assert position(d) == pytest.approx(250, abs=10)
    clock.t += 2.5  # halfway in time and in distance, at cruise speed
    regs = inputs(d)
    assert int32_from_registers(regs[IR_ACTUAL_POSITION:]) == pytest.approx(25_000, abs=25)
    assert int32_from_registers(regs[2:4]) == 10_000
    assert regs[IR_STATUS_WORD] == STATUS_ENABLED | STATUS_MOVING
    clock.t += 2.6 - 0.004  # two ticks before the analytic end (5.2 s): still moving, within counts of the goal
    regs = inputs(d)
    assert regs[IR_STATUS_WORD] == STATUS_ENABLED | STATUS_MOVING
    assert 50_000 - 5 <= int32_from_registers(regs[IR_ACTUAL_POSITION:]) <= 50_000
    clock.t += 0.006  # one tick after it: there, exactly, at rest
    regs = inputs(d)
    assert int32_from_registers(regs[IR_ACTUAL_POSITION:]) == 50_000 and d._position_counts == 50_000.0
    assert regs[IR_STATUS_WORD] == STATUS_ENABLED | STATUS_IN_POSITION


def test_stop_brakes_at_the_moves_acceleration(clock: Clock) -> None:
    d = drive()
    write_coil(d, COIL_ENABLE, True)
    move(d, 150_000, 20_000, 40_000)
    clock.t += 1.0  # at 20,000 counts/s after 0.5 s: 5,000 + 10,000 counts
    assert position(d) == pytest.approx(15_000, abs=30)
    assert write_coil(d, COIL_STOP, True) is None
    # braking from 20,000 counts/s at 40,000 counts/s^2 takes 5,000 counts
    assert d._goal_counts == pytest.approx(d._position_counts + 5_000, abs=1e-9)
    clock.t += 1.0
    assert position(d) == pytest.approx(20_000, abs=30) and not d._moving


def test_the_drive_refuses_what_a_real_one_refuses_and_moves_nothing(clock: Clock) -> None:
    d = drive()
    assert move(d, 10_000, 10_000, 50_000) == EXC_SERVER_DEVICE_BUSY  # disabled
    write_coil(d, COIL_ENABLE, True)
    assert move(d, 200_001, 10_000, 50_000) == EXC_ILLEGAL_DATA_VALUE  # one count past the soft limit
    assert move(d, -1, 10_000, 50_000) == EXC_ILLEGAL_DATA_VALUE
    assert move(d, 10_000, 50_001, 50_000) == EXC_ILLEGAL_DATA_VALUE  # over the speed limit
    assert move(d, 10_000, 10_000, 0) == EXC_ILLEGAL_DATA_VALUE
    assert d._moves == [] and d._goal_counts == 0.0
    assert move(d, 200_000, 50_000, 100_000) is None  # at the limits exactly: accepted
    assert len(d._moves) == 1


def test_a_drive_fault_halts_disables_and_stays_until_fault_reset(clock: Clock) -> None:
    d = drive()
    write_coil(d, COIL_ENABLE, True)
    move(d, 100_000, 10_000, 50_000)
    clock.t += 1.0
    d._apply_fault("track_fault", {"code": 0x2310})
    held = d._position_counts
    assert held == pytest.approx(9_000, abs=25)  # 1,000 counts ramp + 0.8 s at 10,000 counts/s
    regs = inputs(d)
    assert regs[IR_STATUS_WORD] == STATUS_FAULT and regs[IR_FAULT_CODE] == 0x2310
    clock.t += 1.0
    assert inputs(d)[IR_ACTUAL_POSITION : IR_ACTUAL_POSITION + 2] == registers_from_int32(round(held))  # halted
    assert write_coil(d, COIL_ENABLE, True) == EXC_SERVER_DEVICE_BUSY  # no enable while faulted
    assert write_coil(d, COIL_FAULT_RESET, True) is None
    assert write_coil(d, COIL_ENABLE, True) is None
    assert inputs(d)[IR_STATUS_WORD] == STATUS_ENABLED | STATUS_IN_POSITION  # at rest where it halted
    # an injected exception answers every request until cleared, reads included
    d._apply_fault("modbus_exception", {"code": 4})
    assert d._handle(FC_READ_INPUT, 0, 0, [0] * N_INPUT_REGISTERS, None) == 4


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"host": "10.0.0.5"}, "the fake track binds loopback only, got host='10.0.0.5'"),
        ({"counts_per_m": 0}, "counts_per_m must be a positive integer, got 0"),
        ({"soft_limits_m": (1.0, 1.0)}, r"soft_limits_m must be \(min, max\) with min < max, got \(1.0, 1.0\)"),
        ({"start_position_m": 2.5}, r"start_position_m=2.5 lies outside the soft limits \(0.0, 2.0\)"),
        ({"max_speed_m_s": 0.0}, "max_speed_m_s, max_accel_m_s2 and tick_s must be > 0"),
        ({"soft_limits_m": (0.0, 30_000.0)}, "does not fit a signed 32-bit register pair"),
    ],
)
def test_a_drive_that_cannot_exist_is_refused_at_construction(kw: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        drive(**kw)
