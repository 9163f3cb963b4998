"""The seam-detection benchmark: the paper's Table I and Table II and a voxel-size sweep, measured on the
simulator's scenes with exact ground truth, for the refined method and the plain paper method.
It lives in ``cell`` because it drives the simulator (perception must not import sim_fakes).

Times are compute times of ``detect`` (capture already in memory), median over repeats.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from perception.capture import Capture
from perception.detect import DetectParams, detect
from perception.errors import NoSeamFound
from perception.evaluate import evaluate_seams, joint_names
from perception.helper_process import HelperProcess
from perception.transforms import invert_X, transform_points

NOISE_LEVELS = ("stereo", "structured")
SWEEP_VOXELS_MM = (1, 2, 3, 4, 5, 6, 7, 8, 9, 10)


@dataclass(frozen=True)
class RunResult:
    scene: str
    noise: str
    seed: int
    method: str
    crop: bool
    voxel_mm: float
    truth: int
    found: int
    false: int
    coverage: float
    rmse_mm: float
    max_mm: float
    p95_mm: float
    linear_rmse_mm: float
    linear_max_mm: float
    curved_rmse_mm: float
    time_s: float
    fine_s: float
    coarse_s: float
    points_raw: int
    points_cropped: int
    points_down: int
    error: str = ""
    named: int = 0  # found seams whose every matched detection names the truth's joint

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, v in self.__dict__.items():
            out[k] = None if isinstance(v, float) and not np.isfinite(v) else v
        return out


def _pool(errors: list[np.ndarray]) -> tuple[float, float]:
    if not errors:
        return float("nan"), float("nan")
    e = np.concatenate(errors)
    return float(np.sqrt(np.mean(e**2)) * 1000), float(e.max() * 1000)


def run_once(scene: str, noise: str, capture: Capture, params: DetectParams, repeats: int, seed: int = 0, *,
             helper: HelperProcess | None = None) -> RunResult:  # fmt: skip
    """``helper``: the detector's second process (timed as on the cell, where it is always running)."""
    from perception.evaluate import point_to_polyline_distance

    times, fines, coarses = [], [], []
    result = None
    error = ""
    for _ in range(repeats):
        t0 = time.perf_counter()
        try:
            result = detect(capture, params, helper=helper)
        except NoSeamFound as err:
            error = str(err)
            result = None
            break
        times.append(time.perf_counter() - t0)
        fines.append(result.timing_s.get("fine", 0.0))
        coarses.append(result.timing_s.get("coarse", 0.0))
    gt = capture.ground_truth or ()
    if result is None:
        return RunResult(scene, noise, seed, params.method, params.crop, params.voxel_m * 1000, len(gt), 0, 0, 0.0,
                         float("nan"), float("nan"), float("nan"), float("nan"), float("nan"), float("nan"),
                         float("nan"), float("nan"), float("nan"), 0, 0, 0, error)  # fmt: skip
    X = capture.X_base_camera
    pts = [s.points if X is None else transform_points(invert_X(X), s.points) for s in result.seams]
    rep = evaluate_seams(pts, gt)
    lin: list[np.ndarray] = []
    cur: list[np.ndarray] = []
    for score in rep.seams:
        for d in score.detected_ids:
            dist = point_to_polyline_distance(pts[d], gt[score.index].points_camera)
            (lin if score.kind == "linear" else cur).append(dist)
    lr, lm = _pool(lin)
    cr, _ = _pool(cur)
    found = [sc.found for sc in rep.seams]
    named, _ = joint_names(rep.seams, found, [g.joint for g in gt], [s.joint for s in result.seams])
    pc = result.point_counts
    return RunResult(
        scene, noise, seed, params.method, params.crop, params.voxel_m * 1000, rep.n_truth, rep.n_found,
        len(rep.false_seams), rep.coverage, rep.rmse_m * 1000, rep.max_m * 1000, rep.p95_m * 1000, lr, lm, cr,
        statistics.median(times), statistics.median(fines), statistics.median(coarses),
        pc.get("raw", 0), pc.get("cropped", 0), pc.get("downsampled", 0), named=named,
    )  # fmt: skip


@dataclass(frozen=True)
class BenchReport:
    table1: list[RunResult]  # every scene x noise x method, cropped
    table2: list[RunResult]  # every scene x noise, refined, crop vs no crop
    sweep: list[RunResult]  # voxel sizes x method on the sweep scenes (stereo)

    def to_json(self) -> dict[str, Any]:
        return {
            "table1": [r.to_json() for r in self.table1],
            "table2": [r.to_json() for r in self.table2],
            "voxel_sweep": [r.to_json() for r in self.sweep],
        }


