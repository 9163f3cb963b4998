"""Two parallel tops a plate apart, grown into one surface, split in two; one noisy plane left whole."""

from __future__ import annotations

import numpy as np
import pytest


def _one_surface_of(p: np.ndarray) -> tuple[np.ndarray, list]:
    from perception.fine.surfaces import _fit_plane
    from perception.fine.types import Surface

    q = p.reshape(-1, 3)
    n, o, rms = _fit_plane(q)
    return np.zeros(p.shape[:2], np.int32), [Surface(0, "plane", n, o, rms, len(q), q.mean(axis=0), 0.8)]


def test_two_parallel_tops_a_plate_apart_are_split_and_one_noisy_plane_is_not() -> None:
    """A 5 mm plate lying on another, both tops grown into one surface (sigma 0.3 mm at 0.8 m): split into
    the two tops, 5 mm apart; one plane with the same noise stays one."""
    from perception.fine.parallel import split_parallel
    from perception.fine.surfaces import SurfaceParams
    from perception.fine.types import NoiseModel

    rng = np.random.default_rng(3)
    u, v = np.meshgrid(np.linspace(-0.1, 0.1, 120), np.linspace(-0.06, 0.06, 80))
    step = np.where(u > 0.02, 0.005, 0.0)  # the upper plate's top, nearer the camera
    sigma = 0.0003
    noise = NoiseModel(sigma_1m_m=sigma / 0.64, floor_m=1e-5, pixel_angle_rad=0.0012)
    for h, parts in ((step, 2), (np.zeros_like(u), 1)):
        z = 0.8 - h + rng.normal(0.0, sigma, u.shape)
        p = np.stack([u, v, z], axis=-1)
        labels, surfaces = _one_surface_of(p)
        normals = np.broadcast_to(np.array([0.0, 0.0, -1.0]), p.shape) + rng.normal(0.0, 0.01, p.shape)
        labels, out = split_parallel(p, labels, surfaces, normals, noise, min_pixels=SurfaceParams().min_pixels)
        assert len(out) == parts
        if parts == 2:
            lower, upper = sorted(out, key=lambda s: s.centroid[2], reverse=True)
            assert abs(float(upper.centroid @ lower.normal + lower.offset)) == pytest.approx(0.005, abs=2e-4)
            assert max(s.rms_m for s in out) < 1.2 * sigma
            assert np.count_nonzero(labels == upper.label) == np.count_nonzero(u > 0.02)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_thin_upper_plate_over_a_third_of_the_surface_is_split_at_its_true_height(seed: int) -> None:
    """A 2.5 mm plate (8 sigma) over 30% of one grown surface: a first split at the median heights cuts the
    larger lower plate in two, and alternating from it settled between the plates; the two-class split of the
    heights starts on the right plates, 2.5 mm apart."""
    from perception.fine.parallel import split_parallel
    from perception.fine.surfaces import SurfaceParams
    from perception.fine.types import NoiseModel

    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.linspace(-0.1, 0.1, 120), np.linspace(-0.06, 0.06, 80))
    sigma, upper_px = 0.0003, u > 0.04
    noise = NoiseModel(sigma_1m_m=sigma / 0.64, floor_m=1e-5, pixel_angle_rad=0.0012)
    p = np.stack([u, v, 0.8 - np.where(upper_px, 0.0025, 0.0) + rng.normal(0.0, sigma, u.shape)], axis=-1)
    labels, surfaces = _one_surface_of(p)
    normals = np.broadcast_to(np.array([0.0, 0.0, -1.0]), p.shape) + rng.normal(0.0, 0.01, p.shape)
    labels, out = split_parallel(p, labels, surfaces, normals, noise, min_pixels=SurfaceParams().min_pixels)
    assert len(out) == 2
    lower, upper = sorted(out, key=lambda s: s.centroid[2], reverse=True)
    assert abs(float(upper.centroid @ lower.normal + lower.offset)) == pytest.approx(0.0025, abs=2e-4)
    assert np.mean((labels == upper.label) == upper_px) > 0.99


