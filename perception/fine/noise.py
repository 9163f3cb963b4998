"""The capture's own noise: local plane fits in a small window at every pixel of the work image.

Box filters give each pixel's window moments (count, mean, covariance) in float64; the smallest eigenvalue
of the covariance is the variance of the points about their best local plane, its eigenvector the normal.
On flat parts that variance is the depth noise; where the window straddles a fold or an edge it is much
larger, which is what the surface segmentation reads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from perception.errors import NoSeamFound
from perception.fine.types import NoiseModel
from perception.fits import median

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


def local_planes(points: NDArray[np.floating], *, window_px: int) -> LocalPlanes:
    """Moments of each pixel's ``window_px`` square window of valid points (NaN = invalid)."""
    import cv2

    p = np.asarray(points, dtype=np.float64)
    valid = np.isfinite(p[..., 2])
    ref = np.zeros(3)
    if valid.any():  # per coordinate, in its own gathered copy: the values of np.nanmedian(p[valid], axis=0)
        ref = np.array([np.nanmedian(p[..., k][valid], overwrite_input=True) for k in range(3)])
    # one contiguous plane per coordinate, relative to one point (small sums, no cancellation): the filters
    # and the per-pixel algebra below run on whole planes, not on strided (h, w, 3) views
    qx, qy, qz = (np.where(valid, p[..., k] - ref[k], 0.0) for k in range(3))

    def box(img: FloatArray) -> FloatArray:
        return np.asarray(cv2.boxFilter(img, cv2.CV_64F, (window_px, window_px), normalize=False,
                                        borderType=cv2.BORDER_CONSTANT))  # fmt: skip

    n = box(valid.astype(np.float64))
    nn = np.maximum(n, 1.0)
    mx, my, mz = box(qx) / nn, box(qy) / nn, box(qz) / nn
    # the normal from the window means' central differences (a plane's means lie on it); the residual
    # variance about that plane is the quadratic form n^T C n (the eigen-solve would cost 4x more)
    nx, ny, nz = _mean_normal((mx, my, mz), max(1, window_px // 2))
    normal = np.stack([nx, ny, nz], axis=-1)
    with np.errstate(invalid="ignore"):
        flip = np.einsum("hwk,hwk->hw", normal, p) > 0  # NaN (an invalid pixel) is never > 0
    for c in (nx, ny, nz):
        np.negative(c, out=c, where=flip)
    cxx = box(qx * qx) / nn - mx**2
    cxy = box(qx * qy) / nn - mx * my
    cxz = box(qx * qz) / nn - mx * mz
    cyy = box(qy * qy) / nn - my**2
    cyz = box(qy * qz) / nn - my * mz
    czz = box(qz * qz) / nn - mz**2
    var = nx * nx * cxx + ny * ny * cyy + nz * nz * czz + 2 * (nx * ny * cxy + nx * nz * cxz + ny * nz * cyz)
    total = np.maximum(cxx + cyy + czz, 1e-30)
    var = np.clip(var, 0.0, None)
    few = (n < 0.5 * window_px * window_px) | ~valid | ~np.isfinite(var)
    var[few] = np.nan
    normal = np.stack([np.where(few, np.nan, c) for c in (nx, ny, nz)], axis=-1)
    return LocalPlanes(n, normal, var, var / total, window_px)


def _mean_normal(m: tuple[FloatArray, FloatArray, FloatArray], st: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(nx, ny, nz) (h, w) planes of the unit normal of the window means ``m`` (x, y, z planes): the cross
    product of their central differences ``st`` pixels to either side along a row and down a column (NaN
    within ``st`` of the border), in NumPy's own order of operations (``np.cross``, ``np.linalg.norm``)."""
    du, dv = [], []
    for c in m:
        du.append(np.full_like(c, np.nan))
        dv.append(np.full_like(c, np.nan))
        du[-1][:, st:-st] = c[:, 2 * st :] - c[:, : -2 * st]
        dv[-1][st:-st, :] = c[2 * st :, :] - c[: -2 * st, :]
    nx = du[1] * dv[2] - du[2] * dv[1]
    ny = du[2] * dv[0] - du[0] * dv[2]
    nz = du[0] * dv[1] - du[1] * dv[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.sqrt(nx * nx + ny * ny + nz * nz)
        return nx / norm, ny / norm, nz / norm


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
    return max(float(np.percentile(sig / z[full] ** 2, NOISE_PERCENTILE)), FLOOR_M)


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
