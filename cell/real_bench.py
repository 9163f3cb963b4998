"""``weldcell bench real``: the detector on every real scan and frame in ``../shared/realdata``.

Nothing is copied: clouds are read in place, the one structured-light RGB-D frame is converted in memory.
Items with a reference (``references/*.json``: seams located by independent plane and groove fits) are
scored the way the references' README asks:
- a reference seam is **covered** when at least 60% of its length (sampled every 1 mm) has a detected path
  point within the reference's ``tolerance_m``;
- a detected seam is **false** when its median distance from every reference seam exceeds twice the
  tolerance;
- an item **passes** when every reference seam is covered and no detected seam is false.
Items without a reference are listed with what was found, or why nothing could be run (a photo without
depth, a CAD mesh), and drawn (``--out``) so that a person can judge them.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any, Literal

import numpy as np

COVER_SHARE = 0.6
CLOUD_SUFFIXES = (".pcd", ".ply")
XIAOYU = "XiaoyuChangeTheWorld_weld-seam-tracker-3d"


@dataclass
class RealItem:
    """One real item and what the detector made of it (lengths in metres, times in seconds)."""

    item: str  # path relative to the realdata folder
    kind: str  # cloud, rgbd frame, photos, mesh
    points: int = 0
    # kind, joint, length_m, and the median distance to a reference when there is one
    seams: list[dict[str, Any]] = field(default_factory=list)
    outcome: str = ""  # seams, no_seam, not_run, error
    reason: str = ""
    time_s: float = 0.0
    reference: str | None = None
    tolerance_m: float | None = None
    coverage: list[float] = field(default_factory=list)  # per reference seam
    false_seams: int = 0
    image: str | None = None
    note: str = ""
    viewpoint: list[float] | None = None  # where the detector looked at the cloud from (the cloud's frame)
    perturbed: list[bool] = field(default_factory=list)  # per draw with points dropped at random: passed

    @property
    def scored(self) -> bool:
        return self.reference is not None

    @property
    def passed(self) -> bool | None:
        if not self.scored:
            return None
        return bool(self.coverage) and all(c >= COVER_SHARE for c in self.coverage) and self.false_seams == 0

    def to_json(self) -> dict[str, Any]:
        out = dict(self.__dict__)
        out["passed"] = self.passed
        return out


def _references(realdata: Path) -> dict[str, dict[str, Any]]:
    refs = {}
    for f in sorted((realdata / "references").glob("*.json")):
        doc = json.loads(f.read_text())
        refs[doc["item"]] = doc | {"file": f.name}
    return refs


def discover(realdata: Path) -> list[tuple[str, str]]:
    """(relative path, kind) of every item in the folder."""
    items: list[tuple[str, str]] = []
    for d in sorted(p for p in realdata.iterdir() if p.is_dir() and p.name != "references"):
        files = sorted(d.rglob("*"))
        if d.name == XIAOYU:
            items.append((d.name, "rgbd frame"))
            continue
        for f in files:
            if f.suffix.lower() in CLOUD_SUFFIXES:
                items.append((str(f.relative_to(realdata)), "mesh" if _is_mesh(f) else "cloud"))
            elif f.suffix.lower() == ".stl":
                items.append((str(f.relative_to(realdata)), "mesh"))
        photo_dirs = sorted({f.parent for f in files if f.suffix.lower() in (".jpg", ".jpeg", ".png")})
        for pd in photo_dirs:
            items.append((str(pd.relative_to(realdata)), "photos"))
    return items


def _is_mesh(path: Path) -> bool:
    """A PLY whose header declares faces is a mesh (a CAD model), not a scan."""
    if path.suffix.lower() != ".ply":
        return False
    with path.open("rb") as f:
        head = f.read(4096)
    end = head.find(b"end_header")
    for line in head[: end if end >= 0 else None].splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[:2] == [b"element", b"face"] and parts[2] != b"0":
            return True
    return False


def xiaoyu_capture(realdata: Path) -> Any:
    """The structured-light frame as a capture: IR image as colour, depth in its own 0.063 mm counts."""
    import cv2

    from perception.capture import CameraIntrinsics, Capture
    from perception.errors import BadCapture

    base = realdata / XIAOYU
    stem = next(base.glob("depth_*.png")).stem.removeprefix("depth_")
    depth_raw = cv2.imread(str(base / f"depth_{stem}.png"), cv2.IMREAD_UNCHANGED)
    if depth_raw is None or depth_raw.ndim != 2:
        raise BadCapture("cannot read the frame's 16-bit depth image", path=base)
    ir = cv2.imread(str(base / f"ir_left_{stem}.png"), cv2.IMREAD_GRAYSCALE)
    text = (base / f"depth_{stem}.txt").read_text()
    k = [float(v) for v in text.split("[Intrinsic]")[1].split("[")[0].strip().split(",")]
    scale_mm = float(text.split("[ScaleUnit]")[1].strip().split()[0])
    h, w = depth_raw.shape
    depth_m = depth_raw.astype(np.float32) * np.float32(scale_mm / 1000.0)
    depth_m[depth_raw == 0] = np.nan
    color = np.repeat(ir[:, :, None], 3, axis=2).astype(np.uint8) if ir is not None else np.zeros((h, w, 3), np.uint8)
    intr = CameraIntrinsics(w, h, k[0], k[4], k[2], k[5])
    return Capture(color, depth_m, intr, depth_scale=1000.0 / scale_mm, source=str(base))


def _score(item: RealItem, seams_pts: list[np.ndarray], ref: dict[str, Any]) -> None:
    from perception.evaluate import point_to_polyline_distance, resample_polyline

    tol = float(ref["tolerance_m"])
    item.reference = ref["file"]
    item.tolerance_m = tol
    ref_lines = [np.asarray(s["points"], dtype=np.float64) for s in ref["seams"]]
    all_pts = np.vstack(seams_pts) if seams_pts else np.zeros((0, 3))
    for line in ref_lines:
        samples = resample_polyline(line, 0.001)
        if all_pts.size == 0:
            item.coverage.append(0.0)
            continue
        from scipy.spatial import cKDTree

        d, _ = cKDTree(all_pts).query(samples)
        item.coverage.append(round(float(np.mean(d <= tol)), 3))
    for s, pts in zip(item.seams, seams_pts, strict=True):
        med = min(float(np.median(point_to_polyline_distance(pts, line))) for line in ref_lines)
        s["median_to_reference_m"] = round(med, 4)
        if med > 2 * tol:
            item.false_seams += 1


Method = Literal["refined", "surfaces", "paper"]


def run_item(realdata: Path, rel: str, kind: str, refs: dict[str, dict[str, Any]],
             method: Method = "refined") -> tuple[RealItem, Any, Any]:  # fmt: skip
    """Detect one item. Returns the item, its cloud (a :class:`perception.capture.PointCloud`, with its
    colours when the file has them) or None, and the seams' paths."""
    from perception.capture import PointCloud, read_point_cloud
    from perception.cloud_view import sensor_side
    from perception.detect import DetectParams, detect, detect_cloud
    from perception.errors import NoSeamFound, PerceptionError

    item = RealItem(rel, kind)
    if kind == "photos":
        item.outcome, item.reason = (
            "not_run",
            (
                "photos without depth: seams need 3D; give an RGB-D capture of the part, or reconstruct a cloud "
                "from several posed views (photogrammetry) and detect on that cloud"
            ),
        )
        return item, None, []
    if kind == "mesh":
        item.outcome, item.reason = "not_run", "a CAD mesh, not sensor data (its scans are the items beside it)"
        return item, None, []
    t0 = time.perf_counter()
    cloud = None
    paths: list[np.ndarray] = []
    try:
        if kind == "rgbd frame":
            cap = xiaoyu_capture(realdata)
            xyz = cap.points_camera().reshape(-1, 3)
            cloud = PointCloud(xyz[np.isfinite(xyz[:, 2])][::16].astype(np.float64), source=rel)
            item.viewpoint = [0.0, 0.0, 0.0]
            item.points = int(np.isfinite(cap.depth_m).sum())
            res = detect(cap, DetectParams(method=method))
        else:
            pc = read_point_cloud(realdata / rel)
            cloud = pc
            item.points = len(pc.points)
            item.viewpoint = sensor_side(pc.points, pc.normals).round(4).tolist()
            res = detect_cloud(pc, DetectParams(method=method))
        item.time_s = time.perf_counter() - t0
        item.outcome = "seams"
        for s in res.seams:
            item.seams.append({"kind": s.kind, "joint": s.joint, "length_m": round(s.length_m, 4)})
            paths.append(np.asarray(s.points))
    except NoSeamFound as err:
        item.time_s = time.perf_counter() - t0
        item.outcome, item.reason = "no_seam", str(err)
    except PerceptionError as err:
        item.time_s = time.perf_counter() - t0
        item.outcome, item.reason = "not_run", f"refused: {err}"
    except Exception as err:  # a bug: shown, never hidden
        item.time_s = time.perf_counter() - t0
        item.outcome, item.reason = "error", f"{type(err).__name__}: {err}"
    if rel in refs:
        _score(item, paths, refs[rel])
    if kind == "rgbd frame":
        item.note = _authors_path(realdata, paths)
    return item, cloud, paths


