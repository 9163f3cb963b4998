"""Export a :class:`cell.planning.WeldPath` as a robot program: URScript for a UR, LS (TP source) for a FANUC.

This is a unit boundary: inside, SI (m, rad, m/s); URScript takes metres, rotation vectors in radians and m/s, so
only the number format changes; FANUC LS takes millimetres, degrees (XYZWPR, extrinsic xyz as in
:func:`perception.transforms.xyzwpr_mm_deg_from_X`), mm/sec for air, approach and retract moves and cm/min for
weld moves (finer steps at welding speeds, as TP speeds are integers).

Everything that goes into the text is sanitised: names to ``[A-Z0-9_]`` starting with a letter (URScript: a
function name, at most :data:`UR_NAME_MAX` characters; FANUC: a program name, at most 36 characters on R-30iB,
8 on older controllers: ``max_name_len``); comments to a whitelist of characters that cannot end a comment or a
statement (no newline, ``;``, quotes, ``#``, ``!``; for FANUC no ``/``), cut to the format's length; numbers
finite, printed with fixed decimals. A NaN or inf anywhere, a pose that is not a proper rigid transform, or a speed
that would print as 0 raises :class:`cell.errors.SafetyViolation`: a program is never written with a bad number.

A program covers the passes at one track position (a robot program cannot move the ground track): split a path
with :meth:`cell.planning.WeldPath.split_at_track_moves` and run the track move between programs. The programs
assume the controller's TCP is the contact tip (see :mod:`cell.planning`).
"""

from __future__ import annotations

import math
import re

import numpy as np

from cell.errors import SafetyViolation
from cell.planning import MoveKind, SeamPass, WeldPath
from cell.safety import check_pose
from drivers.fanuc import CNT100_BLEND_M
from perception.transforms import ur_pose_from_X, xyzwpr_mm_deg_from_X

UR_NAME_MAX = 31
"""URScript function names have no documented limit; 31 characters is a conservative bound."""

FANUC_NAME_MAX = 36
"""R-30iB program names; R-30iA and older take 8 (pass ``max_name_len=8``)."""

FANUC_REMARK_MAX = 32
FANUC_PROG_COMMENT_MAX = 16
UR_COMMENT_MAX = 100

DEFAULT_FANUC_CONFIG = "N U T, 0, 0, 0"

_NAME_BAD = re.compile(r"[^A-Z0-9_]+")
_COMMENT_BAD = re.compile(r"[^A-Za-z0-9 _.,:=+\-/()%\[\]]+")
_FANUC_CONFIG = re.compile(r"^[NF] [UD] [TB], -?[0-9]{1,2}, -?[0-9]{1,2}, -?[0-9]{1,2}$")


# ================================================================================================ sanitising
def sanitize_name(name: str, *, max_len: int, default: str = "WELD") -> str:
    """``name`` as ``[A-Z0-9_]``, starting with a letter, at most ``max_len`` characters."""
    if max_len < 1:
        raise ValueError(f"max_len must be >= 1, got {max_len}")
    cleaned = _NAME_BAD.sub("_", str(name).upper()).strip("_")
    cleaned = re.sub(r"_+", "_", cleaned)
    if not cleaned:
        cleaned = default
    if not cleaned[0].isalpha():
        cleaned = "W" + cleaned
    return cleaned[:max_len].rstrip("_") or default[:max_len]


def sanitize_comment(text: str, *, max_len: int, no_slash: bool = False) -> str:
    """``text`` on one line, only characters that are inert in a URScript ``#`` comment and a FANUC ``!`` remark;
    ``no_slash`` also drops ``/`` (FANUC: LS sections start with it)."""
    cleaned = _COMMENT_BAD.sub(" ", str(text))
    if no_slash:
        cleaned = cleaned.replace("/", " ")
    cleaned = re.sub(r"\s+", " ", cleaned).strip()
    return cleaned[:max_len].rstrip()


def fmt_fixed(value: float, decimals: int, what: str) -> str:
    """``value`` with exactly ``decimals`` decimals; SafetyViolation for NaN/inf. Never prints ``-0.000``."""
    v = float(value)
    if not math.isfinite(v):
        raise SafetyViolation(f"{what} is {v}: refusing to write it into a program")
    text = f"{v:.{decimals}f}"
    if float(text) == 0.0:
        text = f"{0.0:.{decimals}f}"
    return text


