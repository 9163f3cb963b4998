"""An unorganized cloud seen as a range image, so that the surfaces-first stage can run on it.

A PLY or PCD scan has no pixel grid; the fine stage (:mod:`perception.fine`) reads neighbourhoods, contact
bands and rays off one. Here the cloud is looked at from its sensor's side (:func:`sensor_side`, the stated
rule for which side is outside) by a virtual pinhole camera whose pixel is about the cloud's sample
spacing. Each pixel keeps the nearest point along its ray (a z-buffer) at its exact position: the points
are not moved onto the pixel centres, so nothing is lost to the grid but the points behind others; single
empty pixels between points take their nearest neighbour's point. A cloud that holds points behind its
visible faces (scans merged, a mesh sampled on every face, a lower plate sampled under an upper one) is
looked at with pixels coarse enough for its faces' samples to cover them, and a point still seen through a
hole in a face is dropped for the face's own. Seams found in that view are mapped back with
``X_cloud_camera``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from perception.capture import CameraIntrinsics
from perception.errors import PerceptionError

FloatArray = NDArray[np.float64]

PIXEL_PER_SPACING = 1.25  # the virtual pixel, in the cloud's (angular) sample spacings: coarser, so that a
# surface's samples leave no pixel empty for what lies behind it to show through
MAX_SIDE_PX = 1600
MAX_SEEN_THROUGH = 0.06  # of the pixels showing a point behind the faces: below this, holes come one or two
# together, and _drop_seen_through gives them the face's point (see _covering_focal)
HOLES_CLOSE = 2.5  # holes between a face's samples: their share falls this much with pixels 1.25^2 as wide
BRIDGE_GAP_PX = 8  # the widest run between a scan's lines bridged (pixels of 1.25 in-line spacings)
BRIDGE_SLOPE = 3.0  # ... on a face seen up to 72 degrees off its normal
BRIDGE_SHARE = 0.02  # ... when the view shows a scan's lines apart: bridges for this share of its points or more
SEEN_THROUGH_PIXELS = 3.0  # a pixel's point this many pixel widths behind its neighbours on both sides lies
# behind a surface whose samples left its pixel empty: no surface sampled at the pixel holds a pit that deep


@dataclass(frozen=True)
class CloudView:
    """``organized``: (H, W, 3) float32 points in the virtual camera frame, NaN where no point; the
    camera's ``intrinsics``; ``X_cloud_camera``: (4, 4) the camera's pose in the cloud's frame."""

    organized: NDArray[np.float32]
    intrinsics: CameraIntrinsics
    X_cloud_camera: FloatArray


def _angular_spacing(points: FloatArray, eye: FloatArray, *, neighbour: int, sample: int = 20000) -> float:
    """The cloud's sample spacing as seen from ``eye``: the median, over points, of the distance to the
    ``neighbour``-th nearest neighbour divided by the range."""
    from scipy.spatial import cKDTree

    q = points[np.random.default_rng(0).choice(len(points), min(sample, len(points)), replace=False)]
    d, _ = cKDTree(points).query(q, k=neighbour + 1)
    return float(np.median(d[:, neighbour] / np.maximum(np.linalg.norm(q - eye, axis=1), 1e-9)))


def _pixel_keys(xn: FloatArray, yn: FloatArray, f: float) -> NDArray[np.int64]:
    """One integer per pixel of a camera of focal length ``f``, for the points at normalized image
    coordinates ``xn``, ``yn``."""
    return np.floor(f * xn).astype(np.int64) * 1_000_003 + np.floor(f * yn).astype(np.int64)


def _in_front(cam: FloatArray, xn: FloatArray, yn: FloatArray, f: float, depth_per_range: float) -> NDArray[np.bool_]:
    """Which of the (N, 3) camera-frame points ``cam`` (at normalized image coordinates ``xn``, ``yn``) lie
    within ``depth_per_range`` times their range of the nearest point in their pixel of a camera of focal
    length ``f`` (coarse, so that a face's samples fill its pixels): the points seen, not those behind."""
    _, inv = np.unique(_pixel_keys(xn, yn, f), return_inverse=True)
    nearest = np.full(int(inv.max()) + 1, np.inf)
    np.minimum.at(nearest, inv, cam[:, 2])
    return np.asarray(cam[:, 2] <= nearest[inv] * (1.0 + depth_per_range))


