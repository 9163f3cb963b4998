"""Folds: the intersection of two fitted planes (or a plane and a cylinder), clipped to both supports, concave
only. Measured on noise-free renders against the exact seam."""

from __future__ import annotations

import numpy as np
import pytest

from perception.evaluate import point_to_polyline_distance
from perception.fine.adjacency import adjacent_pairs
from perception.fine.folds import fold_seams, joint_type
from perception.fine.support import find_support
from perception.fine.visibility import clip_to_view

from .scenes import rendered, work


def folds(name: str, noise: str = "none"):
    p, _, nm, surf = work(name, noise)
    sup = find_support(p, surf, nm)
    # the candidates as the pipeline keeps them: where both faces are seen at under 75 degrees
    return clip_to_view(fold_seams(p, surf, adjacent_pairs(surf, nm), nm, support=sup))


def test_the_tee_gives_its_visible_fillet_on_the_exact_line_and_no_convex_edge() -> None:
    res = rendered("tee")
    seams = folds("tee")
    (gt,) = res.ground_truth
    near = [s for s in seams if np.median(point_to_polyline_distance(s.points, gt.points_camera)) < 0.002]
    assert len(near) == 1
    s = near[0]
    assert point_to_polyline_distance(s.points, gt.points_camera).max() < 2e-4
    # clipped to the web's length within the work image's 2 mm bins
    gt_length = float(np.linalg.norm(gt.points_camera[-1] - gt.points_camera[0]))
    assert np.linalg.norm(s.points[1] - s.points[0]) == pytest.approx(gt_length, abs=0.005)
    assert s.joint == "fillet"
    # the only other folds found are the web's narrow end and the base's edge against... nothing: none
    assert len(seams) == 1


def test_a_pipe_on_a_plate_gives_one_ring_of_its_radius() -> None:
    res = rendered("pipe")
    seams = [s for s in folds("pipe") if s.kind == "curved"]
    assert len(seams) == 1
    (gt,) = res.ground_truth
    d = point_to_polyline_distance(seams[0].points, gt.points_camera)
    assert np.median(d) < 3e-4
    # ends within a 2 mm bin and the view clip's 1 mm sampling of where the truth's ends are
    assert d.max() < 3e-3


def test_joint_types_follow_how_the_faces_stand() -> None:
    up = np.array([0.0, 0.0, 1.0])
    x, y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    b = np.radians(30.0)
    assert joint_type(up, x, up, 0.08, 0.014) == "fillet"
    assert joint_type(up, x, up, 0.008, 0.014) == "lap"
    assert joint_type(x, y, up, 0.1, 0.014) == "inside_corner"
    bev_l = np.array([np.cos(np.pi / 2 - b), 0.0, np.sin(np.pi / 2 - b)])
    bev_r = np.array([-bev_l[0], 0.0, bev_l[2]])
    assert joint_type(bev_l, bev_r, up, 0.01, 0.014) == "v_groove"
    # bevels 25 degrees from the vertical (a 50-degree included angle): their normals rise 25 degrees
    steep = np.radians(25.0)
    st_l, st_r = np.array([np.cos(steep), 0.0, np.sin(steep)]), np.array([-np.cos(steep), 0.0, np.sin(steep)])
    assert joint_type(st_l, st_r, up, 0.01, 0.014) == "v_groove"
    # walls leaning 10 degrees are still an inside corner
    lean = np.radians(10.0)
    assert joint_type(np.array([np.cos(lean), 0.0, np.sin(lean)]), y, up, 0.1, 0.014) == "inside_corner"
