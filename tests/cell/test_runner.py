"""The job runner against the protocol-level fakes (hardware in the loop, loopback only).

A whole job on the fake FANUC (two captures from two carriage positions, merged) and on the fake UR5: the robot
received exactly the planned poses (0.1 mm, 0.1 deg), the arc came on at each seam's start and went off at its end,
the states followed the table (from the journal). A paused pass resumes where it stopped.
Faults, on both robots (``on_both_robots``): protective stop and connection loss mid-seam, e-stop, camera timeout,
track fault, no seam, a path out of reach (refused before anything moves for welding); each ends in fault with its
reason, the arc off, the job journaled, and the next job runs after an operator's acknowledgement. A dry run moves
nothing.

The FANUC rig is a fresh simulated cell per test; the UR5 cell (the fake controller in its own process, the driver's
ur-rtde worker) is started once for the module, and each test gets its own journal and runner on it.
"""

from __future__ import annotations

import gc
import json
import threading
import time
import weakref
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cell.cli import main
from cell.journal import Journal
from cell.machine import CellState
from cell.runner import CellFaulted, safety_limits
from perception.transforms import X_from_xyzwpr_mm_deg
from tests.cell.runner_rig import (
    BARE_TABLE_CAPTURE,
    EXAMPLES,
    STATES_OF_A_JOB,
    DoutLog,
    Rig,
    assert_fault,
    commanded_poses,
    expected_poses,
    follow_up_job_runs,
    job_text,
    make_job,
    on_both_robots,
    on_state,
    on_weld_pose,
    state_changes,
)


# ---------------------------------------------------------------------------------------------- whole jobs
@pytest.mark.timeout(60)
def test_a_job_on_the_fake_fanuc_welds_every_planned_pose_with_the_arc_on_between_the_seam_ends(fanuc: Rig) -> None:
    dout = DoutLog(fanuc.robot_fake)
    job = make_job(job_text(second_capture_track_m=0.05))
    report = fanuc.runner.run(job)

    assert (report.state, report.outcome, report.reason) == ("done", "welded", None)
    data = fanuc.runner.current
    assert data is not None and data.path is not None
    path = data.path
    # two captures of the same view from two carriage positions: the seams met in the world frame and merged
    assert [round(t, 4) for t, _capture in data.captures] == [0.0, 0.05]
    X_0, X_1 = (capture.X_base_tool for _t, capture in data.captures)
    assert X_0 is not None and X_1 is not None
    assert np.allclose(X_1[:3, 3] - X_0[:3, 3], [0.0, -0.05, 0.0], atol=1e-4)
    assert data.results[0] is not None and data.results[1] is not None
    assert report.seams_found <= len(data.results[0].seams) + len(data.results[1].seams) - 6
    assert sum(len({k for k, _id in s.sources}) == 2 for s in data.seams) >= 6
    assert report.seams_found >= 8 and report.seams_planned == len(path.passes) >= 8
    assert report.seams_welded == len(path.passes)
    want = expected_poses(fanuc, job)
    assert report.poses_sent == len(want)
    records = fanuc.robot_fake.accepted_records()
    commanded_poses(want, [X_from_xyzwpr_mm_deg(r.xyzwpr_mm_deg) for r in records])

    # arc: off while homing, then on exactly at each pass's arc-on pose and off at its arc-off pose
    # (and once more, belt and braces, before the robot goes home)
    expected = [(1, False)] + [(1, True), (1, False)] * len(path.passes) + [(1, False)]
    assert [(port, on) for port, on, _p in dout.writes] == expected
    for k, p in enumerate(path.passes):
        at_on, at_off = dout.writes[1 + 2 * k][2], dout.writes[2 + 2 * k][2]
        assert np.linalg.norm(at_on - p.arc_on.X_base_tcp[:3, 3] * 1e3) <= 0.1
        assert np.linalg.norm(at_off - p.arc_off.X_base_tcp[:3, 3] * 1e3) <= 0.1
    assert fanuc.arc_is_off()
    assert report.arc_time_s == pytest.approx(sum(p.length_m for p in path.passes) / 0.25, rel=0.3)

    twice = [*STATES_OF_A_JOB[:3], "moving_to_capture", "capturing", *STATES_OF_A_JOB[3:]]
    assert state_changes(fanuc.journal, report.job_id) == twice
    steps = [e.reason for e in fanuc.journal.events(report.job_id) if e.from_state == e.to_state == "welding"]
    assert sum("arc on" in s for s in steps) == sum("arc off" in s for s in steps) == len(path.passes)
    record = fanuc.journal.job(report.job_id)
    assert record.state == "done" and record.report == report.to_dict()
    assert set(report.cycle_s) == {"capture", "detection", "planning", "motion", "total"}
    assert sum(report.cycle_s[k] for k in ("capture", "detection", "planning", "motion")) <= report.cycle_s["total"]


