"""sim_fakes.board_render: a flat picture lands in the image exactly where the camera model puts it."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from perception.transforms import make_X
from sim_fakes.board_render import BoardRenderer, RenderParams, board_picture, render_view

# A frontal camera at 0.5 m with f = 500 px sees 1000 px per metre: a picture printed at 1000 px/m maps onto the
# image by a whole-pixel shift. Picture pixel p (board point (p - offset) / ppm, offset = margin - 0.5) lands at
# image pixel u = f * x / Z + cx = p - offset + cx = p + 310 (cx = 319.5, margin 10 px), v = p + 230 (cy = 239.5).
K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
SIZE = (640, 480)
FRONTAL = make_X(np.eye(3), [0.0, 0.0, 0.5])
EXACT = RenderParams(supersample=1, blur_sigma_px=0.0, noise_sigma=0.0, background=90, board_px_per_m=1000.0)


class Stripes:
    """A printable 0.2 x 0.1 m picture with a different gray level in every column and row (so a shift shows)."""

    squares_x, squares_y = 200, 100  # one "square" per column and row

    def __init__(self) -> None:
        self.calls = 0

    def image(self, *, px_per_m: float, margin_px: int = 0) -> NDArray[np.uint8]:
        self.calls += 1
        w, h = round(0.2 * px_per_m), round(0.1 * px_per_m)
        inner = ((np.arange(w)[None, :] * 7 + np.arange(h)[:, None] * 3) % 200 + 20).astype(np.uint8)
        return np.pad(inner, margin_px, constant_values=255)


def test_a_frontal_view_at_the_picture_s_own_scale_is_the_picture_shifted_by_whole_pixels() -> None:
    picture = board_picture(Stripes(), EXACT)
    assert picture.shape == (100 + 20, 200 + 20) and EXACT.margin_px == 10
    image = render_view(picture, FRONTAL, K=K, image_size=SIZE, params=EXACT, rng=np.random.default_rng(0))
    assert image.shape == (480, 640) and image.dtype == np.uint8
    np.testing.assert_array_equal(image[230:350, 310:530], picture)
    outside = np.ones(image.shape, dtype=bool)
    outside[230:350, 310:530] = False
    assert np.all(image[outside] == 90)  # the background gray everywhere else


def test_sensor_noise_has_the_asked_spread_and_blur_keeps_the_mean() -> None:
    picture = board_picture(Stripes(), EXACT)
    noisy = RenderParams(supersample=1, blur_sigma_px=0.0, noise_sigma=4.0, background=90, board_px_per_m=1000.0)
    image = render_view(picture, FRONTAL, K=K, image_size=SIZE, params=noisy, rng=np.random.default_rng(1))
    background = image[:200, :].astype(np.float64) - 90.0  # 128,000 pixels of background
    assert abs(background.std() - 4.0) < 0.05 and abs(background.mean()) < 0.05
    blurred = RenderParams(supersample=3, blur_sigma_px=1.5, noise_sigma=0.0, background=90, board_px_per_m=1000.0)
    image = render_view(picture, FRONTAL, K=K, image_size=SIZE, params=blurred, rng=np.random.default_rng(1))
    sharp = render_view(picture, FRONTAL, K=K, image_size=SIZE, params=EXACT, rng=np.random.default_rng(1))
    assert np.abs(image.astype(float) - sharp).max() > 30  # the stripes' edges are smoothed...
    assert abs(image.astype(float).mean() - sharp.astype(float).mean()) < 0.5  # ...without moving the gray mass


def test_the_distortion_path_agrees_with_the_homography_when_the_lens_is_almost_ideal() -> None:
    """With distortion every pixel's ray is cast onto the board plane; with a negligible one it must give the
    plane homography's image (to a gray level, the maps being float32)."""
    picture = board_picture(Stripes(), EXACT)
    tilted = make_X(np.array([[1.0, 0.0, 0.0], [0.0, np.cos(0.3), -np.sin(0.3)], [0.0, np.sin(0.3), np.cos(0.3)]]),
                    [-0.1, -0.05, 0.5])  # fmt: skip
    plain = render_view(picture, tilted, K=K, image_size=SIZE, params=EXACT, rng=np.random.default_rng(0))
    ray_cast = render_view(
        picture, tilted, K=K, image_size=SIZE, params=EXACT, rng=np.random.default_rng(0), dist=[1e-9, 0, 0, 0, 0]
    )
    diff = np.abs(plain.astype(int) - ray_cast)
    assert diff.max() <= 1 and np.mean(diff > 0) < 0.01
    assert np.count_nonzero(plain != 90) > 15_000  # the tilted picture is in view


