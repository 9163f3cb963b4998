"""The exports of a finished daemon job (``GET /jobs/{id}/export/{format}``): the same five formats as
``weldcell export`` (:mod:`cell.export`), from what the job itself detected and planned.

When a job that planned a path ends, :func:`save_job_result` keeps in ``<results>/<id>/``:

- ``seams.json``: the job's merged seams in the world frame (the base frame with the carriage at 0), written as a
  base-frame seams.json (``weldcell schema seams``), and the same at full precision in ``seams.npz`` (the path is
  planned again from these: seams.json rounds to the micrometre);
- ``plan.json``: where the path was planned from (track position, TCP position) and the job file, so that the
  same planner call gives the same path again (checked against the job's stored report);
- ``cloud.npy``: the captures' points near the seams (world frame, metres), for the 3D views.

The newest :data:`KEEP_RESULTS` jobs' results are kept (:func:`prune_results`).

:func:`export_job` writes one format into a fresh temporary folder and returns the bytes to send with their
media type: a program (one per track position: a zip when there are several), the ROS 2 bag folder (zipped), the
binary glTF or the HTML page.
"""

from __future__ import annotations

import io
import json
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from cell.config import CellConfig
from cell.errors import ConfigError
from cell.export import (
    CROP_RADIUS_M,
    MAX_HTML_CLOUD_POINTS,
    SeamsForExport,
    route_poses,
    write_gltf,
    write_html,
    write_programs,
    write_rosbag2,
)
from cell.job import load_job, weld_params
from cell.job_checks import safety_limits
from cell.job_report import JobData
from cell.planning import WeldPath, plan_weld_path
from cell.world_seams import X_world_base, world_seams
from perception.seams import DetectionResult, Seam, write_seams_json

FORMATS: dict[str, tuple[str, str]] = {
    "urscript": ("text/plain; charset=utf-8", ".script"),
    "ls": ("text/plain; charset=utf-8", ".ls"),
    "rosbag2": ("application/zip", ".zip"),
    "gltf": ("model/gltf-binary", ".glb"),
    "html": ("text/html; charset=utf-8", ".html"),
}
"""Format -> (media type, file suffix)."""

ZIP_TYPE = "application/zip"


KEEP_RESULTS = 200
"""How many jobs' results are kept (the newest; about 1 MB each): older jobs answer 409 like a job without a path."""


class NothingToExport(Exception):
    """The job has no kept result (it planned no path, or it ran before results were kept)."""


@dataclass(frozen=True)
class Exported:
    body: bytes
    media_type: str
    filename: str


def save_job_result(folder: Path, data: JobData) -> Path | None:
    """Keep what the exports of job ``data`` need in ``folder`` (created); None when it planned no path."""
    if data.path is None or data.planned_from is None or not data.seams:
        return None
    folder.mkdir(parents=True, exist_ok=True)
    seams = [
        Seam(
            id=s.id,
            kind=s.kind,  # type: ignore[arg-type]
            points=s.points_world,
            poses=s.X_world_torch,
            length_m=s.length_m,
            confidence=s.confidence,
            frame="base",
        )
        for s in data.seams
    ]
    write_seams_json(DetectionResult(frame="base", seams=tuple(seams)), folder / "seams.json")
    arrays: dict[str, Any] = {}
    for k, s in enumerate(seams):  # full precision: seams.json rounds, and the path must be planned exactly again
        arrays[f"points_{k}"], arrays[f"poses_{k}"] = s.points, s.poses
    meta = [{"id": s.id, "kind": s.kind, "length_m": s.length_m, "confidence": s.confidence} for s in seams]
    np.savez(folder / "seams.npz", meta=np.array(json.dumps(meta)), **arrays)
    track_m, p_world = data.planned_from
    plan = {
        "job_file": data.job.source,
        "track_position_m": float(track_m),
        "p_world_start": [float(v) for v in np.asarray(p_world).reshape(3)],
        "summary": data.path.summary(),
    }
    (folder / "plan.json").write_text(json.dumps(plan, indent=1), encoding="utf-8")
    np.save(folder / "cloud.npy", _cloud_near(data, np.concatenate([s.points for s in seams])))
    prune_results(folder.parent)
    return folder


def prune_results(results: Path, keep: int = KEEP_RESULTS) -> list[int]:
    """Remove all but the ``keep`` newest (highest job id) result folders under ``results``; the ids removed."""
    import shutil

    ids = sorted(int(p.name) for p in results.iterdir() if p.is_dir() and p.name.isdigit())
    old = ids[: max(0, len(ids) - keep)]
    for job_id in old:
        shutil.rmtree(results / str(job_id), ignore_errors=True)
    return old


