"""A plane fitted with Tukey's biweight: each point's weight falls smoothly to zero at TUKEY_C robust sigmas
(the residuals' MAD), so that the few points of another surface that pass a refinement's gates (the last pixel
row of a convex edge beside a face seen a few pixels wide) do not tilt the plane, while the face's own noise
keeps 95% of the least-squares efficiency.

Compiled (:mod:`numba`): the refinement fits each face three times a seam, each fit up to eight weighted
least-squares passes over up to 32 000 points; as NumPy calls (residuals, median, weights, centroid, scatter)
they took a fifth of the refinement."""

from __future__ import annotations

import numpy as np
from numba import njit

from perception.fine.types import FloatArray

TUKEY_C = 4.685  # Tukey's biweight constant: 95% efficiency on normal noise
SETTLED_M = 1e-6  # the biweight stops when the plane moves less than a micrometre at the farthest point


def biweight_plane(p: FloatArray, weights: FloatArray, *, iterations: int = 8,
                   settled_m: float = SETTLED_M) -> tuple[FloatArray, float]:  # fmt: skip
    """The plane (unit normal towards the camera at the origin, offset: ``normal . x + offset = 0``) of the
    (N, 3) points ``p``, each weighted by ``weights`` (N,), fitted with Tukey's biweight from the weighted
    least-squares plane: at most ``iterations`` reweightings, stopping early when the plane moves less than
    ``settled_m`` at the farthest point (the next weights would move it less still), when the residuals'
    MAD is zero, or when fewer than ten points keep a weight (the last plane stands)."""
    n, off = _biweight(np.ascontiguousarray(p, dtype=np.float64), np.ascontiguousarray(weights, dtype=np.float64),
                       int(iterations), TUKEY_C, float(settled_m))  # fmt: skip
    return n, float(off)


@njit(cache=True)
def _weighted_plane(p: FloatArray, w: FloatArray) -> tuple[FloatArray, float]:
    """The weighted least-squares plane of ``p``: the smallest eigenvector of the weighted scatter about the
    weighted centroid, turned towards the origin."""
    total = 0.0
    c = np.zeros(3)
    for i in range(len(p)):
        total += w[i]
        for k in range(3):
            c[k] += w[i] * p[i, k]
    c /= total
    m = np.zeros((3, 3))
    for i in range(len(p)):
        d0, d1, d2 = p[i, 0] - c[0], p[i, 1] - c[1], p[i, 2] - c[2]
        wi = w[i]
        m[0, 0] += wi * d0 * d0
        m[0, 1] += wi * d0 * d1
        m[0, 2] += wi * d0 * d2
        m[1, 1] += wi * d1 * d1
        m[1, 2] += wi * d1 * d2
        m[2, 2] += wi * d2 * d2
    m[1, 0], m[2, 0], m[2, 1] = m[0, 1], m[0, 2], m[1, 2]
    _, vectors = np.linalg.eigh(m)
    n = vectors[:, 0].copy()
    if n[0] * c[0] + n[1] * c[1] + n[2] * c[2] > 0.0:  # towards the camera
        n = -n
    return n, -(n[0] * c[0] + n[1] * c[1] + n[2] * c[2])


@njit(cache=True)
def _biweight(p: FloatArray, weights: FloatArray, iterations: int, tukey_c: float,
              settled_m: float) -> tuple[FloatArray, float]:  # fmt: skip
    """:func:`biweight_plane`'s iterations."""
    n, off = _weighted_plane(p, weights)
    reach = 0.0  # the farthest point's range
    for i in range(len(p)):
        reach = max(reach, p[i, 0] * p[i, 0] + p[i, 1] * p[i, 1] + p[i, 2] * p[i, 2])
    reach = np.sqrt(reach)
    r, a, w = np.empty(len(p)), np.empty(len(p)), np.empty(len(p))
    for _ in range(iterations):
        for i in range(len(p)):
            r[i] = p[i, 0] * n[0] + p[i, 1] * n[1] + p[i, 2] * n[2] + off
            a[i] = abs(r[i])
        scale = 1.4826 * np.median(a)
        if scale <= 0.0:
            break
        cut = tukey_c * scale
        total, kept = 0.0, 0
        for i in range(len(p)):
            x = r[i] / cut  # the residual in units of the biweight's cut-off
            y = 1.0 - x * x
            w[i] = weights[i] * (y * y) if abs(x) < 1.0 else 0.0
            total += w[i]
            kept += w[i] != 0.0
        if total <= 0.0 or kept < 10:
            break
        n_new, off_new = _weighted_plane(p, w)
        moved = abs(off_new - off) + np.sqrt(np.sum((n_new - n) ** 2)) * reach
        n, off = n_new, off_new
        if moved < settled_m:
            break
    return n, off
