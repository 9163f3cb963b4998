"""The capture's own noise: local plane fits in a small window at every pixel of the work image.

Box filters give each pixel's window moments (count, mean, covariance) in float64; the smallest eigenvalue
of the covariance is the variance of the points about their best local plane, its eigenvector the normal.
On flat parts that variance is the depth noise; where the window straddles a fold or an edge it is much
larger, which is what the surface segmentation reads.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from perception.errors import NoSeamFound
from perception.fine.types import NoiseModel
from perception.fits import median, percentile

FloatArray = NDArray[np.float64]

NOISE_PERCENTILE = 30.0  # flat pixels dominate every capture; folds and edges sit in the upper tail
FLOOR_M = 5e-5  # the models' own accuracy: no threshold below this


@dataclass(frozen=True)
class LocalPlanes:
    """Per pixel of an (h, w) work image: window point count, unit normal towards the camera (h, w, 3),
    residual variance about the local plane (m^2) and surface variation (that variance over the trace)."""

    count: NDArray[np.float64]
    normal: NDArray[np.float64]
    variance: NDArray[np.float64]
    variation: NDArray[np.float64]
    window_px: int


def local_planes(points: NDArray[np.floating], *, window_px: int, threads: int = 1) -> LocalPlanes:
    """Moments of each pixel's ``window_px`` square window of valid points (NaN = invalid).

    The box sums are OpenCV's; the per-pixel algebra before and after them runs compiled (:mod:`numba`), one
    pass each (as NumPy expressions over whole planes it took 20 ms of a median dev capture's 40 ms here).
    ``threads=2``: the top and bottom halves of the image on two threads (OpenCV and the compiled passes leave
    the GIL), each with the rows its planes read beyond it (the same values): for a caller whose second core
    is otherwise idle (the detector's, while its helper process waits for the fine stage)."""
    p = np.ascontiguousarray(points, dtype=np.float64)
    valid = np.isfinite(p[..., 2])
    ref = np.zeros(3)
    if valid.any():  # per coordinate, in its own gathered copy: the values of np.nanmedian(p[valid], axis=0)
        ref = np.array([median(p[..., k][valid], overwrite_input=True) for k in range(3)])
    h = p.shape[0]
    reach = 2 * (window_px // 2)  # a row's planes read this many rows either side: the box, then the normals' step
    if threads < 2 or h < 8 * reach:
        return _rows_planes(p, valid, ref, window_px)
    bands = ((0, h // 2), (h // 2, h))

    def band(i: int) -> tuple[LocalPlanes, int, int]:
        a, b = bands[i]
        lo, hi = max(a - reach, 0), min(b + reach, h)
        return _rows_planes(p[lo:hi], valid[lo:hi], ref, window_px), a - lo, b - lo

    with ThreadPoolExecutor(1, thread_name_prefix="local-planes") as pool:
        bottom = pool.submit(band, 1)
        done = [band(0), bottom.result()]  # a failure in either is raised here

    def rows(field: str) -> FloatArray:
        return np.concatenate([getattr(lp, field)[a:b] for lp, a, b in done])

    return LocalPlanes(rows("count"), rows("normal"), rows("variance"), rows("variation"), window_px)


def _rows_planes(p: FloatArray, valid: NDArray[np.bool_], ref: FloatArray, window_px: int) -> LocalPlanes:
    """:func:`local_planes` of the points ``p`` (every row of them) about the reference point ``ref``."""
    import cv2

    # one contiguous plane per moment, relative to one point (small sums, no cancellation)
    k = (window_px, window_px)
    sums = [np.asarray(cv2.boxFilter(img, cv2.CV_64F, k, normalize=False, borderType=cv2.BORDER_CONSTANT), np.float64)
            for img in _moment_planes(p, valid, ref)]  # fmt: skip
    return _planes_from_sums(p, valid, sums, window_px)


def _planes_from_sums(p: FloatArray, valid: NDArray[np.bool_], sums: list[FloatArray], window_px: int) -> LocalPlanes:
    """The local planes from each window's sums of 1, x, y, z and their products (:func:`_moment_planes`' order):
    the normal from the window means' central differences ``window_px // 2`` pixels to either side (a plane's
    means lie on it; NaN within that of the border), towards the camera, and the residual variance about that
    plane, the quadratic form n^T C n (the eigen-solve would cost 4x more)."""
    n = sums[0]
    normal = np.empty(p.shape)
    var = np.empty(n.shape)
    variation = np.empty(n.shape)
    _plane_algebra(p, valid, tuple(sums), max(1, window_px // 2), 0.5 * window_px * window_px, normal, var, variation)
    return LocalPlanes(n, normal, var, variation, window_px)


@njit(cache=True, nogil=True)
def _moment_planes(p: FloatArray, valid: NDArray[np.bool_], ref: FloatArray) -> tuple[FloatArray, ...]:
    """Per pixel, planes of: 1 for a valid point (0 else), its x, y, z relative to ``ref`` (0 when invalid), and
    their products xx, xy, xz, yy, yz, zz."""
    h, w = valid.shape
    out = np.zeros((10, h, w))
    for y in range(h):
        for x in range(w):
            if not valid[y, x]:
                continue
            qx, qy, qz = p[y, x, 0] - ref[0], p[y, x, 1] - ref[1], p[y, x, 2] - ref[2]
            out[0, y, x] = 1.0
            out[1, y, x], out[2, y, x], out[3, y, x] = qx, qy, qz
            out[4, y, x], out[5, y, x], out[6, y, x] = qx * qx, qx * qy, qx * qz
            out[7, y, x], out[8, y, x], out[9, y, x] = qy * qy, qy * qz, qz * qz
    return (out[0], out[1], out[2], out[3], out[4], out[5], out[6], out[7], out[8], out[9])


@njit(cache=True, nogil=True)
def _plane_algebra(p: FloatArray, valid: NDArray[np.bool_], sums: tuple[FloatArray, ...], st: int, min_count: float,
                   normal: FloatArray, var: FloatArray, variation: FloatArray) -> None:  # fmt: skip
    """:func:`_planes_from_sums` into ``normal`` (h, w, 3), ``var`` and ``variation``, in NumPy's order of
    operations on whole planes (the same values)."""
    n, sx, sy, sz, sxx, sxy, sxz, syy, syz, szz = sums
    h, w = n.shape
    mx, my, mz = np.empty((h, w)), np.empty((h, w)), np.empty((h, w))
    for y in range(h):
        for x in range(w):
            nn = max(n[y, x], 1.0)
            mx[y, x], my[y, x], mz[y, x] = sx[y, x] / nn, sy[y, x] / nn, sz[y, x] / nn
    for y in range(h):
        for x in range(w):
            if st <= x < w - st and st <= y < h - st:
                du0, du1 = mx[y, x + st] - mx[y, x - st], my[y, x + st] - my[y, x - st]
                du2 = mz[y, x + st] - mz[y, x - st]
                dv0, dv1 = mx[y + st, x] - mx[y - st, x], my[y + st, x] - my[y - st, x]
                dv2 = mz[y + st, x] - mz[y - st, x]
                cx, cy, cz = du1 * dv2 - du2 * dv1, du2 * dv0 - du0 * dv2, du0 * dv1 - du1 * dv0
                norm = np.sqrt(cx * cx + cy * cy + cz * cz)
                nx, ny, nz = _unit(cx, norm), _unit(cy, norm), _unit(cz, norm)
            else:
                nx, ny, nz = np.nan, np.nan, np.nan
            if nx * p[y, x, 0] + ny * p[y, x, 1] + nz * p[y, x, 2] > 0.0:  # towards the camera (NaN: never)
                nx, ny, nz = -nx, -ny, -nz
            nn = max(n[y, x], 1.0)
            cxx = sxx[y, x] / nn - mx[y, x] * mx[y, x]
            cxy = sxy[y, x] / nn - mx[y, x] * my[y, x]
            cxz = sxz[y, x] / nn - mx[y, x] * mz[y, x]
            cyy = syy[y, x] / nn - my[y, x] * my[y, x]
            cyz = syz[y, x] / nn - my[y, x] * mz[y, x]
            czz = szz[y, x] / nn - mz[y, x] * mz[y, x]
            v = nx * nx * cxx + ny * ny * cyy + nz * nz * czz + 2 * (nx * ny * cxy + nx * nz * cxz + ny * nz * cyz)
            total = cxx + cyy + czz
            total = total if total != total or total > 1e-30 else 1e-30  # np.maximum: NaN stays NaN
            if v < 0.0:
                v = 0.0
            if n[y, x] < min_count or not valid[y, x] or not np.isfinite(v):
                v, nx, ny, nz = np.nan, np.nan, np.nan, np.nan
            normal[y, x, 0], normal[y, x, 1], normal[y, x, 2] = nx, ny, nz
            var[y, x] = v
            variation[y, x] = v / total


@njit(cache=True)
def _unit(c: float, norm: float) -> float:
    """c / norm as NumPy divides (a zero norm: inf with the numerator's sign, or NaN for 0 / 0)."""
    if norm == 0.0:
        if c == 0.0 or c != c:
            return np.nan
        return np.inf if c > 0.0 else -np.inf
    return c / norm


def estimate_noise(points: NDArray[np.floating], planes: LocalPlanes) -> NoiseModel:
    """sigma(z) = s * z^2 fitted to the local plane residuals of full windows, the pixel angle, and the
    structured error (:func:`structured_error`)."""
    sigma_1m = _sigma_1m(points, planes)
    z = np.asarray(points[..., 2], dtype=np.float64)
    x = np.asarray(points[..., 0], dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.abs(np.diff(x / z, axis=1))
    d = d[np.isfinite(d)]
    angle = float(median(d)) if d.size else 1e-3
    return NoiseModel(sigma_1m_m=sigma_1m, floor_m=FLOOR_M, pixel_angle_rad=max(angle, 1e-6),
                      structure_1m_m=structured_error(points, sigma_1m))  # fmt: skip


def _sigma_1m(points: NDArray[np.floating], planes: LocalPlanes) -> float:
    """s of sigma(z) = s * z^2 (at least :data:`FLOOR_M`), from the local plane residuals of full windows."""
    z = np.asarray(points[..., 2], dtype=np.float64)
    full = np.isfinite(planes.variance) & (planes.count >= planes.window_px**2 - 0.5) & np.isfinite(z)
    if full.sum() < 100:
        full = np.isfinite(planes.variance) & np.isfinite(z)
    if not full.any():
        raise NoSeamFound("no pixel has a full window of valid depth: too few neighbouring points to measure the noise")
    k = planes.window_px**2
    # the variance of k points about their own best plane underestimates sigma^2 by (k - 3) / k
    sig = np.sqrt(planes.variance[full] * k / max(k - 3, 1))
    return max(float(percentile(sig / z[full] ** 2, NOISE_PERCENTILE)), FLOOR_M)


WIDE_STEP = 3  # the structured error is measured on planes this many times as wide as the noise model's


def structured_error(points: NDArray[np.floating], sigma_1m_m: float) -> float:
    """The depth error at 1 m that the noise model's small planes do not see: sqrt(sigma_wide^2 - sigma^2),
    with sigma_wide measured as the noise model's ``sigma_1m_m`` is (local planes seven samples wide) on every
    :data:`WIDE_STEP`-th sample: the same estimate on the same number of points, so white noise gives
    sigma_wide = sigma. A stereo camera's smoothed disparities give about 0.25 sigma, the LiDAR sweeps 2 to 3
    sigma. A swept LiDAR measures a welding table as interleaved layers of scan lines a few millimetres apart,
    and bends it by as much across the scene: error that grows with the scale it is seen at."""
    coarse = np.ascontiguousarray(np.asarray(points, dtype=np.float64)[::WIDE_STEP, ::WIDE_STEP])
    try:
        wide = _sigma_1m(coarse, local_planes(coarse, window_px=7))
    except NoSeamFound:  # too few full windows at that spacing: no measure of it
        return 0.0
    return float(np.sqrt(max(wide**2 - sigma_1m_m**2, 0.0)))
