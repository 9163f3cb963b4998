"""The control handle of a fake UR process, used by tests and the cell factory.

Part of :mod:`sim_fakes.fake_ur` (its docstring describes the fake as a whole).
"""

from __future__ import annotations

import ipaddress
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim_fakes.fake_ur.controller import FakeURConfig
from sim_fakes.fake_ur.kinematics import Q_HOME, SUPPORTED_FAULTS, Arm, pose_to_X
from sim_fakes.fake_ur.server import _serve
from sim_fakes.process_fake import ProcessFake

FloatArray = NDArray[np.float64]


class FakeURController(ProcessFake):
    """Control handle of a fake UR controller process (implements :class:`sim_fakes.faults.FaultInjectable`).

    ``host``: a loopback address (``127.0.0.N``); the fake listens on the standard UR ports there.
    ``model``: "UR5" (default) or "UR5e" (kinematics). ``controller_version``: what RTDE and the dashboard report;
    (3, x, ...) is a CB3 streaming at up to 125 Hz, (5, x, ...) an e-Series at up to 500 Hz.
    ``q_home``: the joint angles (rad) the arm starts at and returns to on :meth:`reset`.
    ``program_start_delay_s``: from a control script's arrival to its start. ``protective_stop_unlock_delay_s``:
    how long after a protective stop the dashboard refuses to unlock it (5 s on a CB3). ``power_on_s`` /
    ``brake_release_s``: how long ``power on`` boots the arm and ``brake release`` takes (seconds on a real arm).
    ``program_stop_outputs_low``: the standard digital outputs the installation's I/O setup drives low when a
    program stops (the arc output of a welding cell; see docs/controller-watchdogs.md).

    Use as a context manager or call :meth:`start` / :meth:`stop`.
    """

    supported_faults = SUPPORTED_FAULTS

    def __init__(
        self,
        host: str = "127.0.0.21",
        *,
        model: str = "UR5",
        controller_version: tuple[int, int, int, int] = (3, 15, 8, 106339),
        q_home: Sequence[float] = Q_HOME,
        program_start_delay_s: float = 0.05,
        protective_stop_unlock_delay_s: float = 5.0,
        power_on_s: float = 0.5,
        brake_release_s: float = 0.5,
        program_stop_outputs_low: Sequence[int] = (),
        startup_timeout_s: float = 30.0,
        request_timeout_s: float = 10.0,
    ) -> None:
        if not ipaddress.ip_address(host).is_loopback:
            raise ValueError(f"the fake UR only serves on loopback addresses (127.0.0.N), got {host!r}")
        Arm(model)  # refuse an unknown model here rather than in the child process
        if len(q_home) != 6:
            raise ValueError(f"q_home needs 6 joint angles in radians, got {len(q_home)}")
        self.cfg = FakeURConfig(
            host=host,
            model=model,
            controller_version=tuple(controller_version),  # type: ignore[arg-type]
            q_home=tuple(float(v) for v in q_home),
            program_start_delay_s=program_start_delay_s,
            protective_stop_unlock_delay_s=protective_stop_unlock_delay_s,
            power_on_s=power_on_s,
            brake_release_s=brake_release_s,
            program_stop_outputs_low=tuple(int(i) for i in program_stop_outputs_low),
        )
        if any(not 0 <= i < 8 for i in self.cfg.program_stop_outputs_low):
            raise ValueError(f"program_stop_outputs_low: standard outputs are 0-7, got {program_stop_outputs_low}")
        super().__init__(
            _serve,
            (self.cfg,),
            label=f"fake UR at {host}",
            startup_timeout_s=startup_timeout_s,
            request_timeout_s=request_timeout_s,
        )

    @property
    def host(self) -> str:
        return self.cfg.host

    # FaultInjectable
    def inject(self, fault: str, **params: Any) -> None:
        if fault not in SUPPORTED_FAULTS:
            raise ValueError(f"fault {fault!r} not supported by the fake UR; choose from {sorted(SUPPORTED_FAULTS)}")
        self._request("inject", fault, params)

    def clear_faults(self) -> None:
        self._request("clear")

    def reset(self) -> None:
        """Back to the initial state: home pose, no faults or latched stops, no program, outputs off, log empty."""
        self._request("reset")

    # what the fake saw and is doing
    def snapshot(self) -> dict[str, Any]:
        """Current state: ``X_base_tool`` (4x4 list), ``q``, ``moving``, ``program_running``, safety, outputs."""
        return dict(self._request("snapshot"))

    def X_base_tool(self) -> FloatArray:
        return np.asarray(self.snapshot()["X_base_tool"], dtype=np.float64)

    def events(self) -> list[dict[str, Any]]:
        """Everything the fake was commanded, in order (``kind``: move_linear, path, stop, digital_output, ...)."""
        return list(self._request("log")["events"])

    def errors(self) -> list[str]:
        """Script errors and programs the fake refused or could not run."""
        return list(self._request("log")["errors"])

    def programs(self) -> list[tuple[str, str]]:
        """The last five URScript programs received on the script ports, as (name, text)."""
        return [(name, text) for name, text in self._request("programs")]

    def commanded_targets(self) -> list[FloatArray]:
        """Every commanded tool target (4x4 ``X_base_tool``): moveL targets and path waypoints, in order."""
        targets: list[FloatArray] = []
        for event in self.events():
            if event["kind"] == "move_linear":
                targets.append(pose_to_X(event["pose"]))
            elif event["kind"] == "path":
                targets.extend(pose_to_X(pose) for pose in event["poses"])
        return targets

    def io_changes(self) -> list[tuple[int, bool]]:
        """Every standard digital output write as (index, value), in order."""
        return [(e["index"], e["value"]) for e in self.events() if e["kind"] == "digital_output"]

    def set_digital_input(self, index: int, value: bool) -> None:
        """Drive standard digital input ``index`` (0-7) as a sensor would."""
        if not 0 <= index < 8:
            raise ValueError(f"standard digital inputs are 0-7, got {index}")
        self._request("set_digital_input", index, value)