def _covering_focal(cam: FloatArray, xn: FloatArray, yn: FloatArray, f: float) -> float:
    """``f``, or coarser by steps of 1.25 (four at most) until at most :data:`MAX_SEEN_THROUGH` of the pixels
    show a point behind the faces (:func:`_seen_through_share`), when those are seen through holes between
    the faces' samples. A scan's grid fills every pixel 1.25 spacings wide; a mesh sampled at random, or
    scans merged, leave a third of them empty at that size, and through the holes the layer behind the faces
    (the lower plate under a lap) shows. Such holes close fast with coarser pixels (their share falls as
    exp(-points per pixel): by more than :data:`HOLES_CLOSE` over two steps); points behind for other reasons
    (a face seen at a grazing angle, mixed points along an edge, a tube's far wall seen past its rim) stay,
    and are no reason to give up resolution."""
    shares: dict[int, float] = {}  # per step of 1.25 coarser, each measured once

    def share(step: int) -> float:
        if step not in shares:
            shares[step] = _seen_through_share(cam, xn, yn, f / 1.25**step)
        return shares[step]

    if share(0) <= MAX_SEEN_THROUGH or share(0) < HOLES_CLOSE * share(2):
        return f
    step = 1
    while step < 4 and share(step) > MAX_SEEN_THROUGH:
        step += 1
    return f / 1.25**step


def _seen_through_share(cam: FloatArray, xn: FloatArray, yn: FloatArray, f: float) -> float:
    """The share of the pixels of a camera of focal length ``f`` whose nearest point lies behind the faces:
    behind its pixel's nearest point in a camera of half the focal length, whose pixels the faces' samples
    fill (:func:`_in_front`)."""
    seen = _in_front(cam, xn, yn, 0.5 * f, SEEN_THROUGH_PIXELS / f)
    key = _pixel_keys(xn, yn, f)
    order = np.lexsort((cam[:, 2], key))
    nearest = order[np.r_[True, key[order][1:] != key[order][:-1]]]
    return 1.0 - float(np.mean(seen[nearest]))


def _fill_holes(organized: NDArray[np.float32]) -> NDArray[np.float32]:
    """Empty pixels with at least three of their eight neighbours holding a point take the nearest of those
    points (one pass). A scan seen from another side than it was taken from is sampled coarser across some
    directions than the pixel: without this its faces would come in stripes, and the gaps between stripes
    would read as butt gaps. The point is the neighbour's own, not an interpolation."""
    H, W = organized.shape[:2]
    z = organized[..., 2]
    valid = np.isfinite(z)
    pad = np.pad(organized, ((1, 1), (1, 1), (0, 0)), constant_values=np.nan)
    best = np.full((H, W), np.inf)
    pick = np.full((H, W, 3), np.nan, dtype=np.float32)
    count = np.zeros((H, W), dtype=np.int32)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy == dx == 0:
                continue
            nb = pad[1 + dy : 1 + dy + H, 1 + dx : 1 + dx + W]
            nz = nb[..., 2]
            ok = np.isfinite(nz)
            count += ok
            closer = ok & (nz < best)
            best[closer] = nz[closer]
            pick[closer] = nb[closer]
    fill = ~valid & (count >= 3)
    out = organized.copy()
    out[fill] = pick[fill]
    return out


