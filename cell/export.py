"""Exports of detected seams: robot programs (URScript, FANUC LS), a ROS 2 bag, a glTF scene and an HTML 3D view.

Inputs are a seams.json (:func:`perception.seams.read_seams_json`; camera or base frame, metres) and, for the
programs, welding parameters and the cell's IO from a cell config and a job (:func:`plan_for_export`). Every
writer takes SI values and converts only at its format's boundary:

- URScript / LS: :mod:`cell.programs` (metres and rotation vectors; millimetres and degrees for FANUC).
- ROS 2 bag (``rosbags``, no ROS install): one ``geometry_msgs/msg/PoseArray`` per seam on ``/weldcell/seams``
  (the torch pose at every path point, in seam order) and one ``nav_msgs/msg/Path`` on ``/weldcell/route``:
  the planned route, every TCP waypoint (approach, arc on, travel, arc off, retract) pass after pass, for
  base-frame seams; the seams' torch poses in file order for camera-frame seams (nothing to plan there).
  Metres and unit quaternions, in ``frame_id`` (``base_link`` by default).
- glTF binary (``trimesh``): seams as red lines, torch axes (x red, y green, z blue, ``axis_m`` long) as
  lines, the cloud crop as points, under one root node that turns the z-up robot frame into glTF's y-up.
  Metres, glTF's unit.
- HTML: one self-contained file (no script or style fetched at view time) with a canvas viewer: drag to
  rotate, wheel to zoom; the same content as the glTF, coordinates in millimetres for display.
"""

from __future__ import annotations

import html
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from cell.errors import ConfigError
from cell.planning import CellGeometry, Reach, WeldParams, WeldPath, plan_weld_path
from cell.world_seams import X_world_base, world_seams
from perception.errors import BadCapture
from perception.seams import Frame, Seam, read_seams_json
from perception.transforms import invert_X, xyzquat_from_X

FloatArray = NDArray[np.float64]

SEAMS_TOPIC = "/weldcell/seams"
ROUTE_TOPIC = "/weldcell/route"
DEFAULT_FRAME_ID = "base_link"
BagStorage = Literal["mcap", "sqlite3"]

# Without a cell config nothing limits reach: the planner still orders the seams and builds the passes.
_UNLIMITED_GEOMETRY = CellGeometry(Reach(radius_m=100.0, preferred_m=0.0))

# glTF is y-up; the robot's frames are z-up: x stays, z becomes y (a rotation of -90 deg about x).
X_GLTF_ROBOT = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class SeamsForExport:
    """The seams of one seams.json, in ``frame`` (``camera`` or ``base``), with the file they came from."""

    frame: Frame
    seams: tuple[Seam, ...]
    source: Path


def load_seams(path: str | os.PathLike[str]) -> SeamsForExport:
    """The seams of a seams.json as :class:`perception.seams.Seam` values (ids, lengths, confidences kept)."""
    src = Path(path)
    parsed = read_seams_json(src)
    seams = []
    for i, (kind, pts, poses) in enumerate(zip(parsed.kinds, parsed.points, parsed.poses, strict=True)):
        raw = parsed.raw["seams"][i]
        if len(poses) != len(pts):
            raise BadCapture(f"seam {i}: {len(poses)} poses for {len(pts)} points; exports need both", path=src)
        if kind not in ("linear", "curved"):
            raise BadCapture(f"seam {i}: kind {kind!r} is not 'linear' or 'curved'", path=src)
        seams.append(
            Seam(
                id=int(raw.get("id", i)),
                kind=kind,  # type: ignore[arg-type]
                points=pts,
                poses=poses,
                length_m=float(raw.get("length_m", np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())),
                confidence=float(raw.get("confidence", 1.0)),
                frame=parsed.frame,
            )
        )
    if not seams:
        raise BadCapture("the file holds no seam: nothing to export", path=src)
    return SeamsForExport(parsed.frame, tuple(seams), src)


CROP_RADIUS_M = 0.025


