"""The cell's one configuration file: TOML read into strict pydantic v2 models, unknown keys refused.

Layout (see examples/sim-cell.toml)::

    [robot]      kind = "ur" | "fanuc" | "fake-ur" | "fake-fanuc", host, ports, timeouts, speeds
    [track]      kind = "modbus" | "fake" | "none", host, port, unit_id, counts_per_m, soft limits, profile
    [camera]     kind = "oakd" | "fake", resolution, fps, timeout; device_id (oakd); scene, noise, playback (fake)
    [hand_eye]   path = "hand_eye.json"  or  X_tool_camera = [[...], [...], [...], [...]]   (optional)
      [hand_eye.calibration]   how `weldcell calibrate hand-eye` finds it: board, nominal poses, workspace (optional)
    [home]       the robot's home pose and the track's home position (optional)
    [fixture]    where the workpiece fixture sits (world frame), for jobs whose poses are fixture-relative (optional)
    [safety]     workspace box, reach, speed, jump and torch-up limits (needed by `weldcell run` / `serve`)
    [welding]    default welding parameters (a job's [welding] overrides them)
    [detection]  detector parameters (voxel, crop...) and how seams of several captures merge
    [daemon]     `weldcell serve`: bind host (default 127.0.0.1), port, token, journal and status image paths

Every mistake is a :class:`cell.errors.ConfigError` whose message names the file, the key (``robot.port``) and
the problem; a file with several mistakes lists them all. Types are strict (TOML is typed: ``port = "502"``
is an error, not a string to coerce); integers are accepted where a float is expected.

No address or hardware default lives here: hosts come from the file. Relative paths (``hand_eye.path``,
``camera.playback``) are relative to the file's folder.

The ``[hand_eye]`` tables live in :mod:`cell.config_hand_eye`; the :class:`cell.sections.Section` base and the
error messages in :mod:`cell.sections` (the job file uses them too).

Extending: add a section as a model deriving from :class:`Section` and a field on :class:`CellConfig` (make it
optional with a default so existing files stay valid); :func:`load_config` needs no change.
"""

from __future__ import annotations

import ipaddress
import math
import os
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import Field, PrivateAttr, ValidationError, field_validator, model_validator

from cell.config_hand_eye import HandEyeConfig
from cell.errors import ConfigError
from cell.sections import Section, check_matrix, describe_validation_error, toml_context
from perception.transforms import TransformError, check_X

if TYPE_CHECKING:
    pass

FANUC_RMI_PORT = 16001
"""FANUC RMI's well-known connect port (a protocol constant, used when ``robot.port`` is not given)."""

MODBUS_TCP_PORT = 502
"""Modbus TCP's registered port (used when ``track.port`` is not given)."""

RobotKind = Literal["ur", "fanuc", "fake-ur", "fake-fanuc"]
TrackKind = Literal["modbus", "fake", "none"]
CameraKind = Literal["oakd", "fake"]
NoiseModel = Literal["none", "stereo", "structured"]