def _bridge_scan_lines(organized: NDArray[np.float32], f: float) -> NDArray[np.float32]:
    """Empty runs between a scan's lines bridged: a LiDAR's lines on a face seen at a slant lie several
    pixels apart however fine the in-line sampling that sets the pixel, and each line would be a surface of
    its own, a line with no plane to it. An empty run of at most :data:`BRIDGE_GAP_PX` pixels along a row,
    a column or a diagonal takes the nearer of the points at its two ends when those (a) lie on one surface
    (depths within :data:`BRIDGE_SLOPE` pixel widths per pixel of the run) and (b) are each on a scan line:
    a run of points thinner than the gap across it; and (c) the gap is an empty line between two lines: it
    runs on across the way bridged for three times its width, and three quarters of the pixels within 2G
    along it have a point, or one each way within G. A gap between two plates, or a hole in one, has a face
    wider than itself on both sides; the holes between a cloud's random samples are short; a notch in a
    ragged outline opens onto the empty outside; all stay. Only a view that shows a scan's lines apart (runs
    bridged for :data:`BRIDGE_SHARE` of its points) is bridged."""
    import cv2

    z = organized[..., 2]
    H, W = z.shape
    G = BRIDGE_GAP_PX
    pad = 2 * G + 1
    valid = np.isfinite(z)
    pv = np.pad(valid, pad, constant_values=False)
    pz = np.pad(z, pad)  # the depths of the pixels a run ends at (a padding pixel is never one)

    def at(a: NDArray[Any], dy: NDArray[np.int64] | int, dx: NDArray[np.int64] | int) -> NDArray[Any]:
        """``a`` (padded) at each pixel moved by (dy, dx) pixels (at most the padding)."""
        if isinstance(dy, int) and isinstance(dx, int):  # one shift for all: a slice, not a gather
            return a[pad + dy : pad + dy + H, pad + dx : pad + dx + W]
        return a[pad + np.arange(H)[:, None] + dy, pad + np.arange(W)[None, :] + dx]

    def run(mask: NDArray[np.bool_], dy: int, dx: int) -> NDArray[np.int64]:
        """(padded) How many pixels of ``mask`` follow each pixel in a row (dy, dx) on, up to 2G."""
        out, cont = np.zeros(mask.shape, np.int64), np.ones(mask.shape, bool)
        for k in range(1, 2 * G + 1):
            cont &= np.roll(mask, (-k * dy, -k * dx), axis=(0, 1))
            out += cont
        return out

    def count(mask: NDArray[np.bool_], dy: int, dx: int) -> NDArray[np.int64]:
        """How many pixels of ``mask`` lie within 2G pixels of each pixel on its line (dy, dx), itself included."""
        line = np.zeros((4 * G + 1, 4 * G + 1), np.float32)
        k = np.arange(-2 * G, 2 * G + 1)
        line[2 * G + k * dy, 2 * G + k * dx] = 1.0
        summed = cv2.filter2D(mask.astype(np.float32), -1, line, borderType=cv2.BORDER_CONSTANT)
        return np.rint(summed).astype(np.int64)

    steps = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]
    runs = {d: run(pv, *d) for d in steps}
    empty = np.pad(~valid, pad, constant_values=False)
    empty_runs = {d: run(empty, *d) for d in steps}
    best_gap = np.full((H, W), G + 1)
    pick = np.full((H, W), -1, dtype=np.int64)  # the flat index of the point an empty pixel takes
    rows, cols = np.mgrid[0:H, 0:W]
    for dy, dx in ((1, 0), (0, 1), (1, 1), (1, -1)):
        ends = []
        for sign in (1, -1):
            k_end = np.zeros((H, W), dtype=np.int64)  # steps to the first point that way (0: none within G)
            for k in range(G, 0, -1):
                k_end[at(pv, sign * k * dy, sign * k * dx)] = k
            ey, ex = sign * k_end * dy, sign * k_end * dx
            thick = 1 + at(runs[(sign * dy, sign * dx)], ey, ex)
            ends.append((k_end, thick, at(pz, ey, ex), rows + ey, cols + ex))
        (k1, t1, z1, y1, x1), (k2, t2, z2, y2, x2) = ends
        gap = k1 + k2 - 1
        # the empty run is a line too: as long across the way bridged as three times its width
        along = 1 + empty_runs[(dx, -dy)][pad:-pad, pad:-pad] + empty_runs[(-dx, dy)][pad:-pad, pad:-pad]
        with np.errstate(invalid="ignore"):
            one_surface = np.abs(z1 - z2) <= BRIDGE_SLOPE * (gap + 1) * np.fmin(z1, z2) / f
        # ... between two lines all along it: a notch in a ragged outline opens onto the empty outside
        flanked = count(((k1 > 0) & (k2 > 0) & (gap <= G)) | valid, dx, -dy) > 3 * G
        lines = (t1 < gap) & (t2 < gap) & (along >= 3 * gap) & flanked
        take = (k1 > 0) & (k2 > 0) & (gap < best_gap) & one_surface & lines & ~valid
        near1 = k1 <= k2
        pick[take] = (np.where(near1, y1, y2) * W + np.where(near1, x1, x2))[take]
        best_gap[take] = gap[take]
    fill = pick >= 0
    if fill.sum() < BRIDGE_SHARE * valid.sum():
        return organized  # a few runs here and there, not a scan's lines apart
    out = organized.copy()
    out[fill] = organized.reshape(-1, 3)[pick[fill]]
    return out