def cloud_near_seams(points: FloatArray, seams: Sequence[Seam], *, radius_m: float = CROP_RADIUS_M) -> FloatArray:
    """(K, 3) the points of ``points`` ((N, 3), metres, the seams' frame) within ``radius_m`` of a seam path point:
    the crop around the seams, as a viewer needs it."""
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    tree = cKDTree(np.concatenate([s.points for s in seams]))
    dist, _ = tree.query(pts, k=1, distance_upper_bound=radius_m)
    return pts[np.isfinite(dist)]


def capture_points(folder: str | os.PathLike[str], frame: Frame) -> FloatArray:
    """(N, 3) the valid points of a capture folder in ``frame`` (metres); BadCapture when ``frame`` is base and the
    capture has no pose.json."""
    from perception.capture import backproject, load_capture
    from perception.transforms import transform_points

    capture = load_capture(folder)
    p_camera = backproject(capture.depth_m, capture.intrinsics).reshape(-1, 3).astype(np.float64)
    p_camera = p_camera[np.all(np.isfinite(p_camera), axis=1) & (p_camera[:, 2] > 0)]
    if frame == "camera":
        return p_camera
    X = capture.X_base_camera
    if X is None:
        raise BadCapture("the seams are in the base frame but the capture has no pose.json", path=folder)
    return transform_points(X, p_camera)


# ================================================================================================ planning
def plan_for_export(
    data: SeamsForExport,
    *,
    params: WeldParams | None = None,
    geometry: CellGeometry | None = None,
    track_position_m: float = 0.0,
) -> WeldPath:
    """The weld path of base-frame seams (seen with the carriage at ``track_position_m``): the job's speeds and the
    cell's arc output in ``params`` (planner defaults without), ``geometry`` for reach and track (no limit without).
    ConfigError for camera-frame seams: a program needs the robot pose of the capture."""
    if data.frame != "base":
        raise ConfigError(
            f"{data.source}: the seams are in the camera frame; robot programs need base-frame seams "
            "(detect a capture that has pose.json)"
        )
    seams = world_seams(
        data.seams, track_position_m=track_position_m, axis_base=(geometry or _UNLIMITED_GEOMETRY).axis_base
    )
    return plan_weld_path(
        seams, params or WeldParams(), geometry=geometry or _UNLIMITED_GEOMETRY, track_position_m=track_position_m
    )


def route_poses(data: SeamsForExport, weld_path: WeldPath | None, *, track_position_m: float = 0.0) -> FloatArray:
    """(M, 4, 4) poses of the whole route in the seams' frame: the planned TCP waypoints of ``weld_path`` or,
    without a path, every seam's torch poses in file order.

    The seams' base frame is the base with the carriage where it was at the capture (``track_position_m``); a
    pass planned at another track position is brought into that same frame, so the route is one rigid picture.
    """
    if weld_path is None:
        return np.concatenate([s.poses for s in data.seams])
    X_base0_world = invert_X(X_world_base(track_position_m, weld_path.track_axis_base))
    return np.stack([X_base0_world @ weld_path.X_world_tcp(p, w) for _i, p, w in weld_path.waypoints()])


# ================================================================================================ programs
def write_programs(
    out: str | os.PathLike[str],
    weld_path: WeldPath,
    *,
    language: Literal["urscript", "ls"],
    name: str,
    comment: str = "",
    fanuc_options: dict[str, Any] | None = None,
) -> list[Path]:
    """Write one program per track position (a robot program cannot move the track): ``out`` itself when there
    is one, else ``out`` with ``_1``, ``_2``... before the suffix, run in that order with the track moved between."""
    from cell.programs import fanuc_ls_program, urscript_program

    parts = weld_path.split_at_track_moves()
    target = Path(out)
    written = []
    for k, part in enumerate(parts, start=1):
        path = target if len(parts) == 1 else target.with_name(f"{target.stem}_{k}{target.suffix}")
        part_name = name if len(parts) == 1 else f"{name}_{k}"
        if language == "urscript":
            text = urscript_program(part, name=part_name, comment=comment)
        else:
            text = fanuc_ls_program(part, name=part_name, comment=comment, **(fanuc_options or {}))
        _write_text(path, text)
        written.append(path)
    return written


