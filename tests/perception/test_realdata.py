"""The detector on the real scans in ../shared/realdata: it must run without errors (a clear
NoSeamFound is an answer, a traceback is not). Skipped when the folder is absent."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from perception.capture import read_point_cloud
from perception.detect import DetectParams, detect, detect_cloud
from perception.errors import NoSeamFound

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
pytestmark = [
    pytest.mark.realdata,
    pytest.mark.skipif(not REALDATA.is_dir(), reason="../shared/realdata is not present"),
]
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))


def test_structured_light_frame_converts_with_its_documented_numbers() -> None:
    from realdata import xiaoyu_capture

    cap = xiaoyu_capture(REALDATA)
    # SOURCES.md: 2048 x 1536, fx = fy = 1991.94, cx 713.5, cy 761.3, median depth 676 mm, 85% valid
    assert cap.shape == (1536, 2048)
    assert cap.intrinsics.fx == pytest.approx(1991.9388)
    assert (cap.intrinsics.cx, cap.intrinsics.cy) == pytest.approx((713.5279, 761.3322))
    z = cap.depth_m[np.isfinite(cap.depth_m)]
    assert np.median(z) == pytest.approx(0.676, abs=0.01)
    assert z.size / cap.depth_m.size == pytest.approx(0.85, abs=0.03)
    for c in (cap, replace(cap, prompts_px=None)):
        try:
            res = detect(c, DetectParams())
        except NoSeamFound as err:
            assert "no seam found" in str(err)
        else:
            assert all(np.isfinite(s.points).all() for s in res.seams)


@pytest.mark.parametrize(
    "rel",
    [
        "thillRobot_seam_detection/table_8in10in_tee_x4y24_45.pcd",
        "pengrui-rio_welding-robot/Thu_Apr_2_10_14_30_3_frame.pcd",
        "blackhorsewu_CoboWeld/barpoints.pcd",
        "abhinand4as_weld_seam_ros2/lap_joint_base_frame.pcd",
    ],
)
def test_clouds_run_without_errors(rel: str) -> None:
    path = REALDATA / rel
    if not path.exists():
        pytest.skip(f"{rel} missing")
    cloud = read_point_cloud(path)
    assert len(cloud.points) > 1000
    try:
        res = detect_cloud(cloud, DetectParams())
    except NoSeamFound as err:
        assert "no seam found" in str(err)
    else:
        for s in res.seams:
            assert np.isfinite(s.points).all()
            # a seam found in a cloud lies within the cloud's bounds
            assert (s.points >= cloud.points.min(axis=0) - 0.01).all()
            assert (s.points <= cloud.points.max(axis=0) + 0.01).all()
