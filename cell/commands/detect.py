"""``weldcell detect`` and ``weldcell demo``: find the seams of a capture (or a PLY/PCD cloud)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

SAMPLE_NAME = "ribs"


def sample_capture_dir() -> Path:
    """The bundled sample capture, shipped in the wheel as package data of ``cell`` (samples/ribs in a checkout
    links to it)."""
    from importlib.resources import files

    sample = files("cell").joinpath("samples", SAMPLE_NAME)
    if not isinstance(sample, Path) or not (sample / "camera.json").is_file():
        from perception.errors import BadCapture

        raise BadCapture(f"the bundled sample capture is missing from this installation ({sample})")
    return sample


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "detect",
        help="detect the weld seams of a capture folder (or a .ply/.pcd cloud: fine stage only)",
        description="Coarse-to-fine multi-seam detection. Exit codes: 0 seams found, 2 bad capture, 3 no seam.",
    )
    p.add_argument("capture", nargs="+", help="capture folder(s), or .ply/.pcd/.npy point cloud(s)")
    _add_detect_options(p)
    b = p.add_argument_group(
        "batch", "several captures (or --out-dir): one process pool, one seams.json per capture in --out-dir"
    )
    b.add_argument("--out-dir", help="batch: write <capture name>.seams.json here, and batch.json (a summary)")
    b.add_argument("--jobs", type=int, default=None, help="batch: worker processes (default: the CPU count)")
    b.add_argument("--ray", metavar="ADDRESS", help="batch: run on a Ray cluster ('auto', 'ray://host:10001'; "
                   "'local' starts one here); needs pip install 'weldcell[ray]'")  # fmt: skip
    p.set_defaults(func=run_detect)

    d = sub.add_parser(
        "demo",
        help="detect the seams of the bundled sample capture and score them against its ground truth",
    )
    d.add_argument("--out", default="out", help="folder for seams.json and overlay.png (default: out)")
    d.set_defaults(func=run_demo)


VALIDATED_VOXEL_MM = (3.0, 5.0)  # bench voxel sweep (ribs, pipe, stereo): every seam found, max error <= 0.8 mm


def _add_detect_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", help="write seams.json here")
    p.add_argument("--overlay", help="write the overlay PNG here (a point cloud: its plan, side and detector's views "
                   "with the seams), also when no seam is found")
    p.add_argument("--ply", help="write the kept (cropped) points and the seam paths as a PLY here")
    p.add_argument("--no-crop", action="store_true", help="skip the ROI crop (fine stage on the whole cloud)")
    p.add_argument("--segmenter", choices=("default", "fastsam"), default="default")
    p.add_argument("--model", help="FastSAM ONNX export (with --segmenter fastsam)")
    p.add_argument(
        "--voxel-mm",
        type=float,
        default=None,
        help="voxel size in mm (default 3, the paper's; a sparse .ply/.pcd scan gets 1.5x its sample spacing)",
    )
    p.add_argument(
        "--method",
        choices=("refined", "paper", "surfaces"),
        default="surfaces",
        help="'paper': no sub-voxel refinement; 'surfaces': the fine stage on fitted surfaces (docs/zoo.md)",
    )
    p.add_argument("--step-mm", type=float, default=5.0, help="path point spacing in mm")
    p.add_argument("--work-angle", type=float, default=0.0, help="work angle offset from the bisector, deg")
    p.add_argument("--travel-angle", type=float, default=0.0, help="travel angle, deg (positive = push)")
    p.add_argument("--json", action="store_true", help="print seams.json to stdout instead of a table")


def build_params(args: argparse.Namespace) -> Any:
    from perception.detect import DetectParams
    from perception.errors import BadCapture
    from perception.path import TorchParams

    if args.method == "surfaces":
        # the surfaces stage segments the depth by its geometry (prompts.json only picks the workpiece) and
        # crops to the seams' bands itself: these flags belong to the voxel-region stage; never ignore them
        flags = (("--segmenter fastsam", args.segmenter == "fastsam"), ("--voxel-mm", args.voxel_mm is not None),
                 ("--no-crop", args.no_crop))  # fmt: skip
        given = [f for f, on in flags if on]
        if given:
            raise BadCapture(f"{', '.join(given)}: for --method refined or paper (the voxel-region stage); the "
                             "default surfaces stage has no image segmenter, voxel grid or separate crop")  # fmt: skip
    voxel_mm = 3.0 if args.voxel_mm is None else args.voxel_mm
    if not 0.2 <= voxel_mm <= 50:
        raise BadCapture(f"--voxel-mm must be between 0.2 and 50, got {voxel_mm}")
    if not VALIDATED_VOXEL_MM[0] <= voxel_mm <= VALIDATED_VOXEL_MM[1]:
        # the fine stage's neighbourhoods are a few voxels wide: much finer voxels see noise, much coarser
        # ones blur a 30 mm face into a few voxels (weldcell bench's voxel sweep shows where seams go)
        print(
            f"warning: --voxel-mm {voxel_mm:g} is outside the range the detector is validated for "
            f"({VALIDATED_VOXEL_MM[0]:g}-{VALIDATED_VOXEL_MM[1]:g} mm); seams may be missed or mis-fitted",
            file=sys.stderr,
        )
    if not 0.5 <= args.step_mm <= 100:
        raise BadCapture(f"--step-mm must be between 0.5 and 100, got {args.step_mm}")
    for name in ("work_angle", "travel_angle"):
        if abs(getattr(args, name)) > 60:
            raise BadCapture(f"--{name.replace('_', '-')} must be within +-60 degrees")
    return DetectParams(
        crop=not args.no_crop,
        voxel_m=voxel_mm / 1000.0,
        method=args.method,
        torch=TorchParams(
            step_m=args.step_mm / 1000.0,
            work_angle_rad=math.radians(args.work_angle),  # the flags are degrees, as operators read them
            travel_angle_rad=math.radians(args.travel_angle),
        ),
    )


def make_segmenter(args: argparse.Namespace) -> Any:
    from perception.errors import BadCapture

    if args.segmenter == "fastsam":
        if not args.model:
            raise BadCapture("--segmenter fastsam needs --model FILE (a FastSAM ONNX export; see docs/fastsam.md)")
        from perception.segment_fastsam import FastSamSegmenter

        return FastSamSegmenter(args.model)
    from perception.segment_default import GraphSegmenter

    return GraphSegmenter()


def _cloud_overlay(path: str, cloud: Any, result: Any, title: str, viewpoint: Any) -> None:
    """A cloud's overlay (:func:`cell.cloud_picture.draw_cloud`): its views with ``result``'s seams (none when
    ``result`` is None) in red."""
    from cell.cloud_picture import draw_cloud

    seams = () if result is None else result.seams
    draw_cloud(cloud, [s.points for s in seams], [s.joint for s in seams], path, title=title, viewpoint=viewpoint)
    print(f"overlay    -> {path}", file=sys.stderr)


def run_detect(args: argparse.Namespace) -> int:
    if len(args.capture) > 1 or args.out_dir or args.jobs is not None or args.ray:
        from cell.commands.detect_batch import run_batch

        return run_batch(args)
    args.capture = args.capture[0]
    return detect_one(args)


def detect_one(args: argparse.Namespace) -> int:
    from perception.capture import load_capture, read_point_cloud
    from perception.detect import detect, detect_cloud
    from perception.errors import NoSeamFound
    from perception.seams import seams_to_json, write_seams_json

    params = build_params(args)
    src = Path(args.capture)
    capture = None
    if src.is_file() or src.suffix.lower() in (".ply", ".pcd", ".npy"):
        cloud = read_point_cloud(src)
        try:
            result = detect_cloud(cloud, replace(params, crop=False), auto_voxel=args.voxel_mm is None)
        except NoSeamFound as err:
            if args.overlay:  # the cloud as the detector saw it, and why nothing came of it
                _cloud_overlay(args.overlay, cloud, None, f"{src.name}: {err}", err.artifacts.get("viewpoint"))
            raise
        if args.overlay:
            _cloud_overlay(args.overlay, cloud, result, f"{src.name}: {len(result.seams)} seam(s)",
                           result.info.get("viewpoint"))  # fmt: skip
    else:
        capture = load_capture(src)
        if params.method == "surfaces":  # its modules and compiled kernels loaded before the detection is timed
            from perception.helper_process import preload

            preload()
        try:
            result = detect(capture, params, segmenter=make_segmenter(args))
        except NoSeamFound as err:
            if args.overlay:
                # an overlay of what was seen and why nothing came of it, so that a user can see why
                from perception.overlay import draw_overlay, write_png
                from perception.seams import DetectionResult

                empty = DetectionResult("camera", (), artifacts=dict(err.artifacts))
                write_png(args.overlay, draw_overlay(capture, empty, note=str(err)))
                print(f"overlay    -> {args.overlay}", file=sys.stderr)
            raise
    if args.out:
        write_seams_json(result, args.out)
    if args.overlay and capture is not None:
        from perception.overlay import draw_overlay, write_png

        write_png(args.overlay, draw_overlay(capture, result))
    if args.ply:
        _write_ply(args.ply, result, capture)
    if args.json:
        print(json.dumps(seams_to_json(result), indent=1))
    else:
        print_table(result, title=str(src))
        if args.out:
            print(f"seams.json -> {args.out}")
        if args.overlay and capture is not None:
            print(f"overlay    -> {args.overlay}")
    return 0


def print_table(result: Any, *, title: str) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{title}: {len(result.seams)} seam(s), frame={result.frame}")
    for col in ("id", "kind", "length mm", "points", "start x,y,z mm", "end x,y,z mm", "conf"):
        table.add_column(col, justify="right", no_wrap=True)
    for s in result.seams:
        a, b = s.points[0] * 1000, s.points[-1] * 1000
        table.add_row(
            str(s.id),
            s.kind,
            f"{s.length_m * 1000:.1f}",
            str(len(s.points)),
            f"{a[0]:.1f},{a[1]:.1f},{a[2]:.1f}",
            f"{b[0]:.1f},{b[1]:.1f},{b[2]:.1f}",
            f"{s.confidence:.2f}",
        )
    console = Console()
    console.print(table)
    pc = result.point_counts
    t = result.timing_s
    removed = 1.0 - pc.get("cropped", 0) / max(pc.get("raw", 1), 1)
    # the surfaces stage's "downsampled" count is its work image (every point at 640 pixels across)
    third = "work image" if result.info.get("method") == "surfaces" else "downsampled"
    console.print(
        f"points: raw {pc.get('raw', 0)}, kept {pc.get('cropped', 0)} ({removed * 100:.1f}% removed), "
        f"{third} {pc.get('downsampled', 0)}; time: coarse {t.get('coarse', 0):.3f} s, "
        f"fine {t.get('fine', 0):.3f} s, total {t.get('total', 0):.3f} s"
    )


def _write_ply(path: str, result: Any, capture: Any) -> None:
    import numpy as np
    import open3d as o3d

    pts = [s.points for s in result.seams]
    cols = [np.tile([1.0, 0.1, 0.1], (len(p), 1)) for p in pts]
    kept = result.artifacts.get("kept_points")
    if kept is not None:
        pts.insert(0, kept)
        cols.insert(0, np.tile([0.6, 0.6, 0.6], (len(kept), 1)))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.vstack(pts)))
    pcd.colors = o3d.utility.Vector3dVector(np.vstack(cols))
    if not o3d.io.write_point_cloud(Path(path), pcd):
        raise OSError(f"could not write {path}")


def run_demo(args: argparse.Namespace) -> int:
    from perception.capture import load_capture
    from perception.detect import DetectParams, detect
    from perception.evaluate import evaluate_seams
    from perception.helper_process import HelperProcess, preload
    from perception.overlay import draw_overlay, write_png
    from perception.seams import write_seams_json

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sample = sample_capture_dir()
    # the detection as on the cell, where the daemon's helper process is always running and the detector's
    # modules are loaded: both start here with the capture's loading (about a second, once), so that the time
    # printed is the cell's
    with HelperProcess() as helper:
        capture = load_capture(sample)
        preload()
        helper.wait_ready()
        result = detect(capture, DetectParams(), helper=helper)
    write_seams_json(result, out / "seams.json")
    write_png(str(out / "overlay.png"), draw_overlay(capture, result))
    print_table(result, title=f"bundled sample {sample.name}")
    if capture.ground_truth:
        from perception.transforms import invert_X, transform_points

        X = capture.X_base_camera
        pts = [s.points if X is None else transform_points(invert_X(X), s.points) for s in result.seams]
        rep = evaluate_seams(pts, capture.ground_truth)
        print(
            f"against ground truth: {rep.n_found}/{rep.n_truth} seams found, {len(rep.false_seams)} false, "
            f"coverage {rep.coverage * 100:.1f}%, RMSE {rep.rmse_m * 1000:.3f} mm, max {rep.max_m * 1000:.3f} mm"
        )
    print(f"wrote {out / 'seams.json'} and {out / 'overlay.png'}")
    return 0