@pytest.mark.timeout(60)
def test_a_pass_paused_mid_seam_resumes_where_it_stopped_with_the_arc_back_on(fanuc: Rig) -> None:
    dout = DoutLog(fanuc.robot_fake)
    machine = fanuc.runner.machine

    def pause_then_resume() -> None:
        machine.request_pause("operator pause")
        assert machine.state is CellState.PAUSED and fanuc.arc_is_off()
        assert machine.resume()

    on_weld_pose(fanuc.runner, 1, 2, lambda: threading.Thread(target=pause_then_resume).start())
    report = fanuc.runner.run(make_job(job_text(min_length_m=0.1)))
    assert (report.state, report.outcome) == ("done", "welded"), report
    data = fanuc.runner.current
    assert data is not None and data.path is not None
    n = len(data.path.passes)
    assert report.seams_welded == n
    changes = state_changes(fanuc.journal, report.job_id)
    assert changes[changes.index("welding") :][:3] == ["welding", "paused", "welding"]
    resumed = [e.reason for e in fanuc.journal.events(report.job_id) if "resuming at travel pose" in e.reason]
    assert len(resumed) == 1
    start = int(resumed[0].rsplit(" ", 1)[1])
    first = data.path.passes[0]
    assert 2 <= start < len(first.travel) - 1
    # arc: on at the arc-on pose, off at the pause, on again at the travel pose the pass resumed from
    ons = [p for _port, on, p in dout.writes if on]
    assert len(ons) == n + 1
    assert np.linalg.norm(ons[0] - first.arc_on.X_base_tcp[:3, 3] * 1e3) <= 0.1
    assert np.linalg.norm(ons[1] - first.travel[start].X_base_tcp[:3, 3] * 1e3) <= 0.1
    assert fanuc.arc_is_off()


