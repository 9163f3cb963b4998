"""perception.butt: a butt joint between two plates in one plane, found at the exact centre of an exact gap."""

from __future__ import annotations

import numpy as np
import pytest

from perception.butt import butt_from_surfaces
from perception.seamfit import SeamParams

VIEWPOINT = np.zeros(3)  # the camera, 0.5 m above the plates (camera frame: the plates lie at z = 0.5)


def plates(gap_m: float, *, step_m: float = 0.0005) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Two plates at z = 0.5 m either side of a gap centred on x = 0, sampled every ``step_m`` in x (pixel
    centres a quarter step off the edges, so the last pixel on a plate is half a step short of its edge) and
    every 1 mm in y from -20 to 20 mm; the scanlines are the rows of constant y, in pixel order."""
    x = np.arange(-0.03 + step_m / 2, 0.03, step_m)
    x = x[np.abs(x) > gap_m / 2]
    rows = [np.column_stack([x, np.full_like(x, y), np.full_like(x, 0.5)]) for y in np.arange(-0.02, 0.0205, 0.001)]
    cloud = np.vstack(rows)
    return cloud[cloud[:, 0] < 0], cloud[cloud[:, 0] > 0], rows


def test_the_seam_is_the_mid_line_of_the_gap_and_its_width_is_exact() -> None:
    pa, pb, scanlines = plates(0.002)
    found = butt_from_surfaces(pa, pb, scanlines, SeamParams(), VIEWPOINT)
    assert found is not None
    ends, normal, rms, gap = found
    assert gap == pytest.approx(0.002, abs=1e-12) and rms < 1e-12
    np.testing.assert_allclose(normal, [0.0, 0.0, -1.0], atol=1e-12)  # towards the camera
    # the ends: the extent of the scanlines less end_trim_m (2 mm) at each end, on x = 0 in the plates' plane
    np.testing.assert_allclose(sorted(ends[:, 1]), [-0.018, 0.018], atol=1e-12)
    np.testing.assert_allclose(ends[:, [0, 2]], [[0.0, 0.5], [0.0, 0.5]], atol=1e-12)


def test_a_callable_gives_the_scanlines_only_when_needed_and_no_gap_is_no_butt_joint() -> None:
    pa, pb, scanlines = plates(0.003)
    found = butt_from_surfaces(pa, pb, lambda: scanlines, SeamParams(), VIEWPOINT)
    assert found is not None and found[3] == pytest.approx(0.003, abs=1e-12)
    # plates touching (no gap wider than the sampling): not a butt joint
    pa, pb, scanlines = plates(0.0)
    assert butt_from_surfaces(pa, pb, scanlines, SeamParams(), VIEWPOINT) is None
    # a gap wider than max_gap_m (5 mm): not a butt joint either
    pa, pb, scanlines = plates(0.007)
    assert butt_from_surfaces(pa, pb, scanlines, SeamParams(), VIEWPOINT) is None
    # a step of 10 mm between the plates: not in one plane
    pa, pb, scanlines = plates(0.002)
    assert butt_from_surfaces(pa, pb + np.array([0.0, 0.0, 0.01]), scanlines, SeamParams(), VIEWPOINT) is None