# ================================================================================================ ROS 2 bag
def write_rosbag2(
    out: str | os.PathLike[str],
    data: SeamsForExport,
    route: FloatArray,
    *,
    frame_id: str = DEFAULT_FRAME_ID,
    storage: BagStorage = "mcap",
    stamp_ns: int = 0,
) -> Path:
    """A rosbag2 folder at ``out`` (must not exist): one PoseArray per seam on :data:`SEAMS_TOPIC`, 1 ms apart from
    ``stamp_ns``, then the route ((M, 4, 4) poses, metres) as one nav_msgs/Path on :data:`ROUTE_TOPIC`."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    if not frame_id or any(c.isspace() for c in frame_id):
        raise ConfigError(f"frame id {frame_id!r} must be a non-empty name without spaces")
    target = Path(out)
    if target.exists():
        raise ConfigError(f"{target} exists; a bag is written into a new folder (remove it or pick another --out)")
    if target.suffix == ".bag":
        # rosbags' AnyReader (and people) take '*.bag' for a ROS 1 bag file
        raise ConfigError(f"{target}: a ROS 2 bag is a folder; drop the ROS 1 suffix '.bag' (e.g. {target.stem})")
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Point, Quaternion, Pose = (
        T["geometry_msgs/msg/Point"],
        T["geometry_msgs/msg/Quaternion"],
        T["geometry_msgs/msg/Pose"],
    )
    PoseArray, PoseStamped, PathMsg = (
        T["geometry_msgs/msg/PoseArray"],
        T["geometry_msgs/msg/PoseStamped"],
        T["nav_msgs/msg/Path"],
    )

    def header(t_ns: int) -> Any:
        return Header(stamp=Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000), frame_id=frame_id)

    def pose(X: FloatArray) -> Any:
        x, y, z, qx, qy, qz, qw = (float(v) for v in xyzquat_from_X(X))
        return Pose(position=Point(x=x, y=y, z=z), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw))

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(target, version=9, storage_plugin=plugin) as writer:
        seams_conn = writer.add_connection(SEAMS_TOPIC, PoseArray.__msgtype__, typestore=ts)
        route_conn = writer.add_connection(ROUTE_TOPIC, PathMsg.__msgtype__, typestore=ts)
        t = int(stamp_ns)
        for seam in data.seams:
            msg = PoseArray(header=header(t), poses=[pose(X) for X in seam.poses])
            writer.write(seams_conn, t, ts.serialize_cdr(msg, PoseArray.__msgtype__))
            t += 1_000_000
        path_msg = PathMsg(header=header(t), poses=[PoseStamped(header=header(t), pose=pose(X)) for X in route])
        writer.write(route_conn, t, ts.serialize_cdr(path_msg, PathMsg.__msgtype__))
    return target


# ================================================================================================ glTF
def torch_axes_segments(poses: FloatArray, *, axis_m: float) -> dict[str, FloatArray]:
    """(N, 2, 3) line segments from each pose's origin along its x, y and z axes, ``axis_m`` long, by axis."""
    origins = poses[:, :3, 3]
    return {name: np.stack([origins, origins + axis_m * poses[:, :3, col]], axis=1) for col, name in enumerate("xyz")}