def _fmt_positive(value: float, decimals: int, what: str) -> str:
    text = fmt_fixed(value, decimals, what)
    if float(text) <= 0.0:
        raise SafetyViolation(f"{what} = {value!r} prints as {text}: must be > 0")
    return text


def _fmt_int(value: float, what: str, *, minimum: int) -> int:
    v = float(value)
    if not math.isfinite(v):
        raise SafetyViolation(f"{what} is {v}: refusing to write it into a program")
    n = round(v)
    if n < minimum:
        raise SafetyViolation(f"{what} = {v:.6g} rounds to {n}, below {minimum}")
    return n


def _single_track_position(weld_path: WeldPath) -> float:
    if not weld_path.passes:
        raise ValueError("the weld path has no pass: nothing to write")
    positions = {p.track_position_m for p in weld_path.passes}
    if len(positions) != 1:
        raise ValueError(
            f"the weld path spans {len(positions)} track positions; a robot program cannot move the track: "
            "export each part of WeldPath.split_at_track_moves() and move the track between them"
        )
    t = float(next(iter(positions)))
    if not math.isfinite(t):
        raise SafetyViolation(f"track position is {t}: refusing to write it into a program")
    return t


def _arc_notes(weld_path: WeldPath, *, per: str = "/") -> list[str]:
    p = weld_path.params
    notes = []
    if p.weld_job is not None:
        notes.append(f"weld job {int(p.weld_job)}")
    if p.voltage_v is not None:
        notes.append(f"{fmt_fixed(p.voltage_v, 2, 'voltage_v')} V")
    if p.wire_feed_m_s is not None:
        notes.append(f"wire feed {fmt_fixed(p.wire_feed_m_s, 5, 'wire_feed_m_s')} m{per}s")
    return notes


def _passes(weld_path: WeldPath) -> str:
    n = len(weld_path.passes)
    return f"{n} pass" if n == 1 else f"{n} passes"


def _pass_title(k: int, p: SeamPass) -> str:
    direction = "reversed" if p.reversed else "forward"
    return f"pass {k + 1}: seam {p.seam_id}, {direction}, {fmt_fixed(p.length_m, 4, 'seam length')} m"


# ================================================================================================ URScript
def urscript_program(weld_path: WeldPath, *, name: str, comment: str = "") -> str:
    """A URScript program (``def NAME(): ... end``) welding every pass of ``weld_path``.

    ``movel(p[x, y, z, rx, ry, rz], a=, v=, r=)``: metres, rotation vector in radians, m/s², m/s, blend radius m;
    arc on/off with ``set_standard_digital_out(arc_do_index, True/False)`` at the arc-on and arc-off points
    (reached with r=0), dwell with ``sleep``.
    """
    t = _single_track_position(weld_path)
    params = weld_path.params
    prog = sanitize_name(name, max_len=UR_NAME_MAX)
    do = int(params.arc_do_index)
    if not 0 <= do <= 7:
        raise SafetyViolation(f"arc_do_index {do}: a UR has standard digital outputs 0-7")
    accel = _fmt_positive(params.accel_m_s2, 4, "acceleration accel_m_s2")
    lines = [f"def {prog}():"]

    def note(text: str) -> None:
        cleaned = sanitize_comment(text, max_len=UR_COMMENT_MAX)
        if cleaned:
            lines.append(f"  # {cleaned}")

    note(f"weldcell weld program {prog}: {_passes(weld_path)}")
    note(comment)
    note("poses: TCP = contact tip, robot base frame, metres and rotation vectors (rad)")
    note(f"run with the track at {fmt_fixed(t, 6, 'track position')} m")
    note(f"arc: standard digital output {do}" + "".join(f", {n}" for n in _arc_notes(weld_path)))
    lines.append(f"  set_standard_digital_out({do}, False)")
    for k, seam_pass in enumerate(weld_path.passes):
        note(_pass_title(k, seam_pass))
        for w in seam_pass.waypoints:
            where = f"pass {k + 1} (seam {seam_pass.seam_id}) {w.label}"
            X = check_pose(w.X_base_tcp, where)
            pose = ", ".join(fmt_fixed(v, 6, f"{where}: pose") for v in ur_pose_from_X(X))
            v = _fmt_positive(w.speed_m_s, 5, f"{where}: speed")
            r = fmt_fixed(w.blend_m, 5, f"{where}: blend")
            if float(r) < 0:
                raise SafetyViolation(f"{where}: blend radius {w.blend_m!r} is negative")
            label = sanitize_comment(w.label, max_len=40)
            lines.append(f"  movel(p[{pose}], a={accel}, v={v}, r={r})  # {label}")
            if w is seam_pass.arc_on:
                lines.append(f"  set_standard_digital_out({do}, True)")
                if params.arc_on_dwell_s > 0:
                    lines.append(f"  sleep({fmt_fixed(params.arc_on_dwell_s, 3, 'arc_on_dwell_s')})")
            if w is seam_pass.arc_off:
                if params.arc_off_dwell_s > 0:
                    lines.append(f"  sleep({fmt_fixed(params.arc_off_dwell_s, 3, 'arc_off_dwell_s')})")
                lines.append(f"  set_standard_digital_out({do}, False)")
    lines.append("end")
    return "\n".join(lines) + "\n"


