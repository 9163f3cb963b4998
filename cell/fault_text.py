"""A cell fault told to an operator: one sentence saying what happened, its cause and what to do.

The state machine's fault reason is written for the journal: ``advance failed in welding: ProtectiveStop: ...``,
``watchdog: robot: protective stop (...)``, with ``(then ...)`` and ``; stopping failed: ...`` appended when more
went wrong. :func:`explain_fault` reads it (the first cause is what the operator must deal with) into
:class:`FaultText`; the full reason stays available next to it.
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from typing import Any

_ACK = "then press Acknowledge"


@dataclass(frozen=True)
class FaultText:
    """``sentence``: what happened, in one sentence; ``cause``: the device's or the check's own words;
    ``action``: what the operator does about it; ``stop_failed``: the stop or the arc-off was not confirmed."""

    sentence: str
    cause: str
    action: str
    stop_failed: bool = False

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


_RULES: list[tuple[re.Pattern[str], str, str]] = [
    (
        re.compile(r"emergency stop", re.I),
        "The emergency stop is active: the robot stopped and the arc is off.",
        "Make the cell safe, release the emergency stop and reset it on the controller, " + _ACK + ".",
    ),
    (
        re.compile(r"protective stop", re.I),
        "The robot stopped itself (protective stop): the arm is still and the arc is off.",
        "Look for a collision of the torch with the part or the fixture, clear the stop on the robot's pendant "
        "if it asks, " + _ACK + ".",
    ),
    (
        re.compile(r"track.*fault latched|TrackFault", re.I),
        "The track drive reported a fault and stopped the carriage.",
        "Check the track for an obstruction or a tripped limit switch, " + _ACK + " (it resets the drive).",
    ),
    (
        re.compile(r"unreachable|ConnectionLost|DeviceTimeout|no status from|not answer|timed out|timeout", re.I),
        "The cell lost contact with a device, so it stopped the motion and switched the arc off.",
        "Check the device's power and its network cable, " + _ACK + " (it reconnects before anything moves).",
    ),
    (
        re.compile(r"unclean stop", re.I),
        "The previous daemon stopped while a job was running; the torch may still stand on the part.",
        "Check the torch and the part, move the robot clear by hand if needed, " + _ACK + ".",
    ),
    (
        re.compile(r"NoSeamFound|no seam", re.I),
        "No seam to weld was found in the captures, so nothing was welded.",
        "Check that the part sits on the fixture in the camera's view and the job's [seams] filter, "
        + _ACK
        + " and submit the job again.",
    ),
    (
        re.compile(r"SafetyViolation|workspace|reach|exceeds|safety", re.I),
        "The safety check refused the planned path, so nothing was welded.",
        "Check where the part lies against the cell's workspace and the job's speeds, " + _ACK + " and submit "
        "the job again.",
    ),
    (
        re.compile(r"daemon is stopping", re.I),
        "The cell service was stopped while a job was running; the motion was stopped and the arc switched off.",
        "Check the torch and the part, " + _ACK + ".",
    ),
]

_PREFIX = re.compile(r"^(?:watchdog:\s*|\w+ failed in [a-z_]+:\s*)")
_EXC = re.compile(r"^([A-Z][A-Za-z]+(?:Error|Stop|Fault|Lost|Timeout|Found|Violation|Aborted)):\s*")


def explain_fault(reason: str | None) -> FaultText | None:
    """The operator's view of a fault ``reason`` (None: no fault)."""
    if reason is None or not reason.strip():
        return None
    first, _, _later = reason.partition(" (then ")
    stop_failed = "stopping failed" in reason
    first = first.split("; stopping failed:")[0].strip()
    cause = _PREFIX.sub("", first)
    exc = _EXC.match(cause)
    kind = exc.group(1) if exc else ""
    cause = cause[exc.end() :] if exc else cause
    probe = f"{kind} {cause}"
    sentence, action = next(
        ((sentence, action) for pattern, sentence, action in _RULES if pattern.search(probe)),
        (
            "The cell stopped because of an error: the motion was stopped and the arc switched off.",
            "Read the cause below and the job's journal (GET /jobs/{id}), fix it, " + _ACK + ".",
        ),
    )
    if stop_failed:  # the rule's sentence says the arm is still and the arc off: that is not known here
        what = re.split(r":|;|, so ", sentence, maxsplit=1)[0].rstrip(".")
        sentence = what + ", and the stop or the arc-off was not confirmed by the robot."
        action = "Switch the welder off at its own switch and check the robot first; " + action
    return FaultText(sentence=sentence, cause=_capital(cause.strip().rstrip(".")) + ".", action=action,
                     stop_failed=stop_failed)  # fmt: skip


def _capital(text: str) -> str:
    return text[:1].upper() + text[1:]