def _drop_seen_through(organized: NDArray[np.float32], depth_per_range: float) -> NDArray[np.float32]:
    """Pixels whose point was seen through the sampling gaps of a surface in front of it, emptied (for
    :func:`_fill_holes` to give them the front surface's point). A cloud merged from several views, or
    sampled under an upper plate, holds points behind its visible surfaces; where that surface's samples
    leave a pixel empty, the z-buffer keeps the point behind: a pit of another layer's depth in the middle of
    the face. Such a pixel has a point more than ``depth_per_range`` times its range in front of it in every
    one of the eight directions round it (within two pixels), and those points are one layer: their depths
    spread less than twice as far as the pit lies behind the deepest of them. A background pixel beside an
    occluding edge, in a gap, or at a fold's root has its own surface on at least one side; a pixel at a
    ragged edge has points of several depths round it."""
    z = organized[..., 2].astype(np.float64)
    H, W = z.shape
    r = 2
    pad = np.pad(z, r, constant_values=np.nan)
    limit = z * (1.0 - depth_per_range)
    sectors = np.zeros((8, H, W), dtype=bool)
    front_lo = np.full((H, W), np.inf)
    front_hi = np.full((H, W), -np.inf)
    with np.errstate(invalid="ignore"):
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                if dy == dx == 0:
                    continue
                nb = pad[r + dy : r + dy + H, r + dx : r + dx + W]
                near = nb < limit
                sectors[int(np.round(np.arctan2(dy, dx) / (np.pi / 4))) % 8] |= near
                front_lo = np.where(near, np.minimum(front_lo, nb), front_lo)
                front_hi = np.where(near, np.maximum(front_hi, nb), front_hi)
    seen_through = sectors.all(axis=0) & (front_hi - front_lo < 2.0 * (z - front_hi))
    out = organized.copy()
    out[seen_through] = np.nan
    return out


def sensor_side(points: FloatArray, normals: FloatArray | None = None, *, spacing_m: float | None = None) -> FloatArray:
    """Where a cloud's sensor stood, by the stated rule for clouds that do not say (this decides which side
    of a surface is outside, so concave and convex):

    1. the file's normals, when they agree on a side (a scanner's normals face the sensor that saw them);
    2. a cloud in front of its origin (every point at positive z, within a 110-degree cone) is in a camera
       frame: the sensor is the origin;
    3. otherwise the cloud is in a robot or world frame with z up, and the sensor stood above it, at twice
       its size from its centre, on the side from which none of its points hide behind others
       (:func:`_least_hidden_direction`): straight above unless a side shows far fewer hidden.

    ``spacing_m``: the cloud's sample spacing (:func:`perception.cloud.surface_spacing`) when the caller has
    it already."""
    p = np.asarray(points, dtype=np.float64)
    centre = np.median(p, axis=0)
    size = max(float(np.linalg.norm(np.ptp(p, axis=0))), 0.1)
    if normals is not None and len(normals) == len(p):
        n = np.asarray(normals, dtype=np.float64)
        n = n[np.all(np.isfinite(n), axis=1)]  # a NaN normal says nothing (all of them NaN: no normals)
        mean = n.mean(axis=0) if len(n) else np.zeros(3)
        if np.linalg.norm(mean) > 0.2:
            return np.asarray(centre + mean / np.linalg.norm(mean) * 2.0 * size)
    z = p[:, 2]
    if np.all(z > 0) and np.percentile(np.maximum(np.abs(p[:, 0]), np.abs(p[:, 1])) / z, 98) < 1.43:
        return np.zeros(3)
    return np.asarray(centre + _least_hidden_direction(p, centre, size, spacing_m) * 2.0 * size)


