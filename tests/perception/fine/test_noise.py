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


def test_local_planes_of_a_tilted_plane_and_a_fold_against_their_exact_geometry() -> None:
    """A plane z = 0.5 + 0.2 x - 0.1 y sampled every millimetre: every full window's normal is the plane's to
    rounding and its residual variance zero; within the window's half of the border and at invalid pixels,
    nothing; where the windows straddle a fold (the plane turning 45 degrees), the variance grows."""
    h, w = 20, 30
    y, x = np.mgrid[:h, :w] * 0.001
    z = 0.5 + 0.2 * x - 0.1 * y
    p = np.stack([x, y, z], axis=-1)
    p[10, 12] = np.nan
    lp = local_planes(p, window_px=5)
    n_true = np.array([0.2, -0.1, -1.0]) / np.linalg.norm([0.2, -0.1, -1.0])  # towards the camera (z < 0)
    inner = np.zeros((h, w), bool)
    inner[2:-2, 2:-2] = True
    inner[10, 12] = False
    full = inner & (lp.count == 25)
    assert np.abs(lp.normal[inner] - n_true).max() < 1e-9
    assert np.abs(lp.variance[full]).max() < 1e-15
    assert np.isnan(lp.normal[~inner]).all() and np.isnan(lp.variance[~inner]).all()
    assert lp.count[10, 12] == 25 - 1 and lp.count[0, 0] == 9  # a corner's window holds 3 x 3 of its points
    folded = p.copy()
    folded[..., 2] = np.where(x < 0.015, z, z + (x - 0.015))  # the slope along x turns from 0.2 to 1.2
    folded[10, 12] = np.nan
    lf = local_planes(folded, window_px=5)
    assert (lf.variance[5:15, 13:17] > 1e-10).all() and np.nanmax(lf.variance[5:15, 2:11]) < 1e-15


def _numpy_local_planes(points, *, window_px):  # type: ignore[no-untyped-def]
    """local_planes as NumPy computed it on whole planes until 2026-12-08 (the reference)."""
    import cv2

    p = np.asarray(points, dtype=np.float64)
    valid = np.isfinite(p[..., 2])
    ref = np.array([np.nanmedian(p[..., k][valid]) for k in range(3)])
    qx, qy, qz = (np.where(valid, p[..., k] - ref[k], 0.0) for k in range(3))

    def box(img):  # type: ignore[no-untyped-def]
        return cv2.boxFilter(img, cv2.CV_64F, (window_px, window_px), normalize=False, borderType=cv2.BORDER_CONSTANT)

    n = box(valid.astype(np.float64))
    nn = np.maximum(n, 1.0)
    mx, my, mz = box(qx) / nn, box(qy) / nn, box(qz) / nn
    st = max(1, window_px // 2)
    du, dv = [], []
    for c in (mx, my, mz):
        du.append(np.full_like(c, np.nan))
        dv.append(np.full_like(c, np.nan))
        du[-1][:, st:-st] = c[:, 2 * st :] - c[:, : -2 * st]
        dv[-1][st:-st, :] = c[2 * st :, :] - c[: -2 * st, :]
    nx = du[1] * dv[2] - du[2] * dv[1]
    ny = du[2] * dv[0] - du[0] * dv[2]
    nz = du[0] * dv[1] - du[1] * dv[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / norm, ny / norm, nz / norm
    with np.errstate(invalid="ignore"):
        flip = np.einsum("hwk,hwk->hw", np.stack([nx, ny, nz], axis=-1), p) > 0
    for c in (nx, ny, nz):
        np.negative(c, out=c, where=flip)
    cxx, cxy, cxz = box(qx * qx) / nn - mx**2, box(qx * qy) / nn - mx * my, box(qx * qz) / nn - mx * mz
    cyy, cyz, czz = box(qy * qy) / nn - my**2, box(qy * qz) / nn - my * mz, box(qz * qz) / nn - mz**2
    var = nx * nx * cxx + ny * ny * cyy + nz * nz * czz + 2 * (nx * ny * cxy + nx * nz * cxz + ny * nz * cyz)
    total = np.maximum(cxx + cyy + czz, 1e-30)
    var = np.clip(var, 0.0, None)
    few = (n < 0.5 * window_px * window_px) | ~valid | ~np.isfinite(var)
    var[few] = np.nan
    normal = np.stack([np.where(few, np.nan, c) for c in (nx, ny, nz)], axis=-1)
    return n, normal, var, var / total


def test_the_compiled_local_planes_are_the_numpy_ones_on_a_noisy_capture() -> None:
    p, _lp, _nm, _ = work("tee", "stereo")
    for step, window in ((1, 7), (3, 7), (2, 5)):
        q = np.ascontiguousarray(p[::step, ::step])
        got = local_planes(q, window_px=window)
        want = _numpy_local_planes(q, window_px=window)
        for a, b in zip((got.count, got.normal, got.variance, got.variation), want, strict=True):
            assert np.array_equal(a, b, equal_nan=True)


def test_local_planes_on_two_threads_are_the_same_planes() -> None:
    """The two halves of the image on two threads, each with the rows its planes read beyond it: the same counts
    and normals, and the same variances to rounding (OpenCV's box sums run down from each half's first row,
    so their last bits differ); the same with a half too short to split (one thread)."""
    p, _lp, _nm, _ = work("tee", "stereo")
    for step, window in ((1, 7), (2, 5), (3, 3)):
        q = np.ascontiguousarray(p[::step, ::step])
        one, two = local_planes(q, window_px=window), local_planes(q, window_px=window, threads=2)
        assert np.array_equal(one.count, two.count) and np.array_equal(one.normal, two.normal, equal_nan=True)
        for a, b in ((one.variance, two.variance), (one.variation, two.variation)):
            assert np.array_equal(np.isnan(a), np.isnan(b))
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-18, equal_nan=True)
    small = np.ascontiguousarray(p[:40])
    assert np.array_equal(local_planes(small, window_px=7, threads=2).variance,
                          local_planes(small, window_px=7).variance, equal_nan=True)  # fmt: skip
