"""The simulated cells the job runner's hardware-in-the-loop tests run on (tests/cell/test_runner.py and the daemon's,
the run command's and the job checks' tests): example configs made fast for tests, the ribs job, the FANUC rig
(a fresh cell per test) and the UR5 rig (one cell per module, the fake controller in its own process), what the
fake controllers accepted, and the checks the fault tests share.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cell.config import CellConfig, config_from_dict
from cell.factory import Cell, build_camera, build_cell
from cell.job import Job, job_from_text
from cell.journal import Journal
from cell.machine import CellState
from cell.runner import CellFaulted, JobReport, JobRunner
from drivers.errors import DriverError
from perception.transforms import rotation_angle_rad
from sim_fakes import fake_ur
from sim_fakes.loopback import free_loopback_host

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"
ROBOTS = ("fanuc", "ur5")
EXAMPLE = {"fanuc": "sim-cell-fanuc.toml", "ur5": "sim-cell.toml"}
UR_HOST = free_loopback_host()  # this session's own: not the example's .41 ('weldcell sim up' may run there)

STATES_OF_A_JOB = [
    "homing",
    "moving_to_capture",
    "capturing",
    "detecting",
    "planning",
    "awaiting_approval",
    "welding",
    "retracting",
    "done",
]


# ---------------------------------------------------------------------------------------------- helpers
def cell_config(tmp_path: Path, example: str, **changes: dict[str, Any]) -> CellConfig:
    """An example config made fast for tests: free ports, quick moves, a short camera timeout; ``changes``
    update whole tables (``safety={"reach_radius_m": 0.5}``)."""
    data = tomllib.loads((EXAMPLES / example).read_text(encoding="utf-8"))
    if data["robot"]["kind"] == "fake-fanuc":
        data["robot"].update(port=0, speed_m_s=0.5, max_speed_m_s=0.5, accel_m_s2=1.0)
    else:  # the fake UR ramps up to speed at the commanded acceleration (the fake FANUC starts at full speed)
        data["robot"].update(host=UR_HOST, speed_m_s=1.0, max_speed_m_s=1.0, accel_m_s2=2.0)
    data["track"].update(port=0, speed_m_s=0.4, accel_m_s2=1.0)
    data["camera"]["timeout_s"] = 1.0
    data["safety"]["max_speed_m_s"] = 0.6
    data["daemon"].update(journal=str(tmp_path / "journal.sqlite3"), status_image=str(tmp_path / "status.png"))
    for table, values in changes.items():
        data[table].update(values)
    return config_from_dict(data, source=tmp_path / f"test-{example}")


RIBS_CAPTURE = (
    'xyz_m = [-0.29854, -0.36207, 0.36562]\nrotvec_rad = [-2.43288, -0.95895, -1.10208]\nprompts = "camera"\n'
)
# the camera looks straight down at the bare table beside the plate (within both robots' reach)
BARE_TABLE_CAPTURE = 'xyzwpr_mm_deg = [550.0, 0.0, 300.0, 180.0, 0.0, 0.0]\nprompts = "automatic"\n'


def job_text(
    *,
    min_length_m: float = 0.02,
    track_position_m: float = 0.0,
    capture: str = RIBS_CAPTURE,
    travel_speed_m_s: float = 0.25,
    approval: bool = False,
    second_capture_track_m: float | None = None,
) -> str:
    """The ribs job with fast welding (0.25 m/s travel) for tests; ``second_capture_track_m``: look again from the
    same place in the fixture with the carriage there (the robot's base-frame pose makes up for it)."""
    second = (
        ""
        if second_capture_track_m is None
        else f"[[capture]]\ntrack_position_m = {second_capture_track_m}\n{capture}\n"
    )
    return (
        f'workpiece = "ribs"\napproval = {str(approval).lower()}\nframe = "fixture"\n\n'
        f"[[capture]]\ntrack_position_m = {track_position_m}\n{capture}\n{second}"
        f"[welding]\ntravel_speed_m_s = {travel_speed_m_s}\napproach_speed_m_s = 0.3\nair_speed_m_s = 0.5\n"
        "accel_m_s2 = 1.0\napproach_m = 0.03\nretract_m = 0.03\ntravel_angle_deg = 10.0\narc_output = 0\n\n"
        f'[seams]\nkinds = ["linear"]\nmin_length_m = {min_length_m}\n'
    )


def make_job(text: str) -> Job:
    return job_from_text(text, source="test-job.toml", base_dir=REPO)


@dataclass
class Rig:
    """A simulated cell with its runner and journal; ``kind``: "fanuc" or "ur5" (see :meth:`arc_is_off` and
    :meth:`watch` for what differs between the fake controllers)."""

    kind: str
    config: CellConfig
    cell: Cell
    runner: JobRunner
    journal: Journal

    @property
    def robot_fake(self) -> Any:
        assert self.cell.simulators is not None
        return self.cell.simulators.robot

    @property
    def track_fake(self) -> Any:
        assert self.cell.simulators is not None
        return self.cell.simulators.track

    def arc_is_off(self) -> bool:
        """The arc output (``arc_output = 0``) as the fake controller holds it: FANUC DO[1], UR standard DO 0."""
        if self.kind == "fanuc":
            return not self.robot_fake.digital_output(1)
        return self.robot_fake.snapshot()["digital_outputs"][0] is False

    def watch(self) -> Watch:
        return Watch(self)


class Watch:
    """What the fake robot controller accepts from now on: arc output writes, motion targets."""

    def __init__(self, rig: Rig) -> None:
        self.fake = rig.robot_fake
        self.fanuc = rig.kind == "fanuc"
        if self.fanuc:
            self.dout = DoutLog(self.fake)
            self.n_motions = len(self.fake.accepted_records())
        else:
            self.n_io = len(self.fake.io_changes())
            self.n_motions = len(self.fake.commanded_targets())

    def arc_writes(self) -> list[bool]:
        if self.fanuc:
            return [on for port, on, _p in self.dout.writes if port == 1]
        return [on for index, on in self.fake.io_changes()[self.n_io :] if index == 0]

    def motions(self) -> int:
        """Motion targets accepted since the watch began (moves and path poses)."""
        if self.fanuc:
            return len(self.fake.accepted_records()) - self.n_motions
        return len(self.fake.commanded_targets()) - self.n_motions


def open_rig(config: CellConfig, tmp_path: Path, kind: str = "fanuc") -> Rig:
    cell = build_cell(config, start_simulators=True)
    try:
        cell.connect()
    except BaseException:
        cell.close()
        raise
    return attach_rig(kind, cell, tmp_path)


def attach_rig(kind: str, cell: Cell, tmp_path: Path) -> Rig:
    """A fresh journal and runner on ``cell`` (connected)."""
    journal = Journal(tmp_path / "journal.sqlite3")
    return Rig(kind, cell.config, cell, JobRunner(cell, journal=journal, watchdog_period_s=0.1), journal)


def close_rig(rig: Rig) -> None:
    rig.cell.close()
    rig.journal.close()


class SharedCell:
    """The module's one simulated UR5 cell, started on first use; :meth:`discard` replaces a cell a test left
    unhealthy (the next :meth:`get` starts a new one), so one failing test does not fail the others."""

    def __init__(self, config: CellConfig) -> None:
        self.config = config
        self.cell: Cell | None = None

    def get(self) -> Cell:
        if self.cell is None:
            # the fake controller refuses to unlock a protective stop for 1 s after it, not a CB3's 5 s: the
            # acknowledgement still has to wait for the controller (tests/drivers/test_ur.py times that wait)
            with pytest.MonkeyPatch.context() as mp:
                mp.setattr(
                    fake_ur, "FakeURController", partial(fake_ur.FakeURController, protective_stop_unlock_delay_s=1.0)
                )
                cell = build_cell(self.config, start_simulators=True)
            try:
                cell.connect()
            except BaseException:
                cell.close()
                raise
            self.cell = cell
        return self.cell

    def discard(self) -> None:
        cell, self.cell = self.cell, None
        if cell is not None:
            cell.close()


def settle(rig: Rig) -> bool:
    """After a test on a shared cell: clear injected faults, acknowledge a fault left behind; True when healthy."""
    try:
        camera: Any = rig.cell.camera
        for fake in (rig.robot_fake, rig.track_fake, camera):
            fake.clear_faults()
        if rig.runner.machine.state is CellState.FAULT and not rig.runner.acknowledge("test teardown"):
            return False
        track = rig.cell.track
        return rig.cell.robot.state().healthy and (track is None or not track.status().fault) and rig.arc_is_off()
    except (DriverError, OSError, RuntimeError, ValueError):  # the fakes' handles raise TimeoutError, ValueError
        return False


@pytest.fixture
def fanuc(tmp_path: Path) -> Iterator[Rig]:
    rig = open_rig(cell_config(tmp_path, EXAMPLE["fanuc"]), tmp_path)
    try:
        yield rig
    finally:
        close_rig(rig)


@pytest.fixture(scope="module")
def ur5_cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SharedCell]:
    shared = SharedCell(cell_config(tmp_path_factory.mktemp("ur5-cell"), EXAMPLE["ur5"]))
    try:
        yield shared
    finally:
        shared.discard()


