"""The fake track drive in a process of its own, as the fake FANUC and the fake UR run, behind a handle with the same
methods.

As a thread of the daemon the fake drive shares the daemon's GIL: while a job renders and detects, its Modbus server
answered late, and the job watchdog's status read (``answer_timeout_s``, 0.6 s) faulted healthy jobs with "no status
from the robot or the track within 0.6 s" under load. :class:`FakeTrackProcess` runs
:class:`sim_fakes.fake_track.FakeTrack` in a spawned child and forwards the control handle's calls
(:data:`HANDLE_METHODS`) over a pipe, each with a deadline. The cell factory starts this one; driver tests that look
inside the fake still construct :class:`~sim_fakes.fake_track.FakeTrack` in their own process.
"""

from __future__ import annotations

from multiprocessing.connection import Connection
from typing import Any

from drivers.priority import enter_io_process
from sim_fakes.fake_track import FakeTrack, MoveRecord
from sim_fakes.process_fake import ServerFake, serve_handle

HANDLE_METHODS = frozenset({"inject", "clear_faults", "position_m", "snapshot", "moves", "refused"})
"""The :class:`FakeTrack` methods the handle forwards (what the cell's tests and fault switch use)."""


def _serve(conn: Connection, host: str, port: int, settings: dict[str, Any]) -> None:
    """The child: start the fake, report its port, answer requests until ``("shutdown",)`` or the parent is gone."""
    enter_io_process()  # it stands in for a drive that answers within its cycle whatever the host does
    try:
        fake = FakeTrack(host=host, port=port, **settings).start()
    except Exception as err:
        conn.send(("error", f"{type(err).__name__}: {err}"))
        return
    conn.send(("ready", fake.port))
    try:
        serve_handle(conn, fake, HANDLE_METHODS, "the fake track")
    finally:
        fake.stop()


class FakeTrackProcess(ServerFake):
    """A :class:`FakeTrack` in a child process: ``host``, ``port``, ``unit_id``, ``counts_per_m`` and the keyword
    arguments ``settings`` (soft limits, speed and acceleration limits, window, start position, as
    :class:`FakeTrack` takes them, in SI).

    Implements :class:`sim_fakes.faults.FaultInjectable`; :attr:`port` is the bound Modbus TCP port once started.
    Each forwarded call waits at most ``request_timeout_s`` (TimeoutError); the fake's own errors (a bad fault
    name, a bad code) come back as ValueError. Use as a context manager or call :meth:`start` / :meth:`stop`.
    """

    supported_faults = FakeTrack.supported_faults
    handle_methods = HANDLE_METHODS

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        unit_id: int = 1,
        counts_per_m: int = 100_000,
        startup_timeout_s: float = 30.0,
        request_timeout_s: float = 10.0,
        **settings: Any,
    ) -> None:
        self.host = host
        self.port = 0
        self.unit_id = unit_id
        self.counts_per_m = counts_per_m
        super().__init__(
            _serve,
            (host, port, {"unit_id": unit_id, "counts_per_m": counts_per_m, **settings}),
            label=f"fake track at {host}",
            startup_timeout_s=startup_timeout_s,
            request_timeout_s=request_timeout_s,
        )

    # what the drive is doing and did (see FakeTrack)
    def position_m(self) -> float:
        return float(self._call("position_m"))

    def snapshot(self) -> dict[str, Any]:
        return dict(self._call("snapshot"))

    def moves(self) -> list[MoveRecord]:
        return list(self._call("moves"))

    def refused(self) -> list[tuple[int, int]]:
        return list(self._call("refused"))
