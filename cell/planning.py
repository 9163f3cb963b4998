"""Weld planning: detected seams and welding parameters in, a :class:`WeldPath` out. Pure functions, no devices.

Frames (metres, radians):

- ``base``: the robot base frame. The ground track's carriage carries the base, so the base moves with the
  track position ``t``; the robot is always commanded in it (``X_base_tcp``).
- ``world``: the robot base frame with the track at 0 (:mod:`cell.world_seams`: ``X_world_base(t)``, the seams of
  several captures merged there); ordering (:mod:`cell.route`) works here.
- ``torch``: a seam pose from the detector: z along the torch pointing into the joint, x the travel direction
  (:mod:`perception.seams`). The planner takes the detector's poses as *neutral* (run the detector with zero
  work and travel angles, its default) and applies :attr:`WeldParams.work_angle_rad` and
  :attr:`WeldParams.travel_angle_rad` itself, after choosing the travel direction.
- ``tcp``: the **contact tip**. The robot's configured TCP is the end of the contact tube; the wire sticks out
  ``stickout_m`` beyond it along the torch axis and its end is on the seam, so
  ``X_torch_tcp = Trans(0, 0, -stickout_m)`` (same orientation as the torch).

A seam pass is: ``approach`` (the arc-on TCP pose backed off ``approach_m`` along -z; reached by an air move),
``arc_on`` (the first travel pose, reached along the torch axis; the arc is switched on there), the travel poses
(the last one is ``arc_off``) and ``retract`` (the arc-off TCP pose backed off ``retract_m`` along -z).

Ordering keeps air moves short (:mod:`cell.route`): each pass's retract pose to the next pass's approach pose,
each seam welded in whichever direction makes the route shortest.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation, Slerp

from cell.errors import ConfigError, SafetyViolation
from cell.route import order_seams, route_length
from cell.world_seams import DEFAULT_TRACK_AXIS_BASE, SeamFilter, WorldSeam, X_world_base, filter_seams
from perception.transforms import make_X

FloatArray = NDArray[np.float64]


# ================================================================================================ parameters
@dataclass(frozen=True)
class WeldParams:
    """Welding parameters, SI. Speeds in m/s, distances in m, angles in rad, times in s.

    ``work_angle_rad``: rotation of the torch about the travel axis (torch x), positive towards torch +y; when a
    seam is welded backwards the planner negates it so the torch still leans towards the same plate.
    ``travel_angle_rad``: rotation about torch y, positive = push (the torch points ahead of the arc), whatever
    the direction. ``stickout_m``: contact tip to work distance (the TCP is the contact tip).
    ``approach_m``/``retract_m``: back-off along -z before arc on and after arc off.
    ``blend_m``: blend radius between travel poses (clamped to half the neighbouring segments; 0 at the arc-on
    and arc-off points and for approach/retract). ``max_segment_m``/``max_segment_rad``: longer travel segments
    are subdivided (so the safety step limits stay meaningful for sparse linear seams).
    Arc: ``arc_do_index`` is the :class:`drivers.protocols.Robot` digital output index (UR standard output n,
    FANUC ``DO[n + 1]``); ``weld_job`` (the power source's job/schedule number), ``voltage_v`` and
    ``wire_feed_m_s`` are recorded in programs and reports; ``arc_on_dwell_s`` waits after arc on before
    travelling, ``arc_off_dwell_s`` waits at the end with the arc on (crater fill).
    """

    travel_speed_m_s: float = 0.008
    approach_speed_m_s: float = 0.05
    air_speed_m_s: float = 0.25
    accel_m_s2: float = 0.5
    blend_m: float = 0.001
    work_angle_rad: float = 0.0
    travel_angle_rad: float = 0.0
    stickout_m: float = 0.015
    approach_m: float = 0.05
    retract_m: float = 0.05
    max_segment_m: float = 0.02
    max_segment_rad: float = math.radians(5.0)
    arc_do_index: int = 0
    weld_job: int | None = None
    voltage_v: float | None = None
    wire_feed_m_s: float | None = None
    arc_on_dwell_s: float = 0.0
    arc_off_dwell_s: float = 0.0
    seam_filter: SeamFilter = field(default_factory=SeamFilter)

    def __post_init__(self) -> None:
        positive = ["travel_speed_m_s", "approach_speed_m_s", "air_speed_m_s", "accel_m_s2"]
        positive += ["max_segment_m", "max_segment_rad"]
        non_negative = ("blend_m", "stickout_m", "approach_m", "retract_m", "arc_on_dwell_s", "arc_off_dwell_s")
        for name in positive:
            _require(name, getattr(self, name), lambda v: v > 0.0, "> 0")
        for name in non_negative:
            _require(name, getattr(self, name), lambda v: v >= 0.0, ">= 0")
        for name in ("work_angle_rad", "travel_angle_rad"):
            _require(name, getattr(self, name), lambda v: abs(v) < math.pi / 2, "within (-pi/2, pi/2)")
        for name in ("voltage_v", "wire_feed_m_s"):
            value = getattr(self, name)
            if value is not None:
                _require(name, value, lambda v: v > 0.0, "> 0")
        if isinstance(self.arc_do_index, bool) or not isinstance(self.arc_do_index, int) or self.arc_do_index < 0:
            raise ConfigError(f"weld params: arc_do_index must be an integer >= 0, got {self.arc_do_index!r}")
        if self.weld_job is not None and (
            isinstance(self.weld_job, bool) or not isinstance(self.weld_job, int) or self.weld_job < 0
        ):
            raise ConfigError(f"weld params: weld_job must be an integer >= 0, got {self.weld_job!r}")


def _require(name: str, value: Any, ok: Any, what: str) -> None:
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"weld params: {name} must be a number, got {value!r}") from err
    if not (math.isfinite(v) and ok(v)):
        raise ConfigError(f"weld params: {name} must be finite and {what}, got {value!r}")


@dataclass(frozen=True)
class Reach:
    """The robot's reach: a sphere of ``radius_m`` around ``centre_base`` ((3,), metres, in the base frame, which
    the carriage carries). ``preferred_m``: the distance from the centre at which seams are best welded."""

    radius_m: float
    preferred_m: float
    centre_base: FloatArray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        c = np.asarray(self.centre_base, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(c)):
            raise ConfigError(f"reach: centre_base must be finite, got {c.tolist()}")
        object.__setattr__(self, "centre_base", c)
        if not (math.isfinite(self.radius_m) and self.radius_m > 0):
            raise ConfigError(f"reach: radius_m must be finite and > 0, got {self.radius_m}")
        if not (math.isfinite(self.preferred_m) and 0 <= self.preferred_m <= self.radius_m):
            raise ConfigError(f"reach: preferred_m must lie in [0, radius_m={self.radius_m}], got {self.preferred_m}")


@dataclass(frozen=True)
class TrackAxis:
    """The ground track: positions ``min_m``..``max_m`` (its soft limits) along ``axis_base`` ((3,) unit)."""

    min_m: float
    max_m: float
    axis_base: FloatArray = field(default_factory=lambda: np.array(DEFAULT_TRACK_AXIS_BASE))

    def __post_init__(self) -> None:
        a = np.asarray(self.axis_base, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(a)) and abs(np.linalg.norm(a) - 1.0) < 1e-6):
            raise ConfigError(f"track: axis_base must be a unit 3-vector, got {a.tolist()}")
        object.__setattr__(self, "axis_base", a)
        if not (math.isfinite(self.min_m) and math.isfinite(self.max_m) and self.min_m <= self.max_m):
            raise ConfigError(f"track: need finite min_m <= max_m, got {self.min_m}, {self.max_m}")


@dataclass(frozen=True)
class CellGeometry:
    """Reach of the robot and its track (None: no track, the base stays at the world origin)."""

    reach: Reach
    track: TrackAxis | None = None

    @property
    def axis_base(self) -> FloatArray:
        return self.track.axis_base if self.track is not None else np.array(DEFAULT_TRACK_AXIS_BASE)


# ================================================================================================ the path
class MoveKind(StrEnum):
    """How the robot reaches a waypoint."""

    AIR = "air"  # from wherever it is (start, the previous retract) to an approach pose: torch cold, free jump
    APPROACH = "approach"  # approach pose -> arc-on point, along the torch axis
    WELD = "weld"  # along the seam with the arc on
    RETRACT = "retract"  # arc-off point -> retract pose, along -torch axis


@dataclass(frozen=True)
class Waypoint:
    """One commanded TCP pose: ``X_base_tcp`` (4, 4), metres, in the base frame at its pass's track position;
    ``speed_m_s`` and ``blend_m`` of the move that reaches it (blend 0 = stop exactly: FINE)."""

    X_base_tcp: FloatArray
    speed_m_s: float
    blend_m: float
    kind: MoveKind
    label: str

    def __post_init__(self) -> None:
        X = np.asarray(self.X_base_tcp, dtype=np.float64)
        if X.shape != (4, 4):
            raise ValueError(f"waypoint {self.label}: X_base_tcp must be (4, 4), got {X.shape}")
        object.__setattr__(self, "X_base_tcp", X)
        object.__setattr__(self, "kind", MoveKind(self.kind))


@dataclass(frozen=True)
class SeamPass:
    """One seam welded once: ``waypoints`` are approach (AIR), arc_on (APPROACH), travel (WELD, the last one is
    arc_off) and retract (RETRACT). ``track_position_m``: where the carriage stands for the whole pass.
    ``reversed``: welded against the detector's point order. Numbers are checked by :func:`cell.safety.validate`,
    not here, so that a bad path can be represented and refused with a reason."""

    seam_id: int
    kind: str
    sources: tuple[tuple[int, int], ...]
    reversed: bool
    track_position_m: float
    waypoints: tuple[Waypoint, ...]
    length_m: float

    def __post_init__(self) -> None:
        kinds = [w.kind for w in self.waypoints]
        ok = (
            len(kinds) >= 4
            and kinds[0] is MoveKind.AIR
            and kinds[1] is MoveKind.APPROACH
            and kinds[-1] is MoveKind.RETRACT
            and all(k is MoveKind.WELD for k in kinds[2:-1])
        )
        if not ok:
            raise ValueError(
                f"seam pass {self.seam_id}: waypoints must be air, approach, weld (>= 1), retract; got {kinds}"
            )

    @property
    def approach(self) -> Waypoint:
        return self.waypoints[0]

    @property
    def arc_on(self) -> Waypoint:
        return self.waypoints[1]

    @property
    def travel(self) -> tuple[Waypoint, ...]:
        """The poses from arc_on to arc_off, both included (what is welded)."""
        return self.waypoints[1:-1]

    @property
    def arc_off(self) -> Waypoint:
        return self.waypoints[-2]

    @property
    def retract(self) -> Waypoint:
        return self.waypoints[-1]


@dataclass(frozen=True)
class WeldPath:
    """Everything to weld, in order. ``track_axis_base``: (3,) the carriage direction the passes were planned
    with; ``air_length_m``: the summed air-move length the ordering minimised; ``skipped``: (seam id, reason)."""

    passes: tuple[SeamPass, ...]
    params: WeldParams
    track_axis_base: FloatArray = field(default_factory=lambda: np.array(DEFAULT_TRACK_AXIS_BASE))
    air_length_m: float = 0.0
    skipped: tuple[tuple[int, str], ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "track_axis_base", np.asarray(self.track_axis_base, dtype=np.float64).reshape(3))

    def waypoints(self) -> Iterator[tuple[int, SeamPass, Waypoint]]:
        """(pass index, pass, waypoint) in execution order."""
        for i, p in enumerate(self.passes):
            for w in p.waypoints:
                yield i, p, w

    def X_world_tcp(self, seam_pass: SeamPass, waypoint: Waypoint) -> FloatArray:
        return X_world_base(seam_pass.track_position_m, self.track_axis_base) @ waypoint.X_base_tcp

    @property
    def track_positions_m(self) -> tuple[float, ...]:
        """The distinct track positions in execution order (consecutive repeats collapsed)."""
        out: list[float] = []
        for p in self.passes:
            if not out or p.track_position_m != out[-1]:
                out.append(p.track_position_m)
        return tuple(out)

    def split_at_track_moves(self) -> list[WeldPath]:
        """One path per run of passes at the same track position (a robot program cannot move the track)."""
        groups: list[list[SeamPass]] = []
        for p in self.passes:
            if groups and groups[-1][-1].track_position_m == p.track_position_m:
                groups[-1].append(p)
            else:
                groups.append([p])
        return [WeldPath(tuple(g), self.params, self.track_axis_base, self.air_length_m, self.skipped) for g in groups]

    def summary(self) -> dict[str, Any]:
        """A JSON-ready description for job reports and dry runs."""
        return {
            "passes": [
                {
                    "seam_id": p.seam_id,
                    "kind": p.kind,
                    "sources": [list(s) for s in p.sources],
                    "reversed": p.reversed,
                    "track_position_m": round(p.track_position_m, 6),
                    "length_m": round(p.length_m, 6),
                    "waypoints": len(p.waypoints),
                }
                for p in self.passes
            ],
            "air_length_m": round(self.air_length_m, 6),
            "weld_length_m": round(sum(p.length_m for p in self.passes), 6),
            "skipped": [{"seam_id": i, "reason": r} for i, r in self.skipped],
        }


# ================================================================================================ pass geometry
def _subdivide(X: FloatArray, *, max_m: float, max_rad: float) -> FloatArray:
    """(N, 4, 4) poses with poses interpolated (linear position, slerp rotation) into over-long segments."""
    out = [X[0]]
    for A, B in itertools.pairwise(X):
        d = float(np.linalg.norm(B[:3, 3] - A[:3, 3]))
        rots = Rotation.from_matrix(np.stack([A[:3, :3], B[:3, :3]]))
        angle = float((rots[0].inv() * rots[1]).magnitude())
        n = max(1, math.ceil(d / max_m - 1e-9), math.ceil(angle / max_rad - 1e-9))
        if n > 1:
            u = np.arange(1, n) / n
            R = Slerp([0.0, 1.0], rots)(u).as_matrix()
            for k, uk in enumerate(u):
                out.append(make_X(R[k], (1 - uk) * A[:3, 3] + uk * B[:3, 3]))
        out.append(B)
    return np.stack(out)


def pass_poses_world(seam: WorldSeam, params: WeldParams, *, reverse: bool) -> FloatArray:
    """(N + 2, 4, 4) ``X_world_tcp`` of one pass: approach, the travel poses (arc on ... arc off), retract.

    Travel poses: the seam's neutral torch poses (reversed if asked), subdivided, turned by the work and travel
    angles, then moved back ``stickout_m`` along their own (tilted) z so the wire tip is on the seam.
    """
    s = seam.reversed() if reverse else seam
    X = _subdivide(s.X_world_torch, max_m=params.max_segment_m, max_rad=params.max_segment_rad)
    work = -params.work_angle_rad if reverse else params.work_angle_rad
    local = Rotation.from_euler("XY", [work, params.travel_angle_rad]).as_matrix()
    X = X.copy()
    X[:, :3, :3] = X[:, :3, :3] @ local
    X[:, :3, 3] -= params.stickout_m * X[:, :3, 2]
    approach = X[0].copy()
    approach[:3, 3] -= params.approach_m * X[0, :3, 2]
    retract = X[-1].copy()
    retract[:3, 3] -= params.retract_m * X[-1, :3, 2]
    return np.concatenate([approach[None], X, retract[None]])


def _travel_blends(positions: FloatArray, blend_m: float) -> list[float]:
    """Blend radius at each travel pose: ``blend_m`` clamped to half of either neighbouring segment (a larger
    radius makes the blends overlap, which controllers refuse); 0 at the first and last pose."""
    seg = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    out = [0.0]
    for k in range(1, len(positions) - 1):
        out.append(float(min(blend_m, 0.5 * seg[k - 1], 0.5 * seg[k])))
    out.append(0.0)
    return out


def _build_pass(
    seam: WorldSeam,
    X_world_tcp: FloatArray,
    params: WeldParams,
    *,
    reverse: bool,
    track_position_m: float,
    axis_base: FloatArray,
) -> SeamPass:
    """The pass over ``seam`` through ``X_world_tcp`` (from :func:`pass_poses_world`), commanded in the base frame
    with the carriage at ``track_position_m``."""
    X_base_world = X_world_base(-track_position_m, axis_base)  # the inverse of a pure translation
    X_base_tcp = np.einsum("ij,njk->nik", X_base_world, X_world_tcp)
    travel = X_base_tcp[1:-1]
    blends = _travel_blends(travel[:, :3, 3], params.blend_m)
    waypoints = [Waypoint(X_base_tcp[0], params.air_speed_m_s, 0.0, MoveKind.AIR, "approach")]
    waypoints.append(Waypoint(travel[0], params.approach_speed_m_s, 0.0, MoveKind.APPROACH, "arc_on"))
    for k in range(1, len(travel)):
        label = "arc_off" if k == len(travel) - 1 else f"travel[{k}]"
        waypoints.append(Waypoint(travel[k], params.travel_speed_m_s, blends[k], MoveKind.WELD, label))
    waypoints.append(Waypoint(X_base_tcp[-1], params.approach_speed_m_s, 0.0, MoveKind.RETRACT, "retract"))
    return SeamPass(
        seam_id=seam.id,
        kind=seam.kind,
        sources=seam.sources,
        reversed=reverse,
        track_position_m=float(track_position_m),
        waypoints=tuple(waypoints),
        length_m=seam.length_m,
    )


# ================================================================================================ track and reach
def reach_distances_m(points_world: ArrayLike, track_position_m: float, geometry: CellGeometry) -> FloatArray:
    """Distance of each (N, 3) world point from the reach centre with the carriage at ``track_position_m``."""
    p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    centre_world = geometry.reach.centre_base + float(track_position_m) * geometry.axis_base
    return np.asarray(np.linalg.norm(p - centre_world, axis=1), dtype=np.float64)


def in_reach(points_world: ArrayLike, track_position_m: float, geometry: CellGeometry) -> bool:
    return bool(np.all(reach_distances_m(points_world, track_position_m, geometry) <= geometry.reach.radius_m))


def choose_track_position(
    points_world: ArrayLike, *, geometry: CellGeometry, current_m: float = 0.0, label: str = "seam"
) -> float:
    """The carriage position for a pass whose TCP positions are ``points_world`` ((N, 3), world).

    The current position when every point is in reach there; otherwise the position (within the track's limits)
    that puts the points' centre closest to ``reach.preferred_m`` from the reach centre (of two such positions the
    one nearer ``current_m``), or, when that leaves a point out of reach, the position with the largest reach
    margin. Raises SafetyViolation when no position reaches every point.
    """
    p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    if in_reach(p, current_m, geometry):
        return float(current_m)
    track = geometry.track
    if track is None:
        farthest = float(reach_distances_m(p, 0.0, geometry).max())
        raise SafetyViolation(
            f"{label}: a pose is {farthest:.3f} m from the reach centre, beyond the reach radius "
            f"{geometry.reach.radius_m:.3f} m, and the cell has no track to bring it closer"
        )
    a = track.axis_base
    rel = p.mean(axis=0) - geometry.reach.centre_base
    s = float(rel @ a)
    r_perp = float(np.linalg.norm(rel - s * a))
    pref = geometry.reach.preferred_m
    if r_perp >= pref:
        candidates = [s]
    else:
        h = math.sqrt(pref**2 - r_perp**2)
        candidates = [s - h, s + h]
    clamped = [float(np.clip(t, track.min_m, track.max_m)) for t in candidates]

    def off_preferred(t: float) -> float:
        return abs(float(np.linalg.norm(rel - t * a)) - pref)

    clamped.sort(key=lambda t: (round(off_preferred(t), 12), abs(t - current_m), t))
    t_best = clamped[0]
    if in_reach(p, t_best, geometry):
        return t_best

    def worst(t: float) -> float:
        return float(reach_distances_m(p, t, geometry).max())

    # max over points of a convex function of t is convex: the bounded search finds its minimum
    res = minimize_scalar(worst, bounds=(track.min_m, track.max_m), method="bounded", options={"xatol": 1e-7})
    t_margin = float(res.x)
    if worst(t_margin) <= geometry.reach.radius_m:
        return t_margin
    raise SafetyViolation(
        f"{label}: no track position in [{track.min_m:.3f}, {track.max_m:.3f}] m brings every pose within the reach "
        f"radius {geometry.reach.radius_m:.3f} m (best: {worst(t_margin):.3f} m at {t_margin:.3f} m)"
    )


# ================================================================================================ planning
def plan_weld_path(
    seams: Sequence[WorldSeam],
    params: WeldParams,
    *,
    geometry: CellGeometry,
    track_position_m: float = 0.0,
    p_world_start: ArrayLike | None = None,
    exact_max: int = 10,
) -> WeldPath:
    """Plan every seam that passes ``params.seam_filter``: direction and order (short air moves), pass geometry,
    and a track position per pass (the carriage moves only when a pass is out of reach where it stands).

    ``seams``: world-frame seams (:func:`cell.world_seams.world_seams`, :func:`cell.world_seams.collect_seams`);
    ``track_position_m``: where the carriage is now; ``p_world_start``: (3,) the TCP position now, in world
    (None: the route may start anywhere).
    Raises SafetyViolation when a seam cannot be brought into reach. The result still has to pass
    :func:`cell.safety.validate`.
    """
    kept, skipped = filter_seams(seams, params.seam_filter)
    axis = geometry.axis_base
    poses = [[pass_poses_world(s, params, reverse=rev) for rev in (False, True)] for s in kept]
    entries = np.array([[P[0][0, :3, 3], P[1][0, :3, 3]] for P in poses]).reshape(-1, 2, 3)
    exits = np.array([[P[0][-1, :3, 3], P[1][-1, :3, 3]] for P in poses]).reshape(-1, 2, 3)
    start = None if p_world_start is None else np.asarray(p_world_start, dtype=np.float64).reshape(3)
    route = order_seams(entries, exits, p_start=start, exact_max=exact_max)
    passes = []
    t = float(track_position_m)
    for i, rev in route:
        seam = kept[i]
        t = choose_track_position(poses[i][int(rev)][:, :3, 3], geometry=geometry, current_m=t, label=f"seam {seam.id}")
        passes.append(_build_pass(seam, poses[i][int(rev)], params, reverse=rev, track_position_m=t, axis_base=axis))
    return WeldPath(
        passes=tuple(passes),
        params=params,
        track_axis_base=axis,
        air_length_m=route_length(route, entries, exits, start),
        skipped=tuple(skipped),
    )
