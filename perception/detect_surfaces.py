"""Seam detection surfaces first (``DetectParams(method="surfaces")``): the pipeline of :mod:`perception.fine`.

The coarse stage is geometric here: surfaces are segmented on every ``factor``-th pixel (a quarter of them
at 1280x720), and only bands around the candidate seams are read at full resolution (the share of points
left out is ``info["removed_share"]``). The image segmenter is not used (``segmenter`` is accepted for the same
signature as :func:`perception.detect.detect`); the table is told apart by geometry. The operator's prompts,
when given, say which surfaces are the workpiece (:mod:`perception.fine.workpiece`): clutter's folds are not
seams.

    noise -> surfaces -> support -> adjacency -> workpiece -> folds, gaps, grooves     (work resolution)
          -> wide folds (a swept LiDAR's captures only: perception.fine.wide_folds)
          -> refine -> inner gaps, steps -> merge -> groove trace -> view clip -> corners  (full resolution)
          -> the wide folds in place of the seams along them

Each step is timed and counted in the result's ``timing_s`` (``step_<name>``) and ``info["counts"]``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from perception.capture import CameraIntrinsics, Capture
from perception.detect import DetectParams, StepLog, _to_seams
from perception.errors import NoSeamFound
from perception.fine.types import NoiseModel, Pair, SeamCurve, SurfaceSet
from perception.fits import median
from perception.helper_process import HelperProcess
from perception.seamfit import SeamGeometry
from perception.seams import DetectionResult
from perception.segmentation import Segmenter

if TYPE_CHECKING:
    from perception.fine.gaps import Outline


def detect_surfaces(
    capture: Capture,
    params: DetectParams | None = None,
    *,
    segmenter: Segmenter | None = None,
    organized: NDArray[np.float32] | None = None,
    helper: HelperProcess | None = None,
) -> DetectionResult:
    """Every seam of ``capture`` from fitted surfaces and the joints between them; NoSeamFound (with the
    fitted surfaces as artifacts, for the overlay) when there is none. ``organized``: the (H, W, 3) points
    to use instead of the depth back-projected through the pixel centres (a cloud's range image,
    :mod:`perception.cloud_view`, keeps its points where they were measured). ``helper``: a second process
    for the fine stage's independent jobs (the result is the same without one)."""
    from perception.fine.wide_folds import in_place_of_along

    del segmenter  # same signature as detect(); the surfaces stage does not use the image segmenter yet
    p = params or DetectParams()
    log = StepLog()
    t0 = time.perf_counter()
    with log.step("backproject"):
        if organized is None:
            organized = capture.points_camera()
    log.counts["raw"] = int(np.isfinite(organized[..., 2]).sum())
    factor = max(1, round(organized.shape[1] / 640))
    with log.step("work_image"):
        work = _work_image(organized, factor, p)
    log.counts["work"] = int(np.isfinite(work[..., 2]).sum())
    curves, surf, noise, support, skip, pairs = _work_resolution_steps(work, factor, organized, capture, log,
                                                                       aim=p.unprompted == "aim",
                                                                       threads=1 if helper is None else 2)  # fmt: skip
    proposed = list(curves)  # the candidates before the refinement: they confirm a wide fold along them
    with log.step("wide_folds"):
        wide = _wide_folds(work, surf, noise, support, skip)
    log.counts["wide_folds"] = len(wide)
    t_coarse = time.perf_counter() - t0
    curves, used = _full_resolution_steps(curves, surf, noise, skip, pairs, work, organized, capture, log,
                                          on_support=bool(support), helper=helper)  # fmt: skip
    curves = in_place_of_along(curves, wide, noise, points=work, proposed=proposed)
    t_fine = time.perf_counter() - t0 - t_coarse
    if not curves:
        raise NoSeamFound(
            f"{len(surf.surfaces)} surface(s) fitted and {len(pairs)} adjacent pair(s) examined; none meets another "
            "in a concave fold or across a narrow gap",
            artifacts={"surfaces": surf},
        )
    geoms = [
        SeamGeometry(c.kind, c.joint, c.points, c.normals_a, c.normals_b, c.surfaces, c.surfaces, c.support, c.rms_m)
        for c in curves
    ]
    t2 = time.perf_counter()
    seams = _to_seams(geoms, p, capture.X_base_camera)
    timing = {"coarse": t_coarse, "fine": t_fine, "path": time.perf_counter() - t2, "total": time.perf_counter() - t0}
    timing.update({f"step_{k}": v for k, v in log.timing_s.items()})
    info: dict[str, Any] = {
        "method": "surfaces",
        "noise_sigma_1m_m": round(noise.sigma_1m_m, 7),
        "work_factor": factor,
        "support": sorted(support),
        "removed_share": round(1.0 - used / max(log.counts["raw"], 1), 4),
        "counts": dict(log.counts),
    }
    return DetectionResult(
        frame="base" if capture.X_base_camera is not None else "camera",
        seams=tuple(seams),
        point_counts={"raw": log.counts["raw"], "cropped": used, "downsampled": log.counts["work"]},
        timing_s=timing,
        info=info,
        artifacts={"surfaces": surf},
    )


