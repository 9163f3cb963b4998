"""The surface the workpiece stands on (the table, a fixture plate): never a seam's face.

It is the plane below everything: nearly every valid point lies on it or on its camera side, and what stands
off it stands on it: over its outline (dropped onto the plane, mostly inside it), or touching it along an
edge (a part on a table seen on one side of it only). Two butted plates filling the view with no table, one
a few millimetres lower and parted from the other by the gap, are not one standing on the other: neither is
a support and both are the workpiece (the XiaoyuChangeTheWorld frame). Of the planes that qualify (holding a
fair share of the image), the largest one the operator did not prompt as part of the workpiece is taken; the
largest of all when every one was prompted (a stray click on the table's border).

"Flat" is as flat as the sensor can show it. A swept LiDAR measures a welding table as interleaved layers of
scan lines a few millimetres apart, and bends it by as much across the scene: error that grows with the scale
it is seen at, which the noise model's sigma (planes seven samples wide) does not hold; its structured error
(:func:`perception.fine.noise.structured_error`, on planes three times as wide) does, and is allowed for. And
what lies behind the support is counted on the points of fitted surfaces: a LiDAR's mixed points at a plate's
top edge, seen between it and the table, fit no surface.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from perception.fine.types import FloatArray, NoiseModel, Surface, SurfaceSet
from perception.fits import percentile

ABOVE_SHARE = 0.97  # at least this share of all points lies on or above the support
MIN_SHARE = 0.08  # and it holds at least this share of the labelled pixels (all its pieces together)
FLATNESS_M = 0.001  # pieces of the support plane agree this well (a welding table is flat to a fraction of this)
BEHIND_SIGMA = 4.0  # a point more than this many sigma (and the flatness) behind a plane lies behind it: the
# support has nothing behind it (a lap's upper plate, 6 mm over the lower one, is not the table)
CARRY_SHARE = 0.5  # at least this share of the points standing off a support lies over its outline
FOOTPRINT_GROW_M = 0.006  # an outline (the convex hull of points dropped onto a plane) grown by this much
CONTACT_M = 0.02  # or what stands off it touches it along this much (a part standing on it seen from one side)
TABLE_AROUND_M = 0.03  # a surface lies on the table when it lies on the plane of the table's points this near it
TABLE_SAMPLE = 6000  # ... of a sample of about this many of the table's points


def find_support(
    points: NDArray[np.floating],
    surfaces: SurfaceSet,
    noise: NoiseModel,
    *,
    prompted: frozenset[int] = frozenset(),
) -> frozenset[int]:
    """The labels of the support plane in an (h, w, 3) work cloud: the best qualifying plane and every
    other piece of the same plane (the table seen on both sides of the part); empty when none qualifies."""
    p = np.asarray(points, dtype=np.float64)
    valid = np.isfinite(p[..., 2])
    every = np.flatnonzero(valid)
    sample = every[:: max(1, len(every) // 40000)]
    q = p.reshape(-1, 3)[sample]  # the sample, gathered alone
    tol = _off_tolerance(noise, q[:, 2])
    flatness = _flatness(noise, q[:, 2])
    behind = BEHIND_SIGMA * noise.sigma_m(q[:, 2]) + flatness  # a point further behind is not on the plane
    on_surface = surfaces.labels.reshape(-1)[sample] >= 0
    labelled = int((surfaces.labels >= 0).sum())
    qualify: dict[int, frozenset[int]] = {}  # each qualifying plane's label: the labels of all its pieces
    pieces_of = _plane_pieces(surfaces, noise)
    for s in surfaces.surfaces:
        if s.kind != "plane":
            continue
        # the share is the whole plane's: a table seen between and around the parts is in several pieces. A
        # plane is judged from its largest piece (a sliver's own plane, tilted by its noise, may pass through
        # a larger plane's centroid and take it for a piece: that plane is judged on its own pieces)
        pieces = pieces_of[s.label]
        if max(pieces, key=lambda k: (surfaces.surfaces[k].n_points, -k)) != s.label:
            continue
        if sum(surfaces.surfaces[k].n_points for k in pieces) < MIN_SHARE * labelled:
            continue
        res = q @ s.normal + s.offset
        if np.mean((res >= -behind)[on_surface]) < ABOVE_SHARE:
            continue
        mine = np.isin(surfaces.labels, sorted(pieces))
        if _carries(p, surfaces, noise, pieces, mine, q[res > tol]) or _touches(surfaces, noise, pieces, mine, s):
            qualify[s.label] = pieces
    # the faces of an inside corner seen from in front each have every point on their camera side: of those
    # that qualify, one the operator did not click is the table (a click on the table itself, a stray one on
    # a thin face's border, does not make a wall the support)
    unclicked = [k for k in qualify if k not in prompted]
    if not qualify:
        return frozenset()
    return qualify[max(unclicked or qualify, key=lambda k: surfaces.surfaces[k].n_points)]


def on_table(points: NDArray[np.floating], surfaces: SurfaceSet, noise: NoiseModel, support: frozenset[int], *,
             prompted: frozenset[int] = frozenset()) -> frozenset[int]:  # fmt: skip
    """The surfaces besides the ``support`` (:func:`find_support`) that are the table seen again: their points
    lie on the plane of the support's points around them (:func:`table_around`) as closely as those points do
    (their median distance within the larger of the noise and the table's own spread there, nine in ten within
    2.5 times that), whatever their own plane says (of the surfaces whose centre lies on the support's plane
    within the support's own tolerances). A few scan lines of a LiDAR's table fit a plane at any tilt
    about them, and where the sensor bends the table its pieces leave the support's plane: without this, two
    such strips a few millimetres apart on their tilted planes pass for a lap. A surface with no table points
    around it (a strip of the table at the image's border, below a plate's edge face) is the table when it is
    near the support's tilt (:data:`STRIP_TILT_RAD`) and its points lie on the support's own plane as the
    table's do (:func:`_on_plane`). A plate lying on the table is its thickness above it; a surface the
    operator clicked is the workpiece."""
    from scipy.ndimage import find_objects
    from scipy.spatial import cKDTree

    if not support:
        return frozenset()
    plane = surfaces.surfaces[max(sorted(support), key=lambda k: surfaces.surfaces[k].n_points)]  # the largest piece
    # only a surface whose centre lies on the support's plane as the support's own test takes a point to (no
    # further in front than the off tolerance, nor behind than the noise and the table's flatness allow)
    near = [s for s in surfaces.surfaces if s.label not in support and s.label not in prompted
            and -float(BEHIND_SIGMA * noise.sigma_m(s.z_m) + _flatness(noise, s.z_m))
            <= float(plane.residual(s.centroid[None])[0]) <= float(_off_tolerance(noise, s.z_m))]  # fmt: skip
    p = np.asarray(points, dtype=np.float64)
    labels = surfaces.labels
    table = table_sample(p, labels, support, TABLE_SAMPLE) if near else np.zeros((0, 3))
    if len(table) < 3:
        return frozenset()
    tree = cKDTree(table)
    boxes = find_objects(labels + 1)  # each surface's bounding box: its pixels are looked for there alone
    out = set()
    for s in near:
        box = boxes[s.label] if s.label < len(boxes) else None
        if box is None:
            continue
        own = p[box][labels[box] == s.label]
        x = own[:: max(1, len(own) // 48)]
        x = x[np.isfinite(x[:, 2])]
        local = table_around(tree, table, x, TABLE_AROUND_M)
        if local is None:
            # no table around it (a strip of it at the image's border, below a plate's edge face): on the
            # support's own plane as the table is, if near its tilt (a strip a few pixels wide fits a plane
            # tilted by its noise, all the more where the sensor smoothed its depth)
            if float(s.normal @ plane.normal) > np.cos(STRIP_TILT_RAD) and _on_plane(x, plane, noise):
                out.add(s.label)
            continue
        c, n, around = local
        res = np.abs((x - c) @ n)
        spread = max(float(noise.sigma_m(s.z_m)), 1.4826 * float(np.median(np.abs((around - c) @ n))))
        if float(np.median(res)) <= spread and float(percentile(res, 90)) <= 2.5 * spread:
            out.add(s.label)
    return frozenset(out)


STRIP_TILT_RAD = float(np.radians(15.0))  # a table strip alone fits a plane at most this far off the table's


def _on_plane(x: FloatArray, plane: Surface, noise: NoiseModel) -> bool:
    """Whether the (N, 3) points ``x`` lie on ``plane`` as the table's do: their median distance within its
    flatness and the noise, nine in ten within 2.5 times that."""
    if len(x) < 10:
        return False
    r = np.abs(plane.residual(x)) / (_flatness(noise, x[:, 2]) + noise.sigma_m(x[:, 2]))
    return bool(np.median(r) <= 1.0 and percentile(r, 90) <= 2.5)


def table_sample(points: NDArray[np.floating], labels: NDArray[np.int32], support: frozenset[int],
                 size: int) -> FloatArray:  # fmt: skip
    """About ``size`` of the valid points of the (h, w, 3) ``points`` whose ``labels`` are the support's, evenly
    taken."""
    is_table = np.zeros(int(labels.max(initial=-1)) + 2, dtype=bool)  # the last entry: label -1
    is_table[sorted(support)] = True
    idx = np.flatnonzero(is_table[labels.reshape(-1)])
    q = np.asarray(points, dtype=np.float64).reshape(-1, 3)[idx[:: max(1, len(idx) // max(size, 1))]]
    return q[np.isfinite(q[:, 2])]


def table_around(tree: Any, table: FloatArray, x: FloatArray, radius_m: float) -> tuple[FloatArray, FloatArray,
                                                                                        FloatArray] | None:  # fmt: skip
    """The plane of the table's points ``table`` (indexed by the k-d ``tree``) around the (N, 3) points ``x``: the
    twelve nearest each within ``radius_m``; its centroid and unit normal, and those table points. None when
    fewer than half of ``x`` have a table point that near, or fewer than 20 table points are around them (the
    table is not around them to tell)."""
    from perception.fits import fit_plane

    if len(x) < 3:
        return None
    d, near = tree.query(x, k=12, distance_upper_bound=radius_m)
    found = np.isfinite(d)
    around = table[np.unique(near[found])]
    if np.mean(found[:, 0]) < 0.5 or len(around) < 20:
        return None
    c, n, _ = fit_plane(around)
    return c, n, around


def _off_tolerance(noise: NoiseModel, z: FloatArray | float) -> FloatArray:
    """How far in front of a support plane a point at range ``z`` may lie and still count as on it: six sigma of
    the noise plus 2 mm. Beyond that it stands off the plane (:func:`_carries`, :func:`_touches`)."""
    return np.asarray(6.0 * noise.sigma_m(z) + 0.002)


def _flatness(noise: NoiseModel, z: FloatArray | float) -> FloatArray:
    """How flat a table at range ``z`` can be shown: a table's own flatness and four times the sensor's
    structured error there."""
    return np.asarray(FLATNESS_M + BEHIND_SIGMA * noise.structure_1m_m * np.square(z))


def _plane_pieces(surfaces: SurfaceSet, noise: NoiseModel) -> dict[int, frozenset[int]]:
    """Per plane's label: the labels of it and of every other piece of the same plane (the table seen on both
    sides of the part), for all planes at once (every pair of planes is compared: a loop per plane over all
    the others grew with the square of their number in Python)."""
    planes = [s for s in surfaces.surfaces if s.kind == "plane"]
    if not planes:
        return {}
    labels = np.array([s.label for s in planes])
    normal = np.array([s.normal for s in planes])  # (k, 3)
    centroid = np.array([s.centroid for s in planes])
    z = np.array([s.z_m for s in planes])
    n = np.maximum(np.array([s.n_points for s in planes]), 1)
    parallel = normal @ normal.T > np.cos(np.radians(3.0))  # [i, j]: plane j is parallel to plane i
    # the same plane: the piece's mean within a table's flatness of the plane (its noise averages out over its
    # points, the sensor's structured error does not); a plate lying on the table is its thickness above it
    res = np.abs(np.einsum("jk,ik->ij", centroid, normal) + np.array([s.offset for s in planes])[:, None])
    same = parallel & (res <= _flatness(noise, z) + 3.0 * noise.sigma_m(z) / np.sqrt(n))
    np.fill_diagonal(same, True)
    return {int(labels[i]): frozenset(labels[same[i]].tolist()) for i in range(len(planes))}


def _carries(p: NDArray[np.floating], surfaces: SurfaceSet, noise: NoiseModel, pieces: frozenset[int],
             mine: NDArray[np.bool_], off: FloatArray) -> bool:  # fmt: skip
    """Whether the points ``off`` (standing off a plane, on its camera side) stand over it: at least
    :data:`CARRY_SHARE` of them, dropped onto the plane, lie within its outline (the footprint of the points
    of all its ``pieces``, whose pixels ``mine`` marks, :func:`footprint_share`, grown by twice its samples'
    spacing along it). Nothing standing off it: it carries (an empty table)."""
    if len(off) == 0:
        return True
    from perception.fine.cylinder import axis_basis

    s = surfaces.surfaces[max(sorted(pieces), key=lambda k: surfaces.surfaces[k].n_points)]  # the largest piece
    e1, e2 = axis_basis(s.normal)
    idx = np.flatnonzero(mine.reshape(-1))
    own = np.asarray(p, dtype=np.float64).reshape(-1, 3)[idx[:: max(1, len(idx) // 2000)]]
    own = own[np.isfinite(own[:, 2])]
    if len(own) < 3:
        return False
    # the outline is as coarse as the plane's samples along it: a floor seen at a grazing angle ends a
    # stretched sample short of the wall standing on it
    cos_in = np.abs(own @ s.normal) / np.linalg.norm(own, axis=1)
    stretched = noise.spacing_m(own[:, 2]) / np.maximum(cos_in, 0.1)
    grow = FOOTPRINT_GROW_M + 2.0 * float(percentile(stretched, 95))
    off = off[:: max(1, len(off) // 2000)]
    e12 = np.column_stack([e1, e2])
    return footprint_share(off @ e12, own @ e12, grow) >= CARRY_SHARE


def _touches(surfaces: SurfaceSet, noise: NoiseModel, pieces: frozenset[int], mine: NDArray[np.bool_],
             S: Surface) -> bool:  # fmt: skip
    """Whether the surfaces standing off plane ``S`` (their centroid beyond its tolerance on its camera side)
    touch its ``pieces`` (their pixels: ``mine``) pixel to pixel along :data:`CONTACT_M` at least: a plate lying
    on a table seen on one side of it only stands on it along its edge, a plate beside a lower one is parted
    from it by a gap (pixels with no depth, or depth behind both)."""
    import cv2

    off = [t.label for t in surfaces.surfaces if t.label not in pieces
           and float(S.residual(t.centroid[None])[0]) > float(_off_tolerance(noise, t.z_m))]  # fmt: skip
    if not off:
        return False
    ring = cv2.dilate(mine.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~mine
    contact = int(np.count_nonzero(ring & np.isin(surfaces.labels, off)))
    return contact * float(noise.spacing_m(S.z_m)) >= CONTACT_M  # the work image's own spacing


def footprint_share(xy: FloatArray, of: FloatArray, grow_m: float = FOOTPRINT_GROW_M) -> float:
    """The share of the (N, 2) points ``xy`` within the footprint of the (M, 2) points ``of``: their convex
    hull grown by ``grow_m`` (both dropped onto one plane, in its own axes)."""
    from scipy.spatial import ConvexHull, Delaunay, QhullError

    try:  # the grown hull's corners are the hull's corners grown (a Minkowski sum): grow only those
        base = of[ConvexHull(of).vertices]
    except QhullError:  # too few or collinear points: grown, they still span an area
        base = of
    grown = np.vstack([base + step for step in grow_m * np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])])
    try:
        hull = grown[ConvexHull(grown).vertices]
        return float(np.mean(Delaunay(hull).find_simplex(xy) >= 0))
    except QhullError:  # points along one line: a hull of no area holds nothing
        return 0.0
