"""The test-only fault switches of ``weldcell serve --sim-faults``: the simulators this daemon started, their
faults switched on and off over ``/sim/faults`` (``sim_fakes.faults``), each switch journaled.

A soak or a test plays the broken device and the cell reacts as it would to the real one. The daemon refuses the
switch unless every device is a simulator it started itself (:meth:`cell.factory.Cell.fault_injectors`); without
it no :class:`SimFaultSwitch` exists in the process and the paths answer 404.
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable
from typing import Any

from cell.errors import ConfigError, WeldcellError
from cell.request_parsing import body_text, parse_json_object

logger = logging.getLogger(__name__)


class SimFaultSwitch:
    """Fault switches of the simulated devices in ``injectors`` (role -> the simulator's fault handle).
    ``note(text)`` journals a switch; ``arc_output()`` is the digital output that switches the arc."""

    def __init__(self, injectors: dict[str, Any], *, note: Callable[[str], None], arc_output: Callable[[], int]):
        self.injectors = injectors
        self._note = note
        self._arc_output = arc_output
        self._lock = threading.Lock()
        self._injected: dict[str, list[dict[str, Any]]] = {}

    def view(self) -> dict[str, Any]:
        """The simulated devices: the faults each supports and those injected since they were last cleared."""
        with self._lock:
            injected = {role: list(faults) for role, faults in self._injected.items()}
        return {
            "devices": {
                role: {"supported": sorted(handle.supported_faults), "injected": injected.get(role, [])}
                for role, handle in self.injectors.items()
            },
            "arc_output_on": self.simulated_arc_on(),
        }

    def simulated_arc_on(self) -> bool | None:
        """The arc output as the simulated controller itself holds it (not as the driver reports it): what an
        independent reader of the controller's outputs sees. None: unknown."""
        robot: Any = self.injectors.get("robot")
        index = self._arc_output()
        try:
            if hasattr(robot, "digital_output"):  # the fake FANUC: DO[index + 1]
                return bool(robot.digital_output(index + 1))
            if hasattr(robot, "snapshot"):  # the fake UR, through its process's control pipe
                return bool(robot.snapshot()["digital_outputs"][index])
        except (RuntimeError, TimeoutError, OSError, ValueError, IndexError, KeyError):
            return None
        return None

    def inject(self, device: str, fault: str, params: dict[str, Any]) -> None:
        """Switch ``fault`` of the simulated ``device`` on. ConfigError for an unknown device, fault or parameter."""
        handle = self._device(device)
        try:
            handle.inject(fault, **params)
        except (ValueError, TypeError) as err:
            raise ConfigError(f"simulated {device}: {err}") from err
        except (RuntimeError, TimeoutError, OSError) as err:  # a fake (the UR's own process) that does not answer
            raise WeldcellError(f"the simulated {device} did not take the fault: {err}") from err
        with self._lock:
            self._injected.setdefault(device, []).append({"fault": fault, "params": params})
        self._journal(f"test fault injected into the simulated {device}: {fault} {json.dumps(params)}")

    def clear(self, device: str | None = None) -> list[str]:
        """Switch the faults of the simulated ``device`` (None: every one) off; returns the devices cleared."""
        roles = [device] if device is not None else sorted(self.injectors)
        handles = [(role, self._device(role)) for role in roles]
        for role, handle in handles:
            try:
                handle.clear_faults()
            except (RuntimeError, TimeoutError, OSError) as err:
                raise WeldcellError(f"the simulated {role} did not clear its faults: {err}") from err
            with self._lock:
                self._injected.pop(role, None)
        self._journal(f"test faults cleared in the simulated {', '.join(roles)}")
        return roles

    def command(self, path: str, body: bytes) -> dict[str, Any]:
        """POST /sim/faults {"device", "fault", "params"} or /sim/faults/clear {"device"} (optional)."""
        obj = parse_json_object(body_text(body))
        device = obj.get("device")
        if path.endswith("/clear"):
            if device is not None and not isinstance(device, str):
                raise ConfigError('"device" must be a device name (or left out: every simulator)')
            return {"cleared": self.clear(device)}
        fault, params = obj.get("fault"), obj.get("params", {})
        if not isinstance(device, str) or not isinstance(fault, str) or not isinstance(params, dict):
            raise ConfigError('send {"device": "robot" | "track" | "camera", "fault": "<name>", "params": {}}')
        self.inject(device, fault, params)
        return {"device": device, "fault": fault, "params": params}

    def _device(self, device: str) -> Any:
        if device not in self.injectors:
            raise ConfigError(f"no simulated device {device!r}; choose one of {sorted(self.injectors)}")
        return self.injectors[device]

    def _journal(self, text: str) -> None:
        logger.warning("%s", text)
        self._note(text)
