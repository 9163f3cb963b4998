"""The fine stage's value types (perception/fine/types.py): the noise model's numbers and the surfaces' residuals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from perception.fine.types import NoiseModel, Surface


def test_the_noise_model_grows_with_the_square_of_range_above_its_floor() -> None:
    noise = NoiseModel(sigma_1m_m=0.002, floor_m=0.0005, pixel_angle_rad=0.001)
    z = np.array([0.25, 0.5, 1.0, 2.0])
    # 0.002 z^2: 0.000125 (under the floor), 0.0005 (at it), 0.002, 0.008
    assert noise.sigma_m(z) == pytest.approx([0.0005, 0.0005, 0.002, 0.008], abs=1e-15)
    assert float(noise.sigma_m(1.5)) == pytest.approx(0.0045, abs=1e-15)
    assert noise.spacing_m(z) == pytest.approx([0.00025, 0.0005, 0.001, 0.002], abs=1e-15)


@pytest.mark.parametrize("name", ["sigma_1m_m", "floor_m", "pixel_angle_rad"])
@pytest.mark.parametrize("bad", [0.0, -1e-3, math.nan, math.inf])
def test_a_noise_model_with_a_field_not_a_positive_number_is_refused(name: str, bad: float) -> None:
    good = {"sigma_1m_m": 0.002, "floor_m": 0.0005, "pixel_angle_rad": 0.001}
    with pytest.raises(ValueError, match=rf"NoiseModel\.{name} must be a positive number, got {bad}"):
        NoiseModel(**{**good, name: bad})


def test_a_planes_residual_is_the_signed_distance_along_its_normal() -> None:
    # the plane z = 0.8 seen from the origin: normal towards the camera (0, 0, -1), offset 0.8
    plane = Surface(label=3, kind="plane", normal=np.array([0.0, 0.0, -1.0]), offset=0.8, rms_m=0.0,
                    n_points=100, centroid=np.array([0.0, 0.0, 0.8]), z_m=0.8)  # fmt: skip
    p = np.array([[0.1, -0.2, 0.8], [0.0, 0.0, 0.79], [5.0, 5.0, 0.83]])
    assert plane.residual(p) == pytest.approx([0.0, 0.01, -0.03], abs=1e-12)  # positive: towards the camera
    assert plane.residual(np.array([1.0, 2.0, 0.75])).shape == (1,)  # one point is a row


def test_a_cylinders_residual_is_the_radial_distance_minus_its_radius() -> None:
    axis = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    pipe = Surface(label=1, kind="cylinder", normal=np.zeros(3), offset=0.0, rms_m=0.0, n_points=50,
                   centroid=np.zeros(3), z_m=0.9, axis=axis, centre=np.array([0.0, 0.0, 0.9]),
                   radius=0.05)  # fmt: skip
    across = np.array([1.0, -1.0, 0.0]) / math.sqrt(2.0)  # perpendicular to the axis, in the x-y plane
    c = np.array([0.0, 0.0, 0.9])
    p = np.array(
        [
            c + 0.05 * across,  # on the surface
            c + 3.0 * axis + 0.05 * np.array([0.0, 0.0, 1.0]),  # on it, further along the axis
            c + 0.08 * across - 2.0 * axis,  # 3 cm outside
            c + 0.01 * np.array([0.0, 0.0, -1.0]),  # 4 cm inside
            c + 7.0 * axis,  # on the axis: minus the radius
        ]
    )
    assert pipe.residual(p) == pytest.approx([0.0, 0.0, 0.03, -0.04, -0.05], abs=1e-12)


def test_a_planes_cylinder_fields_default_to_zeros() -> None:
    plane = Surface(label=0, kind="plane", normal=np.array([0.0, 0.0, -1.0]), offset=1.0, rms_m=0.0, n_points=1,
                    centroid=np.zeros(3), z_m=1.0)  # fmt: skip
    assert plane.axis.tolist() == [0.0, 0.0, 0.0] and plane.centre.tolist() == [0.0, 0.0, 0.0]
    assert plane.radius == 0.0
    other = Surface(label=1, kind="plane", normal=np.array([0.0, 0.0, -1.0]), offset=1.0, rms_m=0.0, n_points=1,
                    centroid=np.zeros(3), z_m=1.0)  # fmt: skip
    assert other.axis is not plane.axis  # one default array per surface, not one shared
