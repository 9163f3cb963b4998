"""Growing surfaces into the band between them: each free pixel goes to the surface it lies on within the
noise, up to the corner, ring by ring; pixels on neither stay free."""

from __future__ import annotations

import numpy as np

from perception.fine.grow import grow
from perception.fine.types import Surface


def _fold(cols: int = 40, rows: int = 20, corner: int = 20):
    """A floor (z = 0.8) left of column ``corner`` and a face rising towards the camera right of it (z falls
    1 mm per column), sampled every millimetre; the two planes exact."""
    x = (np.arange(cols) - corner) * 0.001
    y = np.arange(rows) * 0.001
    X, Y = np.meshgrid(x, y)
    Z = np.where(X <= 0, 0.8, 0.8 - X)
    p = np.stack([X, Y, Z], axis=-1)
    floor = Surface(0, "plane", np.array([0.0, 0.0, -1.0]), 0.8, 0.0, 0, np.array([-0.01, 0.01, 0.8]), 0.8)
    n = np.array([-1.0, 0.0, -1.0]) / np.sqrt(2.0)  # the face z = 0.8 - x, towards the camera
    face = Surface(1, "plane", n, -float(n @ [0.0, 0.0, 0.8]), 0.0, 0, np.array([0.01, 0.01, 0.79]), 0.79)
    return p, [floor, face]


def test_the_band_between_two_faces_is_shared_out_up_to_the_corner() -> None:
    p, surfaces = _fold()
    labels = np.full(p.shape[:2], -1, np.int32)
    labels[:, :12] = 0  # the floor's segmented pixels end 8 columns short of the corner (column 20) ...
    labels[:, 26:] = 1  # ... and the face's 6 columns beyond it
    sigma = np.full(p.shape[:2], 1e-4)
    out = grow(p, labels, surfaces, sigma, within_sigma=3.0, rings=10)
    assert (out[:, :20] == 0).all()
    assert (out[:, 20:] == 1).all()  # the corner column lies on both: the face, nearer, reaches it first


def test_growth_stops_after_its_rings_and_at_points_on_neither_face() -> None:
    p, surfaces = _fold()
    labels = np.full(p.shape[:2], -1, np.int32)
    labels[:, :12] = 0
    labels[:, 26:] = 1
    p[:, 16, 2] -= 0.002  # a column standing 2 mm off the floor: on neither face
    sigma = np.full(p.shape[:2], 1e-4)
    out = grow(p, labels, surfaces, sigma, within_sigma=3.0, rings=3)
    assert (out[:, :15] == 0).all() and (out[:, 15:23] == -1).all() and (out[:, 23:] == 1).all()
    out = grow(p, labels, surfaces, sigma, within_sigma=3.0, rings=10)
    assert (out[:, :16] == 0).all() and (out[:, 16] == -1).all()  # the floor does not grow past the column
    # the floor's columns beyond it lie 0.7 mm (7 sigma) off the face's plane: the face stops at the corner
    assert (out[:, 17:20] == -1).all() and (out[:, 20:] == 1).all()


def test_a_pixel_as_near_two_surfaces_joins_the_one_met_first_left_right_above_below() -> None:
    p, surfaces = _fold()
    twin = Surface(2, "plane", surfaces[0].normal, surfaces[0].offset, 0.0, 0, surfaces[0].centroid, 0.8)
    labels = np.full(p.shape[:2], -1, np.int32)
    labels[:, 3] = 2  # the same floor plane twice: on the left of column 4 ...
    labels[:, 5] = 0  # ... and on its right
    sigma = np.full(p.shape[:2], 1e-4)
    out = grow(p, labels, [surfaces[0], surfaces[1], twin], sigma, within_sigma=3.0, rings=1)
    assert (out[:, 4] == 2).all()  # the left neighbour's
    labels[:, 3], labels[:, 5] = 0, 2
    out = grow(p, labels, [surfaces[0], surfaces[1], twin], sigma, within_sigma=3.0, rings=1)
    assert (out[:, 4] == 0).all()


def test_a_cylinder_grows_over_the_pixels_on_it_and_stops_where_they_leave_it() -> None:
    # a pipe of radius 20 mm along y, its axis 0.52 m away; the pixels on its near half, sampled every millimetre
    x = np.arange(-15, 16) * 0.001
    y = np.arange(10) * 0.001
    X, Y = np.meshgrid(x, y)
    Z = 0.52 - np.sqrt(0.02**2 - X**2)
    Z[:, 25:] += 0.001  # the last six columns 1 mm off the pipe (10 sigma)
    p = np.stack([X, Y, Z], axis=-1)
    pipe = Surface(0, "cylinder", np.zeros(3), 0.0, 0.0, 0, np.array([0.0, 0.005, 0.5]), 0.5,
                   axis=np.array([0.0, 1.0, 0.0]), centre=np.array([0.0, 0.0, 0.52]), radius=0.02)
    labels = np.full(p.shape[:2], -1, np.int32)
    labels[:, 10:14] = 0
    out = grow(p, labels, [pipe], np.full(p.shape[:2], 1e-4), within_sigma=3.0, rings=30)
    assert (out[:, :25] == 0).all() and (out[:, 25:] == -1).all()


