"""What the fake FANUC controller (:mod:`sim_fakes.fake_fanuc`) holds besides its sockets: the integrator's
heartbeat program, the record of each instruction received, a queued linear move and how packets are read.

Units are the controller's: mm, degrees, mm/s; rotations are scipy Rotations.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from drivers.fanuc_protocol import POSITION_KEYS, Packet


@dataclass(frozen=True)
class HeartbeatProgram:
    """The integrator's ``WC_HBEAT`` watchdog as installed on the controller: ``register`` (``R[n]``) is the host's
    heartbeat, ``timeout_s`` how long it may stand still, ``arc_ports`` the ``DO[..]`` switched OFF on a trip."""

    register: int = 90
    timeout_s: float = 0.3
    arc_ports: tuple[int, ...] = (1,)


@dataclass(frozen=True)
class InstructionRecord:
    """One TP instruction as the fake received it (device units), with the ErrorID it was answered with
    at once (0 when it was accepted into the buffer) and the number in flight just after it arrived."""

    sequence_id: int
    instruction: str
    xyzwpr_mm_deg: tuple[float, ...]
    speed: float
    speed_type: str
    term_type: str
    term_value: int
    error_id: int
    in_flight: int
    received_s: float


@dataclass
class Segment:
    """A queued linear move: positions in mm, rotations as scipy Rotations."""

    seq: int
    instruction: str
    p_target_mm: NDArray[np.float64]
    R_target: Rotation
    speed_mm_s: float
    term_type: str
    p_start_mm: NDArray[np.float64] | None = None
    R_start: Rotation | None = None
    rotvec_delta: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    duration_s: float = 0.0
    elapsed_s: float = 0.0

    def begin(self, p_mm: NDArray[np.float64], R: Rotation, *, max_rotation_speed_deg_s: float) -> None:
        self.p_start_mm = p_mm.copy()
        self.R_start = R
        self.rotvec_delta = (R.inv() * self.R_target).as_rotvec()
        distance_mm = float(np.linalg.norm(self.p_target_mm - p_mm))
        angle_deg = float(np.degrees(np.linalg.norm(self.rotvec_delta)))
        self.duration_s = max(distance_mm / self.speed_mm_s, angle_deg / max_rotation_speed_deg_s)

    def pose_at(self, fraction: float) -> tuple[NDArray[np.float64], Rotation]:
        assert self.p_start_mm is not None and self.R_start is not None
        p = self.p_start_mm + fraction * (self.p_target_mm - self.p_start_mm)
        return p, self.R_start * Rotation.from_rotvec(fraction * self.rotvec_delta)


def parse_packet(line: bytes) -> Packet | None:
    """The JSON object of one packet line, or None when it is not one."""
    try:
        msg = json.loads(line)
    except json.JSONDecodeError:
        return None
    return msg if isinstance(msg, dict) else None


def instruction_record(
    name: str, seq: int, msg: Packet, error: int, in_flight: int, received_s: float
) -> InstructionRecord:
    pos = msg.get("Position") if isinstance(msg.get("Position"), dict) else {}
    assert isinstance(pos, dict)
    xyzwpr = tuple(_as_float(pos.get(k)) for k in POSITION_KEYS)
    term_value = msg.get("TermValue", -1)
    return InstructionRecord(
        sequence_id=seq,
        instruction=name,
        xyzwpr_mm_deg=xyzwpr,
        speed=_as_float(msg.get("Speed")),
        speed_type=str(msg.get("SpeedType", "")),
        term_type=str(msg.get("TermType", "")),
        term_value=int(term_value) if isinstance(term_value, int) else -1,
        error_id=error,
        in_flight=in_flight,
        received_s=received_s,
    )


def _as_float(value: object) -> float:
    return float(value) if isinstance(value, int | float) else float("nan")