SIDE_ELEVATIONS_DEG = (70.0, 50.0, 30.0)  # the directions looked at besides straight down, every 30 degrees round
HIDDEN_DEPTH_SPACINGS = 5.0  # a point this many sample spacings behind the nearest along its pixel's ray is hidden


def view_axes(forward: FloatArray) -> FloatArray:
    """(3, 3) columns x, y, z of a camera looking along the unit ``forward`` (z), x level where it can be
    (across z's up, else across x): the virtual camera of :func:`view_cloud` and of its viewpoint search."""
    x = np.cross(forward, [0.0, 0.0, 1.0] if abs(forward[2]) < 0.9 else [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(forward, x), forward])


def _hidden_share(p: FloatArray, eye: FloatArray, middle: FloatArray, spacing: float) -> float:
    """The share of the (N, 3) points ``p`` that lie behind another point of the cloud (by more than
    :data:`HIDDEN_DEPTH_SPACINGS` sample spacings) along the ray from ``eye``, in pixels 1.5 spacings wide, the
    camera looking at ``middle``."""
    d = p - eye
    r = np.linalg.norm(d, axis=1)
    u = d / r[:, None]
    axis = middle - eye
    x, y, axis = view_axes(axis / np.linalg.norm(axis)).T
    w = np.maximum(u @ axis, 1e-9)
    pix = 1.5 * spacing / float(np.median(r))
    col = np.floor((u @ x) / w / pix).astype(np.int64)
    row = np.floor((u @ y) / w / pix).astype(np.int64)
    key = (col - col.min()) * (int(row.max() - row.min()) + 1) + (row - row.min())
    order = np.argsort(key)  # by pixel (the order within a pixel does not matter: its nearest is its minimum)
    ks, rs = key[order], r[order]
    first = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    nearest = np.repeat(np.minimum.reduceat(rs, first), np.diff(np.r_[first, len(rs)]))
    return float(np.mean(rs - nearest > HIDDEN_DEPTH_SPACINGS * spacing))


def _least_hidden_direction(p: FloatArray, centre: FloatArray, size: float, spacing_m: float | None = None, *,
                            sample: int = 20000) -> FloatArray:  # fmt: skip
    """The unit direction from the cloud's centre towards its sensor, for a cloud in a z-up frame: a scan
    hides none of its own points from the place it was taken from. Straight above, unless a direction
    :data:`SIDE_ELEVATIONS_DEG` above the horizon hides at most half as many points (and 1% of them fewer):
    a tee scanned from one side shows its standing face edge-on from above, and the base plate's shadow
    behind it."""
    from perception.cloud import surface_spacing

    q = p[np.random.default_rng(0).choice(len(p), min(sample, len(p)), replace=False)]
    spacing = surface_spacing(p) if spacing_m is None else spacing_m
    middle = np.median(q, axis=0)  # where every candidate camera looks
    up = np.array([0.0, 0.0, 1.0])
    above = _hidden_share(q, centre + up * 2.0 * size, middle, spacing)
    best, best_dir = above, up
    for el in np.radians(SIDE_ELEVATIONS_DEG):
        for az in np.radians(np.arange(0.0, 360.0, 30.0)):
            d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
            h = _hidden_share(q, centre + d * 2.0 * size, middle, spacing)
            if h < best:
                best, best_dir = h, d
    if best <= 0.5 * above and above - best >= 0.01:
        return best_dir
    return up