def _numpy_grow(p, labels, surfaces, sigma, *, within_sigma, rings):  # type: ignore[no-untyped-def]
    """The rings as the NumPy version of perception.fine.grow computed them until 2026-12-08 (the reference)."""
    lab = labels.copy()
    h, w = lab.shape
    valid = np.isfinite(p[..., 2])
    nb = ((0, -1), (0, 1), (-1, 0), (1, 0))
    known = lab >= 0
    beside = np.zeros_like(known)
    beside[:, 1:] |= known[:, :-1]
    beside[:, :-1] |= known[:, 1:]
    beside[1:, :] |= known[:-1, :]
    beside[:-1, :] |= known[1:, :]
    ys, xs = np.nonzero(beside & valid & ~known)
    for _ in range(rings):
        if len(ys) == 0:
            break
        q = p[ys, xs]
        best = np.full(len(ys), np.inf)
        best_lab = np.full(len(ys), -1, np.int32)
        for dy, dx in nb:
            ny, nx = ys + dy, xs + dx
            ok = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
            cand = np.full(len(ys), -1, np.int32)
            cand[ok] = lab[ny[ok], nx[ok]]
            res = np.full(len(ys), np.inf)
            for s_lab in np.unique(cand[cand >= 0]):
                sel = cand == s_lab
                res[sel] = np.abs(surfaces[int(s_lab)].residual(q[sel]))
            better = res < best
            best[better] = res[better]
            best_lab[better] = cand[better]
        take = (best_lab >= 0) & (best <= within_sigma * sigma[ys, xs])
        if not take.any():
            break
        lab[ys[take], xs[take]] = best_lab[take]
        cy, cx = ys[take], xs[take]
        yy = np.concatenate([cy + dy for dy, _ in nb])
        xx = np.concatenate([cx + dx for _, dx in nb])
        inside = (yy >= 0) & (yy < h) & (xx >= 0) & (xx < w)
        flat = np.unique(yy[inside] * w + xx[inside])
        ys, xs = flat // w, flat % w
        free = valid[ys, xs] & (lab[ys, xs] < 0)
        ys, xs = ys[free], xs[free]
    return lab


def test_the_compiled_rings_give_the_numpy_rings_labels_on_noisy_planes_and_a_pipe() -> None:
    rng = np.random.default_rng(11)
    h, w = 40, 60
    y, x = np.mgrid[:h, :w] * 0.001
    z = np.where(x < 0.03, 0.6 + 0.2 * x, 0.6 + 0.006 - 0.3 * (x - 0.03))  # two planes meeting in a ridge
    p = np.stack([x, y, z + rng.normal(0.0, 1e-4, (h, w))], axis=-1)
    p[rng.random((h, w)) < 0.05] = np.nan  # dropouts
    n_a = np.array([0.2, 0.0, -1.0]) / np.linalg.norm([0.2, 0.0, -1.0])
    n_b = np.array([-0.3, 0.0, -1.0]) / np.linalg.norm([-0.3, 0.0, -1.0])
    planes = [Surface(0, "plane", n_a, -float(n_a @ [0.0, 0.0, 0.6]), 0.0, 0, np.zeros(3), 0.6),
              Surface(1, "plane", n_b, -float(n_b @ [0.03, 0.0, 0.606]), 0.0, 0, np.zeros(3), 0.6),
              Surface(2, "cylinder", np.zeros(3), 0.0, 0.0, 0, np.zeros(3), 0.6, axis=np.array([0.0, 1.0, 0.0]),
                      centre=np.array([0.03, 0.0, 0.64]), radius=0.034)]  # fmt: skip
    sigma = np.full((h, w), 1e-4)
    for seed in range(6):
        labels = np.full((h, w), -1, np.int32)
        seeds = np.random.default_rng(seed).random((h, w))
        labels[(seeds < 0.05) & (x < 0.025)] = 0
        labels[(seeds < 0.05) & (x > 0.035)] = 1
        labels[(seeds > 0.98)] = 2
        for within, rings in ((3.0, 10), (2.0, 3), (6.0, 40)):
            want = _numpy_grow(p, labels, planes, sigma, within_sigma=within, rings=rings)
            got = grow(p, labels, planes, sigma, within_sigma=within, rings=rings)
            assert np.array_equal(got, want)
