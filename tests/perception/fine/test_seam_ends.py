"""A fold seam's ends: where both faces' points are near it, moved in past what the noise carries beyond a
sharp end, and onto a face's straight edge where one stops there."""

from __future__ import annotations

import numpy as np
import pytest

from perception.fine.refine import RefineParams
from perception.fine.seam_ends import noise_ends, supported_ends
from perception.fine.types import NoiseModel, Surface


def _floor_and_wall() -> tuple[NoiseModel, Surface, Surface, np.ndarray, float]:
    """A floor at 0.8 m facing the camera and a wall standing on it along x (their fold: the x axis at 0.8 m)."""
    nm = NoiseModel(sigma_1m_m=0.0005, floor_m=1e-4, pixel_angle_rad=0.001)
    z0 = 0.8
    floor = Surface(0, "plane", np.array([0.0, 0.0, -1.0]), z0, 3e-4, 1000, np.array([0.0, 0.02, z0]), z0)
    wall = Surface(1, "plane", np.array([0.0, 1.0, 0.0]), 0.0, 3e-4, 1000, np.array([0.0, 0.0, z0 - 0.02]), z0)
    return nm, floor, wall, np.array([1.0, 0.0, 0.0]), z0


def test_the_ends_of_a_seam_hold_where_one_face_is_seen_sparsely() -> None:
    # a face seen obliquely leaves about one point per millimetre near the line: its random holes (several
    # millimetres at times) are not its end; the seam runs the face's whole 60 mm, its ends within 4 mm (a
    # few sample spacings of that face) on at least 15 of 20 draws (1 of 20 with 1 mm bins of 2 points each)
    nm, floor, wall, u, z0 = _floor_and_wall()
    whole = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        n_floor, n_wall = 600, 60  # 10 and 1 points per millimetre within 5 mm of the line
        qa = np.column_stack([rng.uniform(0, 0.06, n_floor), rng.uniform(0, 0.005, n_floor), np.full(n_floor, z0)])
        qb = np.column_stack([rng.uniform(0, 0.06, n_wall), np.zeros(n_wall), z0 - rng.uniform(0.0015, 0.005, n_wall)])
        pieces = supported_ends(qa, qb, floor, wall, np.array([0.0, 0.0, z0]), u, 0.0, 0.06, nm, RefineParams())
        if pieces:
            t = np.sort(pieces[0] @ u)
            whole += abs(t[0]) < 0.004 and abs(t[1] - 0.06) < 0.004
    assert whole >= 15


def test_stray_points_past_a_faces_end_do_not_carry_the_seam_out() -> None:
    # two faces along 60 mm of line, and three flying pixels near the line 4-5 mm past the wall's end: the
    # seam ends where the wall does (before: where the strays are)
    nm, floor, wall, u, z0 = _floor_and_wall()
    rng = np.random.default_rng(0)
    qa = np.column_stack([rng.uniform(0, 0.07, 1400), rng.uniform(0, 0.005, 1400), np.full(1400, z0)])
    qb = np.column_stack([rng.uniform(0, 0.06, 300), np.zeros(300), z0 - rng.uniform(0.0015, 0.005, 300)])
    strays = np.array([[0.064, 0.0, z0 - 0.002], [0.0645, 0.0, z0 - 0.003], [0.065, 0.0, z0 - 0.0025]])
    (ends,) = supported_ends(qa, np.concatenate([qb, strays]), floor, wall, np.array([0.0, 0.0, z0]), u, 0.0, 0.06,
                              nm, RefineParams())  # fmt: skip
    t = np.sort(ends @ u)
    assert abs(t[1] - 0.06) < 0.0005


def test_a_face_seen_again_past_a_hole_keeps_its_end() -> None:
    # a sparse face (a line scanner's rows): the last row of a bin's worth of points lies past a 6 mm hole; it is the
    # face seen again, not a stray, and the seam runs to it (a tail is stray only with fewer than a bin holds)
    nm, floor, wall, u, z0 = _floor_and_wall()
    rng = np.random.default_rng(1)
    qa = np.column_stack([rng.uniform(0, 0.07, 1400), rng.uniform(0, 0.005, 1400), np.full(1400, z0)])
    qb = np.column_stack([rng.uniform(0, 0.052, 300), np.zeros(300), z0 - rng.uniform(0.0015, 0.005, 300)])
    row = np.column_stack([np.linspace(0.0584, 0.0590, 6), np.zeros(6), z0 - np.linspace(0.0015, 0.005, 6)])
    (ends,) = supported_ends(qa, np.concatenate([qb, row]), floor, wall, np.array([0.0, 0.0, z0]), u, 0.0, 0.06,
                              nm, RefineParams())  # fmt: skip
    t = np.sort(ends @ u)
    assert abs(t[1] - 0.059) < 0.0005


