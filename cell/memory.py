"""Allocator tuning for a process that runs for days (the cell daemon).

A daemon that runs for days must not creep. Each job allocates and frees a few hundred MiB of arrays on the worker
thread; glibc keeps freed memory in per-thread arenas, so the resident size grew ~0.4 MiB per job over a 100-job
soak (scripts/soak.py) with no Python object leaked. Fewer arenas (:func:`limit_malloc_arenas`, before the threads
exist) and handing freed memory back after each job (:func:`release_freed_memory`) keep it flat. Both are no-ops
where glibc is absent.

Measuring it (:class:`MemoryLog`, switched on by the environment variable ``WELDCELL_MEMORY_SNAPSHOTS=<file>``):
the resident size mixes Python's live objects with what the allocator keeps. With the variable set, the daemon
traces Python's allocations (``tracemalloc``, NumPy's array buffers included) and, after each job and its
``malloc_trim``, appends one JSON line to the file: the traced (live) memory, the resident size and the largest
allocation sites. A leak shows as traced memory that grows; allocator growth as resident memory alone
(scripts/soak.py judges both).
"""

from __future__ import annotations

import json
import os
import threading
import time
import tracemalloc
from collections.abc import Mapping
from pathlib import Path
from typing import Any

MEMORY_SNAPSHOTS_ENV = "WELDCELL_MEMORY_SNAPSHOTS"
"""The environment variable naming the file :class:`MemoryLog` appends to (unset or empty: no tracing)."""
MIB = 1024.0 * 1024.0

_M_ARENA_MAX = -8  # mallopt parameter (glibc malloc.h)


def _libc() -> Any:
    import ctypes
    import ctypes.util
    import sys

    name = ctypes.util.find_library("c")
    if not name or not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(name)
    except OSError:
        return None


def limit_malloc_arenas(arenas: int = 2) -> bool:
    """Cap glibc's malloc arenas (as MALLOC_ARENA_MAX would); True when it took effect."""
    libc = _libc()
    return bool(libc is not None and hasattr(libc, "mallopt") and libc.mallopt(_M_ARENA_MAX, arenas) == 1)


def release_freed_memory() -> bool:
    """Return freed heap memory to the system (glibc malloc_trim); True when some was released."""
    libc = _libc()
    return bool(libc is not None and hasattr(libc, "malloc_trim") and libc.malloc_trim(0) == 1)



def resident_mib() -> float | None:
    """This process's resident size (VmRSS of /proc/self/status) in MiB; None where /proc is absent."""
    try:
        text = Path("/proc/self/status").read_text(encoding="ascii")
    except OSError:
        return None
    for line in text.splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return None


class MemoryLog:
    """Traced and resident memory after each job, one JSON line per :meth:`record` appended to ``path``.

    Starts ``tracemalloc`` (one frame per allocation: the site, not the stack) unless it runs already. Each line:
    ``{"n": jobs recorded so far, "job_id", "t_s": seconds since this log started, "traced_mib": live Python
    memory, "traced_peak_mib", "tracemalloc_mib": tracemalloc's own tables (in the resident size, not in the
    traced), "rss_mib"}``; the first line also ``"top": [[file:line, MiB], ...]`` the ``top`` largest sites and
    ``"snapshot_s"``, what that took, and :meth:`close` writes a last line ``{"final": true, ...}`` with them. A
    snapshot walks every traced block holding the GIL (about a second in the daemon, which has imported Open3D):
    taken after a job, it held up the HTTP requests that time a fault's arc-off (the next job's deadlines, had one
    been queued). Safe to call from any thread (one at a time)."""

    def __init__(self, path: str | os.PathLike[str], *, top: int = 5) -> None:
        self.path = Path(path)
        self.top = top
        self._n = 0
        self._t0 = time.monotonic()
        self._lock = threading.Lock()
        if not tracemalloc.is_tracing():
            tracemalloc.start(1)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.path.write_text("", encoding="utf-8")

    def record(self, job_id: int | None) -> dict[str, Any]:
        """Append the figures now (call it once the job's memory is released) and return them."""
        with self._lock:
            self._n += 1
            traced, peak = tracemalloc.get_traced_memory()
            entry: dict[str, Any] = {
                "n": self._n,
                "job_id": job_id,
                "t_s": round(time.monotonic() - self._t0, 3),
                "traced_mib": round(traced / MIB, 3),
                "traced_peak_mib": round(peak / MIB, 3),
                "tracemalloc_mib": round(tracemalloc.get_tracemalloc_memory() / MIB, 3),
                "rss_mib": resident_mib(),
            }
            tracemalloc.reset_peak()
            if self._n == 1:
                entry.update(self._top_sites())
            self._write(entry)
            return entry

    def close(self) -> dict[str, Any]:
        """The last line (the largest sites now, to compare with the first line's) when the daemon stops."""
        with self._lock:
            traced, _peak = tracemalloc.get_traced_memory()
            entry: dict[str, Any] = {
                "final": True,
                "jobs": self._n,
                "t_s": round(time.monotonic() - self._t0, 3),
                "traced_mib": round(traced / MIB, 3),
                "rss_mib": resident_mib(),
                **self._top_sites(),
            }
            self._write(entry)
            return entry

    def _top_sites(self) -> dict[str, Any]:
        t0 = time.monotonic()
        stats = tracemalloc.take_snapshot().statistics("lineno")[: self.top]
        return {
            "top": [[f"{s.traceback[0]}", round(s.size / MIB, 3)] for s in stats],
            "snapshot_s": round(time.monotonic() - t0, 3),
        }

    def _write(self, entry: dict[str, Any]) -> None:
        with self.path.open("a", encoding="utf-8") as f:
            f.write(json.dumps(entry) + "\n")


def memory_log_from_env(environ: Mapping[str, str] = os.environ) -> MemoryLog | None:
    """A :class:`MemoryLog` writing to ``$WELDCELL_MEMORY_SNAPSHOTS`` when that is set (and not empty), else None."""
    path = environ.get(MEMORY_SNAPSHOTS_ENV, "").strip()
    return MemoryLog(path) if path else None
