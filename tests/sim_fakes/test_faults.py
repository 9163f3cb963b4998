"""The fault-injection switch (sim_fakes/faults.py): every fake's handle is a FaultInjectable, with the names the
module documents, shared where they mean the same."""

from __future__ import annotations

from typing import Any

import pytest

import sim_fakes.faults
from sim_fakes.fake_camera import FakeCamera
from sim_fakes.fake_fanuc import FakeFanucController
from sim_fakes.fake_fanuc_process import FakeFanucProcess
from sim_fakes.fake_track import FakeTrack
from sim_fakes.fake_track_process import FakeTrackProcess
from sim_fakes.fake_ur import FakeURController
from sim_fakes.faults import FaultInjectable

HANDLES = {
    "ur": FakeURController,
    "fanuc": FakeFanucController,
    "fanuc process": FakeFanucProcess,
    "track": FakeTrack,
    "track process": FakeTrackProcess,
    "camera": FakeCamera,
}


def test_every_fakes_handle_has_the_faults_the_module_documents() -> None:
    faults = {name: handle.supported_faults for name, handle in HANDLES.items()}
    assert faults == {
        "ur": {"drop_connection", "no_answer", "protective_stop", "emergency_stop"},
        "fanuc": {
            *("drop_connection", "no_answer", "protective_stop", "emergency_stop"),
            *("rmi_error", "system_fault", "alarm"),
        },
        "fanuc process": faults["fanuc"],  # the process handle forwards to the same fake
        "track": {"drop_connection", "no_answer", "modbus_exception", "track_fault"},
        "track process": faults["track"],
        "camera": {"frame_timeout", "corrupt_frame", "drop_connection"},
    }
    doc = sim_fakes.faults.__doc__ or ""
    every = set().union(*faults.values())
    assert sorted(f for f in every if f'``"{f}"``' not in doc) == []  # each name the fakes know is documented
    # a shared name is one idea: the drop and the hang are the network faults every networked device has
    assert set.intersection(*(set(f) for f in faults.values())) == {"drop_connection"}
    hang = {"ur", "fanuc", "fanuc process", "track", "track process"}
    assert {n for n, f in faults.items() if "no_answer" in f} == hang


def test_the_protocol_is_checked_at_run_time_on_what_a_handle_has() -> None:
    class Complete:
        supported_faults = frozenset({"no_answer"})

        def inject(self, fault: str, **params: Any) -> None:
            pass

        def clear_faults(self) -> None:
            pass

    class NoClear:
        supported_faults = frozenset({"no_answer"})

        def inject(self, fault: str, **params: Any) -> None:
            pass

    assert isinstance(Complete(), FaultInjectable)
    assert not isinstance(NoClear(), FaultInjectable)
    assert not isinstance(object(), FaultInjectable)


@pytest.mark.timeout(20)
def test_a_started_fake_refuses_a_fault_it_does_not_know_and_names_the_ones_it_does() -> None:
    with FakeTrack() as track:
        assert isinstance(track, FaultInjectable)
        with pytest.raises(
            ValueError,
            match=r"fake track does not support fault 'protective_stop'; supported: "
            r"\['drop_connection', 'modbus_exception', 'no_answer', 'track_fault'\]",
        ):
            track.inject("protective_stop")
        track.clear_faults()  # nothing on: clearing is harmless
