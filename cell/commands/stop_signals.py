"""SIGINT / SIGTERM for the foreground services (``weldcell serve``, ``weldcell sim up``)."""

from __future__ import annotations

import signal
import threading
from types import FrameType, TracebackType
from typing import Any

SIGNALS = (signal.SIGINT, signal.SIGTERM)


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
