"""``weldcell export``: a seams.json as a robot program, a ROS 2 bag, a glTF scene or an HTML 3D view."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

FORMATS = ("urscript", "ls", "rosbag2", "gltf", "html")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export",
        help="write a seams.json as URScript, FANUC LS, a ROS 2 bag, glTF or a self-contained HTML 3D view",
        description="urscript/ls: the planned weld path (order, approach, arc on/off, retract) with the job's speeds "
        "and the cell's arc output; one program per track position. rosbag2: one geometry_msgs/PoseArray per seam "
        "on /weldcell/seams and a nav_msgs/Path of the route on /weldcell/route. gltf/html: seams, torch axes and "
        "the cloud crop (--capture or --cloud). Exit 2: bad input.",
    )
    p.add_argument("seams_json", help="seams.json written by 'weldcell detect' or 'weldcell demo'")
    p.add_argument("--to", required=True, choices=FORMATS, dest="fmt", help="output format")
    p.add_argument("--out", required=True, help="output file (rosbag2: a new folder)")
    p.add_argument("--config", help="cell config: welding defaults, arc output, reach, track, safety limits")
    p.add_argument("--job", help="job file: its [welding] speeds and [seams] selection override the cell's")
    p.add_argument("--track-position-m", type=float, default=0.0, help="carriage position at the capture (m)")
    p.add_argument("--name", help="program name (default: the job's workpiece, else 'weldcell')")
    p.add_argument("--uframe", type=int, default=0, help="FANUC user frame number (ls)")
    p.add_argument("--utool", type=int, default=1, help="FANUC tool frame number (ls)")
    p.add_argument("--frame-id", default=None, help="ROS frame id (rosbag2; default base_link, camera seams: camera)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="rosbag2 storage plugin")
    p.add_argument("--capture", help="capture folder of the seams: its points near the seams are the crop (gltf/html)")
    p.add_argument("--cloud", help=".ply/.pcd/.npy cloud in the seams' frame to show, cropped near the seams")
    p.add_argument("--axis-mm", type=float, default=15.0, help="length of the drawn torch axes (gltf/html)")
    p.add_argument("--json", action="store_true", help="print what was written as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cell.export import load_seams

    data = load_seams(args.seams_json)
    if args.fmt in ("urscript", "ls"):
        written = _programs(args, data)
        summary: dict[str, Any] = {"format": args.fmt, "files": [str(p) for p in written]}
    elif args.fmt == "rosbag2":
        summary = _rosbag(args, data)
    else:
        summary = _view(args, data)
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        for path in summary["files"]:
            print(f"{args.fmt} -> {path}")
    return 0


def _plan(args: argparse.Namespace, data: Any) -> Any:
    from cell.export import plan_for_export

    params = geometry = limits = None
    if args.config:
        from cell.config import load_config
        from cell.job import weld_params
        from cell.runner import safety_limits
        from cell.world_seams import SeamFilter

        config = load_config(args.config)
        job_welding, seam_filter = config.welding, SeamFilter()
        if args.job:
            from cell.job import load_job

            job = load_job(args.job)
            job_welding, seam_filter = job.spec.welding, job.spec.seams.seam_filter()
        params = weld_params(config.welding, job_welding, seam_filter)
        if config.safety is not None:
            limits = safety_limits(config)
            geometry = limits.geometry
    elif args.job:
        from cell.errors import ConfigError

        raise ConfigError("--job needs --config: a job's [welding] overrides the cell's, which the config holds")
    weld_path = plan_for_export(data, params=params, geometry=geometry, track_position_m=args.track_position_m)
    if limits is not None:
        from cell.safety import validate

        validate(weld_path, limits)  # a program that the cell would refuse to run is not written either
    return weld_path


def _programs(args: argparse.Namespace, data: Any) -> list[Path]:
    from cell.export import write_programs

    weld_path = _plan(args, data)
    name = args.name
    if name is None and args.job:
        from cell.job import load_job

        name = load_job(args.job).workpiece
    return write_programs(
        args.out,
        weld_path,
        language=args.fmt,
        name=name or "weldcell",
        comment=f"from {Path(args.seams_json).name}",
        fanuc_options={"uframe": args.uframe, "utool": args.utool},
    )


def _rosbag(args: argparse.Namespace, data: Any) -> dict[str, Any]:
    from cell.export import DEFAULT_FRAME_ID, route_poses, write_rosbag2

    weld_path = _plan(args, data) if data.frame == "base" else None
    route = route_poses(data, weld_path, track_position_m=args.track_position_m)
    frame_id = args.frame_id or (DEFAULT_FRAME_ID if data.frame == "base" else "camera")
    stamp_ns = int(Path(args.seams_json).stat().st_mtime * 1e9)  # the detection's time, as near as the file says
    out = write_rosbag2(args.out, data, route, frame_id=frame_id, storage=args.storage, stamp_ns=stamp_ns)
    return {
        "format": "rosbag2",
        "files": [str(out)],
        "storage": args.storage,
        "frame_id": frame_id,
        "pose_arrays": len(data.seams),
        "route_poses": len(route),
        "route": "planned TCP waypoints" if weld_path is not None else "seam torch poses in file order",
    }


def _view(args: argparse.Namespace, data: Any) -> dict[str, Any]:
    import numpy as np

    from cell.export import capture_points, cloud_near_seams, write_gltf, write_html
    from perception.errors import BadCapture

    if not 1.0 <= args.axis_mm <= 200.0:
        raise BadCapture(f"--axis-mm must be between 1 and 200, got {args.axis_mm}")
    cloud = None
    if args.capture and args.cloud:
        raise BadCapture("give --capture or --cloud, not both")
    if args.capture:
        cloud = cloud_near_seams(capture_points(args.capture, data.frame), data.seams)
    elif args.cloud:
        from perception.capture import read_point_cloud

        cloud = cloud_near_seams(np.asarray(read_point_cloud(args.cloud).points), data.seams)
    axis_m = args.axis_mm / 1000.0
    if args.fmt == "gltf":
        out = write_gltf(args.out, data, cloud_points=cloud, axis_m=axis_m)
    else:
        out = write_html(args.out, data, cloud_points=cloud, axis_m=axis_m)
    return {
        "format": args.fmt,
        "files": [str(out)],
        "seams": len(data.seams),
        "cloud_points": 0 if cloud is None else len(cloud),
    }
