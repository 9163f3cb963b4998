"""The ChArUco calibration board: its definition, a printable image, and detection with pose.

Board frame (OpenCV's): origin at the outer top-left corner of the printed chessboard, x along the
``squares_x`` direction (to the right on the print), y along ``squares_y`` (downward on the print),
z = x × y pointing into the board, away from a camera that sees its printed face. Metres.

A printed image puts the board edge at pixel-centre coordinate ``-0.5`` (the left edge of pixel 0),
so board point ``(x, y)`` is at pixel ``(margin - 0.5 + x * px_per_m, margin - 0.5 + y * px_per_m)``.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.errors import CalibrationError
from perception.transforms import check_X, make_X

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int32]

METRES_PER_INCH = 0.0254
DEFAULT_MIN_CORNERS = 6


@dataclass(frozen=True)
class CharucoBoardSpec:
    """A ChArUco board: ``squares_x`` × ``squares_y`` chessboard squares of ``square_length_m`` metres,
    with ArUco markers of ``marker_length_m`` metres from ``dictionary`` (a ``cv2.aruco.DICT_*`` name)
    in the white squares. ``legacy_pattern`` selects the pre-4.6 layout for boards with an even number
    of rows printed by old OpenCV versions."""

    squares_x: int = 7
    squares_y: int = 5
    square_length_m: float = 0.030
    marker_length_m: float = 0.022
    dictionary: str = "DICT_5X5_100"
    legacy_pattern: bool = False

    def __post_init__(self) -> None:
        if self.squares_x < 2 or self.squares_y < 2:
            raise CalibrationError(f"board needs at least 2x2 squares, got {self.squares_x}x{self.squares_y}")
        if not 0.0 < self.marker_length_m < self.square_length_m:
            raise CalibrationError(
                f"marker length {self.marker_length_m} m must be positive and smaller than the square "
                f"length {self.square_length_m} m"
            )
        if not (self.dictionary.startswith("DICT_") and hasattr(cv2.aruco, self.dictionary)):
            raise CalibrationError(f"unknown ArUco dictionary {self.dictionary!r}; use a cv2.aruco.DICT_* name")
        n_markers = (self.squares_x * self.squares_y) // 2
        dict_size = _dictionary_size(self.dictionary)
        if dict_size is not None and n_markers > dict_size:
            raise CalibrationError(
                f"board needs {n_markers} markers but {self.dictionary} holds only {dict_size}; "
                "pick a larger dictionary or fewer squares"
            )

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the chessboard area in metres."""
        return (self.squares_x * self.square_length_m, self.squares_y * self.square_length_m)

    @property
    def n_corners(self) -> int:
        """Number of inner chessboard (ChArUco) corners."""
        return (self.squares_x - 1) * (self.squares_y - 1)

    @property
    def corners_board(self) -> FloatArray:
        """(n_corners, 3) ChArUco corner positions in the board frame, metres, indexed by corner id."""
        return np.asarray(self.cv_board().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)

    def cv_board(self) -> cv2.aruco.CharucoBoard:
        """A fresh ``cv2.aruco.CharucoBoard`` for this definition."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        board = cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y), self.square_length_m, self.marker_length_m, dictionary
        )
        board.setLegacyPattern(self.legacy_pattern)
        return board

    def image(self, *, px_per_m: float, margin_px: int = 0) -> NDArray[np.uint8]:
        """(H, W) uint8 picture of the board at ``px_per_m`` pixels per metre with a white margin.

        The board spans pixels ``[margin_px, margin_px + round(width_m * px_per_m))``; rounding the
        size to whole pixels changes the scale by at most half a pixel over the board.
        """
        if px_per_m <= 0:
            raise CalibrationError(f"px_per_m must be positive, got {px_per_m}")
        width_m, height_m = self.size_m
        w_px = round(width_m * px_per_m)
        h_px = round(height_m * px_per_m)
        inner = self.cv_board().generateImage((w_px, h_px), marginSize=0, borderBits=1)
        framed = cv2.copyMakeBorder(inner, margin_px, margin_px, margin_px, margin_px, cv2.BORDER_CONSTANT, value=255)
        return np.asarray(framed, dtype=np.uint8)

    def default_filename(self, dpi: float) -> str:
        """A file name stating the board and its print scale (dpi to 0.1)."""
        return (
            f"charuco_{self.squares_x}x{self.squares_y}_sq{self.square_length_m * 1000:g}mm"
            f"_mk{self.marker_length_m * 1000:g}mm_{self.dictionary}_{dpi:.1f}dpi.png"
        )


def _dictionary_size(name: str) -> int | None:
    """Number of markers in a predefined dictionary (``DICT_5X5_100`` -> 100), None if not in the name."""
    tail = name.rsplit("_", 1)[-1]
    return int(tail) if tail.isdigit() else None


@dataclass(frozen=True)
class BoardObservation:
    """ChArUco corners found in one image and the board pose they give.

    ``corner_ids``: (N,) int32 ChArUco corner ids.
    ``corners_px``: (N, 2) float64 pixel positions (u = column, v = row; OpenCV pixel-centre convention).
    ``corners_board``: (N, 3) float64 the same corners in the board frame, metres.
    ``X_camera_board``: (4, 4) pose of the board in the camera frame, metres.
    ``rms_px``: RMS reprojection error of the corners under that pose, pixels.
    """

    corner_ids: IntArray
    corners_px: FloatArray
    corners_board: FloatArray
    X_camera_board: FloatArray
    rms_px: float

    def __post_init__(self) -> None:
        ids = np.asarray(self.corner_ids, dtype=np.int32).reshape(-1)
        px = np.asarray(self.corners_px, dtype=np.float64)
        pb = np.asarray(self.corners_board, dtype=np.float64)
        n = ids.shape[0]
        if px.shape != (n, 2) or pb.shape != (n, 3):
            raise CalibrationError(
                f"BoardObservation: expected corners_px (N, 2) and corners_board (N, 3) with N = {n}, "
                f"got {px.shape} and {pb.shape}"
            )
        X = check_X(self.X_camera_board, name="X_camera_board")
        object.__setattr__(self, "corner_ids", ids)
        object.__setattr__(self, "corners_px", px)
        object.__setattr__(self, "corners_board", pb)
        object.__setattr__(self, "X_camera_board", X)
        object.__setattr__(self, "rms_px", float(self.rms_px))

    @property
    def n_corners(self) -> int:
        return int(self.corner_ids.shape[0])


def render_board_png(path: str | Path, *, board: CharucoBoardSpec, dpi: float = 300.0, margin_m: float = 0.01) -> Path:
    """Write a printable PNG of ``board`` at about ``dpi`` (print at 100 % scale, no "fit to page").

    Every square gets the same whole number of pixels (the nearest to ``dpi``), so the print is crisp
    and its scale exact: the effective resolution is ``square_px / square_length_m`` pixels per metre,
    which the PNG states in its ``pHYs`` chunk (honoured by print dialogs), in a ``tEXt`` description
    and in the default file name. ``path`` is a file name, or a directory in which
    :meth:`CharucoBoardSpec.default_filename` is used. ``margin_m`` of white surrounds the board (the
    markers need a quiet zone). Returns the path written.
    """
    if dpi <= 0:
        raise CalibrationError(f"dpi must be positive, got {dpi}")
    square_px = round(board.square_length_m * dpi / METRES_PER_INCH)
    if square_px < 8:
        raise CalibrationError(f"{dpi:g} dpi gives {square_px} px per square; use at least 8 (a higher dpi)")
    px_per_m = square_px / board.square_length_m
    dpi_eff = px_per_m * METRES_PER_INCH
    out = Path(path)
    if out.is_dir():
        out = out / board.default_filename(dpi_eff)
    image = board.image(px_per_m=px_per_m, margin_px=round(margin_m * px_per_m))
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise CalibrationError(f"could not encode the board image for {out}")
    width_m, height_m = board.size_m
    description = (
        f"ChArUco board {board.squares_x}x{board.squares_y} squares, square {board.square_length_m * 1000:g} mm, "
        f"marker {board.marker_length_m * 1000:g} mm, {board.dictionary}, legacy={board.legacy_pattern}; "
        f"board {width_m * 1000:g} x {height_m * 1000:g} mm; {square_px} px per square = {dpi_eff:.2f} dpi "
        f"({px_per_m:.1f} px/m); print at 100 % scale and measure one square before use"
    )
    png = _with_png_metadata(encoded.tobytes(), px_per_m=px_per_m, text={"Description": description})
    out.write_bytes(png)
    return out


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def _with_png_metadata(png: bytes, *, px_per_m: float, text: dict[str, str]) -> bytes:
    """Insert ``pHYs`` (unit = metre) and ``tEXt`` chunks right after the IHDR chunk of ``png``."""
    signature = b"\x89PNG\r\n\x1a\n"
    if not png.startswith(signature) or png[12:16] != b"IHDR":
        raise CalibrationError("encoded board image is not a PNG with a leading IHDR chunk")
    ihdr_end = 8 + 8 + struct.unpack(">I", png[8:12])[0] + 4
    ppm = round(px_per_m)
    extra = _png_chunk(b"pHYs", struct.pack(">IIB", ppm, ppm, 1))
    for key, value in text.items():
        extra += _png_chunk(b"tEXt", key.encode("latin-1") + b"\x00" + value.encode("latin-1"))
    return png[:ihdr_end] + extra + png[ihdr_end:]


def read_png_scale_px_per_m(path: str | Path) -> float | None:
    """Pixels per metre from a PNG's ``pHYs`` chunk, or None when it has none (or no metric unit)."""
    data = Path(path).read_bytes()
    pos = 8
    while pos + 8 <= len(data):
        length = struct.unpack(">I", data[pos : pos + 4])[0]
        kind = data[pos + 4 : pos + 8]
        if kind == b"pHYs":
            ppx, ppy, unit = struct.unpack(">IIB", data[pos + 8 : pos + 17])
            return float(ppx) if unit == 1 and ppx == ppy else None
        if kind == b"IDAT":
            return None
        pos += 12 + length
    return None


