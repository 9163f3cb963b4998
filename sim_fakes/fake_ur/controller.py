"""The fake UR's controller state: robot and safety modes, the running program, IO, watchdogs, the dashboard.

Part of :mod:`sim_fakes.fake_ur` (its docstring describes the fake as a whole).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.ur_protocol import (
    DASHBOARD_PORT,
    JOINT_MODE_RUNNING,
    ROBOT_BIT_POWER_ON,
    ROBOT_BIT_PROGRAM_RUNNING,
    ROBOT_MODE_BOOTING,
    ROBOT_MODE_IDLE,
    ROBOT_MODE_NAMES,
    ROBOT_MODE_POWER_OFF,
    ROBOT_MODE_RUNNING,
    RTDE_PORT,
    RUNTIME_PAUSED,
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    SAFETY_BIT_EMERGENCY_STOPPED,
    SAFETY_BIT_NORMAL,
    SAFETY_BIT_PROTECTIVE_STOPPED,
    SAFETY_BIT_ROBOT_EMERGENCY_STOPPED,
    SAFETY_BIT_STOPPED_DUE_TO_SAFETY,
    SAFETY_MODE_NAMES,
    SAFETY_MODE_NORMAL,
    SAFETY_MODE_PROTECTIVE_STOP,
    SAFETY_MODE_ROBOT_EMERGENCY_STOP,
    SCRIPT_PORTS,
)
from sim_fakes import rtde_wire as wire
from sim_fakes.fake_ur.control_script import ControlScript
from sim_fakes.fake_ur.kinematics import _GRAVITY_M_S2, Q_HOME, Arm, FloatArray, pose_to_X, rotation, rotvec, ur_pose
from sim_fakes.fake_ur.motion import Motion, Segment

log = logging.getLogger("sim_fakes.fake_ur")


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
        self.reach_check: Callable[[list[Segment], FloatArray], Future[str]] | None = None
        """Runs :meth:`check_reachable` away from the control cycle (the server's thread; None: at once, in the
        cycle). A 100 mm weld path of 200 waypoints costs 0.15 s of CPU, several seconds' share on a loaded host:
        done in the cycle it stopped the fake's streaming for up to 1.1 s, which the driver rightly takes for a lost
        controller. A real controller plans while it streams."""
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
        self.protective_on_next_program = False  # the fault injected to come with the next program's arrival
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
        # rtde_set_watchdog: variable -> (min frequency Hz, action, cycle_time_s of its last update)
        self.rtde_watchdogs: dict[str, tuple[float, str, float]] = {}
        self.cycle_time_s = 0.0
        """The controller's running time: the sum of its control cycles' steps (each at most 50 ms; see tick)."""
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
        if self.protective_on_next_program:
            self.protective_on_next_program = False
            self.protective_stop(f"injected as program {name!r} arrived")
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
        self.rtde_watchdogs[variable] = (min_frequency_hz, action, self.cycle_time_s)

    def check_rtde_watchdogs(self) -> None:
        """Take the action of each watchdog whose variable no input package has updated for longer than 1/f s of
        the controller's running time (:attr:`cycle_time_s`): a real controller receives every package as it comes,
        and a fake whose process was not scheduled for a while finds the host's packages of that while still
        queued in its sockets, read only after this check; wall time would count its own stall as the host's
        silence."""
        now = self.cycle_time_s
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
    def check_reachable(self, segments: Sequence[Segment], q_start: FloatArray | None = None) -> str:
        """'' if every segment has an inverse-kinematics solution along its straight line (from the joints
        ``q_start``, default the arm's now), else why not. Pure: :attr:`reach_check` may run it in a thread."""
        q = self.q if q_start is None else q_start
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
                        f"(pose {np.round(ur_pose(seg.p1, seg.R0 @ rotation(seg.w)), 4).tolist()})"
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
        """One control cycle of ``dt`` seconds (the server passes the time since the last cycle, at most 50 ms)."""
        self.cycle_time_s += dt
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
            self.tcp_speed = np.concatenate([(self.p - p_prev) / dt, rotvec(self.R @ R_prev.T) / dt])
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
        now = self.cycle_time_s
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
        """The dashboard server's answer to one command line (the texts a CB3 or e-Series sends)."""
        # two if-chains over the commands, in the order of UR's dashboard manual, so that each command's answer
        # reads next to its condition: what reports the controller's state, then what changes it
        cmd = line.strip()
        low = cmd.lower()
        report = self._dashboard_report(low)
        return report if report is not None else self._dashboard_command(cmd, low)

    def _dashboard_report(self, low: str) -> str | None:
        """The answer to a dashboard query of the controller's state, None when ``low`` is no query."""
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
        if low == "isprogramsaved":
            return f"true {self.loaded_program or '<unnamed>'}"
        return None

    def _dashboard_command(self, cmd: str, low: str) -> str:
        """The answer to a dashboard command that acts (loads, plays, stops, powers, unlocks), or the refusal."""
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
