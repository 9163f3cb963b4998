"""Emulation of ur-rtde's control script (``def rtde_control():``): its register handshake and injected paths.

Part of :mod:`sim_fakes.fake_ur` (its docstring describes the fake as a whole).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from concurrent.futures import Future
from typing import TYPE_CHECKING

from drivers.ur_protocol import (
    CMD_MOVE_PATH,
    CMD_MOVEL,
    CMD_NO_CMD,
    CMD_PROTECTIVE_STOP,
    CMD_SET_PAYLOAD,
    CMD_SET_WATCHDOG,
    CMD_STOP_SCRIPT,
    CMD_STOPJ,
    CMD_STOPL,
    DONE_WITH_CMD,
    READY_FOR_CMD,
    RUNTIME_PLAYING,
)
from sim_fakes.fake_ur.kinematics import ROT_RADIUS_M
from sim_fakes.fake_ur.motion import Motion, Waypoint, build_segments

if TYPE_CHECKING:  # the controller runs the script; the script only reads and writes its registers
    from sim_fakes.fake_ur.controller import Controller


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
        # a move whose reach the controller's reach_check still computes: (result, waypoints, async, progress)
        self.pending: tuple[Future[str], list[Waypoint], bool, bool] | None = None

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
        if self.pending is not None:
            result, waypoints, asynchronous, progress = self.pending
            if not result.done():
                return  # the command stays unanswered (no "done") until its path is checked; the cycle goes on
            self.pending = None
            problem = result.result()
            if problem:
                ctl.halt_program(problem)
            else:
                self._start_move(ctl, waypoints, asynchronous, progress=progress)
            return
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
        if ctl.reach_check is not None:
            self.pending = (ctl.reach_check(segments, ctl.q.copy()), waypoints, asynchronous, progress)
            return
        problem = ctl.check_reachable(segments)
        if problem:
            ctl.halt_program(problem)
            return
        self._start_move(ctl, waypoints, asynchronous, progress=progress)

    def _start_move(self, ctl: Controller, waypoints: list[Waypoint], asynchronous: bool, *, progress: bool) -> None:
        segments = build_segments(ctl.p, ctl.R, waypoints)  # from where the arm is now (it stood still meanwhile)
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
