"""FastSAM backend: decoding, NMS, mask assembly, point prompts and model checks, against planted ground truth.

The model is a stand-in built by ``fastsam_fixture`` (no FastSAM weights are involved): it has FastSAM's
tensor interface and emits outputs that encode known shapes in a 640 x 400 image, so the letterbox padding
(48 px top and bottom at input 256) has to be removed exactly for the masks to match.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from perception.errors import BadCapture, PerceptionError
from perception.segment_fastsam import (
    FastSamSegmenter,
    letterbox,
    nms,
    pick_smallest_containing,
    to_input_tensor,
)
from perception.segmentation import Segmenter
from tests.perception.fastsam_fixture import (
    NUM_COEFFS,
    Scene,
    build_fastsam_onnx,
    iou,
    many_instances_scene,
    num_anchors,
    weld_scene,
)

# Prompts (u, v) on the weld scene and what each must select.
PROMPTS = np.array(
    [
        [100.0, 320.0],  # 0: plate only
        [200.0, 200.0],  # 1: disc centre, inside the plate too -> the disc (smaller)
        [420.0, 150.0],  # 2: rect, inside the plate -> rect
        [610.2, 369.7],  # 3: tab where it sticks out of the plate (rounds to pixel 610, 370)
        [10.0, 10.0],  # 4: in no mask -> empty surface, score 0
        [205.0, 195.0],  # 5: the disc again -> already taken by prompt 1 -> empty, score 0
    ]
)


@pytest.fixture(scope="module")
def scene() -> Scene:
    return weld_scene()


@pytest.fixture(scope="module")
def model_path(tmp_path_factory: pytest.TempPathFactory, scene: Scene) -> Path:
    return scene.build(tmp_path_factory.mktemp("fastsam") / "fastsam_stand_in.onnx")


@pytest.fixture(scope="module")
def segmenter(model_path: Path) -> FastSamSegmenter:
    return FastSamSegmenter(model_path)


@pytest.fixture(scope="module")
def image(scene: Scene) -> np.ndarray:
    rng = np.random.default_rng(3)
    return rng.integers(0, 256, (*scene.image_hw, 3), dtype=np.uint8)


def depth_for(img: np.ndarray) -> np.ndarray:
    return np.full(img.shape[:2], 0.6, np.float32)


def expected_labels(scene: Scene, owners: dict[str, int]) -> np.ndarray:
    """Paint the exact masks, largest first, so the smaller mask owns any overlap."""
    labels = np.full(scene.image_hw, -1, np.int32)
    masks = {name: scene.instance(name).expected_mask(scene.image_hw) for name in owners}
    for name in sorted(owners, key=lambda n: -int(masks[n].sum())):
        labels[masks[name]] = owners[name]
    return labels


# --------------------------------------------------------------------------------------------------
# Decoding: everything mode


def test_is_a_segmenter_with_the_models_input_size(segmenter: FastSamSegmenter) -> None:
    assert isinstance(segmenter, Segmenter)
    assert segmenter.name == "fastsam"
    assert segmenter.input_hw == (256, 256)  # read from the model, not from imgsz=1024


def test_everything_filters_low_confidence_and_suppresses_the_duplicate(
    segmenter: FastSamSegmenter, scene: Scene, image: np.ndarray
) -> None:
    res = segmenter.everything(image)
    assert res.count == 4  # faint (0.3 < conf 0.4) filtered, disc_dup (box IoU 0.936 > 0.9) suppressed
    np.testing.assert_allclose(res.scores, [0.90, 0.85, 0.80, 0.75], atol=1e-6)
    assert res.masks.shape == (4, 400, 640)
    for k, name in enumerate(["plate", "disc", "rect", "tab"]):
        inst = scene.instance(name)
        assert iou(res.masks[k], inst.expected_mask(scene.image_hw)) > 0.98, name
        np.testing.assert_allclose(res.boxes_px[k], inst.box_px, atol=1e-3)


def test_box_crop_is_exact_in_original_pixels(segmenter: FastSamSegmenter, scene: Scene, image: np.ndarray) -> None:
    # The plate's prototype is positive everywhere: its mask is the box, mapped back through the letterbox.
    plate = segmenter.everything(image).masks[0]
    want = scene.instance("plate").expected_mask(scene.image_hw)
    assert want.sum() == 560 * 320
    np.testing.assert_array_equal(plate, want)


def test_disc_lands_on_the_exact_circle(segmenter: FastSamSegmenter, scene: Scene, image: np.ndarray) -> None:
    # A half-pixel slip in the prototype -> image mapping would shift the disc by 5 px and fail this.
    disc = segmenter.everything(image).masks[1]
    want = scene.instance("disc").expected_mask(scene.image_hw)
    assert iou(disc, want) > 0.99
    v, u = np.nonzero(disc)
    assert abs(u.mean() - 200.0) < 0.3 and abs(v.mean() - 200.0) < 0.3


def test_lower_conf_keeps_the_faint_detection(model_path: Path, scene: Scene, image: np.ndarray) -> None:
    res = FastSamSegmenter(model_path, conf=0.25).everything(image)
    assert res.count == 5
    assert res.scores[-1] == pytest.approx(0.30, abs=1e-6)
    # Its radius is 1.5 prototype pixels: bilinear interpolation rounds the distance field's tip by ~0.8 px.
    faint = res.masks[-1]
    assert iou(faint, scene.instance("faint").expected_mask(scene.image_hw)) > 0.9
    v, u = np.nonzero(faint)
    assert abs(u.mean() - 580.0) < 0.5 and abs(v.mean() - 20.0) < 0.5


def test_looser_nms_keeps_the_duplicate(model_path: Path, scene: Scene, image: np.ndarray) -> None:
    res = FastSamSegmenter(model_path, iou=0.95).everything(image)
    assert res.count == 5
    np.testing.assert_allclose(res.scores, [0.90, 0.85, 0.80, 0.75, 0.70], atol=1e-6)
    assert iou(res.masks[4], scene.instance("disc_dup").expected_mask(scene.image_hw)) > 0.98


def test_max_det_keeps_the_best(model_path: Path, image: np.ndarray) -> None:
    res = FastSamSegmenter(model_path, max_det=2).everything(image)
    np.testing.assert_allclose(res.scores, [0.90, 0.85], atol=1e-6)


# --------------------------------------------------------------------------------------------------
# Point prompts


def test_each_prompt_gets_the_smallest_mask_containing_it(
    segmenter: FastSamSegmenter, scene: Scene, image: np.ndarray
) -> None:
    out = segmenter.segment(image, depth_for(image), PROMPTS)
    assert out.count == len(PROMPTS)
    np.testing.assert_array_equal(out.prompts_px, PROMPTS)
    np.testing.assert_allclose(out.scores, [0.90, 0.85, 0.80, 0.75, 0.0, 0.0], atol=1e-6)

    want = expected_labels(scene, {"plate": 0, "disc": 1, "rect": 2, "tab": 3})
    for k in range(4):
        assert iou(out.mask(k), want == k) > 0.98, k
    assert not out.mask(4).any()  # prompt outside every mask
    assert not out.mask(5).any()  # second prompt on the disc: the first one keeps it
    for k in range(4):  # every prompt lies on its own surface
        u, v = np.floor(PROMPTS[k] + 0.5).astype(int)
        assert out.labels[v, u] == k


def test_overlaps_go_to_the_smaller_mask(segmenter: FastSamSegmenter, image: np.ndarray) -> None:
    out = segmenter.segment(image, depth_for(image), PROMPTS[:4])
    assert out.labels[200, 200] == 1  # disc (11 310 px) over plate (179 200 px)
    assert out.labels[270, 520] == 3  # tab (15 600 px) over rect (28 800 px) over plate
    assert out.labels[200, 450] == 2  # rect over plate
    assert out.labels[300, 100] == 0  # plate alone
    assert out.labels[10, 10] == -1  # nobody's
    assert out.labels[370, 610] == 3  # tab outside the plate
    # The tab's whole rectangle is labelled 3, including the part it shares with the rect.
    assert (out.labels[250:380, 500:620] == 3).mean() > 0.99


def test_prompt_order_does_not_change_the_masks(segmenter: FastSamSegmenter, image: np.ndarray) -> None:
    order = [3, 2, 1, 0]
    a = segmenter.segment(image, depth_for(image), PROMPTS[:4])
    b = segmenter.segment(image, depth_for(image), PROMPTS[order])
    for new_k, old_k in enumerate(order):
        np.testing.assert_array_equal(b.mask(new_k), a.mask(old_k))
        assert b.scores[new_k] == a.scores[old_k]


def test_fast_prompt_path_matches_brute_force_on_clutter(tmp_path: Path) -> None:
    # 30 overlapping discs; the prompt path pre-filters on sampled logits and renders only box windows.
    # Oracle: full-frame everything() masks, a Python loop over prompts, painting largest first.
    scene = many_instances_scene((400, 640), 256, count=30, seed=7)
    seg = FastSamSegmenter(scene.build(tmp_path / "clutter.onnx"))
    img = np.zeros((400, 640, 3), np.uint8)
    rng = np.random.default_rng(11)
    prompts = np.column_stack([rng.uniform(0, 639, 40), rng.uniform(0, 399, 40)])
    out = seg.segment(img, depth_for(img), prompts)

    every = seg.everything(img)
    assert every.count == 30
    areas = every.masks.reshape(every.count, -1).sum(axis=1)
    owner: dict[int, int] = {}
    want_scores = [0.0] * len(prompts)
    for k, (u, v) in enumerate(np.floor(prompts + 0.5).astype(int)):
        inside = [n for n in range(every.count) if every.masks[n, v, u]]
        if inside:
            n = min(inside, key=lambda n: (areas[n], n))
            if n not in owner:
                owner[n] = k
                want_scores[k] = float(every.scores[n])
    want = np.full((400, 640), -1, np.int32)
    for n in sorted(owner, key=lambda n: (-areas[n], -n)):
        want[every.masks[n]] = owner[n]
    assert 5 < len(owner) < len(prompts)  # the draw exercises selection, duplicates and misses
    np.testing.assert_array_equal(out.labels, want)
    np.testing.assert_allclose(out.scores, want_scores)


def test_pick_smallest_containing_breaks_ties_by_confidence() -> None:
    contains = np.array([[True, False, False], [True, True, False], [True, True, False]])
    areas = np.array([100, 50, 50])
    np.testing.assert_array_equal(pick_smallest_containing(contains, areas), [1, 1, -1])
    assert pick_smallest_containing(np.zeros((0, 2), bool), np.zeros(0, np.int64)).tolist() == [-1, -1]


def test_no_prompts_gives_no_surfaces(segmenter: FastSamSegmenter, image: np.ndarray) -> None:
    out = segmenter.segment(image, depth_for(image), np.zeros((0, 2)))
    assert out.count == 0 and out.labels.shape == (400, 640) and (out.labels == -1).all()


@pytest.mark.parametrize("uv", [[640.0, 10.0], [-0.6, 10.0], [10.0, 399.6], [np.nan, 1.0]])
def test_prompt_outside_the_image_is_refused(segmenter: FastSamSegmenter, image: np.ndarray, uv: list[float]) -> None:
    with pytest.raises(BadCapture, match="prompt"):
        segmenter.segment(image, depth_for(image), np.array([uv]))


def test_bad_image_or_depth_is_refused(segmenter: FastSamSegmenter, image: np.ndarray) -> None:
    with pytest.raises(BadCapture, match="uint8"):
        segmenter.segment(image.astype(np.float32), depth_for(image), PROMPTS[:1])
    with pytest.raises(BadCapture, match="depth"):
        segmenter.segment(image, np.zeros((10, 10), np.float32), PROMPTS[:1])


# --------------------------------------------------------------------------------------------------
# Pre-processing and NMS


def test_letterbox_centres_and_pads_with_grey() -> None:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (400, 640, 3), dtype=np.uint8)
    out, lb = letterbox(img, input_hw=(256, 256))
    assert out.shape == (256, 256, 3)
    assert (lb.gain, lb.pad_x, lb.pad_y) == (0.4, 0, 48)
    assert (out[:48] == 114).all() and (out[208:] == 114).all()
    np.testing.assert_array_equal(out[48:208], cv2.resize(img, (256, 160), interpolation=cv2.INTER_LINEAR))


def test_letterbox_odd_padding_puts_the_extra_row_at_the_bottom() -> None:
    img = np.zeros((302, 640, 3), np.uint8)  # resized to 256 x 121: 135 rows of padding
    out, lb = letterbox(img, input_hw=(256, 256))
    assert lb.pad_y == 67
    assert (out[:67] == 114).all() and (out[67:188] == 0).all() and (out[188:] == 114).all()


def test_letterbox_auto_pads_to_the_stride_only() -> None:
    img = np.zeros((720, 1280, 3), np.uint8)
    out, lb = letterbox(img, input_hw=(1024, 1024), auto=True)
    assert out.shape == (576, 1024, 3) and (lb.pad_x, lb.pad_y) == (0, 0)
    out, lb = letterbox(np.zeros((700, 1280, 3), np.uint8), input_hw=(1024, 1024), auto=True)
    assert out.shape == (576, 1024, 3) and lb.pad_y == 8  # 560 rows + 16 of padding


def test_input_tensor_is_rgb_nchw_in_unit_range() -> None:
    img = np.zeros((2, 3, 3), np.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 255, 51, 0
    x = to_input_tensor(img)
    assert x.shape == (1, 3, 2, 3) and x.dtype == np.float32
    np.testing.assert_allclose(x[0, :, 0, 0], [1.0, 0.2, 0.0], atol=1e-7)


def test_nms_suppresses_above_the_threshold_only() -> None:
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [20, 20, 30, 30], [0, 0, 10, 10]], float)
    scores = np.array([0.9, 0.8, 0.7, 0.95])
    # IoU(0, 1) = 90 / 110 = 0.818; box 3 duplicates box 0 exactly and scores higher.
    assert nms(boxes, scores, iou=0.8).tolist() == [3, 2]
    assert nms(boxes, scores, iou=0.85).tolist() == [3, 1, 2]
    assert nms(boxes, scores, iou=0.85, max_det=2).tolist() == [3, 1]
    assert nms(np.zeros((0, 4)), np.zeros(0), iou=0.5).tolist() == []


# --------------------------------------------------------------------------------------------------
# Model loading and the tensor contract


def test_missing_model_is_a_perception_error(tmp_path: Path) -> None:
    with pytest.raises(PerceptionError, match=r"does not exist.*yolo export"):
        FastSamSegmenter(tmp_path / "FastSAM-s.onnx")


def test_corrupt_model_is_a_perception_error(tmp_path: Path) -> None:
    bad = tmp_path / "FastSAM-s.onnx"
    bad.write_bytes(b"not a protobuf at all" * 10)
    with pytest.raises(PerceptionError, match="cannot load"):
        FastSamSegmenter(bad)


def test_unknown_provider_is_a_perception_error(model_path: Path) -> None:
    with pytest.raises(PerceptionError, match="NoSuchExecutionProvider"):
        FastSamSegmenter(model_path, providers=("NoSuchExecutionProvider",))


def test_coco_seg_model_is_refused_naming_both_shapes(tmp_path: Path) -> None:
    n = num_anchors(256)
    path = build_fastsam_onnx(
        tmp_path / "yolov8n-seg.onnx",
        output0=np.zeros((1, 116, n), np.float32),
        output1=np.zeros((1, 32, 64, 64), np.float32),
        size=256,
    )
    with pytest.raises(PerceptionError, match=r"\(1, 116, 1344\).*\(1, 37, 1344\).*80 classes"):
        FastSamSegmenter(path)


def test_wrong_prototype_shape_is_refused(tmp_path: Path) -> None:
    path = build_fastsam_onnx(
        tmp_path / "m.onnx",
        output0=np.zeros((1, 37, num_anchors(256)), np.float32),
        output1=np.zeros((1, NUM_COEFFS, 32, 32), np.float32),
        size=256,
    )
    with pytest.raises(PerceptionError, match=r"'output1'.*\(1, 32, 32, 32\).*\(1, 32, 64, 64\)"):
        FastSamSegmenter(path)


def test_wrong_tensor_names_are_refused(tmp_path: Path, scene: Scene) -> None:
    out0, out1 = scene.outputs()
    path = build_fastsam_onnx(tmp_path / "m.onnx", output0=out0, output1=out1, size=256, input_name="input")
    with pytest.raises(PerceptionError, match="expected input 'images'"):
        FastSamSegmenter(path)


def test_dynamic_model_uses_imgsz(tmp_path: Path, scene: Scene) -> None:
    path = scene.build(tmp_path / "dynamic.onnx", dynamic=True)
    seg = FastSamSegmenter(path, imgsz=256)
    assert seg.input_hw == (256, 256)
    # A square image fills the 256 x 256 input, which is what the constant outputs encode: decoding works.
    img = np.zeros((256, 256, 3), np.uint8)
    assert seg.everything(img).count > 0
    # The 640 x 400 image becomes a 256 x 160 input, but the stand-in still answers for 256 x 256:
    # the run-time check must catch outputs that do not fit the input.
    with pytest.raises(PerceptionError, match=r"'output0'.*expected \(1, 37, 840\) for a 256x160 input"):
        seg.everything(np.zeros((400, 640, 3), np.uint8))
