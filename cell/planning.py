"""Weld planning: detected seams and welding parameters in, a :class:`WeldPath` out. Pure functions, no devices.

Frames (metres, radians):

- ``base``: the robot base frame. The ground track's carriage carries the base, so the base moves with the
  track position ``t``; the robot is always commanded in it (``X_base_tcp``).
- ``world``: the robot base frame with the track at 0. The carriage only translates the base along the unit
  vector ``axis_base``, so ``X_world_base(t) = Trans(t * axis_base)`` (the convention of the fake camera).
  Seams seen from several track positions meet here; ordering and merging work here.
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

Ordering keeps air moves short: the cost of a route is the summed straight-line distance from each pass's retract
pose to the next pass's approach pose (and from the start position to the first approach, when it is known);
each seam may be welded in either direction. Up to ``exact_max`` seams the route is optimal (dynamic programming
over subsets); above it, greedy nearest neighbour then a local search with 2-opt moves (segment reversal flips the
direction of every seam in the segment; a one-seam segment is a direction flip) and relocation moves (one seam
moved elsewhere, in either direction). Both are deterministic.
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
from perception.seams import Seam, check_seam_path
from perception.transforms import make_X

FloatArray = NDArray[np.float64]

DEFAULT_TRACK_AXIS_BASE = (0.0, 1.0, 0.0)
"""The direction the carriage moves the base, in the base frame (the fake camera's default)."""

ID_STRIDE = 1000
"""Seam ids of capture ``k`` are ``k * ID_STRIDE + detector id``, so capture 0 keeps the detector's ids."""

_FLIP_XY = np.diag([-1.0, -1.0, 1.0, 1.0])  # right-multiplied: the same pose travelling the other way


# ================================================================================================ parameters
@dataclass(frozen=True)
class SeamFilter:
    """Which seams to weld. ``ids``: planner seam ids (see :data:`ID_STRIDE`), None = all; ``kinds``: detector
    kinds (``"linear"``, ``"curved"``), None = all; ``min_length_m``: shorter seams are skipped."""

    ids: frozenset[int] | None = None
    kinds: frozenset[str] | None = None
    min_length_m: float = 0.0

    def __post_init__(self) -> None:
        if self.ids is not None:
            object.__setattr__(self, "ids", frozenset(int(i) for i in self.ids))
        if self.kinds is not None:
            object.__setattr__(self, "kinds", frozenset(str(k) for k in self.kinds))
        if not (math.isfinite(self.min_length_m) and self.min_length_m >= 0.0):
            raise ConfigError(f"seam filter: min_length_m must be a finite number >= 0, got {self.min_length_m}")

    def reason_to_skip(self, seam: WorldSeam) -> str | None:
        """Why ``seam`` is filtered out, or None when it is welded."""
        if self.ids is not None and seam.id not in self.ids:
            return f"id {seam.id} not in the selected ids {sorted(self.ids)}"
        if self.kinds is not None and seam.kind not in self.kinds:
            return f"kind {seam.kind!r} not in the selected kinds {sorted(self.kinds)}"
        if seam.length_m < self.min_length_m:
            return f"length {seam.length_m:.4f} m below min_length_m {self.min_length_m:.4f} m"
        return None


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


def X_world_base(track_position_m: float, axis_base: ArrayLike) -> FloatArray:
    """(4, 4) pose of the robot base in the world frame with the carriage at ``track_position_m``."""
    return make_X(np.eye(3), float(track_position_m) * np.asarray(axis_base, dtype=np.float64).reshape(3))


# ================================================================================================ seams in world
@dataclass(frozen=True)
class WorldSeam:
    """A seam in the world frame (the base frame with the track at 0): a :class:`perception.seams.Seam` moved
    there by :func:`world_seams`, checked by the same rule (:func:`perception.seams.check_seam_path`).

    ``points_world``: (N, 3) path, metres, ordered along the seam; ``X_world_torch``: (N, 4, 4) neutral torch
    poses there; ``sources``: the (capture index, detector seam id) pairs it was built from.
    """

    id: int
    kind: str
    points_world: FloatArray
    X_world_torch: FloatArray
    confidence: float
    sources: tuple[tuple[int, int], ...]

    def __post_init__(self) -> None:
        pts, poses = check_seam_path(
            self.points_world,
            self.X_world_torch,
            what=f"seam {self.id}:",
            points_name="points_world",
            poses_name="X_world_torch",
        )
        object.__setattr__(self, "points_world", pts)
        object.__setattr__(self, "X_world_torch", poses)

    @property
    def length_m(self) -> float:
        return polyline_length(self.points_world)

    def reversed(self) -> WorldSeam:
        """The same seam ordered the other way (torch x and y flip, z stays)."""
        return WorldSeam(
            self.id,
            self.kind,
            self.points_world[::-1].copy(),
            self.X_world_torch[::-1] @ _FLIP_XY,
            self.confidence,
            self.sources,
        )


def polyline_length(points: ArrayLike) -> float:
    p = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def world_seams(
    seams: Sequence[Seam],
    *,
    track_position_m: float = 0.0,
    axis_base: ArrayLike = DEFAULT_TRACK_AXIS_BASE,
    capture_index: int = 0,
) -> list[WorldSeam]:
    """Base-frame seams of one capture (taken with the carriage at ``track_position_m``) in the world frame.

    Raises ConfigError for a camera-frame seam: planning needs the capture's robot pose and a hand-eye result.
    """
    X_wb = X_world_base(track_position_m, axis_base)
    out = []
    for s in seams:
        if s.frame != "base":
            raise ConfigError(
                f"seam {s.id} of capture {capture_index} is in the {s.frame!r} frame; planning needs base-frame "
                "seams (the capture needs the robot pose, and the cell a [hand_eye] result)"
            )
        moved = s.transformed(X_wb, "base")
        out.append(
            WorldSeam(
                id=capture_index * ID_STRIDE + s.id,
                kind=s.kind,
                points_world=moved.points,
                X_world_torch=moved.poses,
                confidence=float(s.confidence),
                sources=((capture_index, s.id),),
            )
        )
    return out


def collect_seams(
    captures: Sequence[tuple[float, Sequence[Seam]]],
    *,
    axis_base: ArrayLike = DEFAULT_TRACK_AXIS_BASE,
    tol_m: float = 0.003,
    min_overlap_m: float = 0.02,
    max_axis_angle_rad: float = math.radians(30.0),
) -> list[WorldSeam]:
    """Seams of several captures ``(track_position_m, seams)`` in the world frame, duplicates merged."""
    all_seams: list[WorldSeam] = []
    for k, (t, seams) in enumerate(captures):
        all_seams.extend(world_seams(seams, track_position_m=t, axis_base=axis_base, capture_index=k))
    return merge_seams(all_seams, tol_m=tol_m, min_overlap_m=min_overlap_m, max_axis_angle_rad=max_axis_angle_rad)


def _project_onto_polyline(points: FloatArray, line: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Distance of each (M, 3) point to the polyline (K, 3), and its arc-length parameter along it.

    The first and last segments are extended, so a point before the start gets s < 0 and one past the end
    s > length; its distance is still measured to the polyline itself (clamped).
    """
    a, b = line[:-1], line[1:]
    ab = b - a
    seg_len = np.linalg.norm(ab, axis=1)
    s0 = np.concatenate([[0.0], np.cumsum(seg_len)])
    denom = np.maximum(seg_len**2, 1e-18)
    u = ((points[:, None, :] - a[None]) * ab[None]).sum(axis=2) / denom[None]  # (M, K-1)
    u_clamped = np.clip(u, 0.0, 1.0)
    closest = a[None] + u_clamped[..., None] * ab[None]
    dist = np.linalg.norm(points[:, None, :] - closest, axis=2)
    k = np.argmin(dist, axis=1)
    rows = np.arange(len(points))
    s = s0[k] + u_clamped[rows, k] * seg_len[k]
    # beyond the ends: extrapolate along the end segments
    before = (k == 0) & (u[:, 0] < 0)
    s[before] = u[before, 0] * seg_len[0]
    last = len(seg_len) - 1
    after = (k == last) & (u[:, last] > 1)
    s[after] = s0[last] + u[after, last] * seg_len[last]
    return dist[rows, k], s


def seam_overlap_m(
    a: WorldSeam, b: WorldSeam, *, tol_m: float, max_axis_angle_rad: float = math.radians(30.0)
) -> float:
    """Length (metres, along ``b``) over which ``b`` lies within ``tol_m`` of ``a`` with a torch axis within
    ``max_axis_angle_rad`` of ``a``'s there. Two fillets either side of a thin plate never overlap."""
    dist, s = _project_onto_polyline(b.points_world, a.points_world)
    near = dist <= tol_m
    if near.sum() < 2:
        return 0.0
    # torch axis agreement at each near point: compare with a's pose at the nearest vertex
    a_s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(a.points_world, axis=0), axis=1))])
    idx = np.clip(np.searchsorted(a_s, s), 0, len(a_s) - 1)
    za = a.X_world_torch[idx, :3, 2]
    zb = b.X_world_torch[:, :3, 2]
    cos = np.clip((za * zb).sum(axis=1), -1.0, 1.0)
    near &= np.arccos(cos) <= max_axis_angle_rad
    seg = np.linalg.norm(np.diff(b.points_world, axis=0), axis=1)
    return float(seg[near[:-1] & near[1:]].sum())


