"""A job file: what to weld on one workpiece, as TOML read into strict pydantic models (unknown keys refused).

Layout (see examples/jobs/ribs.toml)::

    workpiece = "ribs"            # a name for reports and the journal
    approval = false              # true: an operator approves the planned path before the arc is struck
    frame = "fixture"             # capture poses are X_fixture_tool (the cell config's [fixture] says where the
                                  # fixture is), or "base" (default): X_base_tool at the capture's track position

    [[capture]]                   # one or more: where the camera looks from
    track_position_m = 0.0        # the carriage position (metres)
    xyz_m = [-0.30, -0.36, 0.37]  # the tool pose (in `frame`): xyz_m + rotvec_rad (UR pose vector),
    rotvec_rad = [...]            #   or xyzwpr_mm_deg = [X, Y, Z, W, P, R]
    prompts = "camera"            # "camera" (the prompts the camera delivers, else automatic), "automatic",
                                  # or a prompts.json file (relative to the job file)

    [welding]                     # overrides the cell config's [welding] (cell.config.WeldingConfig)
    travel_speed_m_s = 0.025
    work_angle_deg = 0.0

    [seams]                       # which detected seams to weld
    kinds = ["linear"]            # "linear" | "curved"; absent: all
    ids = [0, 3]                  # planner seam ids (capture k: k * 1000 + detector id); absent: all
    min_length_m = 0.02

Every mistake is a :class:`cell.errors.ConfigError` naming the file and the key (``capture[1].xyz_m``).
"""

from __future__ import annotations

import json
import math
import os
import stat
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, ValidationError, model_validator

from cell.config import DetectionConfig, PoseConfig, WeldingConfig
from cell.errors import ConfigError
from cell.planning import WeldParams
from cell.sections import Section, describe_validation_error, toml_context
from cell.world_seams import SeamFilter

PROMPTS_FROM_CAMERA = "camera"
PROMPTS_AUTOMATIC = "automatic"


class CaptureSpec(PoseConfig):
    """``[[capture]]``: the carriage at ``track_position_m`` (metres) and the tool at the pose of
    :class:`cell.config.PoseConfig` (base frame); ``prompts``: ``"camera"``, ``"automatic"`` or a prompts file."""

    track_position_m: float = 0.0
    prompts: str = Field(default=PROMPTS_FROM_CAMERA, min_length=1)

    @model_validator(mode="after")
    def _check_track(self) -> CaptureSpec:
        if not math.isfinite(self.track_position_m):
            raise ValueError(f"track_position_m must be a finite number, got {self.track_position_m}")
        return self


class SeamSelection(Section):
    """``[seams]``: the seams to weld (:class:`cell.world_seams.SeamFilter`)."""

    ids: list[int] | None = None
    kinds: list[Literal["linear", "curved"]] | None = None
    min_length_m: float = Field(default=0.0, ge=0)

    def seam_filter(self) -> SeamFilter:
        return SeamFilter(
            ids=None if self.ids is None else frozenset(self.ids),
            kinds=None if self.kinds is None else frozenset(self.kinds),
            min_length_m=self.min_length_m,
        )


class JobFile(Section):
    """The whole job file (see the module docstring)."""

    workpiece: str = Field(min_length=1)
    approval: bool = False
    frame: Literal["base", "fixture"] = "base"
    capture: list[CaptureSpec] = Field(min_length=1)
    welding: WeldingConfig = Field(default_factory=WeldingConfig)
    seams: SeamSelection = Field(default_factory=SeamSelection)


@dataclass(frozen=True)
class FileRules:
    """Where a job may name files, for jobs from an untrusted client (the HTTP service): every file must resolve
    (symlinks followed) inside one of ``roots`` and be a regular file of at most ``max_bytes``. Errors name the rule
    and never quote a file's contents; a path outside the roots is refused before anything looks at it, so an
    error cannot tell whether it exists."""

    roots: tuple[Path, ...]
    max_bytes: int = 1 << 20

    def check(self, path: Path, what: str) -> Path:
        """``path`` resolved, or ConfigError naming the rule it breaks."""
        resolved = Path(os.path.realpath(path))
        roots = [Path(os.path.realpath(r)) for r in self.roots]
        if not any(resolved.is_relative_to(root) for root in roots):
            raise ConfigError(
                f"{what}: files must lie inside the configured directories ({', '.join(map(str, roots))}); "
                "this one does not"
            )
        try:
            st = resolved.stat()
        except OSError as err:
            raise ConfigError(f"{what}: no readable file there ({err.strerror or 'cannot stat'})") from err
        if not stat.S_ISREG(st.st_mode):
            raise ConfigError(f"{what}: not a regular file")
        if st.st_size > self.max_bytes:
            raise ConfigError(f"{what}: {st.st_size} bytes, more than the {self.max_bytes} bytes allowed")
        return resolved


def _read_bounded(path: Path, max_bytes: int | None) -> bytes:
    with path.open("rb") as f:
        data = f.read() if max_bytes is None else f.read(max_bytes + 1)
    if max_bytes is not None and len(data) > max_bytes:
        raise ConfigError(f"{path}: more than the {max_bytes} bytes allowed")
    return data


