"""cell.route: the welding order is optimal up to exact_max seams (checked by brute force), a local optimum above."""

from __future__ import annotations

import numpy as np
import pytest

from cell.route import improve_route, order_seams, route_length
from tests.cell.planning_helpers import brute_force


# ------------------------------------------------------------------------------------------------ ordering
@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6])
@pytest.mark.parametrize("with_start", [False, True])
def test_order_is_optimal_on_small_random_cases(n: int, with_start: bool) -> None:
    rng = np.random.default_rng(100 * n + with_start)
    for _ in range(3):
        entries = rng.uniform(-1, 1, size=(n, 2, 3))
        exits = rng.uniform(-1, 1, size=(n, 2, 3))
        start = rng.uniform(-1, 1, size=3) if with_start else None
        route = order_seams(entries, exits, p_start=start)
        assert sorted(i for i, _ in route) == list(range(n))
        assert route_length(route, entries, exits, start) == pytest.approx(
            brute_force(entries, exits, start), abs=1e-12
        )


def test_heuristic_for_many_seams_is_a_local_optimum() -> None:
    rng = np.random.default_rng(7)
    n = 14
    entries = rng.uniform(-1, 1, size=(n, 2, 3))
    exits = entries + rng.uniform(-0.2, 0.2, size=(n, 2, 3))
    start = np.zeros(3)
    route = order_seams(entries, exits, p_start=start, exact_max=10)
    length = route_length(route, entries, exits, start)
    assert sorted(i for i, _ in route) == list(range(n))
    # no segment reversal (incl. single flips) and no relocation of one seam improves it
    for i in range(n):
        for j in range(i, n):
            cand = route[:i] + [(k, not r) for k, r in reversed(route[i : j + 1])] + route[j + 1 :]
            assert route_length(cand, entries, exits, start) >= length - 1e-12
        rest = route[:i] + route[i + 1 :]
        for j in range(n):
            for rev in (False, True):
                cand = [*rest[:j], (route[i][0], rev), *rest[j:]]
                assert route_length(cand, entries, exits, start) >= length - 1e-12
    assert improve_route(route, entries, exits, start) == route
    # from a poor start (the identity order) the local search only shortens the route
    identity = [(i, False) for i in range(n)]
    improved = improve_route(identity, entries, exits, start)
    assert route_length(improved, entries, exits, start) < route_length(identity, entries, exits, start)
    # the exact solver (forced) can only be better or equal
    exact = order_seams(entries[:9], exits[:9], p_start=start, exact_max=10)
    heuristic = order_seams(entries[:9], exits[:9], p_start=start, exact_max=0)
    assert (
        route_length(exact, entries[:9], exits[:9], start)
        <= route_length(heuristic, entries[:9], exits[:9], start) + 1e-12
    )


def test_heuristic_welds_collinear_seams_in_a_row() -> None:
    n = 12
    order = np.random.default_rng(3).permutation(n)
    entries = np.zeros((n, 2, 3))
    exits = np.zeros((n, 2, 3))
    for slot, k in enumerate(order):
        a, b = np.array([0.1 * k, 0, 0]), np.array([0.1 * k + 0.05, 0, 0])
        entries[slot] = [a, b]
        exits[slot] = [b, a]
    route = order_seams(entries, exits, p_start=np.array([-0.1, 0, 0]), exact_max=5)
    assert route_length(route, entries, exits, np.array([-0.1, 0, 0])) == pytest.approx(0.1 + 0.05 * (n - 1))
    assert [int(order[i]) for i, _ in route] == list(range(n))
    assert not any(r for _, r in route)
