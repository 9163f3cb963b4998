"""The handle of a fake device that runs in a spawned process of its own, talking to it over a pipe.

A fake in the host's process shares the host's GIL, and the drivers' real deadlines then trip on the simulator's
lateness (the fake UR must run apart anyway: ur-rtde's C++ client holds the GIL while it waits). The child's entry
point gets its end of the pipe first; it answers ``("ready", detail)`` once it serves (or ``("error", text)``),
then each request tuple with ``("ok", result)`` or ``("error", text)``, and ``("shutdown",)`` with ``("ok", None)``
before it ends. It must end by itself when the pipe closes (the handle's process is gone).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import threading
from collections.abc import Callable
from multiprocessing.connection import Connection
from types import TracebackType
from typing import Any, Self


class ProcessFake:
    """Start, stop and ask a fake in a child process (``entry(conn, *args)``). ``label`` names it in messages.
    ``startup_timeout_s`` bounds :meth:`start`; ``request_timeout_s`` each request (TimeoutError). The child's own
    errors come back as ValueError. Use as a context manager or call :meth:`start` / :meth:`stop`."""

    def __init__(
        self,
        entry: Callable[..., None],
        args: tuple[Any, ...],
        *,
        label: str,
        startup_timeout_s: float,
        request_timeout_s: float,
    ) -> None:
        self._entry, self._args, self._label = entry, args, label
        self.startup_timeout_s = startup_timeout_s
        self.request_timeout_s = request_timeout_s
        self._proc: multiprocessing.process.BaseProcess | None = None
        self._conn: Connection | None = None
        self._lock = threading.Lock()

    def start(self) -> Self:
        """Start the child and wait until it serves (its ``ready`` detail goes to :meth:`_on_ready`)."""
        self._on_ready(self._start_process())
        return self

    def _on_ready(self, detail: Any) -> None:
        """What the child's ``ready`` said (a bound port, for instance)."""

    def _start_process(self) -> Any:
        if self._proc is not None:
            raise RuntimeError(f"{self._label} is already running")
        ctx = multiprocessing.get_context("spawn")
        parent, child = ctx.Pipe()
        name = self._label.replace(" at ", "-").replace(" ", "-")
        proc = ctx.Process(target=self._entry, args=(child, *self._args), name=name, daemon=True)
        proc.start()
        child.close()
        self._proc, self._conn = proc, parent
        if not parent.poll(self.startup_timeout_s):
            self.stop()
            raise TimeoutError(f"{self._label} did not start within {self.startup_timeout_s} s")
        try:
            status, detail = parent.recv()
        except EOFError:
            status, detail = "error", f"its process ended (exit code {proc.exitcode})"
        if status != "ready":
            self.stop()
            raise RuntimeError(f"{self._label} could not start: {detail}")
        return detail

    def stop(self) -> None:
        """Stop the fake's process (safe to call twice)."""
        proc, conn = self._proc, self._conn
        self._proc = self._conn = None
        if conn is not None:
            with contextlib.suppress(OSError, EOFError):
                conn.send(("shutdown",))
                if conn.poll(2.0):
                    conn.recv()
            conn.close()
        if proc is not None:
            proc.join(3.0)
            if proc.is_alive():
                proc.terminate()
                proc.join(2.0)
            if proc.is_alive():
                proc.kill()
                proc.join(2.0)

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    def _request(self, *request: Any) -> Any:
        with self._lock:
            conn = self._conn
            if conn is None:
                raise RuntimeError(f"{self._label} is not running; call start() first")
            conn.send(request)
            if not conn.poll(self.request_timeout_s):
                raise TimeoutError(f"{self._label} did not answer {request[0]!r} within {self.request_timeout_s} s")
            status, result = conn.recv()
        if status != "ok":
            raise ValueError(result)
        return result


class ServerFake(ProcessFake):
    """A process fake that serves a network port (its ``ready`` detail: the bound port, in :attr:`port`) and whose
    handle takes faults: requests go to the child's fake by method name, only those in ``handle_methods``."""

    handle_methods: frozenset[str] = frozenset()
    port: int = 0

    def _on_ready(self, detail: Any) -> None:
        self.port = int(detail)

    def _call(self, name: str, *args: Any, **kwargs: Any) -> Any:
        if name not in self.handle_methods:
            raise AttributeError(f"{self._label}'s handle has no method {name!r}")
        return self._request(name, args, kwargs)

    # FaultInjectable
    def inject(self, fault: str, **params: Any) -> None:
        self._call("inject", fault, **params)

    def clear_faults(self) -> None:
        self._call("clear_faults")


def serve_handle(conn: Connection, fake: Any, methods: frozenset[str], label: str) -> None:
    """The child's side once ``fake`` serves: answer ``(method, args, kwargs)`` requests with the result of that
    method of ``fake`` (only those in ``methods``) until ``("shutdown",)`` or until the parent goes away. The caller
    sent ``("ready", ...)`` and stops ``fake`` afterwards."""
    while True:
        try:
            request = conn.recv()
        except (EOFError, OSError):
            return  # the parent is gone: nobody can use the fake any more
        if request[0] == "shutdown":
            conn.send(("ok", None))
            return
        name, args, kwargs = request
        if name not in methods:
            conn.send(("error", f"{label}'s handle has no method {name!r}"))
            continue
        try:
            conn.send(("ok", getattr(fake, name)(*args, **kwargs)))
        except Exception as err:
            conn.send(("error", f"{type(err).__name__}: {err}"))
