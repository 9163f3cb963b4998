"""What the cell checks of a job before it is queued or run, against the cell config's ``[safety]`` and ``[track]``:
the :class:`cell.safety.SafetyLimits` of a config, a job's limits (:func:`check_job`), its capture poses in the
robot's base frame (:func:`capture_pose`) and which of them, or home, the robot stands at (:func:`station_of`)."""

from __future__ import annotations

import math

import numpy as np

from cell.config import CellConfig
from cell.errors import ConfigError
from cell.job import Job, weld_params
from cell.planning import CellGeometry, Reach, TrackAxis
from cell.safety import SafetyLimits
from cell.world_seams import X_world_base
from perception.transforms import rotation_angle_rad

MAX_DWELL_S = 10.0
"""The longest arc-on or arc-off dwell a job may ask for."""
STATION_TOLERANCE_M = 0.005
STATION_TOLERANCE_RAD = math.radians(1.0)
STATION_TRACK_TOLERANCE_M = 0.001
"""How close the tool (position, orientation) and the carriage must be to a pose for :func:`station_of` to say the
robot stands there: a stopped controller settles within a millimetre; a fault mid-move leaves it centimetres off."""


def safety_limits(config: CellConfig) -> SafetyLimits:
    """The :class:`SafetyLimits` of ``config``'s ``[safety]`` and ``[track]``; ConfigError without ``[safety]``."""
    sc = config.safety
    if sc is None:
        raise ConfigError(
            f"{config.where('safety')}: running jobs needs a [safety] table (workspace box, reach, limits); "
            "see examples/sim-cell.toml"
        )
    track = None
    if config.track.kind != "none":
        lo, hi = config.track.soft_limits_m
        track = TrackAxis(lo, hi, np.asarray(sc.track_axis_base, dtype=np.float64))
    reach = Reach(sc.reach_radius_m, sc.reach_preferred_m, np.asarray(sc.reach_centre_base, dtype=np.float64))
    return SafetyLimits(
        workspace_min_world=np.asarray(sc.workspace_min_world, dtype=np.float64),
        workspace_max_world=np.asarray(sc.workspace_max_world, dtype=np.float64),
        geometry=CellGeometry(reach, track),
        max_speed_m_s=sc.max_speed_m_s,
        max_accel_m_s2=sc.max_accel_m_s2,
        max_blend_m=sc.max_blend_m,
        max_step_m=sc.max_step_m,
        max_step_rad=math.radians(sc.max_step_deg),
        max_tilt_rad=math.radians(sc.max_tilt_deg),
    )


