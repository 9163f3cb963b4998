"""The checks every ``drivers.protocols.Track`` implementation must pass.

A test module subclasses :class:`TrackContract` and provides the fixture ``track_and_fake`` yielding
``(track, fake)``: a connected driver, disabled, at rest at :data:`START_M` with soft limits
[:data:`LIMIT_MIN_M`, :data:`LIMIT_MAX_M`] and no fault, and the fake's
:class:`sim_fakes.faults.FaultInjectable` handle (None against real hardware, where fault tests are skipped).
The driver's ``timeout_s`` must be at most :data:`REQUEST_TIMEOUT_S`; each test gets a fresh fake.
"""

from __future__ import annotations

import threading
import time

import pytest

from drivers.errors import ConnectionLost, DeviceTimeout, ModbusError, MotionAborted, MotionRejected, TrackFault
from drivers.protocols import Track, TrackStatus

START_M = 0.1
LIMIT_MIN_M = 0.0
LIMIT_MAX_M = 1.0
REQUEST_TIMEOUT_S = 0.5
POSITION_TOL_M = 0.0002  # the in-position window the fixtures configure


class TrackContract:
    """Subclass and provide ``track_and_fake``. Every test has a timeout."""

    @pytest.mark.timeout(20)
    def test_is_a_track_and_reports_its_state(self, track_and_fake):
        track, _ = track_and_fake
        assert isinstance(track, Track)
        st = track.status()
        assert isinstance(st, TrackStatus)
        assert st == TrackStatus(
            position_m=START_M, enabled=False, moving=False, in_position=False, fault=False, fault_code=0
        )
        assert track.position_m() == START_M

    @pytest.mark.timeout(20)
    def test_enable_then_disable(self, track_and_fake):
        track, _ = track_and_fake
        track.enable()
        st = track.status()
        assert (st.enabled, st.in_position, st.moving, st.fault) == (True, True, False, False)
        track.enable(False)
        assert track.status().enabled is False
        with pytest.raises(MotionRejected):  # a disabled axis does not move
            track.move_to(START_M + 0.05, timeout_s=5)
        assert track.position_m() == START_M

    @pytest.mark.timeout(20)
    def test_move_to_arrives_and_takes_the_time_it_should(self, track_and_fake):
        track, _ = track_and_fake
        track.enable()
        target = START_M + 0.15
        t0 = time.monotonic()
        track.move_to(target, speed_m_s=0.25, timeout_s=10)
        elapsed = time.monotonic() - t0
        st = track.status()
        assert abs(st.position_m - target) <= POSITION_TOL_M
        assert st.in_position and not st.moving and st.enabled
        # 0.15 m can not be covered faster than at 0.25 m/s all the way: the axis integrates motion
        assert elapsed >= 0.15 / 0.25
        assert elapsed < 0.15 / 0.25 + 2.0

    @pytest.mark.timeout(20)
    def test_a_move_while_moving_is_watched_from_another_thread(self, track_and_fake):
        track, _ = track_and_fake
        track.enable()
        seen: list[TrackStatus] = []
        done = threading.Event()

        def watch() -> None:
            while not done.is_set():
                seen.append(track.status())
                time.sleep(0.02)

        watcher = threading.Thread(target=watch, name="contract-watcher")
        watcher.start()
        try:
            track.move_to(START_M + 0.1, speed_m_s=0.3, timeout_s=10)
        finally:
            done.set()
            watcher.join(5)
        moving = [s for s in seen if s.moving]
        assert moving, "the watcher never saw the axis moving"
        assert all(not s.in_position for s in moving)
        positions = [s.position_m for s in seen]
        assert positions == sorted(positions)  # monotonic towards the target
        assert START_M < moving[len(moving) // 2].position_m < START_M + 0.1

    @pytest.mark.timeout(20)
    def test_soft_limits_refuse_the_target_and_nothing_moves(self, track_and_fake):
        track, _ = track_and_fake
        track.enable()
        for target in (LIMIT_MAX_M + 0.001, LIMIT_MIN_M - 0.001, float("nan")):
            with pytest.raises(MotionRejected):
                track.move_to(target, timeout_s=5)
            st = track.status()
            assert st.position_m == START_M and not st.moving and not st.fault
        track.move_to(LIMIT_MIN_M, speed_m_s=0.5, timeout_s=10)  # the limit itself is allowed
        assert abs(track.position_m() - LIMIT_MIN_M) <= POSITION_TOL_M

    @pytest.mark.timeout(20)
    def test_stop_from_another_thread_aborts_the_move(self, track_and_fake):
        track, _ = track_and_fake
        track.enable()
        timer = threading.Timer(0.3, track.stop)
        timer.start()
        try:
            with pytest.raises(MotionAborted):
                track.move_to(LIMIT_MAX_M, speed_m_s=0.3, timeout_s=10)
        finally:
            timer.cancel()
        stopped = track.status()
        assert START_M + 0.02 < stopped.position_m < LIMIT_MAX_M - 0.2  # halted part-way
        assert not stopped.moving and stopped.in_position
        time.sleep(0.1)
        assert track.position_m() == stopped.position_m
        track.stop()  # harmless at rest

    @pytest.mark.timeout(20)
    def test_track_fault_during_a_move_raises_with_its_code_and_latches(self, track_and_fake):
        track, fake = track_and_fake
        if fake is None:
            pytest.skip("fault injection needs the fake")
        track.enable()
        fired: list[float] = []

        def fault() -> None:
            fired.append(time.monotonic())
            fake.inject("track_fault", code=0x2310)

        timer = threading.Timer(0.3, fault)
        timer.start()
        try:
            with pytest.raises(TrackFault) as info:
                track.move_to(LIMIT_MAX_M, speed_m_s=0.3, timeout_s=10)
        finally:
            timer.cancel()
        assert info.value.code == 0x2310
        assert time.monotonic() - fired[0] < REQUEST_TIMEOUT_S  # noticed at the next status poll
        st = track.status()
        assert st.fault and st.fault_code == 0x2310 and not st.enabled and not st.moving
        assert START_M < st.position_m < LIMIT_MAX_M - 0.2
        fake.clear_faults()
        assert track.status().fault  # latched until the driver resets it
        with pytest.raises(TrackFault):
            track.enable()
        track.reset_fault()
        track.enable()
        track.move_to(START_M, speed_m_s=0.5, timeout_s=10)
        assert abs(track.position_m() - START_M) <= POSITION_TOL_M

    @pytest.mark.timeout(20)
    def test_modbus_exception_surfaces_with_its_code(self, track_and_fake):
        track, fake = track_and_fake
        if fake is None:
            pytest.skip("fault injection needs the fake")
        fake.inject("modbus_exception", code=4)
        t0 = time.monotonic()
        with pytest.raises(ModbusError) as info:
            track.status()
        assert time.monotonic() - t0 < REQUEST_TIMEOUT_S
        assert getattr(info.value, "code", None) == 4
        with pytest.raises(ModbusError):
            track.enable()
        fake.clear_faults()
        track.enable()
        assert track.status().enabled

    @pytest.mark.timeout(20)
    def test_no_answer_times_out_within_the_request_timeout(self, track_and_fake):
        track, fake = track_and_fake
        if fake is None:
            pytest.skip("fault injection needs the fake")
        fake.inject("no_answer")
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout):
            track.position_m()
        assert REQUEST_TIMEOUT_S * 0.9 <= time.monotonic() - t0 < REQUEST_TIMEOUT_S + 1.0
        with pytest.raises(ConnectionLost):  # the connection is given up until connect()
            track.status()
        fake.clear_faults()
        track.connect()
        assert track.position_m() == START_M

    @pytest.mark.timeout(20)
    def test_dropped_connection_raises_then_reconnects(self, track_and_fake):
        track, fake = track_and_fake
        if fake is None:
            pytest.skip("fault injection needs the fake")
        track.enable()
        fake.inject("drop_connection")
        t0 = time.monotonic()
        with pytest.raises(ConnectionLost):
            track.status()
        assert time.monotonic() - t0 < REQUEST_TIMEOUT_S + 0.5
        with pytest.raises(ConnectionLost):  # refused while the fault is on
            track.connect()
        fake.clear_faults()
        track.connect()
        st = track.status()
        assert st.enabled and st.position_m == START_M  # the drive kept its state
        track.move_to(START_M + 0.05, speed_m_s=0.3, timeout_s=10)
        assert abs(track.position_m() - (START_M + 0.05)) <= POSITION_TOL_M