def test_a_barrel_distortion_puts_the_picture_s_outline_where_opencv_projects_it() -> None:
    """The renderer inverts the lens model (undistorting each pixel's ray); OpenCV's forward projection of the
    picture's outline must land on the rendered picture's first and last columns and rows."""
    import cv2

    picture = board_picture(Stripes(), EXACT)
    X = make_X(np.eye(3), [0.05, 0.03, 0.5])  # off centre, so the far corner sees r = 0.6 (of the focal length)
    dist = np.array([-0.3, 0.0, 0.0, 0.0, 0.0])
    plain = render_view(picture, X, K=K, image_size=SIZE, params=EXACT, rng=np.random.default_rng(0))
    barrel = render_view(picture, X, K=K, image_size=SIZE, params=EXACT, rng=np.random.default_rng(0), dist=dist)
    # the picture's outline in the board frame: pixel edges -0.5 and 219.5 / 119.5, offset 9.5, 1000 px/m
    s = np.linspace(0.0, 1.0, 400)
    x0, x1, y0, y1 = -0.01, 0.21, -0.01, 0.11
    outline = np.concatenate(
        [np.column_stack([x0 + (x1 - x0) * s, np.full_like(s, y)]) for y in (y0, y1)]
        + [np.column_stack([np.full_like(s, x), y0 + (y1 - y0) * s]) for x in (x0, x1)]
    )
    uv, _ = cv2.projectPoints(np.column_stack([outline, np.zeros(len(outline))]), np.zeros(3), X[:3, 3], K, dist)
    u, v = uv.reshape(-1, 2).T
    cols = np.flatnonzero((barrel != 90).any(axis=0))
    rows = np.flatnonzero((barrel != 90).any(axis=1))
    # a pixel is drawn when its centre falls inside the outline: first = ceil(min), last = floor(max), to 1 px
    assert abs(cols[0] - np.ceil(u.min())) <= 1 and abs(cols[-1] - np.floor(u.max())) <= 1
    assert abs(rows[0] - np.ceil(v.min())) <= 1 and abs(rows[-1] - np.floor(v.max())) <= 1
    # and the lens really moved it: undistorted the picture spans columns 360..579, rows 260..379
    plain_cols = np.flatnonzero((plain != 90).any(axis=0))
    assert (plain_cols[0], plain_cols[-1]) == (360, 579)
    assert cols[-1] < 579 - 15


def test_the_renderer_draws_the_picture_once_per_board_and_renders_as_render_view() -> None:
    board, other = Stripes(), Stripes()
    renderer = BoardRenderer(EXACT)
    first = renderer(board, FRONTAL, K=K, image_size=SIZE, rng=np.random.default_rng(0))
    renderer(board, FRONTAL, K=K, image_size=SIZE, rng=np.random.default_rng(0))
    assert board.calls == 1
    renderer(other, FRONTAL, K=K, image_size=SIZE, rng=np.random.default_rng(0))
    assert other.calls == 1
    expected = render_view(
        board_picture(Stripes(), EXACT), FRONTAL, K=K, image_size=SIZE, params=EXACT, rng=np.random.default_rng(0)
    )
    np.testing.assert_array_equal(first, expected)
    assert BoardRenderer().params == RenderParams()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"supersample": 0}, "supersample >= 1"),
        ({"board_px_per_m": 0.0}, "board_px_per_m > 0"),
        ({"noise_sigma": -1.0}, "noise_sigma >= 0"),
        ({"background": 300}, "background <= 255"),
    ],
)
def test_render_params_refuse_settings_that_draw_nothing_sensible(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        RenderParams(**kwargs)  # type: ignore[arg-type]
