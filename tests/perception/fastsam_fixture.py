"""A tiny stand-in for a FastSAM ONNX export, built with the ``onnx`` package, whose outputs encode known masks.

The graph has FastSAM's exact interface (input "images" (1, 3, S, S); outputs "output0" (1, 37, N) and
"output1" (1, 32, S/4, S/4)) and emits constant tensors; the input is consumed (its mean, times zero, is
added to both outputs) so onnxruntime still checks its shape. Nothing here is derived from real weights.

Masks are planted as *signed fields*: prototype channel c holds, at each prototype pixel, a signed distance
(in image pixels) to a known shape in the original image, positive inside. Bilinear interpolation of such a
field reproduces the shape's edge to a fraction of a pixel, so decoding must land on the exact analytic
shape in original-image coordinates, which checks the letterbox padding removal and the scaling.

The prototype pixel -> image mapping is derived here from first principles, independently of the code under
test: prototype pixel j covers input pixels 4j .. 4j+3 (centre 4j + 1.5); the letterbox resize maps image
coordinate x to input coordinate (x + 0.5) * gain - 0.5 + pad.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import onnx
from numpy.typing import NDArray
from onnx import TensorProto, helper, numpy_helper

NUM_COEFFS = 32
HEAD_STRIDES = (8, 16, 32)
PROTO_STRIDE = 4


def num_anchors(size: int) -> int:
    return sum((size // s) ** 2 for s in HEAD_STRIDES)


def build_fastsam_onnx(
    path: Path,
    *,
    output0: NDArray[np.float32],
    output1: NDArray[np.float32],
    size: int,
    dynamic: bool = False,
    input_name: str = "images",
) -> Path:
    """Write an ONNX model with FastSAM's interface that returns ``output0`` and ``output1`` for any input.

    output0: (1, C, N) float32; output1: (1, 32, h, w) float32 (shapes are not checked here, so tests can
    build wrong models on purpose). size: S of the (1, 3, S, S) input; ``dynamic`` makes H and W symbolic.
    """
    hw: list[int | str] = ["height", "width"] if dynamic else [size, size]
    images = helper.make_tensor_value_info(input_name, TensorProto.FLOAT, [1, 3, *hw])
    out_shape0: list[int | str] = ["batch", int(output0.shape[1]), "anchors"] if dynamic else list(output0.shape)
    out_shape1: list[int | str] = (
        ["batch", int(output1.shape[1]), "proto_h", "proto_w"] if dynamic else list(output1.shape)
    )
    out0 = helper.make_tensor_value_info("output0", TensorProto.FLOAT, out_shape0)
    out1 = helper.make_tensor_value_info("output1", TensorProto.FLOAT, out_shape1)
    inits = [
        numpy_helper.from_array(np.ascontiguousarray(output0, dtype=np.float32), "const0"),
        numpy_helper.from_array(np.ascontiguousarray(output1, dtype=np.float32), "const1"),
        numpy_helper.from_array(np.array(0.0, dtype=np.float32), "zero"),
    ]
    nodes = [
        helper.make_node("ReduceMean", [input_name], ["mean"], keepdims=0),
        helper.make_node("Mul", ["mean", "zero"], ["nothing"]),
        helper.make_node("Add", ["const0", "nothing"], ["output0"]),
        helper.make_node("Add", ["const1", "nothing"], ["output1"]),
    ]
    graph = helper.make_graph(nodes, "fastsam_stand_in", [images], [out0, out1], initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="weldcell-tests")
    model.ir_version = 8
    model.metadata_props.append(onnx.StringStringEntryProto(key="task", value="segment"))
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


# --------------------------------------------------------------------------------------------------
# A scene of known instances


@dataclass(frozen=True)
class Instance:
    """A planted detection, in original-image pixels.

    kind: "box" = the prototype is positive everywhere, so the mask is the box itself (tests the crop);
    "disc" = centre (a, b), radius c; "rect" = x1 = a, y1 = b, x2 = c, y2 = d (edges between pixels).
    box_px: (x1, y1, x2, y2) detection box; score: confidence; channel: its prototype channel.
    """

    name: str
    kind: Literal["box", "disc", "rect"]
    shape: tuple[float, ...]
    box_px: tuple[float, float, float, float]
    score: float
    channel: int

    def field(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        """Signed distance in image pixels, > 0 inside the shape (before the box crop)."""
        if self.kind == "box":
            return np.full(np.broadcast(x, y).shape, 10.0)
        if self.kind == "disc":
            cx, cy, r = self.shape
            return r - np.hypot(x - cx, y - cy)
        x1, y1, x2, y2 = self.shape
        return np.minimum(np.minimum(x - x1, x2 - x), np.minimum(y - y1, y2 - y))

    def expected_mask(self, image_hw: tuple[int, int]) -> NDArray[np.bool_]:
        """The exact mask in image pixels: pixel (u, v) is inside when its centre (u, v) is."""
        v, u = np.mgrid[0 : image_hw[0], 0 : image_hw[1]].astype(np.float64)
        bx1, by1, bx2, by2 = self.box_px
        in_box = (u >= bx1) & (u < bx2) & (v >= by1) & (v < by2)
        return in_box & (self.field(u, v) > 0)


@dataclass(frozen=True)
class Scene:
    """Instances planted for an image of ``image_hw`` seen by a model of input ``size`` x ``size``."""

    image_hw: tuple[int, int]
    size: int
    instances: tuple[Instance, ...]
    noise_seed: int = 0

    @property
    def gain(self) -> float:
        return min(self.size / self.image_hw[0], self.size / self.image_hw[1])

    @property
    def pad_xy(self) -> tuple[float, float]:
        """Left and top letterbox padding in input pixels (both sides equal in the scenes used here)."""
        h, w = self.image_hw
        return (self.size - round(w * self.gain)) / 2, (self.size - round(h * self.gain)) / 2

    def to_input(self, x: float, y: float) -> tuple[float, float]:
        """Image coordinate -> input coordinate, for box corners (continuous coordinates, no half pixel)."""
        px, py = self.pad_xy
        return x * self.gain + px, y * self.gain + py

    def outputs(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """(output0, output1) encoding the instances, plus low-confidence clutter on every other anchor."""
        n = num_anchors(self.size)
        rng = np.random.default_rng(self.noise_seed)
        out0 = np.zeros((1, 4 + 1 + NUM_COEFFS, n), dtype=np.float32)
        # Clutter: random boxes, confidences below every threshold the tests use, random coefficients.
        cxy = rng.uniform(0, self.size, size=(2, n))
        wh = rng.uniform(4, self.size / 2, size=(2, n))
        out0[0, 0:2] = cxy
        out0[0, 2:4] = wh
        out0[0, 4] = rng.uniform(0.0, 0.2, size=n)
        out0[0, 5:] = rng.normal(size=(NUM_COEFFS, n))
        slots = rng.choice(n, size=len(self.instances), replace=False)
        for slot, inst in zip(slots, self.instances, strict=True):
            x1, y1 = self.to_input(inst.box_px[0], inst.box_px[1])
            x2, y2 = self.to_input(inst.box_px[2], inst.box_px[3])
            out0[0, 0:4, slot] = ((x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1)
            out0[0, 4, slot] = inst.score
            out0[0, 5:, slot] = 0.0
            out0[0, 5 + inst.channel, slot] = 1.0

        m = self.size // PROTO_STRIDE
        centre_in = PROTO_STRIDE * np.arange(m) + (PROTO_STRIDE - 1) / 2  # input pixel coordinate of proto centres
        px, py = self.pad_xy
        x_img = (centre_in - px + 0.5) / self.gain - 0.5
        y_img = (centre_in - py + 0.5) / self.gain - 0.5
        yy, xx = np.meshgrid(y_img, x_img, indexing="ij")
        out1 = np.zeros((1, NUM_COEFFS, m, m), dtype=np.float32)
        used: set[int] = set()
        for inst in self.instances:
            field = inst.field(xx, yy)
            # Instances sharing a channel (only in the timing scene) see the union of their shapes.
            out1[0, inst.channel] = np.maximum(out1[0, inst.channel], field) if inst.channel in used else field
            used.add(inst.channel)
        return out0, out1

    def build(self, path: Path, *, dynamic: bool = False) -> Path:
        out0, out1 = self.outputs()
        return build_fastsam_onnx(path, output0=out0, output1=out1, size=self.size, dynamic=dynamic)

    def instance(self, name: str) -> Instance:
        return next(i for i in self.instances if i.name == name)


def iou(a: NDArray[np.bool_], b: NDArray[np.bool_]) -> float:
    union = int(np.logical_or(a, b).sum())
    return 1.0 if union == 0 else int(np.logical_and(a, b).sum()) / union


def weld_scene(size: int = 256) -> Scene:
    """A 640 x 400 image (non-square: 48 px of letterbox padding top and bottom at size 256).

    plate (box) contains a disc; a rect inside the plate is overlapped by a smaller rect "tab" that sticks out
    of the plate; "disc_dup" is a slightly shifted, lower-scoring copy of the disc's box that NMS at 0.9 must
    suppress (box IoU 0.936); "faint" scores 0.3, below the default conf 0.4.
    """
    return Scene(
        image_hw=(400, 640),
        size=size,
        instances=(
            Instance("plate", "box", (), (39.5, 39.5, 599.5, 359.5), 0.90, 0),
            Instance("disc", "disc", (200.0, 200.0, 60.0), (139.5, 139.5, 260.5, 260.5), 0.85, 1),
            Instance("rect", "rect", (379.5, 119.5, 539.5, 299.5), (375.0, 115.0, 545.0, 305.0), 0.80, 2),
            Instance("tab", "rect", (499.5, 249.5, 619.5, 379.5), (495.0, 245.0, 625.0, 385.0), 0.75, 3),
            Instance("disc_dup", "disc", (202.0, 202.0, 45.0), (141.5, 141.5, 262.5, 262.5), 0.70, 4),
            Instance("faint", "disc", (580.0, 20.0, 15.0), (565.0, 5.0, 595.0, 35.0), 0.30, 5),
        ),
    )


def many_instances_scene(image_hw: tuple[int, int], size: int, count: int, seed: int = 1) -> Scene:
    """``count`` random discs with random scores, for a timing run (beyond 32, discs share channels)."""
    rng = np.random.default_rng(seed)
    h, w = image_hw
    insts = []
    for i in range(count):
        r = float(rng.uniform(20, min(h, w) / 4))
        cx, cy = float(rng.uniform(r, w - r)), float(rng.uniform(r, h - r))
        box = (cx - r - 2, cy - r - 2, cx + r + 2, cy + r + 2)
        insts.append(Instance(f"d{i}", "disc", (cx, cy, r), box, float(rng.uniform(0.45, 0.99)), i % NUM_COEFFS))
    return Scene(image_hw=image_hw, size=size, instances=tuple(insts), noise_seed=seed)
