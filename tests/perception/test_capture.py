"""Capture folder I/O: round trips, the pixel-centre convention, and every bad input refused clearly."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from perception.capture import (
    CameraIntrinsics,
    Capture,
    backproject,
    load_capture,
    read_point_cloud,
    save_capture,
)
from perception.errors import BadCapture
from perception.transforms import make_X


def small_capture(**kw) -> Capture:
    h, w = 48, 64
    rng = np.random.default_rng(0)
    color = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
    depth = np.full((h, w), 0.5, np.float32) + rng.uniform(0, 0.1, (h, w)).astype(np.float32)
    depth[0, 0] = np.nan
    intr = CameraIntrinsics(w, h, 60.0, 61.0, 31.5, 23.5)
    return Capture(color_rgb=color, depth_m=depth, intrinsics=intr, depth_scale=10000.0, **kw)


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    X = make_X(np.eye(3), [0.1, 0.2, 0.3])
    cap = small_capture(X_base_tool=X, X_tool_camera=np.eye(4), prompts_px=np.array([[3.0, 4.0], [60.0, 40.0]]))
    return save_capture(cap, tmp_path / "cap")


def test_round_trip_png_quantises_to_depth_scale(folder: Path) -> None:
    cap = load_capture(folder)
    ref = small_capture()
    assert cap.shape == (48, 64)
    assert np.array_equal(cap.color_rgb, ref.color_rgb)
    ok = np.isfinite(ref.depth_m)
    assert np.isnan(cap.depth_m[0, 0])
    assert np.abs(cap.depth_m[ok] - ref.depth_m[ok]).max() <= 0.5 / 10000.0 + 1e-7
    assert cap.intrinsics == ref.intrinsics
    assert cap.depth_scale == 10000.0
    assert np.allclose(cap.X_base_camera, make_X(np.eye(3), [0.1, 0.2, 0.3]))
    assert cap.prompts_px.tolist() == [[3.0, 4.0], [60.0, 40.0]]
    cam = json.loads((folder / "camera.json").read_text())
    assert cam["intrinsic_matrix"] == [60.0, 0.0, 0.0, 0.0, 61.0, 0.0, 31.5, 23.5, 1.0]  # column-major
    assert (folder / "color.png").stat().st_mode & 0o044  # readable by others, not 0600


def test_round_trip_npy_is_exact(tmp_path: Path) -> None:
    ref = small_capture()
    cap = load_capture(save_capture(ref, tmp_path / "c", depth_format="npy"))
    assert np.array_equal(np.isnan(cap.depth_m), np.isnan(ref.depth_m))
    ok = np.isfinite(ref.depth_m)
    assert np.array_equal(cap.depth_m[ok], ref.depth_m[ok])
    assert not (tmp_path / "c" / "depth.png").exists()


def test_backprojection_uses_pixel_centres() -> None:
    intr = CameraIntrinsics(64, 48, 60.0, 61.0, 31.5, 23.5)
    depth = np.full((48, 64), 2.0, np.float32)
    pts = backproject(depth, intr)
    # pixel (u, v) -> z * ((u - cx)/fx, (v - cy)/fy, 1)
    assert pts[10, 40].tolist() == pytest.approx([2.0 * (40 - 31.5) / 60.0, 2.0 * (10 - 23.5) / 61.0, 2.0], abs=1e-6)
    # the principal point lies between pixels 31 and 32: their x are symmetric about 0
    assert pts[0, 31, 0] == pytest.approx(-pts[0, 32, 0], abs=1e-7)
    # projecting back lands on the pixel itself
    uv = intr.project(pts[10, 40].astype(float)[None])
    assert uv[0].tolist() == pytest.approx([40.0, 10.0], abs=1e-4)


def _expect(folder: Path, fragment: str, file: str) -> BadCapture:
    with pytest.raises(BadCapture) as exc:
        load_capture(folder)
    msg = str(exc.value)
    assert fragment in msg, msg
    assert file in msg, msg
    return exc.value


def test_missing_color(folder: Path) -> None:
    (folder / "color.png").unlink()
    _expect(folder, "missing colour image", "color.png")


def test_missing_camera(folder: Path) -> None:
    (folder / "camera.json").unlink()
    _expect(folder, "missing camera.json", "camera.json")


def test_missing_depth(folder: Path) -> None:
    (folder / "depth.png").unlink()
    _expect(folder, "missing depth", str(folder))


def test_corrupt_color(folder: Path) -> None:
    (folder / "color.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    _expect(folder, "cannot decode colour image", "color.png")


def test_corrupt_depth(folder: Path) -> None:
    data = (folder / "depth.png").read_bytes()
    (folder / "depth.png").write_bytes(data[: len(data) // 3])
    _expect(folder, "depth", "depth.png")


def test_eight_bit_depth_png_refused(folder: Path) -> None:
    cv2.imwrite(str(folder / "depth.png"), np.full((48, 64), 100, np.uint8))
    _expect(folder, "single-channel 16-bit", "depth.png")


def test_size_mismatch_color_depth(folder: Path) -> None:
    cv2.imwrite(str(folder / "color.png"), np.zeros((40, 64, 3), np.uint8))
    _expect(folder, "size mismatch", "64x40")


def test_size_mismatch_camera_json(folder: Path) -> None:
    cam = json.loads((folder / "camera.json").read_text())
    cam["height"] = 40
    (folder / "camera.json").write_text(json.dumps(cam))
    _expect(folder, "camera.json says 64x40 but the images are 64x48", "camera.json")


def test_depth_scale_missing(folder: Path) -> None:
    cam = json.loads((folder / "camera.json").read_text())
    del cam["depth_scale"]
    (folder / "camera.json").write_text(json.dumps(cam))
    _expect(folder, "'depth_scale' is missing", "camera.json")


@pytest.mark.parametrize("value", [0, -1000.0])
def test_depth_scale_zero_or_negative(folder: Path, value: float) -> None:
    cam = json.loads((folder / "camera.json").read_text())
    cam["depth_scale"] = value
    (folder / "camera.json").write_text(json.dumps(cam))
    _expect(folder, "'depth_scale' must be positive", "camera.json")


def test_depth_scale_wrong_units(folder: Path) -> None:
    cam = json.loads((folder / "camera.json").read_text())
    cam["depth_scale"] = 1.0  # counts read as metres: 5000 m away
    (folder / "camera.json").write_text(json.dumps(cam))
    _expect(folder, "implausible", "depth.png")


def test_all_depth_invalid(folder: Path) -> None:
    cv2.imwrite(str(folder / "depth.png"), np.zeros((48, 64), np.uint16))
    _expect(folder, "all depth is invalid", "depth.png")


def test_all_nan_depth_npy(tmp_path: Path) -> None:
    folder = save_capture(small_capture(), tmp_path / "c", depth_format="npy")
    np.save(folder / "depth.npy", np.full((48, 64), np.nan, np.float32))
    _expect(folder, "all depth is invalid", "depth.npy")


def test_inf_depth_npy(tmp_path: Path) -> None:
    folder = save_capture(small_capture(), tmp_path / "c", depth_format="npy")
    d = np.full((48, 64), 0.5, np.float32)
    d[3, 3] = np.inf
    np.save(folder / "depth.npy", d)
    _expect(folder, "inf", "depth.npy")


def test_nan_in_intrinsics(folder: Path) -> None:
    text = (folder / "camera.json").read_text().replace("60.0", "NaN", 1)
    (folder / "camera.json").write_text(text)
    _expect(folder, "NaN", "camera.json")


def test_row_major_intrinsics_refused(folder: Path) -> None:
    cam = json.loads((folder / "camera.json").read_text())
    cam["intrinsic_matrix"] = [60.0, 0.0, 31.5, 0.0, 61.0, 23.5, 0.0, 0.0, 1.0]
    (folder / "camera.json").write_text(json.dumps(cam))
    _expect(folder, "column-major", "camera.json")


def test_implausible_focal_length(folder: Path) -> None:
    cam = json.loads((folder / "camera.json").read_text())
    cam["intrinsic_matrix"][0] = 6.0  # a 64 px wide image with a 6 px focal length
    (folder / "camera.json").write_text(json.dumps(cam))
    _expect(folder, "implausible", "camera.json")


@pytest.mark.parametrize("name", ["camera.json", "prompts.json", "pose.json"])
def test_malformed_json(folder: Path, name: str) -> None:
    (folder / name).write_text('{"width": 64,, }')
    _expect(folder, "malformed JSON at line 1", name)


def test_prompt_outside_image(folder: Path) -> None:
    (folder / "prompts.json").write_text(json.dumps({"points": [[10, 10], [64, 5]]}))
    _expect(folder, "prompt 1 at (u=64, v=5) lies outside the 64x48 image", "prompts.json")


def test_pose_not_rigid(folder: Path) -> None:
    bad = np.eye(4)
    bad[0, 0] = 2.0
    (folder / "pose.json").write_text(json.dumps({"X_base_tool": bad.tolist(), "X_tool_camera": np.eye(4).tolist()}))
    _expect(folder, "not orthonormal", "pose.json")


def test_pose_missing_key(folder: Path) -> None:
    (folder / "pose.json").write_text(json.dumps({"X_base_tool": np.eye(4).tolist()}))
    _expect(folder, "'X_tool_camera'", "pose.json")


def test_not_a_folder(tmp_path: Path) -> None:
    with pytest.raises(BadCapture, match="does not exist"):
        load_capture(tmp_path / "nope")


def test_ground_truth_must_be_camera_frame(folder: Path) -> None:
    (folder / "ground_truth.json").write_text(json.dumps({"frame": "base", "seams": []}))
    _expect(folder, "camera frame", "ground_truth.json")


def test_extra_json_keys_ignored(folder: Path) -> None:
    cam = json.loads((folder / "camera.json").read_text())
    cam["vendor"] = {"serial": "x"}
    (folder / "camera.json").write_text(json.dumps(cam))
    assert load_capture(folder).intrinsics.fx == 60.0


def test_gray_color_is_accepted(folder: Path) -> None:
    cv2.imwrite(str(folder / "color.png"), np.full((48, 64), 77, np.uint8))
    cap = load_capture(folder)
    assert cap.color_rgb.shape == (48, 64, 3)
    assert int(cap.color_rgb[5, 5, 2]) == 77


def test_point_cloud_formats(tmp_path: Path) -> None:
    import open3d as o3d

    pts = np.array([[0.0, 0.0, 0.5], [0.01, 0.0, 0.5], [0.0, 0.01, 0.52], [np.nan, 0, 0]])
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    o3d.io.write_point_cloud(str(tmp_path / "a.pcd"), pcd)
    pc = read_point_cloud(tmp_path / "a.pcd")
    assert pc.points.shape == (3, 3)
    assert pc.colors is None
    pcd.colors = o3d.utility.Vector3dVector(np.tile([1.0, 0.5, 0.0], (4, 1)))
    o3d.io.write_point_cloud(str(tmp_path / "b.ply"), pcd)
    pc = read_point_cloud(tmp_path / "b.ply")
    assert pc.points.shape == (3, 3)
    assert pc.colors is not None and np.allclose(pc.colors[0], [1.0, 0.5, 0.0], atol=1 / 255)
    np.save(tmp_path / "c.npy", pts[:3])
    assert read_point_cloud(tmp_path / "c.npy").points.shape == (3, 3)
    (tmp_path / "d.ply").write_text("not a ply")
    with pytest.raises(BadCapture, match=r"d\.ply"):
        read_point_cloud(tmp_path / "d.ply")
    with pytest.raises(BadCapture, match="unsupported"):
        read_point_cloud(tmp_path / "e.xyz")


def test_bundled_sample_loads() -> None:
    sample = Path(__file__).resolve().parents[2] / "samples" / "ribs"
    if not sample.exists():
        pytest.fail("the bundled sample capture samples/ribs is missing")
    cap = load_capture(sample)
    assert cap.ground_truth is not None and len(cap.ground_truth) == 10
    assert cap.prompts_px is not None
    assert sum(f.stat().st_size for f in sample.iterdir()) < 1_200_000


def test_copy_of_folder_is_independent(folder: Path, tmp_path: Path) -> None:
    dst = tmp_path / "copy"
    shutil.copytree(folder, dst)
    (dst / "prompts.json").unlink()
    assert load_capture(dst).prompts_px is None
    assert load_capture(folder).prompts_px is not None
