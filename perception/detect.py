"""Coarse-to-fine multi-seam detection (after Wei et al.), as a short sequence of timed, pure steps.

    Capture -> prompts (given or automatic) -> segment -> seam ROI (bands where two masks meet)
            -> organized cloud cropped to the ROI -> pass-through -> voxel grid -> KD-tree
            -> normals + curvature -> region growing -> edge points between regions
            -> seam candidates (concave junction or narrow gap) -> fit (line | curve)
            -> refine from full-resolution points -> path points -> torch poses -> base frame

This module holds the coarse stage, the butt joints (from the coarse masks), the support plane, the path and the
output frame; the fine stage on voxel regions is :func:`perception.region_seams.regions_to_seams`, the
surfaces-first pipeline (``method="surfaces"``) :mod:`perception.detect_surfaces`.

Usable on its own: ``detect(load_capture(path), DetectParams())``.
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import dataclass, replace
from functools import partial
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from threadpoolctl import ThreadpoolController

from perception.butt import butt_from_surfaces
from perception.capture import MAX_PLAUSIBLE_DEPTH_M, Capture, PointCloud
from perception.cloud import stray_points, surface_spacing
from perception.detect_params import DetectParams, StepLog
from perception.errors import BadCapture, NoSeamFound, PerceptionError
from perception.fits import fit_plane
from perception.helper_process import HelperProcess
from perception.organized import veil_mask
from perception.path import interpolate_rows, sample_uniform, torch_poses
from perception.region_seams import regions_to_seams
from perception.seamfit import SeamGeometry
from perception.seams import DetectionResult, Seam
from perception.segment_default import GraphSegmenter, auto_prompts, seam_roi
from perception.segmentation import Segmenter, SurfaceMasks

FloatArray = NDArray[np.float64]
logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class CoarseResult:
    prompts_px: FloatArray
    prompts_source: str
    masks: SurfaceMasks
    roi_mask: NDArray[np.bool_]
    pairs: dict[tuple[int, int], int]


def coarse_stage(
    capture: Capture, points: NDArray[np.float32], params: DetectParams, segmenter: Segmenter, log: StepLog
) -> CoarseResult:
    with log.step("prompts"):
        if capture.prompts_px is not None and len(capture.prompts_px):
            prompts, source = capture.prompts_px, "prompts.json"
        else:
            prompts, source = (
                auto_prompts(points, params=params.auto_prompts, segmenter_params=params.segmenter),
                "auto",
            )
    if len(prompts) < 2:
        raise NoSeamFound(f"only {len(prompts)} workpiece surface(s) prompted ({source}); a seam needs two")
    with log.step("segment"):
        masks = segmenter.segment(capture.color_rgb, capture.depth_m, prompts, points_camera=points)
    with log.step("roi"):
        z_med = float(np.nanmedian(capture.depth_m))
        band_px = max(2, round(params.roi_band_m * capture.intrinsics.fx / max(z_med, 1e-3)))
        roi = seam_roi(masks.labels, band_px=band_px)
    return CoarseResult(prompts, source, masks, roi.mask, roi.pairs)


AUTO_VOXEL_FACTOR = 1.5  # clouds: voxel >= this times the sample spacing
MAX_AUTO_VOXEL_M = 0.010


def _butt_seams(
    organized: NDArray[np.float32],
    band: NDArray[np.bool_],
    label_image: NDArray[np.int32],
    pairs: dict[tuple[int, int], int],
    voxel_planes: dict[int, tuple[FloatArray, FloatArray, float]],
    params: DetectParams,
    viewpoint: FloatArray,
) -> list[SeamGeometry]:
    """Butt joints come from the coarse stage: two surfaces (masks) that meet in the seam band, lie on
    one plane and are separated by a narrow gap (the voxel grid would bridge a gap this narrow).

    The cheap test runs on each mask's plane from the voxel grid; only coplanar neighbours get the
    full-resolution edge tracing, on every valid pixel of the band (no veil filter: the gap itself is a
    depth jump, and the filter would trim one plate's edge more than the other's)."""
    out: list[SeamGeometry] = []
    if params.method == "paper":
        return out  # the paper's fine stage has no butt-joint step
    from scipy import ndimage

    cos_max = np.cos(2 * params.seams.max_coplanar_rad)
    boxes: list[Any] | None = None
    for i, j in sorted(pairs):
        pi, pj = voxel_planes.get(i), voxel_planes.get(j)
        if pi is None or pj is None or abs(pi[1] @ pj[1]) < cos_max:
            continue
        if abs((pj[0] - pi[0]) @ pi[1]) > 0.004 + pi[2] + pj[2]:
            continue
        if boxes is None:
            boxes = ndimage.find_objects(label_image + 1)  # label k: object k + 1, index k
        if i >= len(boxes) or j >= len(boxes) or boxes[i] is None or boxes[j] is None:
            continue
        # the joint lies where the two masks meet: work inside their joint bounding box only
        bi, bj = boxes[i], boxes[j]
        crop = (
            slice(min(bi[0].start, bj[0].start), max(bi[0].stop, bj[0].stop)),
            slice(min(bi[1].start, bj[1].start), max(bi[1].stop, bj[1].stop)),
        )
        org_c, band_c, lab_c = organized[crop], band[crop], label_image[crop]
        pa = org_c[band_c & (lab_c == i)].astype(np.float64)
        pb = org_c[band_c & (lab_c == j)].astype(np.float64)
        scanlines = partial(_scanlines, org_c, band_c, lab_c, (i, j))
        res = butt_from_surfaces(pa, pb, scanlines, params.seams, viewpoint)
        if res is None:
            continue
        ends, n, rms, _gap = res
        nn = np.tile(n, (2, 1))
        out.append(SeamGeometry("linear", "butt", ends, nn, nn, (-1, -1), (i, j), min(len(pa), len(pb)), rms))
    return out


def _scanlines(
    organized: NDArray[np.float32], band: NDArray[np.bool_], label_image: NDArray[np.int32], pair: tuple[int, int]
) -> list[FloatArray]:
    """Valid band points of each image row (or column, whichever crosses the joint more squarely) that
    holds both surfaces of ``pair``, in pixel order."""
    m_a = band & (label_image == pair[0])
    m_b = band & (label_image == pair[1])
    ya, xa = np.nonzero(m_a)
    yb, xb = np.nonzero(m_b)
    if len(ya) == 0 or len(yb) == 0:
        return []
    # the joint runs roughly perpendicular to the line joining the two masks' centres
    dy, dx = yb.mean() - ya.mean(), xb.mean() - xa.mean()
    use_rows = abs(dx) >= abs(dy)
    grid = organized if use_rows else organized.transpose(1, 0, 2)
    sel = band if use_rows else band.T
    has_a = (m_a if use_rows else m_a.T).any(axis=1)
    has_b = (m_b if use_rows else m_b.T).any(axis=1)
    out = []
    for r in np.flatnonzero(has_a & has_b):
        row = grid[r][sel[r]]
        out.append(row[np.isfinite(row[:, 2])].astype(np.float64))
    return out


def support_plane(
    organized: NDArray[np.float32], labels: NDArray[np.int32], *, inlier_m: float = 0.003, seed: int = 0
) -> tuple[FloatArray, FloatArray] | None:
    """The table or fixture plate the workpiece stands on: the dominant plane of the background pixels
    (RANSAC on a sample), when it holds at least a third of them. (centroid, unit normal) or None."""
    # every 4th pixel each way is plenty for a plane, and 16 times cheaper to gather and sample
    pts, lab = organized[::4, ::4], labels[::4, ::4]
    bg = pts[(lab < 0) & np.isfinite(pts[..., 2])].astype(np.float64)
    if len(bg) < 100:
        return None
    rng = np.random.default_rng(seed)
    sample = bg[rng.choice(len(bg), 3000, replace=False)] if len(bg) > 3000 else bg
    best_n, best = 0, None
    for _ in range(60):
        a, b, c = sample[rng.choice(len(sample), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-9:
            continue
        n /= norm
        inl = np.abs((sample - a) @ n) < inlier_m
        if inl.sum() > best_n:
            best_n, best = int(inl.sum()), inl
    if best is None or best_n < len(sample) / 3:
        return None
    c0, n0, _ = fit_plane(sample[best])
    return c0, n0


def _on_support(g: SeamGeometry, support: tuple[FloatArray, FloatArray], *, tol_m: float = 0.004) -> bool:
    """A seam one of whose faces is the support plane (a plate edge standing on the table)."""
    c, n = support
    near = np.abs((g.points - c) @ n).max() < tol_m
    parallel = max(abs(float(g.normals_a.mean(axis=0) @ n)), abs(float(g.normals_b.mean(axis=0) @ n)))
    return bool(near and parallel > np.cos(np.radians(10.0)))


def _to_seams(geoms: list[SeamGeometry], params: DetectParams, frame_X: FloatArray | None) -> list[Seam]:
    """Sample paths, build torch poses, order deterministically and express in the output frame."""
    seams: list[Seam] = []
    for g in geoms:
        line = g.points
        seg = np.linalg.norm(np.diff(line, axis=0), axis=1)
        s_src = np.concatenate([[0.0], np.cumsum(seg)])
        pts, s_new = sample_uniform(line, params.torch.step_m)
        na = interpolate_rows(s_src, g.normals_a, s_new, unit=True)
        nb = interpolate_rows(s_src, g.normals_b, s_new, unit=True)
        poses = torch_poses(pts, na, nb, params=params.torch)
        conf = float(np.clip(min(1.0, g.support / 60.0) * np.exp(-g.rms_m / 0.001), 0.0, 1.0))
        seams.append(
            Seam(
                id=0,
                kind=g.kind,
                points=pts,
                poses=poses,
                length_m=float(s_new[-1]),
                confidence=conf,
                surfaces=(min(g.labels), max(g.labels)),
                joint=g.joint,
            )
        )
    frame: Literal["camera", "base"] = "camera"
    if frame_X is not None:
        seams = [s.transformed(frame_X, "base") for s in seams]
        frame = "base"
    seams = [_orient(s, frame) for s in seams]
    seams.sort(key=lambda s: (round(float(s.points.mean(axis=0)[0]), 3), round(float(s.points.mean(axis=0)[1]), 3)))
    return [replace(s, id=i) for i, s in enumerate(seams)]


def _orient(seam: Seam, frame: str) -> Seam:
    """Deterministic travel direction: vertical seams (in the base frame) upwards, others towards +x
    (then +y) of the output frame."""
    d = seam.points[-1] - seam.points[0]
    d = d / max(np.linalg.norm(d), 1e-12)
    if frame == "base" and abs(d[2]) > 0.7:
        flip = d[2] < 0
    elif abs(d[0]) >= 0.3:
        flip = d[0] < 0
    else:
        flip = d[1] < 0
    if not flip:
        return seam
    pts = seam.points[::-1].copy()
    poses = seam.poses[::-1].copy()
    poses[:, :3, 0] *= -1  # travel direction reverses: x -> -x, y -> -y keeps z and a right-handed frame
    poses[:, :3, 1] *= -1
    return replace(seam, points=pts, poses=poses)


@functools.cache
def _blas() -> ThreadpoolController:
    """The BLAS libraries this process has loaded, found once, after the modules a detection imports."""
    import perception.detect_surfaces  # noqa: F401  (it loads SciPy's BLAS beside NumPy's)

    return ThreadpoolController()


def detect(capture: Capture, params: DetectParams | None = None, *, segmenter: Segmenter | None = None,
           helper: HelperProcess | None = None) -> DetectionResult:  # fmt: skip
    """Detect every seam in ``capture``. Raises NoSeamFound (with the step that emptied it). ``helper``: a
    second process that takes a share of the surfaces method's fine stage (the same result, sooner).

    BLAS runs on one thread meanwhile: the detector's products are of 3 x N and 3 x 3 matrices, which a second
    BLAS thread barely shortens, while its threads wait spinning on the cores the helper works on (a median
    26 ms a capture less with one, paired on 42 dev and ribs captures with the helper)."""
    with _blas().limit(limits=1, user_api="blas"):
        return _detect(capture, params, segmenter=segmenter, helper=helper)


def _detect(capture: Capture, params: DetectParams | None, *, segmenter: Segmenter | None,
            helper: HelperProcess | None) -> DetectionResult:  # fmt: skip
    p = params or DetectParams()
    if p.method == "surfaces":
        from perception.detect_surfaces import detect_surfaces

        return detect_surfaces(capture, p, segmenter=segmenter, helper=helper)
    seg = segmenter or GraphSegmenter(p.segmenter)
    log = StepLog()
    t0 = time.perf_counter()
    with log.step("backproject"):
        organized = capture.points_camera()
    valid = np.isfinite(organized[..., 2])
    log.counts["raw"] = int(valid.sum())
    coarse = coarse_stage(capture, organized, p, seg, log)
    t_coarse = time.perf_counter() - t0
    with log.step("veil"):
        # flying ("veil") pixels at occlusion edges hang between foreground and background; they would
        # join surfaces that do not touch. Concave seams have no depth jump, so they lose nothing.
        f = 2 if organized.shape[1] >= 960 else 1  # half resolution is plenty to find depth jumps
        small = veil_mask(np.ascontiguousarray(organized[::f, ::f]), jump_m=p.veil_jump_m, dilate_px=1)
        H, W = valid.shape
        veil = np.repeat(np.repeat(small, f, axis=0), f, axis=1)[:H, :W] & valid
    log.counts["veil"] = int(veil.sum())
    with log.step("crop"):
        keep = valid & ~veil
        if p.crop:
            keep &= coarse.roi_mask
        pts = organized[keep].astype(np.float64)
        labels = coarse.masks.labels[keep]
    log.counts["cropped"] = len(pts)
    t1 = time.perf_counter()
    geoms = regions_to_seams(pts, labels, p, log, viewpoint=np.zeros(3), pairs=coarse.pairs)
    with log.step("butt"):
        band = valid & (coarse.roi_mask if p.crop else True)
        geoms += _butt_seams(
            organized, band, coarse.masks.labels, coarse.pairs, log.voxel_planes, p, viewpoint=np.zeros(3)
        )
    with log.step("support"):
        table = support_plane(organized, coarse.masks.labels)
        if table is not None:
            geoms = [g for g in geoms if not _on_support(g, table)]
    t_fine = time.perf_counter() - t1
    if not geoms:
        raise NoSeamFound(
            f"{log.counts.get('candidates', 0)} junction(s) between surfaces were examined but none is a concave "
            "seam or a narrow gap",
            artifacts={"masks": coarse.masks, "roi": coarse.roi_mask},
        )
    t2 = time.perf_counter()
    seams = _to_seams(geoms, p, capture.X_base_camera)
    t_path = time.perf_counter() - t2
    total = time.perf_counter() - t0
    timing = {"coarse": t_coarse, "fine": t_fine, "path": t_path, "total": total}
    timing.update({f"step_{k}": v for k, v in log.timing_s.items()})
    info: dict[str, Any] = {
        "prompts": coarse.prompts_px.round(1).tolist(),
        "prompts_source": coarse.prompts_source,
        "segmenter": getattr(seg, "name", type(seg).__name__),
        "method": p.method,
        "voxel_m": p.voxel_m,
        "crop": p.crop,
        "removed_share": round(1.0 - log.counts["cropped"] / max(log.counts["raw"], 1), 4),
        "counts": dict(log.counts),
    }
    counts = {
        "raw": log.counts["raw"],
        "cropped": log.counts["cropped"],
        "downsampled": log.counts.get("downsampled", 0),
    }
    return DetectionResult(
        frame="base" if capture.X_base_camera is not None else "camera",
        seams=tuple(seams),
        point_counts=counts,
        timing_s=timing,
        info=info,
        artifacts={"masks": coarse.masks, "roi": coarse.roi_mask},
    )


MAX_CLOUD_SPAN_M = MAX_PLAUSIBLE_DEPTH_M / 3.0  # its view stands twice its size off: within the depth limit


def detect_cloud(cloud: PointCloud, params: DetectParams | None = None, *, auto_voxel: bool = True) -> DetectionResult:
    """Fine stage only, on an unorganized cloud (PLY/PCD): no segmentation, no crop. With ``auto_voxel``
    a sparse cloud (a LiDAR scan) gets a voxel of 1.5 times its sample spacing when that is coarser than
    ``params.voxel_m``, so that every voxel holds a point or two."""
    p = params or DetectParams()
    finite = np.all(np.isfinite(np.asarray(cloud.points, dtype=np.float64)), axis=1)
    if not finite.all():  # an organized cloud's invalid pixels, NaN or inf: no point there
        cloud = cloud.subset(finite)
    if len(cloud.points) < 50:
        raise PerceptionError(f"{cloud.source}: only {len(cloud.points)} finite points")
    spacing = surface_spacing(cloud.points)
    stray = stray_points(cloud.points, spacing)
    if stray.any():  # a few points far off the part (a far return, flying pixels): not the workpiece
        cloud = cloud.subset(~stray)
    size = float(np.linalg.norm(np.ptp(cloud.points, axis=0)))
    if size > MAX_CLOUD_SPAN_M:
        raise BadCapture(f"the cloud spans {size:.1f} m across, more than a part in a welding cell: crop it to the "
                         "workpiece (a room or a cell scanned whole holds walls and floor), and give it in metres "
                         "(one in millimetres must be scaled by 0.001)", path=cloud.source)  # fmt: skip
    centred = cloud.points - cloud.points.mean(axis=0)
    var, axes = np.linalg.eigh(centred.T @ centred / len(centred))  # ascending
    if np.sqrt(max(float(var[1]), 0.0)) < max(spacing, 1e-4):
        length = float(np.ptp(centred @ axes[:, 2]))
        raise NoSeamFound(f"the cloud's points lie along a line {length * 1000:.0f} mm long (or at one point): "
                          "there is no surface to find a seam on")  # fmt: skip
    if p.method == "surfaces":  # its own viewpoint rule and range image: no voxel, no viewpoint guess here
        res = _detect_cloud_surfaces(cloud, p, spacing)
        return replace(res, info=res.info | {"stray_points": int(stray.sum())})
    if auto_voxel and AUTO_VOXEL_FACTOR * spacing > p.voxel_m:
        p = replace(p, voxel_m=min(AUTO_VOXEL_FACTOR * spacing, MAX_AUTO_VOXEL_M))
    log = StepLog()
    t0 = time.perf_counter()
    log.counts["raw"] = len(cloud.points)
    log.counts["cropped"] = len(cloud.points)
    # the viewpoint: clouds in a robot or world frame are not seen from their origin; use a point
    # above the cloud's centroid along the axis of least spread, on the side of most normals
    viewpoint = _guess_viewpoint(cloud.points, cloud.normals)
    if p.z_range_m == DetectParams().z_range_m:
        # the default working range is for camera-frame depth; a cloud may be in a robot frame
        p = replace(p, z_range_m=(-np.inf, np.inf))
    geoms = regions_to_seams(cloud.points, None, p, log, viewpoint=viewpoint, spacing_m=spacing)
    if not geoms:
        raise NoSeamFound(f"{log.counts.get('candidates', 0)} junction(s) examined, none is a concave seam")
    seams = _to_seams(geoms, p, None)
    total = time.perf_counter() - t0
    timing = {"coarse": 0.0, "fine": total, "total": total} | {f"step_{k}": v for k, v in log.timing_s.items()}
    return DetectionResult(
        frame="camera",
        seams=tuple(seams),
        point_counts={
            "raw": log.counts["raw"],
            "cropped": log.counts["cropped"],
            "downsampled": log.counts.get("downsampled", 0),
        },
        timing_s=timing,
        info={
            "method": p.method,
            "voxel_m": p.voxel_m,
            "spacing_m": round(spacing, 5),
            "viewpoint": viewpoint.round(4).tolist(),
            "counts": dict(log.counts),
            "stray_points": int(stray.sum()),
        },
    )


def _detect_cloud_surfaces(cloud: PointCloud, p: DetectParams, spacing: float) -> DetectionResult:
    """The surfaces-first stage on the cloud's range image seen from its sensor's side
    (:func:`perception.cloud_view.sensor_side`); seams in the cloud's frame."""
    from perception.cloud_view import sensor_side, view_cloud
    from perception.detect_surfaces import detect_surfaces

    viewpoint = sensor_side(cloud.points, cloud.normals, spacing_m=spacing)
    view = view_cloud(cloud.points, viewpoint)
    h, w = view.organized.shape[:2]
    cap = Capture(np.zeros((h, w, 3), np.uint8), view.organized[..., 2].copy(), view.intrinsics,
                  X_base_tool=view.X_cloud_camera, X_tool_camera=np.eye(4), source=cloud.source)  # fmt: skip
    # the virtual camera looks at the cloud's middle, not at a part: without prompts every surface counts
    p = replace(p, z_range_m=(0.0, np.inf), workspace_min_m=None, workspace_max_m=None, unprompted="all")
    try:
        res = detect_surfaces(cap, p, organized=view.organized)
        info = res.info | {"spacing_m": round(spacing, 5), "viewpoint": viewpoint.round(4).tolist(),
                           "view_px": [w, h]}  # fmt: skip
        if res.info.get("support"):
            res = _on_the_table(res, cloud.points)
    except NoSeamFound as err:
        err.artifacts["viewpoint"] = viewpoint.round(4).tolist()  # where the cloud was looked at from: a picture of
        raise  # why nothing was found shows it from there
    return replace(res, frame="camera", info=info)


