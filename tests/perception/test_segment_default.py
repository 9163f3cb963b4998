"""perception.segment_default: the weight-free segmenter, automatic prompts and the seam band, on organized clouds
built from a pinhole camera (160 x 120 px, f = 100 px) looking at planes whose boundaries are known exactly."""

from __future__ import annotations

import numpy as np
import pytest

from perception.errors import PerceptionError
from perception.segment_default import (
    GraphSegmenter,
    _component_at,
    _factor,
    auto_prompts,
    seam_roi,
)

W, H, F, CX, CY = 160, 120, 100.0, 79.5, 59.5


def rays() -> np.ndarray:
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    return np.dstack([(u - CX) / F, (v - CY) / F, np.ones((H, W))])


def valley() -> np.ndarray:
    """Two planes meeting in a concave fold along the image's centre column: z = 0.6 + x left of it, z = 0.6 - x
    right of it (each ray d meets them at depth 0.6 / (1 -+ d_x))."""
    d = rays()
    depth = np.where(d[..., 0] < 0, 0.6 / (1.0 - d[..., 0]), 0.6 / (1.0 + d[..., 0]))
    return (d * depth[..., None]).astype(np.float32)


def plate_on_table() -> np.ndarray:
    """A table 0.6 m away filling the view and a plate 20 mm thick on it covering pixels u 50..109, v 30..89."""
    d = rays()
    depth = np.full((H, W), 0.6)
    depth[30:90, 50:110] = 0.58
    return (d * depth[..., None]).astype(np.float32)


GRAY = np.full((H, W, 3), 128, dtype=np.uint8)


def test_the_work_step_keeps_at_least_the_work_width() -> None:
    assert [_factor(w, 640) for w in (160, 640, 960, 1280, 1920)] == [1, 1, 1, 2, 3]


def test_a_prompt_names_its_patch_or_the_nearest_one_within_the_search_window() -> None:
    comp = np.zeros((10, 10), dtype=np.int32)
    comp[:, :4] = 1
    comp[:, 7:] = 2
    assert _component_at(comp, 1.0, 5.0, search=2) == 1
    assert _component_at(comp, 5.4, 5.0, search=2) == 1  # on the edge band: column 3 is nearer than 7
    assert _component_at(comp, 5.6, 5.0, search=2) == 2
    assert _component_at(comp, 20.0, -3.0, search=2) == 2  # clamped into the image first
    assert _component_at(np.zeros((10, 10), dtype=np.int32), 5.0, 5.0, search=2) == 0


def test_the_two_faces_of_a_fold_meet_at_the_fold() -> None:
    masks = GraphSegmenter().segment(GRAY, valley()[..., 2], np.array([[30.0, 60.0], [130.0, 60.0]]),
                                     points_camera=valley())  # fmt: skip
    assert masks.scores == (1.0, 1.0)
    labels = masks.labels
    assert np.all(labels[5:-5, 10:75] == 0) and np.all(labels[5:-5, 85:-10] == 1)
    for row in labels[10:-10]:
        first_right = int(np.argmax(row == 1))
        assert abs(first_right - 80) <= 2  # the fold is between columns 79 and 80


def test_two_prompts_on_one_patch_are_split_by_the_watershed_and_say_so() -> None:
    table = plate_on_table()
    masks = GraphSegmenter().segment(GRAY, table[..., 2], np.array([[60.0, 60.0], [100.0, 60.0]]), points_camera=table)
    assert masks.scores == (0.8, 0.8)
    assert masks.labels[60, 60] == 0 and masks.labels[60, 100] == 1


def test_the_segmenter_needs_the_organized_cloud() -> None:
    with pytest.raises(PerceptionError, match="needs the organized cloud"):
        GraphSegmenter().segment(GRAY, plate_on_table()[..., 2], np.array([[60.0, 60.0]]))


def test_automatic_prompts_find_the_plate_and_not_the_table_it_stands_on() -> None:
    prompts = auto_prompts(plate_on_table())
    # every prompt is on the plate (u 50..109, v 30..89), none on the table around it; the plate's interior gets
    # one at its most interior pixel, the middle. (The sharp synthetic step also leaves a 1 px ring just inside
    # the plate's outline as a patch of its own, between the normals' edge bands: it gets the other prompt.)
    assert np.all((prompts[:, 0] >= 50) & (prompts[:, 0] <= 109) & (prompts[:, 1] >= 30) & (prompts[:, 1] <= 89))
    assert np.any(np.all(np.abs(prompts - [79.5, 59.5]) <= 1.0, axis=1))
    assert len(prompts) == 2


def test_the_seam_band_is_where_two_masks_dilated_by_the_band_overlap() -> None:
    labels = np.full((60, 100), -1, dtype=np.int32)
    labels[:, :50] = 0
    labels[:, 50:] = 1
    labels[:5, :5] = 2  # a corner patch: it touches mask 0 only
    roi = seam_roi(labels, band_px=4, work_factor=1)
    cols = np.flatnonzero(roi.mask[30])
    assert (cols[0], cols[-1]) == (46, 53)  # 4 px dilation on each side of the boundary between 49 and 50
    assert np.all(roi.mask[10:, 46:54]) and not roi.mask[10:, :46].any() and not roi.mask[10:, 54:].any()
    assert roi.pairs[(0, 1)] == 8 * 60 and (1, 2) not in roi.pairs and roi.band_px == 4
    assert (0, 2) in roi.pairs
    # a pair sharing fewer band pixels than min_pair_px does not count
    assert (0, 2) not in seam_roi(labels, band_px=4, work_factor=1, min_pair_px=200).pairs