def _union(a: WorldSeam, b: WorldSeam) -> WorldSeam:
    """One seam covering both extents: ``a``'s points, with ``b``'s points before a's start and past its end."""
    # orient b like a (mean tangents)
    ta = a.points_world[-1] - a.points_world[0]
    tb = b.points_world[-1] - b.points_world[0]
    if float(ta @ tb) < 0:
        b = b.reversed()
    _, s = _project_onto_polyline(b.points_world, a.points_world)
    length_a = a.length_m
    pre = np.flatnonzero(s < 0.0)
    post = np.flatnonzero(s > length_a)
    pre = pre[np.argsort(s[pre], kind="stable")]
    post = post[np.argsort(s[post], kind="stable")]
    points = np.concatenate([b.points_world[pre], a.points_world, b.points_world[post]])
    poses = np.concatenate([b.X_world_torch[pre], a.X_world_torch, b.X_world_torch[post]])
    return WorldSeam(
        id=min(a.id, b.id),
        kind=a.kind if a.kind == b.kind else "curved",
        points_world=points,
        X_world_torch=poses,
        confidence=max(a.confidence, b.confidence),
        sources=tuple(sorted(set(a.sources) | set(b.sources))),
    )


def merge_seams(
    seams: Sequence[WorldSeam],
    *,
    tol_m: float = 0.003,
    min_overlap_m: float = 0.02,
    max_axis_angle_rad: float = math.radians(30.0),
) -> list[WorldSeam]:
    """Merge seams seen in several captures: two seams whose paths lie within ``tol_m`` of each other over at least
    ``min_overlap_m`` (with torch axes within ``max_axis_angle_rad``) become one covering the union of their
    extents, so no seam is welded twice. The longer seam's points are kept where they overlap. Repeats until no
    pair overlaps; the result is sorted by id (a merged seam takes the smaller id)."""
    if not (tol_m > 0 and min_overlap_m > 0):
        raise ValueError(f"tol_m and min_overlap_m must be > 0, got {tol_m}, {min_overlap_m}")
    work = sorted(seams, key=lambda s: s.id)
    merged = True
    while merged:
        merged = False
        for i in range(len(work)):
            for j in range(i + 1, len(work)):
                a, b = work[i], work[j]
                overlap = max(
                    seam_overlap_m(a, b, tol_m=tol_m, max_axis_angle_rad=max_axis_angle_rad),
                    seam_overlap_m(b, a, tol_m=tol_m, max_axis_angle_rad=max_axis_angle_rad),
                )
                if overlap >= min_overlap_m:
                    base, other = (a, b) if a.length_m >= b.length_m else (b, a)
                    union = _union(base, other)
                    work = [s for k, s in enumerate(work) if k not in (i, j)] + [union]
                    work.sort(key=lambda s: s.id)
                    merged = True
                    break
            if merged:
                break
    return work


