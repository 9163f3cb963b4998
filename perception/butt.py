"""Butt joints: two plates in one plane with a narrow gap between them, found from the plates' points and the
image's scanlines across the gap (:func:`butt_from_surfaces`). Camera frame, metres."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from perception.cloud import kdtree
from perception.fits import fit_line, fit_plane_robust, orient_towards
from perception.seamfit import SeamParams

FloatArray = NDArray[np.float64]


def butt_from_surfaces(
    pa: FloatArray,
    pb: FloatArray,
    scanlines: list[FloatArray] | Callable[[], list[FloatArray]],
    params: SeamParams,
    viewpoint: FloatArray,
) -> tuple[FloatArray, FloatArray, float, float] | None:
    """A butt joint between two surfaces: ``pa``, ``pb`` are the points of the two masks near where they
    meet; ``scanlines`` are the valid points of each image row (or column) crossing the joint, in
    order, or a callable giving them (built only once the planes say it may be a butt joint; masks are
    imprecise right at a gap, so the edges are traced on every point). Both surfaces must lie on one
    plane, and a real gap must separate them.

    On each scanline the gap is the widest step between consecutive top-surface samples near the joint
    (one scanline, one last sample per plate: no maximum over noisy rows, which would be biased).
    A plate's edge is its side wall where the camera sees that wall inside the gap, otherwise its
    last sample plus half the sample spacing (the mean shortfall of the last pixel).
    The seam is the mid-line of the two edge lines. Returns (end points (2, 3), plane normal, RMS,
    gap width), or None when it is not a butt joint.
    """
    plane = _common_plane(pa, pb, params, viewpoint)
    if plane is None:
        return None
    c, n, rms, qa, qb = plane
    da, _ = kdtree(qb).query(qa, distance_upper_bound=0.006)
    db, _ = kdtree(qa).query(qb, distance_upper_bound=0.006)
    border = np.vstack([qa[np.isfinite(da)], qb[np.isfinite(db)]])
    if len(border) < 20:
        return None
    mid, d = fit_line(border - np.outer((border - c) @ n, n))
    d -= (d @ n) * n
    d /= np.linalg.norm(d)
    across = np.cross(n, d)
    if (qb.mean(axis=0) - qa.mean(axis=0)) @ across < 0:
        across = -across
    sigma = max(rms, 1e-4)
    if callable(scanlines):
        scanlines = scanlines()
    rows = [
        row
        for line_pts in scanlines
        if (row := _edges_on_scanline(line_pts, mid=mid, d=d, across=across, c=c, n=n, sigma=sigma)) is not None
    ]
    if len(rows) < 5:
        return None
    crossing = sum(1 for line_pts in scanlines if len(line_pts) >= 6)
    if len(rows) < params.butt_min_gap_share * max(crossing, 1):
        return None  # a real gap shows on most scanlines across the joint; noise shows on a few
    arr = np.array(rows)
    A = np.column_stack([np.ones(len(arr)), arr[:, 0]])
    coefs = [_robust_line_fit(A, arr[:, col]) for col in (1, 2)]
    lo = float(arr[:, 0].min()) + params.end_trim_m
    hi = float(arr[:, 0].max()) - params.end_trim_m
    if hi - lo < params.min_length_m:
        return None
    tt = np.array([lo, hi])
    xa = coefs[0][0] + coefs[0][1] * tt
    xb = coefs[1][0] + coefs[1][1] * tt
    gap = float(np.mean(xb - xa))
    if not params.min_gap_m <= gap <= params.max_gap_m:
        return None
    base = mid + np.outer(tt, d)
    base = base - np.outer((base - c) @ n, n)
    ends = base + np.outer(0.5 * (xa + xb), across)
    return ends, n, rms, gap


def _common_plane(
    pa: FloatArray, pb: FloatArray, params: SeamParams, viewpoint: FloatArray
) -> tuple[FloatArray, FloatArray, float, FloatArray, FloatArray] | None:
    """(centre, unit normal towards ``viewpoint``, RMS, inliers of a, inliers of b) of the one plane both plates'
    points lie on, or None when they are not two plates in one plane."""
    if len(pa) < 30 or len(pb) < 30:
        return None
    # the plane tests need a few thousand points, not a mask's tens of thousands (evenly thinned)
    ca, na, rms_a, _ = fit_plane_robust(pa[:: max(1, len(pa) // 4000)], sigma_gate=params.plane_gate_sigma)
    cb, nb, rms_b, _ = fit_plane_robust(pb[:: max(1, len(pb) // 4000)], sigma_gate=params.plane_gate_sigma)
    if max(rms_a, rms_b) > params.butt_max_rms_m:
        return None  # not plates: curved or mixed surfaces
    if abs(na @ nb) < np.cos(params.max_coplanar_rad):
        return None
    tol = 0.002 + 3 * max(rms_a, rms_b)
    if abs((cb - ca) @ na) > tol or abs((ca - cb) @ nb) > tol:
        return None
    c, n, rms, keep = fit_plane_robust(np.vstack([pa, pb]), sigma_gate=params.plane_gate_sigma)
    if rms > 1.5 * max(rms_a, rms_b, 2e-4):
        return None
    return c, orient_towards(n, c, viewpoint), rms, pa[keep[: len(pa)]], pb[keep[len(pa) :]]


def _edges_on_scanline(
    line_pts: FloatArray,
    *,
    mid: FloatArray,
    d: FloatArray,
    across: FloatArray,
    c: FloatArray,
    n: FloatArray,
    sigma: float,
) -> tuple[float, float, float] | None:
    """(position along the joint, edge of plate a, edge of plate b) on one scanline (its (M, 3) points in pixel
    order), coordinates along ``d`` and ``across`` from ``mid``; None when this scanline shows no gap."""
    # points stay in pixel order: the last pixel on each plate is chosen by where it is in the
    # image, not by its (noisy) coordinate, so it carries noise but no selection bias
    rel = line_pts - mid
    x, h = rel @ across, (line_pts - c) @ n
    near = np.abs(x) < 0.006
    if near.sum() < 6:
        return None
    x, h, tt = x[near], h[near], rel[near] @ d
    top = np.flatnonzero(np.abs(h) < 2.5 * sigma)
    if len(top) < 6:
        return None
    xs = x[top]
    if xs[-1] < xs[0]:  # scanline runs from b to a: walk it from a to b
        top, xs = top[::-1], xs[::-1]
    steps = np.diff(xs)
    k = int(np.argmax(steps))
    spacing = float(np.median(np.abs(steps)))
    if steps[k] < 2.5 * max(spacing, 1e-5) or k < 1 or k + 2 >= len(xs):
        return None  # no gap on this scanline
    ia, ib = top[k], top[k + 1]
    xa_last, xb_first = float(x[ia]), float(x[ib])
    lo_i, hi_i = min(ia, ib), max(ia, ib)
    between = np.arange(lo_i + 1, hi_i)
    walls = between[h[between] < -3.0 * sigma]
    wall_b = x[walls][np.abs(x[walls] - xb_first) < 0.0005]
    wall_a = x[walls][np.abs(x[walls] - xa_last) < 0.0005]
    # signed steps: noise makes |step| too large on average, the signed median stays unbiased
    sp_a = float(np.median(np.diff(xs[: k + 1]))) if k >= 1 else spacing
    sp_b = float(np.median(np.diff(xs[k + 1 :]))) if k + 2 < len(xs) else spacing
    # the last pixel on a plate falls short of its edge by half the local spacing on average
    edge_a = float(np.median(wall_a)) if len(wall_a) >= 2 else xa_last + 0.5 * sp_a
    edge_b = float(np.median(wall_b)) if len(wall_b) >= 2 else xb_first - 0.5 * sp_b
    return float(np.mean(tt)), edge_a, edge_b


def _robust_line_fit(A: FloatArray, y: FloatArray) -> FloatArray:
    """(2,) coefficients of ``y ~ A @ coef``: least squares, then reject beyond 3 MAD-sigmas and refit, twice."""
    ok = np.ones(len(y), bool)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    for _ in range(2):
        resid = y - A @ coef
        mad_sigma = 1.4826 * float(np.median(np.abs(resid[ok] - np.median(resid[ok]))))
        ok = np.abs(resid) < 3 * max(mad_sigma, 1e-5)
        coef, *_ = np.linalg.lstsq(A[ok], y[ok], rcond=None)
    return np.asarray(coef, dtype=np.float64)
