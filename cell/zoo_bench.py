"""``weldcell bench zoo``: detection measured on the randomized weldment zoo (:mod:`sim_fakes.zoo`).

Captures are rendered once and cached as ordinary capture folders (plus ``zoo.json`` with how they were
drawn and the per-seam truth the scorer needs); then each is detected and scored in a process pool.

Scoring (per capture, camera frame, the matching of :mod:`perception.evaluate`):
- a ground-truth seam is **found** when a detected seam is assigned to it (median distance <= 5 mm to its
  seen run, or to the weldment's whole seam for a detection that reaches the seen run: a seam detected past
  the 75-degree rule is not a miss) and the assigned seams cover at least half of its seen run (within
  3 mm); a seam found in pieces counts once and its pieces are counted in ``split_seams``; a seam seen in
  two runs and detected whole through the hidden stretch between them is found in both (its errors count once);
- a detected seam assigned to no ground-truth seam is **false**, unless it lies on a seam of the weldment
  that this shot does not count as seen (hidden, under 20 mm, or a face past 75 degrees): such a seam is
  **unseen**, neither found nor false (the visibility rules are thresholds, and a seam just past one of
  them is still a real seam);
- errors are the distances of every path point of every assigned seam to the weldment's seam (the whole
  fold of the solids, not only the part this shot sees): a point on the real seam beyond the seen run is
  not an error in position. How far seams run on beyond what the shot sees is reported as **overreach**
  (per capture, the longest stretch of a detected seam more than 3 mm from the seen run), and the errors
  against the seen runs alone are kept as ``rmse_seen_mm`` / ``max_seen_mm``;
- a capture **passes** when every seam is found, no seam is false, RMSE <= 0.3 mm and max <= 1 mm.
Times are the compute time of ``detect`` on the capture in memory.
"""

from __future__ import annotations

import json
import os
import statistics
import time
from collections.abc import Callable, Sequence
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cell.pools import ONE_THREAD_VARS, one_thread_children
from perception.helper_process import HelperProcess

ZOO_VERSION = 4  # bump when the generator or renderer changes what a (family, seed) draws
COVER_FOUND = 0.5
PASS_RMSE_MM = 0.3
PASS_MAX_MM = 1.0


def default_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "weldcell" / "zoo"


@dataclass
class CaptureScore:
    """One zoo capture, detected and scored. Millimetres and seconds (NaN where undefined)."""

    family: str
    seed: int
    sensor: str
    prompted: bool
    clutter: int
    camera_distance_m: float
    gt_seams: int
    found: int
    reported: int
    false_seams: int
    split_seams: int
    rmse_mm: float
    p95_mm: float
    max_mm: float
    time_s: float
    outcome: str  # "seams", "no_seam" (NoSeamFound) or "error" (anything else: a bug)
    reason: str = ""
    missed_joints: list[str] = field(default_factory=list)
    joint_named: int = 0  # found seams whose every assigned detection names the truth's joint
    misnamed_joints: list[str] = field(default_factory=list)  # the others: "fillet as v_groove"
    unseen_seams: int = 0  # detected on a seam of the weldment this shot does not count as seen
    overreach_mm: float = 0.0  # longest stretch of an assigned seam beyond (over 3 mm from) its seen run
    rmse_seen_mm: float = float("nan")  # the errors against the seen runs only
    max_seen_mm: float = float("nan")
    # per path point of every assigned seam: error (mm), range (m), incidence of the steeper face (rad)
    point_error_mm: list[float] = field(default_factory=list, repr=False)
    point_range_m: list[float] = field(default_factory=list, repr=False)
    point_incidence_rad: list[float] = field(default_factory=list, repr=False)

    @property
    def passed(self) -> bool:
        return (
            self.found == self.gt_seams
            and self.false_seams == 0
            and (self.gt_seams == 0 or (self.rmse_mm <= PASS_RMSE_MM and self.max_mm <= PASS_MAX_MM))
        )

    @property
    def name(self) -> str:
        return f"{self.family}-{self.seed}"

    def to_json(self, *, points: bool = False) -> dict[str, Any]:
        out = {k: v for k, v in asdict(self).items() if points or not k.startswith("point_")}
        out = {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in out.items()}
        out["passed"] = self.passed
        return out


