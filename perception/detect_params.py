"""What tunes the detector (:class:`DetectParams`) and what its steps record (:class:`StepLog`).

Apart from :mod:`perception.detect` so that the steps' modules (:mod:`perception.region_seams`,
:mod:`perception.detect_surfaces`) take them without importing the detector that calls them;
``perception.detect`` offers both under its own name, where callers have always found them.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from perception.cloud import RegionParams
from perception.path import TorchParams
from perception.seamfit import SeamParams
from perception.segment_default import AutoPromptParams, GraphSegmenterParams

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class DetectParams:
    """Everything that tunes detection. Lengths in metres, angles (in the nested params) in radians."""

    crop: bool = True
    roi_band_m: float = 0.010  # half-width of the seam band around where two masks meet
    z_range_m: tuple[float, float] = (0.1, 3.0)
    workspace_min_m: tuple[float, float, float] | None = None  # optional box, camera frame
    workspace_max_m: tuple[float, float, float] | None = None
    voxel_m: float = 0.003
    veil_jump_m: float = 0.003
    knn: int = 16
    normal_radius_voxels: float = 2.5
    method: Literal["surfaces", "refined", "paper"] = "surfaces"
    # without prompts, which surfaces may be seams' faces (surfaces method): "aim", the part the camera is
    # aimed at and whatever stands on it (a cell's capture poses look at the part; boxes beside it on the
    # table are not it), or "all" (a cloud's virtual camera is aimed at the cloud's middle, not at a part)
    unprompted: Literal["aim", "all"] = "aim"
    regions: RegionParams = field(default_factory=RegionParams)
    seams: SeamParams = field(default_factory=SeamParams)
    torch: TorchParams = field(default_factory=TorchParams)
    segmenter: GraphSegmenterParams = field(default_factory=GraphSegmenterParams)
    auto_prompts: AutoPromptParams = field(default_factory=AutoPromptParams)


class StepLog:
    """Records the time (summed over repeats) and point count of each step, and the coarse masks' planes."""

    def __init__(self) -> None:
        self.timing_s: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        self.voxel_planes: dict[int, tuple[FloatArray, FloatArray, float]] = {}  # per coarse label

    @contextmanager
    def step(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.timing_s[name] = self.timing_s.get(name, 0.0) + time.perf_counter() - t0
