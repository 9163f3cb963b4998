"""perception.evaluate: distances to polylines and the scoring of detected seams, against exact geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from perception.capture import GroundTruthSeam
from perception.evaluate import evaluate_seams, joint_names, point_to_polyline_distance, resample_polyline


def test_distance_to_a_polyline_is_to_its_nearest_segment_clamped_at_the_ends() -> None:
    line = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    pts = np.array([[0.5, 0.3, 0.0], [-0.3, 0.4, 0.0], [1.2, 0.5, 0.0], [1.0, 1.0, 2.0], [0.5, 0.0, 0.0]])
    np.testing.assert_allclose(point_to_polyline_distance(pts, line), [0.3, 0.5, 0.2, 2.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(point_to_polyline_distance(pts[:2], line[:1]), [math.hypot(0.5, 0.3), 0.5])


def test_resample_puts_points_evenly_along_the_polyline() -> None:
    line = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.3, 0.1, 0.0]])
    out = resample_polyline(line, 0.1)
    np.testing.assert_allclose(out, [[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.3, 0, 0], [0.3, 0.1, 0]], atol=1e-15)
    np.testing.assert_array_equal(resample_polyline(np.zeros((2, 3)), 0.1), np.zeros((1, 3)))


def test_scores_count_found_false_and_covered_seams_with_their_errors() -> None:
    truth = (
        GroundTruthSeam("linear", np.array([[0.0, 0.0, 0.5], [0.1, 0.0, 0.5]])),
        GroundTruthSeam("linear", np.array([[0.0, 0.1, 0.5], [0.1, 0.1, 0.5]])),
    )
    x = np.linspace(0.0, 0.05, 51)
    half_of_first = np.column_stack([x, np.full_like(x, 0.001), np.full_like(x, 0.5)])  # 1 mm off, half its length
    far_away = np.array([[0.5, 0.5, 0.5], [0.6, 0.5, 0.5]])
    report = evaluate_seams([half_of_first, far_away], truth)
    assert (report.n_truth, report.n_detected, report.n_found, report.false_seams) == (2, 2, 1, (1,))
    first, second = report.seams
    assert first.found and first.detected_ids == (0,) and first.n_points == 51
    assert first.rmse_m == pytest.approx(0.001, abs=1e-12) and first.max_m == pytest.approx(0.001, abs=1e-12)
    # covered within 3 mm: the first 53 of the 101 one-millimetre samples (0 .. 52 mm)
    assert first.coverage == pytest.approx(53 / 101, abs=1e-12)
    assert not second.found and math.isnan(second.rmse_m) and second.coverage == 0.0
    assert report.coverage == pytest.approx(0.5 * 53 / 101, abs=1e-12)  # length-weighted, equal lengths
    doc = report.to_json()
    assert (doc["found"], doc["false_seams"], doc["rmse_mm"], doc["seams"][1]["rmse_mm"]) == (1, 1, 1.0, None)
    assert not report.all_found


def test_a_detection_past_the_seen_run_is_matched_on_the_whole_seam_and_measured_to_it() -> None:
    # the whole seam runs 0 .. 200 mm along x; this shot counts 0 .. 40 mm as seen
    whole = np.array([[0.0, 0.0, 0.5], [0.2, 0.0, 0.5]])
    truth = (GroundTruthSeam("linear", np.array([[0.0, 0.0, 0.5], [0.04, 0.0, 0.5]])),)
    x = np.linspace(0.0, 0.2, 201)
    along_whole = np.column_stack([x, np.full_like(x, 0.0005), np.full_like(x, 0.5)])  # 0.5 mm off, all of it
    beside = np.column_stack([x[100:], np.full_like(x[100:], 0.001), np.full_like(x[100:], 0.5)])  # never reaches
    plain = evaluate_seams([along_whole, beside], truth)
    assert plain.n_found == 0 and plain.false_seams == (0, 1)  # median 80 mm from the seen run
    report = evaluate_seams([along_whole, beside], truth, whole_camera=[whole])
    assert report.n_found == 1 and report.seams[0].detected_ids == (0,) and report.false_seams == (1,)
    assert report.seams[0].coverage == 1.0
    assert report.rmse_m == pytest.approx(0.0005, abs=1e-12) and report.max_m == pytest.approx(0.0005, abs=1e-12)
    with pytest.raises(ValueError, match="whole_camera has 2 seams for 1"):
        evaluate_seams([along_whole], truth, whole_camera=[whole, whole])


def test_a_seam_seen_in_two_runs_and_detected_whole_is_found_in_both_its_errors_counted_once() -> None:
    # the whole seam runs 0 .. 200 mm along x; something in front hides 80 .. 150 mm, so the shot counts two
    # runs as seen; one detection runs all along it (0.5 mm off), another lies on a different seam
    whole = np.array([[0.0, 0.0, 0.5], [0.2, 0.0, 0.5]])
    other = np.array([[0.0, 0.1, 0.5], [0.2, 0.1, 0.5]])
    truth = (GroundTruthSeam("linear", np.array([[0.0, 0.0, 0.5], [0.08, 0.0, 0.5]])),
             GroundTruthSeam("linear", np.array([[0.15, 0.0, 0.5], [0.2, 0.0, 0.5]])),
             GroundTruthSeam("linear", other[:, :]))  # fmt: skip
    x = np.linspace(0.0, 0.2, 201)
    along_whole = np.column_stack([x, np.full_like(x, 0.0005), np.full_like(x, 0.5)])
    report = evaluate_seams([along_whole], truth, whole_camera=[whole, whole, other])
    assert report.n_found == 2 and report.false_seams == ()
    first, second, third = report.seams
    assert first.detected_ids == second.detected_ids == (0,) and not third.found
    assert first.coverage == second.coverage == 1.0
    assert report.n_points == 201 and report.rmse_m == pytest.approx(0.0005, abs=1e-12)
    # without the whole seams only the run nearer in median takes it
    assert evaluate_seams([along_whole], truth).n_found == 0


def test_a_found_seam_is_named_right_only_when_every_detection_on_it_names_its_joint() -> None:
    from types import SimpleNamespace

    truth = ["fillet", "inside_corner", "lap", "butt"]
    rows = [SimpleNamespace(index=0, detected_ids=(0,)), SimpleNamespace(index=1, detected_ids=(1, 2)),
            SimpleNamespace(index=2, detected_ids=(3,)), SimpleNamespace(index=3, detected_ids=())]  # fmt: skip
    joints = ["fillet", "inside_corner", "fillet", "fillet"]
    # seam 1 is found in two pieces, one of them misnamed; seam 3 was not found: not counted either way
    out = joint_names(rows, [True, True, True, False], truth, joints)
    assert out == (1, ["inside_corner as fillet+inside_corner", "lap as fillet"])