# --------------------------------------------------------------------------------------------------
# Cache


def capture_dir(cache: Path, family: str, seed: int, sensor: str | None = None) -> Path:
    """Where (family, seed) is cached; rendered with ``sensor`` in place of the drawn one, beside the others."""
    return cache / (f"v{ZOO_VERSION}" if sensor is None else f"v{ZOO_VERSION}-{sensor}") / f"{family}-{seed}"


def ensure_capture(cache: Path, family: str, seed: int, sensor: str | None = None) -> Path:
    """Render (family, seed) into the cache unless it is there (with ``sensor`` in place of the drawn one,
    :func:`sim_fakes.zoo.draw_capture`); the folder is written atomically."""
    folder = capture_dir(cache, family, seed, sensor)
    if (folder / "zoo.json").is_file():
        return folder
    from perception.capture import save_capture
    from perception.transforms import invert_X, transform_points
    from sim_fakes.zoo import draw_capture

    z = draw_capture(family, seed, sensor=sensor)
    X_camera_world = invert_X(z.result.X_world_camera)
    tmp = folder.with_name(folder.name + f".tmp{os.getpid()}")
    save_capture(z.result.capture, tmp, depth_format="png")
    meta = {
        "zoo_version": ZOO_VERSION,
        "family": family,
        "seed": seed,
        "split": z.split,
        "sensor": z.sensor,
        "prompted": z.prompted,
        "clutter": z.clutter,
        "camera_distance_m": z.camera_distance_m,
        "elevation_rad": z.elevation_rad,
        "truth": [
            {
                "name": g.name,
                "joint": g.joint,
                "kind": g.kind,
                "points_camera": g.points_camera.tolist(),
                "normal_a_camera": g.normal_a_camera.tolist(),
                "normal_b_camera": g.normal_b_camera.tolist(),
                "seam_index": g.seam_index,
            }
            for g in z.result.ground_truth
        ],
        # every seam of the weldment, whole (what the seen runs are cut from), camera frame
        "seams": [
            {
                "name": sd.name,
                "joint": sd.joint,
                "kind": sd.kind,
                "points_camera": transform_points(X_camera_world, sd.points).tolist(),
            }
            for sd in z.result.scene.seams
        ],
    }
    (tmp / "zoo.json").write_text(json.dumps(meta))
    folder.parent.mkdir(parents=True, exist_ok=True)
    try:
        tmp.rename(folder)
    except OSError:  # another worker won the race: its copy is the same draw
        import shutil

        shutil.rmtree(tmp, ignore_errors=True)
    return folder


# --------------------------------------------------------------------------------------------------
# Detect and score one capture


