"""``weldcell detect CAPTURE... --out-dir DIR [--jobs N | --ray ADDRESS]``: many captures, imports paid once per worker.

A worker process imports the detector once and then takes capture after capture (a separate ``weldcell detect`` per
capture pays about a second of imports each time). Each worker returns the seams.json document; this process
writes ``DIR/<capture name>.seams.json`` and ``DIR/batch.json`` (one entry per capture: seams found, time, or
the reason it failed). With ``--ray`` the same function runs as Ray tasks (one CPU each); the captures must then
be readable at the same path on every node, and the results still come back here.

Exit code: 0 when every capture gave seams; otherwise 1 (any failure), or 3 when the only failures are captures
without a seam, with a one-line reason on stderr.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from cell.errors import ConfigError

RAY_HINT = "--ray needs Ray, an optional extra: pip install 'weldcell[ray]' (or pip install 'ray>=2.30,<3')"


@dataclass(frozen=True)
class Task:
    """One capture to detect: ``source`` (a folder or a cloud file) and the settings of the whole batch."""

    source: str
    params: Any  # perception.detect.DetectParams
    segmenter: str
    model: str | None
    auto_voxel: bool


_SEGMENTERS: dict[tuple[str, str | None], Any] = {}  # per worker process: a FastSAM model is loaded once


def detect_task(task: Task) -> dict[str, Any]:
    """Detect one capture; {"source", "ok", "seams", "time_s", "doc"} or {"source", "ok": False, "exit", "error"}.
    Never raises for a bad capture: one bad folder does not stop a batch."""
    from cell.cli import exit_code_for
    from perception.errors import WeldcellError

    t0 = time.perf_counter()
    try:
        doc = _detect_doc(task)
    except WeldcellError as err:
        return {"source": task.source, "ok": False, "exit": exit_code_for(err), "error": str(err)}
    except Exception as err:
        return {"source": task.source, "ok": False, "exit": 1, "error": f"{type(err).__name__}: {err}"}
    return {
        "source": task.source,
        "ok": True,
        "seams": len(doc["seams"]),
        "time_s": round(time.perf_counter() - t0, 4),
        "doc": doc,
    }


def _detect_doc(task: Task) -> dict[str, Any]:
    from perception.capture import load_capture, read_point_cloud
    from perception.detect import detect, detect_cloud
    from perception.seams import seams_to_json

    src = Path(task.source)
    if src.is_file() or src.suffix.lower() in (".ply", ".pcd", ".npy"):
        cloud = read_point_cloud(src)
        result = detect_cloud(cloud, replace(task.params, crop=False), auto_voxel=task.auto_voxel)
    else:
        key = (task.segmenter, task.model)
        if key not in _SEGMENTERS:
            from cell.commands.detect import make_segmenter

            _SEGMENTERS[key] = make_segmenter(argparse.Namespace(segmenter=task.segmenter, model=task.model))
        result = detect(load_capture(src), task.params, segmenter=_SEGMENTERS[key])
    return seams_to_json(result)


def _warm_up() -> None:
    # the imports a separate `weldcell detect` pays every time: once per worker here
    import perception.capture
    import perception.detect
    import perception.seams  # noqa: F401


def output_names(sources: list[str]) -> list[str]:
    """``<name>.seams.json`` per source (folder name, or file stem), made unique with ``-2``, ``-3``..."""
    names: list[str] = []
    seen: dict[str, int] = {}
    for s in sources:
        p = Path(s.rstrip("/\\"))
        base = p.stem if p.suffix.lower() in (".ply", ".pcd", ".npy") else p.name
        base = base or "capture"
        seen[base] = seen.get(base, 0) + 1
        names.append(f"{base}.seams.json" if seen[base] == 1 else f"{base}-{seen[base]}.seams.json")
    return names


def run_batch(args: argparse.Namespace) -> int:
    from cell.commands.detect import build_params
    from perception.errors import BadCapture
    from perception.seams_schema import FORMAT_VERSION

    if not args.out_dir:
        raise BadCapture("several captures need --out-dir DIR (one seams.json per capture goes there)")
    for flag in ("out", "overlay", "ply"):
        if getattr(args, flag):
            raise BadCapture(f"--{flag} is for a single capture; a batch writes DIR/<capture>.seams.json")
    if args.jobs is not None and not 1 <= args.jobs <= 256:
        raise BadCapture(f"--jobs must be between 1 and 256, got {args.jobs}")
    if args.ray and args.jobs is not None:
        raise BadCapture("--jobs is for the local process pool; with --ray the cluster's CPUs set the parallelism")
    if args.segmenter == "fastsam" and not args.model:
        raise BadCapture("--segmenter fastsam needs --model FILE (a FastSAM ONNX export; see docs/fastsam.md)")
    params = build_params(args)
    tasks = [Task(str(c), params, args.segmenter, args.model, args.voxel_mm is None) for c in args.capture]
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    names = output_names([t.source for t in tasks])

    t0 = time.perf_counter()
    if args.ray:
        results, workers = _run_ray(tasks, args.ray), "ray"
    else:
        jobs = args.jobs or os.cpu_count() or 1
        results, workers = _run_pool(tasks, min(jobs, len(tasks))), f"{min(jobs, len(tasks))} process(es)"
    wall_s = time.perf_counter() - t0

    entries = []
    for name, res in zip(names, results, strict=True):
        entry = {k: v for k, v in res.items() if k != "doc"}
        if res["ok"]:
            (out_dir / name).write_text(json.dumps(res["doc"], indent=1), encoding="utf-8")
            entry["out"] = str(out_dir / name)
        entries.append(entry)
    failed = [e for e in entries if not e["ok"]]
    summary = {
        "seams_format_version": FORMAT_VERSION,
        "captures": len(entries),
        "failed": len(failed),
        "workers": workers,
        "wall_s": round(wall_s, 3),
        "results": entries,
    }
    (out_dir / "batch.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        _print_summary(entries, wall_s=wall_s, workers=workers, out_dir=out_dir)
    if not failed:
        return 0
    first = failed[0]
    print(
        f"weldcell detect: {len(failed)} of {len(entries)} capture(s) failed (first: {first['error']}); "
        f"see {out_dir / 'batch.json'}",
        file=sys.stderr,
    )
    return 3 if all(e["exit"] == 3 for e in failed) else 1


def _progress() -> Any:
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn("detect"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        transient=False,
    )


def _collect(tasks: list[Task], completed: Iterator[tuple[int, dict[str, Any]]]) -> list[dict[str, Any]]:
    results: list[dict[str, Any] | None] = [None] * len(tasks)
    with _progress() as progress:
        bar = progress.add_task("detect", total=len(tasks))
        for index, res in completed:
            results[index] = res
            progress.advance(bar)
    assert all(r is not None for r in results)
    return [r for r in results if r is not None]


def _run_pool(tasks: list[Task], jobs: int) -> list[dict[str, Any]]:
    if jobs == 1:
        _warm_up()
        return _collect(tasks, ((i, detect_task(t)) for i, t in enumerate(tasks)))
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from cell.pools import one_thread_children

    # forkserver: workers fork from a clean server that has imported the detector once (no fork of this
    # process's threads); spawn where there is no forkserver (Windows, macOS default)
    ctx: multiprocessing.context.BaseContext
    if "forkserver" in multiprocessing.get_all_start_methods():
        server = multiprocessing.get_context("forkserver")
        server.set_forkserver_preload(["perception.detect", "perception.capture", "perception.seams"])
        ctx = server
    else:
        ctx = multiprocessing.get_context("spawn")
    with one_thread_children(), ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_warm_up) as pool:
        futures = {pool.submit(detect_task, t): i for i, t in enumerate(tasks)}
        return _collect(tasks, ((futures[f], f.result()) for f in as_completed(futures)))


def _run_ray(tasks: list[Task], address: str) -> list[dict[str, Any]]:
    try:
        import ray
    except ImportError as err:
        raise ConfigError(RAY_HINT) from err
    ray.init(address=None if address == "local" else address, include_dashboard=False, log_to_driver=False)
    try:
        remote: Callable[..., Any] = ray.remote(num_cpus=1)(detect_task).remote
        refs = {remote(t): i for i, t in enumerate(tasks)}

        def completed() -> Iterator[tuple[int, dict[str, Any]]]:
            pending = list(refs)
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    yield refs[ref], ray.get(ref)

        return _collect(tasks, completed())
    finally:
        ray.shutdown()


def _print_summary(entries: list[dict[str, Any]], *, wall_s: float, workers: str, out_dir: Path) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{len(entries)} capture(s) -> {out_dir}")
    for col in ("capture", "seams", "time s", "result"):
        table.add_column(col, justify="right" if col in ("seams", "time s") else "left")
    for e in entries:
        if e["ok"]:
            table.add_row(e["source"], str(e["seams"]), f"{e['time_s']:.3f}", Path(e["out"]).name)
        else:
            table.add_row(e["source"], "-", "-", e["error"])
    console = Console()
    console.print(table)
    ok = sum(1 for e in entries if e["ok"])
    console.print(f"{ok}/{len(entries)} captures with seams in {wall_s:.2f} s on {workers}; summary in batch.json")