def detect_board(
    image: ArrayLike,
    *,
    board: CharucoBoardSpec,
    K: ArrayLike,
    dist: ArrayLike | None = None,
    min_corners: int = DEFAULT_MIN_CORNERS,
) -> BoardObservation:
    """Find the ChArUco corners of ``board`` in ``image`` and the board pose ``X_camera_board``.

    ``image``: (H, W) or (H, W, 3) uint8. ``K``: (3, 3) camera matrix, pixels. ``dist``: OpenCV
    distortion coefficients (None = none). The pose comes from planar PnP (IPPE) refined by
    Levenberg-Marquardt on all corners.

    Raises CalibrationError when fewer than ``min_corners`` corners are found (the count is in the
    message), when they are collinear, or when the pose puts the board behind the camera.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3):
        raise CalibrationError(
            f"detect_board: expected an (H, W) or (H, W, 3) uint8 image, got {img.dtype} {img.shape}"
        )
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    K_arr = _check_K(K)
    dist_arr = np.zeros(5) if dist is None else np.asarray(dist, dtype=np.float64).reshape(-1)
    min_corners = max(int(min_corners), 4)

    cv_board = board.cv_board()
    charuco_params = cv2.aruco.CharucoParameters()
    charuco_params.cameraMatrix = K_arr
    charuco_params.distCoeffs = dist_arr
    detector = cv2.aruco.CharucoDetector(cv_board, charuco_params)
    corners, ids, _, _ = detector.detectBoard(img)
    n_found = 0 if ids is None else len(ids)
    if n_found < min_corners:
        raise CalibrationError(
            f"board view rejected: {n_found} ChArUco corners found, at least {min_corners} needed "
            f"(board has {board.n_corners}); bring the whole board into view, closer or with less tilt"
        )
    assert ids is not None and corners is not None
    if cv_board.checkCharucoCornersCollinear(ids):
        raise CalibrationError(f"board view rejected: the {n_found} corners found lie on one line; pose is undefined")
    # For a CharucoBoard, matchImagePoints takes the (N, 1, 2) corner array itself (the stubs only
    # describe the marker-board overload).
    obj_pts, img_pts = cv_board.matchImagePoints(cast(Any, corners), ids)
    obj = np.asarray(obj_pts, dtype=np.float64).reshape(-1, 3)
    pix = np.asarray(img_pts, dtype=np.float64).reshape(-1, 2)
    X_camera_board, rms = solve_board_pose(obj, pix, K=K_arr, dist=dist_arr)
    return BoardObservation(
        corner_ids=np.asarray(ids, dtype=np.int32).reshape(-1),
        corners_px=pix,
        corners_board=obj,
        X_camera_board=X_camera_board,
        rms_px=rms,
    )


def solve_board_pose(
    corners_board: ArrayLike, corners_px: ArrayLike, *, K: ArrayLike, dist: ArrayLike | None = None
) -> tuple[FloatArray, float]:
    """``(X_camera_board, rms_px)`` from (N, 3) planar board points (metres) and their (N, 2) pixels.

    IPPE for the initial pose, then Levenberg-Marquardt on the reprojection error.
    """
    obj = np.asarray(corners_board, dtype=np.float64).reshape(-1, 3)
    pix = np.asarray(corners_px, dtype=np.float64).reshape(-1, 2)
    if obj.shape[0] != pix.shape[0] or obj.shape[0] < 4:
        raise CalibrationError(f"board pose needs >= 4 matched corners, got {obj.shape[0]} and {pix.shape[0]}")
    K_arr = _check_K(K)
    dist_arr = np.zeros(5) if dist is None else np.asarray(dist, dtype=np.float64).reshape(-1)
    try:
        ok, rvec, tvec = cv2.solvePnP(obj, pix, K_arr, dist_arr, flags=cv2.SOLVEPNP_IPPE)
    except cv2.error as err:
        raise CalibrationError(f"board pose: solvePnP failed on {obj.shape[0]} corners ({err})") from err
    if not ok:
        raise CalibrationError(f"board pose: solvePnP found no pose for {obj.shape[0]} corners")
    rvec, tvec = cv2.solvePnPRefineLM(obj, pix, K_arr, dist_arr, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    X_camera_board = make_X(R, tvec.reshape(3))
    if X_camera_board[2, 3] <= 0:
        raise CalibrationError(f"board pose: board is behind the camera (z = {X_camera_board[2, 3]:.3f} m)")
    projected, _ = cv2.projectPoints(obj, rvec, tvec, K_arr, dist_arr)
    rms = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - pix) ** 2, axis=1))))
    return X_camera_board, rms


def _check_K(K: ArrayLike) -> FloatArray:
    K_arr = np.asarray(K, dtype=np.float64)
    if K_arr.shape != (3, 3) or not np.all(np.isfinite(K_arr)) or K_arr[0, 0] <= 0 or K_arr[1, 1] <= 0:
        raise CalibrationError(f"camera matrix K must be a finite (3, 3) array with fx, fy > 0, got {K_arr.tolist()}")
    return K_arr
