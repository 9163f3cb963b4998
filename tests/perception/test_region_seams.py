"""perception.region_seams: the fine stage on voxel regions, on synthetic clouds whose seam is known exactly.

The cloud is a T-joint without rendering: a floor z = 0.6 m (x from -80 mm to 0) and a wall x = 0 standing on it
towards the viewpoint (z from 0.52 to 0.6 m), 100 mm along y, sampled every 0.5 mm. The seam is the line x = 0,
z = 0.6 m; the floor's outward normal is (0, 0, -1), the wall's (-1, 0, 0), both facing the viewpoint.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from perception.detect_params import DetectParams, StepLog
from perception.errors import NoSeamFound
from perception.region_seams import (
    REFERENCE_VOXEL_M,
    _Cand,
    _covers,
    _dedupe,
    _group_collinear,
    _majority,
    _scaled_to_data,
    regions_to_seams,
)
from perception.seamfit import SeamGeometry, SeamParams

VIEWPOINT = np.array([-0.3, 0.0, 0.3])
N_FLOOR, N_WALL = 160 * 201, 160 * 201


def tee(noise_m: float = 0.0) -> np.ndarray:
    y = np.arange(-0.05, 0.05 + 1e-9, 0.0005)
    X, Y = np.meshgrid(np.arange(-0.08, 0.0, 0.0005), y)
    floor = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, 0.6)])
    Z, Y2 = np.meshgrid(np.arange(0.52, 0.6, 0.0005), y)
    wall = np.column_stack([np.zeros(Z.size), Y2.ravel(), Z.ravel()])
    pts = np.vstack([floor, wall])
    assert len(pts) == N_FLOOR + N_WALL
    return pts + np.random.default_rng(0).normal(0.0, noise_m, pts.shape)


def labels(floor: int, wall: int) -> np.ndarray:
    return np.r_[np.full(N_FLOOR, floor), np.full(N_WALL, wall)].astype(np.int32)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def test_a_bare_noisy_cloud_gives_the_fold_from_the_regions_alone() -> None:
    log = StepLog()
    (seam,) = regions_to_seams(tee(noise_m=0.0003), None, DetectParams(), log, viewpoint=VIEWPOINT)
    assert (seam.kind, seam.joint, seam.labels) == ("linear", "fillet", (-1, -1))
    assert seam.regions[0] != seam.regions[1] and min(seam.regions) >= 0
    # on the line x = 0, z = 0.6 within 0.05 mm (0.3 mm noise), over the 100 mm less the trimmed ends
    np.testing.assert_allclose(seam.points[:, [0, 2]], [[0.0, 0.6], [0.0, 0.6]], atol=5e-5)
    assert sorted(seam.points[:, 1]) == pytest.approx([-0.048, 0.048], abs=0.001)
    faces = sorted([seam.normals_a.mean(axis=0), seam.normals_b.mean(axis=0)], key=lambda n: n[0])
    assert angle_deg(faces[0], np.array([-1.0, 0.0, 0.0])) < 1.0  # the wall
    assert angle_deg(faces[1], np.array([0.0, 0.0, -1.0])) < 1.0  # the floor
    assert log.counts["pass_through"] == N_FLOOR + N_WALL and log.counts["regions"] == 2
    assert log.counts["candidates"] == 1 and log.counts["seam_groups"] == 1
    assert set(log.timing_s) == {"pass_through", "voxel", "kdtree", "normals", "regions", "candidates", "fit", "refine"}


def test_two_masks_meeting_at_a_fold_propose_the_seam_exactly_on_clean_data() -> None:
    """Noise-free, the fold's voxels are too curved for region growing to link the two faces; the coarse masks
    meeting in the seam band propose it, and the refinement puts it on the exact line."""
    log = StepLog()
    (seam,) = regions_to_seams(tee(), labels(0, 1), DetectParams(), log, viewpoint=VIEWPOINT, pairs={(0, 1): 100})
    assert (seam.kind, seam.joint, seam.labels) == ("linear", "fillet", (0, 1))
    np.testing.assert_allclose(seam.points[:, [0, 2]], [[0.0, 0.6], [0.0, 0.6]], atol=1e-6)
    assert sorted(seam.points[:, 1]) == pytest.approx([-0.048, 0.048], abs=0.001)
    assert log.counts["candidates"] == 0 and log.counts["seam_groups"] == 1
    # each mask's plane from its voxels, for the butt-joint step: the floor z = 0.6, the wall x = 0
    (c0, n0, _), (c1, n1, _) = log.voxel_planes[0], log.voxel_planes[1]
    assert abs(c0[2] - 0.6) < 1e-3 and abs(abs(n0[2]) - 1.0) < 1e-9
    assert abs(c1[0]) < 1e-3 and abs(abs(n1[0]) - 1.0) < 1e-9


def test_a_fold_with_the_background_on_one_side_is_an_edge_on_the_table_not_a_seam() -> None:
    log = StepLog()
    assert regions_to_seams(tee(noise_m=0.0003), labels(-1, 0), DetectParams(), log, viewpoint=VIEWPOINT) == []
    assert log.counts["candidates"] == 1  # the fold was found, and dropped for its background side
    # the same cloud with both sides on the workpiece keeps it
    assert len(regions_to_seams(tee(0.0003), labels(1, 0), DetectParams(), StepLog(), viewpoint=VIEWPOINT)) == 1


def test_a_cloud_outside_the_working_range_is_refused_with_the_step() -> None:
    params = replace(DetectParams(), z_range_m=(0.1, 0.5))
    with pytest.raises(NoSeamFound, match="only 0 points left after the pass-through filter"):
        regions_to_seams(tee(), None, params, StepLog(), viewpoint=VIEWPOINT)


def test_lengths_scale_with_a_coarser_voxel_and_a_sparser_scan_only() -> None:
    sp = SeamParams()
    assert _scaled_to_data(sp, REFERENCE_VOXEL_M, 0.0) == sp
    assert _scaled_to_data(sp, 0.002, 0.0) == sp  # a finer voxel keeps the tuned lengths
    coarse = _scaled_to_data(sp, 0.006, 0.004)
    assert coarse.patch_radius_m == pytest.approx(2 * sp.patch_radius_m)
    assert coarse.refine_band_m == pytest.approx(0.016)  # 4 x 4 mm spacing over the 10 mm default
    assert coarse.support_bin_m == pytest.approx(0.0048) and coarse.max_hole_m == pytest.approx(0.012)


def cand(p0: list[float], p1: list[float], *, ra: tuple[int, ...] = (0,), rb: tuple[int, ...] = (1,), support=10):
    return _Cand("linear", np.array([p0, p1], dtype=float), ra, rb, np.array([0.0, 0.0, -1.0]),
                 np.array([-1.0, 0.0, 0.0]), 1e-4, support)  # fmt: skip


def test_pieces_of_one_line_are_joined_end_to_end_and_others_are_not() -> None:
    a = cand([0, 0, 0.6], [0, 0.04, 0.6], support=30)
    b = cand([0, 0.05, 0.6], [0, 0.09, 0.6], ra=(2,), rb=(3,))  # 10 mm further along, other regions
    far = cand([0, 0.2, 0.6], [0, 0.25, 0.6])  # 110 mm gap: a second seam
    off = cand([0.01, 0.0, 0.6], [0.01, 0.04, 0.6])  # 10 mm beside: another junction
    joined = _group_collinear([a, b, far, off], voxel_m=0.003)
    assert len(joined) == 3
    np.testing.assert_allclose(joined[0].line, [[0, 0, 0.6], [0, 0.09, 0.6]], atol=1e-12)
    assert (joined[0].regions_a, joined[0].regions_b, joined[0].support) == ((0, 2), (1, 3), 40)
    assert _covers(joined[0].line, b.line) and not _covers(joined[0].line, off.line)
    assert not _covers(a.line, far.line)  # along the line but past its end


def test_a_side_is_named_by_the_mask_most_of_its_voxels_carry() -> None:
    voxel_labels = np.array([-1, -1, -1, 4, 4, 7, 7, 7], dtype=np.int32)
    regions = np.array([0, 0, 0, 0, 0, 1, 1, 1], dtype=np.int32)
    assert _majority(voxel_labels, regions, (0,)) == -1  # three background voxels against two of mask 4
    assert _majority(voxel_labels, regions, (1,)) == 7
    assert _majority(voxel_labels, regions, (1,), avoid=7) == 7  # no other workpiece label: keep it
    # the other side of a fold where mask 7 bled over: its best label is 7 too, so it takes its best other one
    bled = np.array([7, 7, 7, 7, 4, 4, -1, -1, -1], dtype=np.int32)
    assert _majority(bled, np.zeros(9, dtype=np.int32), (0,), avoid=7) == 4  # the background never wins then
    assert _majority(voxel_labels, regions, (5,)) == -1  # no voxel of that region


def test_a_copy_lying_on_a_longer_seam_is_dropped_and_a_partial_overlap_extends_it() -> None:
    def geom(y0: float, y1: float, x: float = 0.0) -> SeamGeometry:
        nn = np.tile([0.0, 0.0, -1.0], (2, 1))
        return SeamGeometry("linear", "fillet", np.array([[x, y0, 0.6], [x, y1, 0.6]]), nn, -nn, (0, 1), (0, 1), 5, 0.0)

    long, inside, beyond, beside = geom(0.0, 0.08), geom(0.02, 0.05), geom(0.06, 0.095), geom(0.0, 0.08, x=0.01)
    (kept,) = _dedupe([inside, long])
    np.testing.assert_array_equal(kept.points, long.points)
    (kept,) = _dedupe([long, beyond])  # within 20 mm of the longer one's end: one seam covering both
    np.testing.assert_allclose(kept.points, [[0.0, 0.0, 0.6], [0.0, 0.095, 0.6]], atol=1e-12)
    assert len(_dedupe([long, beside])) == 2