def test_the_ends_do_not_depend_on_where_the_line_coordinates_start() -> None:
    # the same faces and seam, the line's origin moved along it: the ends found are the same points. The coarse
    # stretch's first bin was int((t0 - (t0 - 6 mm)) / 1 mm), 5 instead of 6 for about a quarter of the places
    # t0 may fall; a slack bin with points then counted in how wide the bins are widened, and an end moved
    # (draw 7 here: two different ends over 201 origins)
    nm, floor, wall, u, z0 = _floor_and_wall()
    length = 0.010
    for seed in (7, 0, 1, 2):
        rng = np.random.default_rng(seed)
        qa = np.column_stack([rng.uniform(-0.004, length, 120), rng.uniform(0.0012, 0.005, 120), np.full(120, z0)])
        tb = rng.uniform(-0.004, length, 14)  # a sparse wall: a bin's count more or less changes the widening
        qb = np.column_stack([tb, np.zeros(len(tb)), z0 - rng.uniform(0.0015, 0.005, len(tb))])
        found = set()
        for shift in np.linspace(-0.2, 0.2, 201):
            origin = np.array([0.0, 0.0, z0]) + shift * u
            (ends,) = supported_ends(qa, qb, floor, wall, origin, u, -shift, length - shift, nm, RefineParams())
            found.add(tuple(np.round(np.sort((ends - np.array([0.0, 0.0, z0])) @ u), 9)))
        assert len(found) == 1, (seed, found)


