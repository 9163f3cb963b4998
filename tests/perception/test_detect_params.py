"""perception.detect_params: the detector's settings and the log its steps write."""

from __future__ import annotations

import math
import time

import pytest

from perception.detect import DetectParams as DetectParamsOfDetect
from perception.detect import StepLog as StepLogOfDetect
from perception.detect_params import DetectParams, StepLog


def test_a_step_s_time_adds_up_over_repeats_and_is_kept_when_it_raises() -> None:
    log = StepLog()
    for _ in range(2):
        with log.step("voxel"):
            time.sleep(0.01)
    with pytest.raises(RuntimeError), log.step("fit"):
        time.sleep(0.01)
        raise RuntimeError("a step that fails")
    assert set(log.timing_s) == {"voxel", "fit"}
    assert 0.02 <= log.timing_s["voxel"] < 0.5 and 0.01 <= log.timing_s["fit"] < 0.5
    assert log.counts == {} and log.voxel_planes == {}


def test_the_defaults_are_the_tuned_ones_in_si_units_and_the_detector_offers_the_same_types() -> None:
    p = DetectParams()
    assert (p.method, p.voxel_m, p.knn, p.normal_radius_voxels, p.roi_band_m) == ("surfaces", 0.003, 16, 2.5, 0.010)
    assert p.z_range_m == (0.1, 3.0) and p.workspace_min_m is None and p.crop
    assert p.seams.max_coplanar_rad == pytest.approx(math.radians(8.0))
    assert p.regions.max_angle_rad == pytest.approx(math.radians(12.0))
    assert DetectParamsOfDetect is DetectParams and StepLogOfDetect is StepLog
