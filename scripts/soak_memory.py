"""The soak's memory rule (scripts/soak.py): no Python leak, and resident memory on a plateau.

The daemon runs with ``WELDCELL_MEMORY_SNAPSHOTS=<work folder>/memory.jsonl`` (:class:`cell.memory.MemoryLog`): after
each job, once its memory is handed back (``malloc_trim``) and the job worker is idle, it records the memory Python
holds live (``tracemalloc``, NumPy's buffers included) and its resident size. Two figures, after the first
``warmup`` jobs:

- **traced** (a leak): the median of the first third of the samples against the median of the last third; it must
  not grow by more than ``traced_bound_mib``. A job's objects that something keeps show here whatever the allocator
  does.
- **resident** (the plateau): the slope, in MiB per job, of the last half of the samples (the median of the slopes
  between every pair of them, which one odd sample does not move); at most ``rss_slope_bound_mib``. The allocator
  keeps some of what a job freed and the resident size climbs for a while after warm-up; it must level off.

The earlier rule (the lowest of two resident samples taken by the soak as each job finished, often while the next
one rendered, first window against last) failed a run whose resident size rose 262 -> 310 MiB while live Python
memory stayed 38.2 -> 38.4 MiB: allocator growth, not a leak, and no sign of levelling off in a window of two.
"""

from __future__ import annotations

import json
import statistics
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

TRACED_BOUND_MIB = 5.0
RSS_SLOPE_BOUND_MIB = 0.5


@dataclass
class MemoryVerdict:
    """The figures of :func:`judge_memory` and what failed (empty: the rule holds). ``samples``: how many after
    warm-up; ``traced_first_mib``/``traced_last_mib``: the medians of the first and last third; ``rss_slope_mib``:
    MiB per job over the last half (``rss_from_n``: the first job of that half); ``rss_first_mib``/``rss_last_mib``:
    the first and last resident sample after warm-up."""

    samples: int = 0
    traced_first_mib: float = 0.0
    traced_last_mib: float = 0.0
    rss_first_mib: float = 0.0
    rss_last_mib: float = 0.0
    rss_slope_mib: float = 0.0
    rss_from_n: int = 0
    failures: list[str] = field(default_factory=list)

    @property
    def traced_growth_mib(self) -> float:
        return self.traced_last_mib - self.traced_first_mib


def read_memory_log(path: Path) -> list[dict[str, Any]]:
    """The daemon's memory lines of its jobs (one per job it ran, in order; not the last line it writes when it
    stops); [] when the file is missing."""
    if not path.is_file():
        return []
    lines = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    return [line for line in lines if "n" in line]


def robust_slope(xs: list[float], ys: list[float]) -> float:
    """The median of the slopes between every pair of points (Theil-Sen); 0.0 for fewer than two points."""
    pairs = [(i, j) for i in range(len(xs)) for j in range(i + 1, len(xs)) if xs[j] != xs[i]]
    slopes = [(ys[j] - ys[i]) / (xs[j] - xs[i]) for i, j in pairs]
    return statistics.median(slopes) if slopes else 0.0


def judge_memory(
    records: list[dict[str, Any]],
    *,
    warmup: int,
    traced_bound_mib: float = TRACED_BOUND_MIB,
    rss_slope_bound_mib: float = RSS_SLOPE_BOUND_MIB,
    min_samples: int = 6,
) -> MemoryVerdict:
    """Judge the daemon's per-job memory ``records`` (:func:`read_memory_log`) after the first ``warmup`` jobs."""
    v = MemoryVerdict()
    after = [r for r in records if int(r["n"]) > warmup and r.get("rss_mib") is not None]
    v.samples = len(after)
    if len(after) < min_samples:
        v.failures.append(
            f"{len(after)} memory samples after the {warmup} warm-up jobs, fewer than the {min_samples} the rule needs "
            f"({len(records)} recorded: is {'WELDCELL_MEMORY_SNAPSHOTS'} reaching the daemon?)"
        )
        return v
    third = len(after) // 3
    v.traced_first_mib = statistics.median(float(r["traced_mib"]) for r in after[:third])
    v.traced_last_mib = statistics.median(float(r["traced_mib"]) for r in after[-third:])
    if v.traced_growth_mib > traced_bound_mib:
        v.failures.append(
            f"live Python memory (tracemalloc) grew {v.traced_growth_mib:.1f} MiB after warm-up: median "
            f"{v.traced_first_mib:.1f} MiB over jobs {after[0]['n']}-{after[third - 1]['n']}, "
            f"{v.traced_last_mib:.1f} MiB over jobs {after[-third]['n']}-{after[-1]['n']} (bound {traced_bound_mib:g})"
        )
    tail = after[len(after) // 2 :]
    v.rss_first_mib, v.rss_last_mib = float(after[0]["rss_mib"]), float(after[-1]["rss_mib"])
    v.rss_from_n = int(tail[0]["n"])
    v.rss_slope_mib = robust_slope([float(r["n"]) for r in tail], [float(r["rss_mib"]) for r in tail])
    if v.rss_slope_mib > rss_slope_bound_mib:
        v.failures.append(
            f"resident memory (idle, after malloc_trim) still grows {v.rss_slope_mib:.2f} MiB per job over jobs "
            f"{tail[0]['n']}-{tail[-1]['n']} (bound {rss_slope_bound_mib:g}): no plateau"
        )
    return v
