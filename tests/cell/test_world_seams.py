"""cell.world_seams: seams of several captures in the world frame, merged once, and selected."""

from __future__ import annotations

import numpy as np
import pytest

from cell.errors import ConfigError
from cell.world_seams import SeamFilter, WorldSeam, X_world_base, merge_seams, seam_overlap_m, world_seams
from tests.cell.planning_helpers import make_seam


def test_crossing_or_touching_seams_are_not_merged() -> None:
    a = world_seams([make_seam(0, (0.0, 0.0, 0.0), (0.3, 0.0, 0.0))])[0]
    crossing = world_seams([make_seam(1, (0.15, -0.1, 0.0), (0.15, 0.1, 0.0))])[0]
    continuing = world_seams([make_seam(2, (0.3, 0.0, 0.0), (0.5, 0.0, 0.0))])[0]  # shares only an end point
    assert len(merge_seams([a, crossing, continuing], tol_m=0.003, min_overlap_m=0.02)) == 3


def test_capture_ids_are_offset_per_capture() -> None:
    seams = world_seams([make_seam(3, (0.5, 0, 0), (0.6, 0, 0))], capture_index=2, track_position_m=0.25)
    assert seams[0].id == 2003 and seams[0].sources == ((2, 3),)
    np.testing.assert_allclose(seams[0].points_world[0], [0.5, 0.25, 0.0])


def test_world_is_the_base_with_the_carriage_at_zero() -> None:
    X = X_world_base(0.25, (0.0, 1.0, 0.0))
    np.testing.assert_array_equal(X, [[1, 0, 0, 0], [0, 1, 0, 0.25], [0, 0, 1, 0], [0, 0, 0, 1]])
    # a base-frame seam seen with the carriage at -0.1 m along x lies 0.1 m further along -x in world
    (seam,) = world_seams([make_seam(0, (0.5, 0.0, 0.0), (0.5, 0.2, 0.0))], track_position_m=-0.1, axis_base=(1, 0, 0))
    np.testing.assert_allclose(seam.points_world[[0, -1]], [[0.4, 0.0, 0.0], [0.4, 0.2, 0.0]], atol=1e-15)
    np.testing.assert_allclose(seam.X_world_torch[:, :3, 3], seam.points_world, atol=1e-15)
    assert seam.length_m == pytest.approx(0.2, abs=1e-15)


def test_reversed_runs_the_other_way_with_the_torch_axis_kept() -> None:
    (seam,) = world_seams([make_seam(5, (0.0, 0.0, 0.0), (0.1, 0.0, 0.0))])
    back = seam.reversed()
    np.testing.assert_array_equal(back.points_world, seam.points_world[::-1])
    np.testing.assert_allclose(back.X_world_torch[:, :3, 0], -seam.X_world_torch[::-1, :3, 0], atol=1e-15)
    np.testing.assert_allclose(back.X_world_torch[:, :3, 1], -seam.X_world_torch[::-1, :3, 1], atol=1e-15)
    np.testing.assert_array_equal(back.X_world_torch[:, :3, 2], seam.X_world_torch[::-1, :3, 2])
    assert (back.id, back.kind, back.sources) == (5, "linear", ((0, 5),))


def test_a_world_seam_is_checked_by_the_seam_rule() -> None:
    good = world_seams([make_seam(1, (0.0, 0.0, 0.0), (0.1, 0.0, 0.0))])[0]
    with pytest.raises(ValueError, match=r"seam 7: points_world must be \(N>=2, 3\), got \(1, 3\)"):
        WorldSeam(7, "linear", good.points_world[:1], good.X_world_torch[:1], 0.9, ())
    with pytest.raises(ValueError, match=r"seam 7: X_world_torch must be \(21, 4, 4\), got \(20, 4, 4\)"):
        WorldSeam(7, "linear", good.points_world, good.X_world_torch[1:], 0.9, ())
    bad = good.points_world.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="seam 7: points_world or X_world_torch contain NaN or inf"):
        WorldSeam(7, "linear", bad, good.X_world_torch, 0.9, ())


def test_the_seam_filter_says_why_a_seam_is_skipped() -> None:
    short, long_curved = world_seams(
        [make_seam(1, (0.6, 0.0, 0.0), (0.6, 0.02, 0.0)), make_seam(2, (0.7, 0.0, 0.0), (0.7, 0.2, 0.0), kind="curved")]
    )
    assert SeamFilter(min_length_m=0.05).reason_to_skip(short) == "length 0.0200 m below min_length_m 0.0500 m"
    assert SeamFilter(min_length_m=0.05).reason_to_skip(long_curved) is None
    assert SeamFilter(ids=frozenset({2})).reason_to_skip(short) == "id 1 not in the selected ids [2]"
    assert SeamFilter(kinds=frozenset({"linear"})).reason_to_skip(long_curved) == (
        "kind 'curved' not in the selected kinds ['linear']"
    )
    with pytest.raises(ConfigError, match="min_length_m must be a finite number >= 0, got -1"):
        SeamFilter(min_length_m=-1.0)


def test_overlap_is_measured_along_the_other_seam_within_the_tolerance() -> None:
    (a,) = world_seams([make_seam(0, (0.0, 0.0, 0.0), (0.3, 0.0, 0.0), step_m=0.01)])
    # b: 0.2 m long, its first 0.1 m beside a (1 mm away), the rest beyond a's end
    (b,) = world_seams([make_seam(1, (0.2, 0.001, 0.0), (0.4, 0.001, 0.0), step_m=0.01)])
    assert seam_overlap_m(a, b, tol_m=0.002) == pytest.approx(0.1, abs=1e-12)
    assert seam_overlap_m(a, b, tol_m=0.0005) == 0.0
    (merged,) = merge_seams([a, b], tol_m=0.002, min_overlap_m=0.05)
    assert merged.id == 0 and merged.sources == ((0, 0), (0, 1))
    assert merged.points_world[0, 0] == 0.0 and merged.points_world[-1, 0] == pytest.approx(0.4, abs=1e-12)
