"""The fake track drive in a process of its own (sim_fakes/fake_track_process.py): the handle forwards to the fake."""

from __future__ import annotations

import os

import pytest

from drivers.errors import TrackFault
from drivers.track import ModbusTrack
from sim_fakes.fake_track_process import FakeTrackProcess
from sim_fakes.faults import FaultInjectable


@pytest.mark.timeout(60)
def test_the_fake_runs_in_its_own_process_and_its_handle_answers_for_it() -> None:
    with FakeTrackProcess(soft_limits_m=(0.0, 1.0), counts_per_m=50_000, start_position_m=0.25) as fake:
        assert isinstance(fake, FaultInjectable) and fake.port > 0 and fake.counts_per_m == 50_000
        assert fake._proc is not None and fake._proc.pid != os.getpid()
        assert fake.position_m() == 0.25
        track = ModbusTrack("127.0.0.1", port=fake.port, counts_per_m=fake.counts_per_m, timeout_s=2.0)
        track.connect()
        try:
            track.enable(True)
            track.move_to(0.30, speed_m_s=0.2)
            assert fake.position_m() == pytest.approx(0.30, abs=0.0002)
            [move] = fake.moves()
            assert (move.target_counts, move.start_counts) == (15_000, 12_500.0)
            assert fake.snapshot()["enabled"] is True
            fake.inject("track_fault", code=0x7310)
            with pytest.raises(TrackFault) as fault:
                track.move_to(0.35, speed_m_s=0.2)
            assert fault.value.code == 0x7310
        finally:
            track.disconnect()
        with pytest.raises(ValueError, match="fake track does not support fault 'earthquake'"):
            fake.inject("earthquake")
        with pytest.raises(ValueError, match=r"a drive fault code is 1\.\.65535"):
            fake.inject("track_fault", code=0)
        with pytest.raises(AttributeError, match="no method '_halt'"):
            fake._call("_halt")
    assert fake._proc is None
    with pytest.raises(RuntimeError, match="not running"):
        fake.position_m()

