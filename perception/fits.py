"""Geometric fits the seam stage is built from: planes (plain and robust), lines, the intersection line of two
planes, coordinates along a line, and the order of points along a curve. Pure functions; metres, any frame."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from perception.cloud import kdtree

FloatArray = NDArray[np.float64]


def sum_rows(p: FloatArray, weights: FloatArray | None = None) -> FloatArray:
    """(3,) sum of the rows of (N, 3) points, each weighted by ``weights`` (N,) when given: the very sum (same
    order, same rounding) of ``p.sum(axis=0)`` or ``(weights[:, None] * p).sum(axis=0)``, several times
    faster. NumPy adds the rows of a row-major array one after another in a loop three values wide; einsum
    adds them in the same order without that loop's overhead. A column-major array is summed pairwise by
    NumPy, and is left to it."""
    if p.ndim != 2 or len(p) < 2 or p.strides[1] >= p.strides[0]:
        return np.asarray(p.sum(axis=0) if weights is None else (weights[:, None] * p).sum(axis=0))
    return np.einsum("ij->j", p) if weights is None else np.einsum("i,ij->j", weights, p)


def median(a: ArrayLike, *, overwrite_input: bool = False) -> np.float64:
    """``np.median(a, overwrite_input=...)`` of a 1-D float64 array, the very value, in about half its time on
    large arrays and without its general-axis overhead on small ones (~7 us a call; the fine stage takes
    thousands of medians). One partition at the middle place: the upper middle value is there and the lower
    one is the largest before it (the values np.median's two-place partition finds); their mean taken as
    NumPy takes it, (a + b) / 2. A NaN sorts last, past the middle place: NaN when the upper half's largest
    is NaN, as np.median. Anything else goes to ``np.median``."""
    a = np.asarray(a)
    n = a.size
    if a.ndim != 1 or n < 3 or a.dtype != np.float64:
        return np.median(a, overwrite_input=overwrite_input)
    h = n // 2
    if overwrite_input:
        a.partition(h)
        part = a
    else:
        part = np.partition(a, h)
    if np.isnan(part[h:].max()):
        return np.float64(np.nan)
    return part[h] if n % 2 else (part[:h].max() + part[h]) / 2


def percentile(a: ArrayLike, q: float) -> np.float64:
    """``np.percentile(a, q)`` of a 1-D float64 array at one percentile ``q`` (linear interpolation), the very
    value in a fifth of its time (~13 us a call on a few thousand values against ~65 us; the refinement
    takes a few thousand a capture). The two order statistics around the virtual index ``(n - 1) q / 100`` by
    one partition (with the last place: a NaN sorts there, and gives NaN as in NumPy), blended as NumPy's
    ``_lerp`` blends them (from the lower one below a weight of one half, from the upper one from there).
    Anything else goes to ``np.percentile``."""
    a = np.asarray(a)
    n = a.size
    if a.ndim != 1 or n < 2 or a.dtype != np.float64 or not 0.0 <= q <= 100.0:
        return np.float64(np.percentile(a, q))
    v = (n - 1) * (float(q) / 100.0)
    if v >= n - 1:  # the largest value (NumPy takes the last place for both neighbours)
        lo = hi = n - 1
        t = v + 1.0  # its weight as NumPy computes it (from the index -1); the two values are the same
    else:
        lo = math.floor(v)
        hi, t = lo + 1, v - lo
    part = np.partition(a, sorted({lo, hi, n - 1}))
    if np.isnan(part[n - 1]):
        return np.float64(np.nan)
    x0, x1 = float(part[lo]), float(part[hi])
    d = x1 - x0
    return np.float64(x1 - d * (1.0 - t) if t >= 0.5 else x0 + d * t)


def cross3(a: FloatArray, b: FloatArray) -> FloatArray:
    """``np.cross(a, b)`` of two 3-vectors, the very values (the same products and differences) without its
    general-shape overhead (~2 us against ~15 us; the fine stage takes thousands)."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def mean_rows(p: FloatArray) -> FloatArray:
    """(3,) mean of the rows of (N, 3) points, the very value of ``p.mean(axis=0)`` (see :func:`sum_rows`)."""
    return sum_rows(p) / len(p)


def fit_plane(p: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """Least-squares plane: (centroid, unit normal, RMS distance), from the 3x3 scatter matrix."""
    c = p.mean(axis=0)
    q = p - c
    evals, evecs = np.linalg.eigh(q.T @ q)
    return c, evecs[:, 0], float(np.sqrt(max(evals[0], 0.0) / max(len(p), 1)))


def fit_plane_robust(
    p: FloatArray, *, sigma_gate: float = 3.0, iters: int = 3
) -> tuple[FloatArray, FloatArray, float, NDArray[np.bool_]]:
    """Plane fit with iterative ``sigma_gate`` * RMS outlier rejection; returns the inlier mask too."""
    keep = np.ones(len(p), bool)
    c, n, rms = fit_plane(p)
    for _ in range(iters):
        d = np.abs((p - c) @ n)
        new = d <= max(sigma_gate * rms, 1e-5)
        if new.sum() < 3 or np.array_equal(new, keep):
            break
        keep = new
        c, n, rms = fit_plane(p[keep])
    return c, n, rms, keep


def fit_line(p: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Least-squares 3D line through points: (centroid, unit direction)."""
    c = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    return c, vt[0]


def orient_towards(n: FloatArray, p: FloatArray, viewpoint: FloatArray) -> FloatArray:
    return n if float(n @ (viewpoint - p)) >= 0 else -n


def plane_intersection(
    c1: FloatArray, n1: FloatArray, c2: FloatArray, n2: FloatArray, near: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Line of two planes: (the point on it closest to ``near``, unit direction)."""
    d = np.cross(n1, n2)
    d /= np.linalg.norm(d)
    # minimise |x - near|^2 subject to n1.x = n1.c1, n2.x = n2.c2
    A = np.array([[2.0, 0, 0, n1[0], n2[0]], [0, 2.0, 0, n1[1], n2[1]], [0, 0, 2.0, n1[2], n2[2]],
                  [n1[0], n1[1], n1[2], 0, 0], [n2[0], n2[1], n2[2], 0, 0]])  # fmt: skip
    b = np.concatenate([2 * near, [n1 @ c1, n2 @ c2]])
    x = np.linalg.solve(A, b)
    return x[:3], d


def connected_components(points: FloatArray, radius: float, *, tree: Any = None) -> NDArray[np.int64]:
    """(N,) component label of each (N, 3) point, points closer than ``radius`` joined. ``tree``: the points'
    KD-tree (:func:`perception.cloud.kdtree`) when the caller has it already."""
    pairs = (kdtree(points) if tree is None else tree).query_pairs(radius, output_type="ndarray")
    return _edge_components(len(points), pairs[:, 0], pairs[:, 1])


def neighbour_components(points: FloatArray, k: int, *, tree: Any = None) -> NDArray[np.int64]:
    """(N,) component label of each (N, 3) point, each point joined to its ``k`` nearest. The reach follows
    the sampling wherever it is: across a scan's lines as far apart as about k/2 in-line spacings (a LiDAR's
    lines on a face seen at a slant), while a cluster of more than ``k`` points keeps its own."""
    n = len(points)
    k = min(k, n - 1)
    if k < 1:
        return np.zeros(n, np.int64)
    _, idx = (kdtree(points) if tree is None else tree).query(points, k=k + 1, workers=2)
    return _edge_components(n, np.repeat(np.arange(n), k), idx[:, 1:].ravel())


def _edge_components(n: int, a: NDArray[np.intp], b: NDArray[np.intp]) -> NDArray[np.int64]:
    """(n,) component label of each of ``n`` nodes of the undirected graph with the edges ``a[i]``-``b[i]``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as graph_components

    g = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(n, n))
    _, lab = graph_components(g, directed=False)
    return lab.astype(np.int64)


def order_along_curve(points: FloatArray, radius: float) -> FloatArray:
    """(N,) parameter along a thin curve-like point set: geodesic distance from one end."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    tree = kdtree(points)
    pairs = tree.query_pairs(radius, output_type="ndarray")
    n = len(points)
    w = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
    g = coo_matrix((w, (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    d0 = dijkstra(g, directed=False, indices=0)
    d0[~np.isfinite(d0)] = -1
    end = int(np.argmax(d0))
    s = dijkstra(g, directed=False, indices=end)
    s[~np.isfinite(s)] = np.nan
    return np.asarray(s)


def line_coordinates(pts: FloatArray, center: FloatArray, direction: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(N,) position along a line through ``center`` with unit ``direction``, and (N,) distance from it."""
    rel = pts - center
    t = rel @ direction
    # Pythagoras instead of the perpendicular vectors: no (N, 3) temporaries (points lie within
    # centimetres of the line here, so the difference of squares loses nothing that matters)
    return t, np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - t * t, 0.0))


def trimmed_line(x: FloatArray, y: FloatArray) -> tuple[float, float]:
    """The line ``y = off + slope * x`` through 2-D samples, by least squares on the samples within three
    robust sigmas (the MAD of all the residuals) of the line before, three times, starting from the median: up
    to half of them may lie off it (mixed pixels at a face's ends and corners, another face's points) without
    turning it. With fewer than ten samples within, the median (slope 0): too few to turn a line on."""
    sol = np.array([float(median(np.asarray(y, dtype=np.float64))), 0.0])
    for _ in range(3):
        res = y - (sol[0] + sol[1] * x)
        keep = np.abs(res) <= 3.0 * (1.4826 * float(median(np.abs(res))) + 1e-6)
        if keep.sum() < 10:
            break
        sol, *_ = np.linalg.lstsq(np.column_stack([np.ones(int(keep.sum())), x[keep]]), y[keep], rcond=None)
    return float(sol[0]), float(sol[1])


def outer_boundary(along: FloatArray, out: FloatArray, bin_m: float, tol_m: float, *, min_bins: int = 5,
                   origin: float | None = None) -> tuple[float, float] | None:  # fmt: skip
    """The boundary of a face's points as the line ``out = off + slope * along``: the outermost point (largest
    ``out``) of each ``bin_m`` bin of ``along`` (bins counted from ``origin``, else from the smallest
    ``along``), fitted by :func:`trimmed_line`. None when fewer than ``min_bins`` bins hold points, or the
    outermost points scatter about the line by more than ``tol_m`` (robust sigma): a ragged boundary is not a
    face's cut edge. The edge itself lies beyond the last samples on the face, by about half a sample spacing,
    which the caller adds."""
    if len(along) == 0:
        return None
    k = np.floor((along - (along.min() if origin is None else origin)) / bin_m).astype(np.int64)
    order = np.lexsort((-out, k))
    first = np.r_[True, k[order][1:] != k[order][:-1]]
    tops = order[first]  # the outermost point of each bin
    if len(tops) < min_bins:
        return None
    off, slope = trimmed_line(along[tops], out[tops])
    res = out[tops] - (off + slope * along[tops])
    if 1.4826 * float(median(np.abs(res - median(res)))) > tol_m:
        return None
    return off, slope
