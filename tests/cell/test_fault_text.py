"""cell.fault_text: the state machine's fault reasons, as the machine, the watchdog and the daemon write them, told
to an operator in one sentence with the cause and what to do."""

from __future__ import annotations

import pytest

from cell.fault_text import explain_fault


@pytest.mark.parametrize(
    ("reason", "sentence_starts", "cause"),
    [
        (
            "watchdog: robot: protective stop (Robot: protective stop is active)",
            "The robot stopped itself (protective stop)",
            "Robot: protective stop (Robot: protective stop is active).",
        ),
        (
            "advance failed in welding: ProtectiveStop: UR5: protective stop during movel",
            "The robot stopped itself (protective stop)",
            "UR5: protective stop during movel.",
        ),
        (
            "watchdog: robot: emergency stop (E-stop pressed)",
            "The emergency stop is active",
            "Robot: emergency stop (E-stop pressed).",
        ),
        (
            "watchdog: track: fault latched (code 7) at 0.1200 m",
            "The track drive reported a fault",
            "Track: fault latched (code 7) at 0.1200 m.",
        ),
        (
            "watchdog: robot unreachable: ConnectionLost: socket closed",
            "The cell lost contact with a device",
            "Robot unreachable: ConnectionLost: socket closed.",
        ),
        (
            "watchdog: no status from the robot or the track within 0.6 s",
            "The cell lost contact with a device",
            "No status from the robot or the track within 0.6 s.",
        ),
        (
            "unclean stop: job 4 was running when the previous daemon stopped; check the torch and the part, then "
            "acknowledge (POST /acknowledge)",
            "The previous daemon stopped while a job was running",
            "Unclean stop: job 4 was running when the previous daemon stopped; check the torch and the part, then "
            "acknowledge (POST /acknowledge).",
        ),
        (
            "advance failed in detecting: NoSeamFound: no seam in any capture: capture 1: no depth",
            "No seam to weld was found",
            "No seam in any capture: capture 1: no depth.",
        ),
        (
            "advance failed in planning: SafetyViolation: pass 2 waypoint 5 leaves the workspace box",
            "The safety check refused the planned path",
            "Pass 2 waypoint 5 leaves the workspace box.",
        ),
        (
            "SIGTERM: the daemon is stopping (then advance failed in welding: MotionAborted: motion aborted)",
            "The cell service was stopped while a job was running",
            "SIGTERM: the daemon is stopping.",
        ),
        (
            "advance failed in capturing: ValueError: frame 3 is empty",
            "The cell stopped because of an error",
            "Frame 3 is empty.",
        ),
    ],
)
def test_each_kind_of_fault_gets_its_sentence_and_the_first_cause(reason: str, sentence_starts: str, cause: str):
    text = explain_fault(reason)
    assert text is not None
    assert text.sentence.startswith(sentence_starts) and text.sentence.endswith(".")
    assert text.sentence.count(". ") == 0  # one sentence
    assert text.cause == cause
    assert "Acknowledge" in text.action and text.stop_failed is False


def test_a_stop_that_was_not_confirmed_says_so_and_asks_for_the_welder_switch():
    reason = "watchdog: robot: protective stop (x); stopping failed: arc_off: not confirmed within 0.5 s"
    text = explain_fault(reason)
    assert text is not None and text.stop_failed is True
    assert text.sentence == (
        "The robot stopped itself (protective stop), and the stop or the arc-off was not confirmed by the robot."
    )
    lost = explain_fault("watchdog: no status from the robot or the track within 0.6 s; stopping failed: x")
    assert lost is not None
    assert lost.sentence == (
        "The cell lost contact with a device, and the stop or the arc-off was not confirmed by the robot."
    )
    assert text.cause == "Robot: protective stop (x)."
    assert text.action.startswith("Switch the welder off at its own switch")


def test_no_reason_is_no_fault():
    assert explain_fault(None) is None and explain_fault("  ") is None
