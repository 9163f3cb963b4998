"""The Universal Robots controller's wire format, as ur-rtde and the controller see it: one home for the driver
(:mod:`drivers.ur`) and the fake controller (:mod:`sim_fakes.fake_ur`).

Ports, the RTDE state values (``robot_mode``, ``safety_mode``, ``runtime_state``), the bits of
``safety_status_bits`` / ``robot_status_bits``, and the command numbers of ur-rtde 1.6's control script
(``rtde_control.script``, ``RTDE::RobotCommand::Type``). Values are the controller's (RTDE guide, "Real-time Data
Exchange (RTDE) Guide", and ur-rtde's ``robot_state.h``).
"""

from __future__ import annotations

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORTS = (30001, 30002, 30003)
"""Primary, secondary and real-time client ports: each accepts a URScript program (ur-rtde uploads to 30003)."""
ALL_PORTS = (DASHBOARD_PORT, *SCRIPT_PORTS, RTDE_PORT)
"""Every port a UR controller (and the fake) listens on, at one address."""

# RTDE robot_mode values
ROBOT_MODE_BOOTING = 2
ROBOT_MODE_POWER_OFF = 3
ROBOT_MODE_POWER_ON = 4
ROBOT_MODE_IDLE = 5
ROBOT_MODE_RUNNING = 7
ROBOT_MODE_NAMES = {
    -1: "NO_CONTROLLER",
    0: "DISCONNECTED",
    1: "CONFIRM_SAFETY",
    2: "BOOTING",
    3: "POWER_OFF",
    4: "POWER_ON",
    5: "IDLE",
    6: "BACKDRIVE",
    7: "RUNNING",
    8: "UPDATING_FIRMWARE",
}

# RTDE safety_mode values
SAFETY_MODE_NORMAL = 1
SAFETY_MODE_PROTECTIVE_STOP = 3
SAFETY_MODE_ROBOT_EMERGENCY_STOP = 7
SAFETY_MODE_NAMES = {1: "NORMAL", 3: "PROTECTIVE_STOP", 7: "ROBOT_EMERGENCY_STOP"}

# bits of safety_status_bits
SAFETY_BIT_NORMAL = 0
SAFETY_BIT_PROTECTIVE_STOPPED = 2
SAFETY_BIT_SAFEGUARD_STOPPED = 4
SAFETY_BIT_SYSTEM_EMERGENCY_STOPPED = 5
SAFETY_BIT_ROBOT_EMERGENCY_STOPPED = 6
SAFETY_BIT_EMERGENCY_STOPPED = 7
SAFETY_BIT_VIOLATION = 8
SAFETY_BIT_FAULT = 9
SAFETY_BIT_STOPPED_DUE_TO_SAFETY = 10
ESTOP_MASK = (
    (1 << SAFETY_BIT_EMERGENCY_STOPPED)
    | (1 << SAFETY_BIT_ROBOT_EMERGENCY_STOPPED)
    | (1 << SAFETY_BIT_SYSTEM_EMERGENCY_STOPPED)
)
PROTECTIVE_MASK = (1 << SAFETY_BIT_PROTECTIVE_STOPPED) | (1 << SAFETY_BIT_SAFEGUARD_STOPPED)

# bits of robot_status_bits
ROBOT_BIT_POWER_ON = 0
ROBOT_BIT_PROGRAM_RUNNING = 1

# runtime_state values
RUNTIME_STOPPED = 1
RUNTIME_PLAYING = 2
RUNTIME_PAUSED = 4

JOINT_MODE_RUNNING = 253

# ur-rtde control-script commands (RTDE::RobotCommand::Type) and its handshake values
CMD_NO_CMD = 0
CMD_MOVEL = 3
CMD_SET_PAYLOAD = 17
CMD_PROTECTIVE_STOP = 31
CMD_STOPL = 33
CMD_STOPJ = 34
CMD_SET_WATCHDOG = 35
CMD_MOVE_PATH = 45
CMD_STOP_SCRIPT = 255
READY_FOR_CMD = 1
DONE_WITH_CMD = 2

# dashboard replies (the same text on CB3 and e-Series)
REPLY_UNLOCKED = "Protective stop releasing"
REPLY_UNLOCK_TOO_EARLY = "Cannot unlock protective stop"
REPLY_POWERING_ON = "Powering on"
REPLY_BRAKE_RELEASING = "Brake releasing"
