"""The capture's own noise: sigma(z) and the sample spacing measured from local plane residuals."""

from __future__ import annotations

import numpy as np
import pytest

from perception.errors import NoSeamFound
from perception.fine.noise import estimate_noise, local_planes

from .scenes import rendered, work


def test_noise_free_depth_measures_the_floor_and_the_pixel_angle() -> None:
    _p, lp, nm, _ = work("tee")
    assert nm.sigma_1m_m == pytest.approx(nm.floor_m)
    assert nm.pixel_angle_rad == pytest.approx(1 / 460.0, rel=0.02)
    # a flat face's local plane: normal exact, no residual
    res = rendered("tee")
    top = (res.part_index == 1) & (res.face_index >= 0)
    ok = top & np.isfinite(lp.variance)
    n_true = res.normals_camera[ok]
    same = res.face_index[ok] == np.bincount(res.face_index[top]).argmax()
    cos = np.einsum("ij,ij->i", lp.normal[ok][same], n_true[same])
    assert np.percentile(cos, 50) > np.cos(np.radians(0.05))


def test_stereo_noise_is_measured_as_the_residual_about_the_surfaces() -> None:
    p, _lp, nm, _ = work("tee", "stereo")
    res = rendered("tee", "stereo")
    # the truth: noisy points' distances from their exact surface (along its normal), over range squared
    ok = np.isfinite(p[..., 2]) & np.isfinite(res.depth_true_m)
    ray = p[ok] / np.linalg.norm(p[ok], axis=1, keepdims=True)
    n = res.normals_camera[ok]
    dz = (p[..., 2] - res.depth_true_m)[ok]
    normal_res = dz / ray[:, 2] * np.abs((n * ray).sum(axis=1))
    truth_1m = float(np.std(normal_res / p[..., 2][ok] ** 2))
    # the estimate takes the 30th percentile of local residuals: within a quarter of the overall truth
    assert nm.sigma_1m_m == pytest.approx(truth_1m, rel=0.25)
    assert float(nm.sigma_m(0.5)) == pytest.approx(nm.sigma_1m_m * 0.25)


def test_no_full_window_is_a_clear_error() -> None:
    p = np.full((20, 20, 3), np.nan)
    with pytest.raises(NoSeamFound, match="full window"):
        estimate_noise(p, local_planes(p, window_px=7))
