"""The coarse stage's segmenter interface: an RGB(-D) image and point prompts in, one mask per prompt out.

Backends:
- ``perception.segment_default.GraphSegmenter``: needs no weights (seeded region growing on colour and
  depth/normal edges); the default.
- ``perception.segment_fastsam.FastSamSegmenter``: a user-supplied FastSAM ONNX export run by onnxruntime.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from perception.errors import PerceptionError

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SurfaceMasks:
    """Result of segmentation.

    labels: (H, W) int32; ``k >= 0`` means the pixel belongs to the surface of prompt ``k``; -1 means
        no prompted surface (background, table, unassigned).
    prompts_px: (K, 2) float (u, v) pixel prompts, one per surface, in label order.
    scores: K confidences in [0, 1], one per surface (1.0 when the backend has no notion of confidence).
    """

    labels: NDArray[np.int32]
    prompts_px: FloatArray
    scores: tuple[float, ...]

    def __post_init__(self) -> None:
        labels = np.asarray(self.labels)
        if labels.ndim != 2:
            raise PerceptionError(f"labels must be (H, W), got {labels.shape}")
        k = int(np.asarray(self.prompts_px).reshape(-1, 2).shape[0])
        if len(self.scores) != k:
            raise PerceptionError(f"{k} prompts but {len(self.scores)} scores")
        if labels.size and int(labels.max(initial=-1)) >= k:
            raise PerceptionError(f"label {int(labels.max())} has no prompt (only {k} prompts)")
        object.__setattr__(self, "labels", labels.astype(np.int32, copy=False))
        object.__setattr__(self, "prompts_px", np.asarray(self.prompts_px, dtype=np.float64).reshape(-1, 2))

    @property
    def count(self) -> int:
        return int(self.prompts_px.shape[0])

    def mask(self, k: int) -> NDArray[np.bool_]:
        return self.labels == k


@runtime_checkable
class Segmenter(Protocol):
    """Split an image into workpiece surfaces, one per point prompt."""

    name: str

    def segment(
        self,
        color_rgb: NDArray[np.uint8],
        depth_m: NDArray[np.float32],
        prompts_px: FloatArray,
        *,
        points_camera: NDArray[np.float32] | None = None,
    ) -> SurfaceMasks:
        """color_rgb: (H, W, 3) uint8; depth_m: (H, W) float32 metres, NaN = none; prompts_px: (K, 2) (u, v);
        points_camera: the organized (H, W, 3) cloud when the caller has it (backends may use it or not).

        Returns one surface per prompt (a surface may be empty when the backend finds nothing there).
        """
        ...
