"""Run the detector on the real scans and frames in ../shared/realdata and summarise what it finds.

    .venv/bin/python scripts/realdata.py [--realdata ../shared/realdata] [--out out/realdata]

Nothing is copied into the repository: the one RGB-D frame (a structured-light depth image with its IR
image) is converted to a capture folder under --out, clouds are read in place. There is no ground
truth for these files (see their SOURCES.md), so the summary reports what was found, how long it
took, and, where the authors published their own detector output, how far our seams lie from it.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from perception.capture import CameraIntrinsics, Capture, read_point_cloud, save_capture  # noqa: E402
from perception.detect import DetectParams, detect, detect_cloud  # noqa: E402
from perception.errors import NoSeamFound, PerceptionError  # noqa: E402

CLOUDS = [
    "thillRobot_seam_detection/table_8in10in_tee_x4y24_45.pcd",
    "thillRobot_seam_detection/table_8in10in_tee_longclamps_x4y24_45.pcd",
    "thillRobot_seam_detection/8in10in_tee_01_blndrB.pcd",
    "thillRobot_seam_detection/2plate_partA_fig1_cropped.pcd",
    "thillRobot_seam_detection/1plate_1tube_partA_fig1_cropped.pcd",
    "thillRobot_seam_detection/1plate_1tube_partB_fig1_cropped.pcd",
    "pengrui-rio_welding-robot/Thu_Apr_2_10_14_30_3_frame.pcd",
    "pengrui-rio_welding-robot/Thu_Apr_2_10_14_30_5_frame.pcd",
    "pengrui-rio_welding-robot/Thu_Apr_2_10_14_30_6_frame.pcd",
    "pengrui-rio_welding-robot/driver_test_cloud.pcd",
    "pengrui-rio_welding-robot/seam_cloud0.pcd",
    "blackhorsewu_CoboWeld/y-tube-joint.pcd",
    "blackhorsewu_CoboWeld/nodownsample.pcd",
    "blackhorsewu_CoboWeld/barpoints.pcd",
    "blackhorsewu_CoboWeld/patch1.pcd",
    "abhinand4as_weld_seam_ros2/lap_joint_base_frame.pcd",
    "abhinand4as_weld_seam_ros2/lap_joint_with_table.pcd",
]


def xiaoyu_capture(realdata: Path) -> Capture:
    """The structured-light frame as a capture: IR image as colour, depth in 0.063 mm counts."""
    import cv2

    base = realdata / "XiaoyuChangeTheWorld_weld-seam-tracker-3d"
    stem = "20260515-165842847"
    depth_raw = cv2.imread(str(base / f"depth_{stem}.png"), cv2.IMREAD_UNCHANGED)
    ir = cv2.imread(str(base / f"ir_left_{stem}.png"), cv2.IMREAD_GRAYSCALE)
    text = (base / f"depth_{stem}.txt").read_text()
    k = [float(v) for v in text.split("[Intrinsic]")[1].split("[")[0].strip().split(",")]
    scale_mm = float(text.split("[ScaleUnit]")[1].strip().split()[0])
    h, w = depth_raw.shape
    depth_m = depth_raw.astype(np.float32) * np.float32(scale_mm / 1000.0)
    depth_m[depth_raw == 0] = np.nan
    color = np.repeat(ir[:, :, None], 3, axis=2) if ir is not None else np.zeros((h, w, 3), np.uint8)
    intr = CameraIntrinsics(w, h, k[0], k[4], k[2], k[5])
    # one operator click per plate (the product's normal input; automatic prompts are tried too)
    prompts = np.array([[500.0, 1200.0], [1700.0, 700.0]])
    return Capture(color, depth_m, intr, depth_scale=1000.0 / scale_mm, prompts_px=prompts, source=str(base))


def authors_path_distance(seams: Any, path: Path) -> str:
    if not path.exists():
        return ""
    from perception.evaluate import point_to_polyline_distance

    ref = np.loadtxt(path, delimiter=",", skiprows=1)[:, :3]
    best = min((float(np.median(point_to_polyline_distance(s.points, ref))) for s in seams), default=np.nan)
    return f"nearest seam to the authors' path: median {best * 1000:.2f} mm"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--realdata", default=str(ROOT.parent / "shared" / "realdata"))
    ap.add_argument("--out", default=str(ROOT / "out" / "realdata"))
    args = ap.parse_args()
    realdata = Path(args.realdata)
    if not realdata.is_dir():
        print(f"no real data at {realdata}")
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []

    # the RGB-D frame: coarse + fine
    try:
        cap = xiaoyu_capture(realdata)
        folder = save_capture(cap, out / "xiaoyu_capture", depth_format="npy")
        t0 = time.perf_counter()
        for label, c in (("auto prompts", replace(cap, prompts_px=None)), ("operator prompts", cap)):
            t1 = time.perf_counter()
            try:
                r = detect(c, DetectParams())
                rows.append((f"xiaoyu frame, {label}", len(r.seams), time.perf_counter() - t1,
                             ", ".join(f"{s.kind} {s.length_m * 1000:.0f} mm" for s in r.seams)))  # fmt: skip
            except NoSeamFound as err:
                rows.append((f"xiaoyu frame, {label}", 0, time.perf_counter() - t1, str(err)))
        try:
            res = detect(cap, DetectParams())
            note = authors_path_distance(
                res.seams, realdata / "XiaoyuChangeTheWorld_weld-seam-tracker-3d" / "weld_trajectory.csv"
            )
            from perception.overlay import draw_overlay, write_png

            write_png(str(out / "xiaoyu_overlay.png"), draw_overlay(cap, res))
            found = ", ".join(f"{s.kind} {s.length_m * 1000:.0f} mm" for s in res.seams)
            rows.append(
                ("xiaoyu frame vs the authors' path", len(res.seams), time.perf_counter() - t0, f"{found}; {note}")
            )
        except NoSeamFound as err:
            rows.append(("xiaoyu structured-light frame (capture)", 0, time.perf_counter() - t0, str(err)))
        print(f"capture written to {folder}")
    except (OSError, PerceptionError, IndexError, ValueError) as err:
        rows.append(("xiaoyu structured-light frame (capture)", -1, 0.0, f"could not read: {err}"))

    # clouds: fine stage only
    for rel in CLOUDS:
        path = realdata / rel
        if not path.exists():
            continue
        t0 = time.perf_counter()
        try:
            cloud = read_point_cloud(path)
            res = detect_cloud(cloud)  # sparse scans get a coarser voxel (from their sample spacing)
            voxel = res.info["voxel_m"]
            desc = ", ".join(f"{s.kind} {s.length_m * 1000:.0f} mm" for s in res.seams)
            rows.append((rel, len(res.seams), time.perf_counter() - t0, f"voxel {voxel * 1000:.1f} mm: {desc}"))
        except NoSeamFound as err:
            rows.append((rel, 0, time.perf_counter() - t0, str(err)))
        except PerceptionError as err:
            rows.append((rel, -1, time.perf_counter() - t0, f"refused: {err}"))
    width = max(len(r[0]) for r in rows)
    for name, n, dt, note in rows:
        print(f"{name:<{width}}  seams {n:>3}  {dt:6.2f} s  {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
