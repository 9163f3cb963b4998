"""A cylinder fitted to points with their normals: the axis from the normals, the centre and radius from an
algebraic circle fit across it, then a robust least-squares fit of the radial distances."""

from __future__ import annotations

import numpy as np
from numba import njit

from perception.fine.types import FloatArray, Surface
from perception.fits import median, percentile

# a cylinder's fit settles within 20 evaluations from its start (dev zoo's pipes: 4 to 17); a nearly flat
# patch's radius runs off towards infinity for hundreds (one V-groove bevel: 325 evaluations, 0.3 s, to 23 m)
MAX_EVALUATIONS = 60
MAX_RADIUS_M = 1.0  # a wider cylinder is a plane to the fit (a pipe, a tank's shell: under a metre)


def fit_cylinder(p: FloatArray, normals: FloatArray, *,
                 turning_start: bool = True) -> tuple[FloatArray, FloatArray, float, float] | None:  # fmt: skip
    """Axis, a centre on it, radius and RMS of a cylinder through (N, 3) points with (N, 3) normals, or None.

    Start: the axis is perpendicular to every normal (the normals' scatter has no component along it) and
    the centre and radius come from an algebraic circle fit of the points projected across it (and, with
    ``turning_start``, from how fast the normals turn, :func:`_turning_start`, when that differs). Then a
    robust least-squares fit of the radial distances over axis, centre and radius (the window normals are
    blurred near the cylinder's outline and its fold with a plate, so the start's axis tilts a little).
    """
    finite = np.isfinite(normals)
    ok = finite[:, 0] & finite[:, 1] & finite[:, 2]  # np.all(axis=1) loops three values wide: slow
    if ok.sum() < 20:
        return None
    nm = normals[ok]
    w, _v = np.linalg.eigh(nm.T @ nm / len(nm))
    if w[1] < 0.02:  # normals hardly spread: a plane, not a cylinder
        return None
    # the axis: the direction most normals are perpendicular to (pairs of normals propose it; a cap's or a
    # plate's normals, parallel to the axis, would pull a plain eigenvector off it)
    rng = np.random.default_rng(0)
    i = rng.integers(0, len(nm), (200, 2))
    cand = np.cross(nm[i[:, 0]], nm[i[:, 1]])
    norm = np.linalg.norm(cand, axis=1)
    cand = cand[norm > 0.2] / norm[norm > 0.2, None]
    if len(cand) == 0:
        return None
    votes = (np.abs(nm[:: max(1, len(nm) // 2000)] @ cand.T) < 0.1).sum(axis=0)
    axis = cand[int(np.argmax(votes))]
    perp = np.abs(nm @ axis) < 0.15
    if perp.sum() >= 20:
        _w2, v2 = np.linalg.eigh(nm[perp].T @ nm[perp] / perp.sum())
        axis = v2[:, 0]
    start = circle_across(p[ok][perp] if perp.sum() >= 20 else p, axis)
    if start is None:
        return None
    rows = np.ascontiguousarray(p[:: max(1, len(p) // 4000)].T)
    fits = [_settle(rows, axis, *start)]
    # the algebraic circle of a short, noisy arc can be far off (a 19 mm pipe's front seen at 0.8 m under 1.2 mm
    # of noise: 48 mm), and the fit settles near it; a second start from how fast the normals turn, when it
    # differs, and the fit that leaves the points the smaller median distance
    turn = _turning_start(p[ok], nm, axis) if turning_start else None
    if turn is not None and abs(turn[1] - start[1]) > 0.2 * start[1]:
        fits.append(_settle(rows, axis, *turn))
    found = [f for f in fits if f is not None]
    if not found:
        return None
    if len(found) > 1:  # the fit that leaves the points the smaller median distance
        found.sort(key=lambda f: float(median(np.abs(_radial(rows, f[1], f[0])[2] - f[2]))))
    a, c, r = found[0]
    da, _, length = _radial(np.ascontiguousarray(p.T), c, a)
    res = length - r
    c = c + float(np.mean(da)) * a
    return a, c, r, float(np.sqrt(np.mean(res**2)))


def _turning_start(p: FloatArray, normals: FloatArray, axis: FloatArray) -> tuple[FloatArray, float] | None:
    """A cylinder's centre (on the plane across ``axis`` through the origin) and radius from how fast its unit
    ``normals`` turn across the axis: between two points a chord of length 2 R sin(t / 2) across the axis goes
    with normals 2 sin(t / 2) apart, so the radius is the median ratio of the two over pairs of points at least
    a tenth of their spread apart; the centre lies a radius behind each point along its normal (in front, for
    a cylinder seen from inside: whichever puts the centres closer together). None for fewer than 20 points."""
    if len(p) < 20:
        return None
    rng = np.random.default_rng(0)
    i = rng.integers(0, len(p), (2000, 2))
    dp, dn = p[i[:, 0]] - p[i[:, 1]], normals[i[:, 0]] - normals[i[:, 1]]
    dp -= np.outer(dp @ axis, axis)
    dn -= np.outer(dn @ axis, axis)
    chord, turned = np.linalg.norm(dp, axis=1), np.linalg.norm(dn, axis=1)
    apart = (chord >= 0.1 * float(np.max(chord))) & (turned > 1e-6)
    if apart.sum() < 20:
        return None
    r = float(median(chord[apart] / turned[apart]))
    e1, e2 = axis_basis(axis)
    best: tuple[float, FloatArray] | None = None
    for sign in (-1.0, 1.0):
        centres = p + sign * r * normals
        xy = np.column_stack([centres @ e1, centres @ e2])
        mid = np.array([median(xy[:, 0]), median(xy[:, 1])])
        spread = float(median(np.linalg.norm(xy - mid, axis=1)))
        if best is None or spread < best[0]:
            best = (spread, mid[0] * e1 + mid[1] * e2)
    assert best is not None
    return best[1], r


def _settle(rows: FloatArray, axis: FloatArray, centre: FloatArray,
            r: float) -> tuple[FloatArray, FloatArray, float] | None:  # fmt: skip
    """The robust least-squares cylinder (axis, centre, radius) of the points given as (3, N) ``rows``, from the
    start ``axis``, ``centre`` and ``r``; None when it does not settle or its radius is not positive."""
    e1, e2 = axis_basis(axis)
    scale = max(r, 1e-3)
    # every vector contiguous: one compiled type (a strided axis would compile another, seconds, mid-detection)
    rows, axis_c, e1_c, e2_c, centre_c = (np.ascontiguousarray(v, dtype=np.float64)
                                          for v in (rows, axis, e1, e2, centre))  # fmt: skip
    r0 = np.abs(_cylinder_residuals(rows, axis_c, e1_c, e2_c, centre_c, np.array([0.0, 0.0, 0.0, 0.0, r])))
    kept = r0 <= percentile(r0, 70)  # the start's worst 30% (other faces) sit out
    sig0 = float(median(r0[kept])) + 1e-6
    x, settled = _soft_l1_cylinder(np.ascontiguousarray(rows[:, kept]), axis_c, e1_c, e2_c, centre_c, float(r),
                                   max(sig0, 1e-4), np.array([0.05, 0.05, scale, scale, scale]), MAX_EVALUATIONS,
                                   MAX_RADIUS_M)  # fmt: skip
    if not settled:
        return None  # still moving after MAX_EVALUATIONS, or past MAX_RADIUS_M: a radius running off to a plane's
    a = axis + x[0] * e1 + x[1] * e2
    a /= np.linalg.norm(a)
    c = centre + x[2] * e1 + x[3] * e2
    if x[4] <= 0:
        return None
    return a, c, float(x[4])


@njit(cache=True)
def _soft_l1_cylinder(rows: FloatArray, axis: FloatArray, e1: FloatArray, e2: FloatArray, centre: FloatArray,
                      r: float, f_scale: float, x_scale: FloatArray, max_evaluations: int,
                      max_radius: float) -> tuple[FloatArray, bool]:  # fmt: skip
    """The cylinder ``x`` minimising sum(rho((r / f_scale)^2)) over the radial distances r of the (3, N)
    ``rows`` (its axis ``axis + x0 e1 + x1 e2``, made unit, its centre ``centre + x2 e1 + x3 e2``, its radius
    ``x4``) with the soft-L1 loss rho(z) = 2 (sqrt(1 + z) - 1) (``scipy.optimize.least_squares(...,
    loss="soft_l1")``'s cost), from x = (0, 0, 0, 0, r), and whether it settled within ``max_evaluations``.
    Levenberg-Marquardt on the reweighted problem: each step solves the normal equations of the residuals
    weighted by rho'(z) = 1 / sqrt(1 + z) (at a minimum of the weighted problem the robust cost's gradient is
    zero too), the variables in units of ``x_scale``; it stops when a step lowers the cost by less than 1e-6
    of it or moves x by less than 1e-6 of its size (scaled), as scipy's does, and gives up (unsettled) when
    the radius passes ``max_radius``. Compiled, the residuals and the normal equations in one pass over the
    points: as NumPy closures handed to scipy's solver a step cost 0.7 ms in Python around it, and as NumPy
    calls a fit of up to 60 evaluations was a fifth of the segmentation on close captures."""
    ftol = xtol = 1e-6
    f2 = f_scale * f_scale
    n = rows.shape[1]
    x = np.array([0.0, 0.0, 0.0, 0.0, r])
    res = _cylinder_residuals(rows, axis, e1, e2, centre, x)
    c = _soft_l1_cost(res, f2)
    evaluations, damping = 1, 1e-6
    a_m = np.zeros((5, 5))
    g = np.zeros(5)
    j = np.zeros(5)
    while evaluations < max_evaluations:
        # the Jacobian (scaled by x_scale) at x, weighted by rho'(z) = 1 / sqrt(1 + z), into the normal equations;
        # r = |d - (d.a) a| - R with d = q - c: dr/dc = -n along the unit radial n, dr/da = -(d.a) n, and a
        # moves by (I - a a^T) e / |b| per unit of its two parameters
        b0, b1, b2 = axis[0] + x[0] * e1[0] + x[1] * e2[0], axis[1] + x[0] * e1[1] + x[1] * e2[1], \
            axis[2] + x[0] * e1[2] + x[1] * e2[2]
        nb = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        a0, a1, a2 = b0 / nb, b1 / nb, b2 / nb
        c0, c1, c2 = centre[0] + x[2] * e1[0] + x[3] * e2[0], centre[1] + x[2] * e1[1] + x[3] * e2[1], \
            centre[2] + x[2] * e1[2] + x[3] * e2[2]
        a_m[:, :] = 0.0
        g[:] = 0.0
        for i in range(n):
            d0, d1, d2 = rows[0, i] - c0, rows[1, i] - c1, rows[2, i] - c2
            da = d0 * a0 + d1 * a1 + d2 * a2
            q0, q1, q2 = d0 - a0 * da, d1 - a1 * da, d2 - a2 * da
            length = max(np.sqrt(q0 * q0 + q1 * q1 + q2 * q2), 1e-12)
            n1 = (q0 * e1[0] + q1 * e1[1] + q2 * e1[2]) / length
            n2 = (q0 * e2[0] + q1 * e2[1] + q2 * e2[2]) / length
            j[0], j[1], j[2], j[3], j[4] = -da * n1 / nb, -da * n2 / nb, -n1, -n2, -1.0
            w = 1.0 / np.sqrt(1.0 + res[i] * res[i] / f2)
            for k in range(5):
                jk = j[k] * x_scale[k]
                g[k] += jk * w * res[i]
                for m in range(k, 5):
                    a_m[k, m] += jk * w * j[m] * x_scale[m]
        for k in range(5):
            for m in range(k):
                a_m[k, m] = a_m[m, k]
        while evaluations < max_evaluations:
            damped = a_m.copy()
            for k in range(5):
                damped[k, k] += damping * max(a_m[k, k], 1e-12)
            try:
                step = -np.linalg.solve(damped, g) * x_scale
            except Exception:  # a singular system
                return x, False
            x_new = x + step
            res_new = _cylinder_residuals(rows, axis, e1, e2, centre, x_new)
            evaluations += 1
            c_new = _soft_l1_cost(res_new, f2)
            if c_new < c:
                moved = np.sqrt(np.sum((step / x_scale) ** 2))
                settled = c - c_new < ftol * c or moved < xtol * (xtol + np.sqrt(np.sum((x / x_scale) ** 2)))
                x, res, c = x_new, res_new, c_new
                damping = max(damping / 10.0, 1e-12)
                if settled:
                    return x, True
                if x[4] > max_radius:
                    return x, False
                break
            damping *= 4.0
            if damping > 1e12:
                return x, True  # no step lowers the cost: at its minimum
    return x, False


@njit(cache=True)
def _cylinder_residuals(rows: FloatArray, axis: FloatArray, e1: FloatArray, e2: FloatArray, centre: FloatArray,
                        x: FloatArray) -> FloatArray:  # fmt: skip
    """The radial distances of the (3, N) ``rows`` from the cylinder ``x`` of :func:`_soft_l1_cylinder`."""
    b = axis + x[0] * e1 + x[1] * e2
    a = b / np.sqrt(np.sum(b * b))
    c = centre + x[2] * e1 + x[3] * e2
    out = np.empty(rows.shape[1])
    for i in range(rows.shape[1]):
        d0, d1, d2 = rows[0, i] - c[0], rows[1, i] - c[1], rows[2, i] - c[2]
        da = d0 * a[0] + d1 * a[1] + d2 * a[2]
        q0, q1, q2 = d0 - a[0] * da, d1 - a[1] * da, d2 - a[2] * da
        out[i] = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2) - x[4]
    return out


@njit(cache=True)
def _soft_l1_cost(res: FloatArray, f2: float) -> float:
    total = 0.0
    for v in res:
        total += np.sqrt(1.0 + v * v / f2) - 1.0
    return f2 * total


def _radial(rows: FloatArray, c: FloatArray, a: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """For points given as their (3, N) coordinate rows, with d = q - c: (N,) d.a, the (3, N) rows of the
    radial part d - (d.a) a, and its (N,) length. Each value is the one the (N, 3) arithmetic gives (d.a is
    taken on d laid out (N, 3), as BLAS took it), computed along contiguous rows (three times faster)."""
    d = rows - c[:, None]
    da = np.ascontiguousarray(d.T) @ a
    radial = d - a[:, None] * da
    return da, radial, np.sqrt(radial[0] * radial[0] + radial[1] * radial[1] + radial[2] * radial[2])


def axis_basis(axis: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two unit vectors (e1, e2) that make a right-handed frame with the unit ``axis`` (e1 x e2 = axis)."""
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def circle_across(p: FloatArray, axis: FloatArray) -> tuple[FloatArray, float] | None:
    """Centre (on the plane across ``axis`` through the origin) and radius of an algebraic circle fit."""
    e1, e2 = axis_basis(axis)
    x, y = p @ e1, p @ e2
    A = np.column_stack([x, y, np.ones_like(x)])
    sol, *_ = np.linalg.lstsq(A, x * x + y * y, rcond=None)
    cx, cy = sol[0] / 2, sol[1] / 2
    r2 = sol[2] + cx * cx + cy * cy
    if r2 <= 0:
        return None
    return cx * e1 + cy * e2, float(np.sqrt(r2))


def circle_fit_across(p: FloatArray, axis: FloatArray, *, iterations: int = 10) -> tuple[FloatArray, float] | None:
    """Centre (on the plane across ``axis`` through the origin) and radius of the circle nearest the points
    across the axis in the least-squares sense of their distances from it (Gauss-Newton from the algebraic
    fit of :func:`circle_across`). The algebraic fit minimises the squared radii's errors, which on the arc a
    camera sees, with the noise along its rays, biases the radius: a 30 mm pipe seen over 160 degrees with 1 mm
    of noise comes out 0.24 mm small, by this fit 0.06 mm."""
    start = circle_across(p, axis)
    if start is None:
        return None
    e1, e2 = axis_basis(axis)
    x, y = p @ e1, p @ e2
    c = np.array([float(start[0] @ e1), float(start[0] @ e2), start[1]])
    for _ in range(iterations):
        dx, dy = x - c[0], y - c[1]
        d = np.maximum(np.hypot(dx, dy), 1e-12)
        jac = np.column_stack([-dx / d, -dy / d, -np.ones_like(d)])
        step, *_ = np.linalg.lstsq(jac, c[2] - d, rcond=None)
        c = c + step
        if float(np.abs(step).max()) < 1e-9:
            break
    if not np.all(np.isfinite(c)) or c[2] <= 0.0:
        return None
    return c[0] * e1 + c[1] * e2, float(c[2])


def normals_follow(c: Surface, q: FloatArray, normals: FloatArray) -> bool:
    """Whether the measured normals of the points ``q`` of cylinder ``c`` turn with their position around its
    axis, as on a cylinder: their median angular offset from the radial direction is under an eighth of the
    points' angular span (a flat face with bent edges, fitted by a wide cylinder, has normals that stay put
    while the position turns: offsets near a quarter of the span). True when too few normals are known."""
    ok = np.isfinite(normals).all(axis=1)
    if ok.sum() < 10:
        return True
    e1, e2 = axis_basis(c.axis)
    span, pos = span_rad(c, q[ok])
    n = normals[ok]
    off = np.angle(np.exp(1j * (np.arctan2(n @ e2, n @ e1) - pos)))
    off = np.minimum(np.abs(off), np.pi - np.abs(off))  # normals point out of the surface or into it
    return float(median(off)) < span / 8.0


def turns(c: Surface, q: FloatArray, min_turn_rad: float) -> bool:
    """Whether the points of cylinder ``c`` span at least ``min_turn_rad`` around its axis."""
    return span_rad(c, q)[0] >= min_turn_rad


def span_rad(c: Surface, q: FloatArray) -> tuple[float, FloatArray]:
    """The angle the points of cylinder ``c`` span around its axis, and each point's angle."""
    e1, e2 = axis_basis(c.axis)
    rel = q - c.centre
    pos = np.arctan2(rel @ e2, rel @ e1)
    ang = np.sort(pos)
    gaps = np.diff(np.concatenate([ang, [ang[0] + 2 * np.pi]]))
    return float(2 * np.pi - gaps.max()), pos