def score_capture(folder: Path, *, keep_result: bool = False, method: str | None = None,
                  helper: HelperProcess | None = None) -> tuple[CaptureScore, Any]:  # fmt: skip
    """Detect the cached capture in ``folder`` and score it against its truth (``helper``: the detector's
    second process, for a run of one capture at a time)."""
    from perception.capture import load_capture
    from perception.detect import DetectParams, detect
    from perception.errors import NoSeamFound
    from perception.evaluate import MATCH_TOL_M, evaluate_seams, joint_names, point_to_polyline_distance
    from perception.transforms import invert_X, transform_points

    meta = json.loads((folder / "zoo.json").read_text())
    cap = load_capture(folder)
    gt = cap.ground_truth or ()
    base = dict(family=meta["family"], seed=meta["seed"], sensor=meta["sensor"], prompted=meta["prompted"],
                clutter=meta["clutter"], camera_distance_m=meta["camera_distance_m"], gt_seams=len(gt))  # fmt: skip
    t0 = time.perf_counter()
    try:
        params = DetectParams() if method is None else DetectParams(method=method)  # type: ignore[arg-type]
        result = detect(cap, params, helper=helper)
    except NoSeamFound as err:
        return _unscored(base, meta, time.perf_counter() - t0, "no_seam", str(err)), None
    except Exception as err:  # a bug: counted and shown, never hidden
        return _unscored(base, meta, time.perf_counter() - t0, "error", f"{type(err).__name__}: {err}"), None
    dt = time.perf_counter() - t0
    X = cap.X_base_camera
    pts = [s.points if X is None else transform_points(invert_X(X), s.points) for s in result.seams]
    whole = [np.asarray(w["points_camera"]) for w in meta["seams"]]
    rep = evaluate_seams(pts, gt, whole_camera=[whole[t["seam_index"]] for t in meta["truth"]])
    found = [s.found and s.coverage >= COVER_FOUND for s in rep.seams]
    m = _point_errors(rep.seams, meta["truth"], pts, whole)
    truth_joints = [t["joint"] for t in meta["truth"]]
    named, misnamed = joint_names(rep.seams, found, truth_joints, [s.joint for s in result.seams])

    # a seam assigned to no seen run but lying on a seam of the weldment is unseen, not false
    def on_weldment(d: int) -> bool:
        return any(float(np.median(point_to_polyline_distance(np.asarray(pts[d]), w))) <= MATCH_TOL_M for w in whole)

    unseen = [d for d in rep.false_seams if on_weldment(d)]
    e, es = m.errors_mm, m.errors_seen_mm
    nan = float("nan")
    score = CaptureScore(
        **base,
        found=int(sum(found)),
        reported=len(result.seams),
        false_seams=len(rep.false_seams) - len(unseen),
        split_seams=int(sum(max(0, len(s.detected_ids) - 1) for s in rep.seams)),
        rmse_mm=float(np.sqrt(np.mean(e**2))) if e.size else nan,
        p95_mm=float(np.percentile(e, 95)) if e.size else nan,
        max_mm=float(e.max()) if e.size else nan,
        time_s=dt,
        outcome="seams",
        missed_joints=[meta["truth"][s.index]["joint"] for s, f in zip(rep.seams, found, strict=True) if not f],
        joint_named=named,
        misnamed_joints=misnamed,
        unseen_seams=len(unseen),
        overreach_mm=round(1000.0 * m.overreach_m, 1),
        rmse_seen_mm=float(np.sqrt(np.mean(es**2))) if es.size else nan,
        max_seen_mm=float(es.max()) if es.size else nan,
        point_error_mm=[round(float(x), 4) for x in e],
        point_range_m=[round(float(x), 4) for x in m.ranges_m],
        point_incidence_rad=[round(float(x), 4) for x in m.incidence_rad],
    )
    return score, (result if keep_result else None)


def _unscored(base: dict[str, Any], meta: dict[str, Any], dt: float, outcome: str, reason: str) -> CaptureScore:
    """The score of a capture the detector gave no seams for: every seam missed, errors undefined."""
    nan = float("nan")
    return CaptureScore(**base, found=0, reported=0, false_seams=0, split_seams=0, rmse_mm=nan, p95_mm=nan,
                        max_mm=nan, time_s=dt, outcome=outcome, reason=reason,
                        missed_joints=[t["joint"] for t in meta["truth"]])  # fmt: skip


@dataclass(frozen=True)
class _PointErrors:
    """Per detected point of the assigned seams: the error to the weldment's whole seam and to its seen run (mm),
    the range (m) and the worse of the two faces' incidence angles (rad); the longest overreach (m)."""

    errors_mm: np.ndarray
    errors_seen_mm: np.ndarray
    ranges_m: np.ndarray
    incidence_rad: np.ndarray
    overreach_m: float


