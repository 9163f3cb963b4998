"""A fake Universal Robots controller that speaks the real protocols on a loopback address.

The fake runs in its own process (ur-rtde's C++ client holds the GIL while it waits, so it cannot share a process
with the code under test) and serves, on ``host`` (``127.0.0.N``, so several fakes can run side by side):

- RTDE on port 30004 (protocol versions 1 and 2): version negotiation, controller version, output and input recipes
  (types from UR's RTDE guide, ``NOT_FOUND`` for unknown names), start/pause, and data packages streamed at the
  requested frequency (at most 125 Hz for a CB3, 500 Hz for an e-Series). Input data packages write the input
  registers and the IO fields (``standard_digital_output_mask``/``standard_digital_output``, speed slider...).
- the dashboard server on port 29999 (the commands ur-rtde sends; unknown ones answer ``could not understand``).
  ``pause`` holds the running control script and its motion until ``play``; ``load`` records a .urp name but the
  fake cannot run .urp files, so ``play`` of one fails as on a controller that cannot start it.
- the script ports 30001-30003, which accept URScript programs (``def name(): ... end``). The fake does not
  interpret URScript: it recognises ur-rtde's control script (``def rtde_control():``), reads its register offsets
  and the move path ur-rtde injects into it, and emulates its register handshake: command in
  ``input_int_register_0``, parameters in the input registers, ``output_int_register_0`` = 1 ready / 2 done, and
  the async progress word in ``output_int_register_2``. moveL (blocking and asynchronous), moveL/movePath paths,
  stopL/stopJ, stopScript, setPayload, triggerProtectiveStop and setWatchdog are emulated; any other command stops
  the program with an entry in :meth:`FakeURController.errors` (as a script runtime error would on a real controller).
  Programs other than the control script are recorded but not run. The fake does not stream the
  primary/secondary/real-time client state messages on 30001-30003.

Motion: the tool moves in straight lines at the commanded speed under the commanded acceleration (trapezoidal
speed profile along the path, orientation slerped with the travelled fraction); a rotation counts as the arc of a
point 0.1 m from the tool centre. Blended waypoints are passed without stopping (speed carries through, corners
are not rounded); the path ends exactly on its last pose. Joint angles follow from the UR5 (or UR5e) DH model by
damped-least-squares inverse kinematics every cycle, and a target whose straight-line path has no inverse
kinematics solution stops the control script (ur-rtde then reports the command as failed).

Frames and units: poses are UR pose vectors ``[x, y, z, rx, ry, rz]`` (metres, rotation vector in radians) of the
tool in the robot base frame; ``X_base_tool`` arrays are 4x4 in metres. Times are seconds.

Host watchdog (what a real controller does with ur-rtde's control script; see docs/controller-watchdogs.md):
``setWatchdog(f)`` makes the script call ``rtde_set_watchdog("input_int_register_0", f, "stop")``: when no RTDE
input package updates that register for 1/f s (ur-rtde's ``kickWatchdog`` sends one), the program stops, the arm
decelerates to a stop and every watchdog is removed. A program stop (the watchdog, ``stopScript``, a new script
replacing the running one, a safety stop) drives the outputs of ``program_stop_outputs_low`` low, as PolyScope's
I/O setup does for outputs whose program-stop action is "low". The event log records ``rtde_watchdog`` (with how
long the register was silent) and each output the stop switched off (``digital_output`` with a ``cause``).

Faults (:class:`sim_fakes.faults.FaultInjectable`): ``drop_connection`` closes every client connection and the
listening sockets (new connections are refused until cleared; the robot keeps running), ``no_answer`` cuts the
controller off the network (connections stay open, nothing is received, answered or streamed; the controller
itself runs on, so its watchdogs see the host's silence), ``protective_stop`` and ``emergency_stop``
halt motion at once and stop the program; an emergency stop also cuts the arm's power (robot mode POWER_OFF).
``clear_faults()`` lifts the network faults and releases the emergency stop button; the stops stay latched as on a
real controller: a protective stop until the dashboard's ``unlock protective stop`` (accepted
``protective_stop_unlock_delay_s`` after the stop, 5 s on a real CB3), an emergency stop until the arm is powered
up again. Powering up takes time, as on a real arm: ``power on`` (refused while the button is pressed) boots the
arm (robot mode BOOTING for ``power_on_s``, then IDLE), ``brake release`` releases the brakes (IDLE for
``brake_release_s``, then RUNNING; sent to an arm that is powered off or still booting, it powers on first). No
program runs until the robot mode is RUNNING, so the ur-rtde control script must be uploaded again afterwards.
``reset()`` returns the fake to its initial state.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import math
import multiprocessing
import re
import signal
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from sim_fakes import rtde_wire as wire

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORTS = (30001, 30002, 30003)

# RTDE robot_mode values
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
}
ROBOT_MODE_BOOTING = 2
ROBOT_MODE_POWER_OFF = 3
ROBOT_MODE_IDLE = 5
ROBOT_MODE_RUNNING = 7
# RTDE safety_mode values
SAFETY_MODE_NORMAL = 1
SAFETY_MODE_PROTECTIVE_STOP = 3
SAFETY_MODE_ROBOT_EMERGENCY_STOP = 7
SAFETY_MODE_NAMES = {1: "NORMAL", 3: "PROTECTIVE_STOP", 7: "ROBOT_EMERGENCY_STOP"}
# bits of safety_status_bits and robot_status_bits
SAFETY_BIT_NORMAL = 0
SAFETY_BIT_PROTECTIVE_STOPPED = 2
SAFETY_BIT_ROBOT_EMERGENCY_STOPPED = 6
SAFETY_BIT_EMERGENCY_STOPPED = 7
SAFETY_BIT_STOPPED_DUE_TO_SAFETY = 10
ROBOT_BIT_POWER_ON = 0
ROBOT_BIT_PROGRAM_RUNNING = 1
# runtime_state values
RUNTIME_STOPPED = 1
RUNTIME_PLAYING = 2
RUNTIME_PAUSED = 4
JOINT_MODE_RUNNING = 253

# ur-rtde control-script commands (RTDE::RobotCommand::Type) the fake emulates, and the realtime ones it does not
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

SUPPORTED_FAULTS = frozenset({"drop_connection", "no_answer", "protective_stop", "emergency_stop"})

ROT_RADIUS_M = 0.1  # a rotation of θ rad counts as 0.1·θ m of path
_GRAVITY_M_S2 = 9.81

# DH parameters (d, a) in metres; alpha is the same for both models
_DH: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "UR5": ((0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823), (0.0, -0.425, -0.39225, 0.0, 0.0, 0.0)),
    "UR5e": ((0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996), (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)),
}
_DH_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
Q_HOME = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)


# --------------------------------------------------------------------------------------------- rotations


def _vee(M: FloatArray) -> FloatArray:
    return np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])


def log_so3(R: FloatArray) -> FloatArray:
    """Rotation vector (3,) in radians of the (3, 3) rotation ``R``; angle in [0, π]."""
    c = min(1.0, max(-1.0, (float(np.trace(R)) - 1.0) / 2.0))
    angle = math.acos(c)
    if angle < 1e-9:
        return 0.5 * _vee(R)
    if math.pi - angle < 1e-5:
        return np.asarray(Rotation.from_matrix(R).as_rotvec(), dtype=np.float64)
    return angle / (2.0 * math.sin(angle)) * _vee(R)


def exp_so3(w: FloatArray) -> FloatArray:
    """(3, 3) rotation of the rotation vector ``w`` (radians), by Rodrigues' formula."""
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.eye(3)
    k = w / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def ur_pose(p: FloatArray, R: FloatArray) -> list[float]:
    """UR pose vector ``[x, y, z, rx, ry, rz]`` of position ``p`` (m) and rotation ``R``."""
    return [*map(float, p), *map(float, log_so3(R))]