def _cloud_near(data: JobData, seam_points: np.ndarray) -> np.ndarray:
    """(K, 3) world points of the job's captures within :data:`CROP_RADIUS_M` of a seam point, at most
    :data:`MAX_HTML_CLOUD_POINTS` (evenly thinned)."""
    from scipy.spatial import cKDTree

    from perception.capture import backproject
    from perception.transforms import transform_points

    tree = cKDTree(seam_points)
    assert data.path is not None
    axis = data.path.track_axis_base
    kept = []
    for track_m, capture in data.captures:
        X_base_camera = capture.X_base_camera
        if X_base_camera is None:
            continue
        p = backproject(capture.depth_m, capture.intrinsics).reshape(-1, 3).astype(np.float64)
        p = p[np.all(np.isfinite(p), axis=1) & (p[:, 2] > 0)]
        p_world = transform_points(X_world_base(track_m, axis) @ X_base_camera, p)
        dist, _ = tree.query(p_world, k=1, distance_upper_bound=CROP_RADIUS_M)
        kept.append(p_world[np.isfinite(dist)])
    cloud = np.concatenate(kept) if kept else np.zeros((0, 3))
    if len(cloud) > MAX_HTML_CLOUD_POINTS:
        cloud = cloud[:: -(-len(cloud) // MAX_HTML_CLOUD_POINTS)]
    return cloud


def replan(folder: Path, config: CellConfig) -> tuple[SeamsForExport, WeldPath, str]:
    """(the seams for export, the job's path planned again, the workpiece) from a kept result; ConfigError when
    the path planned again is not the one the job ran (its job file changed since)."""
    plan = json.loads((folder / "plan.json").read_text(encoding="utf-8"))
    data = _load_seams(folder)
    job = load_job(plan["job_file"])
    params = weld_params(config.welding, job.spec.welding, job.spec.seams.seam_filter())
    geometry = safety_limits(config).geometry
    seams = world_seams(data.seams, track_position_m=0.0, axis_base=geometry.axis_base)
    path = plan_weld_path(
        seams,
        params,
        geometry=geometry,
        track_position_m=plan["track_position_m"],
        p_world_start=np.asarray(plan["p_world_start"]),
    )
    if _comparable(path.summary()) != _comparable(plan["summary"]):
        raise ConfigError(
            f"the job file {plan['job_file']} changed since the job ran: its path cannot be exported again"
        )
    return data, path, job.workpiece


def _load_seams(folder: Path) -> SeamsForExport:
    with np.load(folder / "seams.npz") as z:
        meta = json.loads(str(z["meta"]))
        seams = tuple(
            Seam(
                id=int(m["id"]),
                kind=m["kind"],
                points=z[f"points_{k}"],
                poses=z[f"poses_{k}"],
                length_m=float(m["length_m"]),
                confidence=float(m["confidence"]),
                frame="base",
            )
            for k, m in enumerate(meta)
        )
    return SeamsForExport("base", seams, folder / "seams.json")


def _comparable(summary: dict[str, Any]) -> list[tuple[int, float, float]]:
    # the seams were merged from several captures; read back from seams.json they come from "one": sources differ
    return [(p["seam_id"], round(p["length_m"], 5), round(p["track_position_m"], 5)) for p in summary["passes"]]


def export_job(folder: Path, config: CellConfig, fmt: str, *, job_id: int) -> Exported:
    """Job ``job_id``'s kept result (``folder``) as ``fmt`` (one of :data:`FORMATS`); NothingToExport when there
    is none."""
    if not (folder / "plan.json").is_file():
        raise NothingToExport(f"job {job_id} has no kept result to export (it planned no path)")
    media, suffix = FORMATS[fmt]
    data, path, workpiece = replan(folder, config)
    stem = f"job{job_id}"
    with tempfile.TemporaryDirectory(prefix="weldcell-export-") as tmp:
        out = Path(tmp) / f"{stem}{suffix}"
        if fmt in ("urscript", "ls"):
            language: Literal["urscript", "ls"] = "urscript" if fmt == "urscript" else "ls"
            written = write_programs(
                out, path, language=language, name=_program_name(workpiece), comment=f"weldcell job {job_id}"
            )
            if len(written) == 1:
                return Exported(written[0].read_bytes(), media, written[0].name)
            return Exported(_zip(written, Path(tmp)), ZIP_TYPE, f"{stem}-{fmt}.zip")
        if fmt == "rosbag2":
            bag = write_rosbag2(Path(tmp) / f"{stem}-bag", data, route_poses(data, path, track_position_m=0.0))
            return Exported(_zip(sorted(p for p in bag.rglob("*") if p.is_file()), Path(tmp)), media, out.name)
        cloud = np.load(folder / "cloud.npy")
        writer = write_gltf if fmt == "gltf" else write_html
        return Exported(writer(out, data, cloud_points=cloud).read_bytes(), media, out.name)


def _program_name(workpiece: str) -> str:
    name = "".join(c if c.isalnum() or c == "_" else "_" for c in workpiece).strip("_")
    return (name or "weldcell")[:24]


def _zip(files: list[Path], root: Path) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for f in files:
            zf.write(f, f.relative_to(root).as_posix())
    return buf.getvalue()
