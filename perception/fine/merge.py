"""Pieces of one straight seam made one seam again.

A face the segmentation left in two fragments gives two folds with the same neighbour, one after the other
on the same line: two pieces of one seam, with a short stretch between them where the fragments meet. They
are one seam when they lie on one line within the noise, their faces stand the same way, and both faces
are there, right up to the line, all along the stretch between them (a crossing plate or a hidden stretch
interrupts a seam: there the faces' points near the line are missing, and the pieces stay apart).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from perception.capture import CameraIntrinsics
from perception.fine.folds import line_coords
from perception.fine.groups import Groups
from perception.fine.refine import near_points
from perception.fine.types import FloatArray, NoiseModel, SeamCurve
from perception.fits import median


@dataclass(frozen=True)
class MergeParams:
    max_angle_rad: float = np.radians(2.0)  # the pieces' directions agree this well
    max_normal_angle_rad: float = np.radians(6.0)  # ... and so do their faces' normals
    min_offset_m: float = 0.0005  # the pieces' lines lie within this (or three sigma) of each other
    max_gap_m: float = 0.040  # the stretch between them is at most this long
    near_m: float = 0.003  # the faces' points within this (plus noise) of the line count as reaching it
    bin_m: float = 0.002
    min_cover: float = 0.6  # share of the stretch's bins where both faces reach the line
    short_gap_m: float = 0.006  # a shorter stretch joins two pieces when both faces and nothing else are in it
    interrupt_share: float = 0.3  # ... nothing else: less than this share of the points there off both faces
    twin_offset_m: float = 0.003  # two seams on a shared face this close (or six sigma) along most of one are one
    twin_angle_rad: float = np.radians(6.0)  # ... when their directions agree this well


def merge_collinear(
    curves: list[SeamCurve],
    full: NDArray[np.float32],
    intr: CameraIntrinsics,
    noise: NoiseModel,
    *,
    params: MergeParams | None = None,
) -> list[SeamCurve]:
    """``curves`` with the pieces of each straight seam joined into one (the longest piece's line and faces,
    over the pieces' whole extent); other curves unchanged, in their order."""
    mp = params or MergeParams()
    lines = [i for i, c in enumerate(curves) if c.kind == "linear" and len(c.points) >= 2]
    sets = Groups(range(len(curves)))
    root = sets.find
    for k, i in enumerate(lines):
        for j in lines[k + 1 :]:
            if root(i) != root(j) and _one_seam(curves[i], curves[j], full, intr, noise, mp):
                sets.join(i, j)
    groups: dict[int, list[int]] = {}
    for i in range(len(curves)):
        groups.setdefault(root(i), []).append(i)
    out = []
    for i, c in enumerate(curves):
        members = groups[root(i)]
        if i != members[0]:
            continue
        out.append(c if len(members) == 1 else _joined([curves[m] for m in members]))
    return _without_overlapping_twins(out, noise, mp)


def _without_overlapping_twins(curves: list[SeamCurve], noise: NoiseModel, mp: MergeParams) -> list[SeamCurve]:
    """``curves`` less each straight seam that runs along another one on a face they share, over most of its
    length: one face meets one other face along one line, so the two are one joint seen twice (the other face's
    fragment, fitted on a few pixels, tilted and met the shared face a millimetre or two away). The better
    supported of the two stays."""
    lines = [i for i, c in enumerate(curves) if c.kind == "linear" and len(c.points) >= 2]
    drop: set[int] = set()
    for k, i in enumerate(lines):
        for j in lines[k + 1 :]:
            a, b = curves[i], curves[j]
            if i in drop or j in drop or a.joint != b.joint or not set(a.surfaces) & set(b.surfaces):
                continue
            (short, s_i), (long_, l_i) = sorted(((a, i), (b, j)), key=lambda x: _direction(x[0])[2])
            p0, u, length = _direction(long_)
            if abs(float(_direction(short)[1] @ u)) < np.cos(mp.twin_angle_rad):
                continue
            z = float(median(short.points[:, 2]))
            within = max(mp.twin_offset_m, 6.0 * float(noise.sigma_m(z)))
            probe = short.points[0] + np.linspace(0.0, 1.0, 21)[:, None] * (short.points[-1] - short.points[0])
            t, off = line_coords(probe, p0, u)
            along = (t >= 0.0) & (t <= length) & (off <= within)
            if along.mean() >= 0.5:
                drop.add(s_i if short.support <= long_.support else l_i)
    return [c for i, c in enumerate(curves) if i not in drop]


def _direction(c: SeamCurve) -> tuple[FloatArray, FloatArray, float]:
    p0, p1 = c.points[0], c.points[-1]
    length = float(np.linalg.norm(p1 - p0))
    return p0, (p1 - p0) / max(length, 1e-12), length


def _one_seam(a: SeamCurve, b: SeamCurve, full: NDArray[np.float32], intr: CameraIntrinsics, noise: NoiseModel,
              mp: MergeParams) -> bool:  # fmt: skip
    if a.joint != b.joint:
        return False
    pa, ua, la = _direction(a)
    pb, ub, lb = _direction(b)
    if abs(float(ua @ ub)) < np.cos(mp.max_angle_rad):
        return False
    # their faces stand the same way; a face both pieces share (the plate a fragmented face stands on) leaves
    # the other faces, fitted on fewer points, a wider tolerance
    shared = bool(set(a.surfaces) & set(b.surfaces))
    cos_n = np.cos(mp.max_normal_angle_rad * (2.5 if shared else 1.0))
    na, nb = (a.normals_a.mean(axis=0), a.normals_b.mean(axis=0)), (b.normals_a.mean(axis=0), b.normals_b.mean(axis=0))
    same = min(float(na[0] @ nb[0]), float(na[1] @ nb[1])) > cos_n
    swapped = min(float(na[0] @ nb[1]), float(na[1] @ nb[0])) > cos_n
    if not (same or swapped):
        return False
    z = float(median(np.concatenate([a.points[:, 2], b.points[:, 2]])))
    sig = float(noise.sigma_m(z))
    tol = max(mp.min_offset_m, 3.0 * sig)
    # the shorter piece on the longer one's line (its own direction is the less certain)
    p0, u, q = (pa, ua, b.points) if la >= lb else (pb, ub, a.points)
    d = q - p0
    if float(np.max(np.linalg.norm(d - np.outer(d @ u, u), axis=1))) > tol:
        return False
    # the stretch between them along a's line
    ta = (0.0, la)
    tb = sorted(float((e - pa) @ ua) for e in (b.points[0], b.points[-1]))
    lo, hi = (ta[1], tb[0]) if tb[0] >= ta[1] else (tb[1], ta[0]) if tb[1] <= ta[0] else (0.0, 0.0)
    gap = hi - lo
    if gap > mp.max_gap_m:
        return False
    if gap <= mp.bin_m:
        return True  # touching or overlapping pieces: nothing between them to check
    longer = a if la >= lb else b
    if gap <= mp.short_gap_m:
        # a stretch a few of the faces' samples long is too short to show them reaching the line in every bin
        # (a face seen obliquely has holes this long): both faces are in it, and no other body
        return _faces_present(pa + lo * ua, pa + hi * ua, ua, longer, full, intr, noise, mp)
    return _faces_reach(pa + lo * ua, pa + hi * ua, ua, longer, full, intr, noise, mp)


def _stretch_points(g0: FloatArray, g1: FloatArray, u: FloatArray, full: NDArray[np.float32], intr: CameraIntrinsics,
                    noise: NoiseModel, mp: MergeParams) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """The points near the line along the stretch g0-g1 (within ``near_m`` plus three sigma), as offsets from
    ``g0``, and their sigma."""
    q = near_points(full, intr, np.array([g0, g1]), mp.near_m + 0.004)
    t, dist = line_coords(q, g0, u)
    sig = noise.sigma_m(q[:, 2])
    keep = (t >= 0.0) & (t <= float(np.linalg.norm(g1 - g0))) & (dist <= mp.near_m + 3.0 * sig)
    return q[keep] - g0, sig[keep]


def _on_planes(d: FloatArray, sig: FloatArray, c: SeamCurve) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Per point (offsets ``d`` from the line): within three sigma of face a's plane through the line, and of
    face b's."""
    return np.abs(d @ c.normals_a[0]) <= 3.0 * sig, np.abs(d @ c.normals_b[0]) <= 3.0 * sig


def _faces_present(g0: FloatArray, g1: FloatArray, u: FloatArray, c: SeamCurve, full: NDArray[np.float32],
                   intr: CameraIntrinsics, noise: NoiseModel, mp: MergeParams) -> bool:  # fmt: skip
    """Whether both of ``c``'s faces have points at the line along the stretch g0-g1 and nothing else stands
    there: fewer than ``interrupt_share`` of the points off both faces (a crossing plate's sides)."""
    d, sig = _stretch_points(g0, g1, u, full, intr, noise, mp)
    plane_a, plane_b = _on_planes(d, sig, c)
    off_both = ~plane_a & ~plane_b
    interrupted = int(off_both.sum()) >= max(3, int(np.ceil(mp.interrupt_share * len(d))))
    return bool((plane_a & ~plane_b).any() and (plane_b & ~plane_a).any() and not interrupted)


def _faces_reach(g0: FloatArray, g1: FloatArray, u: FloatArray, c: SeamCurve, full: NDArray[np.float32],
                 intr: CameraIntrinsics, noise: NoiseModel, mp: MergeParams) -> bool:  # fmt: skip
    """Whether both of ``c``'s faces have points close to the line along most of the stretch g0-g1."""
    d, sig = _stretch_points(g0, g1, u, full, intr, noise, mp)
    if len(d) == 0:
        return False
    t = d @ u
    bins = max(1, int(np.ceil(float(np.linalg.norm(g1 - g0)) / mp.bin_m)))
    k = np.clip((t / mp.bin_m).astype(int), 0, bins - 1)
    covered = np.ones(bins, dtype=bool)
    plane_a, plane_b = _on_planes(d, sig, c)
    for on in (plane_a & ~plane_b, plane_b & ~plane_a):  # on one face's plane and clearly off the other's
        hit = np.zeros(bins, dtype=bool)
        hit[k[on]] = True
        covered &= hit
    return bool(covered.mean() >= mp.min_cover)


def _joined(pieces: list[SeamCurve]) -> SeamCurve:
    """One seam on the longest piece's line over all the pieces' extent."""
    best = max(pieces, key=lambda c: float(np.linalg.norm(c.points[-1] - c.points[0])))
    p0, u, _ = _direction(best)
    t = np.concatenate([(c.points - p0) @ u for c in pieces])
    ends = np.array([p0 + float(t.min()) * u, p0 + float(t.max()) * u])
    return replace(best, points=ends, normals_a=np.tile(best.normals_a[0], (2, 1)),
                   normals_b=np.tile(best.normals_b[0], (2, 1)), support=sum(c.support for c in pieces),
                   rms_m=max(c.rms_m for c in pieces))  # fmt: skip