def pose_to_X(pose: Sequence[float]) -> FloatArray:
    X = np.eye(4)
    X[:3, :3] = exp_so3(np.asarray(pose[3:6], dtype=np.float64))
    X[:3, 3] = pose[:3]
    return X


# --------------------------------------------------------------------------------------------- kinematics


class Arm:
    """Forward and inverse kinematics of a UR arm from its DH parameters (``model``: "UR5" or "UR5e")."""

    def __init__(self, model: str) -> None:
        if model not in _DH:
            raise ValueError(f"unknown robot model {model!r}; the fake knows {sorted(_DH)}")
        self.d, self.a = _DH[model]

    def chain(self, q: FloatArray) -> list[FloatArray]:
        """The 7 frames (4, 4) from the base to the tool flange for joint angles ``q`` (6,) in radians."""
        T = np.eye(4)
        frames = [T]
        for i in range(6):
            ct, st = math.cos(q[i]), math.sin(q[i])
            ca, sa = math.cos(_DH_ALPHA[i]), math.sin(_DH_ALPHA[i])
            A = np.array(
                [
                    [ct, -st * ca, st * sa, self.a[i] * ct],
                    [st, ct * ca, -ct * sa, self.a[i] * st],
                    [0.0, sa, ca, self.d[i]],
                    [0.0, 0.0, 0.0, 1.0],
                ]
            )
            T = T @ A
            frames.append(T)
        return frames

    def fk(self, q: FloatArray) -> FloatArray:
        return self.chain(q)[-1]

    def solve(
        self, X_target: FloatArray, q_seed: FloatArray, *, max_iter: int, tol: float = 1e-10
    ) -> tuple[FloatArray, float]:
        """Joint angles near ``q_seed`` reaching ``X_target`` (damped least squares); returns (q, residual).

        The residual is the norm of [position error (m), rotation error (rad)].
        """
        q = np.array(q_seed, dtype=np.float64)
        for _ in range(max_iter + 1):
            frames = self.chain(q)
            T = frames[-1]
            e = np.concatenate([X_target[:3, 3] - T[:3, 3], log_so3(X_target[:3, :3] @ T[:3, :3].T)])
            residual = float(np.linalg.norm(e))
            if residual < tol:
                return q, residual
            J = np.zeros((6, 6))
            p_end = T[:3, 3]
            for i in range(6):
                z = frames[i][:3, 2]
                J[:3, i] = np.cross(z, p_end - frames[i][:3, 3])
                J[3:, i] = z
            dq = J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), e)
            q += dq / max(1.0, float(np.abs(dq).max()) / 0.3)
        return q, residual


# --------------------------------------------------------------------------------------------- motion


@dataclass
class Segment:
    """A straight tool move from (p0, R0) to (p1, R1); ``length`` in the path metric (m), speed m/s, accel m/s²."""

    p0: FloatArray
    p1: FloatArray
    R0: FloatArray
    w: FloatArray  # rotation vector of R0ᵀ R1, so R(f) = R0 exp(f w)
    length: float
    speed: float
    accel: float
    blend: float
    waypoint: int
    stop: bool = True  # the tool stops at the end of this segment
    to_stop: float = 0.0  # path length from this segment's end to the next stop, m
    v_exit: float = 0.0  # the speed this segment may end with (a slower next segment lowers it), m/s

    def pose_at(self, s: float) -> tuple[FloatArray, FloatArray]:
        f = 1.0 if self.length <= 0.0 else min(1.0, max(0.0, s / self.length))
        return self.p0 + f * (self.p1 - self.p0), self.R0 @ exp_so3(f * self.w)


@dataclass(frozen=True)
class Waypoint:
    """A commanded tool pose (UR pose vector) with its speed (m/s), acceleration (m/s²) and blend radius (m)."""

    pose: tuple[float, ...]
    speed: float
    accel: float
    blend: float


def build_segments(p: FloatArray, R: FloatArray, waypoints: Sequence[Waypoint]) -> list[Segment]:
    segments: list[Segment] = []
    for i, wp in enumerate(waypoints):
        X = pose_to_X(wp.pose)
        p1, R1 = X[:3, 3], X[:3, :3]
        w = log_so3(R.T @ R1)
        length = max(float(np.linalg.norm(p1 - p)), ROT_RADIUS_M * float(np.linalg.norm(w)))
        segments.append(Segment(p, p1, R, w, length, wp.speed, wp.accel, wp.blend, i))
        p, R = p1, R1
    # backward pass: where the next stop is, and the speed each segment may end with
    for i in range(len(segments) - 1, -1, -1):
        seg = segments[i]
        seg.stop = i == len(segments) - 1 or seg.blend <= 0.0
        if seg.stop:
            seg.to_stop, seg.v_exit = 0.0, 0.0
        else:
            nxt = segments[i + 1]
            seg.to_stop = nxt.length + nxt.to_stop
            seg.v_exit = min(seg.speed, nxt.speed)
    return segments


def _braking_speed(u: float, v_end: float, distance: float, accel: float, dt: float) -> float:
    """The fastest speed to reach after ``dt`` from speed ``u`` that still brakes to ``v_end`` within ``distance``.

    Solves u_new² = v_end² + 2·a·(distance − (u + u_new)·dt/2): the end of the step lies on the braking curve.
    """
    c = v_end**2 + 2.0 * accel * distance - accel * u * dt
    return 0.5 * (-accel * dt + math.sqrt((accel * dt) ** 2 + 4.0 * c)) if c > 0.0 else 0.0


class Motion:
    """Integrates a list of segments over time; ``on_waypoint(i)`` fires when segment ``i`` is entered."""

    def __init__(self, segments: list[Segment], on_waypoint: Callable[[int], None] | None = None) -> None:
        self.segments = segments
        self.on_waypoint = on_waypoint
        self.on_finished: list[Callable[[str], None]] = []
        self.k = 0
        self.s = 0.0
        self.u = 0.0  # current path speed, m/s
        self.stop_decel: float | None = None
        self.done = not segments
        self.reason = "arrived"
        self._announced = -1

    def request_stop(self, decel_m_s2: float) -> None:
        self.stop_decel = max(decel_m_s2, 1e-3)

    def pose(self) -> tuple[FloatArray, FloatArray]:
        seg = self.segments[min(self.k, len(self.segments) - 1)]
        return seg.pose_at(self.s)

    def _announce(self) -> None:
        if self._announced != self.k and self.on_waypoint is not None and self.k < len(self.segments):
            self._announced = self.k
            self.on_waypoint(self.segments[self.k].waypoint)

    def _finish_segment(self) -> bool:
        """Move past the current segment's end; True when the whole motion is done."""
        seg = self.segments[self.k]
        self.s = seg.length
        if self.k == len(self.segments) - 1:
            self.done = True
            self.u = 0.0
            return True
        if seg.stop:
            self.u = 0.0
        self.k += 1
        self.s = 0.0
        self._announce()
        return False

    def step(self, dt: float) -> None:
        if self.done:
            return
        self._announce()
        while self.segments[self.k].length <= 1e-12:
            if self._finish_segment():
                return
        seg = self.segments[self.k]
        if self.stop_decel is not None:
            u_new = max(0.0, self.u - self.stop_decel * dt)
        else:
            a = seg.accel
            remaining = max(seg.length - self.s, 0.0)
            u_new = min(seg.speed, self.u + a * dt, _braking_speed(self.u, 0.0, remaining + seg.to_stop, a, dt))
            if seg.v_exit < seg.speed and not seg.stop:  # slow down for a slower next segment
                u_new = min(u_new, _braking_speed(self.u, seg.v_exit, remaining, a, dt))
            u_new = max(0.0, u_new)
        dist = 0.5 * (self.u + u_new) * dt
        self.u = u_new
        while dist > 0.0 and not self.done:
            seg = self.segments[self.k]
            left = seg.length - self.s
            if dist < left - 1e-12:
                self.s += dist
                dist = 0.0
            else:
                dist -= left
                stop_here = seg.stop
                if self._finish_segment():
                    break
                if stop_here:
                    break
        if self.stop_decel is not None and self.u <= 0.0 and not self.done:
            self.done = True
            self.reason = "stopped"