def _work_image(organized: NDArray[np.float32], factor: int, p: DetectParams) -> NDArray[np.float64]:
    """Every ``factor``-th pixel, with points outside the workspace box or the range window made invalid."""
    work = np.ascontiguousarray(organized[::factor, ::factor]).astype(np.float64)
    if p.workspace_min_m is not None and p.workspace_max_m is not None:
        inside = np.all((work >= np.asarray(p.workspace_min_m)) & (work <= np.asarray(p.workspace_max_m)), axis=-1)
        work[~inside] = np.nan
    zr = work[..., 2]
    with np.errstate(invalid="ignore"):
        work[(zr < p.z_range_m[0]) | (zr > p.z_range_m[1])] = np.nan
    return work


def _work_resolution_steps(
    work: NDArray[np.float64],
    factor: int,
    organized: NDArray[np.float32],
    capture: Capture,
    log: StepLog,
    *,
    aim: bool = True,
    threads: int = 1,
) -> tuple[list[SeamCurve], SurfaceSet, NoiseModel, frozenset[int], frozenset[int], tuple[Pair, ...]]:
    """Noise, surfaces, support, adjacency, the workpiece and the candidate seams (folds, gaps, grooves); with
    the support and the surfaces that are never a seam's face (the support, and those off the workpiece).
    ``aim``: without prompts, the part the camera is aimed at is the workpiece (else every surface).
    ``threads``: how many threads the local planes may take (2 when a helper process holds the second core
    for the fine stage, idle until then)."""
    from perception.fine.adjacency import adjacent_pairs
    from perception.fine.folds import fold_seams
    from perception.fine.gaps import gap_seams
    from perception.fine.grooves import groove_seams
    from perception.fine.noise import estimate_noise, local_planes
    from perception.fine.support import find_support, on_table
    from perception.fine.surfaces import segment_surfaces
    from perception.fine.workpiece import prompted_labels, workpiece_labels

    with log.step("noise"):
        planes = local_planes(work, window_px=7, threads=threads)
        noise = estimate_noise(work, planes)
    with log.step("surfaces"):
        surf = segment_surfaces(work, planes, noise, factor=factor)
    log.counts["surfaces"] = len(surf.surfaces)
    with log.step("support"):
        # of the planes that could be the table, one the operator did not click (the faces of an inside corner
        # seen from in front each have every point on their camera side, and the largest is often a wall)
        prompted = prompted_labels(capture.prompts_px, surf)
        support = find_support(work, surf, noise, prompted=prompted)
        # and the surfaces that lie on the table where the sensor bent it or fitted a strip of it at a tilt (the
        # wide planes, fitted on the points off the support's own pieces, leave out the table seen again
        # themselves: perception.fine.wide_folds)
        table = support | on_table(work, surf, noise, support, prompted=prompted)
    with log.step("adjacency"):
        pairs = adjacent_pairs(surf, noise)
    log.counts["pairs"] = len(pairs)
    with log.step("workpiece"):
        workpiece = workpiece_labels(work, surf, pairs, noise, prompted=prompted, support=table, aim=aim)
        # never a seam's face: the table, and with prompts every surface not joined to a prompted one (the
        # workpiece never holds a support surface: it is neither started from nor reached through)
        skip = table if workpiece is None else frozenset(range(len(surf.surfaces))) - workpiece
    log.counts["workpiece"] = len(surf.surfaces) if workpiece is None else len(workpiece)
    with log.step("folds"):
        curves = [c for c in fold_seams(work, surf, pairs, noise, support=table) if not set(c.surfaces) & skip]
    with log.step("gaps"):
        curves += gap_seams(work, surf, pairs, noise, support=skip)
    with log.step("grooves"):
        grooves, surf = groove_seams(work, surf, noise, organized, capture.intrinsics, _full(noise, factor),
                                     support=skip)  # fmt: skip
        # a groove whose bevels were segmented is already a fold between them
        curves += [g for g in grooves if not _duplicates(g, curves, within_m=0.004)]
    log.counts["candidates"] = len(curves)
    return curves, surf, noise, support, skip, pairs


