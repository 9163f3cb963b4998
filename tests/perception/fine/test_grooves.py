"""V-grooves whose bevels are too thin to segment: found from the two plates and the trough between them."""

from __future__ import annotations

import numpy as np
import pytest

from perception.evaluate import point_to_polyline_distance
from perception.fine.grooves import groove_seams
from perception.fine.refine import refine_seams
from perception.fine.support import find_support

from .scenes import rendered, work


@pytest.mark.parametrize("noise", ["none", "stereo"])
def test_the_root_of_a_v_groove_with_thin_bevels(noise: str) -> None:
    name = "v_groove"
    res = rendered(name, noise)
    p, _, nm, surf = work(name, noise)
    full = res.capture.points_camera()
    seams, surf2 = groove_seams(p, surf, nm, full, res.capture.intrinsics, nm, support=find_support(p, surf, nm))
    (gt,) = res.ground_truth
    assert len(seams) == 1 and seams[0].joint == "v_groove"
    assert len(surf2.surfaces) == len(surf.surfaces) + 2  # the two bevels, fitted
    (s,), _ = refine_seams(seams, full, res.capture.intrinsics, surf2, nm)
    # both bevels at 30 degrees from the vertical, so 60 degrees from the plates and 120 degrees apart
    na, nb = s.normals_a[0], s.normals_b[0]
    assert np.degrees(np.arccos(np.clip(na @ nb, -1, 1))) == pytest.approx(120.0, abs=2.0 if noise == "none" else 4.0)
    samples = s.points[0] + np.linspace(0, 1, 60)[:, None] * (s.points[1] - s.points[0])
    err = point_to_polyline_distance(samples, gt.points_camera)
    assert np.median(err) < (2e-4 if noise == "none" else 5e-4)
    length = float(np.linalg.norm(s.points[1] - s.points[0]))
    assert length > 0.8 * float(np.linalg.norm(np.diff(gt.points_camera, axis=0), axis=1).sum())


def test_a_flat_plate_split_in_two_is_no_groove() -> None:
    res = rendered("butt", "none")
    p, _, nm, surf = work("butt", "none")
    seams, _ = groove_seams(p, surf, nm, res.capture.points_camera(), res.capture.intrinsics, nm,
                            support=find_support(p, surf, nm))  # fmt: skip
    assert seams == []


def test_an_open_root_is_placed_at_the_middle_of_the_bevels_lower_edges() -> None:
    """A 1.6 mm root gap above 1 mm root faces, seen through: the bevels' intersection lies (g/2) cot(30
    degrees) = 1.39 mm below the root, where the seam is; the refinement finds the edges from the rays that
    pass the bevels' planes below them."""
    name = "v_groove_open"
    res = rendered(name, "none")
    p, _, nm, surf = work(name, "none")
    full = res.capture.points_camera()
    seams, surf2 = groove_seams(p, surf, nm, full, res.capture.intrinsics, nm, support=find_support(p, surf, nm))
    (gt,) = res.ground_truth
    grooves = [s for s in seams if s.joint == "v_groove"]
    assert len(grooves) == 1
    (s,), _ = refine_seams(grooves, full, res.capture.intrinsics, surf2, nm)
    samples = s.points[0] + np.linspace(0, 1, 60)[:, None] * (s.points[1] - s.points[0])
    err = point_to_polyline_distance(samples, gt.points_camera)
    assert np.median(err) < 3e-4  # the intersection alone would be 1.39 mm off
    assert s.gap_m == pytest.approx(0.0016, abs=4e-4)