def write_gltf(
    out: str | os.PathLike[str],
    data: SeamsForExport,
    *,
    cloud_points: FloatArray | None = None,
    axis_m: float = 0.015,
) -> Path:
    """A binary glTF (.glb) of the seams, their torch axes and the cloud crop ((K, 3) metres, seams' frame)."""
    import trimesh

    scene = trimesh.Scene()
    colors = {"x": (230, 40, 40, 255), "y": (40, 180, 40, 255), "z": (40, 90, 230, 255)}

    def add_lines(name: str, vertices: FloatArray, entities: list[Any], rgba: Sequence[int]) -> None:
        path = trimesh.path.Path3D(
            entities=entities, vertices=vertices, colors=np.tile(np.asarray(rgba, np.uint8), (len(entities), 1))
        )
        scene.add_geometry(path, geom_name=name, node_name=name, transform=X_GLTF_ROBOT)

    Line = trimesh.path.entities.Line
    for seam in data.seams:
        # one polyline through the path points, in order
        add_lines(f"seam_{seam.id}", seam.points, [Line(np.arange(len(seam.points)))], (255, 30, 30, 255))
        for axis, segments in torch_axes_segments(seam.poses, axis_m=axis_m).items():
            lines = [Line(np.array([2 * i, 2 * i + 1])) for i in range(len(segments))]
            add_lines(f"seam_{seam.id}_torch_{axis}", segments.reshape(-1, 3), lines, colors[axis])
    if cloud_points is not None and len(cloud_points):
        cloud = trimesh.PointCloud(np.asarray(cloud_points, dtype=np.float64), colors=(150, 150, 150, 255))
        scene.add_geometry(cloud, geom_name="cloud_crop", node_name="cloud_crop", transform=X_GLTF_ROBOT)
    scene.metadata["weldcell"] = {"frame": data.frame, "units": "m", "source": str(data.source)}
    target = Path(out)
    target.parent.mkdir(parents=True, exist_ok=True)
    blob = scene.export(file_type="glb")
    target.write_bytes(blob if isinstance(blob, bytes) else bytes(blob))
    return target


# ================================================================================================ HTML
MAX_HTML_CLOUD_POINTS = 40_000  # every 10th point of a typical crop; keeps the page a few MB and the canvas fast


def write_html(
    out: str | os.PathLike[str],
    data: SeamsForExport,
    *,
    cloud_points: FloatArray | None = None,
    axis_m: float = 0.015,
    title: str | None = None,
) -> Path:
    """A self-contained HTML page that draws the seams, torch axes and cloud crop in 3D (millimetres shown)."""
    cloud = np.zeros((0, 3)) if cloud_points is None else np.asarray(cloud_points, dtype=np.float64).reshape(-1, 3)
    if len(cloud) > MAX_HTML_CLOUD_POINTS:
        cloud = cloud[:: math.ceil(len(cloud) / MAX_HTML_CLOUD_POINTS)]
    payload = {
        "frame": data.frame,
        "seams": [
            {
                "id": s.id,
                "kind": s.kind,
                "length_mm": round(s.length_m * 1000.0, 1),
                "points": np.round(s.points * 1000.0, 2).tolist(),
                "axes": {
                    k: np.round(v * 1000.0, 2).tolist() for k, v in torch_axes_segments(s.poses, axis_m=axis_m).items()
                },
            }
            for s in data.seams
        ],
        "cloud": np.round(cloud * 1000.0, 1).tolist(),
    }
    page_title = title or f"weldcell: {len(data.seams)} seam(s) of {data.source.name}"
    # "</" never appears inside the script (a seam's data cannot end the script element)
    data_js = json.dumps(payload, separators=(",", ":")).replace("</", "<\\/")
    text = _HTML_TEMPLATE.replace("__TITLE__", html.escape(page_title)).replace("__DATA__", data_js)
    target = Path(out)
    _write_text(target, text)
    return target


def _write_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