def test_a_fold_parted_by_a_gusset_gives_a_seam_on_each_side_of_it() -> None:
    # floor and wall along 100 mm of line, a gusset 5 mm thick standing across the fold at 60-65 mm: neither face
    # has points there, the gusset's own stand in front of both. The stretches on both sides are seams, the
    # longest first; a stretch under min_piece_m (8 mm, past another hole) is not. The same 5 mm hole with
    # nothing standing in it (a dropout) is bridged, and so is one where the points in front of both faces
    # are as dense as all along the fold (a rounded corner). Before, the gusset was bridged too, and of
    # stretches parted further only the longest was kept
    nm, floor, wall, u, z0 = _floor_and_wall()
    rng = np.random.default_rng(2)

    def faces(t0: float, t1: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        qa = np.column_stack([rng.uniform(t0, t1, n), rng.uniform(0.0, 0.005, n), np.full(n, z0)])
        qb = np.column_stack([rng.uniform(t0, t1, n), np.zeros(n), z0 - rng.uniform(0.0015, 0.005, n)])
        return qa, qb

    parts = [faces(0.0, 0.060, 1200), faces(0.065, 0.100, 700), faces(0.112, 0.120, 160)]
    qa, qb = (np.concatenate([p[i] for p in parts]) for i in (0, 1))
    gusset_t = rng.uniform(0.060, 0.065, 80)  # where the gusset's points lie along the fold
    origin = np.array([0.0, 0.0, z0])
    pieces = supported_ends(qa, qb, floor, wall, origin, u, 0.0, 0.12, nm, RefineParams(), standing=gusset_t)
    spans = [np.sort(e @ u) for e in pieces]
    assert len(spans) == 2
    assert spans[0] == pytest.approx([0.0, 0.060], abs=5e-4)
    assert spans[1] == pytest.approx([0.065, 0.100], abs=5e-4)
    (whole,) = supported_ends(qa, qb, floor, wall, origin, u, 0.0, 0.12, nm, RefineParams())
    assert np.sort(whole @ u) == pytest.approx([0.0, 0.100], abs=5e-4)
    # a rounded corner stands in front of both planes all along the fold, as densely in the hole as elsewhere:
    # that is the fold's own shape, not an obstacle, and the hole is bridged
    rounding = rng.uniform(0.0, 0.12, 1900)
    (whole,) = supported_ends(qa, qb, floor, wall, origin, u, 0.0, 0.12, nm, RefineParams(), standing=rounding)
    assert np.sort(whole @ u) == pytest.approx([0.0, 0.100], abs=5e-4)


def test_an_end_is_moved_in_past_the_points_the_noise_carried_beyond_it() -> None:
    """500 points spread evenly over 100 mm of a line, each moved along it by 0.8 mm of noise (a depth camera's
    error along a ray that runs partly along the seam): the outermost point lies past the end by 0.5 mm on
    average and by 1.8 mm one time in a hundred. Of a density rho per metre, rho sigma / sqrt(2 pi) points are
    expected beyond a sharp end; the end taken past them lies short of the true end by about a sample spacing
    (0.2 mm here) on average, and past it by 1 mm at most one time in a hundred."""
    sigma, raw, ends = 0.0008, [], []
    for seed in range(300):
        rng = np.random.default_rng(seed)
        t = np.sort(rng.uniform(0.0, 0.1, 500) + rng.normal(0.0, sigma, 500))
        lo, hi = noise_ends(t, sigma)
        raw += [-t[0], t[-1] - 0.1]
        ends += [-lo, hi - 0.1]
    raw_mm, ends_mm = 1000 * np.array(raw), 1000 * np.array(ends)
    assert raw_mm.mean() > 0.4 and np.percentile(raw_mm, 99) > 1.7
    assert -0.4 < ends_mm.mean() < -0.1 and np.percentile(ends_mm, 99) < 1.0
    # no noise measured: the outermost points are the ends
    t = np.linspace(0.0, 0.1, 50)
    assert noise_ends(t, 0.0) == (0.0, 0.1)


def _wall_ending_at(end_m: float, rng: np.random.Generator, n: int = 400) -> np.ndarray:
    """Points of the wall of :func:`_floor_and_wall` up to 12 mm above the floor, its end a straight vertical
    edge at ``end_m`` along the fold."""
    return np.column_stack([rng.uniform(0.0, end_m, n), np.zeros(n), 0.8 - rng.uniform(0.0015, 0.012, n)])


def test_an_end_is_placed_on_the_faces_straight_edge_not_on_a_mixed_pixel_near_the_corner(monkeypatch) -> None:
    """A wall ending at a straight edge at 60 mm (sampled sparsely: 400 points), and two mixed pixels on the
    depth edge at its end, 1.2 and 1.5 mm past it and 2 mm above the floor, where the fold's support is read:
    the outermost point is theirs, and the end placed by the support alone lies 1.2 mm past the wall's at the
    median of 60 draws (BOUNDARY_MOVE_M = 0: the boundary not used). The wall's edge, fitted on its outermost
    points up to 12 mm up, places the end 0.2 mm from the wall's at the median, past it by 0.5 mm at most nine
    times in ten."""
    import perception.fine.seam_ends as seam_ends

    nm, floor, wall, u, z0 = _floor_and_wall()
    origin = np.array([0.0, 0.0, z0])
    mixed = np.array([[0.0612, 0.0, z0 - 0.002], [0.0615, 0.0, z0 - 0.0021]])

    def past_end(seed: int, *, boundary: bool = True) -> float:
        rng = np.random.default_rng(seed)
        qa = np.column_stack([rng.uniform(0, 0.07, 1400), rng.uniform(0, 0.005, 1400), np.full(1400, z0)])
        qb = np.concatenate([_wall_ending_at(0.06, rng), mixed])
        (ends,) = supported_ends(qa, qb, floor, wall, origin, u, 0.0, 0.06, nm, RefineParams(), boundary=boundary)
        return float(np.sort(ends @ u)[1]) - 0.06

    fitted = np.array([past_end(seed) for seed in range(60)])
    assert abs(float(np.median(fitted))) < 0.0002 and np.percentile(fitted, 90) < 0.0005
    unfitted = [past_end(seed, boundary=False) for seed in range(60)]  # as for a V-groove, which its trace ends
    monkeypatch.setattr(seam_ends, "BOUNDARY_MOVE_M", 0.0)
    assert [past_end(seed) for seed in range(60)] == unfitted
    assert float(np.median(unfitted)) > 0.0011


def test_a_faces_boundary_never_moves_an_end_out_nor_in_past_a_slanted_edge(monkeypatch) -> None:
    """Where the wall's edge leans (a gusset's slanted side, 45 degrees: 12 mm further in at the top), its
    boundary is no straight edge down to the seam, and the end stays where the support puts it (as with
    BOUNDARY_MOVE_M = 0). And a boundary beyond the support's end (the floor's points stopping first) never
    carries the end out: the end is the floor's."""
    import perception.fine.seam_ends as seam_ends
    from perception.fine.seam_ends import boundary_ends

    nm, floor, wall, u, z0 = _floor_and_wall()
    origin = np.array([0.0, 0.0, z0])
    rng = np.random.default_rng(5)
    qa = np.column_stack([rng.uniform(0, 0.07, 1400), rng.uniform(0, 0.005, 1400), np.full(1400, z0)])
    qb = _wall_ending_at(0.072, rng, 3000)
    qb = qb[qb[:, 0] <= 0.06 - (z0 - qb[:, 2])]  # the edge leans in by its height
    (ends,) = supported_ends(qa, qb, floor, wall, origin, u, 0.0, 0.06, nm, RefineParams())
    monkeypatch.setattr(seam_ends, "BOUNDARY_MOVE_M", 0.0)
    (support_only,) = supported_ends(qa, qb, floor, wall, origin, u, 0.0, 0.06, nm, RefineParams())
    assert np.array_equal(ends, support_only)
    # the floor stops at 55 mm, the wall runs on to 60: the end stays at 55 whatever the wall's edge says
    assert boundary_ends(qa[qa[:, 0] <= 0.055], _wall_ending_at(0.06, rng), floor, wall, origin, u, (0.0, 0.055),
                         nm)[1] == 0.055  # fmt: skip
