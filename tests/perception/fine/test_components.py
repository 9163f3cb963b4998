"""Connected pieces of smooth pixels: cut where the normal turns at a fold, where depth jumps between neighbours,
and at pixels with no depth or no normal; numbered in the order of their first pixel in raster order."""

from __future__ import annotations

import numpy as np

from perception.fine.components import smooth_components
from perception.fine.noise import LocalPlanes
from perception.fine.types import NoiseModel

NOISE = NoiseModel(sigma_1m_m=4e-4, floor_m=5e-5, pixel_angle_rad=0.002)  # 0.1 mm and 1 mm apart at 0.5 m
TURN = np.radians(40.0)


def _floor(h: int = 12, w: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """A floor at z = 0.5 m sampled every millimetre, its normals towards the camera."""
    y, x = np.mgrid[:h, :w] * 0.001
    p = np.stack([x, y, np.full((h, w), 0.5)], axis=-1)
    normal = np.zeros((h, w, 3))
    normal[..., 2] = -1.0
    return p, normal


def _planes(normal: np.ndarray) -> LocalPlanes:
    h, w = normal.shape[:2]
    return LocalPlanes(np.full((h, w), 9.0), normal, np.zeros((h, w)), np.zeros((h, w)), 3)


def test_a_plate_standing_off_the_floor_and_a_line_with_no_normal_part_it_in_three() -> None:
    p, normal = _floor()
    p[3:9, 9:15, 2] -= 0.005  # a plate 5 mm over the floor: the jump (5 mm) is far over 6 sigma + half a spacing
    normal[:, 4] = np.nan  # a column with no local plane parts the floor
    comp, counts = smooth_components(p, _planes(normal), NOISE, normal_turn_rad=TURN, jump_sigma=6.0)
    want = np.full(p.shape[:2], 1)
    want[:, :3] = 0  # the floor left of the column: the first pixel in raster order
    want[:, 3:6] = -1  # the column, and the pixels a window's half (one) beside it: no normal to compare there
    want[3:9, 9:15] = 2  # the plate's first pixel comes after the right floor's (0, 6)
    assert np.array_equal(comp, want)
    assert counts.tolist() == [36, 84, 36]


def test_a_fold_drops_the_pixels_whose_neighbours_a_window_apart_turn_past_the_limit() -> None:
    p, normal = _floor()
    normal[:, 8:] = [np.sin(np.radians(60.0)), 0.0, -np.cos(np.radians(60.0))]  # turned 60 degrees from column 8
    comp, counts = smooth_components(p, _planes(normal), NOISE, normal_turn_rad=TURN, jump_sigma=6.0)
    # window 3: the normals one pixel to either side differ at columns 7 and 8 only
    assert (comp[:, 7:9] == -1).all() and (comp[:, :7] == 0).all() and (comp[:, 9:] == 1).all()
    assert counts.tolist() == [84, 84]
    # a turn of 30 degrees is no fold: one piece
    normal[:, 8:] = [np.sin(np.radians(30.0)), 0.0, -np.cos(np.radians(30.0))]
    comp, counts = smooth_components(p, _planes(normal), NOISE, normal_turn_rad=TURN, jump_sigma=6.0)
    assert (comp == 0).all() and counts.tolist() == [192]


def test_pixels_without_depth_are_in_no_piece_and_a_small_step_within_the_noise_does_not_part() -> None:
    p, normal = _floor()
    p[:, 10:, 2] -= 0.0008  # 0.8 mm: within 6 sigma (0.6 mm) plus half the spacing (0.5 mm)
    p[5, :, :] = np.nan  # a row with no depth
    comp, counts = smooth_components(p, _planes(normal), NOISE, normal_turn_rad=TURN, jump_sigma=6.0)
    assert (comp[5] == -1).all() and (comp[:5] == 0).all() and (comp[6:] == 1).all()
    assert counts.tolist() == [80, 96]
