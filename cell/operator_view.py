"""What the operator page shows, as JSON-ready values: a job's per-seam progress and time left, the seams of the
capture being welded in image pixels (welded, current, pending), the devices and the arc, the job history.

Pure functions of the runner's :class:`cell.job_report.JobData`, the watchdog's
:class:`cell.watchdog.DeviceReadings` and the journal's records; :meth:`cell.daemon.Daemon.status` puts them
together.

Time left is the programmed motion still to come: every remaining waypoint's distance from the one before at
that move's programmed speed, plus the arc-on and arc-off dwells. Acceleration, track moves and the return home are
left out, so it is a lower bound that is close for long seams (a seam of 0.2 m at 10 mm/s: 20 s of travel against
well under a second of acceleration).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cell.job_report import JobData
from cell.journal import JobRecord
from cell.machine import CellState
from cell.planning import WeldPath
from cell.watchdog import DeviceReadings
from perception.capture import Capture
from perception.seams import DetectionResult
from perception.transforms import invert_X, transform_points

S = CellState

WELDED, CURRENT, PENDING = "welded", "current", "pending"


def job_view(record: JobRecord) -> dict[str, Any]:
    """One job of the journal; ``duration_s``: from its start to its end (None until both are known)."""
    duration = None
    if record.started_s is not None and record.finished_s is not None:
        duration = round(record.finished_s - record.started_s, 3)
    return {
        "id": record.id,
        "job_file": record.job_file,
        "state": record.state,
        "submitted_s": record.submitted_s,
        "started_s": record.started_s,
        "finished_s": record.finished_s,
        "duration_s": duration,
        "outcome": record.report.get("outcome") if record.report else None,
        "report": record.report,
        "error": record.error,
    }


def pass_statuses(path: WeldPath, next_pass: int, state: CellState) -> list[str]:
    """Each pass's status: welded before ``next_pass``; ``next_pass`` is current while the job welds (or is
    paused there), pending otherwise; the rest pending."""
    welding = state in (S.WELDING, S.PAUSED)
    out = []
    for i in range(len(path.passes)):
        if i < next_pass:
            out.append(WELDED)
        elif i == next_pass and welding:
            out.append(CURRENT)
        else:
            out.append(PENDING)
    return out


def time_left_s(path: WeldPath, next_pass: int, resume_from: int) -> float:
    """Seconds of programmed motion and dwell still to come from pass ``next_pass``, travel pose ``resume_from``
    (0: the pass has not started welding), to the last pass's retract (see the module docstring)."""
    params = path.params
    total = 0.0
    previous: np.ndarray | None = None
    for i in range(next_pass, len(path.passes)):
        waypoints = path.passes[i].waypoints
        first = 0
        if i == next_pass and resume_from > 0:
            first = 2 + resume_from  # waypoints: approach, arc_on (travel[0]), travel[1:] ...; from the pose reached
            previous = waypoints[1 + resume_from].X_base_tcp[:3, 3]
        else:
            total += params.arc_on_dwell_s
        total += params.arc_off_dwell_s
        for w in waypoints[first:]:
            p = w.X_base_tcp[:3, 3]
            if previous is not None and w.speed_m_s > 0:
                total += float(np.linalg.norm(p - previous)) / w.speed_m_s
            previous = p
    return total


def progress_view(data: JobData, state: CellState) -> dict[str, Any]:
    """Where the job stands: the phase, and once planned the seam being welded (``seam`` of ``seams``, 1-based),
    its travel pose, each pass's status and the time left."""
    out: dict[str, Any] = {"phase": state.value, "seams_found": len(data.seams), "seams_welded": data.seams_welded}
    path = data.path
    if path is None or not path.passes:
        return out
    n = len(path.passes)
    k = min(data.next_pass, n - 1)
    statuses = pass_statuses(path, data.next_pass, state)
    current = path.passes[k]
    travel = len(current.travel)
    out.update(
        seam=min(data.next_pass + 1, n),
        seams=n,
        seam_id=current.seam_id,
        pass_length_m=round(current.length_m, 4),
        pose=data.resume_from + 1 if state in (S.WELDING, S.PAUSED) and data.next_pass < n else None,
        poses=travel,
        time_left_s=round(time_left_s(path, data.next_pass, data.resume_from), 1),
        passes=[
            {"seam_id": p.seam_id, "status": st, "length_m": round(p.length_m, 4)}
            for p, st in zip(path.passes, statuses, strict=True)
        ],
    )
    return out


def seams_in_image(capture: Capture, result: DetectionResult) -> dict[int, list[list[float]]]:
    """Each detected seam of ``result`` (by its detector id) as image pixels (u, v) of ``capture``."""
    X_camera_frame = np.eye(4)
    if result.frame == "base" and capture.X_base_camera is not None:
        X_camera_frame = invert_X(capture.X_base_camera)
    out = {}
    for seam in result.seams:
        uv = capture.intrinsics.project(transform_points(X_camera_frame, seam.points))
        out[int(seam.id)] = np.round(uv, 1).tolist()
    return out


def overlay_view(data: JobData, state: CellState) -> dict[str, Any] | None:
    """The seams of the capture shown on the page (the last one with a detection, as in the status image) in
    pixels, each with the status of the pass that welds it (``seam_id`` is the planned seam's id)."""
    k = data.status_capture
    if k is None or k >= len(data.results) or data.results[k] is None:
        return None
    capture = data.captures[k][1]
    result = data.results[k]
    assert result is not None
    pixels = seams_in_image(capture, result)
    height, width = capture.shape
    seams: list[dict[str, Any]] = []
    path = data.path
    if path is None:
        seams = [{"seam_id": sid, "status": PENDING, "uv": uv} for sid, uv in pixels.items()]
    else:
        for p, status in zip(path.passes, pass_statuses(path, data.next_pass, state), strict=True):
            for capture_index, detector_id in p.sources:
                if capture_index == k and detector_id in pixels:
                    seams.append({"seam_id": p.seam_id, "status": status, "uv": pixels[detector_id]})
    return {"capture": k + 1, "width": int(width), "height": int(height), "seams": seams}


def devices_view(
    readings: DeviceReadings | None, *, robot: str, track: str | None, camera: str, arc_output: int
) -> dict[str, Any]:
    """The robot (mode, stops, moving), the track (position, enabled, fault), the camera's name and the arc output
    as the robot reports it (None: unknown)."""
    st = readings.robot if readings is not None else None
    robot_view: dict[str, Any] = {"name": robot, "ok": False, "error": None}
    arc_on: bool | None = None
    if st is not None:
        robot_view.update(
            ok=st.healthy,
            mode=st.mode.value,
            moving=st.is_moving,
            protective_stop=st.protective_stop,
            emergency_stop=st.emergency_stop,
            message=st.message,
        )
        arc_on = bool(st.digital_outputs[arc_output]) if arc_output < len(st.digital_outputs) else None
    elif readings is not None:
        robot_view["error"] = readings.robot_error
    track_view: dict[str, Any] | None = None
    if track is not None:
        status = readings.track if readings is not None else None
        track_view = {"name": track, "ok": False, "error": readings.track_error if readings is not None else None}
        if status is not None:
            track_view.update(
                ok=status.enabled and not status.fault,
                position_m=round(status.position_m, 4),
                enabled=status.enabled,
                moving=status.moving,
                fault=status.fault,
                fault_code=status.fault_code,
            )
    return {
        "robot": robot_view,
        "track": track_view,
        "camera": {"name": camera},
        "arc": {"output": arc_output, "on": arc_on},
        "read_s": readings.time_s if readings is not None else None,
    }
