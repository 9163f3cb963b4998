"""The plane most of a face's points lie on, when another surface close beside a narrow face pulls its fit."""

from __future__ import annotations

import numpy as np
import pytest

from perception.fine.biweight import biweight_plane
from perception.fine.dominant_plane import COS_FLOOR, dominant_plane, normal_sigma, one_sided, within_noise
from perception.fine.types import NoiseModel

NOISE = NoiseModel(sigma_1m_m=0.003, floor_m=5e-5, pixel_angle_rad=0.0015)  # 1.27 mm at 0.65 m


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(min(1.0, abs(float(a @ b))))))


def test_the_noise_across_a_face_is_the_depth_noise_times_the_cosine_of_its_incidence() -> None:
    p = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    n60 = np.array([0.0, np.sin(np.radians(60.0)), -np.cos(np.radians(60.0))])  # 60 degrees off the ray
    assert normal_sigma(p, n60, NOISE) == pytest.approx([0.003 * 0.5, 0.012 * 0.5], rel=1e-12)
    edge_on = np.array([0.0, 1.0, 0.0])  # along the ray: counted as at the floor's incidence
    assert normal_sigma(p, edge_on, NOISE) == pytest.approx([0.003 * COS_FLOOR, 0.012 * COS_FLOOR], rel=1e-12)
    structured = NoiseModel(sigma_1m_m=0.003, floor_m=5e-5, pixel_angle_rad=0.0015, structure_1m_m=0.004)
    assert normal_sigma(p[:1], n60, structured) == pytest.approx([0.005 * 0.5], rel=1e-12)  # hypot(3, 4) mm


def _noisy(rng: np.random.Generator, on: np.ndarray) -> np.ndarray:
    """Points ``on`` a surface, each moved along its own ray (the camera at the origin) by the depth noise."""
    ray = on / np.linalg.norm(on, axis=1, keepdims=True)
    return on + ray * rng.normal(0.0, 1.0, (len(on), 1)) * NOISE.sigma_m(on[:, 2])[:, None]


def test_a_narrow_face_with_its_edge_face_beside_it_is_fitted_on_its_own_points() -> None:
    """A gusset's side seen 68 degrees off square at 0.65 m (600 points, 30 mm wide) and its 8 mm edge face
    along one side, square to it (300 points): the robust fit of all of them is tilted by degrees; the
    dominant plane's points give the side's plane within 1.5 degrees (the edge face's points within the noise
    of the side's plane, along their shared edge, stay)."""
    rng = np.random.default_rng(1)
    side_n = np.array([0.0, np.sin(np.radians(68.0)), -np.cos(np.radians(68.0))])
    centre = np.array([0.0, 0.0, 0.65])
    u = np.cross(side_n, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(side_n, u)
    side = _noisy(rng, centre + rng.uniform(-0.015, 0.015, (600, 1)) * u + rng.uniform(-0.015, 0.015, (600, 1)) * v)
    # the edge face: from the side's edge at +15 mm along u, 8 mm out of the side's plane towards the camera
    edge = _noisy(rng, centre + 0.015 * u + rng.uniform(-0.015, 0.015, (300, 1)) * v
                  + rng.uniform(0.0, 0.008, (300, 1)) * side_n)  # fmt: skip
    pts = np.vstack([side, edge])
    n, off = biweight_plane(pts, np.ones(len(pts)))
    assert _angle_deg(n, side_n) > 3.0  # pulled off by the edge face
    start = dominant_plane(pts, n, off, NOISE)
    assert start is not None
    on = within_noise(pts, *start, NOISE)
    assert on[:600].mean() > 0.9 and on[600:].mean() < 0.3
    n2, off2 = biweight_plane(pts[on], np.ones(int(on.sum())))
    assert _angle_deg(n2, side_n) < 1.5 < 3.0 < _angle_deg(n, side_n)
    assert within_noise(pts, n2, off2, NOISE).sum() > within_noise(pts, n, off, NOISE).sum()
    # what the side's plane leaves out is the edge face, all in front of it (towards the camera)
    assert one_sided(pts, n2, off2, NOISE)


def test_a_clean_face_is_left_to_its_fit() -> None:
    rng = np.random.default_rng(2)
    normal = np.array([0.0, 0.6, -0.8])
    u = np.cross(normal, [1.0, 0.0, 0.0])
    v = np.cross(normal, u)
    pts = _noisy(rng, np.array([0.05, 0.0, 0.7]) + rng.uniform(-0.03, 0.03, (800, 1)) * u
                 + rng.uniform(-0.03, 0.03, (800, 1)) * v)  # fmt: skip
    n, off = biweight_plane(pts, np.ones(len(pts)))
    assert within_noise(pts, n, off, NOISE).mean() > 0.95
    assert dominant_plane(pts, n, off, NOISE) is None
    assert dominant_plane(pts[:5], n, off, NOISE) is None  # too few points to judge


def test_points_off_a_plane_on_both_sides_are_noise_not_another_surface() -> None:
    """The noise scatters to both sides of a face: a face whose noise is twice what the model says leaves a
    fifth of its points outside 2.5 sigma, half on each side; a slab of points 3-6 mm in front does not."""
    rng = np.random.default_rng(3)
    normal = np.array([0.0, 0.0, -1.0])  # square to the camera at 0.8 m: the noise across is the depth noise
    xy = rng.uniform(-0.05, 0.05, (2000, 2))
    z = 0.8 + rng.normal(0.0, 2.0 * float(NOISE.sigma_m(0.8)), 2000)
    noisy = np.column_stack([xy, z])
    off = ~within_noise(noisy, normal, 0.8, NOISE)
    assert 0.15 < off.mean() < 0.35 and not one_sided(noisy, normal, 0.8, NOISE)
    in_front = np.column_stack([xy[:300], 0.8 - rng.uniform(0.003, 0.006, 300)])
    clean = np.column_stack([xy[300:], np.full(1700, 0.8)])
    assert one_sided(np.vstack([clean, in_front]), normal, 0.8, NOISE)
    assert not one_sided(clean, normal, 0.8, NOISE)  # nothing off it at all