# ================================================================================================ FANUC LS
def fanuc_speed(speed_m_s: float, kind: MoveKind, what: str) -> tuple[int, str]:
    """(value, unit) of a FANUC linear speed: cm/min for weld moves, mm/sec otherwise (integers, >= 1)."""
    if kind is MoveKind.WELD:
        return _fmt_int(float(speed_m_s) * 6000.0, f"{what}: speed in cm/min", minimum=1), "cm/min"
    return _fmt_int(float(speed_m_s) * 1000.0, f"{what}: speed in mm/sec", minimum=1), "mm/sec"


def fanuc_termination(blend_m: float, what: str) -> str:
    """FINE for blend 0, else CNT n with weldcell's mapping (:data:`drivers.fanuc.CNT100_BLEND_M`)."""
    b = float(blend_m)
    if not math.isfinite(b) or b < 0:
        raise SafetyViolation(f"{what}: blend radius {b!r} is not a finite number >= 0")
    if b == 0.0:
        return "FINE"
    return f"CNT{int(np.clip(round(100.0 * b / CNT100_BLEND_M), 1, 100))}"


def fanuc_ls_program(
    weld_path: WeldPath,
    *,
    name: str,
    comment: str = "",
    uframe: int = 0,
    utool: int = 1,
    configuration: str = DEFAULT_FANUC_CONFIG,
    max_name_len: int = FANUC_NAME_MAX,
) -> str:
    """A FANUC TP program in LS text (``/PROG``, ``/ATTR``, ``/MN``, ``/POS``, ``/END``) welding ``weld_path``.

    Motion lines ``L P[n] <speed> FINE|CNTn``; the arc is ``DO[arc_do_index + 1]=ON/OFF`` (the FanucRobot
    driver's numbering); positions in user frame ``uframe`` with tool ``utool`` as XYZWPR (mm, deg) with the arm
    ``configuration`` string (e.g. ``'N U T, 0, 0, 0'``: flip, up, top, turn numbers; linear moves keep the
    configuration the robot is in, so this matters for the first point).
    """
    t = _single_track_position(weld_path)
    params = weld_path.params
    prog = sanitize_name(name, max_len=max_name_len)
    for label, value in (("uframe", uframe), ("utool", utool)):
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 61:
            raise SafetyViolation(f"{label} must be an integer in 0..61, got {value!r}")
    if not _FANUC_CONFIG.match(configuration):
        raise SafetyViolation(f"configuration {configuration!r} is not of the form 'N U T, 0, 0, 0'")
    do = int(params.arc_do_index) + 1
    mn: list[str] = []
    positions: list[str] = []

    def remark(text: str) -> None:
        cleaned = sanitize_comment(text, max_len=FANUC_REMARK_MAX, no_slash=True)
        if cleaned:
            mn.append(f"!{cleaned} ;")

    remark(f"weldcell {_passes(weld_path)}")
    remark(comment)
    remark(f"track at {fmt_fixed(t * 1000.0, 1, 'track position')} mm")
    remark("TCP = contact tip")
    for n in _arc_notes(weld_path, per=" per "):
        remark(n)
    mn.append(f"UFRAME_NUM={uframe} ;")
    mn.append(f"UTOOL_NUM={utool} ;")
    mn.append(f"DO[{do}]=OFF ;")
    for k, seam_pass in enumerate(weld_path.passes):
        remark(f"pass {k + 1} seam {seam_pass.seam_id}" + (" rev" if seam_pass.reversed else ""))
        for w in seam_pass.waypoints:
            where = f"pass {k + 1} (seam {seam_pass.seam_id}) {w.label}"
            X = check_pose(w.X_base_tcp, where)
            index = len(positions) + 1
            speed, unit = fanuc_speed(w.speed_m_s, w.kind, where)
            mn.append(f"L P[{index}] {speed}{unit} {fanuc_termination(w.blend_m, where)} ;")
            positions.append(_ls_position(index, X, uframe, utool, configuration, where))
            if w is seam_pass.arc_on:
                mn.append(f"DO[{do}]=ON ;")
                if params.arc_on_dwell_s > 0:
                    mn.append(f"WAIT {fmt_fixed(params.arc_on_dwell_s, 2, 'arc_on_dwell_s')}(sec) ;")
            if w is seam_pass.arc_off:
                if params.arc_off_dwell_s > 0:
                    mn.append(f"WAIT {fmt_fixed(params.arc_off_dwell_s, 2, 'arc_off_dwell_s')}(sec) ;")
                mn.append(f"DO[{do}]=OFF ;")
    return _ls_text(prog, comment, mn, positions)


