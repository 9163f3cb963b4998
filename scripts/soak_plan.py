"""The soak's plan (scripts/soak.py): which job is a fault of which kind, the job files and the cell config copy."""

from __future__ import annotations

import collections
import json
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

DEFAULT_FAULTS = (
    "camera_timeout",
    "track_fault",
    "protective_stop",
    "connection_drop",
    "no_answer",
    "unreachable_pose",
    "link_drop_arc",
    "malformed",
    "hostile",
)
ARC_OFF_WITHIN_S = 1.0
"""After no_answer or a dropped link with the arc on, the simulated controller must read the arc off within this."""
HOSTILE = (  # (path, headers, body, expected status, a piece of the error)
    ("/jobs", {"Content-Type": "application/json"}, b'{"path": "/etc/passwd"}', 400, "configured directories"),
    ("/jobs", {"Content-Type": "application/json"}, b'{"path": "../../../etc/shadow"}', 400, "configured directories"),
    ("/acknowledge", {"Origin": "http://evil.example"}, b'{"operator": "mallory"}', 403, "cross-origin"),
    ("/acknowledge", {"Content-Type": "application/x-www-form-urlencoded"}, b"operator=mallory", 415, "json"),
    ("/jobs", {"Content-Type": "application/toml"}, b"a = " + b"[" * 5000 + b"]" * 5000, 400, "nested too deeply"),
    ("/jobs", {"Content-Type": "application/toml"}, b"#" * (2 << 20), 413, "larger than"),
    ("/jobs", {"Content-Type": "application/json"}, b'{"toml": "workpiece = 1", "dry_run": "false"}', 400, "boolean"),
)


# ================================================================================================ the plan
@dataclass(frozen=True)
class FaultKind:
    """One kind of fault job. ``device``/``fault``/``params``: what is switched on in which simulator (None: the
    job itself is bad); ``when``: ``"idle"`` (before the job starts), ``"arc_on"`` (once its first arc is on) or
    ``"never"``; ``weld``: the job welds (else a dry run); ``state``/``outcome``/``error``: the expected journal
    state, report outcome and a piece of the error (``outcome`` None: refused at submission with a 4xx)."""

    name: str
    device: str | None
    fault: str | None
    params: dict[str, Any]
    when: str
    weld: bool
    state: str
    outcome: str | None
    error: str


FAULTS: dict[str, FaultKind] = {
    f.name: f
    for f in (
        FaultKind("camera_timeout", "camera", "frame_timeout", {}, "idle", False, "failed", "fault", "no frame within"),
        FaultKind(
            "connection_drop", "robot", "drop_connection", {}, "idle", False, "failed", "fault", "ConnectionLost"
        ),
        FaultKind("protective_stop", "robot", "protective_stop", {}, "arc_on", True, "failed", "fault", "protective"),
        FaultKind(
            "track_fault", "track", "track_fault", {"code": 0x7310}, "arc_on", True, "failed", "fault", "fault latched"
        ),
        FaultKind("unreachable_pose", None, None, {}, "never", False, "", None, "[safety] reach_radius_m"),
        FaultKind("malformed", None, None, {}, "never", False, "", None, ""),
        # the controller stops answering / the host link drops while the arc is on: a fault within a second,
        # and the controller's own heartbeat watchdog switches the arc off (read from the simulator itself)
        FaultKind("no_answer", "robot", "no_answer", {}, "arc_on", True, "failed", "fault", "ConnectionLost|no status"),
        FaultKind("link_drop_arc", "robot", "drop_connection", {}, "arc_on", True, "failed", "fault", "ConnectionLost"),
        # hostile requests (files outside the jobs directory, cross-origin, oversized, deep nesting): 4xx, no job
        FaultKind("hostile", None, None, {}, "never", False, "", None, ""),
    )
}


@dataclass(frozen=True)
class PlannedJob:
    """Job ``index`` (1-based) of the soak: ``kind`` is ``"dry"``, ``"weld"`` or a fault name; ``occurrence``: how
    many faults of that kind came before it."""

    index: int
    kind: str
    weld: bool
    fault: FaultKind | None = None
    occurrence: int = 0


