"""Compare detected seams with ground truth.

Matching (documented in docs/evaluation.md):
1. Every path point of a detected seam is measured by its distance to the nearest point of each
   ground-truth centre line (point-to-polyline, exact for the segments of the polyline).
2. A detected seam is assigned to the ground-truth seam with the smallest *median* distance, when that
   median is within ``match_tol_m`` (5 mm). Otherwise it is a **false seam**. Where the truth is a seen run
   cut from a longer seam (``whole_camera``: what the shot counts as seen is a threshold), a detection that
   reaches the seen run (within ``cover_tol_m``) and lies on the whole seam (median within ``match_tol_m``)
   is assigned too, and its errors are measured to the whole seam: a seam found past the visibility rule
   is neither wrong nor false.
3. A ground-truth seam is **found** when at least one detected seam is assigned to it (a seam found in
   two pieces is found once; the pieces both count for coverage and error).
4. **Coverage** of a ground-truth seam: the share of its length (sampled every 1 mm) lying within
   ``cover_tol_m`` (3 mm) of an assigned detected path (its points joined by straight segments).
5. **Error** statistics (RMSE, 95th percentile, max) are over every path point of every assigned seam:
   its distance to the assigned ground-truth centre line. False seams are reported, not averaged in.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from perception.capture import GroundTruthSeam

FloatArray = NDArray[np.float64]

MATCH_TOL_M = 0.005
COVER_TOL_M = 0.003


def point_to_polyline_distance(p: FloatArray, polyline: FloatArray) -> FloatArray:
    """(N,) Euclidean distance from each of (N, 3) points to an (M, 3) polyline (M >= 1), metres."""
    pts = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    line = np.asarray(polyline, dtype=np.float64).reshape(-1, 3)
    if len(line) == 1:
        return np.asarray(np.linalg.norm(pts - line[0], axis=1))
    a = line[:-1]
    ab = line[1:] - a
    ab2 = np.maximum((ab * ab).sum(axis=1), 1e-30)
    out = np.full(len(pts), np.inf)
    chunk = max(1, 2_000_000 // max(len(a), 1))
    for s in range(0, len(pts), chunk):
        q = pts[s : s + chunk]
        t = np.clip(((q[:, None, :] - a[None]) * ab[None]).sum(axis=2) / ab2[None], 0.0, 1.0)
        closest = a[None] + t[..., None] * ab[None]
        out[s : s + chunk] = np.sqrt(((q[:, None, :] - closest) ** 2).sum(axis=2)).min(axis=1)
    return out


def resample_polyline(polyline: FloatArray, step_m: float) -> FloatArray:
    """Points every ``step_m`` along an (M, 3) polyline, both ends included."""
    line = np.asarray(polyline, dtype=np.float64).reshape(-1, 3)
    seg = np.linalg.norm(np.diff(line, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return line[:1].copy()
    n = max(2, int(np.ceil(s[-1] / step_m)) + 1)
    s_new = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(s_new, s, line[:, k]) for k in range(3)])


@dataclass(frozen=True)
class SeamScore:
    """Per ground-truth seam. Errors in metres (NaN when not found)."""

    index: int
    kind: str
    length_m: float
    found: bool
    detected_ids: tuple[int, ...]
    coverage: float
    rmse_m: float
    p95_m: float
    max_m: float
    n_points: int


@dataclass(frozen=True)
class EvaluationReport:
    n_truth: int
    n_detected: int
    n_found: int
    false_seams: tuple[int, ...]
    coverage: float  # length-weighted over all ground-truth seams
    rmse_m: float
    p95_m: float
    max_m: float
    n_points: int
    seams: tuple[SeamScore, ...] = field(default=())

    @property
    def all_found(self) -> bool:
        return self.n_found == self.n_truth

    def to_json(self) -> dict[str, object]:
        def mm(x: float) -> float | None:
            return None if not np.isfinite(x) else round(x * 1000.0, 4)

        return {
            "truth_seams": self.n_truth,
            "detected_seams": self.n_detected,
            "found": self.n_found,
            "false_seams": len(self.false_seams),
            "false_seam_ids": list(self.false_seams),
            "coverage": round(self.coverage, 4),
            "rmse_mm": mm(self.rmse_m),
            "p95_mm": mm(self.p95_m),
            "max_mm": mm(self.max_m),
            "path_points": self.n_points,
            "seams": [
                {
                    "truth_index": s.index,
                    "kind": s.kind,
                    "length_mm": round(s.length_m * 1000.0, 2),
                    "found": s.found,
                    "detected_ids": list(s.detected_ids),
                    "coverage": round(s.coverage, 4),
                    "rmse_mm": mm(s.rmse_m),
                    "p95_mm": mm(s.p95_m),
                    "max_mm": mm(s.max_m),
                }
                for s in self.seams
            ],
        }


def _stats(err: FloatArray) -> tuple[float, float, float]:
    if err.size == 0:
        return (float("nan"),) * 3
    return float(np.sqrt(np.mean(err**2))), float(np.percentile(err, 95)), float(err.max())


def _match(pts: FloatArray, truth: tuple[GroundTruthSeam, ...] | list[GroundTruthSeam],
           whole_camera: list[FloatArray] | None, match_tol_m: float,
           cover_tol_m: float) -> tuple[list[int], FloatArray] | None:  # fmt: skip
    """The ground-truth seams one detection (``pts``) is matched to, the nearest in median first, and its
    point errors (to that seam's whole seam when given); None when it matches none."""
    if len(truth) == 0 or len(pts) == 0:
        return None
    dists = [point_to_polyline_distance(pts, g.points_camera) for g in truth]
    med = [float(np.median(x)) for x in dists]
    if whole_camera is None:
        to_whole = dists
    else:
        to_whole = [point_to_polyline_distance(pts, np.asarray(w, dtype=np.float64)) for w in whole_camera]
    ok = [
        med[i] <= match_tol_m
        or (whole_camera is not None and float(np.median(to_whole[i])) <= match_tol_m and dists[i].min() <= cover_tol_m)
        for i in range(len(truth))
    ]
    if not any(ok):
        return None
    best = min((i for i in range(len(truth)) if ok[i]), key=lambda i: med[i])
    # a seam seen in two runs (something in front of its middle) and detected whole, through the hidden
    # stretch, is found in both: each run it reaches is cut from the same whole seam
    also = [] if whole_camera is None else [
        i for i in range(len(truth)) if i != best and ok[i] and np.array_equal(whole_camera[i], whole_camera[best])
    ]  # fmt: skip
    return [best, *also], to_whole[best]


def joint_names(seams: Sequence[SeamScore], found: Sequence[bool], truth_joints: Sequence[str | None],
                joints: Sequence[str | None]) -> tuple[int, list[str]]:  # fmt: skip
    """Of the ground-truth seams ``seams`` (:func:`evaluate_seams`' per-truth rows) that are ``found``, how many
    every detection assigned to them names as the truth's joint (``truth_joints`` per truth seam, ``joints``
    per detection), and the others ("fillet as v_groove"; "+" between the names of several pieces)."""
    named, misnamed = 0, []
    for s, f in zip(seams, found, strict=True):
        if not f:
            continue
        want = str(truth_joints[s.index])
        got = sorted({str(joints[d]) for d in s.detected_ids})
        if got == [want]:
            named += 1
        else:
            misnamed.append(f"{want} as {'+'.join(got)}")
    return named, misnamed


def evaluate_seams(
    detected_camera: list[FloatArray],
    truth: tuple[GroundTruthSeam, ...] | list[GroundTruthSeam],
    *,
    match_tol_m: float = MATCH_TOL_M,
    cover_tol_m: float = COVER_TOL_M,
    whole_camera: list[FloatArray] | None = None,
) -> EvaluationReport:
    """Score detected seam paths (each (N, 3), camera frame, metres) against the ground truth.

    ``whole_camera``, when given, holds for each ground-truth seam the whole seam its seen run was cut from."""
    n_gt = len(truth)
    if whole_camera is not None and len(whole_camera) != n_gt:
        raise ValueError(f"whole_camera has {len(whole_camera)} seams for {n_gt} ground-truth seams")
    assigned: list[list[int]] = [[] for _ in range(n_gt)]
    primary: dict[int, int] = {}  # the ground-truth seam each matched detection's errors are counted with
    errors: dict[int, FloatArray] = {}
    false_ids: list[int] = []
    for d, pts in enumerate(detected_camera):
        match = _match(np.asarray(pts, dtype=np.float64).reshape(-1, 3), truth, whole_camera, match_tol_m, cover_tol_m)
        if match is None:
            false_ids.append(d)
            continue
        runs, errors[d] = match
        primary[d] = runs[0]
        for i in runs:
            assigned[i].append(d)
    scores = []
    all_err: list[FloatArray] = []
    covered_len = 0.0
    total_len = 0.0
    for i, g in enumerate(truth):
        samples = resample_polyline(g.points_camera, 0.001)
        covered = np.zeros(len(samples), bool)
        for d in assigned[i]:
            det = np.asarray(detected_camera[d], dtype=np.float64).reshape(-1, 3)
            covered |= point_to_polyline_distance(samples, det) <= cover_tol_m
        cov = float(covered.mean()) if len(samples) else 0.0
        mine = [d for d in assigned[i] if primary[d] == i]
        err = np.concatenate([errors[d] for d in mine]) if mine else np.zeros(0)
        all_err.append(err)
        rmse, p95, mx = _stats(err)
        length = g.length_m
        covered_len += cov * length
        total_len += length
        scores.append(
            SeamScore(i, g.kind, length, bool(assigned[i]), tuple(assigned[i]), cov, rmse, p95, mx, int(err.size))
        )
    err_all = np.concatenate(all_err) if all_err else np.zeros(0)
    rmse, p95, mx = _stats(err_all)
    return EvaluationReport(
        n_truth=n_gt,
        n_detected=len(detected_camera),
        n_found=sum(1 for s in scores if s.found),
        false_seams=tuple(false_ids),
        coverage=covered_len / total_len if total_len > 0 else 0.0,
        rmse_m=rmse,
        p95_m=p95,
        max_m=mx,
        n_points=int(err_all.size),
        seams=tuple(scores),
    )