@dataclass(frozen=True)
class Job:
    """A validated job: ``spec`` (the file's content), ``source`` (the file, or a label for a job sent as text),
    ``base_dir`` (where relative prompt files are looked up) and the original ``text``; ``rules``: where it may
    name files (None: anywhere, for a local operator's ``weldcell run``)."""

    spec: JobFile
    source: str
    base_dir: Path
    text: str
    rules: FileRules | None = None

    @property
    def workpiece(self) -> str:
        return self.spec.workpiece

    @property
    def captures(self) -> list[CaptureSpec]:
        return self.spec.capture

    def where(self, key: str) -> str:
        return f"{self.source}: {key}"

    def prompts_px(self, index: int) -> np.ndarray | None:
        """(N, 2) prompts of capture ``index`` from its prompts file, or None for ``"camera"``/``"automatic"``."""
        value = self.captures[index].prompts
        if value in (PROMPTS_FROM_CAMERA, PROMPTS_AUTOMATIC):
            return None
        key = self.where(f"capture[{index}].prompts")
        path = Path(value) if self.rules is not None else Path(value).expanduser()
        path = path if path.is_absolute() else self.base_dir / path
        if self.rules is not None:
            path = self.rules.check(path, f"{key} ({value})")
        try:
            raw = _read_bounded(path, self.rules.max_bytes if self.rules is not None else None)
            obj = json.loads(raw.decode("utf-8"))
        except OSError as err:
            raise ConfigError(f"{key}: cannot read the prompts file {path}: {err.strerror or err}") from err
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
            # the decoder's position only: its message could quote the file
            where = f" (line {err.lineno}, column {err.colno})" if isinstance(err, json.JSONDecodeError) else ""
            raise ConfigError(f"{key}: the prompts file {path} is not valid JSON{where}") from err
        points = obj.get("prompts_px", obj.get("points")) if isinstance(obj, dict) else obj
        try:
            arr = np.asarray(points, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise ConfigError(f"{key}: {path} must hold [[u, v], ...] pixel prompts") from err
        if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < 2 or not np.all(np.isfinite(arr)):
            raise ConfigError(f"{key}: {path} must hold at least two [u, v] pixel prompts, got shape {arr.shape}")
        return arr


def load_job(path: str | os.PathLike[str], *, rules: FileRules | None = None) -> Job:
    """Read and validate a job file; every problem raises :class:`ConfigError` naming the file and the key.
    ``rules``: where the file (and the prompts files it names) may be (None: anywhere); with rules, no error
    quotes the file's text."""
    file = Path(path)
    if rules is not None:
        file = rules.check(file, f"job file {path}")
    try:
        text = _read_bounded(file, rules.max_bytes if rules is not None else None).decode("utf-8")
    except FileNotFoundError as err:
        raise ConfigError(f"{file}: job file does not exist") from err
    except OSError as err:
        raise ConfigError(f"{file}: cannot read job file: {err.strerror or err}") from err
    except UnicodeDecodeError as err:
        raise ConfigError(f"{file}: not UTF-8 text (is it really a TOML job file?)") from err
    return job_from_text(text, source=str(file), base_dir=file.resolve().parent, rules=rules, quote=rules is None)


def job_from_text(
    text: str,
    *,
    source: str = "<job>",
    base_dir: str | os.PathLike[str] | None = None,
    rules: FileRules | None = None,
    quote: bool = True,
) -> Job:
    """Validate a job given as TOML text (``source`` names it in messages, ``base_dir`` resolves prompt files,
    ``rules`` confines them). ``quote``: a TOML error may show the offending line (not for a file read on an
    untrusted client's behalf)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        detail = toml_context(err, text) if quote else str(err)
        raise ConfigError(f"{source}: malformed TOML: {detail}") from err
    except RecursionError as err:
        raise ConfigError(f"{source}: the TOML is nested too deeply to be a job file") from err
    try:
        spec = JobFile.model_validate(data)
    except ValidationError as err:
        problems = "; ".join(describe_validation_error(e, JobFile) for e in err.errors(include_url=False))
        raise ConfigError(f"{source}: {problems}") from err
    except RecursionError as err:
        raise ConfigError(f"{source}: the job is nested too deeply") from err
    job = Job(spec, source, Path(base_dir) if base_dir is not None else Path.cwd(), text, rules)
    for i, _capture in enumerate(job.captures):
        job.prompts_px(i)  # a missing or malformed prompts file is a bad job, found before anything moves
    return job


def weld_params(cell_defaults: WeldingConfig, job: WeldingConfig, seam_filter: SeamFilter) -> WeldParams:
    """:class:`WeldParams` from the job's ``[welding]`` over the cell's over the planner's defaults; degrees and
    ``arc_output`` are converted here, once."""
    merged: dict[str, Any] = {}
    for source in (cell_defaults, job):
        merged.update({k: v for k, v in source.model_dump().items() if v is not None})
    kwargs: dict[str, Any] = {}
    for key, value in merged.items():
        if key == "work_angle_deg":
            kwargs["work_angle_rad"] = math.radians(value)
        elif key == "travel_angle_deg":
            kwargs["travel_angle_rad"] = math.radians(value)
        elif key == "arc_output":
            kwargs["arc_do_index"] = value
        else:
            kwargs[key] = value
    return WeldParams(**kwargs, seam_filter=seam_filter)


def detect_params(detection: DetectionConfig) -> Any:
    """:class:`perception.detect.DetectParams` of a ``[detection]`` table."""
    from perception.detect import DetectParams

    near, far = detection.z_range_m
    return DetectParams(
        crop=detection.crop,
        roi_band_m=detection.roi_band_m,
        z_range_m=(near, far),
        voxel_m=detection.voxel_m,
        method=detection.method,
        unprompted=detection.unprompted,
    )