def filter_seams(seams: Sequence[WorldSeam], seam_filter: SeamFilter) -> tuple[list[WorldSeam], list[tuple[int, str]]]:
    """(seams to weld, [(id, reason) skipped])."""
    kept, skipped = [], []
    for s in seams:
        reason = seam_filter.reason_to_skip(s)
        if reason is None:
            kept.append(s)
        else:
            skipped.append((s.id, reason))
    return kept, skipped


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


# ================================================================================================ ordering
Route = list[tuple[int, bool]]
"""(seam index, reversed) in welding order."""


def route_length(route: Route, entries: FloatArray, exits: FloatArray, p_start: FloatArray | None = None) -> float:
    """Summed air-move length of ``route``. ``entries``/``exits``: (n, 2, 3) approach and retract positions of each
    seam welded forward ([:, 0]) and reversed ([:, 1]); ``p_start``: (3,) or None for a free start."""
    total = 0.0
    prev = None if p_start is None else np.asarray(p_start, dtype=np.float64)
    for i, rev in route:
        if prev is not None:
            total += float(np.linalg.norm(prev - entries[i, int(rev)]))
        prev = exits[i, int(rev)]
    return total


def order_seams(
    entries: ArrayLike, exits: ArrayLike, *, p_start: ArrayLike | None = None, exact_max: int = 10
) -> Route:
    """The welding order and direction of each seam minimising :func:`route_length` (see the module docstring):
    exact up to ``exact_max`` seams, nearest neighbour + local search above. Deterministic (ties: lowest index)."""
    E = np.asarray(entries, dtype=np.float64).reshape(-1, 2, 3)
    Q = np.asarray(exits, dtype=np.float64).reshape(-1, 2, 3)
    if E.shape != Q.shape:
        raise ValueError(f"entries and exits must have the same shape, got {E.shape} and {Q.shape}")
    start = None if p_start is None else np.asarray(p_start, dtype=np.float64).reshape(3)
    n = len(E)
    if n == 0:
        return []
    if n <= exact_max:
        return _order_exact(E, Q, start)
    return improve_route(_order_nearest(E, Q, start), E, Q, start)