CHARUCO_SCENE = "charuco"
"""The fake camera's scene that shows the calibration board of ``[hand_eye.calibration.board]``."""


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class RobotConfig(Section):
    """``[robot]``. ``host``: the controller's address (for ``fake-*``: the loopback address the simulator binds).

    ``port``: FANUC RMI connect port (default 16001; 0 lets a ``fake-fanuc`` pick a free one, only useful when
    the same process starts the simulator). ``dashboard_port``: UR dashboard server (default 29999); UR's RTDE
    and script ports are fixed by the controller. ``timeout_s``: per request; ``connect_timeout_s``: to open
    the connection. ``speed_m_s``/``accel_m_s2``: default tool motion; ``max_speed_m_s``: the cell's limit.
    ``heartbeat_timeout_s``: the controller-side watchdog's timeout (UR: ``setWatchdog``; FANUC: what ``WC_HBEAT``
    is installed with); ``heartbeat_register``: the FANUC's ``R[n]`` the host rewrites (docs/controller-watchdogs.md).
    """

    kind: RobotKind
    name: str = "robot"
    host: str = Field(min_length=1)
    port: int | None = Field(default=None, ge=0, le=65535)
    dashboard_port: int | None = Field(default=None, ge=0, le=65535)
    timeout_s: float = Field(default=2.0, gt=0)
    connect_timeout_s: float = Field(default=15.0, gt=0)
    speed_m_s: float = Field(default=0.1, gt=0)
    max_speed_m_s: float = Field(default=0.5, gt=0)
    accel_m_s2: float = Field(default=0.5, gt=0)
    heartbeat_timeout_s: float = Field(default=0.3, ge=0.05, le=2.0)
    heartbeat_register: int = Field(default=90, ge=1, le=200)

    @model_validator(mode="after")
    def _check_kind(self) -> RobotConfig:
        if self.kind.startswith("fake-") and not is_loopback(self.host):
            raise ValueError(f"a {self.kind} simulator binds a loopback address (127.0.0.N), not {self.host!r}")
        if self.kind in ("ur", "fake-ur") and self.port is not None:
            raise ValueError("UR controllers use fixed RTDE/script ports; 'port' is for FANUC (use dashboard_port)")
        if self.kind in ("fanuc", "fake-fanuc") and self.dashboard_port is not None:
            raise ValueError("'dashboard_port' is for UR controllers; a FANUC takes 'port' (RMI)")
        if self.kind == "fanuc" and self.port == 0:
            raise ValueError("port 0 only makes sense for a fake-fanuc simulator")
        if self.speed_m_s > self.max_speed_m_s:
            raise ValueError(f"speed_m_s={self.speed_m_s} exceeds max_speed_m_s={self.max_speed_m_s}")
        return self

    @property
    def rmi_port(self) -> int:
        return FANUC_RMI_PORT if self.port is None else self.port


class TrackConfig(Section):
    """``[track]``. ``kind = "none"`` for a cell without a track (no other key is needed then).

    ``counts_per_m``: encoder counts per metre on the wire; ``soft_limit_min_m``/``soft_limit_max_m``: targets
    allowed, metres from home; ``speed_m_s``/``accel_m_s2``: the move profile. For ``kind = "fake"`` the
    simulated drive also takes ``max_speed_m_s``, ``max_accel_m_s2``, ``in_position_window_m`` and
    ``start_position_m`` (ignored by a real drive, which reports its own).
    """

    kind: TrackKind
    name: str = "track"
    host: str | None = Field(default=None, min_length=1)
    port: int = Field(default=MODBUS_TCP_PORT, ge=0, le=65535)
    unit_id: int = Field(default=1, ge=0, le=247)
    counts_per_m: int | None = Field(default=None, gt=0, le=0xFFFFFFFF)
    soft_limit_min_m: float | None = None
    soft_limit_max_m: float | None = None
    timeout_s: float = Field(default=1.0, gt=0)
    speed_m_s: float = Field(default=0.2, gt=0)
    accel_m_s2: float = Field(default=0.5, gt=0)
    max_speed_m_s: float = Field(default=0.5, gt=0)
    max_accel_m_s2: float = Field(default=1.0, gt=0)
    in_position_window_m: float = Field(default=0.0002, ge=0)
    start_position_m: float = 0.0

    @model_validator(mode="after")
    def _check_kind(self) -> TrackConfig:
        if self.kind == "none":
            return self
        missing = [
            key
            for key in ("host", "counts_per_m", "soft_limit_min_m", "soft_limit_max_m")
            if getattr(self, key) is None
        ]
        if missing:
            raise ValueError(f"kind = {self.kind!r} needs {', '.join(missing)}")
        assert self.soft_limit_min_m is not None and self.soft_limit_max_m is not None and self.host is not None
        if not all(math.isfinite(v) for v in (self.soft_limit_min_m, self.soft_limit_max_m)):
            raise ValueError("soft limits must be finite numbers")
        if not self.soft_limit_min_m < self.soft_limit_max_m:
            raise ValueError(
                f"soft_limit_min_m ({self.soft_limit_min_m}) must be below soft_limit_max_m ({self.soft_limit_max_m})"
            )
        if self.kind == "fake":
            if not is_loopback(self.host):
                raise ValueError(f"the fake track binds a loopback address, not {self.host!r}")
            if not self.soft_limit_min_m <= self.start_position_m <= self.soft_limit_max_m:
                raise ValueError(f"start_position_m={self.start_position_m} lies outside the soft limits")
            if self.speed_m_s > self.max_speed_m_s or self.accel_m_s2 > self.max_accel_m_s2:
                raise ValueError("speed_m_s / accel_m_s2 exceed the fake drive's max_speed_m_s / max_accel_m_s2")
        elif self.port == 0:
            raise ValueError("port 0 only makes sense for a fake track")
        return self

    @property
    def soft_limits_m(self) -> tuple[float, float]:
        if self.soft_limit_min_m is None or self.soft_limit_max_m is None:
            raise ConfigError("[track] has no soft limits (kind = 'none')")
        return (self.soft_limit_min_m, self.soft_limit_max_m)


