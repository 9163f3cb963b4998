"""The order of the seam passes: which seam after which, and in which direction, keeping air moves short.

The cost of a route is the summed straight-line distance from each pass's exit (retract pose) to the next
pass's entry (approach pose), and from the start position to the first entry when it is known; each seam may be
welded in either direction. Up to ``exact_max`` seams the route is optimal (dynamic programming over subsets);
above it, greedy nearest neighbour then a local search with 2-opt moves (segment reversal flips the direction of
every seam in the segment; a one-seam segment is a direction flip) and relocation moves (one seam moved
elsewhere, in either direction). Both are deterministic. Pure functions on (n, 2, 3) arrays of points, metres.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

Route = list[tuple[int, bool]]
"""(seam index, reversed) in welding order."""


def route_length(route: Route, entries: FloatArray, exits: FloatArray, p_start: FloatArray | None = None) -> float:
    """Summed air-move length of ``route``. ``entries``/``exits``: (n, 2, 3) approach and retract positions of each
    seam welded forward ([:, 0]) and reversed ([:, 1]); ``p_start``: (3,) or None for a free start."""
    total = 0.0
    prev = None if p_start is None else np.asarray(p_start, dtype=np.float64)
    for i, rev in route:
        if prev is not None:
            total += float(np.linalg.norm(prev - entries[i, int(rev)]))
        prev = exits[i, int(rev)]
    return total


def order_seams(
    entries: ArrayLike, exits: ArrayLike, *, p_start: ArrayLike | None = None, exact_max: int = 10
) -> Route:
    """The welding order and direction of each seam minimising :func:`route_length` (see the module docstring):
    exact up to ``exact_max`` seams, nearest neighbour + local search above. Deterministic (ties: lowest index)."""
    E = np.asarray(entries, dtype=np.float64).reshape(-1, 2, 3)
    Q = np.asarray(exits, dtype=np.float64).reshape(-1, 2, 3)
    if E.shape != Q.shape:
        raise ValueError(f"entries and exits must have the same shape, got {E.shape} and {Q.shape}")
    start = None if p_start is None else np.asarray(p_start, dtype=np.float64).reshape(3)
    n = len(E)
    if n == 0:
        return []
    if n <= exact_max:
        return _order_exact(E, Q, start)
    return improve_route(_order_nearest(E, Q, start), E, Q, start)


def _cost_tables(E: FloatArray, Q: FloatArray, start: FloatArray | None) -> tuple[FloatArray, FloatArray]:
    """States ``b = 2 * seam + reversed``: ``C[a, b]`` from the exit of a to the entry of b; ``S[b]`` from start."""
    m = 2 * len(E)
    ends, outs = E.reshape(m, 3), Q.reshape(m, 3)
    C = np.linalg.norm(outs[:, None, :] - ends[None, :, :], axis=2)
    S = np.zeros(m) if start is None else np.linalg.norm(ends - start, axis=1)
    return C, S


def _order_exact(E: FloatArray, Q: FloatArray, start: FloatArray | None) -> Route:
    """Held-Karp over (subset of seams, last state)."""
    n = len(E)
    m = 2 * n
    C, S = _cost_tables(E, Q, start)
    full = (1 << n) - 1
    D = np.full((1 << n, m), np.inf)
    parent = np.full((1 << n, m), -1, dtype=np.int64)
    for b in range(m):
        D[1 << (b // 2), b] = S[b]
    seam_of = np.arange(m) // 2
    for mask in range(1, full + 1):
        row = D[mask]
        if not np.isfinite(row).any():
            continue
        cand = row[:, None] + C  # (from, to)
        best_from = np.argmin(cand, axis=0)
        best = cand[best_from, np.arange(m)]
        for b in range(m):
            j = seam_of[b]
            if mask >> j & 1:
                continue
            nm = mask | (1 << j)
            if best[b] < D[nm, b]:
                D[nm, b] = best[b]
                parent[nm, b] = best_from[b]
    b = int(np.argmin(D[full]))
    route: Route = []
    mask = full
    while b >= 0:
        route.append((b // 2, bool(b % 2)))
        prev = int(parent[mask, b])
        mask &= ~(1 << (b // 2))
        b = prev
    route.reverse()
    return route


def _nearest_from(first: int, C: FloatArray, n: int) -> list[int]:
    states = [first]
    left = np.ones(n, dtype=bool)
    left[first // 2] = False
    for _ in range(n - 1):
        d = C[states[-1]].copy()
        d[np.repeat(~left, 2)] = np.inf
        b = int(np.argmin(d))
        states.append(b)
        left[b // 2] = False
    return states


def _states_cost(states: list[int] | NDArray[np.int64], C: FloatArray, S: FloatArray) -> float:
    s = np.asarray(states, dtype=np.int64)
    return float(S[s[0]] + C[s[:-1], s[1:]].sum())


def _order_nearest(E: FloatArray, Q: FloatArray, start: FloatArray | None) -> Route:
    """Greedy nearest neighbour: from ``start``, or (free start) the best of every possible first seam."""
    n = len(E)
    C, S = _cost_tables(E, Q, start)
    if start is not None:
        states = _nearest_from(int(np.argmin(S)), C, n)
    else:
        candidates = [_nearest_from(b, C, n) for b in range(2 * n)]
        states = min(candidates, key=lambda st: _states_cost(st, C, S))  # min keeps the first of equals
    return [(b // 2, bool(b % 2)) for b in states]


def improve_route(route: Route, entries: ArrayLike, exits: ArrayLike, p_start: ArrayLike | None = None) -> Route:
    """Local search from ``route`` until no move shortens it, taking the best move each round. Moves: 2-opt
    (reverse a segment, flipping every seam in it; a one-seam segment is a direction flip) and relocation (take
    one seam out and put it back anywhere, in either direction). Returns a local optimum for both."""
    E = np.asarray(entries, dtype=np.float64).reshape(-1, 2, 3)
    Q = np.asarray(exits, dtype=np.float64).reshape(-1, 2, 3)
    start = None if p_start is None else np.asarray(p_start, dtype=np.float64).reshape(3)
    C, S = _cost_tables(E, Q, start)
    best = [2 * i + int(rev) for i, rev in route]
    best_len = _states_cost(best, C, S)
    n = len(best)
    while True:
        improved: list[int] | None = None
        improved_len = best_len
        for cand in _neighbours(best, n):
            length = _states_cost(cand, C, S)
            if length < improved_len - 1e-12:
                improved, improved_len = cand, length
        if improved is None:
            return [(b // 2, bool(b % 2)) for b in best]
        best, best_len = improved, improved_len


def _neighbours(states: list[int], n: int) -> Iterator[list[int]]:
    for i in range(n):
        for j in range(i, n):
            yield states[:i] + [b ^ 1 for b in reversed(states[i : j + 1])] + states[j + 1 :]
    for i in range(n):
        rest = states[:i] + states[i + 1 :]
        for j in range(n):
            for b in (states[i], states[i] ^ 1):
                if j != i or b != states[i]:
                    yield [*rest[:j], b, *rest[j:]]