def _cost_tables(E: FloatArray, Q: FloatArray, start: FloatArray | None) -> tuple[FloatArray, FloatArray]:
    """States ``b = 2 * seam + reversed``: ``C[a, b]`` from the exit of a to the entry of b; ``S[b]`` from start."""
    m = 2 * len(E)
    ends, outs = E.reshape(m, 3), Q.reshape(m, 3)
    C = np.linalg.norm(outs[:, None, :] - ends[None, :, :], axis=2)
    S = np.zeros(m) if start is None else np.linalg.norm(ends - start, axis=1)
    return C, S


def _order_exact(E: FloatArray, Q: FloatArray, start: FloatArray | None) -> Route:
    """Held-Karp over (subset of seams, last state)."""
    n = len(E)
    m = 2 * n
    C, S = _cost_tables(E, Q, start)
    full = (1 << n) - 1
    D = np.full((1 << n, m), np.inf)
    parent = np.full((1 << n, m), -1, dtype=np.int64)
    for b in range(m):
        D[1 << (b // 2), b] = S[b]
    seam_of = np.arange(m) // 2
    for mask in range(1, full + 1):
        row = D[mask]
        if not np.isfinite(row).any():
            continue
        cand = row[:, None] + C  # (from, to)
        best_from = np.argmin(cand, axis=0)
        best = cand[best_from, np.arange(m)]
        for b in range(m):
            j = seam_of[b]
            if mask >> j & 1:
                continue
            nm = mask | (1 << j)
            if best[b] < D[nm, b]:
                D[nm, b] = best[b]
                parent[nm, b] = best_from[b]
    b = int(np.argmin(D[full]))
    route: Route = []
    mask = full
    while b >= 0:
        route.append((b // 2, bool(b % 2)))
        prev = int(parent[mask, b])
        mask &= ~(1 << (b // 2))
        b = prev
    route.reverse()
    return route


def _nearest_from(first: int, C: FloatArray, n: int) -> list[int]:
    states = [first]
    left = np.ones(n, dtype=bool)
    left[first // 2] = False
    for _ in range(n - 1):
        d = C[states[-1]].copy()
        d[np.repeat(~left, 2)] = np.inf
        b = int(np.argmin(d))
        states.append(b)
        left[b // 2] = False
    return states


def _states_cost(states: list[int] | NDArray[np.int64], C: FloatArray, S: FloatArray) -> float:
    s = np.asarray(states, dtype=np.int64)
    return float(S[s[0]] + C[s[:-1], s[1:]].sum())


def _order_nearest(E: FloatArray, Q: FloatArray, start: FloatArray | None) -> Route:
    """Greedy nearest neighbour: from ``start``, or (free start) the best of every possible first seam."""
    n = len(E)
    C, S = _cost_tables(E, Q, start)
    if start is not None:
        states = _nearest_from(int(np.argmin(S)), C, n)
    else:
        candidates = [_nearest_from(b, C, n) for b in range(2 * n)]
        states = min(candidates, key=lambda st: _states_cost(st, C, S))  # min keeps the first of equals
    return [(b // 2, bool(b % 2)) for b in states]


def improve_route(route: Route, entries: ArrayLike, exits: ArrayLike, p_start: ArrayLike | None = None) -> Route:
    """Local search from ``route`` until no move shortens it, taking the best move each round. Moves: 2-opt
    (reverse a segment, flipping every seam in it; a one-seam segment is a direction flip) and relocation (take
    one seam out and put it back anywhere, in either direction). Returns a local optimum for both."""
    E = np.asarray(entries, dtype=np.float64).reshape(-1, 2, 3)
    Q = np.asarray(exits, dtype=np.float64).reshape(-1, 2, 3)
    start = None if p_start is None else np.asarray(p_start, dtype=np.float64).reshape(3)
    C, S = _cost_tables(E, Q, start)
    best = [2 * i + int(rev) for i, rev in route]
    best_len = _states_cost(best, C, S)
    n = len(best)
    while True:
        improved: list[int] | None = None
        improved_len = best_len
        for cand in _neighbours(best, n):
            length = _states_cost(cand, C, S)
            if length < improved_len - 1e-12:
                improved, improved_len = cand, length
        if improved is None:
            return [(b // 2, bool(b % 2)) for b in best]
        best, best_len = improved, improved_len


def _neighbours(states: list[int], n: int) -> Iterator[list[int]]:
    for i in range(n):
        for j in range(i, n):
            yield states[:i] + [b ^ 1 for b in reversed(states[i : j + 1])] + states[j + 1 :]
    for i in range(n):
        rest = states[:i] + states[i + 1 :]
        for j in range(n):
            for b in (states[i], states[i] ^ 1):
                if j != i or b != states[i]:
                    yield [*rest[:j], b, *rest[j:]]


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

    ``seams``: world-frame seams (:func:`world_seams`, :func:`collect_seams`); ``track_position_m``: where the
    carriage is now; ``p_world_start``: (3,) the TCP position now, in world (None: the route may start anywhere).
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
