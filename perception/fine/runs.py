"""Runs of covered bins along a seam: the one helper the steps share for "where is there support"."""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray


def covered_runs(covered: NDArray[np.bool_], max_hole: int, *, closed: bool = False,
                 blocked: NDArray[np.bool_] | None = None) -> list[tuple[int, int]]:  # fmt: skip
    """[start, stop) runs of ``covered`` bins, holes of up to ``max_hole`` bins closed, unless they hold a
    ``blocked`` bin (something stands there: a hole in the data is bridged, an obstacle is not). With
    ``closed`` (a ring) a run may wrap around the end: its stop is then beyond ``len(covered)``."""
    c = np.asarray(covered, bool).copy()
    if blocked is not None:
        c &= ~np.asarray(blocked, bool)
    idx = np.flatnonzero(c)
    if idx.size == 0:
        return []
    for i, j in itertools.pairwise(idx.tolist()):
        if 1 < j - i <= max_hole + 1 and (blocked is None or not blocked[i:j].any()):
            c[i:j] = True
    if closed and c.all():
        return [(0, len(c))]
    edges = np.flatnonzero(np.diff(np.concatenate([[0], c.astype(np.int8), [0]])))
    runs = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    if closed and len(runs) > 1 and runs[0][0] == 0 and runs[-1][1] == len(c):
        first, last = runs.pop(0), runs.pop()
        runs.append((last[0], first[1] + len(c)))
    return runs


def trim_stray_tails(t: NDArray[np.float64], *, max_tail: int = 20) -> NDArray[np.float64]:
    """Positions ``t`` (sorted) along a line without the few at either end that lie past a gap holding more
    than they do: a gap that would have held, at the points' mean spacing, two more points than the tail
    beyond it holds (flying pixels at a part's end, a stray point past a face's end) is the end of what is
    there. At most ``max_tail`` points go at each end."""
    t = np.asarray(t, dtype=np.float64)
    if t.size < 4:
        return t
    spacing = float(t[-1] - t[0]) / (t.size - 1)  # the mean gap (a random gap is often several median ones)
    if spacing <= 0.0:
        return t
    lo, hi = 0, t.size
    for j in range(min(max_tail, t.size // 4), 0, -1):  # the longest tail that is stray
        if j < (t[hi - j] - t[hi - j - 1]) / spacing - 2.0:
            hi -= j
            break
    for j in range(min(max_tail, (hi - lo) // 4), 0, -1):
        if j < (t[lo + j] - t[lo + j - 1]) / spacing - 2.0:
            lo += j
            break
    return t[lo:hi]