# --------------------------------------------------------------------------------------------- control script

_INJECTED_MOVE = re.compile(
    r"^\t(movel|movej|movep)\((p?)\[([^\]]*)\],a=([^,]+),v=([^,]+),r=([^)]+)\)\s*$",
)
_PROGRESS = re.compile(r"^\tsignal_async_progress\((\d+)\)\s*$")


def parse_injected_path(script: str) -> tuple[list[Waypoint], str]:
    """The path ur-rtde injects after ``# inject move path`` in its control script, and an error ('' if none)."""
    marker = script.find("# inject move path\n")
    if marker < 0:
        return [], ""
    lines = script[marker + len("# inject move path\n") :].split("\n")
    path: list[Waypoint] = []
    for line in lines:
        if not line.startswith("\t"):
            break
        if _PROGRESS.match(line):
            continue
        m = _INJECTED_MOVE.match(line)
        if m is None:
            return [], f"injected path line not understood: {line.strip()!r}"
        kind, is_pose = m.group(1), m.group(2) == "p"
        if kind == "movej" or not is_pose:
            return [], f"{kind} with {'a pose' if is_pose else 'joint angles'} in a path is not emulated"
        values = tuple(float(v) for v in m.group(3).split(","))
        if len(values) != 6:
            return [], f"path pose needs 6 numbers, got {m.group(3)!r}"
        path.append(Waypoint(values, float(m.group(5)), float(m.group(4)), float(m.group(6))))
    return path, ""


class ControlScript:
    """Emulates the register handshake of ur-rtde's control script (``def rtde_control():``)."""

    # commands the real script processes every cycle without the done handshake (servo, speed, force...)
    REALTIME = frozenset({6, 9, 10, 11, 24, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})

    def __init__(self, text: str, start_at: float) -> None:
        # ur-rtde injects the offset on the line after "global reg_offset_int = # int register offset"
        m_int = re.search(r"global reg_offset_int\s*=\s*(?:#[^\n]*)?\s*(\d+)", text)
        m_float = re.search(r"global reg_offset_float\s*=\s*(?:#[^\n]*)?\s*(\d+)", text)
        self.off_int = int(m_int.group(1)) if m_int else 0
        self.off_float = int(m_float.group(1)) if m_float else 0
        self.path, self.path_error = parse_injected_path(text)
        self.start_at = start_at
        self.started = False
        self.executing = False
        self.blocking: Callable[[], bool] | None = None
        self.async_wr_count = 0
        self.async_op_id = 0
        self.async_motion: Motion | None = None

    # registers as the script sees them (with its offsets)
    def in_int(self, ctl: Controller, i: int) -> int:
        return int(ctl.regs[f"input_int_register_{self.off_int + i}"])

    def in_double(self, ctl: Controller, i: int) -> float:
        return float(ctl.regs[f"input_double_register_{self.off_float + i}"])

    def signal(self, ctl: Controller, value: int) -> None:
        ctl.regs[f"output_int_register_{self.off_int}"] = value

    def write_async(self, ctl: Controller, value: int) -> None:
        """The async progress word: op id (bits 24-30), write count (16-23), running (15), progress (0-14)."""
        self.async_wr_count = (self.async_wr_count + 1) % 128
        if value == 0:
            self.async_op_id = (self.async_op_id + 1) % 128
        reg = self.async_wr_count * 65536 + self.async_op_id * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        ctl.regs[f"output_int_register_{self.off_int + 2}"] = reg

    def step(self, ctl: Controller) -> None:
        if not self.started:
            if ctl.now() < self.start_at:
                return
            self.started = True
            ctl.runtime_state = RUNTIME_PLAYING
            self.write_async(ctl, -1)  # reset_async_progress()
        if self.blocking is not None:
            if self.blocking():
                return
            self.blocking = None
            self.signal(ctl, DONE_WITH_CMD)
            return
        cmd = self.in_int(ctl, 0)
        if cmd == CMD_NO_CMD:
            self.executing = False
            self.signal(ctl, READY_FOR_CMD)
            return
        if self.executing:
            return
        self.executing = True
        self.process(ctl, cmd)

    def _kill_async(self, ctl: Controller) -> None:
        if self.async_motion is not None:
            self.async_motion = None
            self.write_async(ctl, -1)

    def _run(self, ctl: Controller, motion: Motion, asynchronous: bool) -> None:
        if asynchronous:
            self.async_motion = motion

            def finished(_reason: str) -> None:
                if self.async_motion is motion and ctl.program is self:  # a stopped script writes nothing
                    self.async_motion = None
                    self.write_async(ctl, -1)

            motion.on_finished.append(finished)
            self.signal(ctl, DONE_WITH_CMD)
        else:
            self.blocking = lambda: ctl.motion is motion and not motion.done

    def process(self, ctl: Controller, cmd: int) -> None:
        if cmd == CMD_MOVEL:
            pose = tuple(self.in_double(ctl, i) for i in range(6))
            speed, accel = self.in_double(ctl, 6), self.in_double(ctl, 7)
            asynchronous = self.in_int(ctl, 1) != 0
            ctl.record("move_linear", pose=list(pose), speed=speed, accel=accel, asynchronous=asynchronous)
            self._move(ctl, [Waypoint(pose, speed, accel, 0.0)], asynchronous, progress=False)
        elif cmd == CMD_MOVE_PATH:
            asynchronous = self.in_int(ctl, 1) != 0
            ctl.record(
                "path",
                poses=[list(w.pose) for w in self.path],
                speeds=[w.speed for w in self.path],
                accels=[w.accel for w in self.path],
                blends=[w.blend for w in self.path],
                asynchronous=asynchronous,
            )
            if self.path_error or not self.path:
                ctl.halt_program(f"movePath: {self.path_error or 'no path was injected into the control script'}")
                return
            self._move(ctl, self.path, asynchronous, progress=True)
        elif cmd in (CMD_STOPL, CMD_STOPJ):
            decel = self.in_double(ctl, 0)
            asynchronous = self.in_int(ctl, 1) != 0
            ctl.record("stop", decel=decel, asynchronous=asynchronous, joint=cmd == CMD_STOPJ)
            self._kill_async(ctl)
            motion = ctl.motion
            if motion is None:
                self.signal(ctl, DONE_WITH_CMD)
                return
            motion.request_stop(decel if cmd == CMD_STOPL else decel * ROT_RADIUS_M * 10.0)
            if asynchronous:
                self.write_async(ctl, 0)
                self._run(ctl, motion, asynchronous=True)
            else:
                self._run(ctl, motion, asynchronous=False)
        elif cmd == CMD_STOP_SCRIPT:
            ctl.record("stop_script")
            ctl.stop_program("stopScript")
        elif cmd == CMD_PROTECTIVE_STOP:
            ctl.record("trigger_protective_stop")
            ctl.protective_stop("triggerProtectiveStop()")
        elif cmd == CMD_SET_WATCHDOG:
            # the script: rtde_set_watchdog("input_int_register_<0 | 24>", read_input_float_reg(0), "stop")
            variable = f"input_int_register_{24 if self.off_int == 24 else 0}"
            min_frequency_hz = self.in_double(ctl, 0)
            ctl.record("set_watchdog", variable=variable, min_frequency_hz=min_frequency_hz, action="stop")
            ctl.set_rtde_watchdog(variable, min_frequency_hz, "stop")
            self.signal(ctl, DONE_WITH_CMD)
        elif cmd == CMD_SET_PAYLOAD:
            mass = self.in_double(ctl, 0)
            cog = [self.in_double(ctl, i) for i in (1, 2, 3)]
            ctl.record("set_payload", mass=mass, cog=cog)
            ctl.payload_kg = mass
            if any(cog):
                ctl.payload_cog_m = cog
            self.signal(ctl, DONE_WITH_CMD)
        else:
            kind = "realtime " if cmd in self.REALTIME else ""
            ctl.halt_program(f"{kind}control-script command {cmd} is not emulated by fake_ur")

    def _move(self, ctl: Controller, waypoints: list[Waypoint], asynchronous: bool, *, progress: bool) -> None:
        bad = [w for w in waypoints if not (w.speed > 0.0 and w.accel > 0.0)]
        if bad:
            ctl.halt_program(f"move with speed {bad[0].speed} m/s and acceleration {bad[0].accel} m/s^2")
            return
        segments = build_segments(ctl.p, ctl.R, waypoints)
        problem = ctl.check_reachable(segments)
        if problem:
            ctl.halt_program(problem)
            return
        self._kill_async(ctl)
        if asynchronous:
            self.write_async(ctl, 0)

        def on_waypoint(i: int) -> None:
            if ctl.program is self and (self.async_motion is motion or not asynchronous):
                self.write_async(ctl, i)

        motion = ctl.start_motion(segments, on_waypoint if progress else None)
        self._run(ctl, motion, asynchronous)
        if not asynchronous and progress:

            def path_done(_reason: str) -> None:
                if ctl.program is self:
                    self.write_async(ctl, -1)

            motion.on_finished.append(path_done)