PIECE_POINTS = 200_000  # a cloud's pieces are found on at most about this many of its points
PIECE_NEIGHBOURS = 16  # ... each joined to its 16 nearest


def _on_the_table(res: DetectionResult, points: FloatArray) -> DetectionResult:
    """The seams of a cloud with a table (a support was found) that lie on the table's piece of it: the table
    and everything standing on it are one piece, its points joined to their nearest (:data:`PIECE_NEIGHBOURS`,
    :func:`perception.fits.neighbour_components`, so a LiDAR's scan lines far apart on a steep face
    still join); a piece clear of it (a clamp's handle over the part, a stray cluster) is not the workpiece.
    NoSeamFound when no seam is left."""
    from perception.cloud import kdtree
    from perception.fits import neighbour_components

    # a dense cloud is judged on every k-th point (memory and time stay those of PIECE_POINTS points)
    points = points[:: max(1, int(np.ceil(len(points) / PIECE_POINTS)))]
    tree = kdtree(points)
    piece = neighbour_components(points, PIECE_NEIGHBOURS, tree=tree)
    table = int(np.argmax(np.bincount(piece)))  # the largest piece: the table and all that stands on it
    kept = tuple(s for s in res.seams if np.bincount(piece[tree.query(np.asarray(s.points))[1]]).argmax() == table)
    if not kept:
        raise NoSeamFound(f"{len(res.seams)} seam(s) found, none on the table's piece of the cloud: each lies on a "
                          "piece clear of the table and what stands on it")  # fmt: skip
    return replace(res, seams=tuple(replace(s, id=i) for i, s in enumerate(kept)))


def _guess_viewpoint(points: FloatArray, normals: FloatArray | None = None) -> FloatArray:
    c = points.mean(axis=0)
    extent = max(float(np.ptp(points, axis=0).max()), 0.3)
    if normals is not None:
        # the file's normals face the sensor that saw the surfaces: their mean points towards it
        mean = normals.mean(axis=0)
        if np.linalg.norm(mean) > 0.2:
            return np.asarray(c + mean / np.linalg.norm(mean) * extent)
    if np.linalg.norm(c) > 0.05 and c[2] > 0.05 and np.all(np.abs(c[:2]) < 0.6 * c[2]):
        # looks like a camera-frame cloud (in front of the origin): the camera is the viewpoint
        return np.zeros(3)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    up = vt[2]
    if up[2] < 0:
        up = -up  # robot/world frames: z up, the sensor looks down
    return np.asarray(c + up * extent)


# --------------------------------------------------------------------------------------------------
# The fine stage rebuilt on fitted surfaces (perception/fine/): the steps, in order
