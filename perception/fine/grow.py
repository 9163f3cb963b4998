"""Surfaces grown into the bands between them: the blurred band around a fold is shared out to the two
surfaces up to the corner, pixel ring by pixel ring, each pixel to the surface it lies on within the noise,
so that their supports meet where the seam is.

The rings run compiled (:mod:`numba`): a capture's three growths took 23 ms of NumPy calls a ring and a label
at a time (dev zoo, median capture 0.42 s), a few pixels each."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from perception.fine.types import FloatArray, Surface

PLANE, CYLINDER = 0, 1  # a surface's kind in the compiled rings


def grow(p: FloatArray, labels: NDArray[np.int32], surfaces: list[Surface], sigma: FloatArray, *,
         within_sigma: float, rings: int) -> NDArray[np.int32]:  # fmt: skip
    """Ring by ring (at most ``rings``), the unassigned valid pixels of the (h, w, 3) work cloud ``p`` next to a
    surface of ``labels`` join it when they lie on it within ``within_sigma`` times the noise ``sigma`` (h, w)
    at their range (the nearer surface wins where two could take a pixel; of two as near, the one met first
    left, right, above, below). A pixel's chance changes only when a neighbour joins a surface, so each ring
    looks only at the free pixels beside the last ring's."""
    if not surfaces:
        return labels
    lab = labels.copy()
    kind = np.array([CYLINDER if s.kind == "cylinder" else PLANE for s in surfaces], dtype=np.int64)
    normal = np.array([s.normal for s in surfaces], dtype=np.float64).reshape(-1, 3)
    offset = np.array([s.offset for s in surfaces], dtype=np.float64)
    axis = np.array([s.axis for s in surfaces], dtype=np.float64).reshape(-1, 3)
    centre = np.array([s.centre for s in surfaces], dtype=np.float64).reshape(-1, 3)
    radius = np.array([s.radius for s in surfaces], dtype=np.float64)
    _rings(np.ascontiguousarray(p, dtype=np.float64), lab, np.ascontiguousarray(sigma, dtype=np.float64),
           float(within_sigma), (kind, normal, offset, axis, centre, radius), int(rings))  # fmt: skip
    return lab


@njit(cache=True)
def _residual(k: int, q0: float, q1: float, q2: float, model: tuple) -> float:
    """|distance| of point (q0, q1, q2) from surface ``k`` of the ``model`` arrays (:meth:`Surface.residual`)."""
    kind, normal, offset, axis, centre, radius = model
    if kind[k] == PLANE:
        return abs(q0 * normal[k, 0] + q1 * normal[k, 1] + q2 * normal[k, 2] + offset[k])
    d0, d1, d2 = q0 - centre[k, 0], q1 - centre[k, 1], q2 - centre[k, 2]
    t = d0 * axis[k, 0] + d1 * axis[k, 1] + d2 * axis[k, 2]
    r0, r1, r2 = d0 - t * axis[k, 0], d1 - t * axis[k, 1], d2 - t * axis[k, 2]
    return abs(np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) - radius[k])


@njit(cache=True)
def _rings(p: FloatArray, lab: NDArray[np.int32], sigma: FloatArray, within: float, model: tuple,
           rings: int) -> None:  # fmt: skip
    """:func:`grow`'s rings on ``lab`` in place."""
    h, w = lab.shape
    dys = (0, 0, -1, 1)
    dxs = (-1, 1, 0, 0)
    # the first ring: every free valid pixel beside a surface, in raster order
    first = np.empty(h * w, np.int64)
    n = 0
    for y in range(h):
        for x in range(w):
            if lab[y, x] >= 0 or not np.isfinite(p[y, x, 2]):
                continue
            for d in range(4):
                ny, nx = y + dys[d], x + dxs[d]
                if 0 <= ny < h and 0 <= nx < w and lab[ny, nx] >= 0:
                    first[n] = y * w + x
                    n += 1
                    break
    flat = first[:n].copy()
    mark = np.zeros(h * w, np.bool_)
    for _ in range(rings):
        n = len(flat)
        if n == 0:
            return
        joins = np.full(n, -1, np.int32)
        taken = 0
        for i in range(n):
            y, x = flat[i] // w, flat[i] % w
            best, best_lab = np.inf, -1
            for d in range(4):
                ny, nx = y + dys[d], x + dxs[d]
                if ny < 0 or ny >= h or nx < 0 or nx >= w or lab[ny, nx] < 0:
                    continue
                r = _residual(lab[ny, nx], p[y, x, 0], p[y, x, 1], p[y, x, 2], model)
                if r < best:
                    best, best_lab = r, lab[ny, nx]
            if best_lab >= 0 and best <= within * sigma[y, x]:
                joins[i] = best_lab
                taken += 1
        if taken == 0:
            return
        lo, hi = h * w, -1
        for i in range(n):
            if joins[i] < 0:
                continue
            y, x = flat[i] // w, flat[i] % w
            lab[y, x] = joins[i]
            for d in range(4):
                ny, nx = y + dys[d], x + dxs[d]
                if 0 <= ny < h and 0 <= nx < w and lab[ny, nx] < 0 and np.isfinite(p[ny, nx, 2]):
                    mark[ny * w + nx] = True
                    lo, hi = min(lo, ny * w + nx), max(hi, ny * w + nx)
        # the next ring, in raster order: the free valid pixels beside this one's (marked, then read off in order)
        n = 0
        for f in range(lo, hi + 1):
            if mark[f]:
                mark[f] = False
                if lab[f // w, f % w] < 0:  # not joined by this ring after it was marked
                    first[n] = f
                    n += 1
        flat = first[:n].copy()
