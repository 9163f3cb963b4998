"""A butt gap's far edge fitted to the rays' ranges: on rays traced through a square-cut gap seen obliquely,
under noise where a depth cut on the face's points is biased, and no answer where the gap's rays have no
range."""

from __future__ import annotations

import numpy as np
import pytest

from perception.fine.gap_profile import gap_edges
from perception.fine.types import Surface


def _traced(gap_m: float, tilt_deg: float, sigma_m: float, *, seed: int = 0, thick_m: float = 0.006):
    """Rays from a camera 0.7 m away, tilted ``tilt_deg`` across a gap in a plates' top (the plane z = 0 of a
    local frame, normal +z to the camera; the far plate for x < 0, its square edge face at x = 0, the near
    plate from x = ``gap_m``, both ``thick_m`` thick over a floor), traced to what each meets, with
    ``sigma_m`` of range noise. Returns the camera-frame points, their sigma, the top as a Surface and the
    frame's origin and across direction in the camera frame."""
    rng = np.random.default_rng(seed)
    t = np.radians(tilt_deg)
    eye = np.array([0.7 * np.sin(t), 0.0, 0.7 * np.cos(t)])  # the camera on the near side (+x), above
    # rays at random through a 12 mm x 40 mm patch of the top's plane around the gap
    aim = np.column_stack([rng.uniform(-0.006, 0.006 + gap_m, 6000), rng.uniform(-0.02, 0.02, 6000), np.zeros(6000)])
    d = aim - eye
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    s_top = -eye[2] / d[:, 2]  # every ray crosses the top's plane at aim
    x = eye[0] + s_top * d[:, 0]
    s_hit = s_top.copy()
    in_gap = (x > 0.0) & (x < gap_m)
    s_face = (0.0 - eye[0]) / d[:, 0]  # where the ray reaches the face's plane x = 0
    depth_at_face = -(eye[2] + s_face * d[:, 2])
    meets_face = in_gap & (depth_at_face <= thick_m)
    s_hit[meets_face] = s_face[meets_face]
    through = in_gap & ~meets_face
    s_hit[through] = (-thick_m - eye[2]) / d[through, 2]  # the floor
    pts_local = eye + (s_hit + sigma_m * rng.standard_normal(len(d)))[:, None] * d
    # the camera frame: origin at the eye, z along the view to the gap's middle (any rotation will do)
    z = np.array([gap_m / 2, 0.0, 0.0]) - eye
    z /= np.linalg.norm(z)
    xc = np.cross([0.0, 1.0, 0.0], z)
    xc /= np.linalg.norm(xc)
    R = np.vstack([xc, np.cross(z, xc), z])  # rows: camera axes in the local frame
    q = (pts_local - eye) @ R.T
    n_cam = R @ np.array([0.0, 0.0, 1.0])
    top = Surface(0, "plane", n_cam, -float(n_cam @ (R @ -eye)), sigma_m, len(q), q.mean(axis=0), 0.7)
    return q, np.full(len(q), sigma_m), top, R @ -eye, R @ np.array([1.0, 0.0, 0.0])


@pytest.mark.parametrize(("gap_m", "tilt_deg"), [(0.0005, 26.0), (0.0025, 37.0)])
def test_the_far_edge_of_a_gap_seen_obliquely_is_where_the_rays_say(gap_m: float, tilt_deg: float) -> None:
    q, sig, top, c3, across = _traced(gap_m, tilt_deg, 0.0006)
    # the counts' first estimates: the far edge pulled 0.3 mm into the gap; the near one stands
    fitted = gap_edges(q, sig, top, c3, across, (0.0003, gap_m - 0.0001))
    assert fitted is not None
    far, near = fitted
    assert far == pytest.approx(0.0, abs=1e-4)
    assert near == gap_m - 0.0001


def test_a_depth_cut_on_the_face_points_is_biased_where_the_profile_is_not() -> None:
    # a 0.5 mm gap at 26 degrees: the face is seen about 1 mm deep, under two sigma; the points past 3 sigma
    # behind the top are those the noise pushed along their rays, which run across into the far plate
    sigma = 0.0006
    q, sig, top, c3, across = _traced(0.0005, 26.0, sigma, seed=1)
    r = q @ top.normal + top.offset
    a = (q - c3) @ across
    deep = (r < -3.0 * sigma) & (r > -12.0 * sigma) & (np.abs(a) < 0.0015)
    assert float(np.median(a[deep])) < -0.0005  # the cut's "face" stands half a millimetre inside the plate
    far, _ = gap_edges(q, sig, top, c3, across, (0.0003, 0.0004))
    assert abs(far) < 1e-4


def test_a_gap_whose_rays_have_no_range_gives_no_fit() -> None:
    # a stereo shadow or a structured-light dropout: no ray that enters the gap has a range; the tops alone
    # do not place its edges, and the counts' estimates stand
    q, sig, top, c3, across = _traced(0.0015, 30.0, 0.0003)
    crossing = (q * (-top.offset / (q @ top.normal))[:, None] - c3) @ across
    tops = (crossing < 0.0) | (crossing > 0.0015)
    assert gap_edges(q[tops], sig[tops], top, c3, across, (0.0003, 0.0015)) is None
    assert gap_edges(q, sig, top, c3, across, (0.0003, 0.0015)) is not None  # with the gap's rays: a fit