@dataclass(frozen=True)
class _FineJobs:
    """What the fine stage's independent jobs read besides the full-resolution arrays (:func:`_fine_job`): job
    k < len(seams) refines seam k, job len(seams) + j searches outline j for inner gaps."""

    seams: tuple[SeamCurve, ...]
    outlines: tuple[Outline, ...]
    intrinsics: CameraIntrinsics
    surfaces: SurfaceSet
    noise_full: NoiseModel


def _fine_job(jobs: _FineJobs, arrays: dict[str, NDArray[Any]], job: int) -> tuple[list[SeamCurve], NDArray[np.intp]]:
    """One of the fine stage's independent jobs (in this process or the helper's): the refined pieces of a seam
    and the flat indices of the full-resolution pixels it read, or the inner gaps of an outline (none read: the
    crop is the seams' bands). ``arrays``: the organized cloud ("full"), the colour image ("color", when the
    capture has one), and the colour image's dark-line response once an outline has needed it ("dark")."""
    from perception.fine.gaps import outline_gap_seams
    from perception.fine.refine import RefineParams, refine_one

    full = arrays["full"]
    if job >= len(jobs.seams):
        dark = [arrays["dark"]] if "dark" in arrays else []
        outline = jobs.outlines[job - len(jobs.seams)]
        found = outline_gap_seams(full, jobs.intrinsics, jobs.surfaces, jobs.noise_full, outline,
                                  color_rgb=arrays.get("color"), dark=dark)  # fmt: skip
        if dark and "dark" not in arrays:
            arrays["dark"] = dark[0]  # for this capture's other outlines in this process
        return found, np.zeros(0, dtype=np.intp)
    read = np.zeros(full.shape[:2], dtype=bool)
    pieces = refine_one(jobs.seams[job], full, jobs.intrinsics, jobs.surfaces, jobs.noise_full, RefineParams(), read)
    return pieces, np.flatnonzero(read)