class CameraConfig(Section):
    """``[camera]``. ``resolution``: [width, height] of colour and registered depth.

    ``oakd``: ``device_id`` (device id or IP; absent = the first OAK found), ``fps``, ``max_depth_m``.
    ``fake``: ``scene`` (a simulator scene name), ``noise``, ``seed``, ``X_base_world`` (4x4, metres: where the
    scene's world frame sits in the robot base frame with the track at 0; absent = the simulator's default, in
    front of the fake FANUC's start pose); or ``playback``: capture folders (or folders of capture folders)
    played back in a cycle instead of rendering. ``X_tool_camera`` (4x4, metres): the simulated camera's true
    mount on the tool, which a hand-eye calibration should find (absent = the simulator's default; the cell's
    ``[hand_eye]`` is what the cell *believes*, a separate thing on purpose).
    ``scene = "charuco"`` shows the calibration board of ``[hand_eye.calibration.board]`` instead of a weldment,
    lying at ``X_base_board`` (4x4, metres, base frame with the track at 0; required), imaged with lens blur
    ``blur_sigma_px`` (default 0.6) and sensor noise ``image_noise`` (gray levels of 255, default 2).
    """

    kind: CameraKind
    name: str = "camera"
    resolution: list[int] = Field(default_factory=lambda: [1280, 720], min_length=2, max_length=2)
    fps: float = Field(default=10.0, gt=0)
    timeout_s: float = Field(default=5.0, gt=0)
    min_valid_depth_share: float = Field(default=0.01, ge=0, le=1)
    device_id: str | None = Field(default=None, min_length=1)
    max_depth_m: float = Field(default=10.0, gt=0)
    scene: str = Field(default="ribs", min_length=1)
    noise: NoiseModel = "stereo"
    seed: int = 0
    playback: list[str] = Field(default_factory=list)
    X_base_world: list[list[float]] | None = None
    X_tool_camera: list[list[float]] | None = None
    X_base_board: list[list[float]] | None = None
    blur_sigma_px: float | None = Field(default=None, ge=0)
    image_noise: float | None = Field(default=None, ge=0)

    @field_validator("resolution")
    @classmethod
    def _check_resolution(cls, value: list[int]) -> list[int]:
        w, h = value
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise ValueError(f"resolution must be [width, height] between 16 and 8192 pixels, got {value}")
        return value

    @model_validator(mode="after")
    def _check_kind(self) -> CameraConfig:
        if self.kind == "oakd" and self.resolution[0] % 16:
            raise ValueError(f"an OAK-D's aligned depth needs a width that is a multiple of 16, got {self.resolution}")
        if self.kind == "oakd" and (self.playback or self.X_base_world is not None):
            raise ValueError("playback and X_base_world are for kind = 'fake'")
        if self.X_base_world is not None:
            try:
                check_X(np.asarray(self.X_base_world, dtype=np.float64), name="X_base_world")
            except (TransformError, ValueError) as err:
                raise ValueError(str(err)) from err
        simulated = ("X_tool_camera", "X_base_board", "blur_sigma_px", "image_noise")
        if self.kind == "oakd" and any(getattr(self, key) is not None for key in simulated):
            raise ValueError(f"{', '.join(simulated)} describe the simulator: they are for kind = 'fake'")
        check_matrix(self.X_tool_camera, "X_tool_camera")
        check_matrix(self.X_base_board, "X_base_board")
        if self.kind == "fake":
            if self.scene == CHARUCO_SCENE and self.X_base_board is None:
                raise ValueError(f"scene = {CHARUCO_SCENE!r} needs X_base_board, where the board lies (base frame)")
            board_keys = [k for k in ("X_base_board", "blur_sigma_px", "image_noise") if getattr(self, k) is not None]
            if self.scene != CHARUCO_SCENE and board_keys:
                raise ValueError(f"{', '.join(board_keys)} are for scene = {CHARUCO_SCENE!r}")
        return self

    @property
    def size(self) -> tuple[int, int]:
        return (self.resolution[0], self.resolution[1])


