"""Surfaces grown into the bands between them: the blurred band around a fold is shared out to the two
surfaces up to the corner, pixel ring by pixel ring, each pixel to the surface it lies on within the noise,
so that their supports meet where the seam is."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from perception.fine.types import FloatArray, Surface


def grow(p: FloatArray, labels: NDArray[np.int32], surfaces: list[Surface], sigma: FloatArray, *,
         within_sigma: float, rings: int) -> NDArray[np.int32]:  # fmt: skip
    """Ring by ring (at most ``rings``), the unassigned valid pixels of the (h, w, 3) work cloud ``p`` next to a
    surface of ``labels`` join it when they lie on it within ``within_sigma`` times the noise ``sigma`` (h, w)
    at their range (the nearer surface wins where two could take a pixel). A pixel's chance changes only when
    a neighbour joins a surface, so each ring looks only at the free pixels beside the last ring's."""
    if not surfaces:
        return labels
    lab = labels.copy()
    h, w = lab.shape
    valid = np.isfinite(p[..., 2])
    neighbours = ((0, -1), (0, 1), (-1, 0), (1, 0))  # the order ties are settled in
    known = lab >= 0
    beside = np.zeros_like(known)
    for dy, dx in neighbours:
        beside |= _shift(known, -dy, -dx, False)
    ys, xs = np.nonzero(beside & valid & ~known)  # the first ring: every free pixel beside a surface
    for _ in range(rings):
        if len(ys) == 0:
            break
        q = p[ys, xs]
        best = np.full(len(ys), np.inf)
        best_lab = np.full(len(ys), -1, np.int32)
        for dy, dx in neighbours:
            ny, nx = ys + dy, xs + dx
            ok = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
            cand = np.full(len(ys), -1, np.int32)
            cand[ok] = lab[ny[ok], nx[ok]]
            res = np.full(len(ys), np.inf)
            for s_lab in np.unique(cand[cand >= 0]):
                sel = cand == s_lab
                res[sel] = np.abs(surfaces[int(s_lab)].residual(q[sel]))
            better = res < best
            best[better] = res[better]
            best_lab[better] = cand[better]
        take = (best_lab >= 0) & (best <= within_sigma * sigma[ys, xs])
        if not take.any():
            break
        lab[ys[take], xs[take]] = best_lab[take]
        ys, xs = _free_beside(ys[take], xs[take], lab, valid, neighbours)  # the next ring
    return lab


def _free_beside(cy: NDArray[np.int64], cx: NDArray[np.int64], lab: NDArray[np.int32], valid: NDArray[np.bool_],
                 neighbours: tuple[tuple[int, int], ...]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:  # fmt: skip
    """The unlabelled valid pixels (rows, columns, in raster order) beside the pixels (cy, cx)."""
    h, w = lab.shape
    ys = np.concatenate([cy + dy for dy, _ in neighbours])
    xs = np.concatenate([cx + dx for _, dx in neighbours])
    inside = (ys >= 0) & (ys < h) & (xs >= 0) & (xs < w)
    flat = ys[inside] * w + xs[inside]
    if len(flat):  # np.unique's sorted distinct values, from marks over their range (no sort)
        lo = int(flat.min())
        mark = np.zeros(int(flat.max()) - lo + 1, bool)
        mark[flat - lo] = True
        flat = np.flatnonzero(mark) + lo
    ys, xs = flat // w, flat % w
    free = valid[ys, xs] & (lab[ys, xs] < 0)
    return ys[free], xs[free]


def _shift(a: NDArray, dy: int, dx: int, fill: int | float) -> NDArray:
    """``a`` moved by (dy, dx) pixels, ``fill`` where nothing moved in."""
    out = np.full_like(a, fill)
    h, w = a.shape[:2]
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
    out[yd, xd] = a[ys, xs]
    return out