def view_cloud(points: FloatArray, viewpoint: FloatArray) -> CloudView:
    """The range image of (N, 3) ``points`` seen from ``viewpoint`` (in the cloud's frame), its pixel
    :data:`PIXEL_PER_SPACING` sample spacings wide (coarser if the image would be wider than
    :data:`MAX_SIDE_PX`). A viewpoint too close for the cloud to fit a 110-degree field of view is moved
    back along its line of sight."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 5:
        raise PerceptionError(f"a cloud must be (N, 3) with N >= 5, got {p.shape}")
    eye = np.asarray(viewpoint, dtype=np.float64)
    centre = np.median(p, axis=0)
    z = centre - eye
    dist = float(np.linalg.norm(z))
    if dist < 1e-6:
        raise PerceptionError("the viewpoint lies at the cloud's centre")
    z /= dist
    R = view_axes(z)  # camera axes in the cloud's frame
    cam = (p - eye) @ R
    # 98% of the points within 55 degrees of the axis (tan 55 = 1.43): move back as far as that needs
    lateral = np.maximum(np.abs(cam[:, 0]), np.abs(cam[:, 1]))
    back = float(np.percentile(lateral / 1.43 - cam[:, 2], 98))
    if back > 0:
        eye = eye - z * back
        cam[:, 2] += back
    front = cam[:, 2] > 1e-3
    cam = cam[front]
    if len(cam) < 5:
        raise PerceptionError("no point of the cloud lies in front of its viewpoint")
    # seen from its own sensor, a cloud is that sensor's grid: its nearest neighbour is a pixel away. Seen
    # from elsewhere (a robot-frame scan, LiDAR lines), it is sampled coarser across some directions, which
    # the fourth neighbour gives: with the finer spacing the faces would come in stripes, and the gaps
    # between stripes read as butt gaps
    own = not np.any(eye)
    f = 1.0 / (PIXEL_PER_SPACING * max(_angular_spacing(cam, np.zeros(3), neighbour=1 if own else 2), 1e-9))
    xn, yn = cam[:, 0] / cam[:, 2], cam[:, 1] / cam[:, 2]
    if not own:
        f = _covering_focal(cam, xn, yn, f)
    span = max(float(np.ptp(xn)), float(np.ptp(yn)), 1e-9)
    f = min(f, (MAX_SIDE_PX - 5) / span)
    cx, cy = -f * float(xn.min()) + 2.0, -f * float(yn.min()) + 2.0
    W = int(np.ceil(f * float(np.ptp(xn)))) + 5
    H = int(np.ceil(f * float(np.ptp(yn)))) + 5
    f = float(np.clip(f, 0.25 * max(W, H), 19.0 * max(W, H)))  # within what a pinhole camera can be
    intr = CameraIntrinsics(fx=f, fy=f, cx=cx, cy=cy, width=W, height=H)
    u = np.floor(f * xn + cx + 0.5).astype(np.int64)  # pixel centres at integers
    v = np.floor(f * yn + cy + 0.5).astype(np.int64)
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    cam, u, v = cam[inside], u[inside], v[inside]
    idx = v * W + u
    order = np.lexsort((cam[:, 2], idx))  # by pixel, nearest first
    first = np.ones(len(order), dtype=bool)
    first[1:] = idx[order][1:] != idx[order][:-1]
    keep = order[first]
    organized = np.full((H, W, 3), np.nan, dtype=np.float32)
    organized[v[keep], u[keep]] = cam[keep]
    if not own:  # seen from its own sensor, every point was seen: none lies behind another's sampling gaps
        organized = _drop_seen_through(organized, SEEN_THROUGH_PIXELS / f)
        organized = _bridge_scan_lines(organized, f)
    organized = _fill_holes(organized)
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, eye
    return CloudView(organized, intr, X)
