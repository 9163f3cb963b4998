"""What a job gathers while it runs (:class:`JobData`) and what it reports at its end (:class:`JobReport`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cell.errors import SafetyViolation
from cell.job import Job
from cell.machine import CellMachine, CellState
from cell.planning import WeldParams, WeldPath
from cell.world_seams import WorldSeam
from perception.capture import Capture
from perception.errors import NoSeamFound
from perception.seams import DetectionResult

S = CellState

CYCLE_PHASES = ("capture", "detection", "planning", "motion")


@dataclass
class JobReport:
    """What a job did. ``state``: the machine's final state (``done``, ``fault``, ``idle``); ``outcome``:
    ``welded``, ``dry_run``, ``rejected``, ``no_seam``, ``refused`` (a safety violation, nothing moved for
    welding) or ``fault``; ``reason``: why it did not weld (None when it did). Times in seconds."""

    job_id: int
    workpiece: str
    state: str
    outcome: str
    reason: str | None
    dry_run: bool
    seams_found: int
    seams_planned: int
    seams_welded: int
    poses_sent: int
    arc_time_s: float
    cycle_s: dict[str, float]
    path: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["arc_time_s"] = round(self.arc_time_s, 3)
        out["cycle_s"] = {k: round(v, 3) for k, v in self.cycle_s.items()}
        return out


@dataclass
class JobData:
    """What the running (or last) job has gathered and done so far: its captures ((track position m, Capture)),
    detection results, world-frame seams, the validated path, where welding stands (``next_pass``, ``resume_from``:
    the travel pose a paused pass resumes from; ``pending_retract``: a retract pose not yet reached), counters
    and the seconds spent per cycle phase. ``status_capture``: the capture drawn in the status image;
    ``planned_from``: the track position (m) and the world TCP position ((3,) m) the path was planned from."""

    job: Job
    job_id: int
    dry_run: bool
    params: WeldParams
    captures: list[tuple[float, Capture]] = field(default_factory=list)
    results: list[DetectionResult | None] = field(default_factory=list)
    seams: list[WorldSeam] = field(default_factory=list)
    path: WeldPath | None = None
    next_pass: int = 0
    resume_from: int = 0
    pending_retract: np.ndarray | None = None
    status_capture: int | None = None
    planned_from: tuple[float, np.ndarray] | None = None
    seams_welded: int = 0
    poses_sent: int = 0
    arc_time_s: float = 0.0
    times: dict[str, float] = field(default_factory=lambda: dict.fromkeys(CYCLE_PHASES, 0.0))


def job_report(machine: CellMachine, data: JobData, total_s: float) -> JobReport:
    """The report of the job ``data`` that ``machine`` has ended (its final state, fault reason and error say how),
    ``total_s`` seconds after it started."""
    m = machine
    state = m.state
    reason: str | None = None
    err = m.last_error
    if state is S.DONE:
        outcome = "welded"
    elif state is S.FAULT:
        reason = m.fault_reason
        if isinstance(err, NoSeamFound):
            outcome = "no_seam"
        elif isinstance(err, SafetyViolation):
            outcome = "refused"
        else:
            outcome = "fault"
    elif data.dry_run and data.path is not None:
        outcome, reason = "dry_run", "dry run: planned and validated, nothing moved or welded"
    else:
        outcome, reason = "rejected", "the operator did not approve the path"
    cycle = dict(data.times)
    cycle["total"] = total_s
    path = data.path
    return JobReport(
        job_id=data.job_id,
        workpiece=data.job.workpiece,
        state=state.value,
        outcome=outcome,
        reason=reason,
        dry_run=data.dry_run,
        seams_found=len(data.seams),
        seams_planned=len(path.passes) if path is not None else 0,
        seams_welded=data.seams_welded,
        poses_sent=data.poses_sent,
        arc_time_s=data.arc_time_s,
        cycle_s=cycle,
        path=path.summary() if path is not None else None,
    )
