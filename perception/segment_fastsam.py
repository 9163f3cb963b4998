"""FastSAM backend of the coarse segmenter: a user-supplied FastSAM ONNX export run by onnxruntime.

FastSAM (CASIA-IVA-Lab) is a YOLOv8-seg network trained with a single class ("object"). Its weights are
AGPL-licensed: weldcell neither ships nor downloads them, and no ``.onnx`` file belongs in this repository.
Users export the model once, on a machine that has ultralytics (torch is never needed here)::

    pip install ultralytics
    yolo export model=FastSAM-s.pt format=onnx imgsz=1024
    # or, in Python:
    #   from ultralytics import YOLO
    #   YOLO("FastSAM-s.pt").export(format="onnx", imgsz=1024)

and point ``FastSamSegmenter`` at the resulting ``FastSAM-s.onnx`` (``FastSAM-x.pt`` works the same way).
Do not pass ``nms=True`` to the export: this module runs its own NMS on the raw head output.

Tensor contract (checked when the model is loaded, and the output shapes again on every run):

    input  "images"  (1, 3, H, W) float32 (or float16 for a ``half=True`` export), RGB in [0, 1],
                     H and W multiples of 32 (1024 x 1024 for ``imgsz=1024``)
    output "output0" (1, 4 + 1 + 32, N) float32: per anchor the box (cx, cy, w, h) in input pixels,
                     the class-"object" confidence (already a sigmoid), and 32 mask coefficients;
                     N = (H/8)(W/8) + (H/16)(W/16) + (H/32)(W/32)  (21504 for 1024 x 1024)
    output "output1" (1, 32, H/4, W/4) float32: the mask prototypes (256 x 256 for 1024 x 1024)

Post-processing follows ultralytics' segmentation predictor as FastSAM runs it (``retina_masks=True``,
the default of FastSAM's ``Inference.py``):

1. letterbox: resize keeping the aspect ratio (bilinear), centre, pad with grey 114 to the model's static
   input size; a model with dynamic H, W gets ``imgsz`` on its long side and the minimal stride-32
   rectangle (ultralytics' ``auto=True``);
2. keep anchors with confidence > ``conf``; greedy NMS (IoU > ``iou`` suppresses, as torchvision.ops.nms),
   at most ``max_det`` detections, best first;
3. masks (``process_mask_native``/``scale_masks``): logits = coefficients @ prototypes, padding removed at
   prototype resolution, bilinear resize (half-pixel centres) to the original image, cropped to the box
   mapped back to original pixels (``scale_boxes``), then thresholded at logit > 0, i.e. sigmoid > 0.5.
   Ultralytics' non-retina path instead crops at prototype resolution and upsamples to the letterbox
   first; the two differ by at most a pixel along mask edges.

Point prompts. FastSAM's ``point_prompt`` walks all masks sorted by area, largest first, and for a
foreground point ORs together every mask that contains it. A weld cell needs one surface per prompt and
the union of nested masks (face within plate within workpiece within "whole frame") would merge exactly
the surfaces the seam step must keep apart, so this backend keeps the last mask that walk would paint:
**the smallest mask containing the prompt pixel** (ties: the higher confidence). Then

- where masks chosen for different prompts overlap, the pixel goes to the smaller mask (painting largest
  first, as FastSAM draws its masks; equal areas: the higher confidence wins);
- a prompt inside no mask gets an empty surface and score 0;
- a prompt whose mask was already chosen by an earlier prompt (two clicks on one surface) also gets an
  empty surface and score 0: a pixel has one label, and the earlier prompt keeps it.

The score of a surface is its detection confidence. Depth is not used: FastSAM sees colour only.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from perception.errors import BadCapture, PerceptionError
from perception.segmentation import FloatArray, SurfaceMasks

log = logging.getLogger(__name__)

INPUT_NAME = "images"
DETECTIONS_NAME = "output0"
PROTOTYPES_NAME = "output1"
NUM_CLASSES = 1  # FastSAM's single class, "object"
NUM_COEFFS = 32  # mask coefficients per detection = prototype channels
HEAD_STRIDES = (8, 16, 32)  # YOLOv8 detection heads: anchors per input pixel
STRIDE = 32  # input sides must be multiples of the coarsest head stride
PROTO_STRIDE = 4  # prototypes are at 1/4 of the input resolution
PAD_VALUE = 114  # ultralytics' letterbox grey
MAX_NMS = 30000  # candidates entering NMS (ultralytics' max_nms)
EXPORT_HINT = "export it with: yolo export model=FastSAM-s.pt format=onnx imgsz=1024 (see perception.segment_fastsam)"

# The prompt pre-filter samples each mask's logit at the prompt pixel with its own bilinear formula;
# masks within this margin of the threshold are rendered and decided on the rendered pixel, so float
# differences between that formula and cv2.resize can never change which mask a prompt selects.
_PREFILTER_MARGIN_LOGIT = 0.05


# --------------------------------------------------------------------------------------------------
# Value types


@dataclass(frozen=True)
class Letterbox:
    """How an original image maps into the network input: ``p_input = p_image * gain + (pad_x, pad_y)``.

    image_hw: (H, W) of the original image, pixels. input_hw: (H, W) of the network input, pixels.
    gain: input pixels per image pixel. pad_x, pad_y: left and top grey padding, input pixels.
    """

    image_hw: tuple[int, int]
    input_hw: tuple[int, int]
    gain: float
    pad_x: int
    pad_y: int

    def __post_init__(self) -> None:
        if min(self.image_hw) < 1 or min(self.input_hw) < 1 or not self.gain > 0:
            raise PerceptionError(f"invalid letterbox {self}")


@dataclass(frozen=True)
class InstanceMasks:
    """Every instance FastSAM found in one image (its "everything" mode), best confidence first.

    masks: (N, H, W) bool, in original image pixels.
    boxes_px: (N, 4) float64 boxes (x1, y1, x2, y2) in original image pixels; a mask never leaves its box.
    scores: (N,) float64 confidences in [0, 1], non-increasing.
    """

    masks: NDArray[np.bool_]
    boxes_px: FloatArray
    scores: FloatArray

    def __post_init__(self) -> None:
        masks = np.asarray(self.masks, dtype=bool)
        boxes = np.asarray(self.boxes_px, dtype=np.float64).reshape(-1, 4)
        scores = np.asarray(self.scores, dtype=np.float64).reshape(-1)
        if masks.ndim != 3:
            raise PerceptionError(f"masks must be (N, H, W), got {masks.shape}")
        if not masks.shape[0] == boxes.shape[0] == scores.shape[0]:
            raise PerceptionError(f"{masks.shape[0]} masks, {boxes.shape[0]} boxes and {scores.shape[0]} scores")
        object.__setattr__(self, "masks", masks)
        object.__setattr__(self, "boxes_px", boxes)
        object.__setattr__(self, "scores", scores)

    @property
    def count(self) -> int:
        return int(self.masks.shape[0])


@dataclass(frozen=True)
class _Detections:
    """Decoded network output for one image (internal).

    boxes_px: (N, 4) xyxy in original image pixels; scores: (N,) float64, best first;
    coeffs: (N, 32) float32; protos: (32, h, w) float32 prototypes with the letterbox padding removed.
    """

    boxes_px: FloatArray
    scores: FloatArray
    coeffs: NDArray[np.float32]
    protos: NDArray[np.float32]
    image_hw: tuple[int, int]


# --------------------------------------------------------------------------------------------------
# Pure steps


def letterbox(
    color_rgb: NDArray[np.uint8], *, input_hw: tuple[int, int], auto: bool = False, stride: int = STRIDE
) -> tuple[NDArray[np.uint8], Letterbox]:
    """Resize keeping the aspect ratio and pad with grey 114, centred, as ultralytics' ``LetterBox``.

    color_rgb: (H, W, 3) uint8. input_hw: (H_in, W_in) target size in pixels; with ``auto`` the padding is
    reduced to the smallest multiple of ``stride`` (for models with dynamic input size).
    Returns the (H_in', W_in', 3) uint8 image and its :class:`Letterbox`.
    """
    h0, w0 = int(color_rgb.shape[0]), int(color_rgb.shape[1])
    hin, win = input_hw
    gain = min(hin / h0, win / w0)
    new_w, new_h = round(w0 * gain), round(h0 * gain)
    dw, dh = float(win - new_w), float(hin - new_h)
    if auto:
        dw, dh = float(np.mod(dw, stride)), float(np.mod(dh, stride))
    dw, dh = dw / 2, dh / 2
    img = (
        color_rgb
        if (new_w, new_h) == (w0, h0)
        else cv2.resize(color_rgb, (new_w, new_h), interpolation=cv2.INTER_LINEAR)
    )
    # The -0.1/+0.1 puts an odd padding's extra pixel on the bottom/right, as ultralytics does.
    top, bottom = round(dh - 0.1), round(dh + 0.1)
    left, right = round(dw - 0.1), round(dw + 0.1)
    out = cv2.copyMakeBorder(img, top, bottom, left, right, cv2.BORDER_CONSTANT, value=(PAD_VALUE,) * 3)
    lb = Letterbox(image_hw=(h0, w0), input_hw=(int(out.shape[0]), int(out.shape[1])), gain=gain, pad_x=left, pad_y=top)
    return np.asarray(out, dtype=np.uint8), lb


def to_input_tensor(img_rgb: NDArray[np.uint8], *, dtype: type[np.floating[Any]] = np.float32) -> NDArray[Any]:
    """(H, W, 3) uint8 RGB -> (1, 3, H, W) in [0, 1] (NCHW, the layout of the "images" input)."""
    chw = np.ascontiguousarray(img_rgb.transpose(2, 0, 1))[None]
    out = chw.astype(np.float32)
    out *= np.float32(1.0 / 255.0)
    return out.astype(dtype, copy=False)


def nms(boxes_xyxy: FloatArray, scores: FloatArray, *, iou: float, max_det: int | None = None) -> NDArray[np.intp]:
    """Greedy non-maximum suppression with torchvision's semantics.

    boxes_xyxy: (N, 4) (x1, y1, x2, y2); scores: (N,). A box is dropped when its IoU with an already kept,
    higher-scoring box is greater than ``iou``. Returns kept indices, highest score first (at most ``max_det``).
    """
    boxes = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4)
    order = np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable")
    x1, y1, x2, y2 = boxes.T
    areas = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    keep: list[int] = []
    limit = len(order) if max_det is None else max_det
    while order.size and len(keep) < limit:
        i = int(order[0])
        keep.append(i)
        rest = order[1:]
        w = np.clip(np.minimum(x2[i], x2[rest]) - np.maximum(x1[i], x1[rest]), 0, None)
        h = np.clip(np.minimum(y2[i], y2[rest]) - np.maximum(y1[i], y1[rest]), 0, None)
        inter = w * h
        union = areas[i] + areas[rest] - inter
        overlap = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
        order = rest[overlap <= iou]
    return np.asarray(keep, dtype=np.intp)


def decode_detections(
    output0: NDArray[np.floating[Any]], *, conf: float, iou: float, max_det: int
) -> tuple[FloatArray, FloatArray, NDArray[np.float32]]:
    """Confidence filter and NMS on the raw head output (ultralytics' ``non_max_suppression``, nc=1).

    output0: (1, 37, N) as documented in the module docstring.
    Returns boxes (M, 4) xyxy in input (letterbox) pixels, scores (M,) best first, coefficients (M, 32).
    """
    pred = np.asarray(output0)[0]
    scores_all = pred[4]
    cand = np.flatnonzero(scores_all > conf)
    if cand.size > MAX_NMS:
        cand = cand[np.argsort(-scores_all[cand], kind="stable")[:MAX_NMS]]
    cx, cy, w, h = (pred[j, cand].astype(np.float64) for j in range(4))
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)
    scores = scores_all[cand].astype(np.float64)
    keep = nms(boxes, scores, iou=iou, max_det=max_det)
    coeffs = np.ascontiguousarray(pred[4 + NUM_CLASSES :, cand[keep]].T, dtype=np.float32)
    return boxes[keep], scores[keep], coeffs


def boxes_to_image(boxes_input: FloatArray, lb: Letterbox) -> FloatArray:
    """(N, 4) xyxy in input pixels -> original image pixels, clipped to the image (``scale_boxes``)."""
    out = np.array(boxes_input, dtype=np.float64).reshape(-1, 4)
    out[:, [0, 2]] -= lb.pad_x
    out[:, [1, 3]] -= lb.pad_y
    out /= lb.gain
    h0, w0 = lb.image_hw
    out[:, [0, 2]] = out[:, [0, 2]].clip(0, w0)
    out[:, [1, 3]] = out[:, [1, 3]].clip(0, h0)
    return out


def unpad_prototypes(protos: NDArray[np.float32], image_hw: tuple[int, int]) -> NDArray[np.float32]:
    """Cut the letterbox padding off (32, h, w) prototypes, as ultralytics' ``scale_masks`` does.

    The padding is recomputed at prototype resolution from the original (H, W) and truncated to whole
    prototype pixels. Returns a (32, h', w') view.
    """
    _, mh, mw = protos.shape
    h0, w0 = image_hw
    gain = min(mh / h0, mw / w0)
    pad_w, pad_h = (mw - w0 * gain) / 2, (mh - h0 * gain) / 2
    top, left = int(pad_h), int(pad_w)
    bottom, right = max(int(mh - pad_h), top + 1), max(int(mw - pad_w), left + 1)
    return protos[:, top:bottom, left:right]


def _resize_coords(
    n_dst: int, n_src: int, dst: NDArray[np.float64]
) -> tuple[NDArray[np.intp], NDArray[np.intp], FloatArray]:
    """Source taps and weight of destination coordinates under a half-pixel-centre bilinear resize.

    Same mapping as cv2.resize(INTER_LINEAR) and torch's interpolate(align_corners=False) without
    antialiasing: src = (dst + 0.5) * n_src / n_dst - 0.5, clamped to the edge pixels.
    """
    src = np.clip((dst + 0.5) * (n_src / n_dst) - 0.5, 0.0, n_src - 1)
    i0 = np.floor(src).astype(np.intp)
    i1 = np.minimum(i0 + 1, n_src - 1)
    return i0, i1, src - i0


def sample_prototypes(protos: NDArray[np.float32], image_hw: tuple[int, int], uv: NDArray[np.intp]) -> FloatArray:
    """Prototype values at image pixels, bilinearly, as the full-resolution mask resize would give them.

    protos: (32, h, w) unpadded prototypes; uv: (K, 2) integer pixels (column, row). Returns (32, K).
    Because the resize is linear, ``coeffs @ sample_prototypes(...)`` equals the mask logits at those pixels.
    """
    _, h, w = protos.shape
    h0, w0 = image_hw
    x0, x1, fx = _resize_coords(w0, w, uv[:, 0].astype(np.float64))
    y0, y1, fy = _resize_coords(h0, h, uv[:, 1].astype(np.float64))
    p = protos.astype(np.float64)
    top = p[:, y0, x0] * (1 - fx) + p[:, y0, x1] * fx
    bot = p[:, y1, x0] * (1 - fx) + p[:, y1, x1] * fx
    return np.asarray(top * (1 - fy) + bot * fy)


def _box_pixel_range(box: FloatArray, image_hw: tuple[int, int]) -> tuple[int, int, int, int]:
    """Integer pixel bounds [c0, c1) x [r0, r1) of ``c >= x1 and c < x2`` (ultralytics' ``crop_mask``)."""
    h0, w0 = image_hw
    c0, r0 = max(0, math.ceil(box[0])), max(0, math.ceil(box[1]))
    c1, r1 = min(w0, math.ceil(box[2])), min(h0, math.ceil(box[3]))
    return c0, max(c0, c1), r0, max(r0, r1)


@dataclass(frozen=True)
class BoxMask:
    """One instance mask stored inside its box window (a mask never leaves its box).

    row0, col0: image pixel of the window's top-left corner; mask: (h, w) bool, ``mask[r - row0, c - col0]``
    for image pixel (column c, row r). h or w is 0 for a box that holds no pixel centre.
    """

    row0: int
    col0: int
    mask: NDArray[np.bool_]

    @property
    def area(self) -> int:
        return int(np.count_nonzero(self.mask))

    def contains(self, uv: NDArray[np.intp]) -> NDArray[np.bool_]:
        """(K, 2) integer pixels (column, row) -> (K,) whether each lies in the mask."""
        r, c = uv[:, 1] - self.row0, uv[:, 0] - self.col0
        h, w = self.mask.shape
        inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        out = np.zeros(uv.shape[0], dtype=bool)
        out[inside] = self.mask[r[inside], c[inside]]
        return out

    def window(self, image: NDArray[Any]) -> NDArray[Any]:
        """The view of an (H, W) image array covered by this mask's box."""
        h, w = self.mask.shape
        return image[self.row0 : self.row0 + h, self.col0 : self.col0 + w]


def render_box_masks(
    coeffs: NDArray[np.float32], boxes_px: FloatArray, protos: NDArray[np.float32], image_hw: tuple[int, int]
) -> list[BoxMask]:
    """Full-resolution masks: sigmoid(coeffs @ protos) > 0.5, resized to the image and cropped to the box.

    coeffs: (N, 32); boxes_px: (N, 4) xyxy image pixels; protos: (32, h, w) unpadded prototypes;
    image_hw: (H, W). Returns N :class:`BoxMask`. One cv2.resize per mask (about 0.5 ms at 1280 x 720).
    """
    h0, w0 = image_hw
    _, h, w = protos.shape
    logits = (coeffs.astype(np.float32) @ protos.reshape(NUM_COEFFS, -1)).reshape(-1, h, w)
    out = []
    for i in range(logits.shape[0]):
        c0, c1, r0, r1 = _box_pixel_range(boxes_px[i], image_hw)
        if c1 <= c0 or r1 <= r0:
            out.append(BoxMask(r0, c0, np.zeros((0, 0), dtype=bool)))
            continue
        full = cv2.resize(logits[i], (w0, h0), interpolation=cv2.INTER_LINEAR)
        out.append(BoxMask(r0, c0, full[r0:r1, c0:c1] > 0))
    return out


def render_masks(
    coeffs: NDArray[np.float32], boxes_px: FloatArray, protos: NDArray[np.float32], image_hw: tuple[int, int]
) -> NDArray[np.bool_]:
    """As :func:`render_box_masks`, pasted into full frames: (N, H, W) bool."""
    box_masks = render_box_masks(coeffs, boxes_px, protos, image_hw)
    out = np.zeros((len(box_masks), *image_hw), dtype=bool)
    for i, bm in enumerate(box_masks):
        bm.window(out[i])[...] = bm.mask
    return out


def pick_smallest_containing(contains: NDArray[np.bool_], areas: NDArray[np.int64]) -> NDArray[np.intp]:
    """For each prompt, the smallest mask containing it (ties: the lower index, i.e. higher confidence).

    contains: (N, K) whether mask n contains prompt k; areas: (N,) mask areas in pixels.
    Returns (K,) mask indices, -1 where no mask contains the prompt.
    """
    n, k = contains.shape
    if n == 0:
        return np.full(k, -1, dtype=np.intp)
    cost = np.where(contains, areas[:, None].astype(np.float64), np.inf)
    best = np.argmin(cost, axis=0).astype(np.intp)
    best[~contains.any(axis=0)] = -1
    return best


def assemble_labels(
    masks: Sequence[BoxMask], chosen: NDArray[np.intp], scores: FloatArray, image_hw: tuple[int, int]
) -> tuple[NDArray[np.int32], tuple[float, ...]]:
    """Label image from one chosen mask per prompt; overlaps go to the smaller mask.

    masks: N masks in descending confidence; chosen: (K,) mask index per prompt or -1; scores: (N,)
    confidences; image_hw: (H, W). A mask chosen by several prompts belongs to the first of them; the
    others, and prompts without a mask, get an empty surface and score 0.
    Returns labels (H, W) int32 (-1 = no prompted surface) and K scores.
    """
    labels = np.full(image_hw, -1, dtype=np.int32)
    owner: dict[int, int] = {}
    for k, n in enumerate(chosen.tolist()):
        if n >= 0 and n not in owner:
            owner[n] = k
    out_scores = [0.0] * len(chosen)
    # Paint largest first so the smaller mask ends on top; equal areas: the higher confidence on top.
    for n in sorted(owner, key=lambda n: (-masks[n].area, -n)):
        masks[n].window(labels)[masks[n].mask] = owner[n]
        out_scores[owner[n]] = float(scores[n])
    return labels, tuple(out_scores)


# --------------------------------------------------------------------------------------------------
# The backend


def _shape_str(shape: Sequence[Any]) -> str:
    return "(" + ", ".join(str(d) if isinstance(d, int) else (repr(d) if d else "?") for d in shape) + ")"


def _static(dim: Any) -> int | None:
    return int(dim) if isinstance(dim, int) and dim > 0 else None


class FastSamSegmenter:
    """FastSAM, exported to ONNX by the user, run by onnxruntime: one mask per point prompt.

    model_path: the ONNX export (see the module docstring for the command and the tensor contract).
    imgsz: long side of the network input when the export has a dynamic input size; a static export's
        own size always wins. conf: confidence threshold; iou: NMS IoU threshold (FastSAM's defaults
        0.4 and 0.9). max_det: detections kept after NMS. providers: onnxruntime execution providers.
    """

    name = "fastsam"

    def __init__(
        self,
        model_path: str | os.PathLike[str],
        *,
        imgsz: int = 1024,
        conf: float = 0.4,
        iou: float = 0.9,
        max_det: int = 300,
        providers: Sequence[str] = ("CPUExecutionProvider",),
    ) -> None:
        if not 0.0 <= conf <= 1.0 or not 0.0 <= iou <= 1.0:
            raise PerceptionError(f"conf and iou must lie in [0, 1], got conf={conf}, iou={iou}")
        if imgsz < STRIDE or imgsz % STRIDE:
            raise PerceptionError(f"imgsz must be a positive multiple of {STRIDE}, got {imgsz}")
        if max_det < 1:
            raise PerceptionError(f"max_det must be at least 1, got {max_det}")
        try:
            import onnxruntime as ort
        except ImportError as err:  # pragma: no cover - onnxruntime is a hard dependency of weldcell
            raise PerceptionError("the FastSAM backend needs onnxruntime: pip install onnxruntime") from err

        path = Path(model_path)
        if not path.is_file():
            raise PerceptionError(f"FastSAM model {path} does not exist; {EXPORT_HINT}")
        available = set(ort.get_available_providers())
        missing = [p for p in providers if p not in available]
        if missing or not providers:
            raise PerceptionError(
                f"onnxruntime execution providers {missing or list(providers)} are not available here; "
                f"available: {sorted(available)}"
            )
        options = ort.SessionOptions()
        options.log_severity_level = 3  # errors only; onnxruntime's warnings are not ours to print
        try:
            self._session = ort.InferenceSession(str(path), sess_options=options, providers=list(providers))
        except Exception as err:  # onnxruntime raises its own pybind exception types for corrupt files
            raise PerceptionError(f"cannot load FastSAM model {path}: {err}; {EXPORT_HINT}") from err

        self.model_path = path
        self.conf = float(conf)
        self.iou = float(iou)
        self.max_det = int(max_det)
        self._input_dtype: type[np.floating[Any]] = np.float32
        self._input_hw, self._dynamic = self._check_contract(imgsz)
        meta = self._session.get_modelmeta().custom_metadata_map
        if meta.get("task", "segment") != "segment":
            raise PerceptionError(f"{path} is a {meta['task']!r} model; FastSAM is a 'segment' model; {EXPORT_HINT}")
        log.info(
            "FastSAM model %s: input %dx%d%s, conf %.2f, iou %.2f, providers %s",
            path,
            self._input_hw[1],
            self._input_hw[0],
            " (dynamic)" if self._dynamic else "",
            self.conf,
            self.iou,
            list(providers),
        )

    # ---- contract -------------------------------------------------------------------------------

    def _check_contract(self, imgsz: int) -> tuple[tuple[int, int], bool]:
        inputs = {i.name: i for i in self._session.get_inputs()}
        outputs = {o.name: o for o in self._session.get_outputs()}
        where = f"FastSAM model {self.model_path}"
        if set(inputs) != {INPUT_NAME} or not {DETECTIONS_NAME, PROTOTYPES_NAME} <= set(outputs):
            raise PerceptionError(
                f"{where} has inputs {sorted(inputs)} and outputs {sorted(outputs)}; expected input "
                f"{INPUT_NAME!r} and outputs {DETECTIONS_NAME!r}, {PROTOTYPES_NAME!r}; {EXPORT_HINT}"
            )
        inp = inputs[INPUT_NAME]
        shape = list(inp.shape)
        if len(shape) != 4 or shape[1] != 3 or _static(shape[0]) not in (None, 1):
            raise PerceptionError(
                f"{where}: input {INPUT_NAME!r} has shape {_shape_str(shape)}; expected (1, 3, H, W); {EXPORT_HINT}"
            )
        if inp.type == "tensor(float16)":
            self._input_dtype = np.float16
        elif inp.type != "tensor(float)":
            raise PerceptionError(f"{where}: input {INPUT_NAME!r} is {inp.type}; expected tensor(float)")
        h, w = _static(shape[2]), _static(shape[3])
        dynamic = h is None or w is None
        input_hw = (imgsz, imgsz) if dynamic else (int(h or 0), int(w or 0))
        if input_hw[0] % STRIDE or input_hw[1] % STRIDE:
            raise PerceptionError(f"{where}: input size {input_hw[1]}x{input_hw[0]} is not a multiple of {STRIDE}")
        if not dynamic:
            self._check_output_shapes(
                list(outputs[DETECTIONS_NAME].shape), list(outputs[PROTOTYPES_NAME].shape), input_hw, static_only=True
            )
        return input_hw, dynamic

    def _check_output_shapes(
        self, det_shape: list[Any], proto_shape: list[Any], input_hw: tuple[int, int], *, static_only: bool = False
    ) -> None:
        """Compare output shapes with the contract; symbolic dimensions pass when ``static_only``."""
        h, w = input_hw
        n = sum((h // s) * (w // s) for s in HEAD_STRIDES)
        want_det = (1, 4 + NUM_CLASSES + NUM_COEFFS, n)
        want_proto = (1, NUM_COEFFS, h // PROTO_STRIDE, w // PROTO_STRIDE)
        for name, got, want in ((DETECTIONS_NAME, det_shape, want_det), (PROTOTYPES_NAME, proto_shape, want_proto)):
            ok = len(got) == len(want) and all(
                (static_only and not isinstance(g, int)) or g == e for g, e in zip(got, want, strict=True)
            )
            if not ok:
                extra = ""
                if name == DETECTIONS_NAME and len(got) == 3 and got[2] == want[2] and isinstance(got[1], int):
                    extra = f" ({got[1] - 4 - NUM_COEFFS} classes: a YOLOv8-seg model, but not FastSAM's single class)"
                raise PerceptionError(
                    f"FastSAM model {self.model_path}: output {name!r} has shape {_shape_str(got)}, expected "
                    f"{_shape_str(want)} for a {w}x{h} input{extra}; {EXPORT_HINT} (without nms=True)"
                )

    @property
    def input_hw(self) -> tuple[int, int]:
        """(H, W) of the network input in pixels (``imgsz`` square for a dynamic export)."""
        return self._input_hw

    # ---- inference ------------------------------------------------------------------------------

    def _detect(self, color_rgb: NDArray[np.uint8]) -> _Detections:
        t0 = time.perf_counter()
        img, lb = letterbox(color_rgb, input_hw=self._input_hw, auto=self._dynamic)
        x = to_input_tensor(img, dtype=self._input_dtype)
        t1 = time.perf_counter()
        try:
            out0, out1 = self._session.run([DETECTIONS_NAME, PROTOTYPES_NAME], {INPUT_NAME: x})
        except Exception as err:
            raise PerceptionError(f"FastSAM inference failed on a {x.shape} input: {err}") from err
        t2 = time.perf_counter()
        self._check_output_shapes(list(out0.shape), list(out1.shape), lb.input_hw)
        boxes_in, scores, coeffs = decode_detections(out0, conf=self.conf, iou=self.iou, max_det=self.max_det)
        protos = unpad_prototypes(np.asarray(out1[0], dtype=np.float32), lb.image_hw)
        t3 = time.perf_counter()
        log.debug(
            "FastSAM: letterbox %.1f ms, network %.1f ms, decode %.1f ms, %d detections above conf %.2f",
            1e3 * (t1 - t0),
            1e3 * (t2 - t1),
            1e3 * (t3 - t2),
            len(scores),
            self.conf,
        )
        return _Detections(boxes_to_image(boxes_in, lb), scores, coeffs, protos, lb.image_hw)

    def everything(self, color_rgb: NDArray[np.uint8]) -> InstanceMasks:
        """All instances in the image (FastSAM's everything mode), best confidence first.

        color_rgb: (H, W, 3) uint8 RGB. Memory is N x H x W bytes (300 masks at 1280 x 720: 276 MB).
        """
        det = self._detect(_check_color(color_rgb))
        masks = render_masks(det.coeffs, det.boxes_px, det.protos, det.image_hw)
        return InstanceMasks(masks=masks, boxes_px=det.boxes_px, scores=det.scores)

    def segment(
        self,
        color_rgb: NDArray[np.uint8],
        depth_m: NDArray[np.float32],
        prompts_px: FloatArray,
        *,
        points_camera: NDArray[np.float32] | None = None,
    ) -> SurfaceMasks:
        """One surface per prompt: the smallest FastSAM mask containing the prompt pixel.

        color_rgb: (H, W, 3) uint8 RGB; depth_m: (H, W) float32 metres (checked for shape, otherwise
        unused); prompts_px: (K, 2) pixel (u, v) = (column, row), rounded to the nearest pixel.
        Overlaps, empty surfaces and duplicates follow the rules in the module docstring.
        """
        img = _check_color(color_rgb)
        image_hw = (int(img.shape[0]), int(img.shape[1]))
        if np.shape(depth_m) != image_hw:
            raise BadCapture(f"depth is {np.shape(depth_m)} but the colour image is {image_hw}; they must share a grid")
        prompts = np.asarray(prompts_px, dtype=np.float64).reshape(-1, 2)
        uv = _prompt_pixels(prompts, image_hw)
        if uv.shape[0] == 0:
            return SurfaceMasks(np.full(image_hw, -1, dtype=np.int32), prompts, ())

        det = self._detect(img)
        t0 = time.perf_counter()
        # Cheap pre-filter: the logit of every detection at every prompt pixel, without rendering masks.
        logits = det.coeffs.astype(np.float64) @ sample_prototypes(det.protos, image_hw, uv)  # (N, K)
        c0, c1, r0, r1 = (np.asarray(b)[:, None] for b in _box_ranges(det.boxes_px, image_hw))
        in_box = (uv[None, :, 0] >= c0) & (uv[None, :, 0] < c1) & (uv[None, :, 1] >= r0) & (uv[None, :, 1] < r1)
        candidates = np.flatnonzero(((logits > -_PREFILTER_MARGIN_LOGIT) & in_box).any(axis=1))

        masks = render_box_masks(det.coeffs[candidates], det.boxes_px[candidates], det.protos, image_hw)
        # Containment is decided on the rendered pixels, not on the pre-filter's estimate.
        contains = np.array([m.contains(uv) for m in masks], dtype=bool).reshape(len(masks), uv.shape[0])
        areas = np.array([m.area for m in masks], dtype=np.int64)
        chosen = pick_smallest_containing(contains, areas)
        labels, scores = assemble_labels(masks, chosen, det.scores[candidates], image_hw)
        log.debug(
            "FastSAM prompts: %d prompts, %d candidate masks rendered, %d surfaces, %.1f ms",
            uv.shape[0],
            candidates.size,
            sum(s > 0 for s in scores),
            1e3 * (time.perf_counter() - t0),
        )
        for k in np.flatnonzero(chosen < 0):
            log.debug("FastSAM: prompt %d at (u=%g, v=%g) lies in no mask", k, prompts[k, 0], prompts[k, 1])
        return SurfaceMasks(labels, prompts, scores)


def _box_ranges(boxes_px: FloatArray, image_hw: tuple[int, int]) -> tuple[list[int], list[int], list[int], list[int]]:
    ranges = [_box_pixel_range(b, image_hw) for b in boxes_px]
    return [r[0] for r in ranges], [r[1] for r in ranges], [r[2] for r in ranges], [r[3] for r in ranges]


def _check_color(color_rgb: Any) -> NDArray[np.uint8]:
    img = np.asarray(color_rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or min(img.shape[:2]) < 1:
        raise BadCapture(f"colour image must be (H, W, 3) uint8 RGB, got {img.shape} {img.dtype}")
    return img


def _prompt_pixels(prompts: FloatArray, image_hw: tuple[int, int]) -> NDArray[np.intp]:
    if not np.all(np.isfinite(prompts)):
        raise BadCapture("prompts contain NaN or inf")
    uv = np.floor(prompts + 0.5).astype(np.intp)
    h0, w0 = image_hw
    bad = (uv[:, 0] < 0) | (uv[:, 0] >= w0) | (uv[:, 1] < 0) | (uv[:, 1] >= h0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise BadCapture(f"prompt {i} at (u={prompts[i, 0]:g}, v={prompts[i, 1]:g}) lies outside the {w0}x{h0} image")
    return uv
