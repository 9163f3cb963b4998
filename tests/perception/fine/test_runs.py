"""Runs of covered bins (perception/fine/runs.py): exact [start, stop) runs, hole closing, rings."""

from __future__ import annotations

import numpy as np

from perception.fine.runs import covered_runs, trim_stray_tails


def bins(text: str) -> np.ndarray:
    return np.array([c == "#" for c in text])


def test_runs_are_half_open_and_holes_up_to_max_hole_are_closed() -> None:
    cover = bins("..###.#..##...#")
    assert covered_runs(cover, 0) == [(2, 5), (6, 7), (9, 11), (14, 15)]
    assert covered_runs(cover, 1) == [(2, 7), (9, 11), (14, 15)]  # the one-bin hole at 5 closed
    assert covered_runs(cover, 2) == [(2, 11), (14, 15)]  # and the two-bin hole at 7-8
    assert covered_runs(cover, 3) == [(2, 15)]  # and the three-bin hole at 11-13


def test_nothing_covered_is_no_run_and_everything_covered_is_one() -> None:
    assert covered_runs(bins("....."), 3) == []
    assert covered_runs(np.zeros(0, bool), 3) == []
    assert covered_runs(bins("#####"), 0) == [(0, 5)]
    assert covered_runs(bins("#####"), 0, closed=True) == [(0, 5)]


def test_the_input_is_not_changed() -> None:
    cover = bins("#.#")
    assert covered_runs(cover, 1) == [(0, 3)]
    assert cover.tolist() == [True, False, True]


def test_a_ring_joins_the_run_at_its_end_to_the_one_at_its_start() -> None:
    cover = bins("##...###..#")
    assert covered_runs(cover, 0) == [(0, 2), (5, 8), (10, 11)]
    # on a ring the last bin (10) and the first two (0, 1) are one run, its stop past the end: 10 .. 11 + 2
    assert covered_runs(cover, 0, closed=True) == [(5, 8), (10, 13)]
    # a hole is closed only inside the array, not across the wrap: 8-9 closed, nothing else joined
    assert covered_runs(cover, 2, closed=True) == [(5, 13)]
    # runs that touch neither end are left as they are on a ring
    assert covered_runs(bins(".##.##."), 0, closed=True) == [(1, 3), (4, 6)]
    # a ring closed all round by its holes is one run over the whole ring
    assert covered_runs(bins("#.#.#"), 1, closed=True) == [(0, 5)]


def test_a_few_points_past_a_gap_are_trimmed_and_the_rest_is_kept() -> None:
    face = np.arange(0.0, 0.0601, 0.0005)  # 121 points, 0.5 mm apart, 0-60 mm
    strays = np.array([0.0640, 0.0645, 0.0650, -0.0050])  # three past a 4 mm gap, one 5 mm before the start
    t = np.sort(np.concatenate([face, strays]))
    kept = trim_stray_tails(t)
    assert kept[0] == 0.0 and kept[-1] == face[-1]
    assert kept.size == face.size
    # a piece beyond a gap that holds more points than the gap would have is the face's own: kept
    long_tail = np.sort(np.concatenate([face, 0.0640 + 0.0005 * np.arange(12)]))
    assert trim_stray_tails(long_tail)[-1] == long_tail[-1]
    # nothing to trim, and too few points to judge
    assert np.array_equal(trim_stray_tails(face), face)
    assert np.array_equal(trim_stray_tails(np.array([0.0, 0.01, 0.05])), np.array([0.0, 0.01, 0.05]))


def test_a_sparse_faces_random_gaps_cost_it_little() -> None:
    # one point per millimetre on average (a face seen obliquely), 60 mm: its random gaps are not its end
    # (random points: a grid's samples are more even than these)
    short = []
    for seed in range(100):
        t = np.sort(np.random.default_rng(seed).uniform(0.0, 0.060, 60))
        kept = trim_stray_tails(t)
        short.append((kept[0] - t[0]) + (t[-1] - kept[-1]))
    assert np.mean(np.asarray(short) > 0.0) < 0.2  # 11 of 100 lose anything
    assert np.percentile(short, 90) < 0.004  # 3.0 mm
