"""The controller state machine: happy path, the fault rule, acknowledgement, interruptions, and the generated doc."""

from __future__ import annotations

import dataclasses
import gc
import itertools
import logging
import threading
import weakref
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from transitions import MachineError

from cell.errors import SafetyViolation
from cell.journal import Journal
from cell.machine import (
    DOC_PATH,
    TRANSITIONS,
    CellActions,
    CellMachine,
    CellState,
    mermaid_state_diagram,
    state_machine_doc,
)
from drivers.errors import ConnectionLost, DeviceFault, MotionAborted

S = CellState


class Cell:
    """Recording fake actions: each call is logged with the machine state at that moment; ``fail`` makes one
    action raise; ``block`` makes weld wait until motion is stopped (then it raises MotionAborted)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, Any, CellState | None]] = []
        self.machine: CellMachine | None = None
        self.fail: dict[str, BaseException] = {}
        self.block_weld = False
        self.weld_started = threading.Event()
        self.stopped = threading.Event()

    def _call(self, name: str, arg: Any = None) -> None:
        state = self.machine.state if self.machine is not None else None
        self.calls.append((name, arg, state))
        if name in self.fail:
            raise self.fail[name]

    def names(self) -> list[str]:
        return [c[0] for c in self.calls]

    def weld(self) -> None:
        self._call("weld")
        if self.block_weld:
            self.weld_started.set()
            if not self.stopped.wait(timeout=10):
                raise AssertionError("weld was never stopped")
            raise MotionAborted("stop requested: remaining poses dropped")

    def stop_motion(self) -> None:
        self._call("stop_motion")
        self.stopped.set()

    def actions(self) -> CellActions:
        return CellActions(
            stop_motion=self.stop_motion,
            arc_off=lambda: self._call("arc_off"),
            home=lambda: self._call("home"),
            move_to_capture=lambda i: self._call("move_to_capture", i),
            capture=lambda i: self._call("capture", i),
            detect=lambda: self._call("detect"),
            plan=lambda: self._call("plan"),
            weld=self.weld,
            retract=lambda: self._call("retract"),
            calibrate=lambda: self._call("calibrate"),
            reset_faults=lambda: self._call("reset_faults"),
        )


@pytest.fixture
def journal(tmp_path: Path) -> Any:
    with Journal(tmp_path / "journal.sqlite") as j:
        yield j


def make(journal: Journal | None = None) -> tuple[CellMachine, Cell]:
    cell = Cell()
    machine = CellMachine(cell.actions(), journal=journal)
    cell.machine = machine
    return machine, cell


def transitions_of(journal: Journal, job: int) -> list[tuple[str, str]]:
    return [(e.from_state, e.to_state) for e in journal.events(job)]


# ------------------------------------------------------------------------------------------------ happy path
def test_happy_path_visits_the_states_in_order_and_journals_each_change(
    journal: Journal, caplog: pytest.LogCaptureFixture
) -> None:
    machine, cell = make(journal)
    job = journal.submit("jobs/two-shots.toml")
    caplog.set_level(logging.INFO, logger="cell.machine")
    assert machine.state is S.IDLE
    assert machine.start_job(job, n_captures=2)
    seen = [machine.state]
    while machine.state is not S.AWAITING_APPROVAL:
        assert machine.advance()
        seen.append(machine.state)
    assert machine.approve("alice")
    seen.append(machine.state)
    while machine.state is not S.DONE:
        assert machine.advance()
        seen.append(machine.state)
    assert seen == [
        S.HOMING,
        S.MOVING_TO_CAPTURE,
        S.CAPTURING,
        S.MOVING_TO_CAPTURE,
        S.CAPTURING,
        S.DETECTING,
        S.PLANNING,
        S.AWAITING_APPROVAL,
        S.WELDING,
        S.RETRACTING,
        S.DONE,
    ]
    # each side effect ran while the machine was in the state it belongs to, with the capture index
    assert cell.calls == [
        ("home", None, S.HOMING),
        ("move_to_capture", 0, S.MOVING_TO_CAPTURE),
        ("capture", 0, S.CAPTURING),
        ("move_to_capture", 1, S.MOVING_TO_CAPTURE),
        ("capture", 1, S.CAPTURING),
        ("detect", None, S.DETECTING),
        ("plan", None, S.PLANNING),
        ("weld", None, S.WELDING),
        ("retract", None, S.RETRACTING),
    ]
    states = ["idle"] + [s.value for s in seen]
    assert transitions_of(journal, job) == list(itertools.pairwise(states))
    reasons = [e.reason for e in journal.events(job)]
    assert reasons[0] == "job started" and "path approved by alice" in reasons
    rec = journal.job(job)
    assert rec.state == "done" and rec.started_s is not None and rec.finished_s is not None and rec.error is None
    assert f"job {job}: idle -> homing (job started)" in caplog.messages
    assert f"job {job}: retracting -> done (retracting finished)" in caplog.messages
    assert all(r.levelno == logging.INFO for r in caplog.records if " -> " in r.getMessage())
    # a new job may start from done; the machine no longer belongs to the old one
    assert machine.job_id is None
    second = journal.submit("jobs/again.toml")
    assert machine.start_job(second)
    assert transitions_of(journal, second) == [("done", "homing")]


def test_calibration_and_rejection_run_between_jobs(journal: Journal) -> None:
    machine, cell = make(journal)
    assert machine.calibrate() and machine.state is S.CALIBRATING
    assert machine.advance() and machine.state is S.IDLE
    assert cell.names() == ["calibrate"]
    assert [(e.from_state, e.to_state) for e in journal.events(None)] == [
        ("idle", "calibrating"),
        ("calibrating", "idle"),
    ]
    job = journal.submit("j.toml")
    machine.start_job(job)
    for _ in range(5):
        machine.advance()
    assert machine.state is S.AWAITING_APPROVAL
    with pytest.raises(ValueError, match="operator's name is required"):
        machine.reject("  ")
    assert machine.reject("bob") and machine.state is S.IDLE
    assert "weld" not in cell.names()
    rec = journal.job(job)
    assert rec.state == "cancelled" and rec.error == "path rejected by bob"


# ------------------------------------------------------------------------------------------------ the fault rule
def test_a_failing_side_effect_leaves_the_state_unchanged_then_lands_in_fault_with_arc_off_and_motion_stopped(
    journal: Journal,
) -> None:
    machine, cell = make(journal)
    cell.fail["home"] = DeviceFault("servo alarm", code=1042)
    job = journal.submit("j.toml")
    machine.start_job(job)
    assert machine.advance() is False
    assert machine.state is S.FAULT
    # homing failed while in homing; the stop and arc off happened before the state left homing
    assert cell.calls == [("home", None, S.HOMING), ("stop_motion", None, S.HOMING), ("arc_off", None, S.HOMING)]
    assert machine.fault_reason == "advance failed in homing: DeviceFault: servo alarm (code 1042)"
    assert isinstance(machine.last_error, DeviceFault)
    # never recorded as if homing had finished
    assert transitions_of(journal, job) == [("idle", "homing"), ("homing", "fault")]
    rec = journal.job(job)
    assert rec.state == "failed" and rec.error == machine.fault_reason


def test_the_stored_error_of_a_fault_keeps_no_frame_and_no_capture_of_the_job_alive() -> None:
    # a capture that fails while handling another error: two chained exceptions, each with a traceback whose frames
    # hold the job's arrays (as a detection's do)
    frames: list[weakref.ref[np.ndarray]] = []
    machine, cell = make()

    def capture(index: int) -> None:
        pixels = np.zeros((480, 640, 3))
        frames.append(weakref.ref(pixels))
        try:
            cloud = np.ones((480 * 640, 3))
            frames.append(weakref.ref(cloud))
            raise OSError("socket closed")
        except OSError as err:
            raise ConnectionLost("camera link lost during the frame") from err

    machine.actions = dataclasses.replace(cell.actions(), capture=capture)
    machine.start_job(1)
    while machine.state is not S.FAULT:
        machine.advance()
    gc.collect()
    err = machine.last_error
    assert isinstance(err, ConnectionLost) and str(err) == "camera link lost during the frame"
    assert isinstance(err.__cause__, OSError) and str(err.__cause__) == "socket closed"  # the chain stays readable
    assert [ref() is None for ref in frames] == [True, True]
    assert (err.__traceback__, err.__cause__.__traceback__) == (None, None)
    machine.acknowledge("op")
    machine.start_job(2)
    assert machine.last_error is None  # the next job starts without the last one's error


def test_a_safety_refusal_in_planning_is_a_fault_with_its_reason(journal: Journal) -> None:
    machine, cell = make(journal)
    cell.fail["plan"] = SafetyViolation("pass 1 (seam 3) approach: speed 0.3000 m/s outside (0, 0.2500] m/s")
    machine.start_job(journal.submit("j.toml"))
    while machine.state not in (S.FAULT, S.AWAITING_APPROVAL):
        machine.advance()
    assert machine.state is S.FAULT
    assert (
        machine.fault_reason is not None and "SafetyViolation: pass 1 (seam 3) approach: speed" in machine.fault_reason
    )


def test_stop_failures_still_land_in_fault_and_are_reported(journal: Journal) -> None:
    machine, cell = make(journal)
    cell.fail["weld"] = DeviceFault("arc lost")
    cell.fail["arc_off"] = ConnectionLost("robot gone")
    machine.start_job(journal.submit("j.toml"))
    for _ in range(5):
        machine.advance()
    machine.approve("alice")
    assert machine.advance() is False
    assert machine.state is S.FAULT
    assert cell.names()[-2:] == ["stop_motion", "arc_off"]
    assert machine.fault_reason == (
        "advance failed in welding: DeviceFault: arc lost; stopping failed: arc_off: ConnectionLost: robot gone"
    )


def test_a_journal_failure_is_a_fault(tmp_path: Path) -> None:
    class FailingJournal(Journal):
        def record_state_change(
            self, job_id: int | None, from_state: str, to_state: str, reason: str, **kw: Any
        ) -> None:
            if to_state == "capturing":
                raise OSError("disk full")
            super().record_state_change(job_id, from_state, to_state, reason, **kw)

    with FailingJournal(tmp_path / "j.sqlite") as j:
        machine, cell = make(j)
        job = j.submit("j.toml")
        machine.start_job(job)
        machine.advance()
        assert machine.advance() is False
        assert machine.state is S.FAULT and cell.names()[-2:] == ["stop_motion", "arc_off"]
        assert machine.fault_reason == "advance failed in capturing: OSError: disk full"
        assert transitions_of(j, job) == [("idle", "homing"), ("homing", "moving_to_capture"), ("capturing", "fault")]


def test_keyboard_interrupt_stops_safely_then_propagates() -> None:
    machine, cell = make()
    cell.fail["home"] = KeyboardInterrupt()
    machine.start_job(1)
    with pytest.raises(KeyboardInterrupt):
        machine.advance()
    assert machine.state is S.FAULT and cell.names() == ["home", "stop_motion", "arc_off"]


# ------------------------------------------------------------------------------------------------ leaving fault
def test_fault_needs_an_operators_acknowledgement(journal: Journal) -> None:
    machine, cell = make(journal)
    cell.fail["detect"] = RuntimeError("detector crashed")
    job = journal.submit("j.toml")
    machine.start_job(job)
    for _ in range(4):
        machine.advance()
    assert machine.state is S.FAULT
    for trigger in (machine.advance, machine.resume, machine.calibrate, lambda: machine.start_job(job)):
        with pytest.raises(MachineError):
            trigger()
        assert machine.state is S.FAULT
    with pytest.raises(ValueError, match="operator's name is required"):
        machine.acknowledge("")
    assert machine.state is S.FAULT
    assert machine.acknowledge("carol") is True
    assert machine.state is S.IDLE
    assert cell.names()[-1] == "reset_faults"
    last = journal.events(job)[-1]
    assert (last.from_state, last.to_state, last.reason) == ("fault", "idle", "fault acknowledged by carol")
    assert journal.job(job).state == "failed"  # acknowledging does not rewrite the job's outcome


def test_a_failing_reset_on_acknowledgement_stays_in_fault() -> None:
    machine, cell = make()
    machine.fault_now("e-stop pressed")
    assert machine.state is S.FAULT
    cell.fail["reset_faults"] = DeviceFault("e-stop still engaged")
    assert machine.acknowledge("dave") is False
    assert machine.state is S.FAULT
    assert machine.fault_reason == "acknowledge failed in fault: DeviceFault: e-stop still engaged"


def test_an_invalid_trigger_is_the_callers_mistake_not_a_fault() -> None:
    machine, cell = make()
    with pytest.raises(MachineError):
        machine.advance()
    with pytest.raises(MachineError):
        machine.approve("alice")
    assert machine.state is S.IDLE and cell.calls == []


def test_a_fault_that_lands_between_choosing_a_trigger_and_firing_it_wins(journal: Journal) -> None:
    """The job runner reads the state, then fires the trigger for it; a watchdog's fault_now can land in between.
    With the state it chose from (``seen``) the trigger is not fired: the fault stands, no MachineError."""
    machine, cell = make(journal)
    job = journal.submit("j.toml")
    machine.start_job(job)
    seen = machine.state  # the runner chose advance for homing...
    machine.fault_now("watchdog: robot: protective stop")  # ...and the watchdog's fault landed before it fired
    assert machine.advance(seen=seen) is False
    assert machine.state is S.FAULT
    for trigger in (machine.end_dry_run, lambda seen: machine.approve("ann", seen=seen)):
        assert trigger(seen=S.AWAITING_APPROVAL) is False  # the same for the triggers of awaiting_approval
    assert machine.fault_reason == "watchdog: robot: protective stop"
    assert "home" not in cell.names()  # homing's work never ran
    record = journal.job(job)
    assert (record.state, record.error) == ("failed", "watchdog: robot: protective stop")
    assert transitions_of(journal, job) == [("idle", "homing"), ("homing", "fault")]
    with pytest.raises(MachineError):  # without seen it is still the caller's mistake
        machine.advance()


# ------------------------------------------------------------------------------------------------ interruptions
@pytest.mark.timeout(20)
def test_fault_now_from_another_thread_stops_a_blocking_weld(journal: Journal) -> None:
    machine, cell = make(journal)
    cell.block_weld = True
    job = journal.submit("j.toml")
    machine.start_job(job)
    for _ in range(5):
        machine.advance()
    machine.approve("alice")
    result: list[bool] = []
    runner = threading.Thread(target=lambda: result.append(machine.advance()))
    runner.start()
    assert cell.weld_started.wait(timeout=10)
    machine.fault_now("protective stop: collision on joint 3")
    runner.join(timeout=10)
    assert not runner.is_alive() and result == [False]
    assert machine.state is S.FAULT
    assert machine.fault_reason is not None
    assert machine.fault_reason.startswith("protective stop: collision on joint 3 (then advance failed in welding")
    assert "arc_off" in cell.names()
    assert transitions_of(journal, job)[-1] == ("welding", "fault")


@pytest.mark.timeout(20)
def test_pause_from_another_thread_then_resume_or_abort(journal: Journal) -> None:
    machine, cell = make(journal)
    cell.block_weld = True
    job = journal.submit("j.toml")
    machine.start_job(job)
    for _ in range(5):
        machine.advance()
    machine.approve("alice")
    runner = threading.Thread(target=machine.advance)
    runner.start()
    assert cell.weld_started.wait(timeout=10)
    machine.request_pause("operator pressed hold")
    runner.join(timeout=10)
    assert not runner.is_alive()
    assert machine.state is S.PAUSED and machine.paused_from is S.WELDING
    assert transitions_of(journal, job)[-1] == ("welding", "paused")
    assert journal.events(job)[-1].reason == "operator pressed hold"
    assert "arc_off" in cell.names()
    assert machine.resume() and machine.state is S.WELDING
    cell.block_weld = False
    assert machine.advance() and machine.state is S.RETRACTING
    # pause again (not blocking this time), and give up: retract, and the job ends cancelled
    machine.request_pause()
    assert machine.state is S.PAUSED and machine.paused_from is S.RETRACTING
    assert machine.abort("erin") and machine.state is S.RETRACTING
    assert machine.advance() and machine.state is S.DONE
    rec = journal.job(job)
    assert rec.state == "cancelled" and rec.error == "aborted by the operator"


def test_a_pending_interruption_wins_over_the_next_trigger() -> None:
    machine, cell = make()
    machine.start_job(1)
    # a pause that arrives while the runner is between triggers is applied before its next advance
    machine._interrupt = ("pause", "hold")  # as set by request_pause just before it takes the lock
    assert machine.advance() is False
    assert machine.state is S.PAUSED and "home" not in cell.names()


# ------------------------------------------------------------------------------------------------ the diagram
def test_the_state_machine_doc_in_the_repo_is_generated_from_the_table() -> None:
    assert DOC_PATH.read_text(encoding="utf-8") == state_machine_doc(), (
        "docs/state-machine.md is stale: run `python -m cell.machine`"
    )


def test_the_diagram_has_one_edge_per_transition_of_the_table() -> None:
    text = mermaid_state_diagram()
    edges = [line.strip() for line in text.splitlines() if "-->" in line and "[*]" not in line]
    expected = 0
    for row in TRANSITIONS:
        sources = row["source"] if isinstance(row["source"], list) else [row["source"]]
        expected += sum(1 for s in sources if s != "*")
    assert len(edges) == expected
    assert "capturing --> moving_to_capture : advance [more_captures] / capture" in edges
    assert "fault --> idle : acknowledge [operator_named] / reset_faults" in edges
    assert "fail / safe_stop: from every state" in text
    for edge in edges:  # Mermaid reads a label as ":" followed by anything but ":", ";" and newline
        label = edge.split(" : ", 1)[1]
        assert not set(label) & set(":;#%"), edge
    assert {s.value for s in CellState} <= set(" ".join(edges).split()) | {"fault"}
    # a changed table changes the diagram
    extra = [*TRANSITIONS, {"trigger": "skip", "source": S.IDLE, "dest": S.DONE}]
    assert "idle --> done : skip" in mermaid_state_diagram(extra)
    assert state_machine_doc(extra) != state_machine_doc()