def _full_resolution_steps(
    curves: list[SeamCurve],
    surf: SurfaceSet,
    noise: NoiseModel,
    skip: frozenset[int],
    pairs: tuple[Pair, ...],
    work: NDArray[np.float64],
    organized: NDArray[np.float32],
    capture: Capture,
    log: StepLog,
    *,
    on_support: bool = True,
    helper: HelperProcess | None = None,
) -> tuple[list[SeamCurve], int]:
    """Refinement on the full-resolution points near each seam, the narrow gaps and steps only full
    resolution shows, and the view clip; with how many full-resolution points were read. ``on_support``:
    whether the parts stand on a support (else the refined folds are named by how their faces turn alone).
    ``helper``: a second process that takes a share of the seams' refinements and the inner-gap search."""
    from perception.fine.corners import join_corners
    from perception.fine.gaps import gap_outlines, over_groove
    from perception.fine.merge import merge_collinear
    from perception.fine.steps import step_seams
    from perception.fine.trace import beside_groove, shallow_as_grooves, trace_grooves
    from perception.fine.visibility import clip_to_view

    noise_full = _full(noise, surf.factor)
    # the crop: the full-resolution pixels the fine steps read in bands around the seams (the candidate
    # searches, like the paper's segmenter, look at the whole image: the surfaces at the work resolution,
    # the inner gaps at each plate's depth; merge's checks lie on refined seams' lines, inside their bands)
    read = np.zeros(organized.shape[:2], dtype=bool)
    # the inner gaps read neither the refined seams (only which pairs a butt seam parts already, and the
    # refinement leaves butt seams as they are) nor the crop: each seam's refinement and each plane outline's
    # search for inner gaps is a job of its own, shared with the helper process when there is one
    outlines = gap_outlines(surf, noise_full, support=skip, pairs=pairs, found=[c for c in curves if c.joint == "butt"])
    jobs = _FineJobs(tuple(curves), tuple(outlines), capture.intrinsics, surf, noise_full)
    arrays = {"full": organized} | ({"color": capture.color_rgb} if capture.color_rgb is not None else {})
    with log.step("refine"):  # with the inner gaps
        todo = list(range(len(curves) + len(outlines)))
        done = helper.run(_fine_job, jobs, arrays, todo) if helper is not None else [_fine_job(jobs, arrays, k)
                                                                                     for k in todo]  # fmt: skip
        curves = []
        for pieces, px in done[: len(jobs.seams)]:
            curves += pieces
            read.reshape(-1)[px] = True
        if not on_support:
            curves = shallow_as_grooves(curves)
    for gaps, _ in done[len(jobs.seams) :]:
        curves += gaps
    with log.step("steps"):
        steps = step_seams(work, surf, pairs, noise, organized, capture.intrinsics, noise_full, support=skip,
                           read=read)  # fmt: skip
        # a step places the lap's edge from both plates and the edge face's own points; a fold on the narrow
        # edge face, fitted on a few pixels, is the weaker estimate of the same seam. A thick plate's edge face
        # (a pad's, over 14 mm) is a surface of its own: its fold is the better one
        laps = [c for c in steps if c.joint == "lap"]
        curves = [c for c in curves if not _duplicates(c, laps)] + laps
        curves += [c for c in steps if c.joint != "lap" and not _duplicates(c, curves)]
    with log.step("merge"):
        curves = merge_collinear(curves, organized, capture.intrinsics, noise_full)
    with log.step("trace"):
        curves = trace_grooves(curves, organized, capture.intrinsics, noise_full, read=read)
    with log.step("view"):
        curves = clip_to_view(curves, surf, noise)
        # a V-groove's opening between its plates' tops is not a butt gap beside it, nor a bevel's edge along it
        # a fold or a step: the root is the seam. Only a groove that is seen counts (a butt gap's own walls can
        # pass for a groove the camera cannot see into)
        grooves = [c for c in curves if c.joint == "v_groove"]
        curves = [c for c in curves if c.joint != "butt" or not over_groove(c, grooves)]
        curves = [c for c in curves if c.joint in ("v_groove", "butt") or not beside_groove(c, grooves)]
    with log.step("corners"):
        curves = join_corners(curves, noise_full)
    used = int(read.sum())
    log.counts["cropped"] = used
    return curves, used


def _full(noise: NoiseModel, factor: int) -> NoiseModel:
    """The noise model at full resolution: the same depth noise, ``factor`` times finer sample spacing."""
    return replace(noise, pixel_angle_rad=noise.pixel_angle_rad / factor)


def _wide_folds(work: NDArray[np.float64], surf: SurfaceSet, noise: NoiseModel, support: frozenset[int],
                skip: frozenset[int]) -> list[SeamCurve]:  # fmt: skip
    """The folds between wide planes (:mod:`perception.fine.wide_folds`; none unless the capture's structured
    error is at least its noise), less those whose faces are mostly surfaces that are never a seam's (``skip``:
    off the workpiece)."""
    from perception.fine.wide_folds import wide_fold_seams

    found = wide_fold_seams(work, surf, noise, support=support)
    return [c for c in found if not set(c.surfaces) & (skip - support)]


def _duplicates(seam: SeamCurve, others: list[SeamCurve], *, within_m: float = 0.002) -> bool:
    """Whether ``seam`` lies along one of ``others`` (median distance within ``within_m``)."""
    from perception.evaluate import point_to_polyline_distance

    probe = seam.points[0] + np.linspace(0.0, 1.0, 11)[:, None] * (seam.points[-1] - seam.points[0])
    return any(float(median(point_to_polyline_distance(probe, o.points))) < within_m for o in others)
