"""Image-grid geometry on organized clouds: smoothed points, normals and geometric edges.

All functions take an organized (H, W, 3) camera-frame cloud (metres, NaN where invalid) and work with
box filters, so their cost does not depend on the window size.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatImage = NDArray[np.float32]


def _box(img: NDArray[np.float32], k: int) -> NDArray[np.float32]:
    import cv2

    return np.asarray(cv2.boxFilter(img, -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT))


def smooth_points(points: FloatImage, *, window_px: int) -> tuple[FloatImage, NDArray[np.bool_]]:
    """Normalized box average of valid neighbours: (H, W, 3) smoothed points and the (H, W) valid mask.

    A pixel is valid when at least half of its window has data.
    """
    valid = np.isfinite(points[..., 2])
    w = valid.astype(np.float32)
    filled = np.where(valid[..., None], points, 0.0).astype(np.float32)
    count = _box(w, window_px)
    sums = _box(filled, window_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = sums / count[..., None]
    ok = valid & (count >= 0.5 * window_px * window_px)
    mean[~ok] = np.nan
    return mean.astype(np.float32), ok


def organized_normals(points: FloatImage, *, window_px: int = 5, step_px: int = 2) -> FloatImage:
    """(H, W, 3) unit normals facing the camera (n . p < 0), NaN where undefined.

    Normals are the cross product of central differences of the box-smoothed cloud, ``step_px``
    pixels apart, which is cheap and, at depth edges and folds, undefined or bent (which is what the
    edge detector wants to see).
    """
    sm, ok = smooth_points(points, window_px=window_px)
    s = step_px
    du = np.full_like(sm, np.nan)
    dv = np.full_like(sm, np.nan)
    du[:, s:-s] = sm[:, 2 * s :] - sm[:, : -2 * s]
    dv[s:-s, :] = sm[2 * s :, :] - sm[: -2 * s, :]
    n = np.cross(du, dv)
    norm = np.sqrt(_dot(n, n))[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        n /= norm
    flip = _dot(n, sm) > 0
    n[flip] *= -1
    n[~ok] = np.nan
    return n.astype(np.float32, copy=False)


def _dot(a: FloatImage, b: FloatImage) -> FloatImage:
    """Per-pixel dot product of two (..., 3) images."""
    return np.asarray(np.einsum("...k,...k->...", a, b))


def normal_edges(normals: FloatImage, *, max_angle_rad: float, step_px: int = 2) -> NDArray[np.bool_]:
    """Pixels where the normal turns by more than ``max_angle_rad`` across ``step_px`` in u or v."""
    c = np.cos(max_angle_rad)
    s = step_px
    edge = np.zeros(normals.shape[:2], bool)
    with np.errstate(invalid="ignore"):
        du = _dot(normals[:, 2 * s :], normals[:, : -2 * s])
        dv = _dot(normals[2 * s :, :], normals[: -2 * s, :])
    edge[:, s:-s] |= ~(du > c)
    edge[s:-s, :] |= ~(dv > c)
    return edge


def pixel_angle_rad(points: FloatImage) -> float:
    """Angle between neighbouring pixel rays (about 1 / fx), read off the cloud itself."""
    x = points[..., 0]
    z = points[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.diff(x / z, axis=1)
    d = d[np.isfinite(d)]
    return float(np.median(np.abs(d))) if d.size else 0.0


def depth_edges(points: FloatImage, *, jump_m: float, footprint_factor: float = 4.0) -> NDArray[np.bool_]:
    """Pixels next to a 3D jump to a 4-neighbour, or invalid.

    A jump is a neighbour distance above ``jump_m + footprint_factor * z * pixel_angle``: the pixel
    footprint grows with depth and with obliquity (a surface at 75 degrees spreads pixels ~4x apart).
    """
    z = points[..., 2]
    valid = np.isfinite(z)
    edge = ~valid
    thr = jump_m + footprint_factor * pixel_angle_rad(points) * np.nan_to_num(z)
    for img, t, out in ((points, thr, edge), (points.transpose(1, 0, 2), thr.T, edge.T)):  # along v, then u
        diff = img[1:] - img[:-1]
        d = np.sqrt(_dot(diff, diff))
        with np.errstate(invalid="ignore"):
            jump = ~(d <= t[:-1])
        out[:-1] |= jump
        out[1:] |= jump
    return edge


def veil_mask(
    points: FloatImage, *, jump_m: float = 0.003, spike_ratio: float = 2.5, window_px: int = 5, dilate_px: int = 2
) -> NDArray[np.bool_]:
    """Pixels at a depth discontinuity, where flying pixels hang between foreground and background.

    On the box-smoothed cloud (so sensor noise does not trigger it), a pixel is at a discontinuity when
    the 3D step across it exceeds ``jump_m`` and ``spike_ratio`` times the larger of the steps just
    before and after it: a surface seen obliquely has large but even steps, and a fold between a flat
    and a steep face has the steep face's steps on one side, but a discontinuity is one spike.
    """
    import cv2

    sm, _ = smooth_points(points, window_px=window_px)
    s = 2
    edge = np.zeros(sm.shape[:2], bool)
    with np.errstate(invalid="ignore"):
        for img, out in ((sm, edge), (sm.transpose(1, 0, 2), edge.T)):  # along v, then along u (views)
            n = img.shape[0]
            if n <= 6 * s:
                continue
            # steps across each pixel, 2s apart: D[j] = |p[j + 2s] - p[j]| is centred on pixel j + s, so the
            # step across pixel i and those just before and after it are D[i - s], D[i - 3s] and D[i + s]
            diff = img[2 * s :] - img[: -2 * s]
            D = np.sqrt(_dot(diff, diff))
            d0, d_prev, d_next = D[2 * s : n - 4 * s], D[: n - 6 * s], D[4 * s : n - 2 * s]
            calm = np.fmax(d_prev, d_next)
            spike = (d0 > jump_m) & ~(d0 <= spike_ratio * np.nan_to_num(calm, nan=np.inf))
            spike |= (d0 > jump_m) & np.isnan(calm)
            out[3 * s : n - 3 * s] |= spike
    if dilate_px > 0:
        k = 2 * dilate_px + 1
        edge = cv2.dilate(edge.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
    return edge


def downsample_organized(points: FloatImage, factor: int) -> FloatImage:
    """Every ``factor``-th pixel (no averaging: keeps depth edges sharp and points exact)."""
    if factor <= 1:
        return points
    return np.ascontiguousarray(points[::factor, ::factor])


def points_at(points: FloatImage, rows: NDArray[np.intp], cols: NDArray[np.intp]) -> NDArray[np.float64]:
    """The (N, 3) float64 points of an organized cloud at pixels (``rows``, ``cols``), in that order: taken by
    flat index, two to three times faster than ``points[rows, cols]`` or a boolean mask on a window or a strided
    view of it (the same values)."""
    return np.take(points.reshape(-1, 3), rows * points.shape[1] + cols, axis=0).astype(np.float64)
