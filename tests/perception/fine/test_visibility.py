"""A seam is kept where both faces are seen at under 75 degrees (78 for a face that fits its surface within the
noise, except across a gap), in runs of at least 15 mm."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from perception.fine.types import NoiseModel, SeamCurve, Surface, SurfaceSet
from perception.fine.visibility import clip_to_view


def seam_along_x(normal_b: np.ndarray) -> SeamCurve:
    pts = np.array([[-0.2, 0.0, 0.5], [0.2, 0.0, 0.5]])
    na = np.tile([0.0, 0.0, -1.0], (2, 1))  # face a looks straight at the camera
    return SeamCurve("linear", "fillet", pts, na, np.tile(normal_b, (2, 1)), (0, 1), 100, 1e-4)


def test_the_seam_is_cut_where_face_b_turns_past_75_degrees() -> None:
    # face b's normal is +x: at a point x along the seam the ray to the camera is (-x, 0, -0.5), and the
    # incidence is under 75 degrees where -x / |(x, 0.5)| > cos 75, that is x < -0.5 cot(75 deg)
    (kept,) = clip_to_view([seam_along_x(np.array([1.0, 0.0, 0.0]))])
    x_cut = -0.5 / np.tan(np.radians(75.0))
    assert kept.points[:, 0].min() == pytest.approx(-0.2, abs=1e-9)
    assert kept.points[:, 0].max() == pytest.approx(x_cut, abs=0.0011)


def test_a_seam_whose_faces_are_all_grazing_is_dropped_and_a_short_run_too() -> None:
    assert clip_to_view([seam_along_x(np.array([0.0, 1.0, 0.0]))]) == []
    short = seam_along_x(np.array([0.0, 0.0, -1.0]))
    short = SeamCurve(short.kind, short.joint, short.points * [0.035, 1, 1], short.normals_a, short.normals_b,
                      short.surfaces, short.support, short.rms_m)  # fmt: skip
    assert clip_to_view([short]) == []  # 14 mm
    longer = replace(short, points=short.points * [16 / 14, 1, 1])
    assert len(clip_to_view([longer])) == 1  # 16 mm


def _surfaces(rms_b_m: float) -> tuple[SurfaceSet, NoiseModel]:
    a = Surface(0, "plane", np.array([0.0, 0.0, -1.0]), 0.5, 1e-4, 1000, np.array([0.0, 0.1, 0.5]), 0.5)
    b = Surface(1, "plane", np.array([1.0, 0.0, 0.0]), 0.0, rms_b_m, 1000, np.array([0.0, 0.0, 0.5]), 0.5)
    labels = np.zeros((4, 4), np.int32)
    return SurfaceSet(labels, 1, (a, b)), NoiseModel(sigma_1m_m=0.001, floor_m=1e-6, pixel_angle_rad=0.001)


@pytest.mark.parametrize(
    ("rms_b_m", "joint", "limit_deg"),
    [
        (0.00037, "fillet", 78.0),  # 1.48 sigma at 0.5 m (sigma 0.25 mm): a face, seen to 78 degrees
        (0.00038, "fillet", 75.0),  # 1.52 sigma: a grazing strip that does not fit its plane, cut at 75
        (0.00010, "butt", 75.0),  # a gap's seam never past 75 degrees, however well its faces fit
    ],
)
def test_a_face_that_fits_within_the_noise_counts_as_seen_to_78_degrees(rms_b_m: float, joint: str,
                                                                         limit_deg: float) -> None:  # fmt: skip
    surf, noise = _surfaces(rms_b_m)
    seam = replace(seam_along_x(np.array([1.0, 0.0, 0.0])), joint=joint)
    (kept,) = clip_to_view([seam], surf, noise)
    assert kept.points[:, 0].max() == pytest.approx(-0.5 / np.tan(np.radians(limit_deg)), abs=0.0011)
    (plain,) = clip_to_view([seam])  # without the surfaces and the noise: the 75-degree rule alone
    assert plain.points[:, 0].max() == pytest.approx(-0.5 / np.tan(np.radians(75.0)), abs=0.0011)
