"""The fake FANUC controller in a process of its own, as the fake UR runs, behind a handle with the same methods.

In the host's process the fake shares the host's GIL: a daemon or a test computing a detection or a calibration
starves the fake's event loop, and the driver's real deadlines (a 0.4 s status read, the R[90] heartbeat watched
by WC_HBEAT within 0.3 s) then trip on the simulator's lateness instead of the host's. :class:`FakeFanucProcess`
runs :class:`sim_fakes.fake_fanuc.FakeFanucController` in a spawned child and forwards the control handle's calls
(:data:`HANDLE_METHODS`) over a pipe, each with a deadline. The cell factory starts this one; driver tests that
look inside the fake still construct :class:`~sim_fakes.fake_fanuc.FakeFanucController` in their own process.
"""

from __future__ import annotations

from multiprocessing.connection import Connection
from typing import Any

from drivers.priority import enter_io_process
from sim_fakes.fake_fanuc import FakeFanucController
from sim_fakes.fanuc_program import HeartbeatProgram, InstructionRecord
from sim_fakes.process_fake import ServerFake, serve_handle

HANDLE_METHODS = frozenset(
    {
        "inject",
        "clear_faults",
        "records",
        "max_in_flight",
        "xyzwpr_mm_deg",
        "digital_output",
        "in_flight",
        "events",
        "now_s",
        "register",
    }
)
"""The :class:`FakeFanucController` methods the handle forwards (what the cell's tests and fault switch use)."""


def _serve(conn: Connection, host: str, port: int, heartbeat: HeartbeatProgram | None) -> None:
    """The child: start the fake, report its port, answer ``(method, args, kwargs)`` until ``("shutdown",)`` or
    until the parent goes away."""
    enter_io_process()  # it stands in for a controller that never misses a cycle (as the fake UR does)
    try:
        fake = FakeFanucController(host=host, port=port, heartbeat=heartbeat).start()
    except Exception as err:
        conn.send(("error", f"{type(err).__name__}: {err}"))
        return
    conn.send(("ready", fake.port))
    try:
        serve_handle(conn, fake, HANDLE_METHODS, "the fake FANUC")
    finally:
        fake.stop()


class FakeFanucProcess(ServerFake):
    """A :class:`FakeFanucController` (``host``, ``port``, ``heartbeat`` as there) in a child process.

    Implements :class:`sim_fakes.faults.FaultInjectable`; :attr:`port` is the bound RMI port once started. Each
    forwarded call waits at most ``request_timeout_s`` (TimeoutError); the fake's own errors come back as
    ValueError. Use as a context manager or call :meth:`start` / :meth:`stop`.
    """

    supported_faults = FakeFanucController.supported_faults
    handle_methods = HANDLE_METHODS

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        heartbeat: HeartbeatProgram | None = None,
        startup_timeout_s: float = 30.0,
        request_timeout_s: float = 10.0,
    ) -> None:
        self.host = host
        self.port = 0
        super().__init__(
            _serve,
            (host, port, heartbeat),
            label=f"fake FANUC at {host}",
            startup_timeout_s=startup_timeout_s,
            request_timeout_s=request_timeout_s,
        )

    # what the fake saw and is doing (see FakeFanucController)
    def records(self) -> list[InstructionRecord]:
        return list(self._call("records"))

    def accepted_records(self) -> list[InstructionRecord]:
        return [r for r in self.records() if r.error_id == 0]

    def max_in_flight(self) -> int:
        return int(self._call("max_in_flight"))

    def xyzwpr_mm_deg(self) -> tuple[float, ...]:
        return tuple(self._call("xyzwpr_mm_deg"))

    def digital_output(self, port_number: int) -> bool:
        return bool(self._call("digital_output", port_number))

    def in_flight(self) -> int:
        return int(self._call("in_flight"))

    def events(self) -> list[dict[str, Any]]:
        return list(self._call("events"))

    def now_s(self) -> float:
        return float(self._call("now_s"))

    def register(self, number: int) -> float:
        return float(self._call("register", number))