@pytest.fixture
def ur5(ur5_cell: SharedCell, tmp_path: Path) -> Iterator[Rig]:
    shared = ur5_cell.get()
    # a fresh fake camera: its frames (noise seeds) count from 0 in every test, as on a fresh cell
    camera = build_camera(shared.config, robot=shared.robot, track=shared.track)
    camera.connect()
    rig = attach_rig("ur5", dataclasses.replace(shared, camera=camera), tmp_path)
    try:
        yield rig
    finally:
        healthy = settle(rig)
        rig.journal.close()
        if not healthy:
            ur5_cell.discard()


on_both_robots = pytest.mark.parametrize("robot", ROBOTS, scope="module")
"""For a test whose body does not depend on the robot: it takes ``rig`` and runs on the FANUC rig, then on the UR5
rig (module scope: pytest runs all the FANUC ones first, then all the UR5 ones)."""


@pytest.fixture
def rig(request: pytest.FixtureRequest, robot: str) -> Rig:
    """The ``fanuc`` or the ``ur5`` rig, as the test's ``robot`` parameter says (see :data:`on_both_robots`)."""
    the_rig: Rig = request.getfixturevalue(robot)
    return the_rig


class DoutLog:
    """The digital output writes the fake FANUC accepts from the host from now on, with the tool position (mm) at
    that instant (the fake's ``dout`` events; the watchdog's own switching, which has a ``cause``, left out)."""

    def __init__(self, fake: Any) -> None:
        self.fake = fake
        self.n_events = len(fake.events())

    @property
    def writes(self) -> list[tuple[int, bool, np.ndarray]]:
        return [
            (int(e["port"]), bool(e["value"]), np.asarray(e["xyz_mm"]))
            for e in self.fake.events()[self.n_events :]
            if e["kind"] == "dout" and "cause" not in e
        ]