class PoseConfig(Section):
    """A tool pose ``X_base_tool`` in a file: ``xyz_m`` (metres, base frame) with ``rotvec_rad`` (a rotation vector,
    radians, as UR pose vectors), or ``xyzwpr_mm_deg`` (FANUC X, Y, Z in mm and W, P, R in degrees, fixed-axis
    x-y-z). Converted to SI once, in :meth:`X_base_tool`."""

    xyz_m: list[float] | None = Field(default=None, min_length=3, max_length=3)
    rotvec_rad: list[float] | None = Field(default=None, min_length=3, max_length=3)
    xyzwpr_mm_deg: list[float] | None = Field(default=None, min_length=6, max_length=6)

    @model_validator(mode="after")
    def _check_pose(self) -> PoseConfig:
        vector = self.xyz_m is not None or self.rotvec_rad is not None
        if vector == (self.xyzwpr_mm_deg is not None):
            raise ValueError("give either xyz_m with rotvec_rad, or xyzwpr_mm_deg")
        if vector and (self.xyz_m is None or self.rotvec_rad is None):
            raise ValueError("xyz_m and rotvec_rad go together")
        values = [*(self.xyz_m or []), *(self.rotvec_rad or []), *(self.xyzwpr_mm_deg or [])]
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"pose values must be finite numbers, got {values}")
        return self

    def X_base_tool(self) -> np.ndarray:
        """(4, 4) the pose, metres."""
        from perception.transforms import X_from_ur_pose, X_from_xyzwpr_mm_deg

        if self.xyzwpr_mm_deg is not None:
            return X_from_xyzwpr_mm_deg(np.asarray(self.xyzwpr_mm_deg, dtype=np.float64))
        assert self.xyz_m is not None and self.rotvec_rad is not None
        return X_from_ur_pose(np.asarray([*self.xyz_m, *self.rotvec_rad], dtype=np.float64))


class FixtureConfig(Section):
    """``[fixture]``: where the workpiece fixture sits, ``X_world_fixture`` (4x4, metres, world frame = base frame with
    the track at 0). A job whose poses are given with ``frame = "fixture"`` runs on every cell that states this."""

    X_world_fixture: list[list[float]]

    @model_validator(mode="after")
    def _check_fixture(self) -> FixtureConfig:
        check_matrix(self.X_world_fixture, "X_world_fixture")
        return self


class HomeConfig(Section):
    """``[home]``: where a job starts and ends. ``pose``: the robot's home tool pose (absent: the robot is not moved
    when homing, only checked); ``track_position_m``: the carriage's home position (metres)."""

    pose: PoseConfig | None = None
    track_position_m: float = 0.0


