"""drivers/ur_protocol.py: the UR wire values the driver and the fake share, against the RTDE guide's numbers."""

from __future__ import annotations

from drivers import ur_protocol as wire


def test_the_ports_of_one_controller() -> None:
    assert (wire.DASHBOARD_PORT, wire.SCRIPT_PORTS, wire.RTDE_PORT) == (29999, (30001, 30002, 30003), 30004)
    assert wire.ALL_PORTS == (29999, 30001, 30002, 30003, 30004)


def test_safety_status_masks_name_the_guide_bits() -> None:
    # bits 5, 6, 7: system, robot and plain emergency stop; bits 2 and 4: protective and safeguard stop
    assert wire.ESTOP_MASK == 0b1110_0000 == 224
    assert wire.PROTECTIVE_MASK == 0b1_0100 == 20
    assert wire.ESTOP_MASK & wire.PROTECTIVE_MASK == 0
    assert (wire.SAFETY_BIT_VIOLATION, wire.SAFETY_BIT_FAULT, wire.SAFETY_BIT_STOPPED_DUE_TO_SAFETY) == (8, 9, 10)


def test_robot_modes_and_runtime_states() -> None:
    named = {wire.ROBOT_MODE_NAMES[m] for m in (2, 3, 4, 5, 7)}
    assert named == {"BOOTING", "POWER_OFF", "POWER_ON", "IDLE", "RUNNING"}
    assert (wire.ROBOT_MODE_BOOTING, wire.ROBOT_MODE_POWER_OFF, wire.ROBOT_MODE_IDLE, wire.ROBOT_MODE_RUNNING) == (
        2,
        3,
        5,
        7,
    )
    assert (wire.RUNTIME_STOPPED, wire.RUNTIME_PLAYING, wire.RUNTIME_PAUSED) == (1, 2, 4)
    assert wire.SAFETY_MODE_NAMES[wire.SAFETY_MODE_PROTECTIVE_STOP] == "PROTECTIVE_STOP"


def test_control_script_commands_of_ur_rtde_1_6() -> None:
    commands = (wire.CMD_MOVEL, wire.CMD_STOPL, wire.CMD_SET_WATCHDOG, wire.CMD_MOVE_PATH, wire.CMD_STOP_SCRIPT)
    assert commands == (3, 33, 35, 45, 255)
    assert (wire.READY_FOR_CMD, wire.DONE_WITH_CMD) == (1, 2)
