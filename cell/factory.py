"""Build the cell's devices from its config: the only place outside the tests that imports ``sim_fakes``.

Two steps, so that a simulated cell can run in one process (``weldcell sim up``) and be used from others
(``weldcell devices check``, the daemon):

- :func:`start_simulators` starts the fake of every ``kind = "fake-*"`` / ``"fake"`` device with a network
  address (the robot controller, the track drive) and returns :class:`Simulators`, a context manager that stops
  them all. The fake camera has no address: it is an in-process renderer that every client builds for itself
  (it reads the live robot and track pose through the client's own drivers).
- :func:`build_cell` creates the drivers (not yet connected) and returns :class:`Cell`, a context manager that
  disconnects them and, when it started them (``start_simulators=True``), stops its simulators.

Without ``start_simulators`` the drivers of fake kinds connect to the addresses in the config, i.e. to the
simulators of a running ``weldcell sim up``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any

import numpy as np

from cell.config import CHARUCO_SCENE, CellConfig
from cell.errors import ConfigError
from drivers.errors import DriverError
from drivers.protocols import Camera, Robot, Track

logger = logging.getLogger(__name__)

UR_PORTS = "30004 (RTDE), 29999 (dashboard), 30001-30003 (script)"


@dataclass(frozen=True)
class DeviceLine:
    """One device of the cell for listings: ``role`` (robot, track, camera), config ``kind``, ``address``."""

    role: str
    kind: str
    address: str
    detail: str = ""

    def format(self) -> str:
        text = f"{self.role:<7} {self.kind:<11} {self.address}"
        return f"{text}  ({self.detail})" if self.detail else text


@dataclass
class Simulators:
    """The running fakes of a config (robot controller, track drive). Stop them with :meth:`stop` or ``with``.

    ``robot``/``track``: the fakes' control handles (``sim_fakes.faults.FaultInjectable``), None when that
    device is real or absent. ``robot_address``/``track_address``: (host, port) they listen on.
    """

    config: CellConfig
    robot: Any = None
    track: Any = None
    robot_address: tuple[str, int] | None = None
    track_address: tuple[str, int] | None = None
    _stops: list[Callable[[], None]] = field(default_factory=list)

    def devices(self) -> list[DeviceLine]:
        """One line per device of the cell, as it is simulated."""
        lines: list[DeviceLine] = []
        rc, tc, cc = self.config.robot, self.config.track, self.config.camera
        if self.robot_address is not None:
            host, port = self.robot_address
            if rc.kind == "fake-ur":
                lines.append(DeviceLine("robot", rc.kind, f"{host}:30004", UR_PORTS))
            else:
                lines.append(DeviceLine("robot", rc.kind, f"{host}:{port}", "FANUC RMI"))
        else:
            lines.append(DeviceLine("robot", rc.kind, f"{rc.host}:{rc.rmi_port}", "real controller, not simulated"))
        if self.track_address is not None:
            host, port = self.track_address
            lines.append(DeviceLine("track", tc.kind, f"{host}:{port}", f"Modbus TCP, unit {tc.unit_id}"))
        elif tc.kind != "none":
            lines.append(DeviceLine("track", tc.kind, f"{tc.host}:{tc.port}", "real drive, not simulated"))
        if cc.kind == "fake":
            what = (
                f"playback of {len(cc.playback)} folder entr{'y' if len(cc.playback) == 1 else 'ies'}"
                if cc.playback
                else f"scene {cc.scene}, {cc.size[0]}x{cc.size[1]}, "
                + ("a calibration board" if cc.scene == CHARUCO_SCENE else f"noise {cc.noise}")
            )
            lines.append(
                DeviceLine("camera", cc.kind, "in-process", f"{what}; each client renders from the live robot pose")
            )
        else:
            lines.append(DeviceLine("camera", cc.kind, cc.device_id or "first OAK found", "real camera"))
        return lines

    def stop(self) -> None:
        """Stop every simulator, last started first; safe to call twice."""
        while self._stops:
            stop = self._stops.pop()
            try:
                stop()
            except Exception:  # one fake failing to stop must not leave the others running
                logger.exception("stopping a simulator failed")

    def __enter__(self) -> Simulators:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()


def start_simulators(config: CellConfig) -> Simulators:
    """Start the fake robot controller and fake track drive the config asks for (none for real devices)."""
    sims = Simulators(config)
    try:
        rc = config.robot
        arc = config.welding.arc_output if config.welding.arc_output is not None else 0
        if rc.kind == "fake-fanuc":
            from sim_fakes.fake_fanuc_process import FakeFanucProcess
            from sim_fakes.fanuc_program import HeartbeatProgram

            # the fake runs the watchdog program an integrator installs (docs/controller-watchdogs.md), in a process
            # of its own: the host's computing must not starve the simulated controller (as with the fake UR)
            program = HeartbeatProgram(rc.heartbeat_register, rc.heartbeat_timeout_s, (arc + 1,))
            fanuc = FakeFanucProcess(host=rc.host, port=rc.rmi_port, heartbeat=program).start()
            sims._stops.append(fanuc.stop)
            sims.robot, sims.robot_address = fanuc, (rc.host, fanuc.port)
        elif rc.kind == "fake-ur":
            from sim_fakes.fake_ur import FakeURController

            # the installation drives the arc output low at a program stop (docs/controller-watchdogs.md)
            ur = FakeURController(
                rc.host, startup_timeout_s=rc.connect_timeout_s, program_stop_outputs_low=(arc,)
            ).start()
            sims._stops.append(ur.stop)
            sims.robot, sims.robot_address = ur, (rc.host, 30004)
        tc = config.track
        if tc.kind == "fake":
            from sim_fakes.fake_track_process import FakeTrackProcess

            # in a process of its own too: as a thread of the daemon it answered the job watchdog's status reads
            # late while a job was detecting on a loaded host
            assert tc.host is not None and tc.counts_per_m is not None
            track = FakeTrackProcess(
                host=tc.host,
                port=tc.port,
                unit_id=tc.unit_id,
                counts_per_m=tc.counts_per_m,
                soft_limits_m=tc.soft_limits_m,
                max_speed_m_s=tc.max_speed_m_s,
                max_accel_m_s2=tc.max_accel_m_s2,
                in_position_window_m=tc.in_position_window_m,
                start_position_m=tc.start_position_m,
            ).start()
            sims._stops.append(track.stop)
            sims.track, sims.track_address = track, (tc.host, track.port)
    except (OSError, RuntimeError, TimeoutError) as err:  # a port in use, a fake process that did not come up
        sims.stop()
        raise DriverError(
            f"cannot start the simulators of {config.source or 'the config'}: {err} "
            "(is another 'weldcell sim up' or a test using these addresses?)"
        ) from err
    except BaseException:
        sims.stop()
        raise
    return sims


# ================================================================================================ drivers
@dataclass
class Cell:
    """The cell's device drivers built from a config (not connected until :meth:`connect`).

    ``track`` is None for ``kind = "none"``; ``X_tool_camera`` is the configured hand-eye result (None without
    a ``[hand_eye]`` section); ``simulators`` are the fakes this cell started, stopped on :meth:`close`.
    """

    config: CellConfig
    robot: Robot
    track: Track | None
    camera: Camera
    X_tool_camera: np.ndarray | None
    simulators: Simulators | None = None

    def devices(self) -> list[tuple[str, Robot | Track | Camera]]:
        """(role, driver) of every device, robot first (the fake camera reads the robot and track)."""
        out: list[tuple[str, Robot | Track | Camera]] = [("robot", self.robot)]
        if self.track is not None:
            out.append(("track", self.track))
        out.append(("camera", self.camera))
        return out

    def fault_injectors(self) -> dict[str, Any]:
        """The fault-injection switches of the cell's simulators by role (``robot``, ``track``, ``camera``): each has
        ``supported_faults``, ``inject(fault, **params)`` and ``clear_faults()`` (``sim_fakes.faults``).

        Test-only. ConfigError unless every device is a simulator and this cell started the robot and track fakes
        itself: the switches are the fakes' own in-process handles, so no fault can ever be sent to real hardware
        (nor to the simulators of another process, ``weldcell sim up``)."""
        real = real_devices(self.config)
        if real:
            raise ConfigError(
                f"{self.config.source or 'the config'}: fault injection is for simulated cells only, and "
                f"{', '.join(real)} is real hardware"
            )
        if self.simulators is None:
            raise ConfigError(
                "fault injection needs the simulators in this process: they run elsewhere (--no-sims, "
                "'weldcell sim up'); inject faults through their own handles there"
            )
        handles = {"robot": self.simulators.robot, "track": self.simulators.track, "camera": self.camera}
        out: dict[str, Any] = {}
        for role, handle in handles.items():
            if handle is None:
                continue  # no track
            if not all(hasattr(handle, name) for name in ("supported_faults", "inject", "clear_faults")):
                raise ConfigError(f"the simulated {role} ({type(handle).__name__}) has no fault switch")
            out[role] = handle
        return out

    def connect(self) -> None:
        """Connect every device, robot first; the first failure propagates (already connected ones stay)."""
        for _role, device in self.devices():
            device.connect()

    def close(self) -> None:
        """Disconnect every device (camera first) and stop the simulators this cell started."""
        for role, device in reversed(self.devices()):
            try:
                device.disconnect()
            except Exception:  # keep going: the others must still be released
                logger.exception("disconnecting the %s failed", role)
        if self.simulators is not None:
            self.simulators.stop()

    def __enter__(self) -> Cell:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def real_devices(config: CellConfig) -> list[str]:
    """``"robot.kind = 'fanuc'"``-style names of the devices of ``config`` that are real hardware, not simulators."""
    real = []
    if not config.robot.kind.startswith("fake-"):
        real.append(f"robot.kind = {config.robot.kind!r}")
    if config.track.kind not in ("fake", "none"):
        real.append(f"track.kind = {config.track.kind!r}")
    if config.camera.kind != "fake":
        real.append(f"camera.kind = {config.camera.kind!r}")
    return real


def build_cell(config: CellConfig, *, start_simulators: bool = False) -> Cell:
    """Drivers for every device of ``config``; with ``start_simulators`` the fakes are started first."""
    sims = _start(config) if start_simulators else None
    try:
        robot = build_robot(config, address=sims.robot_address if sims else None)
        track = build_track(config, address=sims.track_address if sims else None)
        camera = build_camera(config, robot=robot, track=track)
        X_tool_camera = config.X_tool_camera()
    except BaseException:
        if sims is not None:
            sims.stop()
        raise
    return Cell(config, robot, track, camera, X_tool_camera, sims)


def _start(config: CellConfig) -> Simulators:
    return start_simulators(config)


def build_robot(config: CellConfig, *, address: tuple[str, int] | None = None) -> Robot:
    """The robot driver; ``address`` overrides the configured (host, port) (a simulator's actual port)."""
    rc = config.robot
    if rc.kind in ("fanuc", "fake-fanuc"):
        from drivers.fanuc import FanucRobot

        host, port = address if address is not None else (rc.host, rc.rmi_port)
        if port == 0:
            raise ConfigError(
                f"{config.where('robot.port')}: port 0 (a free port picked when the simulator starts) cannot be "
                "reached from another process; give the fixed port 'weldcell sim up' uses"
            )
        return FanucRobot(
            host, port=port, name=rc.name, timeout_s=rc.timeout_s, heartbeat_register=rc.heartbeat_register
        )
    from drivers.ur import DASHBOARD_PORT, URRobot

    return URRobot(
        rc.host,
        name=rc.name,
        dashboard_port=rc.dashboard_port if rc.dashboard_port is not None else DASHBOARD_PORT,
        connect_timeout_s=rc.connect_timeout_s,
        command_timeout_s=rc.timeout_s,
        heartbeat_timeout_s=rc.heartbeat_timeout_s,
    )


def build_track(config: CellConfig, *, address: tuple[str, int] | None = None) -> Track | None:
    """The track driver, None for ``kind = "none"``."""
    tc = config.track
    if tc.kind == "none":
        return None
    from drivers.track import ModbusTrack

    assert tc.host is not None
    host, port = address if address is not None else (tc.host, tc.port)
    if port == 0:
        raise ConfigError(
            f"{config.where('track.port')}: port 0 (a free port picked when the simulator starts) cannot be "
            "reached from another process; give the fixed port 'weldcell sim up' uses"
        )
    return ModbusTrack(
        host,
        port=port,
        unit_id=tc.unit_id,
        counts_per_m=tc.counts_per_m,
        soft_limits_m=tc.soft_limits_m,
        name=tc.name,
        timeout_s=tc.timeout_s,
        speed_m_s=tc.speed_m_s,
        accel_m_s2=tc.accel_m_s2,
    )


def build_camera(config: CellConfig, *, robot: Robot, track: Track | None) -> Camera:
    """The camera driver; a fake camera renders from ``robot``'s and ``track``'s live pose."""
    cc = config.camera
    if cc.kind == "oakd":
        from drivers.oakd import OakDCamera

        return OakDCamera(
            device_id=cc.device_id,
            name=cc.name,
            resolution=cc.size,
            fps=cc.fps,
            max_depth_m=cc.max_depth_m,
            min_valid_depth_share=cc.min_valid_depth_share,
        )
    from sim_fakes.board_render import RenderParams
    from sim_fakes.fake_camera import BoardTarget, FakeCamera
    from sim_fakes.scenes import SCENES

    if cc.scene not in SCENES and cc.scene != CHARUCO_SCENE:
        raise ConfigError(
            f"{config.where('camera.scene')}: unknown scene {cc.scene!r}; choose one of: "
            f"{', '.join([*SCENES, CHARUCO_SCENE])}"
        )
    placement: dict[str, Any] = {}
    if cc.X_base_world is not None:
        placement["X_base_world"] = np.asarray(cc.X_base_world, dtype=np.float64)
    if cc.X_tool_camera is not None:
        placement["X_tool_camera"] = np.asarray(cc.X_tool_camera, dtype=np.float64)
    if cc.scene == CHARUCO_SCENE:
        calibration = config.hand_eye.calibration if config.hand_eye is not None else None
        if calibration is None:
            raise ConfigError(
                f"{config.where('camera.scene')}: scene {CHARUCO_SCENE!r} shows the board of "
                "[hand_eye.calibration.board]; add that table"
            )
        assert cc.X_base_board is not None  # the config refuses the charuco scene without it
        imaging: dict[str, Any] = {"blur_sigma_px": cc.blur_sigma_px, "noise_sigma": cc.image_noise}
        placement["board"] = BoardTarget(
            board=calibration.board.spec(),
            X_base_board=np.asarray(cc.X_base_board, dtype=np.float64),
            imaging=RenderParams(**{key: value for key, value in imaging.items() if value is not None}),
        )
    return FakeCamera(
        cc.scene,
        **placement,
        name=cc.name,
        robot_pose=robot,
        track_position_m=track,
        resolution=cc.size,
        noise=cc.noise,
        seed=cc.seed,
        playback=config.playback_folders() if cc.playback else None,
    )