class SafetyConfig(Section):
    """``[safety]``: the limits every planned path is validated against (:class:`cell.safety.SafetyLimits`).

    ``workspace_min_world``/``workspace_max_world``: the box the TCP stays in (metres, world frame = base frame with
    the track at 0). ``reach_radius_m`` around ``reach_centre_base`` (base frame), ``reach_preferred_m`` where seams
    are best welded. ``track_axis_base``: the unit direction the carriage moves the base. Speeds m/s, acceleration
    m/s², blend and step in metres; ``max_step_deg`` (rotation between consecutive non-air poses) and
    ``max_tilt_deg`` (torch-up limit: the torch axis from straight down) in degrees, as operators read them.
    """

    workspace_min_world: list[float] = Field(min_length=3, max_length=3)
    workspace_max_world: list[float] = Field(min_length=3, max_length=3)
    reach_radius_m: float = Field(gt=0)
    reach_preferred_m: float = Field(ge=0)
    reach_centre_base: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    track_axis_base: list[float] = Field(default_factory=lambda: [0.0, 1.0, 0.0], min_length=3, max_length=3)
    max_speed_m_s: float = Field(default=0.25, gt=0)
    max_accel_m_s2: float = Field(default=1.2, gt=0)
    max_blend_m: float = Field(default=0.01, ge=0)
    max_step_m: float = Field(default=0.1, gt=0)
    max_step_deg: float = Field(default=20.0, gt=0, le=180)
    max_tilt_deg: float = Field(default=60.0, gt=0, le=180)

    @model_validator(mode="after")
    def _check_safety(self) -> SafetyConfig:
        if not all(lo < hi for lo, hi in zip(self.workspace_min_world, self.workspace_max_world, strict=True)):
            raise ValueError(
                f"workspace_min_world {self.workspace_min_world} must lie below workspace_max_world "
                f"{self.workspace_max_world} on every axis"
            )
        if self.reach_preferred_m > self.reach_radius_m:
            raise ValueError(f"reach_preferred_m={self.reach_preferred_m} exceeds reach_radius_m={self.reach_radius_m}")
        if abs(float(np.linalg.norm(self.track_axis_base)) - 1.0) > 1e-6:
            raise ValueError(f"track_axis_base must be a unit vector, got {self.track_axis_base}")
        return self


class WeldingConfig(Section):
    """``[welding]`` (cell defaults) and a job's ``[welding]`` (overrides): :class:`cell.planning.WeldParams` in
    file units. Speeds m/s, distances m, times s; ``work_angle_deg``/``travel_angle_deg`` in degrees (converted to
    radians once, in :func:`cell.job.weld_params`). ``arc_output``: the robot's digital output that switches the
    arc (UR standard output n, FANUC ``DO[n + 1]``). A key left out keeps the cell's (then the planner's) default.
    """

    travel_speed_m_s: float | None = Field(default=None, gt=0)
    approach_speed_m_s: float | None = Field(default=None, gt=0)
    air_speed_m_s: float | None = Field(default=None, gt=0)
    accel_m_s2: float | None = Field(default=None, gt=0)
    blend_m: float | None = Field(default=None, ge=0)
    work_angle_deg: float | None = Field(default=None, gt=-90, lt=90)
    travel_angle_deg: float | None = Field(default=None, gt=-90, lt=90)
    stickout_m: float | None = Field(default=None, ge=0)
    approach_m: float | None = Field(default=None, ge=0)
    retract_m: float | None = Field(default=None, ge=0)
    arc_output: int | None = Field(default=None, ge=0)
    weld_job: int | None = Field(default=None, ge=0)
    voltage_v: float | None = Field(default=None, gt=0)
    wire_feed_m_s: float | None = Field(default=None, gt=0)
    arc_on_dwell_s: float | None = Field(default=None, ge=0)
    arc_off_dwell_s: float | None = Field(default=None, ge=0)