@pytest.mark.timeout(60)
def test_a_pause_requested_between_two_motions_takes_effect_before_the_next_one(
    fanuc: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    runner, machine = fanuc.runner, fanuc.runner.machine
    dout = DoutLog(fanuc.robot_fake)
    seen: dict[str, Any] = {}
    move = runner._move

    def pause_then_resume() -> None:
        machine.request_pause("operator pause")  # returns once the pause is applied
        try:
            seen["state"], seen["arc_off"] = machine.state, fanuc.arc_is_off()
            seen["X_paused"] = fanuc.cell.robot.get_X_base_tool()
            seen["motions"] = watch.motions()
        finally:
            seen["resumed"] = machine.resume()

    def move_then_pause(X: np.ndarray, speed_m_s: float, accel_m_s2: float, what: str) -> None:
        move(X, speed_m_s, accel_m_s2, what)
        if what == "pass 1 approach" and "motions_at_request" not in seen:  # the arc-on move has not begun
            seen["motions_at_request"] = watch.motions()
            threading.Thread(target=pause_then_resume).start()
            deadline = time.monotonic() + 5.0
            while machine.pending_interruption() is None:  # the request is in: now the runner goes on
                assert time.monotonic() < deadline, "the pause request never arrived"
                time.sleep(0.001)

    monkeypatch.setattr(runner, "_move", move_then_pause)
    watch = fanuc.watch()
    report = runner.run(make_job(job_text(min_length_m=0.1)))
    assert (report.state, report.outcome) == ("done", "welded"), report
    assert seen["state"] is CellState.PAUSED and seen["arc_off"] and seen["resumed"]
    assert seen["motions"] == seen["motions_at_request"]  # paused before the arc-on move was sent
    data = runner.current
    assert data is not None and data.path is not None
    first = data.path.passes[0]
    assert np.linalg.norm(seen["X_paused"][:3, 3] - first.approach.X_base_tcp[:3, 3]) < 1e-4  # where it stood
    changes = state_changes(fanuc.journal, report.job_id)
    assert changes[changes.index("welding") :][:3] == ["welding", "paused", "welding"]
    ons = [p for _port, on, p in dout.writes if on]  # the arc went on first at the arc-on pose, after the resume
    assert len(ons) == len(data.path.passes)
    assert np.linalg.norm(ons[0] - first.arc_on.X_base_tcp[:3, 3] * 1e3) <= 0.1


@pytest.mark.timeout(30)
def test_a_dry_run_plans_and_validates_and_moves_nothing(fanuc: Rig) -> None:
    job = make_job(job_text())
    X_capture = fanuc.runner.capture_pose(job, 0)
    fanuc.cell.robot.move_linear(X_capture, speed_m_s=0.5, accel_m_s2=1.0)  # park where the job looks from
    dout = DoutLog(fanuc.robot_fake)
    before = len(fanuc.robot_fake.records())
    report = fanuc.runner.run(job, dry_run=True)
    assert (report.state, report.outcome, report.dry_run) == ("idle", "dry_run", True)
    assert report.seams_planned >= 8 and report.seams_welded == 0 and report.poses_sent == 0
    assert report.path is not None and len(report.path["passes"]) == report.seams_planned
    assert len(fanuc.robot_fake.records()) == before and dout.writes == []
    record = fanuc.journal.job(report.job_id)
    assert (record.state, record.error) == ("dry_run", None)  # a dry run that did its work is not a cancellation


@pytest.mark.timeout(60)
def test_after_a_fault_a_dry_run_captures_only_from_home_or_a_capture_pose_until_a_job_homes(fanuc: Rig) -> None:
    job = make_job(job_text())
    runner, robot = fanuc.runner, fanuc.cell.robot
    X_home = robot.get_X_base_tool()  # the fake FANUC starts at the example's home pose
    runner.machine.fault_now("test: a fault that stopped the robot on its way")
    assert runner.acknowledge("Ada")
    X_away = X_home.copy()
    X_away[2, 3] -= 0.02  # 2 cm below home: where a fault can leave it
    robot.move_linear(X_away, speed_m_s=0.5, accel_m_s2=1.0)
    before = len(fanuc.robot_fake.records())
    refused = runner.run(job, dry_run=True)
    assert (refused.state, refused.outcome) == ("fault", "refused")
    assert refused.reason is not None and "dry run after a fault: the tool stands at [" in refused.reason
    assert "neither at home nor at one of the job's 1 capture pose(s)" in refused.reason
    assert refused.seams_found == 0 and len(fanuc.robot_fake.records()) == before  # nothing moved, no frame used
    assert runner.acknowledge("Ada")
    robot.move_linear(runner.capture_pose(job, 0), speed_m_s=0.5, accel_m_s2=1.0)
    report = runner.run(job, dry_run=True)
    assert report.outcome == "dry_run" and report.seams_planned >= 8
    notes = [e.reason for e in fanuc.journal.events(report.job_id)]
    assert "dry run: capture 1/1 from where the robot stands (capture pose 1)" in notes
    robot.move_linear(X_away, speed_m_s=0.5, accel_m_s2=1.0)
    welded = runner.run(make_job(job_text(approval=True)), approve=lambda path: None)  # homes, captures, declined
    assert welded.outcome == "rejected"
    robot.move_linear(X_away, speed_m_s=0.5, accel_m_s2=1.0)
    assert runner.run(job, dry_run=True).outcome != "refused"  # homed since the fault: where it stands is the rule


@pytest.mark.timeout(60)
def test_three_dry_runs_back_to_back_leave_no_thread_behind_and_are_all_journaled(fanuc: Rig) -> None:
    # the reduced soak (scripts/soak.py runs 100 and prints the memory use); a thread a job leaves shows after one
    job = make_job(job_text())
    fanuc.cell.robot.move_linear(fanuc.runner.capture_pose(job, 0), speed_m_s=0.5, accel_m_s2=1.0)
    threads = threading.active_count()
    reports = [fanuc.runner.run(job, dry_run=True) for _ in range(3)]
    assert [r.outcome for r in reports] == ["dry_run"] * 3
    assert all(r.path is not None and r.seams_planned >= 3 and r.poses_sent == 0 for r in reports)
    assert threading.active_count() == threads
    assert [j.state for j in fanuc.journal.recent_jobs(20)] == ["dry_run"] * 3
    assert fanuc.runner.machine.state is CellState.IDLE


@pytest.mark.timeout(60)
def test_a_watchdog_fault_racing_advance_fails_the_job_and_the_journal_agrees(
    fanuc: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the interleaving forced: the runner has chosen advance from moving_to_capture, then the watchdog's fault lands
    machine = fanuc.runner.machine
    advance = machine.advance

    def fault_first(**kwargs: Any) -> bool:
        if machine.state is CellState.MOVING_TO_CAPTURE:
            machine.fault_now("watchdog: robot: protective stop (landed before advance)")
        return advance(**kwargs)

    monkeypatch.setattr(machine, "advance", fault_first)
    watch = fanuc.watch()
    report = fanuc.runner.run(make_job(job_text()), dry_run=True)  # returns: no MachineError out of the runner
    assert_fault(fanuc, report, words=("landed before advance",))
    assert state_changes(fanuc.journal, report.job_id) == ["homing", "moving_to_capture", "fault"]
    assert watch.motions() == 0  # the fake starts at home; the move to the capture pose was never sent


# ---------------------------------------------------------------------------------------------- faults
@on_both_robots
@pytest.mark.timeout(90)
def test_a_protective_stop_mid_seam_faults_with_the_arc_off_and_the_next_job_runs_after_acknowledgement(
    rig: Rig,
) -> None:
    on_weld_pose(rig.runner, 1, 2, lambda: rig.robot_fake.inject("protective_stop"))
    report = rig.runner.run(make_job(job_text(min_length_m=0.1)))
    assert_fault(rig, report, words=("protective stop", "welding"))
    assert report.seams_welded == 0 and rig.arc_is_off()
    assert report.arc_time_s > 0
    # the stop stays latched through clear_faults(): the acknowledgement unlocks it (the UR's once the controller
    # allows it) and restarts what the stop ended; then a job welds (on the UR5 the quicker declined job: welding
    # there has its own test, and it would add ~9 s of motion)
    follow_up_job_runs(rig, clear=rig.robot_fake.clear_faults, weld=rig.kind == "fanuc")


@on_both_robots
@pytest.mark.timeout(90)
def test_an_emergency_stop_faults_and_the_next_job_runs_once_released_and_acknowledged(rig: Rig) -> None:
    on_weld_pose(rig.runner, 1, 1, lambda: rig.robot_fake.inject("emergency_stop"))
    report = rig.runner.run(make_job(job_text(min_length_m=0.1)))
    assert_fault(rig, report, words=("emergency stop",))
    assert rig.arc_is_off()
    with pytest.raises(CellFaulted):
        rig.runner.run(make_job(job_text()))
    assert not rig.runner.acknowledge("Ada")  # the e-stop is still pressed: clearing fails, still in fault
    assert rig.runner.machine.state is CellState.FAULT
    assert rig.runner.machine.fault_reason is not None
    assert rig.runner.machine.fault_reason.startswith("acknowledge failed in fault")
    follow_up_job_runs(rig, clear=rig.robot_fake.clear_faults, weld=False)


@on_both_robots
@pytest.mark.timeout(90)
def test_a_camera_timeout_faults_before_anything_is_welded(rig: Rig) -> None:
    camera: Any = rig.cell.camera
    camera.inject("frame_timeout")
    watch = rig.watch()
    report = rig.runner.run(make_job(job_text()))
    assert_fault(rig, report, words=("CameraTimeout", "capturing"))
    assert report.seams_welded == 0 and report.seams_found == 0 and rig.arc_is_off()
    assert watch.motions() == report.poses_sent == 2  # home, the capture pose
    assert watch.arc_writes() == [False, False]  # off while homing, and again as the fault stopped everything
    follow_up_job_runs(rig, clear=camera.clear_faults, weld=False)


@on_both_robots
@pytest.mark.timeout(90)
def test_a_track_fault_faults_the_job_and_is_reset_on_acknowledgement(rig: Rig) -> None:
    on_state(rig.runner, "moving_to_capture", lambda: rig.track_fake.inject("track_fault", code=7))
    report = rig.runner.run(make_job(job_text(track_position_m=0.05)))
    assert_fault(rig, report, words=("track", "code 7"))
    assert report.seams_welded == 0 and rig.arc_is_off()
    follow_up_job_runs(rig, weld=False)  # the acknowledgement resets the drive's latched fault


@on_both_robots
@pytest.mark.timeout(90)
def test_a_connection_lost_while_streaming_faults_and_the_arc_is_off_once_reconnected(rig: Rig) -> None:
    on_weld_pose(rig.runner, 1, 2, lambda: rig.robot_fake.inject("drop_connection"))
    report = rig.runner.run(make_job(job_text(min_length_m=0.1)))
    # the arc could not be switched off while the controller was unreachable, and the reason says so
    assert_fault(rig, report, words=("ConnectionLost", "arc_off: ConnectionLost"))
    assert report.seams_welded == 0
    assert not rig.runner.acknowledge("Ada")  # the controller still refuses connections
    follow_up_job_runs(rig, clear=rig.robot_fake.clear_faults, weld=False)
    assert rig.arc_is_off()


@on_both_robots
@pytest.mark.timeout(90)
def test_a_controller_that_stops_answering_during_an_arc_is_a_fault_within_one_second(rig: Rig) -> None:
    injected: list[float] = []

    def go_silent() -> None:
        injected.append(time.time())
        rig.robot_fake.inject("no_answer")

    on_weld_pose(rig.runner, 1, 2, go_silent)
    report = rig.runner.run(make_job(job_text(min_length_m=0.1)))
    assert report.state == "fault" and report.outcome == "fault", report
    t_fault = next(e.time_s for e in rig.journal.events(report.job_id) if e.to_state == "fault")
    assert 0.0 < t_fault - injected[0] < 1.0, t_fault - injected[0]
    record = rig.journal.job(report.job_id)
    assert record.state == "failed" and record.error == report.reason  # the report and the journal agree
    # the controller's own watchdog switched the arc off: the host could not reach it
    wait_for_arc_off(rig, limit_s=1.0)
    follow_up_job_runs(rig, clear=rig.robot_fake.clear_faults, weld=False)


def wait_for_arc_off(rig: Rig, *, limit_s: float) -> None:
    deadline = time.monotonic() + limit_s
    while not rig.arc_is_off():
        assert time.monotonic() < deadline, f"the arc output still reads on after {limit_s} s"
        time.sleep(0.01)


@pytest.mark.timeout(90)
def test_an_acknowledgement_waits_until_the_runner_has_finished_the_job(fanuc: Rig) -> None:
    runner = fanuc.runner
    answers: list[tuple[float, bool]] = []
    acked = threading.Event()

    def acknowledge_at_once() -> None:  # from another thread, the moment the machine enters fault
        ok = runner.acknowledge("Ada")
        answers.append((time.monotonic(), ok))
        acked.set()

    def on_fault(kind: str, data: dict[str, Any]) -> None:
        if kind == "state" and data["state"] == "fault" and not answers and not acked.is_set():
            threading.Thread(target=acknowledge_at_once, daemon=True).start()
            time.sleep(0.3)  # the runner is still finishing its job: the acknowledgement must wait for it

    runner.on_progress = on_fault
    on_state_machine = runner.machine
    fanuc.robot_fake.inject("protective_stop")
    report = runner.run(make_job(job_text()))
    finished = time.monotonic()
    assert acked.wait(30)
    assert report.outcome == "fault" and report.state == "fault", report  # not "rejected" by a racing ack
    assert fanuc.journal.job(report.job_id).state == "failed"
    t_ack, ok = answers[0]
    assert t_ack >= finished - 0.05
    assert not ok  # the stop is still latched (the cause was not cleared), so the cell stays in fault
    assert on_state_machine.state is CellState.FAULT
    follow_up_job_runs(fanuc, clear=fanuc.robot_fake.clear_faults, weld=False)


@on_both_robots
@pytest.mark.timeout(90)
def test_no_seam_found_faults_with_the_reason_and_nothing_is_welded(rig: Rig) -> None:
    report = rig.runner.run(make_job(job_text(capture=BARE_TABLE_CAPTURE)))
    assert_fault(rig, report, words=("NoSeamFound",), outcome="no_seam")
    assert report.seams_found == 0 and report.poses_sent == 2 and rig.arc_is_off()
    follow_up_job_runs(rig, weld=False)


@pytest.mark.timeout(90)
def test_a_faulted_jobs_captures_are_freed_once_the_next_job_has_run(fanuc: Rig) -> None:
    # the fault's error is kept after the job (the report reads it): it must not keep the job's frames and with them
    # its captures (hundreds of MiB on a real camera); the runner itself keeps only the latest job's
    report = fanuc.runner.run(make_job(job_text(capture=BARE_TABLE_CAPTURE)))
    assert report.outcome == "no_seam"
    data = fanuc.runner.current
    assert data is not None and len(data.captures) == 1
    capture = weakref.ref(data.captures[0][1])
    pixels = weakref.ref(data.captures[0][1].depth_m)
    del data
    follow_up_job_runs(fanuc, weld=False)
    gc.collect()
    assert capture() is None, "the faulted job's capture is still alive"
    assert pixels() is None, "the faulted job's depth image is still alive"


@on_both_robots
@pytest.mark.timeout(90)
def test_a_path_out_of_reach_is_refused_before_the_torch_moves(rig: Rig) -> None:
    job = make_job(job_text())
    # a reach sphere that holds the capture pose but none of the seams: centred 0.5 m beyond the capture pose, seen
    # from the fixture (the seams lie within 0.3 m of the fixture's origin, the capture pose 0.6 m from it)
    assert rig.config.fixture is not None and rig.config.safety is not None
    p_capture = rig.runner.capture_pose(job, 0)[:3, 3]
    p_fixture = np.asarray(rig.config.fixture.X_world_fixture, dtype=np.float64)[:3, 3]  # track at 0: world = base
    away = (p_capture - p_fixture) / np.linalg.norm(p_capture - p_fixture)
    reach = {"reach_centre_base": (p_capture + 0.5 * away).tolist(), "reach_radius_m": 0.55, "reach_preferred_m": 0.4}
    cell_limits = rig.runner.limits
    rig.runner.limits = safety_limits(
        rig.config.model_copy(update={"safety": rig.config.safety.model_copy(update=reach)})
    )
    watch = rig.watch()
    report = rig.runner.run(job)
    assert_fault(rig, report, words=("SafetyViolation", "reach radius"), outcome="refused")
    assert report.seams_found >= 8 and report.seams_planned == 0 and report.poses_sent == 2
    assert watch.motions() == 2  # home and the capture pose: no weld motion
    assert watch.arc_writes() == [False, False] and rig.arc_is_off()  # off while homing and at the fault, never on
    rig.runner.limits = cell_limits  # the operator puts the cell's reach back, then acknowledges
    follow_up_job_runs(rig, weld=False)


@pytest.mark.timeout(60)
def test_weldcell_run_exits_3_without_a_seam_and_2_for_a_bad_job(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "cell.toml"
    text = (EXAMPLES / "sim-cell-fanuc.toml").read_text(encoding="utf-8")
    text = text.replace("port = 16001", "port = 0").replace("port = 5020", "port = 0")
    text = text.replace("speed_m_s = 0.1                # default tool speed", "speed_m_s = 0.5")
    text = text.replace('journal = "../out/weldcell-fanuc-journal.sqlite3"', f'journal = "{tmp_path / "j.sqlite3"}"')
    config.write_text(text, encoding="utf-8")
    job = tmp_path / "job.toml"
    job.write_text(job_text(capture=BARE_TABLE_CAPTURE), encoding="utf-8")
    assert main(["run", str(job), "--config", str(config), "--json"]) == 3
    out, err = capsys.readouterr()
    report = json.loads(out)
    assert (report["state"], report["outcome"], report["seams_found"], report["seams_welded"]) == (
        "fault",
        "no_seam",
        0,
        0,
    )
    assert set(report["cycle_s"]) == {"capture", "detection", "planning", "motion", "total"}
    assert "weldcell run: no seam found: " in err
    with Journal(tmp_path / "j.sqlite3") as journal:
        assert journal.job(report["job_id"]).state == "failed"
    bad = tmp_path / "bad.toml"
    bad.write_text(job_text().replace("[welding]", "[welding]\ncurrent_a = 180"), encoding="utf-8")
    assert main(["run", str(bad), "--config", str(config)]) == 2
    assert f"{bad}: welding.current_a: unknown key" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- the UR5 job
# last, with the UR5 faults just before it: the module's UR5 cell then runs only while its tests do (the fault
# tests run grouped by robot, the FANUC ones first)
@pytest.mark.timeout(90)
def test_a_job_on_the_fake_ur5_welds_every_planned_pose_with_the_arc_between_the_seam_ends(ur5: Rig) -> None:
    fake = ur5.robot_fake
    n_events, n_targets, n_io = len(fake.events()), len(fake.commanded_targets()), len(fake.io_changes())
    job = make_job(job_text(min_length_m=0.1))
    report = ur5.runner.run(job)
    assert (report.state, report.outcome) == ("done", "welded"), report
    data = ur5.runner.current
    assert data is not None and data.path is not None
    path = data.path
    assert report.seams_welded == len(path.passes) >= 3
    commanded_poses(expected_poses(ur5, job), fake.commanded_targets()[n_targets:])
    # the order of the commands: approach, arc-on pose, arc on, travel path, arc off, retract
    events = fake.events()[n_events:]
    # the driver's writes (the program-stop action's own "arc off" at each path upload is checked below)
    kinds = [e["kind"] for e in events if e["kind"] in ("move_linear", "path", "digital_output") and "cause" not in e]
    per_pass = ["move_linear", "move_linear", "digital_output", "path", "digital_output", "digital_output"]
    per_pass.append("move_linear")  # approach, arc-on pose, arc on, path (restored arc), arc off, retract
    home_and_capture = ["digital_output", "move_linear", "move_linear"]
    assert kinds == [*home_and_capture, *per_pass * len(path.passes), "digital_output", "move_linear"]
    writes = [(e["index"], e["value"]) for e in events if e["kind"] == "digital_output" and "cause" not in e]
    assert writes == [(0, False)] + [(0, True), (0, True), (0, False)] * len(path.passes) + [(0, False)]
    # each path upload stopped the program (arc output low) and the arc was back on before the slider let go
    for i, e in enumerate(events):
        if e["kind"] == "path":
            before = [x for x in events[:i] if x["kind"] == "digital_output"][-1]
            after = [x for x in events[i:] if x["kind"] in ("digital_output", "speed_slider")][:2]
            assert before.get("cause", "").startswith("program stop") and before["value"] is False
            assert [(x["kind"], x.get("value"), x.get("fraction")) for x in after] == [
                ("digital_output", True, None),
                ("speed_slider", None, 1.0),
            ]
    assert fake.io_changes()[n_io:][0] == (0, False)
    assert ur5.arc_is_off()
    assert state_changes(ur5.journal, report.job_id) == STATES_OF_A_JOB
