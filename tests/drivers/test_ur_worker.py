"""drivers/ur_worker.py: the RTDE state sample as the UR driver reads it, and the lazy ur-rtde import."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from drivers.errors import DriverNotInstalled
from drivers.ur_worker import RECEIVE_VARIABLES, Status, import_ur_rtde


def status(**changes: object) -> Status:
    fields: dict[str, object] = dict(
        X_base_tool=np.eye(4),
        tcp_speed=(0.0,) * 6,
        robot_mode=7,
        safety_mode=1,
        safety_status_bits=1,
        runtime_state=2,
        digital_output_bits=0,
        async_running=False,
        async_progress=-1,
        control_ready=True,
    )
    fields.update(changes)
    return Status(**fields)  # type: ignore[arg-type]


def test_safety_bits_read_as_stops() -> None:
    assert not status().emergency_stop and not status().protective_stop
    for bit in (5, 6, 7):  # system, robot, plain emergency stop
        assert status(safety_status_bits=1 << bit).emergency_stop
    for bit in (2, 4):  # protective, safeguard stop
        st = status(safety_status_bits=1 << bit)
        assert st.protective_stop and not st.emergency_stop
    assert not status(safety_status_bits=1 << 3).protective_stop  # bit 3 (recovery mode) is neither


def test_moving_means_above_0_1_mm_s_or_1_mrad_s_and_playing_means_runtime_state_2() -> None:
    assert not status(tcp_speed=(9e-5, 0.0, 0.0, 0.0, 0.0, 9e-4)).moving
    assert status(tcp_speed=(0.0, 1.1e-4, 0.0, 0.0, 0.0, 0.0)).moving
    assert status(tcp_speed=(0.0, 0.0, 0.0, 0.0, 0.0, 1.1e-3)).moving
    assert status().program_running and not status(runtime_state=4).program_running


def test_the_receive_recipe_and_a_missing_ur_rtde(monkeypatch: pytest.MonkeyPatch) -> None:
    assert RECEIVE_VARIABLES[0] == "timestamp" and "actual_digital_output_bits" in RECEIVE_VARIABLES
    monkeypatch.setitem(sys.modules, "rtde_control", None)  # an import of it now raises ImportError
    with pytest.raises(DriverNotInstalled, match=r"pip install 'ur-rtde>=1.5.8,<2'"):
        import_ur_rtde()
