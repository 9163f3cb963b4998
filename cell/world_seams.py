"""Seams in the world frame: detected seams of several captures (taken at several track positions) moved into
one frame, duplicates merged, and the selection of the ones to weld. Pure functions, no devices.

Frames (metres): ``base`` is the robot base frame; the ground track's carriage carries it, so it moves with the
track position ``t``. ``world`` is the base frame with the track at 0. The carriage only translates the base
along the unit vector ``axis_base``, so ``X_world_base(t) = Trans(t * axis_base)`` (the convention of the fake
camera). Seams seen from several track positions meet in the world frame; ordering and merging work there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cell.errors import ConfigError
from perception.seams import Seam, check_seam_path
from perception.transforms import make_X

FloatArray = NDArray[np.float64]

DEFAULT_TRACK_AXIS_BASE = (0.0, 1.0, 0.0)
"""The direction the carriage moves the base, in the base frame (the fake camera's default)."""


ID_STRIDE = 1000
"""Seam ids of capture ``k`` are ``k * ID_STRIDE + detector id``, so capture 0 keeps the detector's ids."""


_FLIP_XY = np.diag([-1.0, -1.0, 1.0, 1.0])  # right-multiplied: the same pose travelling the other way


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


def X_world_base(track_position_m: float, axis_base: ArrayLike) -> FloatArray:
    """(4, 4) pose of the robot base in the world frame with the carriage at ``track_position_m``."""
    return make_X(np.eye(3), float(track_position_m) * np.asarray(axis_base, dtype=np.float64).reshape(3))


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