class DetectionConfig(Section):
    """``[detection]``: :class:`perception.detect.DetectParams` the cell uses, and how seams seen in several captures
    are merged. ``voxel_m``: voxel grid; ``crop``: keep only the seam bands; ``roi_band_m``: their half-width;
    ``z_range_m``: [near, far] pass-through (camera z, metres); ``method``: ``"refined"``, ``"surfaces"`` (the
    fine stage on fitted surfaces, :mod:`perception.detect_surfaces`) or ``"paper"``; ``unprompted``: without
    prompts, ``"aim"`` welds the part the camera is aimed at (and what stands on it), not boxes or fixtures
    beside it on the table; ``"all"`` every part in view;
    ``merge_tol_m``/``merge_min_overlap_m``: two seams closer than this over at least that length are one;
    ``helper_process``: the daemon keeps a second process that takes a share of each detection's fine stage
    (:mod:`perception.helper_process`: the same seams, sooner on a computer with two cores or more)."""

    voxel_m: float = Field(default=0.003, gt=0, le=0.05)
    crop: bool = True
    roi_band_m: float = Field(default=0.010, gt=0)
    z_range_m: list[float] = Field(default_factory=lambda: [0.1, 3.0], min_length=2, max_length=2)
    method: Literal["surfaces", "refined", "paper"] = "surfaces"
    unprompted: Literal["aim", "all"] = "aim"
    merge_tol_m: float = Field(default=0.003, gt=0)
    merge_min_overlap_m: float = Field(default=0.02, gt=0)
    helper_process: bool = True

    @model_validator(mode="after")
    def _check_range(self) -> DetectionConfig:
        near, far = self.z_range_m
        if not 0 <= near < far:
            raise ValueError(f"z_range_m must be [near, far] with 0 <= near < far, got {self.z_range_m}")
        return self


class DaemonConfig(Section):
    """``[daemon]`` (``weldcell serve``): bind ``host`` (default 127.0.0.1) and ``port``; ``token``: the bearer token
    every request must carry (required when ``host`` is not a loopback address; at least 16 characters);
    ``journal``: the SQLite journal; ``status_image``: where the last capture overlay is written (PNG).
    ``jobs_dir`` (default: ``jobs`` next to the journal, where the jobs sent as text are kept) and ``captures_dir``
    (default: ``captures`` next to the journal): the only folders a job sent over HTTP may name files in
    (``{"path": ...}`` job files in ``jobs_dir``, prompts files in either or among the kept jobs);
    ``max_file_bytes``: the largest such file read. ``allowed_hosts``: further names the ``Host`` header may carry
    (loopback names and ``host`` always may); ``allowed_origins``: further browser origins (``http://name:port``)
    allowed to POST; ``request_timeout_s``: a request's head and body must arrive within it; ``max_body_bytes``;
    ``max_connections`` served at once. Relative paths are relative to the config file's
    folder."""

    host: str = Field(default="127.0.0.1", min_length=1)
    port: int = Field(default=8765, ge=0, le=65535)
    token: str | None = Field(default=None, min_length=16)
    journal: str = Field(default="weldcell-journal.sqlite3", min_length=1)
    status_image: str = Field(default="weldcell-status.png", min_length=1)
    recent_jobs: int = Field(default=20, ge=1, le=1000)
    jobs_dir: str | None = Field(default=None, min_length=1)
    captures_dir: str | None = Field(default=None, min_length=1)
    max_file_bytes: int = Field(default=1 << 20, ge=1024, le=64 << 20)
    allowed_hosts: list[str] = Field(default_factory=list)
    allowed_origins: list[str] = Field(default_factory=list)
    request_timeout_s: float = Field(default=10.0, gt=0, le=300)
    max_body_bytes: int = Field(default=1 << 20, ge=1024, le=64 << 20)
    max_connections: int = Field(default=512, ge=4, le=4096)

    @model_validator(mode="after")
    def _check_token(self) -> DaemonConfig:
        if not is_loopback(self.host) and self.token is None:
            raise ValueError(
                f"host = {self.host!r} is not a loopback address: set 'token' (a bearer token of 16+ characters) "
                "so that only clients that know it can start jobs"
            )
        return self


