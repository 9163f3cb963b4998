"""cell.memory: the glibc allocator tuning the daemon applies (Linux only; elsewhere both calls say False), and the
memory figures it records after each job with WELDCELL_MEMORY_SNAPSHOTS."""

from __future__ import annotations

import json
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from cell.memory import (
    MEMORY_SNAPSHOTS_ENV,
    MemoryLog,
    limit_malloc_arenas,
    memory_log_from_env,
    release_freed_memory,
    resident_mib,
)

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc tuning is Linux-only")


@linux
def test_the_arena_cap_takes_effect() -> None:
    assert limit_malloc_arenas(2) is True


@linux
def test_freed_memory_is_handed_back() -> None:
    # 64 MiB in small pieces (below mmap's threshold, so they live in the heap and only malloc_trim returns them)
    pieces = [np.ones(16 * 1024, dtype=np.uint8) for _ in range(4096)]
    assert sum(p.nbytes for p in pieces) == 64 * 1024 * 1024
    del pieces
    assert release_freed_memory() is True


def test_the_memory_log_is_off_unless_the_environment_names_its_file(tmp_path: Path) -> None:
    assert memory_log_from_env({}) is None
    assert memory_log_from_env({MEMORY_SNAPSHOTS_ENV: "  "}) is None
    was_tracing = tracemalloc.is_tracing()
    log = memory_log_from_env({MEMORY_SNAPSHOTS_ENV: str(tmp_path / "out" / "memory.jsonl")})
    try:
        assert log is not None and log.path == tmp_path / "out" / "memory.jsonl" and tracemalloc.is_tracing()
        assert log.path.read_text() == ""  # a fresh file for this run
    finally:
        if not was_tracing:
            tracemalloc.stop()


@linux
def test_each_record_has_the_live_python_memory_the_resident_size_and_the_largest_site(tmp_path: Path) -> None:
    was_tracing = tracemalloc.is_tracing()
    log = MemoryLog(tmp_path / "memory.jsonl")
    try:
        first = log.record(1)
        kept = np.empty(8 * 1024 * 1024 // 8)  # 8 MiB that stay alive: a leak as the log must show it
        kept.fill(1.0)
        second = log.record(2)
        final = log.close()
        del kept
        third = log.record(None)
    finally:
        if not was_tracing:
            tracemalloc.stop()
    lines = [json.loads(line) for line in log.path.read_text().splitlines()]
    assert lines == [first, second, final, third]
    lines.remove(final)
    assert [e["n"] for e in lines] == [1, 2, 3] and [e["job_id"] for e in lines] == [1, 2, None]
    assert second["traced_mib"] - first["traced_mib"] == pytest.approx(8.0, abs=0.5)
    assert third["traced_mib"] - first["traced_mib"] == pytest.approx(0.0, abs=0.5)
    # the largest sites: on the first line and on the last one (close), not on every job's
    assert "top" in first and "top" not in second and "top" not in third
    assert final["final"] is True and final["jobs"] == 2 and 0 <= final["snapshot_s"] < 10
    assert final["top"][0][0].endswith("test_memory.py:" + str(_line_of("kept = np.empty")))
    assert final["top"][0][1] == pytest.approx(8.0, abs=0.01)
    rss = resident_mib()
    assert rss is not None and second["rss_mib"] is not None and 0 < second["rss_mib"] <= rss + 64


def _line_of(text: str) -> int:
    lines = Path(__file__).read_text().splitlines()
    return next(i for i, line in enumerate(lines, 1) if text in line and "_line_of" not in line)
