"""drivers/fanuc_protocol.py: RMI packets, replies and error codes, against the values of the R912 manual."""

from __future__ import annotations

import pytest

from drivers.errors import DriverError
from drivers.fanuc_protocol import (
    DEFAULT_CONFIGURATION,
    REJECTION_CODES,
    TERMINATOR,
    CartesianPosition,
    ErrorID,
    LinearMotion,
    RMIStatus,
    describe_error_id,
    instructions_for_path,
)


def test_error_ids_are_named_as_the_pendant_shows_them() -> None:
    assert describe_error_id(2556956) == "RMIT-028 WAIT_FOR_INSTRUCTION_DONE"
    assert describe_error_id(int(ErrorID.INVALID_SEQUENCE_ID)) == "RMIT-029 INVALID_SEQUENCE_ID"
    assert describe_error_id(1234) == "ErrorID 1234"
    assert ErrorID.INVALID_SPEED_VALUE in REJECTION_CODES and ErrorID.HOLD not in REJECTION_CODES


def test_a_linear_motion_packet_carries_the_pose_speed_and_termination() -> None:
    motion = LinearMotion((500.0, 1.23456, 400.0, 180.0, 0.0, -90.0), speed_mm_s=250, term_type="CNT", term_value=40)
    packet = motion.packet(7)
    assert packet == {
        "Instruction": "FRC_LinearMotion",
        "SequenceID": 7,
        "Configuration": dict(DEFAULT_CONFIGURATION),
        "Position": {"X": 500.0, "Y": 1.2346, "Z": 400.0, "W": 180.0, "P": 0.0, "R": -90.0, "Ext1": 0.0,
                     "Ext2": 0.0, "Ext3": 0.0},
        "SpeedType": "mmSec",
        "Speed": 250,
        "TermType": "CNT",
        "TermValue": 40,
    }  # fmt: skip
    assert TERMINATOR == b"\r\n"
    for bad, match in (
        (dict(speed_mm_s=0), "1..65535"),
        (dict(speed_mm_s=65536), "1..65535"),
        (dict(speed_mm_s=10, term_value=101), "0..100"),
    ):
        with pytest.raises(ValueError, match=match):
            LinearMotion((0.0,) * 6, **bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="6 values"):
        LinearMotion((0.0,) * 5, speed_mm_s=10)


def test_a_path_blends_between_its_poses_and_stops_fine_at_the_last() -> None:
    poses = [(500.0 + i, 0.0, 400.0, 180.0, 0.0, 0.0) for i in range(3)]
    blended = instructions_for_path(poses, speed_mm_s=100, cnt_value=50, configuration=DEFAULT_CONFIGURATION)
    assert [(m.term_type, m.term_value) for m in blended] == [("CNT", 50), ("CNT", 50), ("FINE", 0)]
    assert [m.xyzwpr_mm_deg[0] for m in blended] == [500.0, 501.0, 502.0]
    fine = instructions_for_path(poses, speed_mm_s=100, cnt_value=0, configuration=DEFAULT_CONFIGURATION)
    assert {m.term_type for m in fine} == {"FINE"}


def test_replies_are_read_into_values_and_a_malformed_one_is_a_driver_error() -> None:
    status = RMIStatus.from_reply(
        {"ServoReady": 1, "TPMode": 0, "RMIMotionStatus": 1, "NextSequenceID": 12, "ProtectiveStop": 1}
    )
    assert (status.servo_ready, status.rmi_running, status.next_sequence_id, status.protective_stop) == (
        True,
        True,
        12,
        True,
    )
    assert (status.override_percent, status.emergency_stop) == (100, False)
    with pytest.raises(DriverError, match="FRC_GetStatus reply is malformed"):
        RMIStatus.from_reply({"ServoReady": 1})
    position = CartesianPosition.from_reply(
        {"Position": {"X": 1, "Y": 2, "Z": 3, "W": 180, "P": 0, "R": 90}, "Configuration": {"Front": 1}, "TimeTag": 5}
    )
    assert position == CartesianPosition((1.0, 2.0, 3.0, 180.0, 0.0, 90.0), {"Front": 1}, 5)
    with pytest.raises(DriverError, match="FRC_ReadCartesianPosition reply is malformed"):
        CartesianPosition.from_reply({"Position": {"X": 1}})