def plan_jobs(n_jobs: int, *, fault_every: int, weld_every: int, faults: tuple[str, ...]) -> list[PlannedJob]:
    """The soak's jobs: a fault every ``fault_every`` (in turn from ``faults``), a weld every ``weld_every`` and
    after a fault that left the robot away from its home pose (the torch stopped on the part, or the camera failed
    at the first capture pose: dry runs capture where the robot stands, and the weld brings it home), dry runs
    otherwise (0: never)."""
    unknown = [name for name in faults if name not in FAULTS]
    if unknown:
        raise ValueError(f"unknown fault kinds {unknown}; choose from {sorted(FAULTS)}")
    plan: list[PlannedJob] = []
    rerun = False
    seen: collections.Counter[str] = collections.Counter()
    for i in range(1, n_jobs + 1):
        if fault_every and faults and i % fault_every == 0:
            f = FAULTS[faults[sum(seen.values()) % len(faults)]]
            plan.append(PlannedJob(i, f.name, f.weld, f, seen[f.name]))
            seen[f.name] += 1
            rerun = f.when == "arc_on" or f.name == "camera_timeout"
        elif rerun or (weld_every and i % weld_every == 0):
            plan.append(PlannedJob(i, "weld", True))
            rerun = False
        else:
            plan.append(PlannedJob(i, "dry", False))
    return plan


# ================================================================================================ TOML files
def toml_dumps(data: dict[str, Any]) -> str:
    """TOML text of ``data`` (tables of scalars, lists, nested tables; arrays of tables). Comments are not kept."""

    def key(k: str) -> str:
        return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int):
            return str(v)
        if isinstance(v, float):
            if math.isnan(v):
                return "nan"
            return ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{key(k)} = {value(x)}" for k, x in v.items()) + "}"
        raise TypeError(f"cannot write {type(v).__name__} as TOML")

    def is_table_array(v: Any) -> bool:
        return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)

    lines: list[str] = []

    def table(path: list[str], body: dict[str, Any], header: str | None) -> None:
        if header is not None:
            lines.extend(["", header])
        for k, v in body.items():
            if not isinstance(v, dict) and not is_table_array(v):
                lines.append(f"{key(k)} = {value(v)}")
        for k, v in body.items():
            if isinstance(v, dict):
                name = ".".join(key(p) for p in [*path, k])
                table([*path, k], v, f"[{name}]")
        for k, v in body.items():
            if is_table_array(v):
                name = ".".join(key(p) for p in [*path, k])
                for item in v:
                    lines.extend(["", f"[[{name}]]"])
                    lines.extend(f"{key(ik)} = {value(iv)}" for ik, iv in item.items())

    table([], data, None)
    return "\n".join(lines).lstrip("\n") + "\n"


def soak_config(config_path: Path, workdir: Path) -> tuple[Path, dict[str, Any]]:
    """A copy of the cell config in ``workdir``: the fakes on free ports (the fake UR, whose ports are fixed, on a free
    loopback address), journal and status image in ``workdir``, the file paths it names made absolute. Returns (path,
    its data)."""
    data = tomllib.loads(config_path.read_text(encoding="utf-8"))
    base = config_path.resolve().parent
    robot, track = data.setdefault("robot", {}), data.setdefault("track", {})
    if robot.get("kind") == "fake-fanuc":
        robot["port"] = 0
    if robot.get("kind") == "fake-ur":
        from sim_fakes.loopback import free_loopback_host

        robot["host"] = free_loopback_host()
    if track.get("kind") == "fake":
        track["port"] = 0
    camera = data.get("camera", {})
    if camera.get("playback"):
        camera["playback"] = [str((base / p).resolve()) for p in camera["playback"]]
    hand_eye = data.get("hand_eye", {})
    if isinstance(hand_eye.get("path"), str):
        hand_eye["path"] = str((base / hand_eye["path"]).resolve())
    daemon = data.setdefault("daemon", {})
    daemon["journal"] = str(workdir / "journal.sqlite3")
    daemon["status_image"] = str(workdir / "status.png")
    path = workdir / "cell.toml"
    path.write_text(f"# soak copy of {config_path}\n" + toml_dumps(data), encoding="utf-8")
    return path, data


def job_variant(job: dict[str, Any], planned: PlannedJob) -> str:
    """The TOML of ``planned``: the job renamed ``soak-NNN-<kind>-<workpiece>``; for ``unreachable_pose`` its first
    capture pose 3 m away; for ``malformed`` an unknown key or broken TOML (by turns)."""
    data = json.loads(json.dumps(job))  # a deep copy
    data["workpiece"] = f"soak-{planned.index:03d}-{planned.kind}-{job.get('workpiece', 'job')}"
    if planned.kind == "unreachable_pose":
        capture = data["capture"][0]
        if "xyzwpr_mm_deg" in capture:
            capture["xyzwpr_mm_deg"] = [0.0, 3000.0, 400.0, *capture["xyzwpr_mm_deg"][3:]]
        else:
            capture["xyz_m"] = [0.0, 3.0, 0.4]
    text = toml_dumps(data)
    if planned.kind == "malformed":
        if planned.occurrence % 2:
            return text[: len(text) // 2] + "\n[[capture]\n"  # a torn upload
        return text + "\n[welding_parameters]\ncurrent_a = 180\n"  # a table no job file has
    return text