# --------------------------------------------------------------------------------------------- controller model


@dataclass(frozen=True)
class FakeURConfig:
    """Everything the fake process needs; see :class:`FakeURController` for the meaning of each field."""

    host: str
    model: str = "UR5"
    controller_version: tuple[int, int, int, int] = (3, 15, 8, 106339)
    q_home: tuple[float, ...] = Q_HOME
    rtde_port: int = RTDE_PORT
    dashboard_port: int = DASHBOARD_PORT
    script_ports: tuple[int, ...] = SCRIPT_PORTS
    program_start_delay_s: float = 0.05
    protective_stop_unlock_delay_s: float = 5.0
    power_on_s: float = 0.5
    brake_release_s: float = 0.5
    serial_number: str = "2018300001"
    program_stop_outputs_low: tuple[int, ...] = ()

    @property
    def rate_hz(self) -> float:
        return 500.0 if self.controller_version[0] >= 5 else 125.0


@dataclass
class ControllerLog:
    events: list[dict[str, Any]] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    programs: list[tuple[str, str]] = field(default_factory=list)  # the last few (name, URScript text)


class Controller:
    """The robot controller's state: arm, safety, program, registers and IO. No networking."""

    def __init__(self, cfg: FakeURConfig) -> None:
        self.cfg = cfg
        self.arm = Arm(cfg.model)
        self.t0 = time.monotonic()
        self.reset()

    def now(self) -> float:
        return time.monotonic() - self.t0

    def reset(self) -> None:
        self.q = np.array(self.cfg.q_home, dtype=np.float64)
        X = self.arm.fk(self.q)
        self.p = X[:3, 3].copy()
        self.R = X[:3, :3].copy()
        self.qd = np.zeros(6)
        self.tcp_speed = np.zeros(6)
        self.elbow = self.arm.chain(self.q)[3][:3, 3].copy()
        self.elbow_speed = np.zeros(3)
        self.regs: dict[str, Any] = {}
        for name, rtde_type in wire.OUTPUT_TYPES.items():
            if "register" in name:
                self.regs[name] = False if rtde_type == "BOOL" else (0.0 if rtde_type == "DOUBLE" else 0)
        self.robot_mode = ROBOT_MODE_RUNNING
        self.booted_at: float | None = None  # when a power-on in progress ends (BOOTING -> IDLE)
        self.released_at: float | None = None  # when a brake release in progress ends (IDLE -> RUNNING)
        self.release_after_boot = False  # "brake release" arrived while the arm was powered off or booting
        self.protective = False
        self.protective_since = 0.0
        self.estop_pressed = False
        self.estop_latched = False
        self.program: ControlScript | None = None
        self.program_name = ""
        self.loaded_program = ""
        self.runtime_state = RUNTIME_STOPPED
        self.motion: Motion | None = None
        self.digital_out = 0
        self.digital_in = 0
        self.analog_out = [0.0, 0.0]
        self.speed_fraction = 1.0
        self.payload_kg = 0.0
        self.payload_cog_m = [0.0, 0.0, 0.0]
        self.external_wrench = [0.0] * 6
        # rtde_set_watchdog: variable -> (min frequency Hz, action, controller time of its last update)
        self.rtde_watchdogs: dict[str, tuple[float, str, float]] = {}
        self.log = ControllerLog()

    def record(self, kind: str, **data: Any) -> None:
        self.log.events.append({"kind": kind, "t": round(self.now(), 4), **data})

    # ------------------------------------------------------------------ safety and program
    def safety_status_bits(self) -> int:
        if self.estop_latched:
            return (
                (1 << SAFETY_BIT_ROBOT_EMERGENCY_STOPPED)
                | (1 << SAFETY_BIT_EMERGENCY_STOPPED)
                | (1 << SAFETY_BIT_STOPPED_DUE_TO_SAFETY)
            )
        if self.protective:
            return (1 << SAFETY_BIT_PROTECTIVE_STOPPED) | (1 << SAFETY_BIT_STOPPED_DUE_TO_SAFETY)
        return 1 << SAFETY_BIT_NORMAL

    def safety_mode(self) -> int:
        if self.estop_latched:
            return SAFETY_MODE_ROBOT_EMERGENCY_STOP
        if self.protective:
            return SAFETY_MODE_PROTECTIVE_STOP
        return SAFETY_MODE_NORMAL

    def robot_status_bits(self) -> int:
        bits = 1 << ROBOT_BIT_POWER_ON if self.robot_mode >= 4 else 0
        if self.runtime_state == RUNTIME_PLAYING:
            bits |= 1 << ROBOT_BIT_PROGRAM_RUNNING
        return bits

    def can_run(self) -> str:
        """Why a program cannot run now ('' when it can)."""
        if self.estop_latched:
            return "emergency stop is active"
        if self.protective:
            return "protective stop is active"
        if self.robot_mode != ROBOT_MODE_RUNNING:
            return f"robot mode is {ROBOT_MODE_NAMES.get(self.robot_mode, self.robot_mode)}"
        return ""

    def run_program(self, name: str, text: str) -> None:
        """A complete ``def name(): ... end`` program arrived on a script port."""
        self.stop_program(f"replaced by program {name!r}")
        self.record("program", name=name, chars=len(text))
        self.log.programs = [*self.log.programs[-4:], (name, text)]
        why_not = self.can_run()
        if why_not:
            self.log.errors.append(f"program {name!r} not started: {why_not}")
            return
        if name != "rtde_control":
            self.log.errors.append(f"program {name!r} received but not run: fake_ur only emulates rtde_control")
            return
        self.program = ControlScript(text, self.now() + self.cfg.program_start_delay_s)
        self.program_name = name

    def stop_program(self, reason: str) -> None:
        if self.program is None and self.runtime_state == RUNTIME_STOPPED:
            return
        if self.runtime_state == RUNTIME_PAUSED and self.motion is not None:
            self.hard_stop()  # a paused arm is standing still already
        log.debug("program stopped: %s", reason)
        self.program = None
        self.runtime_state = RUNTIME_STOPPED
        self.rtde_watchdogs.clear()  # "all watchdogs are removed on program stop" (URScript manual)
        if self.motion is not None:
            self.motion.request_stop(10.0)
        # the installation's I/O setup: outputs configured to go low when the program stops
        for index in self.cfg.program_stop_outputs_low:
            if self.digital_out >> index & 1:
                self.digital_out &= ~(1 << index)
                self.record("digital_output", index=index, value=False, cause=f"program stop ({reason})")

    def set_rtde_watchdog(self, variable: str, min_frequency_hz: float, action: str) -> None:
        """URScript ``rtde_set_watchdog(variable, min_frequency, action)``: when no RTDE input package updates
        ``variable`` for 1/min_frequency s, ``action`` ("ignore" | "pause" | "stop") is taken."""
        if min_frequency_hz <= 0.0:
            self.rtde_watchdogs.pop(variable, None)
            return
        self.rtde_watchdogs[variable] = (min_frequency_hz, action, self.now())

    def check_rtde_watchdogs(self) -> None:
        now = self.now()
        for variable, (frequency, action, last) in list(self.rtde_watchdogs.items()):
            silent_s = now - last
            if silent_s <= 1.0 / frequency or action == "ignore":
                continue
            self.record("rtde_watchdog", variable=variable, silent_s=round(silent_s, 4), action=action)
            if action == "pause" and self.runtime_state == RUNTIME_PLAYING:
                self.runtime_state = RUNTIME_PAUSED
                self.hard_stop()
            else:
                self.stop_program(f"RTDE watchdog: {variable} not updated for {silent_s:.3f} s")

    def halt_program(self, error: str) -> None:
        """A script runtime error: the program stops and the error is kept."""
        self.log.errors.append(error)
        self.record("script_error", message=error)
        self.stop_program(error)

    def hard_stop(self) -> None:
        if self.motion is not None:
            motion, self.motion = self.motion, None
            motion.done = True
            motion.reason = "halted"
            for callback in motion.on_finished:
                callback("halted")
        self.tcp_speed = np.zeros(6)
        self.qd = np.zeros(6)

    def protective_stop(self, reason: str) -> None:
        if self.estop_latched:
            return
        self.record("protective_stop", reason=reason)
        self.protective = True
        self.protective_since = self.now()
        self.stop_program(f"protective stop ({reason})")
        self.hard_stop()

    def emergency_stop(self) -> None:
        self.record("emergency_stop")
        self.estop_pressed = True
        self.estop_latched = True
        self.protective = False
        self.stop_program("emergency stop")
        self.hard_stop()
        self.power_off()

    def power_off(self) -> None:
        """The arm's power is cut (an emergency stop, ``power off``...): any power-up in progress is abandoned."""
        self.robot_mode = ROBOT_MODE_POWER_OFF
        self.booted_at = self.released_at = None
        self.release_after_boot = False

    def power_on(self) -> str:
        """Dashboard ``power on``: boot a powered-off arm (refused while the emergency stop button is pressed)."""
        if self.estop_pressed:
            return "Failed to execute: power on"
        if self.robot_mode == ROBOT_MODE_POWER_OFF:
            self.estop_latched = False  # the button is released: powering on resets the emergency stop
            self.robot_mode = ROBOT_MODE_BOOTING
            self.booted_at = self.now() + self.cfg.power_on_s
            self.record("power_on")
        return "Powering on"

    def brake_release(self) -> str:
        """Dashboard ``brake release``: release the brakes of an idle arm, powering it on first if needed."""
        if self.robot_mode in (ROBOT_MODE_POWER_OFF, ROBOT_MODE_BOOTING):
            if self.power_on() != "Powering on":
                return "Failed to execute: brake release"
            self.release_after_boot = True
        elif self.robot_mode == ROBOT_MODE_IDLE and self.released_at is None:
            self.released_at = self.now() + self.cfg.brake_release_s
            self.record("brake_release")
        return "Brake releasing"

    def advance_power(self) -> None:
        """Finish a power-on or a brake release whose time has come."""
        now = self.now()
        if self.robot_mode == ROBOT_MODE_BOOTING and self.booted_at is not None and now >= self.booted_at:
            self.robot_mode, self.booted_at = ROBOT_MODE_IDLE, None
            self.record("powered_on")
            if self.release_after_boot:
                self.release_after_boot = False
                self.brake_release()
        if self.robot_mode == ROBOT_MODE_IDLE and self.released_at is not None and now >= self.released_at:
            self.robot_mode, self.released_at = ROBOT_MODE_RUNNING, None
            self.record("brakes_released")

    # ------------------------------------------------------------------ motion
    def check_reachable(self, segments: Sequence[Segment]) -> str:
        """'' if every segment has an inverse-kinematics solution along its straight line, else why not."""
        q = self.q
        for seg in segments:
            steps = max(1, math.ceil(seg.length / 0.02))
            for j in range(1, steps + 1):
                p, R = seg.pose_at(seg.length * j / steps)
                X = np.eye(4)
                X[:3, :3], X[:3, 3] = R, p
                q, residual = self.arm.solve(X, q, max_iter=60)
                if residual > 1e-7:
                    return (
                        f"no inverse kinematics solution on the way to waypoint {seg.waypoint} "
                        f"(pose {np.round(ur_pose(seg.p1, seg.R0 @ exp_so3(seg.w)), 4).tolist()})"
                    )
        return ""

    def start_motion(self, segments: list[Segment], on_waypoint: Callable[[int], None] | None) -> Motion:
        if self.motion is not None:
            old, self.motion = self.motion, None
            for callback in old.on_finished:
                callback("replaced")
        self.motion = Motion(segments, on_waypoint)
        return self.motion

    def tick(self, dt: float) -> None:
        self.advance_power()
        self.check_rtde_watchdogs()
        if self.runtime_state == RUNTIME_PAUSED:
            return
        if self.program is not None:
            self.program.step(self)
        p_prev, R_prev, q_prev, elbow_prev = self.p, self.R, self.q, self.elbow
        motion = self.motion
        if motion is not None:
            motion.step(dt * self.speed_fraction)
            p, R = motion.pose()
            X = np.eye(4)
            X[:3, :3], X[:3, 3] = R, p
            q, residual = self.arm.solve(X, self.q, max_iter=12)
            if residual > 1e-6:
                self.protective_stop(f"no joint solution at {np.round(p, 4).tolist()} m (singularity or reach)")
                return
            self.p, self.R, self.q = p.copy(), R.copy(), q
            self.elbow = self.arm.chain(self.q)[3][:3, 3].copy()
            if motion.done and self.motion is motion:
                self.motion = None
                for callback in motion.on_finished:
                    callback(motion.reason)
        if dt > 0.0:
            self.tcp_speed = np.concatenate([(self.p - p_prev) / dt, log_so3(self.R @ R_prev.T) / dt])
            self.qd = (self.q - q_prev) / dt
            self.elbow_speed = (self.elbow - elbow_prev) / dt

    # ------------------------------------------------------------------ RTDE
    def rtde_values(self) -> dict[str, Any]:
        """Every RTDE output variable's current value."""
        zeros6 = (0.0,) * 6
        pose = ur_pose(self.p, self.R)
        q = tuple(map(float, self.q))
        qd = tuple(map(float, self.qd))
        speed = tuple(map(float, self.tcp_speed))
        values: dict[str, Any] = dict(self.regs)
        values.update(
            {
                "timestamp": self.now(),
                "target_q": q,
                "target_qd": qd,
                "target_qdd": zeros6,
                "target_current": zeros6,
                "target_moment": zeros6,
                "actual_q": q,
                "actual_qd": qd,
                "actual_current": zeros6,
                "joint_control_output": zeros6,
                "actual_TCP_pose": pose,
                "actual_TCP_speed": speed,
                "actual_TCP_force": tuple(self.external_wrench),
                "target_TCP_pose": pose,
                "target_TCP_speed": speed,
                "actual_digital_input_bits": self.digital_in,
                "joint_temperatures": (31.0,) * 6,
                "actual_execution_time": 0.3,
                "robot_mode": self.robot_mode,
                "joint_mode": (JOINT_MODE_RUNNING,) * 6,
                "safety_mode": self.safety_mode(),
                "safety_status": self.safety_mode(),
                "actual_tool_accelerometer": tuple(map(float, self.R.T @ np.array([0.0, 0.0, _GRAVITY_M_S2]))),
                "speed_scaling": self.speed_fraction,
                "target_speed_fraction": self.speed_fraction,
                "actual_momentum": 0.0,
                "actual_main_voltage": 48.0,
                "actual_robot_voltage": 48.0,
                "actual_robot_current": 0.6,
                "actual_joint_voltage": (47.5,) * 6,
                "actual_digital_output_bits": self.digital_out,
                "runtime_state": self.runtime_state,
                "elbow_position": tuple(map(float, self.elbow)),
                "elbow_velocity": tuple(map(float, self.elbow_speed)),
                "robot_status_bits": self.robot_status_bits(),
                "safety_status_bits": self.safety_status_bits(),
                "analog_io_types": 0,
                "standard_analog_input0": 0.0,
                "standard_analog_input1": 0.0,
                "standard_analog_output0": self.analog_out[0],
                "standard_analog_output1": self.analog_out[1],
                "io_current": 0.1,
                "tool_mode": 0,
                "tool_analog_input_types": 0,
                "tool_analog_input0": 0.0,
                "tool_analog_input1": 0.0,
                "tool_output_voltage": 0,
                "tool_output_current": 0.0,
                "tool_temperature": 30.0,
                "tcp_force_scalar": 0.0,
                "payload": self.payload_kg,
                "payload_cog": tuple(self.payload_cog_m),
                "payload_inertia": zeros6,
                "script_control_line": 0,
                "ft_raw_wrench": zeros6,
                "joint_position_deviation_ratio": 0.0,
                "collision_detection_ratio": 0.0,
                "time_scale_source": 0,
                "actual_current_as_torque": zeros6,
            }
        )
        return values

    def apply_inputs(self, values: dict[str, Any]) -> None:
        """Apply one input data package: registers, digital/analog outputs, speed slider."""
        now = self.now()
        for name, value in values.items():
            if name in self.regs:
                self.regs[name] = value
            watched = self.rtde_watchdogs.get(name)
            if watched is not None:
                self.rtde_watchdogs[name] = (watched[0], watched[1], now)
        masks = (
            ("standard_digital_output", 0, 8, "digital_output"),
            ("configurable_digital_output", 8, 8, "configurable_digital_output"),
            ("tool_digital_output", 16, 2, "tool_digital_output"),
        )
        for field_name, shift, count, kind in masks:
            mask = values.get(f"{field_name}_mask")
            if not mask:
                continue
            level = int(values.get(field_name, (self.digital_out >> shift) & 0xFF))
            for bit in range(count):
                if mask & (1 << bit):
                    on = bool(level & (1 << bit))
                    if on:
                        self.digital_out |= 1 << (shift + bit)
                    else:
                        self.digital_out &= ~(1 << (shift + bit))
                    self.record(kind, index=bit, value=on)
        if values.get("speed_slider_mask", 0) & 1 and "speed_slider_fraction" in values:
            self.speed_fraction = min(1.0, max(0.0, float(values["speed_slider_fraction"])))
            self.record("speed_slider", fraction=self.speed_fraction)
        analog_mask = values.get("standard_analog_output_mask", 0)
        for i in (0, 1):
            if analog_mask & (1 << i) and f"standard_analog_output_{i}" in values:
                self.analog_out[i] = float(values[f"standard_analog_output_{i}"])
                self.record("analog_output", index=i, value=self.analog_out[i])
        if "external_force_torque" in values:
            self.external_wrench = list(values["external_force_torque"])

    # ------------------------------------------------------------------ dashboard
    def dashboard(self, line: str) -> str:
        cmd = line.strip()
        low = cmd.lower()
        major, minor = self.cfg.controller_version[:2]
        new_dashboard = major == 5 and minor > 5
        if low == "robotmode":
            return f"Robotmode: {ROBOT_MODE_NAMES.get(self.robot_mode, str(self.robot_mode))}"
        if low == "safetystatus":
            return f"Safetystatus: {SAFETY_MODE_NAMES[self.safety_mode()]}"
        if low == "safetymode":
            return f"Safetymode: {SAFETY_MODE_NAMES[self.safety_mode()]}"
        if low == "polyscopeversion":
            v = self.cfg.controller_version
            return f"URSoftware {v[0]}.{v[1]}.{v[2]}.{v[3]} (Jan 01 2024)"
        if low == "is in remote control" and new_dashboard:
            return "true"
        if low == "get serial number" and new_dashboard:
            return self.cfg.serial_number
        if low == "get robot model":
            return self.cfg.model.rstrip("e")
        if low == "running":
            return f"Program running: {'true' if self.runtime_state == RUNTIME_PLAYING else 'false'}"
        if low == "programstate":
            state = "PLAYING" if self.runtime_state == RUNTIME_PLAYING else "STOPPED"
            return f"{state} {self.program_name or self.loaded_program or '<unnamed>'}"
        if low == "get loaded program":
            return f"Loaded program: {self.loaded_program}" if self.loaded_program else "No program loaded"
        if low.startswith("load "):
            self.loaded_program = cmd[5:].strip()
            return f"Loading program: {self.loaded_program}"
        if low == "play":
            if self.runtime_state == RUNTIME_PAUSED and self.program is not None and not self.can_run():
                self.runtime_state = RUNTIME_PLAYING
                return "Starting program"
            self.log.errors.append("dashboard play: fake_ur resumes a paused control script but cannot run .urp files")
            return "Failed to execute: play"
        if low == "stop":
            self.stop_program("dashboard stop")
            return "Stopped"
        if low == "pause":
            if self.runtime_state != RUNTIME_PLAYING:
                return "Failed to execute: pause"
            self.runtime_state = RUNTIME_PAUSED  # the program and its motion hold where they are until play
            self.tcp_speed = np.zeros(6)
            self.qd = np.zeros(6)
            return "Pausing program"
        if low == "unlock protective stop":
            if self.protective and self.now() - self.protective_since < self.cfg.protective_stop_unlock_delay_s:
                delay = self.cfg.protective_stop_unlock_delay_s
                return (
                    f"Cannot unlock protective stop until {delay:g}s after occurrence. "
                    "Always inspect cause of protective stop before unlocking"
                )
            if self.protective:
                self.protective = False
                self.record("protective_stop_unlocked")
            return "Protective stop releasing"
        if low == "close safety popup":
            return "closing safety popup"
        if low == "close popup":
            return "closing popup"
        if low.startswith("popup "):
            return "showing popup"
        if low.startswith("addtolog "):
            return "Added log message"
        if low == "power on":
            return self.power_on()
        if low == "power off":
            self.stop_program("dashboard power off")
            self.hard_stop()
            self.power_off()
            return "Powering off"
        if low == "brake release":
            return self.brake_release()
        if low == "restart safety":  # the safety system restarts with the arm powered off
            self.stop_program("dashboard restart safety")
            self.hard_stop()
            self.protective = False
            self.power_off()
            return "Restarting safety"
        if low == "isprogramsaved":
            return f"true {self.loaded_program or '<unnamed>'}"
        if low.startswith("setuserrole "):
            return "Setting user role: " + cmd.split(" ", 1)[1]
        if low == "quit":
            return "Disconnected"
        if low == "shutdown":  # the fake keeps serving, with the arm powered off and no program
            self.stop_program("dashboard shutdown")
            self.hard_stop()
            self.power_off()
            return "Shutting down"
        return f"could not understand: '{cmd}'"

    # ------------------------------------------------------------------ the handle's view
    def snapshot(self) -> dict[str, Any]:
        return {
            "X_base_tool": pose_to_X(ur_pose(self.p, self.R)).tolist(),
            "q": self.q.tolist(),
            "moving": self.motion is not None,
            "program_running": self.runtime_state == RUNTIME_PLAYING,
            "protective_stop": self.protective,
            "emergency_stop": self.estop_latched,
            "robot_mode": self.robot_mode,
            "safety_mode": self.safety_mode(),
            "digital_outputs": [bool(self.digital_out >> i & 1) for i in range(8)],
            "speed_fraction": self.speed_fraction,
            "timestamp": self.now(),
        }


