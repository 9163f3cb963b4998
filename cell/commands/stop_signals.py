"""SIGINT / SIGTERM for the foreground services (``weldcell serve``, ``weldcell sim up``)."""

from __future__ import annotations

import logging
import multiprocessing
import signal
import threading
from types import FrameType, TracebackType
from typing import Any

SIGNALS = (signal.SIGINT, signal.SIGTERM)

logger = logging.getLogger(__name__)


class StopSignals:
    """Within ``with``: the signals are ignored until :meth:`arm` (while devices start: a fake that runs in its
    own process, the UR, inherits an *ignored* signal across exec, so a Ctrl-C sent to the whole process group
    reaches only this process, which then stops every fake in order instead of each child dying with its own
    traceback); once armed, the first one is recorded and :meth:`wait` returns its name. The previous handlers
    are restored on leaving."""

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._received: list[str] = []
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> StopSignals:
        self._previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in SIGNALS}
        return self

    def arm(self) -> None:
        for sig in SIGNALS:
            signal.signal(sig, self._on_signal)

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self._received.append(signal.Signals(signum).name)
        self._stop.set()

    def wait(self) -> str:
        """Block until a signal arrives; its name ("SIGTERM")."""
        while not self._stop.wait(0.25):
            pass
        return self._received[0] if self._received else "stop"

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def end_child_processes(timeout_s: float = 3.0) -> list[str]:
    """End every multiprocessing child of this process still running, within a bound: terminate, wait up to
    ``timeout_s``, then kill. Returns the names of those that had to be ended.

    The devices' own close stops their processes; this is the bound behind it. At exit multiprocessing terminates
    its daemonic children and then waits for each *without* a timeout, so one child that does not end there (it
    ignores SIGTERM, or nobody closed its device) would keep a stopping service alive for ever."""
    children = multiprocessing.active_children()
    for child in children:
        logger.warning("child process %s (pid %s) still running at exit: terminating it", child.name, child.pid)
        child.terminate()
    for child in children:
        child.join(timeout_s)
        if child.is_alive():
            logger.error("child %s (pid %s) outlived SIGTERM by %.0f s: killing it", child.name, child.pid, timeout_s)
            child.kill()
            child.join(timeout_s)
    return [child.name for child in children]