def state_changes(journal: Journal, job_id: int) -> list[str]:
    """The machine states a job went through (steps inside a state are left out)."""
    return [e.to_state for e in journal.events(job_id) if e.from_state != e.to_state]


def on_weld_pose(runner: JobRunner, pass_number: int, pose: int, action: Callable[[], None]) -> None:
    """Call ``action`` (once) when travel pose ``pose`` of pass ``pass_number`` is reported done."""
    fired = threading.Event()

    def progress(kind: str, data: dict[str, Any]) -> None:
        if kind == "weld" and data["pass"] == pass_number and data["pose"] >= pose and not fired.is_set():
            fired.set()
            action()

    runner.on_progress = progress


def on_state(runner: JobRunner, state: str, action: Callable[[], None]) -> None:
    fired = threading.Event()

    def progress(kind: str, data: dict[str, Any]) -> None:
        if kind == "state" and data["state"] == state and not fired.is_set():
            fired.set()
            action()

    runner.on_progress = progress


def assert_fault(rig: Rig, report: JobReport, *, words: tuple[str, ...], outcome: str = "fault") -> None:
    assert report.state == "fault" and report.outcome == outcome, report
    assert report.reason is not None
    for word in words:
        assert word in report.reason, (word, report.reason)
    record = rig.journal.job(report.job_id)
    assert record.state == "failed" and record.error == report.reason
    assert record.report is not None and record.report["outcome"] == outcome
    assert state_changes(rig.journal, report.job_id)[-1] == "fault"


def follow_up_job_runs(rig: Rig, *, clear: Callable[[], None] | None = None, weld: bool = True) -> JobReport:
    """After a fault: the cause is cleared, an operator acknowledges, and a job runs: it welds the long seams
    (``weld``) or, quicker, homes, captures, plans and validates a path that the operator then declines."""
    runner = rig.runner
    runner.on_progress = None
    with pytest.raises(CellFaulted, match="acknowledge"):
        runner.run(make_job(job_text()))
    if clear is not None:
        clear()
    assert runner.acknowledge("Ada")
    assert runner.machine.state is CellState.IDLE
    if weld:
        report = runner.run(make_job(job_text(min_length_m=0.1)))
        assert (report.state, report.outcome) == ("done", "welded"), report
        assert report.seams_welded == report.seams_planned >= 2
    else:
        report = runner.run(make_job(job_text(approval=True)), approve=lambda path: None)
        assert (report.state, report.outcome) == ("idle", "rejected"), report
        assert report.seams_planned >= 8 and report.seams_welded == 0 and report.poses_sent == 2
        assert rig.journal.job(report.job_id).state == "cancelled"
    assert rig.arc_is_off()
    return report


def commanded_poses(path_poses: list[np.ndarray], got: list[np.ndarray]) -> None:
    assert len(got) == len(path_poses)
    for k, (X_want, X_got) in enumerate(zip(path_poses, got, strict=True)):
        dist_mm = float(np.linalg.norm(X_want[:3, 3] - X_got[:3, 3])) * 1e3
        angle_deg = math.degrees(rotation_angle_rad(X_want, X_got))
        assert dist_mm <= 0.1 and angle_deg <= 0.1, (k, dist_mm, angle_deg)


def expected_poses(rig: Rig, job: Job) -> list[np.ndarray]:
    """Home, each capture pose, every waypoint of the planned path, home: what the robot must have been sent."""
    data = rig.runner.current
    assert data is not None and data.path is not None
    home = rig.config.home.pose
    assert home is not None
    poses = [home.X_base_tool()]
    poses += [rig.runner.capture_pose(job, i) for i in range(len(job.captures))]
    poses += [w.X_base_tcp for _i, _p, w in data.path.waypoints()]
    poses.append(home.X_base_tool())
    return poses