@cache
def authors_points(realdata: Path) -> np.ndarray | None:
    """The Xiaoyu frame's own detected weld path (weld_trajectory.csv, camera frame) in metres; None when the
    file is not there. Read once (the item's note and its picture both use it)."""
    csv = realdata / XIAOYU / "weld_trajectory.csv"
    if not csv.is_file():
        return None
    ref = np.loadtxt(csv, delimiter=",", skiprows=1)[:, :3]
    return np.asarray(ref / 1000.0 if np.abs(ref).max() > 10 else ref, dtype=np.float64)


def _authors_path(realdata: Path, paths: list[np.ndarray]) -> str:
    """The Xiaoyu frame ships its authors' own detected weld path (camera frame, mm): how far ours lies."""
    ref = authors_points(realdata)
    if ref is None:
        return ""
    from perception.evaluate import point_to_polyline_distance

    if not paths:
        length = np.linalg.norm(np.diff(ref, axis=0), axis=1).sum()
        return f"the authors' path: {len(ref)} points, {length * 1000:.0f} mm long; no seam of ours to compare"
    best = min(float(np.median(point_to_polyline_distance(p, ref))) for p in paths)
    return f"nearest of our seams to the authors' path: median {best * 1000:.1f} mm"


def draw(item: RealItem, cloud: Any, paths: list[np.ndarray], ref: dict[str, Any] | None, path: Path) -> None:
    """The item's picture (:func:`cell.cloud_picture.draw_cloud`), with the reference in green and the verdict."""
    from cell.cloud_picture import draw_cloud

    verdict = "" if item.passed is None else (" PASS" if item.passed else " FAIL")
    joints = [s.get("joint", "") for s in item.seams]
    title = f"{item.item}: {item.outcome}, {len(paths)} seam(s){verdict}  (green: reference, red: detected)"
    draw_cloud(cloud, paths, joints, path, viewpoint=item.viewpoint, reference=ref, title=title)