def _point_errors(seams: Any, truth: list[dict[str, Any]], pts: list[Any], whole: list[np.ndarray]) -> _PointErrors:
    """The point errors of every detected seam assigned to a seen run (``seams``: evaluate_seams' per-truth rows)."""
    from perception.evaluate import COVER_TOL_M, point_to_polyline_distance, resample_polyline

    errs: list[np.ndarray] = []
    errs_seen: list[np.ndarray] = []
    ranges: list[np.ndarray] = []
    incid: list[np.ndarray] = []
    overreach_m = 0.0
    runs: dict[int, list[int]] = {}  # each assigned detection's seen runs (two when it runs through a hidden stretch)
    for s in seams:
        for d in s.detected_ids:
            runs.setdefault(d, []).append(s.index)
    for d, idx in runs.items():
        t = truth[idx[0]]  # the runs of one detection are cut from one whole seam
        seen_runs = [np.asarray(truth[i]["points_camera"]) for i in idx]
        tp = np.vstack(seen_runs)
        na = np.vstack([np.asarray(truth[i]["normal_a_camera"]) for i in idx])
        nb = np.vstack([np.asarray(truth[i]["normal_b_camera"]) for i in idx])
        p = np.asarray(pts[d])
        errs.append(point_to_polyline_distance(p, whole[t["seam_index"]]) * 1000.0)
        errs_seen.append(np.min([point_to_polyline_distance(p, run) for run in seen_runs], axis=0) * 1000.0)
        dense = resample_polyline(p, 0.001)
        beyond = np.min([point_to_polyline_distance(dense, run) for run in seen_runs], axis=0) > COVER_TOL_M
        overreach_m = max(overreach_m, 0.001 * int(beyond.sum()))
        ranges.append(np.linalg.norm(p, axis=1))
        k = np.argmin(((p[:, None, :] - tp[None]) ** 2).sum(axis=2), axis=1)
        view = p / np.linalg.norm(p, axis=1, keepdims=True)
        cos = np.minimum(-(na[k] * view).sum(axis=1), -(nb[k] * view).sum(axis=1))
        incid.append(np.arccos(np.clip(cos, -1.0, 1.0)))

    def joined(parts: list[np.ndarray]) -> np.ndarray:
        return np.concatenate(parts) if parts else np.zeros(0)

    return _PointErrors(joined(errs), joined(errs_seen), joined(ranges), joined(incid), overreach_m)


def _work(args: tuple[str, str, int, str | None, str | None], helper: HelperProcess | None = None) -> CaptureScore:
    cache, family, seed, method, sensor = args
    folder = ensure_capture(Path(cache), family, seed, sensor)
    return score_capture(folder, method=method, helper=helper)[0]


def _init_worker() -> None:
    # each worker is one of N on N cores: no nested thread pools (for what reads the variables later)
    os.environ.update(dict.fromkeys(ONE_THREAD_VARS, "1"))


# --------------------------------------------------------------------------------------------------
# The run and its summary