@pytest.mark.parametrize("seed", [0, 1])
def test_plates_four_sigma_apart_split_as_two_regions_and_a_noisier_face_stays_whole(seed: int) -> None:
    """A 1.2 mm plate (4 sigma) over a third of one grown surface: one by one its heights overlap the lower
    plate's, but as two regions of the image (each pixel with most of its neighbours) they are two planes
    1.2 mm apart, told pixel for pixel. A face seen obliquely, twice as noisy as the capture's sigma at its
    range, split in two by its heights is salt and pepper: it stays one."""
    from perception.fine.parallel import split_parallel
    from perception.fine.surfaces import SurfaceParams
    from perception.fine.types import NoiseModel

    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.linspace(-0.1, 0.1, 120), np.linspace(-0.06, 0.06, 80))
    sigma, upper_px = 0.0003, u > 0.035
    noise = NoiseModel(sigma_1m_m=sigma / 0.64, floor_m=1e-5, pixel_angle_rad=0.0012)
    normals = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (*u.shape, 3)) + rng.normal(0.0, 0.01, (*u.shape, 3))
    p = np.stack([u, v, 0.8 - np.where(upper_px, 0.0012, 0.0) + rng.normal(0.0, sigma, u.shape)], axis=-1)
    labels, surfaces = _one_surface_of(p)
    labels, out = split_parallel(p, labels, surfaces, normals, noise, min_pixels=SurfaceParams().min_pixels)
    assert len(out) == 2
    lower, upper = sorted(out, key=lambda s: s.centroid[2], reverse=True)
    assert abs(float(upper.centroid @ lower.normal + lower.offset)) == pytest.approx(0.0012, abs=1e-4)
    assert np.mean((labels == upper.label) == upper_px) > 0.995

    p = np.stack([u, v, 0.8 + rng.normal(0.0, 2.0 * sigma, u.shape)], axis=-1)
    labels, surfaces = _one_surface_of(p)
    labels, out = split_parallel(p, labels, surfaces, normals, noise, min_pixels=SurfaceParams().min_pixels)
    assert len(out) == 1


def test_two_tops_fitted_as_one_on_a_widened_inlier_band_are_still_split() -> None:
    """Zoo dev lap 46 (a 6 mm plate on another, seen frontally so that its edge face ramps the two tops into
    one patch): the patch's fit took its inliers within a scale the two layers widened, and reported their
    rms (0.68 mm, a little over twice sigma) as the one plane's. Each top's own rms (up to 0.6 mm with the edge's
    ramp) is not under 0.7 of that, and the split was refused; measured on all the surface's points the one
    plane misfits by half the step, and the tops are split."""
    from perception.fine.parallel import split_parallel
    from perception.fine.surfaces import SurfaceParams
    from perception.fine.types import NoiseModel, Surface

    rng = np.random.default_rng(5)
    u, v = np.meshgrid(np.linspace(-0.1, 0.1, 120), np.linspace(-0.06, 0.06, 80))
    sigma = 0.0003
    h = np.where(u > 0.0, 0.006, 0.0) + np.clip((u + 0.002) / 0.004, 0.0, 1.0) * 0.006 * (np.abs(u) < 0.002)
    z = 0.8 - np.maximum(h, np.where(u > 0.0, 0.006, 0.0)) + rng.normal(0.0, 1.6 * sigma, u.shape)
    p = np.stack([u, v, z], axis=-1)
    q = p.reshape(-1, 3)
    noise = NoiseModel(sigma_1m_m=sigma / 0.64, floor_m=1e-5, pixel_angle_rad=0.0012)
    # the one plane through both tops, with the rms of a fit on an inlier band the layers widened
    one = Surface(0, "plane", np.array([0.0, 0.0, -1.0]), 0.797, 0.00068, len(q), q.mean(axis=0), 0.8)
    normals = np.broadcast_to(np.array([0.0, 0.0, -1.0]), p.shape) + rng.normal(0.0, 0.01, p.shape)
    _, out = split_parallel(p, np.zeros(p.shape[:2], np.int32), [one], normals, noise,
                            min_pixels=SurfaceParams().min_pixels)  # fmt: skip
    assert len(out) == 2
    lower, upper = sorted(out, key=lambda s: s.centroid[2], reverse=True)
    assert abs(float(upper.centroid @ lower.normal + lower.offset)) == pytest.approx(0.006, abs=3e-4)
