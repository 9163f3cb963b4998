"""The FANUC Remote Motion Interface's wire format (R912, manual B-84184EN): one home for the client
(:mod:`drivers.fanuc_rmi`, :mod:`drivers.fanuc`) and the fake controller (:mod:`sim_fakes.fake_fanuc`).

One JSON object per packet, terminated by ``"\\r\\n"``; the handshake port; the ``ErrorID`` codes; the replies the
client reads (``FRC_GetStatus``, ``FRC_ReadCartesianPosition``) and the one instruction it sends
(``FRC_LinearMotion``). Units are the controller's: millimetres, degrees, mm/s.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, Literal

from drivers.errors import DriverError, MotionRejected, RMIError

RMI_CONNECT_PORT = 16001
"""The well-known port of the RMI handshake (the session port comes from the controller)."""

MAX_INSTRUCTIONS_IN_FLIGHT = 8
"""RMI buffers at most 8 TP instructions that have been sent but not yet answered."""

TERMINATOR = b"\r\n"
MAX_PACKET_BYTES = 1 << 16

Packet = dict[str, Any]
TermType = Literal["FINE", "CNT"]


class ErrorID(IntEnum):
    """RMI ``ErrorID`` values used by weldcell.

    Every ``RMIT-0nn`` alarm is reported as ``2556928 + nn`` (the RMI facility code 39 times 65536 plus the
    alarm number; the table in the RMI manual's appendix, reproduced by several public clients). All values
    below follow that rule; none is invented.
    """

    OK = 0
    INTERNAL_SYSTEM_ERROR = 2556929  # RMIT-001
    INVALID_UTOOL_NUMBER = 2556930  # RMIT-002
    INVALID_UFRAME_NUMBER = 2556931  # RMIT-003
    SERVO_OFF = 2556935  # RMIT-007 Controller Servo is Off
    TP_ENABLED = 2556936  # RMIT-008 Teach Pendant is Enabled
    NOT_RUNNING = 2556937  # RMIT-009 RMI is Not Running
    CANNOT_RESUME = 2556939  # RMIT-011 Cannot Resume TP program
    CANNOT_RESET = 2556940  # RMIT-012 Cannot Reset Controller
    INVALID_COMMAND = 2556941  # RMIT-013 Invalid RMI Command
    INVALID_CONTROLLER_STATE = 2556943  # RMIT-015 Invalid Controller State
    INVALID_INSTRUCTION = 2556948  # RMIT-020 Invalid RMI Instruction
    INVALID_VALUE = 2556949  # RMIT-021 Invalid Value
    INVALID_POSITION_DATA = 2556951  # RMIT-023 Invalid Position Data
    HOLD = 2556952  # RMIT-024 RMI is In HOLD State
    ALREADY_CONNECTED = 2556954  # RMIT-026 Robot is Already Connected
    WAIT_FOR_COMMAND_DONE = 2556955  # RMIT-027
    WAIT_FOR_INSTRUCTION_DONE = 2556956  # RMIT-028 (a 9th instruction in flight)
    INVALID_SEQUENCE_ID = 2556957  # RMIT-029 (a gap in the SequenceIDs; RMI enters HOLD)
    INVALID_SPEED_TYPE = 2556958  # RMIT-030
    INVALID_SPEED_VALUE = 2556959  # RMIT-031
    INVALID_TERM_TYPE = 2556960  # RMIT-032
    INVALID_TERM_VALUE = 2556961  # RMIT-033
    INVALID_DESTINATION = 2556964  # RMIT-036 Invalid Destination Position
    INVALID_PORT_NUMBER = 2556966  # RMIT-038
    INVALID_GROUP_MASK = 2556968  # RMIT-040


def describe_error_id(code: int) -> str:
    """``"RMIT-028 WAIT_FOR_INSTRUCTION_DONE"`` for a known code, ``"ErrorID 1234"`` otherwise."""
    try:
        known = ErrorID(code)
    except ValueError:
        return f"ErrorID {code}"
    if known >= ErrorID.INTERNAL_SYSTEM_ERROR:
        return f"RMIT-{known - 2556928:03d} {known.name}"
    return known.name


class RMIMotionRejected(RMIError, MotionRejected):
    """An instruction refused for its content (pose, speed, termination): both an RMIError with the ErrorID
    and a MotionRejected, so callers can catch either."""


REJECTION_CODES = frozenset(
    {
        ErrorID.INVALID_UTOOL_NUMBER,
        ErrorID.INVALID_UFRAME_NUMBER,
        ErrorID.INVALID_POSITION_DATA,
        ErrorID.INVALID_SPEED_TYPE,
        ErrorID.INVALID_SPEED_VALUE,
        ErrorID.INVALID_TERM_TYPE,
        ErrorID.INVALID_TERM_VALUE,
        ErrorID.INVALID_DESTINATION,
    }
)


@dataclass(frozen=True)
class RMIStatus:
    """The reply to ``FRC_GetStatus``.

    ``rmi_motion_status`` / ``program_status``: 0 not running, 1 running, 2 paused.
    ``emergency_stop`` / ``protective_stop`` come from the optional fields ``"EmergencyStop"`` and
    ``"ProtectiveStop"``: weldcell's fake reports them, a real controller does not (they read False there, and
    a safety stop shows only as ``servo_ready`` False).
    """

    servo_ready: bool
    tp_mode: int
    rmi_motion_status: int
    program_status: int
    single_step_mode: bool
    next_sequence_id: int
    override_percent: int
    emergency_stop: bool = False
    protective_stop: bool = False
    raw: Mapping[str, Any] = field(default_factory=dict, compare=False)

    @property
    def rmi_running(self) -> bool:
        return self.rmi_motion_status == 1

    @classmethod
    def from_reply(cls, reply: Mapping[str, Any]) -> RMIStatus:
        try:
            return cls(
                servo_ready=bool(int(reply["ServoReady"])),
                tp_mode=int(reply["TPMode"]),
                rmi_motion_status=int(reply["RMIMotionStatus"]),
                program_status=int(reply.get("ProgramStatus", 0)),
                single_step_mode=bool(int(reply.get("SingleStepMode", 0))),
                next_sequence_id=int(reply.get("NextSequenceID", 0)),
                override_percent=int(reply.get("Override", 100)),
                emergency_stop=bool(int(reply.get("EmergencyStop", 0))),
                protective_stop=bool(int(reply.get("ProtectiveStop", 0))),
                raw=dict(reply),
            )
        except (KeyError, TypeError, ValueError) as err:
            raise DriverError(f"FRC_GetStatus reply is malformed ({err!r}): {reply}") from err


POSITION_KEYS = ("X", "Y", "Z", "W", "P", "R")
"""The fields of a ``Position`` object, in order (mm, mm, mm, deg, deg, deg)."""
DEFAULT_CONFIGURATION: Mapping[str, int] = {
    "UToolNumber": 1,
    "UFrameNumber": 0,
    "Front": 1,
    "Up": 1,
    "Left": 0,
    "Flip": 0,
    "Turn4": 0,
    "Turn5": 0,
    "Turn6": 0,
}


@dataclass(frozen=True)
class CartesianPosition:
    """The reply to ``FRC_ReadCartesianPosition``: ``xyzwpr_mm_deg`` is (6,) ``[X, Y, Z, W, P, R]``
    in mm and degrees, in the active user frame; ``configuration`` is the arm configuration dict."""

    xyzwpr_mm_deg: tuple[float, ...]
    configuration: Mapping[str, int]
    time_tag: int = 0

    @classmethod
    def from_reply(cls, reply: Mapping[str, Any]) -> CartesianPosition:
        try:
            pos = reply["Position"]
            xyzwpr = tuple(float(pos[k]) for k in POSITION_KEYS)
            config = {k: int(v) for k, v in dict(reply.get("Configuration", {})).items()}
        except (KeyError, TypeError, ValueError) as err:
            raise DriverError(f"FRC_ReadCartesianPosition reply is malformed ({err!r}): {reply}") from err
        return cls(xyzwpr_mm_deg=xyzwpr, configuration=config, time_tag=int(reply.get("TimeTag", 0)))


@dataclass(frozen=True)
class LinearMotion:
    """One ``FRC_LinearMotion`` TP instruction, in controller units.

    ``xyzwpr_mm_deg``: (6,) target in mm / degrees (FANUC fixed-axis W, P, R). ``speed_mm_s``: 1..65535
    (the field is an unsigned 16-bit integer). ``term_type`` FINE (stop at the point) or CNT with
    ``term_value`` 0..100 (corner rounding).
    """

    xyzwpr_mm_deg: tuple[float, ...]
    speed_mm_s: int
    term_type: TermType = "FINE"
    term_value: int = 0
    configuration: Mapping[str, int] = field(default_factory=lambda: dict(DEFAULT_CONFIGURATION))

    def __post_init__(self) -> None:
        if len(self.xyzwpr_mm_deg) != 6:
            raise ValueError(f"xyzwpr_mm_deg needs 6 values, got {len(self.xyzwpr_mm_deg)}")
        if not 1 <= self.speed_mm_s <= 65535:
            raise ValueError(f"speed_mm_s must be 1..65535 (uint16 on the wire), got {self.speed_mm_s}")
        if self.term_type not in ("FINE", "CNT"):
            raise ValueError(f"term_type must be 'FINE' or 'CNT', got {self.term_type!r}")
        if not 0 <= self.term_value <= 100:
            raise ValueError(f"term_value must be 0..100, got {self.term_value}")

    def packet(self, sequence_id: int) -> Packet:
        position: dict[str, float] = {
            k: round(float(v), 4) for k, v in zip(POSITION_KEYS, self.xyzwpr_mm_deg, strict=True)
        }
        position.update({"Ext1": 0.0, "Ext2": 0.0, "Ext3": 0.0})
        return {
            "Instruction": "FRC_LinearMotion",
            "SequenceID": sequence_id,
            "Configuration": dict(self.configuration),
            "Position": position,
            "SpeedType": "mmSec",
            "Speed": int(self.speed_mm_s),
            "TermType": self.term_type,
            "TermValue": int(self.term_value),
        }


def instructions_for_path(
    xyzwpr_mm_deg_path: Iterable[Sequence[float]],
    *,
    speed_mm_s: int,
    cnt_value: int,
    configuration: Mapping[str, int],
) -> list[LinearMotion]:
    """Linear instructions through every pose; CNT ``cnt_value`` between them (FINE when 0), FINE at the end."""
    poses = [tuple(float(v) for v in p) for p in xyzwpr_mm_deg_path]
    out: list[LinearMotion] = []
    for i, pose in enumerate(poses):
        last = i == len(poses) - 1
        term: TermType = "FINE" if last or cnt_value <= 0 else "CNT"
        out.append(
            LinearMotion(
                pose,
                speed_mm_s=speed_mm_s,
                term_type=term,
                term_value=0 if term == "FINE" else cnt_value,
                configuration=configuration,
            )
        )
    return out