@dataclass
class ZooReport:
    split: str
    scores: list[CaptureScore]
    wall_s: float

    def summary(self, scores: Sequence[CaptureScore]) -> dict[str, Any]:
        e = np.array([x for s in scores for x in s.point_error_mm])
        seen = [s for s in scores if np.isfinite(s.rmse_seen_mm)]
        n_seen = sum(len(s.point_error_mm) for s in seen)
        rmse_seen = np.sqrt(sum(s.rmse_seen_mm**2 * len(s.point_error_mm) for s in seen) / n_seen) if n_seen else np.nan
        times = sorted(s.time_s for s in scores)
        gt = sum(s.gt_seams for s in scores)
        found = sum(s.found for s in scores)
        reported = sum(s.reported for s in scores)
        false = sum(s.false_seams for s in scores)

        def r(x: float, nd: int = 3) -> float | None:
            return None if not np.isfinite(x) else round(float(x), nd)

        return {
            "captures": len(scores),
            "passed": sum(s.passed for s in scores),
            "gt_seams": gt,
            "found": found,
            "false_seams": false,
            "reported": reported,
            "split_seams": sum(s.split_seams for s in scores),
            "joint_named": sum(s.joint_named for s in scores),
            "unseen_seams": sum(s.unseen_seams for s in scores),
            "overreach_mm_p95": r(float(np.percentile([s.overreach_mm for s in scores], 95)) if scores else np.nan, 1),
            "rmse_seen_mm": r(float(rmse_seen)),
            "max_seen_mm": r(max((s.max_seen_mm for s in seen), default=float("nan"))),
            "no_seam": sum(s.outcome == "no_seam" for s in scores),
            "errors": sum(s.outcome == "error" for s in scores),
            "recall": r(found / gt if gt else float("nan"), 4),
            "false_rate": r(false / reported if reported else 0.0, 4),
            "rmse_mm": r(float(np.sqrt(np.mean(e**2))) if e.size else float("nan")),
            "p95_mm": r(float(np.percentile(e, 95)) if e.size else float("nan")),
            "max_mm": r(float(e.max()) if e.size else float("nan")),
            "time_s_median": r(statistics.median(times) if times else float("nan")),
            "time_s_p95": r(float(np.percentile(times, 95)) if times else float("nan")),
        }

    def to_json(self, *, captures: bool = False) -> dict[str, Any]:
        fams = list(dict.fromkeys(s.family for s in self.scores))
        out: dict[str, Any] = {
            "split": self.split,
            "captures": len(self.scores),
            "zoo_version": ZOO_VERSION,
            "families": {f: self.summary([s for s in self.scores if s.family == f]) for f in fams},
            "overall": self.summary(self.scores),
            "wall_s": round(self.wall_s, 1),
        }
        if captures:
            out["per_capture"] = [s.to_json() for s in self.scores]
        return out


def run_zoo(
    split: str,
    n: int,
    *,
    families: list[str] | None = None,
    jobs: int = 1,
    cache: Path | None = None,
    method: str | None = None,
    sensor: str | None = None,
    progress: Callable[[int, int, CaptureScore], None] | None = None,
) -> ZooReport:
    from sim_fakes.zoo import split_plan

    plan = split_plan(split, n, families)
    cache_dir = cache or default_cache_dir()
    cache_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    scores: list[CaptureScore] = []
    tasks = [(str(cache_dir), f, s, method, sensor) for f, s in plan]
    if jobs <= 1:
        # one capture at a time, as on the cell: the surfaces method's helper process takes the second core
        from perception.detect import DetectParams

        uses_helper = (method or DetectParams().method) == "surfaces"
        with HelperProcess() if uses_helper else nullcontext() as helper:
            if helper is not None:
                helper.wait_ready()  # started before the first capture is timed
            for k, t in enumerate(tasks):
                scores.append(_work(t, helper))
                if progress:
                    progress(k + 1, len(tasks), scores[-1])
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        ctx = mp.get_context("spawn")  # a clean interpreter per worker: no inherited open3d or thread state
        with one_thread_children(), ProcessPoolExecutor(max_workers=jobs, mp_context=ctx,
                                                        initializer=_init_worker) as pool:  # fmt: skip
            for k, score in enumerate(pool.map(_work, tasks, chunksize=1)):
                scores.append(score)
                if progress:
                    progress(k + 1, len(tasks), score)
    return ZooReport(split, scores, time.perf_counter() - t0)


