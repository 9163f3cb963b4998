"""cell.memory: the glibc allocator tuning the daemon applies (Linux only; elsewhere both calls say False)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from cell.memory import limit_malloc_arenas, release_freed_memory

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
