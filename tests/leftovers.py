"""Shared test check: no thread of ours is still running after a test."""

from __future__ import annotations

import threading
import time


def assert_no_threads_left(prefixes: tuple[str, ...], *, grace_s: float = 2.0) -> None:
    """Fail when a thread whose name starts with one of ``prefixes`` outlives ``grace_s``."""
    deadline = time.monotonic() + grace_s
    while True:
        leftover = [t.name for t in threading.enumerate() if t.name.startswith(prefixes)]
        if not leftover or time.monotonic() > deadline:
            break
        time.sleep(0.01)
    assert not leftover, f"threads left running after the test: {leftover}"