def perturbed_passes(pc: Any, ref: dict[str, Any], *, draws: int, dropout: float,
                     method: Method = "refined") -> list[bool]:  # fmt: skip
    """Whether referenced cloud ``pc`` (a :class:`perception.capture.PointCloud`) still passes with a share
    ``dropout`` of its points dropped at random, in each of ``draws`` seeded draws: a result that one sensor's
    sampling happens to give, and another sampling of the same part does not, is luck, not a detector that
    works on real data."""
    from perception.detect import DetectParams, detect_cloud
    from perception.errors import PerceptionError

    out = []
    for seed in range(draws):
        keep = np.random.default_rng(seed).random(len(pc.points)) >= dropout
        cloud = pc.subset(keep)
        item = RealItem(pc.source, "cloud")
        paths: list[np.ndarray] = []
        try:
            res = detect_cloud(cloud, DetectParams(method=method))
            item.seams = [{"kind": s.kind, "joint": s.joint, "length_m": s.length_m} for s in res.seams]
            paths = [np.asarray(s.points) for s in res.seams]
        except PerceptionError:
            pass  # no seam (or refused): every reference seam uncovered
        _score(item, paths, ref)
        out.append(bool(item.passed))
    return out


def run_real(realdata: Path, out: Path | None = None, method: Method = "refined", *, draws: int = 0,
             dropout: float = 0.02) -> list[RealItem]:  # fmt: skip
    """Every item of ``realdata`` detected (and drawn under ``out``); each referenced cloud also in ``draws``
    draws with a share ``dropout`` of its points dropped (:func:`perturbed_passes`)."""
    refs = _references(realdata)
    items = []
    for rel, kind in discover(realdata):
        item, cloud, paths = run_item(realdata, rel, kind, refs, method)
        if draws and kind == "cloud" and rel in refs and cloud is not None:  # the cloud run_item read
            item.perturbed = perturbed_passes(cloud, refs[rel], draws=draws, dropout=dropout, method=method)
        if out is not None and cloud is not None:
            out.mkdir(parents=True, exist_ok=True)
            img = out / (rel.replace("/", "__") + ".png")
            ref = refs.get(rel)
            authors = authors_points(realdata) if kind == "rgbd frame" else None
            if ref is None and authors is not None:  # the frame's authors' own path, drawn as its reference
                ref = {"seams": [{"points": authors}]}
            draw(item, cloud, paths, ref, img)
            item.image = str(img)
        items.append(item)
    return items
