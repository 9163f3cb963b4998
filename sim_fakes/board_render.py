"""A flat printed picture (a calibration board) as a camera sees it: warped, supersampled, blurred, noisy.

The fake camera's ``"charuco"`` scene and the hand-eye simulation (:func:`calibration.simulate.simulate_views`, which
is handed a :class:`BoardRenderer`) draw their board images here. What is printed is the caller's business: anything
with an ``image(px_per_m=..., margin_px=...)`` method (:class:`BoardPicture`; ``calibration.board.CharucoBoardSpec``
is one) gives the picture, so sim_fakes needs nothing of calibration.

Picture convention (the board's): board point (x, y), metres, is at picture pixel ``margin - 0.5 + (x, y) * px_per_m``
(pixel centres), the board frame's z axis pointing away from the printed face.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from perception.transforms import check_X


class BoardPicture(Protocol):
    """A printed board of ``squares_x`` by ``squares_y`` squares; ``image`` draws it at ``px_per_m`` pixels per metre
    with a white margin, (H, W) uint8."""

    @property
    def squares_x(self) -> int: ...

    @property
    def squares_y(self) -> int: ...

    def image(self, *, px_per_m: float, margin_px: int = 0) -> NDArray[np.uint8]: ...


@dataclass(frozen=True)
class RenderParams:
    """Synthetic image settings. ``supersample``: render at this factor and area-average down.
    ``blur_sigma_px``: Gaussian lens blur, pixels. ``noise_sigma``: sensor noise, gray levels.
    ``background``: gray level around the board. ``board_px_per_m``: resolution of the board picture
    that is warped (keep it above the projected resolution times ``supersample``)."""

    supersample: int = 3
    blur_sigma_px: float = 0.6
    noise_sigma: float = 2.0
    background: int = 90
    board_px_per_m: float = 8000.0
    board_margin_m: float = 0.01

    def __post_init__(self) -> None:
        if self.supersample < 1 or self.board_px_per_m <= 0 or self.board_margin_m < 0:
            raise ValueError(
                f"need supersample >= 1, board_px_per_m > 0 and board_margin_m >= 0, got {self.supersample}, "
                f"{self.board_px_per_m}, {self.board_margin_m}"
            )
        if self.blur_sigma_px < 0 or self.noise_sigma < 0 or not 0 <= self.background <= 255:
            raise ValueError(
                f"need blur_sigma_px >= 0, noise_sigma >= 0 and 0 <= background <= 255, got {self.blur_sigma_px}, "
                f"{self.noise_sigma}, {self.background}"
            )

    @property
    def margin_px(self) -> int:
        """The picture's white margin, whole pixels."""
        return round(self.board_margin_m * self.board_px_per_m)


def board_picture(board: BoardPicture, params: RenderParams) -> NDArray[np.uint8]:
    """The picture :func:`render_view` warps: ``board`` at ``params.board_px_per_m`` with ``params.margin_px``."""
    return board.image(px_per_m=params.board_px_per_m, margin_px=params.margin_px)


class BoardRenderer:
    """Draws views of a board with fixed :class:`RenderParams`; the board's picture is made once per board.

    Called as ``renderer(board, X_camera_board, K=..., image_size=..., rng=..., dist=...)``, the signature
    :class:`calibration.simulate.ViewRenderer` asks for.
    """

    def __init__(self, params: RenderParams | None = None) -> None:
        self.params = params or RenderParams()
        self._board: BoardPicture | None = None
        self._picture: NDArray[np.uint8] | None = None

    def __call__(
        self,
        board: BoardPicture,
        X_camera_board: ArrayLike,
        *,
        K: ArrayLike,
        image_size: tuple[int, int],
        rng: np.random.Generator,
        dist: ArrayLike | None = None,
    ) -> NDArray[np.uint8]:
        if self._picture is None or self._board is not board:
            self._board, self._picture = board, board_picture(board, self.params)
        return render_view(
            self._picture, X_camera_board, K=K, image_size=image_size, params=self.params, rng=rng, dist=dist
        )


