"""The RANSAC line trials' count: which of many trial lines on a plane (the points p with ``across . p =
offset``) holds the most points within a tolerance, and those points. The butt gaps' hole lines and the
steps' edge lines are found with it.

Compiled (:mod:`numba`): a trial's distance to each point is the value NumPy's
``np.einsum("tk,nk->tn", across, points) - offset`` gives (the products of x, then z, then y added in that
order: the detector's results were measured with it), the very value, without the (trials, points) matrix
(a plate's many hole points ran it to tens of MB, whose page faults cost more than the arithmetic)."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from perception.fine.types import FloatArray


def best_line(across: FloatArray, offset: FloatArray, rows: FloatArray, tol_m: float) -> NDArray[np.bool_]:
    """Per point given as the (3, N) ``rows``: whether it lies within ``tol_m`` of the trial line (unit
    ``across`` (T, 3) and ``offset`` (T,)) that holds the most of them (the first of equals,
    :func:`best_trial`)."""
    across, offset, rows = _contiguous(across, offset, rows)
    best = int(np.argmax(_counts(across, offset, rows, float(tol_m)))) if len(across) > 1 else 0
    return _within(across[best], float(offset[best]), rows, float(tol_m))


def best_trial(across: FloatArray, offset: FloatArray, rows: FloatArray, tol_m: float) -> int:
    """The index of the trial line of :func:`best_line` that holds the most of the points ``rows`` (the first
    of equals)."""
    return int(np.argmax(_counts(*_contiguous(across, offset, rows), float(tol_m))))


def _contiguous(across: FloatArray, offset: FloatArray, rows: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The arrays as the kernels are compiled for: contiguous float64 (one type)."""
    return (np.ascontiguousarray(across, dtype=np.float64), np.ascontiguousarray(offset, dtype=np.float64),
            np.ascontiguousarray(rows, dtype=np.float64))  # fmt: skip


@njit(cache=True)
def _distance(a0: float, a1: float, a2: float, o: float, x: float, y: float, z: float) -> float:
    """``across . p - offset`` in einsum's order (x, then z, then y)."""
    d = a0 * x + a2 * z
    d += a1 * y
    return d - o


@njit(cache=True)
def _counts(across: FloatArray, offset: FloatArray, rows: FloatArray, tol: float) -> NDArray[np.int64]:
    """Per trial line: how many of the points ``rows`` lie within ``tol`` of it."""
    n = rows.shape[1]
    out = np.zeros(len(across), np.int64)
    for t in range(len(across)):
        a0, a1, a2, o = across[t, 0], across[t, 1], across[t, 2], offset[t]
        c = 0
        for j in range(n):
            if abs(_distance(a0, a1, a2, o, rows[0, j], rows[1, j], rows[2, j])) <= tol:
                c += 1
        out[t] = c
    return out


@njit(cache=True)
def _within(across: FloatArray, offset: float, rows: FloatArray, tol: float) -> NDArray[np.bool_]:
    """Per point of ``rows``: whether it lies within ``tol`` of the line (``across``, ``offset``)."""
    n = rows.shape[1]
    out = np.empty(n, np.bool_)
    for j in range(n):
        out[j] = abs(_distance(across[0], across[1], across[2], offset, rows[0, j], rows[1, j], rows[2, j])) <= tol
    return out
