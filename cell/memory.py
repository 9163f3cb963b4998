"""Allocator tuning for a process that runs for days (the cell daemon).

A daemon that runs for days must not creep. Each job allocates and frees a few hundred MiB of arrays on the worker
thread; glibc keeps freed memory in per-thread arenas, so the resident size grew ~0.4 MiB per job over a 100-job
soak (scripts/soak.py) with no Python object leaked. Fewer arenas (:func:`limit_malloc_arenas`, before the threads
exist) and handing freed memory back after each job (:func:`release_freed_memory`) keep it flat. Both are no-ops
where glibc is absent.
"""

from __future__ import annotations

from typing import Any

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

