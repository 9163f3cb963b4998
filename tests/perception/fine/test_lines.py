"""perception.fine.lines: the RANSAC line trials' count, compiled, against NumPy's einsum on the same points."""

from __future__ import annotations

import numpy as np

from perception.fine.lines import best_line, best_trial


def _reference(across: np.ndarray, offset: np.ndarray, pts: np.ndarray, tol: float) -> np.ndarray:
    """Per trial and point: within ``tol`` of the line, by einsum's distances (what the count was measured with)."""
    return np.abs(np.einsum("tk,nk->tn", across, pts) - offset[:, None]) <= tol


def test_the_counts_and_the_best_lines_points_are_einsums_bit_for_bit() -> None:
    """Random trial lines through points of a plate with a line of holes (1 to 5 000 points, 1 to 300 trials,
    points placed on the tolerance's edge): the best trial and its points are the ones einsum's distances
    give, the first of equal counts."""
    rng = np.random.default_rng(11)
    for n, t in ((1, 1), (7, 3), (40, 1), (5000, 290), (3000, 300)):
        pts = rng.normal(size=(n, 3)) * 0.1 + [0.05, 0.02, 0.6]
        pts[: n // 3, 1] = 0.02 + rng.normal(0.0, 4e-4, n // 3)  # a line of them along x
        across = np.cross([0.0, 0.0, 1.0], rng.normal(size=(t, 3)))
        across /= np.maximum(np.linalg.norm(across, axis=1, keepdims=True), 1e-12)
        offset = np.einsum("tk,tk->t", across, pts[rng.integers(0, n, t)])
        if n > 2:
            offset[0] = np.einsum("k,k->", across[0], pts[1]) + 0.001  # point 1 on trial 0's tolerance edge
        rows = np.ascontiguousarray(pts.T)
        ref = _reference(across, offset, pts, 0.001)
        want = int(np.argmax(ref.sum(axis=1)))
        assert best_trial(across, offset, rows, 0.001) == want
        assert np.array_equal(best_line(across, offset, rows, 0.001), ref[want])


def test_the_line_through_a_row_of_points_wins_and_holds_just_that_row() -> None:
    # 30 points on y = 0.01 (z = 0.5) and 20 scattered ones; trial 2 is that line: it holds the 30 exactly
    rng = np.random.default_rng(2)
    row = np.column_stack([np.linspace(-0.05, 0.05, 30), np.full(30, 0.01), np.full(30, 0.5)])
    scatter = np.column_stack([rng.uniform(-0.05, 0.05, 20), rng.uniform(0.02, 0.05, 20), np.full(20, 0.5)])
    rows = np.ascontiguousarray(np.vstack([row, scatter]).T)
    across = np.array([[1.0, 0.0, 0.0], [0.6, 0.8, 0.0], [0.0, 1.0, 0.0]])
    offset = np.array([0.0, 0.01, 0.01])
    assert best_trial(across, offset, rows, 1e-4) == 2
    on = best_line(across, offset, rows, 1e-4)
    assert on[:30].all() and not on[30:].any()
