"""The fault-injection switch every fake device exposes to tests.

A fake's control handle (returned when the fake is started) implements :class:`FaultInjectable`.
Fault names are shared across devices where they mean the same thing:

- ``"drop_connection"``: close every client connection now (and refuse new ones until cleared).
- ``"no_answer"``: keep connections open but stop answering (a hung controller).
- ``"protective_stop"`` / ``"emergency_stop"``: robot safety stops (motion halts, state reports it).
- ``"rmi_error"`` (FANUC, param ``code``), ``"system_fault"`` (FANUC), ``"alarm"`` (FANUC, param ``text``: a STOP.G
  alarm pauses the program with servo power on).
- ``"modbus_exception"`` (track, param ``code``), ``"track_fault"`` (track, param ``code``).
- ``"frame_timeout"``, ``"corrupt_frame"`` (camera).

``clear_faults()`` returns the fake to normal (a safety stop stays latched in the robot state until the
driver resets it, as on real controllers, but new connections are accepted again).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class FaultInjectable(Protocol):
    supported_faults: frozenset[str]

    def inject(self, fault: str, **params: Any) -> None:
        """Switch ``fault`` on; raises ValueError for a fault this fake does not support."""

    def clear_faults(self) -> None:
        """Switch every fault off."""