_HTML_TEMPLATE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>__TITLE__</title>
<style>
 body { margin: 0; font: 14px system-ui, sans-serif; background: #1d1f21; color: #ddd; }
 #info { position: absolute; top: 8px; left: 10px; pointer-events: none; }
 canvas { display: block; width: 100vw; height: 100vh; cursor: grab; }
 .k { display: inline-block; width: 10px; height: 10px; margin: 0 4px 0 10px; }
</style></head>
<body>
<div id="info"><b>__TITLE__</b><br>
 <span class="k" style="background:#ff1e1e"></span>seam
 <span class="k" style="background:#e62828"></span>torch x (travel)
 <span class="k" style="background:#28b428"></span>torch y
 <span class="k" style="background:#285ae6"></span>torch z (into the joint)
 <span class="k" style="background:#969696"></span>cloud crop<br>
 <span id="frame"></span>, mm. Drag: rotate. Shift+drag: pan. Wheel: zoom.</div>
<canvas id="view"></canvas>
<script>
"use strict";
const DATA = __DATA__;
const canvas = document.getElementById("view"), ctx = canvas.getContext("2d");
document.getElementById("frame").textContent = DATA.frame + " frame";
const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
for (const p of DATA.cloud.concat(...DATA.seams.map(s => s.points)))
  for (let i = 0; i < 3; i++) { lo[i] = Math.min(lo[i], p[i]); hi[i] = Math.max(hi[i], p[i]); }
const centre = [0, 1, 2].map(i => (lo[i] + hi[i]) / 2);
const extent = Math.max(1, ...[0, 1, 2].map(i => hi[i] - lo[i]));
let yaw = -0.6, pitch = 0.9, zoom = 1, pan = [0, 0];
function project(p) {
  const x = p[0] - centre[0], y = p[1] - centre[1], z = p[2] - centre[2];
  const cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
  const x1 = cy * x - sy * y, y1 = sy * x + cy * y;     // about z (z is up in the robot frames)
  const y2 = cp * y1 - sp * z, z2 = sp * y1 + cp * z;   // tilt towards the viewer
  const s = zoom * Math.min(canvas.width, canvas.height) / (1.3 * extent);
  return [canvas.width / 2 + pan[0] + s * x1, canvas.height / 2 + pan[1] - s * z2, y2];
}
function line(a, b, colour, width) {
  const p = project(a), q = project(b);
  ctx.strokeStyle = colour; ctx.lineWidth = width;
  ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(q[0], q[1]); ctx.stroke();
}
function draw() {
  canvas.width = canvas.clientWidth * devicePixelRatio; canvas.height = canvas.clientHeight * devicePixelRatio;
  ctx.fillStyle = "#1d1f21"; ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = "#969696";
  for (const p of DATA.cloud) { const q = project(p); ctx.fillRect(q[0], q[1], 1.5, 1.5); }
  const axisColour = { x: "#e62828", y: "#28b428", z: "#285ae6" };
  for (const s of DATA.seams) {
    for (const k of ["x", "y", "z"]) for (const seg of s.axes[k]) line(seg[0], seg[1], axisColour[k], 1);
    for (let i = 1; i < s.points.length; i++) line(s.points[i - 1], s.points[i], "#ff1e1e", 3);
    const m = project(s.points[Math.floor(s.points.length / 2)]);
    ctx.fillStyle = "#fff"; ctx.font = (12 * devicePixelRatio) + "px sans-serif";
    ctx.fillText("seam " + s.id + " (" + s.length_mm + " mm)", m[0] + 6, m[1] - 6);
    ctx.fillStyle = "#969696";
  }
}
let drag = null;
canvas.addEventListener("mousedown", e => { drag = [e.clientX, e.clientY, e.shiftKey]; });
addEventListener("mouseup", () => { drag = null; });
addEventListener("mousemove", e => {
  if (!drag) return;
  const dx = e.clientX - drag[0], dy = e.clientY - drag[1];
  if (drag[2]) { pan[0] += dx * devicePixelRatio; pan[1] += dy * devicePixelRatio; }
  else { yaw += dx * 0.01; pitch = Math.max(-1.57, Math.min(1.57, pitch + dy * 0.01)); }
  drag = [e.clientX, e.clientY, drag[2]]; draw();
});
canvas.addEventListener("wheel", e => { e.preventDefault(); zoom *= Math.exp(-e.deltaY * 0.001); draw(); });
addEventListener("resize", draw);
draw();
</script>
</body></html>
"""