def run_bench(
    scenes: Sequence[str],
    *,
    noises: Sequence[str] = NOISE_LEVELS,
    repeats: int = 3,
    seeds: Sequence[int] = (1,),
    sweep_scenes: Sequence[str] = ("ribs", "pipe_on_plate"),
    sweep_voxels_mm: Sequence[float] = SWEEP_VOXELS_MM,
    methods: Sequence[str] = ("surfaces", "refined", "paper"),
    progress: Callable[[str], None] | None = None,
) -> BenchReport:
    from sim_fakes.render import render
    from sim_fakes.scenes import get_scene

    say = progress or (lambda _m: None)
    # the surfaces method's helper process warms up while the scenes render (the other methods do not use one)
    helper = HelperProcess() if "surfaces" in methods else None
    t1, t2 = [], []
    try:
        captures: dict[tuple[str, str, int], Capture] = {}
        for s in scenes:
            for n in noises:
                for sd in seeds:
                    say(f"render {s} ({n}, seed {sd})")
                    captures[(s, n, sd)] = render(get_scene(s), noise=n, seed=sd).capture  # type: ignore[arg-type]
        base = DetectParams()
        if helper is not None:
            helper.wait_ready()  # its first capture is timed as the others
        for (s, n, sd), cap in captures.items():
            for method in methods:
                say(f"table I  {s} {n} seed {sd} {method}")
                p = replace(base, method=method)  # type: ignore[arg-type]
                t1.append(run_once(s, n, cap, p, repeats, sd, helper=helper))
            if sd == seeds[0] and "refined" in methods:  # the crop's effect is the voxel stage's (Table II)
                say(f"table II {s} {n} no crop")
                t2.append(next(r for r in t1 if (r.scene, r.noise, r.seed, r.method) == (s, n, sd, "refined")))
                t2.append(run_once(s, n, cap, replace(base, crop=False, method="refined"), max(1, repeats // 2), sd))
    finally:
        if helper is not None:
            helper.close()
    sw = []
    voxel_methods = [m for m in methods if m in ("refined", "paper")]  # the sweep is over the voxel size
    for s in sweep_scenes if voxel_methods else ():
        sd = seeds[0]
        cap = captures.get((s, "stereo", sd)) or render(get_scene(s), noise="stereo", seed=sd).capture
        for v in sweep_voxels_mm:
            for method in voxel_methods:
                say(f"sweep    {s} {v:g} mm {method}")
                sw.append(run_once(s, "stereo", cap, replace(base, voxel_m=v / 1000.0, method=method), 1, sd))  # type: ignore[arg-type]
    return BenchReport(t1, t2, sw)


def plot(report: BenchReport, path: str) -> None:
    """Three panels: RMSE per scene (refined vs paper), time with and without crop, the voxel sweep."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(17, 5))
    ax = axes[0]
    rows = [r for r in report.table1 if r.noise == "stereo"]
    scenes = list(dict.fromkeys(r.scene for r in rows))
    x = np.arange(len(scenes))
    for k, method in enumerate(("refined", "paper")):
        vals = [next((r.rmse_mm for r in rows if r.scene == s and r.method == method), np.nan) for s in scenes]
        ax.bar(x + (k - 0.5) * 0.38, vals, 0.38, label=method)
    ax.axhline(0.2, color="k", ls="--", lw=0.8, label="target 0.2 mm")
    ax.set_xticks(x, scenes, rotation=30, ha="right")
    ax.set_ylabel("RMSE (mm)")
    ax.set_title("Table I: RMSE per scene (stereo noise)")
    ax.legend()
    ax = axes[1]
    rows2 = [r for r in report.table2 if r.noise == "stereo"]
    for k, crop in enumerate((True, False)):
        vals = [next((r.fine_s for r in rows2 if r.scene == s and r.crop == crop), np.nan) for s in scenes]
        ax.bar(x + (k - 0.5) * 0.38, vals, 0.38, label="cropped" if crop else "no crop")
    ax.set_xticks(x, scenes, rotation=30, ha="right")
    ax.set_ylabel("fine-stage time (s)")
    ax.set_title("Table II: fine stage with and without the ROI crop")
    ax.legend()
    ax = axes[2]
    for s in dict.fromkeys(r.scene for r in report.sweep):
        for method, style in (("refined", "-o"), ("paper", "--s")):
            rr = [r for r in report.sweep if r.scene == s and r.method == method]
            ax.plot([r.voxel_mm for r in rr], [r.rmse_mm for r in rr], style, label=f"{s} {method}")
    ax.set_xlabel("voxel size (mm)")
    ax.set_ylabel("RMSE (mm)")
    ax.set_title("Voxel-size sweep (stereo noise)")
    if report.sweep:
        ax.legend(fontsize=8)
    else:  # --sweep '': an empty panel says so (a legend of nothing is a matplotlib warning on the user's screen)
        ax.text(0.5, 0.5, "no sweep run", ha="center", va="center", transform=ax.transAxes)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
