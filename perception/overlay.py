"""The overlay image: surfaces tinted, the seam band (ROI) outlined, seams and torch axes drawn on the RGB
image, each seam labelled with its id."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from perception.capture import Capture
from perception.seams import DetectionResult
from perception.segmentation import SurfaceMasks
from perception.transforms import invert_X, rotate_vectors, transform_points

PALETTE = np.array(
    [
        [230, 159, 0],
        [86, 180, 233],
        [0, 158, 115],
        [240, 228, 66],
        [0, 114, 178],
        [213, 94, 0],
        [204, 121, 167],
        [140, 86, 75],
        [127, 127, 127],
        [188, 189, 34],
        [23, 190, 207],
        [148, 103, 189],
        [255, 152, 150],
        [197, 176, 213],
        [196, 156, 148],
        [247, 182, 210],
    ],
    dtype=np.float64,
)
SEAM_COLOR = (255, 40, 40)


def draw_overlay(
    capture: Capture,
    result: DetectionResult,
    *,
    masks: SurfaceMasks | None = None,
    roi: NDArray[np.bool_] | None = None,
    truth: bool = False,
    note: str = "",
) -> NDArray[np.uint8]:
    """(H, W, 3) uint8 RGB overlay. ``truth`` also draws the ground-truth seams (thin, green); ``note`` is
    written across the top (why no seam was found, say)."""
    import cv2

    img = capture.color_rgb.astype(np.float64)
    masks = masks if masks is not None else result.artifacts.get("masks")
    roi = roi if roi is not None else result.artifacts.get("roi")
    surf = result.artifacts.get("surfaces")
    lab = None
    if masks is not None:
        lab = masks.labels
    elif surf is not None:  # the surfaces-first stage's fitted surfaces, at their work resolution
        f = surf.factor
        H, W = capture.shape
        lab = np.repeat(np.repeat(surf.labels, f, axis=0), f, axis=1)[:H, :W]
    if lab is not None:
        tint = PALETTE[np.where(lab >= 0, lab, 0) % len(PALETTE)]
        img = np.where((lab >= 0)[..., None], 0.55 * img + 0.45 * tint, img * 0.75)
    out = np.clip(img, 0, 255).astype(np.uint8)
    if roi is not None and roi.any():
        contours, _ = cv2.findContours(roi.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(out, contours, -1, (255, 255, 255), 1, cv2.LINE_AA)
    X_camera_frame = np.eye(4)
    if result.frame == "base":
        X_base_camera = capture.X_base_camera
        if X_base_camera is not None:
            X_camera_frame = invert_X(X_base_camera)
    intr = capture.intrinsics
    scale = max(1, capture.shape[1] // 640)
    if truth and capture.ground_truth:
        for g in capture.ground_truth:
            uv = intr.project(g.points_camera)
            cv2.polylines(out, [np.round(uv).astype(np.int32)], False, (60, 255, 60), scale, cv2.LINE_AA)
    for seam in result.seams:
        p_cam = transform_points(X_camera_frame, seam.points)
        uv = intr.project(p_cam)
        cv2.polylines(out, [np.round(uv).astype(np.int32)], False, SEAM_COLOR, 2 * scale, cv2.LINE_AA)
        # torch axes at every other path point: z (torch, blue) and x (travel, yellow), 15 mm long
        for i in range(0, len(seam.points), 2):
            X = seam.poses[i]
            o = transform_points(X_camera_frame, X[:3, 3])[0]
            z = rotate_vectors(X_camera_frame, X[:3, 2])[0]
            x = rotate_vectors(X_camera_frame, X[:3, 0])[0]
            for axis, col, length in ((z, (40, 120, 255), 0.015), (x, (255, 220, 0), 0.008)):
                tail = o - axis * length if axis is z else o
                head = o if axis is z else o + axis * length
                a, b = intr.project(np.array([tail, head]))
                cv2.line(out, tuple(np.round(a).astype(int)), tuple(np.round(b).astype(int)), col, scale, cv2.LINE_AA)
        mid = uv[len(uv) // 2]
        cv2.putText(out, str(seam.id), (int(mid[0]) + 6, int(mid[1]) - 6), cv2.FONT_HERSHEY_SIMPLEX,
                    0.5 * scale, (255, 255, 255), 2 * scale, cv2.LINE_AA)  # fmt: skip
        cv2.putText(out, str(seam.id), (int(mid[0]) + 6, int(mid[1]) - 6), cv2.FONT_HERSHEY_SIMPLEX,
                    0.5 * scale, (0, 0, 0), scale, cv2.LINE_AA)  # fmt: skip
    if note:
        for k, line in enumerate(_wrap(note, max(30, capture.shape[1] // (11 * scale)))):
            org = (8 * scale, (22 + 22 * k) * scale)
            cv2.putText(out, line, org, cv2.FONT_HERSHEY_SIMPLEX, 0.55 * scale, (0, 0, 0), 3 * scale, cv2.LINE_AA)
            cv2.putText(out, line, org, cv2.FONT_HERSHEY_SIMPLEX, 0.55 * scale, (255, 255, 255), scale, cv2.LINE_AA)
    return out


def _wrap(text: str, width: int) -> list[str]:
    lines, cur = [], ""
    for word in text.split():
        if cur and len(cur) + 1 + len(word) > width:
            lines.append(cur)
            cur = word
        else:
            cur = f"{cur} {word}".strip()
    return [*lines, cur] if cur else lines


def write_png(path: str, rgb: NDArray[np.uint8]) -> None:
    import cv2

    if not cv2.imwrite(str(path), np.ascontiguousarray(rgb[:, :, ::-1])):
        raise OSError(f"could not write {path}")
