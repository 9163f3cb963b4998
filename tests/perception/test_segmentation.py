"""perception.segmentation: SurfaceMasks checks its labels against its prompts."""

from __future__ import annotations

import numpy as np
import pytest

from perception.errors import PerceptionError
from perception.segmentation import SurfaceMasks


def test_masks_hold_one_label_per_prompt() -> None:
    labels = np.array([[-1, 0, 0], [1, 1, -1]])
    masks = SurfaceMasks(labels, [[1.0, 0.0], [0.0, 1.0]], (0.9, 1.0))
    assert masks.count == 2 and masks.labels.dtype == np.int32 and masks.prompts_px.shape == (2, 2)
    np.testing.assert_array_equal(masks.mask(1), [[False, False, False], [True, True, False]])
    assert int(masks.mask(0).sum()) == 2


def test_inconsistent_masks_are_refused() -> None:
    with pytest.raises(PerceptionError, match=r"labels must be \(H, W\), got \(3,\)"):
        SurfaceMasks(np.zeros(3), np.zeros((1, 2)), (1.0,))
    with pytest.raises(PerceptionError, match="2 prompts but 1 scores"):
        SurfaceMasks(np.zeros((2, 2)), np.zeros((2, 2)), (1.0,))
    with pytest.raises(PerceptionError, match=r"label 2 has no prompt \(only 2 prompts\)"):
        SurfaceMasks(np.array([[0, 2]]), np.zeros((2, 2)), (1.0, 1.0))
