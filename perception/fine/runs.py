"""Runs of covered bins along a seam: the one helper the steps share for "where is there support"."""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray


def covered_runs(covered: NDArray[np.bool_], max_hole: int, *, closed: bool = False) -> list[tuple[int, int]]:
    """[start, stop) runs of ``covered`` bins, holes of up to ``max_hole`` bins closed. With ``closed`` (a
    ring) a run may wrap around the end: its stop is then beyond ``len(covered)``."""
    c = np.asarray(covered, bool).copy()
    idx = np.flatnonzero(c)
    if idx.size == 0:
        return []
    for i, j in itertools.pairwise(idx.tolist()):
        if 1 < j - i <= max_hole + 1:
            c[i:j] = True
    if closed and c.all():
        return [(0, len(c))]
    edges = np.flatnonzero(np.diff(np.concatenate([[0], c.astype(np.int8), [0]])))
    runs = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    if closed and len(runs) > 1 and runs[0][0] == 0 and runs[-1][1] == len(c):
        first, last = runs.pop(0), runs.pop()
        runs.append((last[0], first[1] + len(c)))
    return runs
