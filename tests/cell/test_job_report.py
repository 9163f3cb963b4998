"""cell.job_report: how the machine's end state and error become a job's outcome, and the report's numbers."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from cell.errors import SafetyViolation
from cell.job import job_from_text
from cell.job_report import CYCLE_PHASES, JobData, job_report
from cell.machine import CellState
from cell.planning import WeldParams
from perception.errors import NoSeamFound
from tests.cell.runner_rig import job_text
from tests.cell.test_operator_view import PATH

S = CellState


def data(**changes: Any) -> JobData:
    job = job_from_text(job_text(), source="job.toml", base_dir=Path("."))
    d = JobData(job=job, job_id=4, dry_run=False, params=WeldParams())
    for k, v in changes.items():
        setattr(d, k, v)
    return d


@pytest.mark.parametrize(
    ("state", "error", "changes", "outcome", "reason"),
    [
        (S.DONE, None, {"path": PATH}, "welded", None),
        (S.FAULT, NoSeamFound("none"), {}, "no_seam", "r"),
        (S.FAULT, SafetyViolation("out"), {"path": PATH}, "refused", "r"),
        (S.FAULT, RuntimeError("x"), {}, "fault", "r"),
        (S.IDLE, None, {"dry_run": True, "path": PATH}, "dry_run", "dry run: planned and validated, nothing moved or "
         "welded"),
        (S.IDLE, None, {"path": PATH}, "rejected", "the operator did not approve the path"),
    ],
)  # fmt: skip
def test_outcomes(state: CellState, error: Exception | None, changes: dict, outcome: str, reason: str | None) -> None:
    machine = SimpleNamespace(state=state, fault_reason="r", last_error=error)
    report = job_report(machine, data(**changes), 12.0)  # type: ignore[arg-type]
    assert (report.state, report.outcome, report.reason) == (state.value, outcome, reason)
    assert report.seams_planned == (2 if "path" in changes else 0)


def test_the_report_rounds_only_when_written_and_totals_the_cycle() -> None:
    d = data(path=PATH, seams_welded=2, poses_sent=31, arc_time_s=61.23456)
    d.times["motion"] = 70.1234567
    report = job_report(SimpleNamespace(state=S.DONE, fault_reason=None, last_error=None), d, 99.87654)  # type: ignore[arg-type]
    assert report.cycle_s == {**dict.fromkeys(CYCLE_PHASES, 0.0), "motion": 70.1234567, "total": 99.87654}
    out = report.to_dict()
    assert out["arc_time_s"] == 61.235 and out["cycle_s"]["motion"] == 70.123 and out["cycle_s"]["total"] == 99.877
    assert out["path"]["weld_length_m"] == 0.6 and [p["seam_id"] for p in out["path"]["passes"]] == [7, 3]