def _ls_text(prog: str, comment: str, mn: list[str], positions: list[str]) -> str:
    """The LS file around the program's ``/MN`` lines ``mn`` and ``/POS`` entries ``positions``."""
    prog_comment = sanitize_comment(comment or "weldcell", max_len=FANUC_PROG_COMMENT_MAX, no_slash=True)
    out = [
        f"/PROG  {prog}",
        "/ATTR",
        "OWNER\t\t= MNEDITOR;",
        f'COMMENT\t\t= "{prog_comment}";',
        "PROG_SIZE\t= 0;",
        f"FILE_NAME\t= {prog};",
        "VERSION\t\t= 0;",
        f"LINE_COUNT\t= {len(mn)};",
        "MEMORY_SIZE\t= 0;",
        "PROTECT\t\t= READ_WRITE;",
        "TCD:  STACK_SIZE\t= 0,",
        "      TASK_PRIORITY\t= 50,",
        "      TIME_SLICE\t= 0,",
        "      BUSY_LAMP_OFF\t= 0,",
        "      ABORT_REQUEST\t= 0,",
        "      PAUSE_REQUEST\t= 0;",
        "DEFAULT_GROUP\t= 1,*,*,*,*;",
        "CONTROL_CODE\t= 00000000 00000000;",
        "/MN",
    ]
    for i, line in enumerate(mn, start=1):
        sep = "" if line.startswith("L ") else "  "
        out.append(f"{i:4d}:{sep}{line}")
    out.append("/POS")
    out.extend(positions)
    out.append("/END")
    return "\n".join(out) + "\n"


def _ls_position(index: int, X: np.ndarray, uframe: int, utool: int, configuration: str, where: str) -> str:
    x, y, z, w, p, r = (fmt_fixed(v, 3, f"{where}: XYZWPR") for v in xyzwpr_mm_deg_from_X(X))
    return (
        f"P[{index}]{{\n"
        "   GP1:\n"
        f"\tUF : {uframe}, UT : {utool},\t\tCONFIG : '{configuration}',\n"
        f"\tX = {x:>10s}  mm,\tY = {y:>10s}  mm,\tZ = {z:>10s}  mm,\n"
        f"\tW = {w:>10s} deg,\tP = {p:>10s} deg,\tR = {r:>10s} deg\n"
        "};"
    )
