"""sim_fakes/fanuc_program.py: the fake FANUC's queued moves, instruction records and packet reading."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from sim_fakes.fanuc_program import HeartbeatProgram, Segment, instruction_record, parse_packet


def test_a_segment_lasts_its_distance_over_its_speed_or_its_turn_over_the_rotation_limit() -> None:
    seg = Segment(1, "FRC_LinearMotion", np.array([100.0, 0.0, 0.0]), Rotation.from_euler("z", 90, degrees=True),
                  speed_mm_s=50.0, term_type="FINE")  # fmt: skip
    seg.begin(np.zeros(3), Rotation.identity(), max_rotation_speed_deg_s=180.0)
    assert seg.duration_s == 2.0  # 100 mm at 50 mm/s; the 90 degree turn alone would take 0.5 s
    p, R = seg.pose_at(0.5)
    np.testing.assert_allclose(p, [50.0, 0.0, 0.0])
    assert math.isclose(R.magnitude(), math.radians(45.0))
    slow_turn = Segment(2, "FRC_LinearMotion", np.zeros(3), Rotation.from_euler("x", 90, degrees=True),
                        speed_mm_s=50.0, term_type="CNT")  # fmt: skip
    slow_turn.begin(np.zeros(3), Rotation.identity(), max_rotation_speed_deg_s=30.0)
    assert math.isclose(slow_turn.duration_s, 3.0)


def test_packets_are_read_and_recorded_with_nan_for_what_is_missing() -> None:
    assert parse_packet(b'{"Command": "FRC_GetStatus"}\r\n') == {"Command": "FRC_GetStatus"}
    assert parse_packet(b"[1, 2]\r\n") is None and parse_packet(b"{not json\r\n") is None
    msg = {"Position": {"X": 1.5, "Y": 2, "Z": "3"}, "Speed": 100, "SpeedType": "mmSec", "TermType": "FINE"}
    record = instruction_record("FRC_LinearMotion", 4, msg, 0, 2, 1.25)
    assert record.xyzwpr_mm_deg[:2] == (1.5, 2.0) and all(math.isnan(v) for v in record.xyzwpr_mm_deg[2:])
    assert (record.speed, record.term_type, record.term_value, record.in_flight) == (100.0, "FINE", -1, 2)
    assert HeartbeatProgram() == HeartbeatProgram(90, 0.3, (1,))
