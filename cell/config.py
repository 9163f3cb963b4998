"""The cell's one configuration file: TOML read into strict pydantic v2 models, unknown keys refused.

Layout (see examples/sim-cell.toml)::

    [robot]      kind = "ur" | "fanuc" | "fake-ur" | "fake-fanuc", host, ports, timeouts, speeds
    [track]      kind = "modbus" | "fake" | "none", host, port, unit_id, counts_per_m, soft limits, profile
    [camera]     kind = "oakd" | "fake", resolution, fps, timeout; device_id (oakd); scene, noise, playback (fake)
    [hand_eye]   path = "hand_eye.json"  or  X_tool_camera = [[...], [...], [...], [...]]   (optional)

Every mistake is a :class:`cell.errors.ConfigError` whose message names the file, the key (``robot.port``) and
the problem; a file with several mistakes lists them all. Types are strict (TOML is typed: ``port = "502"``
is an error, not a string to coerce); integers are accepted where a float is expected.

No address or hardware default lives here: hosts come from the file. Relative paths (``hand_eye.path``,
``camera.playback``) are relative to the file's folder.

Extending: add a section as a model deriving from :class:`Section` and a field on :class:`CellConfig` (make it
optional with a default so existing files stay valid); :func:`load_config` needs no change.
"""

from __future__ import annotations

import ipaddress
import json
import math
import os
import re
import tomllib
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, field_validator, model_validator

from cell.errors import ConfigError
from perception.transforms import TransformError, check_X

FANUC_RMI_PORT = 16001
"""FANUC RMI's well-known connect port (a protocol constant, used when ``robot.port`` is not given)."""

MODBUS_TCP_PORT = 502
"""Modbus TCP's registered port (used when ``track.port`` is not given)."""

RobotKind = Literal["ur", "fanuc", "fake-ur", "fake-fanuc"]
TrackKind = Literal["modbus", "fake", "none"]
CameraKind = Literal["oakd", "fake"]
NoiseModel = Literal["none", "stereo", "structured"]


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class Section(BaseModel):
    """Base of every config table: strict types, unknown keys refused, immutable once read."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class RobotConfig(Section):
    """``[robot]``. ``host``: the controller's address (for ``fake-*``: the loopback address the simulator binds).

    ``port``: FANUC RMI connect port (default 16001; 0 lets a ``fake-fanuc`` pick a free one, only useful when
    the same process starts the simulator). ``dashboard_port``: UR dashboard server (default 29999); UR's RTDE
    and script ports are fixed by the controller. ``timeout_s``: per request; ``connect_timeout_s``: to open
    the connection. ``speed_m_s``/``accel_m_s2``: default tool motion; ``max_speed_m_s``: the cell's limit.
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
    played back in a cycle instead of rendering.
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
        return self

    @property
    def size(self) -> tuple[int, int]:
        return (self.resolution[0], self.resolution[1])


class HandEyeConfig(Section):
    """``[hand_eye]``: the camera pose on the tool, ``X_tool_camera`` (4x4, metres), given inline or as
    ``path`` to a JSON file holding an object with an ``"X_tool_camera"`` key (as in a capture's pose.json)."""

    path: str | None = Field(default=None, min_length=1)
    X_tool_camera: list[list[float]] | None = None

    @model_validator(mode="after")
    def _check_one(self) -> HandEyeConfig:
        if (self.path is None) == (self.X_tool_camera is None):
            raise ValueError("give exactly one of 'path' and 'X_tool_camera'")
        if self.X_tool_camera is not None:
            try:
                check_X(np.asarray(self.X_tool_camera, dtype=np.float64), name="X_tool_camera")
            except (TransformError, ValueError) as err:
                raise ValueError(str(err)) from err
        return self