# --------------------------------------------------------------------------------------------- network


class RtdeSession:
    """One RTDE client connection: its protocol version, recipes and streaming schedule."""

    def __init__(self, writer: asyncio.StreamWriter, cfg: FakeURConfig) -> None:
        self.writer = writer
        self.cfg = cfg
        self.protocol = 1
        self.outputs: list[wire.Recipe] = []
        self.due: list[float] = []
        self.inputs: dict[int, wire.Recipe] = {}
        # output and input recipes are numbered separately, both from 1 (ur-rtde relies on it)
        self.next_output_id = 1
        self.next_input_id = 1
        self.started = False

    def handle(self, msg_type: int, payload: bytes, ctl: Controller, now: float) -> bytes:
        M = wire.MsgType
        if msg_type == M.REQUEST_PROTOCOL_VERSION:
            version = int.from_bytes(payload[:2], "big") if len(payload) >= 2 else 0
            accepted = version in wire.PROTOCOL_VERSIONS
            if accepted:
                self.protocol = version
            return wire.pack_message(msg_type, bytes([int(accepted)]))
        if msg_type == M.GET_URCONTROL_VERSION:
            return wire.pack_message(msg_type, b"".join(v.to_bytes(4, "big") for v in self.cfg.controller_version))
        if msg_type == M.CONTROL_PACKAGE_SETUP_OUTPUTS:
            if self.protocol >= 2:
                frequency = float(np.frombuffer(payload[:8], dtype=">f8")[0]) if len(payload) >= 8 else 0.0
                names = wire.parse_names(payload[8:])
            else:
                frequency, names = self.cfg.rate_hz, wire.parse_names(payload)
            types = [wire.output_type(n, self.cfg.controller_version) for n in names]
            ok = bool(names) and wire.NOT_FOUND not in types and 0.0 < frequency <= self.cfg.rate_hz
            recipe = wire.Recipe.build(self.next_output_id if ok else 0, names, types, frequency)
            if ok:
                self.next_output_id += 1
                self.outputs.append(recipe)
                self.due.append(now)
            else:
                log.debug("output setup refused: %s at %s Hz", names, frequency)
            reply = wire.setup_reply(recipe)
            return wire.pack_message(msg_type, reply if self.protocol >= 2 else reply[1:])
        if msg_type == M.CONTROL_PACKAGE_SETUP_INPUTS:
            names = wire.parse_names(payload)
            types = [wire.INPUT_TYPES.get(n, wire.NOT_FOUND) for n in names]
            ok = bool(names) and wire.NOT_FOUND not in types
            recipe = wire.Recipe.build(self.next_input_id if ok else 0, names, types)
            if ok:
                self.inputs[recipe.recipe_id] = recipe
                self.next_input_id += 1
            return wire.pack_message(msg_type, wire.setup_reply(recipe))
        if msg_type == M.CONTROL_PACKAGE_START:
            self.started = True
            self.due = [now] * len(self.outputs)
            return wire.pack_message(msg_type, b"\x01")
        if msg_type == M.CONTROL_PACKAGE_PAUSE:
            self.started = False
            return wire.pack_message(msg_type, b"\x01")
        if msg_type == M.DATA_PACKAGE:
            recipe_in = self.inputs.get(payload[0]) if payload else None
            if recipe_in is None or len(payload) < recipe_in.layout.size:
                return wire.text_message(1, f"data package for unknown input recipe {payload[:1].hex()}")
            ctl.apply_inputs(recipe_in.unpack(payload))
            return b""
        if msg_type == M.TEXT_MESSAGE:
            return b""
        return wire.text_message(1, f"unknown RTDE message type {msg_type}")


