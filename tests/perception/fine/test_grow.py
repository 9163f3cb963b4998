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
