"""cell.operator_view: per-seam progress, time left and the overlay's seam states, checked on a hand-built path
whose every distance and speed is known."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cell.job import job_from_text
from cell.job_report import JobData
from cell.journal import JobRecord
from cell.machine import CellState
from cell.operator_view import devices_view, job_view, pass_statuses, progress_view, time_left_s
from cell.planning import MoveKind, SeamPass, Waypoint, WeldParams, WeldPath
from cell.watchdog import DeviceReadings
from drivers.protocols import RobotMode, RobotState, TrackStatus
from tests.cell.runner_rig import job_text

S = CellState
PARAMS = WeldParams(arc_on_dwell_s=0.5, arc_off_dwell_s=0.25)


def wp(x: float, z: float, speed: float, kind: MoveKind) -> Waypoint:
    X = np.eye(4)
    X[:3, 3] = (x, 0.0, z)
    return Waypoint(X, speed, 0.0, kind, kind.value)


def seam_pass(seam_id: int, x0: float) -> SeamPass:
    """Approach 0.1 m above x0 (air, 0.5 m/s), down 0.1 m (approach, 0.05 m/s), three 0.1 m weld moves along x at
    0.01 m/s, up 0.1 m (retract, 0.05 m/s)."""
    ways = (
        wp(x0, 0.1, 0.5, MoveKind.AIR),
        wp(x0, 0.0, 0.05, MoveKind.APPROACH),
        *(wp(x0 + 0.1 * k, 0.0, 0.01, MoveKind.WELD) for k in (1, 2, 3)),
        wp(x0 + 0.3, 0.1, 0.05, MoveKind.RETRACT),
    )
    return SeamPass(seam_id, "linear", ((0, seam_id),), False, 0.0, ways, 0.3)


PATH = WeldPath((seam_pass(7, 0.0), seam_pass(3, 1.0)), PARAMS)
# one pass from its approach: down 2 s, weld 30 s, up 2 s, dwells 0.75 s; between the passes an air move from
# (0.3, 0, 0.1) to (1.0, 0, 0.1): 0.7 m at 0.5 m/s = 1.4 s
PASS_S = 2.0 + 30.0 + 2.0 + 0.75


def test_time_left_counts_every_remaining_move_at_its_speed_and_the_dwells():
    assert time_left_s(PATH, 0, 0) == pytest.approx(PASS_S + 1.4 + PASS_S)
    # pass 1 welded up to travel pose 1 (x = 0.1): two weld moves (20 s), retract, arc-off dwell only
    assert time_left_s(PATH, 0, 1) == pytest.approx(20.0 + 2.0 + 0.25 + 1.4 + PASS_S)
    assert time_left_s(PATH, 1, 0) == pytest.approx(PASS_S)
    assert time_left_s(PATH, 2, 0) == 0.0


def test_pass_statuses_follow_the_welding():
    assert pass_statuses(PATH, 0, S.AWAITING_APPROVAL) == ["pending", "pending"]
    assert pass_statuses(PATH, 0, S.WELDING) == ["current", "pending"]
    assert pass_statuses(PATH, 1, S.PAUSED) == ["welded", "current"]
    assert pass_statuses(PATH, 2, S.RETRACTING) == ["welded", "welded"]


def test_progress_names_seam_k_of_n_its_pose_and_the_time_left():
    job = job_from_text(job_text(), source="<test>")
    data = JobData(job=job, job_id=5, dry_run=False, params=PARAMS, path=PATH, next_pass=1, resume_from=2)
    data.seams_welded = 1
    view = progress_view(data, S.WELDING)
    assert view.pop("time_left_s") == pytest.approx(10.0 + 2.0 + 0.25, abs=0.051)  # rounded to 0.1 s
    assert view == {
        "phase": "welding", "seams_found": 0, "seams_welded": 1, "seam": 2, "seams": 2, "seam_id": 3,
        "pass_length_m": 0.3, "pose": 3, "poses": 4,
        "passes": [
            {"seam_id": 7, "status": "welded", "length_m": 0.3}, {"seam_id": 3, "status": "current", "length_m": 0.3},
        ],
    }  # fmt: skip
    assert "seam" not in progress_view(dataclasses.replace(data, path=None), S.DETECTING)


def test_job_history_entries_carry_their_duration_and_outcome():
    record = JobRecord(
        id=3, job_file="a.toml", state="done", submitted_s=100.0, started_s=101.5, finished_s=164.25,
        report={"outcome": "welded"}, error=None,
    )  # fmt: skip
    view = job_view(record)
    assert view["duration_s"] == 62.75 and view["outcome"] == "welded"
    assert job_view(dataclasses.replace(record, finished_s=None, report=None))["duration_s"] is None


def test_devices_show_the_arc_output_as_the_robot_reports_it():
    robot = RobotState(RobotMode.MOVING, np.eye(4), True, False, False, (False, True, False), "")
    track = TrackStatus(position_m=0.25, enabled=True, moving=False, in_position=True, fault=False)
    view = devices_view(DeviceReadings(10.0, robot, None, track, None), robot="r", track="t", camera="c", arc_output=1)
    assert view["arc"] == {"output": 1, "on": True}
    assert view["robot"]["ok"] is True and view["robot"]["mode"] == "moving"
    assert view["track"]["position_m"] == 0.25 and view["track"]["ok"] is True
    lost = devices_view(DeviceReadings(10.0, None, "ConnectionLost: gone", None, None), robot="r", track=None,
                        camera="c", arc_output=1)  # fmt: skip
    assert lost["robot"] == {"name": "r", "ok": False, "error": "ConnectionLost: gone"} and lost["arc"]["on"] is None
    assert lost["track"] is None
