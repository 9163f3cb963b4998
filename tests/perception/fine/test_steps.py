"""Laps and steps: the upper plate's edge dropped onto the lower plate, placed by the edge face's points."""

from __future__ import annotations

import numpy as np
import pytest

from perception.evaluate import point_to_polyline_distance
from perception.fine.adjacency import adjacent_pairs
from perception.fine.steps import step_seams
from perception.fine.support import find_support

from .scenes import rendered, work


def steps(name: str, noise: str, seed: int = 0):
    res = rendered(name, noise, seed)
    p, _, nm, surf = work(name, noise, seed)
    return res, step_seams(p, surf, adjacent_pairs(surf, nm), nm, res.capture.points_camera(), res.capture.intrinsics,
                           nm, support=find_support(p, surf, nm))  # fmt: skip


@pytest.mark.parametrize("noise", ["none", "stereo"])
def test_a_lap_seen_towards_its_edge_face_gives_its_seam_at_the_foot_of_the_edge(noise: str) -> None:
    res, seams = steps("lap", noise)
    (gt,) = [g for g in res.ground_truth if g.joint == "fillet" or g.joint == "lap"]
    (s,) = seams
    probe = s.points[0] + np.linspace(0, 1, 41)[:, None] * (s.points[1] - s.points[0])
    err = point_to_polyline_distance(probe, gt.points_camera)
    assert np.median(err) < (1e-4 if noise == "none" else 3e-4)
    assert s.joint == "lap"
    length_gt = float(np.linalg.norm(gt.points_camera[-1] - gt.points_camera[0]))
    assert float(np.linalg.norm(s.points[1] - s.points[0])) == pytest.approx(length_gt, abs=0.006)


def test_a_lap_seen_from_behind_its_edge_gives_no_seam() -> None:
    res, seams = steps("lap_behind", "stereo")
    assert res.ground_truth == () and seams == []