def render_view(
    board_picture: NDArray[np.uint8],
    X_camera_board: ArrayLike,
    *,
    K: ArrayLike,
    image_size: tuple[int, int],
    params: RenderParams,
    rng: np.random.Generator,
    dist: ArrayLike | None = None,
) -> NDArray[np.uint8]:
    """(H, W) uint8 camera image of ``board_picture`` (made by :func:`board_picture` with the same ``params``)
    lying at ``X_camera_board`` (4, 4, metres); ``K`` (3, 3), ``image_size`` (width, height) pixels, ``dist``
    OpenCV distortion coefficients, sensor noise drawn from ``rng``.

    Board point (x, y) is at picture pixel ``margin - 0.5 + (x, y) * px_per_m`` (pixel-centre
    convention). Without distortion the picture is warped by the plane homography; with distortion
    each image pixel's ray is intersected with the board plane and the picture is remapped.
    """
    import cv2  # here: a RenderParams alone (the fake camera's board settings) needs no OpenCV

    X = check_X(X_camera_board, name="X_camera_board")
    K_arr = np.asarray(K, dtype=np.float64)
    dist_arr = np.zeros(5) if dist is None else np.asarray(dist, dtype=np.float64).reshape(-1)
    width, height = image_size
    s = int(params.supersample)
    ppm = params.board_px_per_m
    offset = round(params.board_margin_m * ppm) - 0.5
    # Board metres -> picture pixels, and supersampled-image pixels -> image pixels (pixel centres).
    picture_from_board = np.array([[ppm, 0.0, offset], [0.0, ppm, offset], [0.0, 0.0, 1.0]])
    big_from_image = np.array([[s, 0.0, (s - 1) / 2.0], [0.0, s, (s - 1) / 2.0], [0.0, 0.0, 1.0]])
    big_size = (width * s, height * s)
    if not np.any(dist_arr):
        image_from_board = K_arr @ np.column_stack([X[:3, 0], X[:3, 1], X[:3, 3]])
        H = big_from_image @ image_from_board @ np.linalg.inv(picture_from_board)
        big = cv2.warpPerspective(
            board_picture,
            H,
            big_size,
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=params.background,
        )
    else:
        # Cast the ray of every image pixel centre onto the board plane (undistorting it first), then
        # upsample that smooth map to the supersampled grid: cv2.resize's pixel-centre convention
        # puts big pixel x at image pixel (x + 0.5) / s - 0.5, exactly where it belongs.
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        image_uv = np.stack([u, v], axis=-1).reshape(-1, 1, 2)
        rays = cv2.undistortPoints(image_uv, K_arr, dist_arr).reshape(-1, 2)
        d_camera = np.column_stack([rays, np.ones(len(rays))])
        # Ray λ d meets the board plane z_board = 0: R^T (λ d - t) has zero z.
        R, t = X[:3, :3], X[:3, 3]
        d_board = d_camera @ R
        t_board = R.T @ t
        with np.errstate(divide="ignore"):
            lam = t_board[2] / d_board[:, 2]
        p_board = lam[:, None] * d_board - t_board
        map_x = (p_board[:, 0] * ppm + offset).reshape(height, width).astype(np.float32)
        map_y = (p_board[:, 1] * ppm + offset).reshape(height, width).astype(np.float32)
        off_board = ~np.isfinite(lam) | (lam <= 0)
        map_x[off_board.reshape(height, width)] = -1e6
        big = cv2.remap(
            board_picture,
            cv2.resize(map_x, big_size, interpolation=cv2.INTER_LINEAR),
            cv2.resize(map_y, big_size, interpolation=cv2.INTER_LINEAR),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=params.background,
        )
    image = cv2.resize(big, (width, height), interpolation=cv2.INTER_AREA).astype(np.float64)
    if params.blur_sigma_px > 0:
        image = np.asarray(cv2.GaussianBlur(image, (0, 0), params.blur_sigma_px), dtype=np.float64)
    image += rng.normal(0.0, params.noise_sigma, image.shape)
    return np.asarray(np.clip(np.rint(image), 0, 255), dtype=np.uint8)