def write_outputs(report: ZooReport, out: Path, cache: Path | None = None, method: str | None = None,
                  sensor: str | None = None) -> list[Path]:  # fmt: skip
    """bench.json, errors.png (error against range, noise and incidence) and a gallery of the worst 12
    (``sensor``: the one the report's captures were rendered with in place of the drawn ones)."""
    out.mkdir(parents=True, exist_ok=True)
    written = [out / "bench.json"]
    full = report.to_json(captures=True)
    (out / "bench.json").write_text(json.dumps(full, indent=1))
    written.append(_plot_errors(report, out / "errors.png"))
    written += _gallery(report, out / "gallery", cache or default_cache_dir(), method, sensor)
    return written


def _sensor_sigma_mm(sensor: str, range_m: np.ndarray) -> np.ndarray:
    """The sensor model's per-pixel depth noise at a range (normal incidence), mm."""
    from sim_fakes.zoo import SENSORS

    s = SENSORS.get(sensor)
    if s is None:  # structured light: 0.1 mm at 0.5 m, growing with range squared
        return 0.1 * (range_m / 0.5) ** 2
    fb = 920.0 * s.baseline_m
    return 1000.0 * range_m**2 / fb * float(np.hypot(s.sigma_px, s.sigma_corr_px))


def _plot_errors(report: ZooReport, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.6))
    for s in report.scores:
        if not s.point_error_mm:
            continue
        e = np.asarray(s.point_error_mm)
        rg = np.asarray(s.point_range_m)
        inc = np.degrees(np.asarray(s.point_incidence_rad))
        col = {"oakd": "tab:blue", "oakd_high": "tab:red", "structured": "tab:green"}.get(s.sensor, "k")
        axes[0].scatter(rg, e, s=2, c=col, alpha=0.3)
        axes[1].scatter(_sensor_sigma_mm(s.sensor, rg), e, s=2, c=col, alpha=0.3)
        axes[2].scatter(inc, e, s=2, c=col, alpha=0.3)
    labels = ("range (m)", "sensor depth noise at that range (mm)", "incidence of the steeper face (deg)")
    for ax, xl in zip(axes, labels, strict=True):
        ax.set_xlabel(xl)
        ax.set_ylabel("path point error (mm)")
        ax.axhline(PASS_MAX_MM, color="k", ls="--", lw=0.8)
        ax.set_yscale("log")
    axes[0].set_title(f"zoo {report.split}: blue OAK-D, red OAK-D high noise, green structured light")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _badness(s: CaptureScore) -> tuple[float, ...]:
    missed = s.gt_seams - s.found
    return (float(s.passed), -float(s.outcome == "error"), -float(missed + s.false_seams),
            -(s.max_mm if np.isfinite(s.max_mm) else 1e9))  # fmt: skip


def _gallery(report: ZooReport, folder: Path, cache: Path, method: str | None = None,
             sensor: str | None = None) -> list[Path]:  # fmt: skip
    """Overlays (detected seams red with torch axes, truth green) of the 12 worst captures."""
    import cv2

    from perception.capture import load_capture
    from perception.overlay import draw_overlay, write_png
    from perception.seams import DetectionResult

    folder.mkdir(parents=True, exist_ok=True)
    written = []
    worst = sorted(report.scores, key=_badness)[:12]
    for rank, s in enumerate(worst):
        src = capture_dir(cache, s.family, s.seed, sensor)
        score, result = score_capture(src, keep_result=True, method=method)
        cap = load_capture(src)
        img = draw_overlay(cap, result or DetectionResult("camera", ()), truth=True)
        text = (f"{s.name} {s.sensor}: {s.found}/{s.gt_seams} found, {s.false_seams} false, "
                f"max {s.max_mm:.2f} mm" if s.outcome == "seams" else f"{s.name} {s.sensor}: {s.outcome}: "
                f"{s.reason[:90]}")  # fmt: skip
        cv2.putText(img, text, (12, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 4, cv2.LINE_AA)
        cv2.putText(img, text, (12, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 1, cv2.LINE_AA)
        path = folder / f"{rank:02d}-{s.name}.png"
        write_png(str(path), img)
        written.append(path)
        del score
    return written
