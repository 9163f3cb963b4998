"""The cell controller's state machine, declared as data and run by ``transitions``.

States are :class:`CellState`; :data:`TRANSITIONS` is the whole table (a list of dicts in ``transitions``'
format, with callback and condition *names*); :func:`state_machine_doc` turns that same table into the Mermaid
diagram in docs/state-machine.md (``python -m cell.machine`` rewrites it; a test fails when it is stale).

The callback rule:

- ``conditions``/``unless``: pure predicates on the machine's own data; no device, no side effect, never raise.
- ``before``: every side effect that can fail (device commands, detection, planning and safety validation). It
  runs while the machine is still in the *source* state, so the state only changes once the work succeeded.
  An activity state (homing, welding...) is therefore left by ``advance``, whose ``before`` does that state's
  work: during the work the machine says what it is doing.
- ``prepare``: not used (it runs before the conditions, on every attempt; nothing here needs it).
- after every state change: the journal entry and an INFO log line with the job id (recording what happened).

The fault rule: any exception raised by a callback (``MachineError``, a trigger that is not allowed in the current
state, excepted: that is the caller's mistake and is raised to it) leaves the state as it was and is then handed
to ``transitions``' ``on_exception`` hook, which fires ``fail``: its ``before`` stops the motion and turns the arc
off through the injected :attr:`CellActions.stop_motion` and :attr:`CellActions.arc_off` (both attempted at once,
each whatever the other does, and waited for at most :data:`STOP_ATTEMPT_S`: a robot that does not answer must
not keep the cell out of ``fault``; their failures are added to the reason), then the machine enters ``fault``.
A device fault noticed outside a callback (a watchdog, an e-stop input) calls :meth:`CellMachine.fault_now`, which
stops motion and the arc immediately, from any thread, and then takes the machine to ``fault``. ``fault`` is
left only by :meth:`CellMachine.acknowledge` with an operator's name.

Threads: triggers are serialised by one re-entrant lock (:attr:`CellMachine.lock`). :meth:`fault_now` and
:meth:`request_pause` act on the devices *before* taking the lock, so they interrupt a blocking activity
(the activity's driver call then fails with ``MotionAborted``, which lands in ``paused`` for a pause request,
in ``fault`` otherwise), and a pending interruption is applied before any other trigger runs.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from transitions import EventData, Machine, MachineError

from cell.journal import Journal
from drivers.errors import MotionAborted

logger = logging.getLogger(__name__)

DOC_PATH = Path(__file__).resolve().parents[1] / "docs" / "state-machine.md"


class CellState(StrEnum):
    IDLE = "idle"
    HOMING = "homing"
    MOVING_TO_CAPTURE = "moving_to_capture"
    CAPTURING = "capturing"
    DETECTING = "detecting"
    PLANNING = "planning"
    AWAITING_APPROVAL = "awaiting_approval"
    WELDING = "welding"
    RETRACTING = "retracting"
    DONE = "done"
    PAUSED = "paused"
    CALIBRATING = "calibrating"
    FAULT = "fault"


S = CellState

PAUSABLE = (S.HOMING, S.MOVING_TO_CAPTURE, S.WELDING, S.RETRACTING)
"""States with motion that an operator may pause (and resume into)."""

TRANSITIONS: list[dict[str, Any]] = [
    # a job: home, capture at each capture position, detect, plan + validate, wait for the operator, weld, retract
    {"trigger": "start_job", "source": [S.IDLE, S.DONE], "dest": S.HOMING, "before": "begin_job"},
    {"trigger": "advance", "source": S.HOMING, "dest": S.MOVING_TO_CAPTURE, "before": "home"},
    {"trigger": "advance", "source": S.MOVING_TO_CAPTURE, "dest": S.CAPTURING, "before": "move_to_capture"},
    {
        "trigger": "advance",
        "source": S.CAPTURING,
        "dest": S.MOVING_TO_CAPTURE,
        "conditions": "more_captures",
        "before": "capture",
    },
    {"trigger": "advance", "source": S.CAPTURING, "dest": S.DETECTING, "unless": "more_captures", "before": "capture"},
    {"trigger": "advance", "source": S.DETECTING, "dest": S.PLANNING, "before": "detect"},
    {"trigger": "advance", "source": S.PLANNING, "dest": S.AWAITING_APPROVAL, "before": "plan"},
    {"trigger": "approve", "source": S.AWAITING_APPROVAL, "dest": S.WELDING, "conditions": "operator_named"},
    {"trigger": "reject", "source": S.AWAITING_APPROVAL, "dest": S.IDLE, "conditions": "operator_named"},
    {"trigger": "end_dry_run", "source": S.AWAITING_APPROVAL, "dest": S.IDLE, "conditions": "dry_run"},
    {"trigger": "advance", "source": S.WELDING, "dest": S.RETRACTING, "before": "weld"},
    {"trigger": "advance", "source": S.RETRACTING, "dest": S.DONE, "before": "retract"},
    # an operator's pause stops motion and the arc; resume returns to the state that was paused; abort retracts
    {"trigger": "pause", "source": list(PAUSABLE), "dest": S.PAUSED, "before": "halt"},
    *[{"trigger": "resume", "source": S.PAUSED, "dest": state, "conditions": "paused_from_dest"} for state in PAUSABLE],
    {
        "trigger": "abort",
        "source": S.PAUSED,
        "dest": S.RETRACTING,
        "conditions": "operator_named",
        "before": "give_up",
    },
    # hand-eye calibration between jobs
    {"trigger": "calibrate", "source": [S.IDLE, S.DONE], "dest": S.CALIBRATING},
    {"trigger": "advance", "source": S.CALIBRATING, "dest": S.IDLE, "before": "run_calibration"},
    # faults: from anywhere; only an operator's acknowledgement leaves
    {"trigger": "fail", "source": "*", "dest": S.FAULT, "before": "safe_stop"},
    {
        "trigger": "acknowledge",
        "source": S.FAULT,
        "dest": S.IDLE,
        "conditions": "operator_named",
        "before": "reset_faults",
    },
]


@dataclass(frozen=True)
class CellActions:
    """What the machine makes happen; the job runner supplies them (devices, perception, planning, safety).

    Each blocks until done and raises on failure. ``move_to_capture``/``capture`` take the capture index
    (0-based). ``plan`` plans and validates (raising SafetyViolation to refuse). ``weld`` welds the approved path
    (resuming where it stopped after a pause is the runner's business). ``stop_motion`` and ``arc_off`` must be
    callable from any thread and be harmless when nothing moves or the arc is off. ``reset_faults``: clears
    latched controller faults on acknowledgement (None: nothing to clear).
    """

    stop_motion: Callable[[], None]
    arc_off: Callable[[], None]
    home: Callable[[], None]
    move_to_capture: Callable[[int], None]
    capture: Callable[[int], None]
    detect: Callable[[], None]
    plan: Callable[[], None]
    weld: Callable[[], None]
    retract: Callable[[], None]
    calibrate: Callable[[], None]
    reset_faults: Callable[[], None] | None = None


class CellMachine:
    """The cell's controller state machine (see the module docstring for the rules).

    ``actions``: the injected side effects; ``journal``: where every state change goes (None: logging only).
    Triggers: :meth:`start_job`, :meth:`advance`, :meth:`approve`, :meth:`reject`, :meth:`request_pause`,
    :meth:`resume`, :meth:`abort`, :meth:`calibrate`, :meth:`fault_now`, :meth:`acknowledge`. Each returns
    True when the state changed; an exception in a side effect returns False with the machine in ``fault``
    (:attr:`fault_reason` says why); a trigger not allowed in the current state raises ``MachineError``.
    """

    def __init__(self, actions: CellActions, *, journal: Journal | None = None, name: str = "cell") -> None:
        self.actions = actions
        self.journal = journal
        self.name = name
        self.lock = threading.RLock()
        self.job_id: int | None = None
        self.n_captures = 0
        self.capture_index = 0
        self.fault_reason: str | None = None
        self.last_error: BaseException | None = None
        self.paused_from: CellState | None = None
        self.dry_run = False
        self._aborted = False
        self._interrupt: tuple[str, str] | None = None  # ("pause" | "fault", reason)
        self._interrupt_lock = threading.Lock()
        self._stopped = threading.Event()  # clear while fault_now/pause_now is attempting the stop and arc-off
        self._stopped.set()
        self._model = _Model()
        self._machine = Machine(
            model=self._model,
            states=CellState,
            transitions=self._resolved_table(),
            initial=S.IDLE,
            send_event=True,
            auto_transitions=False,
            after_state_change=[self._record],
            on_exception=[self._on_exception],
            name=name,
        )

    def _resolved_table(self) -> list[dict[str, Any]]:
        """The table with callback and condition names bound to this instance's ``_cb_<name>`` methods."""
        out = []
        for row in TRANSITIONS:
            resolved = dict(row)
            for key in ("before", "conditions", "unless", "prepare", "after"):
                if key in row:
                    names = row[key] if isinstance(row[key], list) else [row[key]]
                    resolved[key] = [getattr(self, f"_cb_{n}") for n in names]
            out.append(resolved)
        return out

    # ------------------------------------------------------------------------------------------ state
    @property
    def state(self) -> CellState:
        return CellState(self._model.state)

    def _fire(self, trigger: str, *, seen: CellState | None = None, **kwargs: Any) -> bool:
        """Fire ``trigger`` under the lock. ``seen``: the state the caller decided on; when another thread (a
        watchdog's :meth:`fault_now`, a pause) changed it since, that change won and the trigger is not fired
        (False), instead of raising ``MachineError`` for a trigger the new state does not allow."""
        with self.lock:
            if self._interrupt is not None and trigger not in ("fail", "pause"):
                self._apply_interrupt()
                return False
            if seen is not None and self.state is not seen:
                logger.info("%s: %s meant for %s not fired: the cell is %s", self.name, trigger, seen, self.state)
                return False
            return bool(self._model.trigger(trigger, **kwargs))

    # ------------------------------------------------------------------------------------------ triggers
    def start_job(self, job_id: int, *, n_captures: int = 1, dry_run: bool = False) -> bool:
        """Start job ``job_id`` (already submitted to the journal) with ``n_captures`` capture positions."""
        if isinstance(n_captures, bool) or not isinstance(n_captures, int) or n_captures < 1:
            raise ValueError(f"n_captures must be an integer >= 1, got {n_captures!r}")
        return self._fire(
            "start_job", job_id=int(job_id), n_captures=n_captures, dry_run=bool(dry_run), reason="job started"
        )

    def advance(self, *, seen: CellState | None = None) -> bool:
        """Do the current state's work and move on (homing, moving_to_capture, capturing, detecting, planning,
        welding, retracting, calibrating). ``seen`` (the job runner's): only from that state (see :meth:`_fire`)."""
        state = seen if seen is not None else self.state
        return self._fire("advance", seen=seen, reason=f"{state.value} finished")

    def approve(self, operator: str, *, seen: CellState | None = None) -> bool:
        """The operator approves the planned path: welding starts with the next :meth:`advance`."""
        reason = f"path approved by {operator.strip()}"
        return self._fire("approve", seen=seen, operator=_operator(operator), reason=reason)

    def reject(self, operator: str, *, seen: CellState | None = None) -> bool:
        """The operator refuses the planned path: the job is cancelled, nothing moves."""
        reason = f"path rejected by {operator.strip()}"
        return self._fire("reject", seen=seen, operator=_operator(operator), reason=reason)

    def end_dry_run(self, *, seen: CellState | None = None) -> bool:
        """A dry run's path is planned and validated: the job ends (journaled ``dry_run``), nothing moved."""
        return self._fire(
            "end_dry_run", seen=seen, reason="dry run: path planned and validated, nothing moved or welded"
        )

    def resume(self) -> bool:
        """Back to the state that was paused."""
        return self._fire("resume", reason="resumed")

    def abort(self, operator: str) -> bool:
        """From ``paused``: give the job up; the next :meth:`advance` retracts and the job ends cancelled."""
        return self._fire("abort", operator=_operator(operator), reason=f"aborted by {operator.strip()}")

    def calibrate(self) -> bool:
        return self._fire("calibrate", reason="calibration requested")

    def acknowledge(self, operator: str) -> bool:
        """Leave ``fault`` for ``idle``: an operator (named) has seen the fault and cleared its cause."""
        return self._fire("acknowledge", operator=_operator(operator), reason=f"fault acknowledged by {operator}")

    def request_pause(self, reason: str = "pause requested") -> None:
        """From any thread: stop motion and the arc now, then enter ``paused`` (once the activity returns)."""
        self._interrupt_now("pause", reason)

    def pending_interruption(self) -> str | None:
        """The reason of a pause or fault requested from another thread and not applied yet (the activity running
        holds the lock), or None: an activity checks it at each motion boundary and stops there."""
        with self._interrupt_lock:
            return None if self._interrupt is None else f"{self._interrupt[0]}: {self._interrupt[1]}"

    def fault_now(self, reason: str) -> None:
        """From any thread (a watchdog, an e-stop input): stop motion and the arc now, then enter ``fault``."""
        self._interrupt_now("fault", reason)

    def _interrupt_now(self, kind: str, reason: str) -> None:
        self._stopped.clear()
        with self._interrupt_lock:
            if self._interrupt is None or kind == "fault":  # a fault outranks a pause
                self._interrupt = (kind, reason)
        try:
            problems = _stop_everything(self.actions)
            if problems:
                with self._interrupt_lock:  # a pause that could not stop is a fault
                    self._interrupt = ("fault", f"{reason}; stopping failed: {'; '.join(problems)}")
        finally:
            self._stopped.set()
        with self.lock:  # waits for a running activity, which the stop above makes return
            self._apply_interrupt()

    def _apply_interrupt(self) -> None:
        with self._interrupt_lock:
            pending, self._interrupt = self._interrupt, None
        if pending is None:
            return
        kind, reason = pending
        state = self.state
        if kind == "fault":
            if state is S.FAULT:
                logger.warning("%s: %s while already in fault (%s)", self.name, reason, self.fault_reason)
            else:  # stop and arc off were attempted by _interrupt_now already: not twice
                self._model.trigger("fail", reason=reason, stopped=True)
        elif state in PAUSABLE:
            self._model.trigger("pause", reason=reason)
        elif state is not S.PAUSED:
            logger.info("%s: %s ignored in state %s (nothing to pause)", self.name, reason, state.value)

    # ------------------------------------------------------------------------------------------ conditions
    def _cb_more_captures(self, event: EventData) -> bool:
        return self.capture_index + 1 < self.n_captures

    def _cb_dry_run(self, event: EventData) -> bool:
        return self.dry_run

    def _cb_operator_named(self, event: EventData) -> bool:
        return bool(str(event.kwargs.get("operator", "")).strip())

    def _cb_paused_from_dest(self, event: EventData) -> bool:
        assert event.transition is not None
        return self.paused_from is not None and self.paused_from.name == event.transition.dest

    # ------------------------------------------------------------------------------------------ side effects
    def _cb_begin_job(self, event: EventData) -> None:
        job_id = int(event.kwargs["job_id"])
        if self.journal is not None:
            job = self.journal.job(job_id)  # KeyError: never submitted
            if job.final:
                raise ValueError(f"job {job_id} is already {job.state}; submit it again to rerun it")
        self.job_id = job_id
        self.n_captures = int(event.kwargs["n_captures"])
        self.dry_run = bool(event.kwargs.get("dry_run", False))
        self.capture_index = 0
        self.paused_from = None
        self._aborted = False
        self.fault_reason = None
        self.last_error = None

    def _cb_home(self, event: EventData) -> None:
        self.actions.home()

    def _cb_move_to_capture(self, event: EventData) -> None:
        self.actions.move_to_capture(self.capture_index)

    def _cb_capture(self, event: EventData) -> None:
        self.actions.capture(self.capture_index)
        self.capture_index += 1

    def _cb_detect(self, event: EventData) -> None:
        self.actions.detect()

    def _cb_plan(self, event: EventData) -> None:
        self.actions.plan()

    def _cb_weld(self, event: EventData) -> None:
        self.actions.weld()

    def _cb_retract(self, event: EventData) -> None:
        self.actions.retract()

    def _cb_halt(self, event: EventData) -> None:
        self.actions.stop_motion()
        self.actions.arc_off()
        self.paused_from = self.state

    def _cb_give_up(self, event: EventData) -> None:
        self._aborted = True  # the job ends cancelled once the torch is retracted

    def _cb_run_calibration(self, event: EventData) -> None:
        self.actions.calibrate()

    def _cb_reset_faults(self, event: EventData) -> None:
        if self.actions.reset_faults is not None:
            self.actions.reset_faults()

    def _cb_safe_stop(self, event: EventData) -> None:
        """Stop motion, arc off: never raises (we are already failing); problems go into the reason."""
        reason = str(event.kwargs.get("reason", "fault"))
        problems = [] if event.kwargs.get("stopped") else _stop_everything(self.actions)
        if problems:
            reason += f"; stopping failed: {'; '.join(problems)}"
        self.fault_reason = reason
        event.kwargs["reason"] = reason

    # ------------------------------------------------------------------------------------------ recording
    def _record(self, event: EventData) -> None:
        """After every state change: journal (with the job's own state when it changes) and log at INFO."""
        assert event.transition is not None
        src = CellState[event.transition.source].value
        dst = self.state
        trigger = event.event.name if event.event is not None else "?"
        reason = str(event.kwargs.get("reason", trigger))
        job_state: str | None = None
        error: str | None = None
        if trigger == "start_job":
            job_state = "running"
        elif dst is S.DONE:
            job_state = "cancelled" if self._aborted else "done"
            if self._aborted:
                error = "aborted by the operator"
        elif trigger == "reject":
            job_state, error = "cancelled", reason
        elif trigger == "end_dry_run":
            job_state = "dry_run"
        elif dst is S.FAULT and self.job_id is not None:
            job_state, error = "failed", reason
        job_id = self.job_id
        logger.info("job %s: %s -> %s (%s)", job_id if job_id is not None else "-", src, dst.value, reason)
        if dst in (S.IDLE, S.DONE):
            self.job_id = None  # what follows (calibration, the next job) is not this job's
        if self.journal is None:
            return
        try:
            self.journal.record_state_change(
                job_id, src, dst.value, reason, job_state=job_state if job_id is not None else None, error=error
            )
        except Exception:
            if dst is not S.FAULT:
                raise  # -> on_exception -> fault: the cell must not go on without its journal
            logger.exception("%s: cannot journal the fault (%s)", self.name, reason)

    def _on_exception(self, event: EventData) -> None:
        err = event.error
        if isinstance(err, MachineError):
            raise err  # a trigger that is not allowed here: the caller's mistake, not a fault
        assert err is not None
        self.last_error = _without_frames(err)
        trigger = event.event.name if event.event is not None else "?"
        where = self.state.value
        reason = f"{trigger} failed in {where}: {type(err).__name__}: {err}"
        if trigger == "fail":  # failing to fail: force the state, never loop
            logger.critical("%s: the fault transition itself raised (%s); forcing fault", self.name, reason)
            _stop_everything(self.actions)
            self.fault_reason = reason
            self._machine.set_state(S.FAULT, model=self._model)
        else:
            with self._interrupt_lock:
                pending, self._interrupt = self._interrupt, None
            if pending is not None:
                # the interrupt's own stop attempt may still be under way: its outcome (a stop or arc-off that
                # failed) belongs in the reason, so wait for it (it gives up within STOP_ATTEMPT_S)
                self._stopped.wait(STOP_ATTEMPT_S + 0.5)
                with self._interrupt_lock:
                    later, self._interrupt = self._interrupt, None
                if later is not None and (later[0] == "fault" or pending[0] == "pause"):
                    pending = later
            if (
                pending is not None
                and pending[0] == "pause"
                and isinstance(err, MotionAborted)
                and self.state in PAUSABLE
            ):
                self._model.trigger("pause", reason=pending[1])
            else:
                if pending is not None:
                    reason = f"{pending[1]} (then {reason})"
                logger.error("%s: %s", self.name, reason)
                # a pending fault_now has attempted the stop and the arc-off already
                self._model.trigger("fail", reason=reason, stopped=pending is not None and pending[0] == "fault")
        if not isinstance(err, Exception):  # KeyboardInterrupt, SystemExit: stopped safely, now let them through
            raise err


class _Model:
    """The object ``transitions`` keeps the state on (and binds its trigger methods to)."""

    state: Any
    trigger: Callable[..., bool]


def _without_frames(err: BaseException) -> BaseException:
    """``err`` with its traceback and those of the exceptions chained to it (``__cause__``, ``__context__``) dropped.

    The machine keeps a fault's error (:attr:`CellMachine.last_error`, which the job report reads) after the job: its
    tracebacks would keep the job's frames alive, and their locals the job's captures and clouds (hundreds of MiB a
    job), chained faults more than one job's. The type and the message are what is read afterwards."""
    seen: set[int] = set()
    todo: list[BaseException] = [err]
    while todo:
        e = todo.pop()
        if id(e) in seen:
            continue
        seen.add(id(e))
        e.__traceback__ = None
        todo.extend(x for x in (e.__cause__, e.__context__) if x is not None)
    return err


def _operator(operator: str) -> str:
    name = str(operator).strip()
    if not name:
        raise ValueError("an operator's name is required")
    return name


STOP_ATTEMPT_S = 0.5
"""How long a fault waits for the stop and arc-off commands before it goes on without their answer. Both are
attempted at once, each in a thread of its own; a controller that does not answer is the controller-side
watchdog's business (docs/controller-watchdogs.md), not a reason to keep the cell out of ``fault``."""


def _stop_everything(actions: CellActions, *, wait_s: float = STOP_ATTEMPT_S) -> list[str]:
    """stop_motion() and arc_off(), both attempted at once whatever the other does, waited for at most ``wait_s``;
    the failures (and the commands still unanswered) as text."""
    results: dict[str, BaseException | None] = {}
    threads = []
    for what, fn in (("stop_motion", actions.stop_motion), ("arc_off", actions.arc_off)):

        def attempt(what: str = what, fn: Callable[[], None] = fn) -> None:
            try:
                fn()
                results[what] = None
            except BaseException as err:
                logger.error("%s failed: %s: %s", what, type(err).__name__, err)
                results[what] = err

        thread = threading.Thread(target=attempt, name=f"cell-{what}", daemon=True)
        thread.start()
        threads.append((what, thread))
    deadline = time.monotonic() + wait_s
    problems = []
    for what, thread in threads:
        thread.join(max(0.0, deadline - time.monotonic()))
        if thread.is_alive():
            logger.error("%s: no answer within %.1f s; not waiting for it", what, wait_s)
            problems.append(f"{what}: not confirmed within {wait_s:.1f} s")
        elif (err := results.get(what)) is not None:
            problems.append(f"{what}: {type(err).__name__}: {err}")
    return problems


# ================================================================================================ documentation
def _names(value: Any) -> list[str]:
    if value is None:
        return []
    return [str(v) for v in (value if isinstance(value, list) else [value])]


def _state_names(value: Any) -> list[str]:
    if value == "*":
        return ["*"]
    return [CellState(v).value for v in (value if isinstance(value, list) else [value])]


def transition_label(row: dict[str, Any]) -> str:
    """``trigger [condition, not unless] / side effect`` for one row of the table."""
    guards = _names(row.get("conditions")) + [f"not {n}" for n in _names(row.get("unless"))]
    label = row["trigger"]
    if guards:
        label += f" [{', '.join(guards)}]"
    effects = _names(row.get("before"))
    if effects:
        label += f" / {', '.join(effects)}"
    return label


def mermaid_state_diagram(table: list[dict[str, Any]] | None = None, *, initial: CellState = S.IDLE) -> str:
    """A Mermaid ``stateDiagram-v2`` of ``table`` (default :data:`TRANSITIONS`); a wildcard source is a note."""
    rows = TRANSITIONS if table is None else table
    lines = ["stateDiagram-v2", f"    [*] --> {initial.value}"]
    notes = []
    for row in rows:
        dest = CellState(row["dest"]).value
        for src in _state_names(row["source"]):
            if src == "*":
                notes.append((dest, f"{transition_label(row)}: from every state"))
            else:
                lines.append(f"    {src} --> {dest} : {transition_label(row)}")
    for dest, text in notes:
        lines.append(f"    note right of {dest}")
        lines.append(f"        {text}")
        lines.append("    end note")
    return "\n".join(lines) + "\n"


def state_machine_doc(table: list[dict[str, Any]] | None = None) -> str:
    """The whole of docs/state-machine.md, generated from ``table`` (default :data:`TRANSITIONS`)."""
    rows = TRANSITIONS if table is None else table
    out = [
        "# The cell's state machine",
        "",
        "Generated from `cell.machine.TRANSITIONS` by `python -m cell.machine`: do not edit by hand",
        "(tests/cell/test_machine.py fails when this file and the table disagree).",
        "",
        "Labels read `trigger [guards] / side effects`. Side effects (`before` callbacks) run while the machine is",
        "still in the source state, so a failure leaves the state unchanged; the exception then fires `fail`,",
        "which stops motion and turns the arc off before entering `fault`. Only `acknowledge` with an operator's",
        "name leaves `fault`. Every state change is journalled and logged at INFO with the job id.",
        "",
        "```mermaid",
        mermaid_state_diagram(rows).rstrip("\n"),
        "```",
        "",
        "| trigger | from | to | guards | side effects |",
        "|---|---|---|---|---|",
    ]
    for row in rows:
        guards = _names(row.get("conditions")) + [f"not {n}" for n in _names(row.get("unless"))]
        out.append(
            f"| `{row['trigger']}` | {', '.join(_state_names(row['source']))} | {CellState(row['dest']).value} "
            f"| {', '.join(guards) or '-'} | {', '.join(_names(row.get('before'))) or '-'} |"
        )
    return "\n".join(out) + "\n"


def write_state_machine_doc(path: str | Path = DOC_PATH) -> Path:
    out = Path(path)
    out.write_text(state_machine_doc(), encoding="utf-8")
    return out


if __name__ == "__main__":
    sys.stdout.write(f"wrote {write_state_machine_doc()}\n")