def split_programs(buffer: str) -> tuple[list[tuple[str, str]], str, list[str]]:
    """Complete top-level ``def``/``sec`` programs in ``buffer`` as (name, text), the unconsumed rest, and the
    non-empty top-level lines outside any program (which the fake does not run)."""
    programs: list[tuple[str, str]] = []
    dropped: list[str] = []
    lines = buffer.split("\n")
    start = None
    consumed = 0
    pos = 0
    for i, line in enumerate(lines[:-1]):  # the last piece has no newline yet
        stripped = line.rstrip("\r")
        if start is None and re.match(r"(def|sec)\s+\w+\s*\(\s*\)\s*:", stripped):
            start = i
        elif start is not None and stripped == "end":
            text = "\n".join(lines[start : i + 1]) + "\n"
            m = re.match(r"(?:def|sec)\s+(\w+)", lines[start])
            programs.append((m.group(1) if m else "", text))
            start = None
            consumed = pos + len(line) + 1
        elif start is None:
            consumed = pos + len(line) + 1
            if stripped.strip():
                dropped.append(stripped.strip())
        pos += len(line) + 1
    return programs, buffer[consumed:], dropped


class FakeURServer:
    """The asyncio side of the fake: listening sockets, client sessions, the control cycle and the handle's pipe."""

    def __init__(self, cfg: FakeURConfig, conn: Connection) -> None:
        self.cfg = cfg
        self.conn = conn
        self.ctl = Controller(cfg)
        self.servers: list[asyncio.base_events.Server] = []
        self.sessions: set[RtdeSession] = set()
        self.writers: set[asyncio.StreamWriter] = set()
        self.answering = asyncio.Event()
        self.answering.set()
        self.dropped = False
        self.finished = asyncio.Event()
        self.tasks: set[asyncio.Task[Any]] = set()

    async def open(self) -> None:
        host = self.cfg.host
        self.servers.append(await asyncio.start_server(self._rtde, host, self.cfg.rtde_port, reuse_address=True))
        self.servers.append(
            await asyncio.start_server(self._dashboard, host, self.cfg.dashboard_port, reuse_address=True)
        )
        for port in self.cfg.script_ports:
            self.servers.append(await asyncio.start_server(self._script, host, port, reuse_address=True))

    def close_servers(self) -> None:
        for server in self.servers:
            server.close()
        self.servers = []

    def drop_clients(self) -> None:
        for writer in list(self.writers):
            with contextlib.suppress(Exception):
                writer.transport.abort()
        self.writers.clear()
        self.sessions.clear()

    async def run(self) -> None:
        try:
            await self.open()
        except OSError as err:
            self.close_servers()
            self.conn.send(("error", f"cannot listen on {self.cfg.host}: {err}"))
            return
        loop = asyncio.get_running_loop()
        loop.add_reader(self.conn.fileno(), self._on_pipe)
        self.conn.send(("ready", None))
        ticker = asyncio.create_task(self._cycle())
        await self.finished.wait()
        ticker.cancel()
        loop.remove_reader(self.conn.fileno())
        self.close_servers()
        self.drop_clients()
        await asyncio.sleep(0.05)  # let the client handlers see their connections end

    async def _cycle(self) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / self.cfg.rate_hz
        next_t = loop.time()
        last = time.monotonic()
        while True:
            next_t += period
            delay = next_t - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            else:
                next_t = loop.time()
                await asyncio.sleep(0)
            now = time.monotonic()
            dt, last = min(now - last, 0.05), now
            try:
                self.ctl.tick(dt)  # the controller runs on while its network does not answer
                if self.answering.is_set():
                    self._stream()
            except Exception as err:  # a bug in the fake must be visible, not kill the controller silently
                log.exception("fake UR cycle failed")
                self.ctl.log.errors.append(f"internal error: {err!r}")

    def _stream(self) -> None:
        values: dict[str, Any] | None = None
        now = self.ctl.now()
        for session in list(self.sessions):
            if not session.started:
                continue
            transport = session.writer.transport
            if transport.is_closing():
                continue
            if transport.get_write_buffer_size() > 4_000_000:  # client stopped reading
                transport.abort()
                continue
            for i, recipe in enumerate(session.outputs):
                if now + 1e-4 < session.due[i]:
                    continue
                if values is None:
                    values = self.ctl.rtde_values()
                session.writer.write(recipe.pack(values))
                step = 1.0 / recipe.frequency_hz
                session.due[i] = session.due[i] + step if now - session.due[i] < step else now + step

    async def _serve_client(self, writer: asyncio.StreamWriter) -> bool:
        if self.dropped:
            writer.transport.abort()
            return False
        self.writers.add(writer)
        return True

    async def _rtde(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if not await self._serve_client(writer):
            return
        session = RtdeSession(writer, self.cfg)
        self.sessions.add(session)
        try:
            while True:
                size, msg_type = wire.HEADER.unpack(await reader.readexactly(wire.HEADER.size))
                if size < wire.HEADER.size:
                    break
                payload = await reader.readexactly(size - wire.HEADER.size)
                await self.answering.wait()
                if writer.transport.is_closing():
                    break
                reply = session.handle(msg_type, payload, self.ctl, self.ctl.now())
                if reply:
                    writer.write(reply)
        except (asyncio.IncompleteReadError, ConnectionError, asyncio.CancelledError):
            pass  # the client left, or the fake is shutting down
        finally:
            self.sessions.discard(session)
            self.writers.discard(writer)
            writer.close()

    async def _dashboard(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if not await self._serve_client(writer):
            return
        try:
            await self.answering.wait()
            writer.write(b"Connected: Universal Robots Dashboard Server\n")
            while True:
                line = await reader.readline()
                if not line:
                    break
                await self.answering.wait()
                if writer.transport.is_closing():
                    break
                text = line.decode("utf-8", errors="replace").strip()
                reply = self.ctl.dashboard(text)
                self.ctl.record("dashboard", command=text, reply=reply)
                writer.write(reply.encode("utf-8") + b"\n")
                if text.lower() == "quit":
                    break
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            self.writers.discard(writer)
            writer.close()

    async def _script(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if not await self._serve_client(writer):
            return
        buffer = ""
        try:
            while True:
                data = await reader.read(65536)
                if not data:
                    break
                await self.answering.wait()
                buffer += data.decode("utf-8", errors="replace")
                programs, buffer, dropped = split_programs(buffer)
                for line in dropped:
                    self.ctl.log.errors.append(f"script line outside a program not run: {line[:80]!r}")
                for name, text in programs:
                    self.ctl.run_program(name, text)
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            self.writers.discard(writer)
            writer.close()

    # ------------------------------------------------------------------ the handle's pipe
    def _on_pipe(self) -> None:
        try:
            while self.conn.poll():
                request = self.conn.recv()
                task = asyncio.get_running_loop().create_task(self._answer(request))
                self.tasks.add(task)
                task.add_done_callback(self.tasks.discard)
        except (EOFError, OSError):  # the handle's process is gone: nobody can stop us, so stop now
            self.finished.set()

    async def _answer(self, request: tuple[Any, ...]) -> None:
        try:
            result = await self._do(request)
            self.conn.send(("ok", result))
        except Exception as err:
            self.conn.send(("error", f"{type(err).__name__}: {err}"))

    async def _do(self, request: tuple[Any, ...]) -> Any:
        op = request[0]
        ctl = self.ctl
        if op == "inject":
            fault, _params = request[1], request[2]
            if fault not in SUPPORTED_FAULTS:
                raise ValueError(f"fault {fault!r} not supported; choose from {sorted(SUPPORTED_FAULTS)}")
            ctl.record("fault", fault=fault)
            if fault == "drop_connection":
                self.dropped = True
                self.close_servers()
                self.drop_clients()
            elif fault == "no_answer":
                self.answering.clear()
            elif fault == "protective_stop":
                ctl.protective_stop("injected")
            elif fault == "emergency_stop":
                ctl.emergency_stop()
            return None
        if op == "clear":
            ctl.record("faults_cleared")
            await self._clear_network_faults()
            ctl.estop_pressed = False
            return None
        if op == "reset":
            await self._clear_network_faults()
            self.drop_clients()
            ctl.reset()
            return None
        if op == "snapshot":
            return ctl.snapshot()
        if op == "log":
            return {"events": list(ctl.log.events), "errors": list(ctl.log.errors)}
        if op == "programs":
            return list(ctl.log.programs)
        if op == "set_digital_input":
            index, value = int(request[1]), bool(request[2])
            if value:
                ctl.digital_in |= 1 << index
            else:
                ctl.digital_in &= ~(1 << index)
            return None
        if op == "shutdown":
            self.finished.set()
            return None
        raise ValueError(f"unknown request {op!r}")

    async def _clear_network_faults(self) -> None:
        self.answering.set()
        if self.dropped:
            self.dropped = False
            await self.open()


def _serve(conn: Connection, cfg: FakeURConfig) -> None:
    """Entry point of the fake's process."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is for the test run; its handle stops this process
    logging.basicConfig(level=logging.WARNING)
    try:
        asyncio.run(FakeURServer(cfg, conn).run())
    finally:
        conn.close()


# --------------------------------------------------------------------------------------------- handle


class FakeURController:
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
        self.startup_timeout_s = startup_timeout_s
        self.request_timeout_s = request_timeout_s
        self._proc: multiprocessing.process.BaseProcess | None = None
        self._conn: Connection | None = None
        self._lock = threading.Lock()

    @property
    def host(self) -> str:
        return self.cfg.host

    def start(self) -> FakeURController:
        if self._proc is not None:
            raise RuntimeError(f"fake UR at {self.host} is already running")
        ctx = multiprocessing.get_context("spawn")
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=_serve, args=(child, self.cfg), name=f"fake-ur-{self.host}", daemon=True)
        proc.start()
        child.close()
        self._proc, self._conn = proc, parent
        if not parent.poll(self.startup_timeout_s):
            self.stop()
            raise TimeoutError(f"fake UR at {self.host} did not start within {self.startup_timeout_s} s")
        try:
            status, detail = parent.recv()
        except EOFError:
            status, detail = "error", f"its process ended (exit code {proc.exitcode})"
        if status != "ready":
            self.stop()
            raise RuntimeError(f"fake UR at {self.host} could not start: {detail}")
        return self

    def stop(self) -> None:
        """Stop the fake's process (safe to call twice)."""
        proc, conn = self._proc, self._conn
        self._proc = self._conn = None
        if conn is not None:
            with contextlib.suppress(OSError, EOFError):
                conn.send(("shutdown",))
                if conn.poll(2.0):
                    conn.recv()
            conn.close()
        if proc is not None:
            proc.join(3.0)
            if proc.is_alive():
                proc.terminate()
                proc.join(2.0)
            if proc.is_alive():
                proc.kill()
                proc.join(2.0)

    def __enter__(self) -> FakeURController:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    def _request(self, *request: Any) -> Any:
        with self._lock:
            conn = self._conn
            if conn is None:
                raise RuntimeError(f"fake UR at {self.host} is not running; call start() first")
            conn.send(request)
            if not conn.poll(self.request_timeout_s):
                raise TimeoutError(f"fake UR at {self.host} did not answer {request[0]!r}")
            status, result = conn.recv()
        if status != "ok":
            raise ValueError(result)
        return result

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
