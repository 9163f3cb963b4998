"""Curved seams (a pipe on a plate): the seam traced cross-section by cross-section, each slab's corner found
where the two surfaces' 2-D lines meet, from the full-resolution points (:func:`refine_curve`). Camera frame,
metres."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from perception.fits import (
    orient_towards,
)
from perception.seamfit import FullRes, SeamParams

FloatArray = NDArray[np.float64]


def refine_curve(
    full: FullRes,
    ra: int | tuple[int, ...],
    rb: int | tuple[int, ...],
    curve: FloatArray,
    params: SeamParams,
    viewpoint: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, float] | None:
    """Cross-section refinement of a curved seam: in thin slabs across the seam, fit the trace of each
    surface as a 2D line and intersect them; then track the seam beyond both ends of the coarse curve
    (extrapolate 2 mm along the tangent, fit the slab there, keep it while both faces are found near
    the prediction). Returns dense points, normals a / b and the median fit RMS."""
    from perception.evaluate import resample_polyline

    samples = resample_polyline(curve, params.curve_step_m)
    tang = np.gradient(samples, axis=0)
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-12)
    fits: list[tuple[FloatArray, FloatArray, FloatArray, float]] = []
    for s, T in zip(samples, tang, strict=True):
        idx = np.asarray(full.tree.query_ball_point(s, params.refine_band_m), dtype=np.int64)
        if idx.size < 20:
            continue
        reg = full.regions[idx]
        in_a, in_b = np.isin(reg, np.atleast_1d(ra)), np.isin(reg, np.atleast_1d(rb))
        res = _slab_corner(full, idx, s, T, in_a, in_b, params, viewpoint)
        if res is not None:
            fits.append(res)
    fits = [f for f in fits if _seen_well(f, viewpoint, params)]
    if len(fits) < 4:
        return None
    fits = _track_curve(full, fits, params, viewpoint, forward=True)
    fits = _track_curve(full, fits, params, viewpoint, forward=False)
    pts = np.array([f[0] for f in fits])
    # light smoothing along the seam (3-point moving average, ends kept)
    sm = pts.copy()
    sm[1:-1] = (pts[:-2] + pts[1:-1] + pts[2:]) / 3.0
    # trim the ends
    seg = np.linalg.norm(np.diff(sm, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    keep = (cum >= params.end_trim_m) & (cum <= cum[-1] - params.end_trim_m)
    if keep.sum() < 2 or cum[-1] < params.min_length_m:
        return None
    na = np.array([f[1] for f in fits])
    nb = np.array([f[2] for f in fits])
    return sm[keep], na[keep], nb[keep], float(np.median([f[3] for f in fits]))


def _slab_corner(
    full: FullRes,
    idx: NDArray[np.int64],
    s: FloatArray,
    T: FloatArray,
    in_a: NDArray[np.bool_],
    in_b: NDArray[np.bool_],
    params: SeamParams,
    viewpoint: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, float] | None:
    rel = full.points[idx] - s
    slab = np.abs(rel @ T) < params.slab_half_width_m
    res = _corner_2d(rel[slab], in_a[slab], in_b[slab], T, params, viewpoint - s)
    if res is None:
        return None
    corner, n_a, n_b, rms = res
    return s + corner, n_a, n_b, rms


def _seen_well(
    fit: tuple[FloatArray, FloatArray, FloatArray, float], viewpoint: FloatArray, params: SeamParams
) -> bool:
    """Both faces seen at less than ``max_incidence_rad``: beyond that, depth data are unreliable (and
    the simulator's ground truth stops there too)."""
    p, n_a, n_b, _ = fit
    v = viewpoint - p
    v /= max(float(np.linalg.norm(v)), 1e-12)
    c = np.cos(params.max_incidence_rad)
    return bool(abs(n_a @ v) >= c and abs(n_b @ v) >= c)


def _track_curve(
    full: FullRes,
    fits: list[tuple[FloatArray, FloatArray, FloatArray, float]],
    params: SeamParams,
    viewpoint: FloatArray,
    *,
    forward: bool,
    max_steps: int = 60,
) -> list[tuple[FloatArray, FloatArray, FloatArray, float]]:
    """Extend a curved seam past one end while the slab fit keeps finding both faces where expected."""
    seq = list(fits) if forward else list(reversed(fits))
    step = params.curve_step_m
    for _ in range(max_steps):
        p2, p1, p0 = seq[-3][0], seq[-2][0], seq[-1][0]
        # second-order prediction keeps the curvature
        nxt = p0 + (p0 - p1) + ((p0 - p1) - (p1 - p2))
        T = nxt - p0
        norm = np.linalg.norm(T)
        if norm < 1e-9:
            break
        T /= norm
        nxt = p0 + T * step
        idx = np.asarray(full.tree.query_ball_point(nxt, params.refine_band_m), dtype=np.int64)
        if idx.size < 20:
            break
        _, n_a, n_b, rms = seq[-1]
        q = full.points[idx]
        da = np.abs((q - p0) @ n_a)
        db = np.abs((q - p0) @ n_b)
        gate = params.plane_gate_sigma * max(rms, 3e-4) + 0.001
        in_a = (da < gate) & (da < db)
        in_b = (db < gate) & (db <= da)
        res = _slab_corner(full, idx, nxt, T, in_a, in_b, params, viewpoint)
        if res is None or np.linalg.norm(res[0] - nxt) > 0.0015:
            break
        if not _seen_well(res, viewpoint, params):
            break
        # both faces must still be seen in earnest on this slab, not a few stray points
        if min(int(in_a.sum()), int(in_b.sum())) < 15:
            break
        seq.append(res)
    return seq if forward else list(reversed(seq))


def _corner_2d(
    rel: FloatArray,
    in_a: NDArray[np.bool_],
    in_b: NDArray[np.bool_],
    T: FloatArray,
    params: SeamParams,
    to_view: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, float] | None:
    """Intersect the 2D traces of two surfaces in a slab (coordinates relative to the slab centre)."""
    if len(rel) < 12:
        return None
    # 2D basis of the cross-section plane
    e1 = np.cross(T, [0.0, 0.0, 1.0])
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross(T, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(T, e1)
    xy = np.column_stack([rel @ e1, rel @ e2])
    corner = np.zeros(2)
    exclude = 0.5 * params.refine_band_m / 3
    la = lb = None
    for _ in range(3):
        dist = np.linalg.norm(xy - corner, axis=1)
        sa = in_a & (dist > exclude)
        sb = in_b & (dist > exclude)
        if sa.sum() < 6 or sb.sum() < 6:
            return None
        la = _fit_line_2d(xy[sa], params.plane_gate_sigma)
        lb = _fit_line_2d(xy[sb], params.plane_gate_sigma)
        (ca, da, ra_), (cb, db, rb_) = la, lb
        cross = da[0] * db[1] - da[1] * db[0]
        if abs(cross) < np.sin(np.radians(10)):
            return None
        # ca + s da = cb + u db
        s = ((cb - ca)[0] * db[1] - (cb - ca)[1] * db[0]) / cross
        corner = ca + s * da
        # membership by distance to the two lines
        na2 = np.array([-da[1], da[0]])
        nb2 = np.array([-db[1], db[0]])
        dA = np.abs((xy - ca) @ na2)
        dB = np.abs((xy - cb) @ nb2)
        gA = params.plane_gate_sigma * max(ra_, 2e-4)
        gB = params.plane_gate_sigma * max(rb_, 2e-4)
        in_a = (dA < gA) & (dA < dB)
        in_b = (dB < gB) & (dB <= dA)
        exclude = params.refine_exclude_m
    assert la is not None and lb is not None
    (ca, da, ra_), (cb, db, rb_) = la, lb
    n_a3 = np.array([-da[1], da[0]]) @ np.vstack([e1, e2])
    n_b3 = np.array([-db[1], db[0]]) @ np.vstack([e1, e2])
    p3 = corner @ np.vstack([e1, e2])
    n_a3 = orient_towards(n_a3, p3, to_view)
    n_b3 = orient_towards(n_b3, p3, to_view)
    return p3, n_a3, n_b3, max(ra_, rb_)


def _fit_line_2d(p: FloatArray, gate: float) -> tuple[FloatArray, FloatArray, float]:
    keep = np.ones(len(p), bool)
    for _ in range(3):
        c = p[keep].mean(axis=0)
        _, s, vt = np.linalg.svd(p[keep] - c, full_matrices=False)
        d = vt[0]
        n = np.array([-d[1], d[0]])
        rms = float(s[1] / np.sqrt(keep.sum()))
        new = np.abs((p - c) @ n) <= max(gate * rms, 1e-5)
        if new.sum() < 4 or np.array_equal(new, keep):
            break
        keep = new
    return c, d, rms