def check_job(config: CellConfig, limits: SafetyLimits, job: Job) -> None:
    """Refuse (ConfigError naming the job's key and the cell's limit) a job the cell must not even queue: speeds,
    acceleration and blend over the cell's ``[safety]`` limits, another arc output than the cell's (its
    controller-side watchdog covers that one), capture poses beyond the reach or track positions outside the
    track's soft limits, dwell times and distances out of any sensible range, seam ids that are not 31-bit
    integers. Numbers are finite already (the job's tables refuse inf and nan)."""
    lim = limits
    params = weld_params(config.welding, job.spec.welding, job.spec.seams.seam_filter())
    w = job.spec.welding
    for key, value, limit, name in (
        ("travel_speed_m_s", params.travel_speed_m_s, lim.max_speed_m_s, "max_speed_m_s"),
        ("approach_speed_m_s", params.approach_speed_m_s, lim.max_speed_m_s, "max_speed_m_s"),
        ("air_speed_m_s", params.air_speed_m_s, lim.max_speed_m_s, "max_speed_m_s"),
        ("accel_m_s2", params.accel_m_s2, lim.max_accel_m_s2, "max_accel_m_s2"),
        ("blend_m", params.blend_m, lim.max_blend_m, "max_blend_m"),
    ):
        if not value <= limit:
            raise ConfigError(
                f"{job.where(f'welding.{key}')}: {value} exceeds the cell's limit [safety] {name} = {limit}"
            )
    reach = lim.geometry.reach
    for key in ("approach_m", "retract_m", "stickout_m"):
        value = getattr(params, key)
        if not value <= reach.radius_m:
            raise ConfigError(
                f"{job.where(f'welding.{key}')}: {value} m exceeds the reach radius [safety] reach_radius_m = "
                f"{reach.radius_m} m"
            )
    for key in ("arc_on_dwell_s", "arc_off_dwell_s"):
        value = getattr(params, key)
        if not value <= MAX_DWELL_S:
            raise ConfigError(f"{job.where(f'welding.{key}')}: {value} s exceeds the limit of {MAX_DWELL_S} s")
    cell_arc = config.welding.arc_output if config.welding.arc_output is not None else 0
    if w.arc_output is not None and w.arc_output != cell_arc:
        raise ConfigError(
            f"{job.where('welding.arc_output')}: {w.arc_output} is not the cell's arc output [welding] "
            f"arc_output = {cell_arc} (the one its controller-side watchdog switches off)"
        )
    for seam_id in job.spec.seams.ids or ():
        if not 0 <= seam_id < 2**31:
            raise ConfigError(f"{job.where('seams.ids')}: {seam_id} is not a seam id (0 <= id < 2^31)")
    track = lim.geometry.track
    for i, capture in enumerate(job.captures):
        t = capture.track_position_m
        if track is None and t != 0.0:
            raise ConfigError(
                f"{job.where(f'capture[{i}].track_position_m')}: {t} m, but the cell has no track ([track])"
            )
        if track is not None and not track.min_m <= t <= track.max_m:
            raise ConfigError(
                f"{job.where(f'capture[{i}].track_position_m')}: {t} m is outside the track's soft limits "
                f"[track] soft_limit_min_m..soft_limit_max_m = {track.min_m}..{track.max_m} m"
            )
        X = capture_pose(config, limits, job, i)
        d = float(np.linalg.norm(X[:3, 3] - reach.centre_base))
        if not d <= reach.radius_m:
            raise ConfigError(
                f"{job.where(f'capture[{i}]')}: the capture pose is {d:.3f} m from the reach centre, beyond "
                f"[safety] reach_radius_m = {reach.radius_m} m"
            )


def capture_pose(config: CellConfig, limits: SafetyLimits, job: Job, index: int) -> np.ndarray:
    """(4, 4) ``X_base_tool`` of capture ``index`` of ``job`` with the carriage at its track position."""
    spec = job.captures[index]
    X = spec.X_base_tool()
    if job.spec.frame == "base":
        return X
    fixture = config.fixture
    if fixture is None:
        raise ConfigError(
            f"{job.where('frame')}: the job's poses are fixture-relative but {config.where('fixture')} "
            "is missing: add [fixture] X_world_fixture to the cell config"
        )
    X_world_fixture = np.asarray(fixture.X_world_fixture, dtype=np.float64)
    X_base_world = X_world_base(-spec.track_position_m, limits.geometry.axis_base)
    return X_base_world @ X_world_fixture @ X


def station_of(
    config: CellConfig, limits: SafetyLimits, job: Job, X_base_tool: np.ndarray, track_position_m: float
) -> str | None:
    """Where the robot stands, of the places a dry run may capture from: ``"home"`` (the cell's ``[home]`` pose with
    the carriage at its home position), ``"capture pose N"`` (1-based: the job's capture N with the carriage at its
    track position), or None (anywhere else: where a fault left it). ``X_base_tool``: (4, 4), the robot's measured
    pose; ``track_position_m``: the carriage's measured position (0 without a track)."""

    def at(X: np.ndarray, track_m: float) -> bool:
        return bool(
            np.linalg.norm(X_base_tool[:3, 3] - X[:3, 3]) <= STATION_TOLERANCE_M
            and rotation_angle_rad(X_base_tool, X) <= STATION_TOLERANCE_RAD
            and abs(track_position_m - track_m) <= STATION_TRACK_TOLERANCE_M
        )

    home = config.home
    if home.pose is not None and at(home.pose.X_base_tool(), home.track_position_m):
        return "home"
    for i, spec in enumerate(job.captures):
        if at(capture_pose(config, limits, job, i), spec.track_position_m):
            return f"capture pose {i + 1}"
    return None