class CellConfig(Section):
    """The whole file. Read it with :func:`load_config`; ``source``/``base_dir`` say where it came from."""

    robot: RobotConfig
    track: TrackConfig = Field(default_factory=lambda: TrackConfig(kind="none"))
    camera: CameraConfig
    hand_eye: HandEyeConfig | None = None

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
        assert he.path is not None
        path = self.resolve(he.path)
        key = self.where("hand_eye.path")
        try:
            obj = json.loads(path.read_text(encoding="utf-8"))
        except OSError as err:
            raise ConfigError(f"{key}: cannot read the hand-eye file {path}: {err.strerror or err}") from err
        except (UnicodeDecodeError, json.JSONDecodeError) as err:
            raise ConfigError(f"{key}: the hand-eye file {path} is not valid JSON: {err}") from err
        if not isinstance(obj, dict) or "X_tool_camera" not in obj:
            raise ConfigError(f"{key}: the hand-eye file {path} has no 'X_tool_camera' key")
        try:
            return check_X(np.asarray(obj["X_tool_camera"], dtype=np.float64), name="X_tool_camera")
        except (TransformError, TypeError, ValueError) as err:
            raise ConfigError(f"{key}: {path}: {err}") from err


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
        raise ConfigError(f"{file}: malformed TOML: {_toml_context(err, text)}") from err
    return config_from_dict(data, source=file)


def config_from_dict(data: dict[str, Any], *, source: str | os.PathLike[str] | None = None) -> CellConfig:
    """Validate an already parsed config (``source`` names it in messages)."""
    try:
        config = CellConfig.model_validate(data)
    except ValidationError as err:
        where = f"{source}: " if source is not None else ""
        problems = "; ".join(_describe(e) for e in err.errors(include_url=False))
        raise ConfigError(f"{where}{problems}") from err
    config._source = Path(source) if source is not None else None
    return config


def _toml_context(err: tomllib.TOMLDecodeError, text: str) -> str:
    """The decoder's message, the dotted key being written when it failed, and the offending line."""
    msg = str(err)
    found = re.search(r"at line (\d+)", msg)
    lines = text.splitlines()
    if found is None or not 1 <= int(found.group(1)) <= len(lines):
        return msg
    lineno = int(found.group(1))
    line = lines[lineno - 1].strip()
    table = ""
    for previous in reversed(lines[: lineno - 1]):
        header = re.match(r"\s*\[+\s*([^\]]+?)\s*\]+", previous)
        if header:
            table = header.group(1)
            break
    assigned = re.match(r"\s*([A-Za-z0-9_\-.\"']+)\s*=", line)
    key = ".".join(k for k in (table, assigned.group(1) if assigned else "") if k)
    where = f"{key} " if key else ""
    return f"{msg}; {where}(line {lineno}: {line!r})"


def _describe(error: Any) -> str:
    loc = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in error["loc"]).replace(".[", "[")
    kind = error["type"]
    msg = str(error["msg"])
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    if kind == "extra_forbidden":
        allowed = _allowed_keys(error["loc"][:-1])
        hint = f" (allowed: {', '.join(allowed)})" if allowed else ""
        return f"{loc}: unknown key{hint}"
    if kind == "missing":
        return f"{loc}: required key is missing"
    if kind in ("model_type", "dict_type") and not loc:
        return f"the file must be a table of sections, got {type(error['input']).__name__}"
    got = error.get("input")
    shown = (
        ""
        if isinstance(got, dict) or kind.startswith("value_error") or kind == "assertion_error"
        else f" (got {got!r})"
    )
    return f"{loc or 'file'}: {msg}{shown}"


def _allowed_keys(loc: tuple[Any, ...]) -> list[str]:
    model: type[BaseModel] = CellConfig
    for part in loc:
        field = model.model_fields.get(str(part))
        if field is None:
            return []
        inner = _model_of(field.annotation)
        if inner is None:
            return []
        model = inner
    return list(model.model_fields)


def _model_of(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()):
        if isinstance(arg, type) and issubclass(arg, BaseModel):
            return arg
    return None
