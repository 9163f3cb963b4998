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
``inject("protective_stop", on_next_program=True)`` holds the stop back until the next program arrives on a script
port (a stop in the moment a path's script is uploaded), which then does not start, as on a real controller;
``inject("no_answer", on_next_program=True)`` likewise cuts the controller off as that program arrives.
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

from sim_fakes.fake_ur.control_script import ControlScript, parse_injected_path
from sim_fakes.fake_ur.controller import Controller, FakeURConfig
from sim_fakes.fake_ur.handle import FakeURController
from sim_fakes.fake_ur.kinematics import Q_HOME, SUPPORTED_FAULTS, Arm, pose_to_X, ur_pose
from sim_fakes.fake_ur.motion import Motion, Segment, Waypoint, build_segments
from sim_fakes.fake_ur.server import FakeURServer, split_programs

__all__ = [
    "Q_HOME",
    "SUPPORTED_FAULTS",
    "Arm",
    "ControlScript",
    "Controller",
    "FakeURConfig",
    "FakeURController",
    "FakeURServer",
    "Motion",
    "Segment",
    "Waypoint",
    "build_segments",
    "parse_injected_path",
    "pose_to_X",
    "split_programs",
    "ur_pose",
]