class CellConfig(Section):
    """The whole file. Read it with :func:`load_config`; ``source``/``base_dir`` say where it came from."""

    robot: RobotConfig
    track: TrackConfig = Field(default_factory=lambda: TrackConfig(kind="none"))
    camera: CameraConfig
    hand_eye: HandEyeConfig | None = None
    home: HomeConfig = Field(default_factory=HomeConfig)
    fixture: FixtureConfig | None = None
    safety: SafetyConfig | None = None
    welding: WeldingConfig = Field(default_factory=WeldingConfig)
    detection: DetectionConfig = Field(default_factory=DetectionConfig)
    daemon: DaemonConfig = Field(default_factory=DaemonConfig)

    _source: Path | None = PrivateAttr(default=None)

    @property
    def source(self) -> Path | None:
        """The file this was read from (None when built in code)."""
        return self._source

    @property
    def base_dir(self) -> Path:
        """The folder relative paths in the file are resolved against."""
        return self._source.parent if self._source is not None else Path.cwd()

    def where(self, key: str) -> str:
        """``file: key`` for messages."""
        return f"{self._source}: {key}" if self._source is not None else key

    def resolve(self, relative: str) -> Path:
        path = Path(relative).expanduser()
        return path if path.is_absolute() else self.base_dir / path

    def playback_folders(self) -> list[Path]:
        """Capture folders to play back: each entry is a capture folder or a folder of capture folders."""
        folders: list[Path] = []
        for i, entry in enumerate(self.camera.playback):
            path = self.resolve(entry)
            if (path / "camera.json").is_file():
                folders.append(path)
            elif path.is_dir():
                inner = sorted(p for p in path.iterdir() if (p / "camera.json").is_file())
                if not inner:
                    raise ConfigError(f"{self.where(f'camera.playback[{i}]')}: {path} holds no capture folder")
                folders.extend(inner)
            else:
                raise ConfigError(f"{self.where(f'camera.playback[{i}]')}: {path} does not exist")
        return folders

    def X_tool_camera(self) -> np.ndarray | None:
        """(4, 4) hand-eye result from ``[hand_eye]`` (inline or read from its file), or None without one."""
        he = self.hand_eye
        if he is None:
            return None
        if he.X_tool_camera is not None:
            return check_X(np.asarray(he.X_tool_camera, dtype=np.float64), name="X_tool_camera")
        from calibration.result_file import ResultFileError, read_X_tool_camera

        assert he.path is not None
        path = self.resolve(he.path)
        try:
            return read_X_tool_camera(path)
        except ResultFileError as err:
            raise ConfigError(f"{self.where('hand_eye.path')}: {err}") from err


# ================================================================================================ loading
def load_config(path: str | os.PathLike[str]) -> CellConfig:
    """Read and validate a cell config file; every problem raises :class:`ConfigError` naming file and key."""
    file = Path(path)
    try:
        raw = file.read_bytes()
    except FileNotFoundError as err:
        raise ConfigError(f"{file}: config file does not exist") from err
    except OSError as err:
        raise ConfigError(f"{file}: cannot read config file: {err.strerror or err}") from err
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{file}: not UTF-8 text (is it really a TOML file?)") from err
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{file}: malformed TOML: {toml_context(err, text)}") from err
    return config_from_dict(data, source=file)


def config_from_dict(data: dict[str, Any], *, source: str | os.PathLike[str] | None = None) -> CellConfig:
    """Validate an already parsed config (``source`` names it in messages)."""
    try:
        config = CellConfig.model_validate(data)
    except ValidationError as err:
        where = f"{source}: " if source is not None else ""
        problems = "; ".join(describe_validation_error(e, CellConfig) for e in err.errors(include_url=False))
        raise ConfigError(f"{where}{problems}") from err
    config._source = Path(source) if source is not None else None
    return config


