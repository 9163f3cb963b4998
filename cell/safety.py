"""Safety checks on a planned :class:`cell.planning.WeldPath`: refuse with a reason, or let it go.

:func:`validate` re-derives everything it checks from the commanded numbers (``X_base_tcp`` of each waypoint and
its pass's track position) instead of trusting the planner, and raises :class:`cell.errors.SafetyViolation` on the
first broken rule, naming the pose (pass, seam, waypoint label), the value and the limit. Rules:

1. every number finite; every pose a proper rigid transform (orthonormal rotation, det +1, last row 0 0 0 1);
2. every track position within the track's limits (0 only, without a track);
3. every TCP position inside the workspace box (world frame: the cell's floor and fixtures do not move with the
   carriage) and within the reach sphere (base frame: the frame the robot is commanded in, i.e. with the track
   offset of its pass taken into account);
4. every speed in (0, ``max_speed_m_s``], every blend radius in [0, ``max_blend_m``], accelerations likewise;
5. no jump between consecutive poses: translation <= ``max_step_m`` and rotation <= ``max_step_rad``, except
   into a pose reached by a declared air move (:attr:`cell.planning.MoveKind.AIR`);
6. the torch never points up: the angle between the TCP's z axis and world -z is <= ``max_tilt_rad``.

A dry run is :func:`cell.planning.plan_weld_path` followed by :func:`validate`: nothing moves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cell.errors import ConfigError, SafetyViolation
from cell.planning import CellGeometry, MoveKind, SeamPass, Waypoint, WeldPath
from cell.world_seams import X_world_base
from perception.transforms import TransformError, check_X, rotation_angle_rad

FloatArray = NDArray[np.float64]

@dataclass(frozen=True)
class SafetyLimits:
    """The cell's limits. Box corners ``workspace_min_world``/``workspace_max_world`` ((3,), metres, world frame =
    base with the track at 0); ``geometry``: reach sphere (base frame) and track limits; speeds m/s, blend m,
    acceleration m/s², steps m and rad, ``max_tilt_rad`` from straight down."""

    workspace_min_world: FloatArray
    workspace_max_world: FloatArray
    geometry: CellGeometry
    max_speed_m_s: float = 0.25
    max_accel_m_s2: float = 1.2
    max_blend_m: float = 0.01
    max_step_m: float = 0.1
    max_step_rad: float = math.radians(20.0)
    max_tilt_rad: float = math.radians(60.0)
    down_world: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, -1.0]))

    def __post_init__(self) -> None:
        lo = np.asarray(self.workspace_min_world, dtype=np.float64).reshape(3)
        hi = np.asarray(self.workspace_max_world, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo < hi)):
            raise ConfigError(f"safety: workspace box needs finite min < max, got {lo.tolist()} .. {hi.tolist()}")
        down = np.asarray(self.down_world, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(down)) and abs(np.linalg.norm(down) - 1.0) < 1e-6):
            raise ConfigError(f"safety: down_world must be a unit vector, got {down.tolist()}")
        object.__setattr__(self, "workspace_min_world", lo)
        object.__setattr__(self, "workspace_max_world", hi)
        object.__setattr__(self, "down_world", down)
        for name in ("max_speed_m_s", "max_accel_m_s2", "max_step_m", "max_step_rad", "max_tilt_rad"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"safety: {name} must be finite and > 0, got {value}")
        if not (math.isfinite(self.max_blend_m) and self.max_blend_m >= 0):
            raise ConfigError(f"safety: max_blend_m must be finite and >= 0, got {self.max_blend_m}")


def _where(i: int, p: SeamPass, w: Waypoint) -> str:
    return f"pass {i + 1} (seam {p.seam_id}) {w.label}"


def _finite(value: float, what: str) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise SafetyViolation(f"{what} is {v}, not a finite number")
    return v


def check_pose(X: ArrayLike, what: str) -> FloatArray:
    """``X`` as a (4, 4) array if it is a finite, proper rigid transform (:func:`perception.transforms.check_X`,
    the one home of that rule); SafetyViolation naming ``what`` otherwise."""
    try:
        return check_X(X, name=f"{what} pose")
    except TransformError as err:
        raise SafetyViolation(str(err)) from err


def _check_path_settings(weld_path: WeldPath, limits: SafetyLimits) -> None:
    """What holds for the whole path: its acceleration and dwell times, and the track axis it was planned with."""
    params = weld_path.params
    _finite(params.accel_m_s2, "acceleration accel_m_s2")
    if not 0 < params.accel_m_s2 <= limits.max_accel_m_s2:
        raise SafetyViolation(
            f"acceleration {params.accel_m_s2:.4f} m/s^2 outside (0, {limits.max_accel_m_s2:.4f}] m/s^2"
        )
    for name in ("arc_on_dwell_s", "arc_off_dwell_s"):
        _finite(getattr(params, name), name)
    axis = np.asarray(weld_path.track_axis_base, dtype=np.float64)
    if not np.all(np.isfinite(axis)) or not np.allclose(axis, limits.geometry.axis_base, atol=1e-9):
        raise SafetyViolation(
            f"the path was planned with track axis {axis.tolist()} but the cell's is "
            f"{limits.geometry.axis_base.tolist()}"
        )


def validate(weld_path: WeldPath, limits: SafetyLimits) -> None:
    """Raise :class:`SafetyViolation` naming the first pose, value and limit that break a rule (module docstring).

    Returns None when the whole path is acceptable.
    """
    _check_path_settings(weld_path, limits)
    reach = limits.geometry.reach
    track = limits.geometry.track
    lo, hi = limits.workspace_min_world, limits.workspace_max_world
    prev: tuple[FloatArray, str] | None = None
    for i, p, w in weld_path.waypoints():
        where = _where(i, p, w)
        t = _finite(p.track_position_m, f"{where}: track position")
        t_min, t_max = (track.min_m, track.max_m) if track is not None else (0.0, 0.0)
        if not t_min <= t <= t_max:
            raise SafetyViolation(
                f"{where}: track position {t:.4f} m outside the track limits [{t_min:.4f}, {t_max:.4f}] m"
            )
        X_base_tcp = check_pose(w.X_base_tcp, where)
        speed = _finite(w.speed_m_s, f"{where}: speed")
        if not 0 < speed <= limits.max_speed_m_s:
            raise SafetyViolation(f"{where}: speed {speed:.4f} m/s outside (0, {limits.max_speed_m_s:.4f}] m/s")
        blend = _finite(w.blend_m, f"{where}: blend radius")
        if not 0 <= blend <= limits.max_blend_m:
            raise SafetyViolation(f"{where}: blend radius {blend:.4f} m outside [0, {limits.max_blend_m:.4f}] m")

        # reach: in the commanded (base) frame
        p_base = X_base_tcp[:3, 3]
        d = float(np.linalg.norm(p_base - reach.centre_base))
        if d > reach.radius_m:
            raise SafetyViolation(
                f"{where}: TCP at {_fmt(p_base)} m (base frame, track at {t:.4f} m) is {d:.4f} m from the reach "
                f"centre, beyond the reach radius {reach.radius_m:.4f} m"
            )
        # workspace: in the world frame
        X_world_tcp = X_world_base(t, limits.geometry.axis_base) @ X_base_tcp
        p_world = X_world_tcp[:3, 3]
        for k, name in enumerate("xyz"):
            if p_world[k] < lo[k]:
                raise SafetyViolation(
                    f"{where}: TCP {name} = {p_world[k]:.4f} m (world) below the workspace box min {name} = "
                    f"{lo[k]:.4f} m"
                )
            if p_world[k] > hi[k]:
                raise SafetyViolation(
                    f"{where}: TCP {name} = {p_world[k]:.4f} m (world) above the workspace box max {name} = "
                    f"{hi[k]:.4f} m"
                )
        # torch direction
        z_world = X_world_tcp[:3, 2]
        tilt = math.acos(float(np.clip(z_world @ limits.down_world, -1.0, 1.0)))
        if tilt > limits.max_tilt_rad:
            raise SafetyViolation(
                f"{where}: torch axis {_fmt(z_world)} is {math.degrees(tilt):.2f} deg from straight down, "
                f"beyond the limit {math.degrees(limits.max_tilt_rad):.2f} deg (the torch would point upward)"
            )
        # jumps: in world, so a track move between passes is not mistaken for a robot jump (those are air moves)
        if prev is not None and w.kind is not MoveKind.AIR:
            X_prev, prev_where = prev
            step = float(np.linalg.norm(p_world - X_prev[:3, 3]))
            if step > limits.max_step_m:
                raise SafetyViolation(
                    f"{where}: jump of {step:.4f} m from {prev_where} exceeds max_step_m {limits.max_step_m:.4f} m "
                    f"(only air moves may jump)"
                )
            angle = rotation_angle_rad(X_prev, X_world_tcp)
            if angle > limits.max_step_rad:
                raise SafetyViolation(
                    f"{where}: rotation step of {math.degrees(angle):.2f} deg from {prev_where} exceeds max_step_rad "
                    f"{math.degrees(limits.max_step_rad):.2f} deg (only air moves may jump)"
                )
        prev = (X_world_tcp, where)


def _fmt(v: FloatArray) -> str:
    return "[" + ", ".join(f"{x:.4f}" for x in v) + "]"
