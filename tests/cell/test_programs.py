"""URScript and FANUC LS export: exactly the planned poses and values, parsed back within the printed precision;
hostile names and comments sanitised; NaN/inf refused."""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable

import numpy as np
import pytest

from cell.errors import SafetyViolation
from cell.planning import CellGeometry, MoveKind, Reach, TrackAxis, WeldParams, WeldPath, plan_weld_path
from cell.programs import (
    fanuc_ls_program,
    fmt_fixed,
    sanitize_comment,
    sanitize_name,
    urscript_program,
)
from cell.world_seams import world_seams
from perception.seams import Seam
from perception.transforms import X_from_ur_pose, make_X, rotation_angle_rad, ur_pose_from_X, xyzwpr_mm_deg_from_X

HOSTILE = 'x"; DO[1]=ON ;\n/END\nend\nsocket_open("10.0.0.1", 1)  # évil'


def seam(seam_id: int, p0: tuple[float, float, float], p1: tuple[float, float, float], tilt_deg: float) -> Seam:
    a, b = np.asarray(p0, float), np.asarray(p1, float)
    pts = np.linspace(a, b, 9)
    x = (b - a) / np.linalg.norm(b - a)
    z = np.array([0.0, math.sin(math.radians(tilt_deg)), -math.cos(math.radians(tilt_deg))])
    z -= (z @ x) * x
    z /= np.linalg.norm(z)
    R = np.column_stack([x, np.cross(z, x), z])
    return Seam(
        seam_id, "linear", pts, np.stack([make_X(R, p) for p in pts]), float(np.linalg.norm(b - a)), 0.9, frame="base"
    )


PARAMS = WeldParams(
    travel_speed_m_s=0.0085,
    blend_m=0.0015,
    arc_do_index=2,
    weld_job=12,
    voltage_v=22.5,
    wire_feed_m_s=0.125,
    arc_on_dwell_s=0.2,
    arc_off_dwell_s=0.35,
    work_angle_rad=math.radians(5),
    travel_angle_rad=math.radians(10),
)


@pytest.fixture(scope="module")
def path() -> WeldPath:
    seams = world_seams(
        [seam(0, (0.5, -0.1, 0.0), (0.5, 0.06, 0.01), 40.0), seam(1, (0.62, 0.1, 0.0), (0.55, 0.2, 0.0), -30.0)],
        track_position_m=0.25,
    )
    geometry = CellGeometry(Reach(radius_m=1.0, preferred_m=0.6), TrackAxis(0.0, 2.0))
    out = plan_weld_path(seams, PARAMS, geometry=geometry, track_position_m=0.25)
    assert out.track_positions_m == (0.25,)
    return out


def all_waypoints(path: WeldPath) -> list:
    return [w for _, _, w in path.waypoints()]


# ------------------------------------------------------------------------------------------------ URScript
MOVEL = re.compile(r"^  movel\(p\[([^\]]*)\], a=([0-9.]+), v=([0-9.]+), r=([0-9.]+)\)  # ([a-z_\[\]0-9]+)$")


def test_urscript_holds_exactly_the_planned_moves_and_arc_io(path: WeldPath) -> None:
    text = urscript_program(path, name="weld job 7")
    lines = text.splitlines()
    assert lines[0] == "def WELD_JOB_7():" and lines[-1] == "end"
    waypoints = all_waypoints(path)
    moves = [MOVEL.match(line) for line in lines if "movel(" in line]
    assert all(moves) and len(moves) == len(waypoints)
    for m, w in zip(moves, waypoints, strict=True):
        assert m is not None
        pose = np.array([float(v) for v in m.group(1).split(", ")])
        np.testing.assert_allclose(pose, ur_pose_from_X(w.X_base_tcp), rtol=0, atol=0.5e-6 + 1e-12)
        X = X_from_ur_pose(pose)
        assert np.linalg.norm(X[:3, 3] - w.X_base_tcp[:3, 3]) < 1e-6
        assert rotation_angle_rad(X, w.X_base_tcp) < 2e-6
        assert float(m.group(2)) == PARAMS.accel_m_s2
        assert abs(float(m.group(3)) - w.speed_m_s) <= 0.5e-5
        assert abs(float(m.group(4)) - w.blend_m) <= 0.5e-5
        assert m.group(5) == w.label
    # the arc: on right after each arc-on point (reached with r=0), a dwell, off after the dwell at arc-off
    events = []
    for line in lines[1:-1]:
        if line.startswith("  # "):
            continue
        m = MOVEL.match(line)
        events.append(m.group(5) if m else line.strip())
    expected = ["set_standard_digital_out(2, False)"]
    for p in path.passes:
        for w in p.waypoints:
            expected.append(w.label)
            if w is p.arc_on:
                expected += ["set_standard_digital_out(2, True)", "sleep(0.200)"]
            if w is p.arc_off:
                expected += ["sleep(0.350)", "set_standard_digital_out(2, False)"]
    assert events == expected
    assert "arc: standard digital output 2, weld job 12, 22.50 V, wire feed 0.12500 m/s" in text
    assert "run with the track at 0.250000 m" in text


def test_urscript_sanitises_names_and_comments() -> None:
    params = WeldParams()
    one = world_seams([seam(0, (0.5, 0.0, 0.0), (0.5, 0.1, 0.0), 0.0)])
    path = plan_weld_path(one, params, geometry=CellGeometry(Reach(1.0, 0.6)))
    text = urscript_program(path, name=HOSTILE, comment=HOSTILE)
    lines = text.splitlines()
    assert re.fullmatch(r"def [A-Z][A-Z0-9_]{0,30}\(\):", lines[0]), lines[0]
    assert lines[0] == "def X_DO_1_ON_END_END_SOCKET_OPEN_1():"
    assert sum(line.startswith("def ") for line in lines) == 1 and lines.count("end") == 1 and lines[-1] == "end"
    allowed = re.compile(
        r"^  (# [A-Za-z0-9 _.,:=+\-/()%\[\]]*|movel\(.*\)  # [a-z_\[\]0-9]+"
        r"|set_standard_digital_out\(\d, (True|False)\))$"
    )
    for line in lines[1:-1]:
        assert allowed.match(line), line
    assert sum("set_standard_digital_out(0, True)" in line for line in lines) == 1
    comment_lines = [line for line in lines if line.startswith("  # x")]
    assert comment_lines == ["  # x DO[1]=ON /END end socket_open( 10.0.0.1 , 1) vil"]  # inert: one comment line


# ------------------------------------------------------------------------------------------------ FANUC LS
MN_LINE = re.compile(r"^ {0,3}(\d+):(.*)$")
MOTION = re.compile(r"^L P\[(\d+)\] (\d+)(mm/sec|cm/min) (FINE|CNT\d+) ;$")
POS = re.compile(
    r"P\[(\d+)\]\{\n   GP1:\n\tUF : (\d+), UT : (\d+),\t\tCONFIG : '([^']*)',\n"
    r"\tX = +(-?\d+\.\d{3})  mm,\tY = +(-?\d+\.\d{3})  mm,\tZ = +(-?\d+\.\d{3})  mm,\n"
    r"\tW = +(-?\d+\.\d{3}) deg,\tP = +(-?\d+\.\d{3}) deg,\tR = +(-?\d+\.\d{3}) deg\n\};"
)


def parse_ls(text: str) -> tuple[list[str], dict[int, tuple]]:
    assert text.endswith("/END\n")
    mn_part = text.split("/MN\n")[1].split("/POS\n")[0]
    body = []
    for k, line in enumerate(mn_part.splitlines(), start=1):
        m = MN_LINE.match(line)
        assert m and int(m.group(1)) == k, line
        body.append(m.group(2).strip())
    pos_part = text.split("/POS\n")[1].split("/END")[0]
    positions = {int(m.group(1)): m.groups()[1:] for m in POS.finditer(pos_part)}
    assert len(positions) == pos_part.count("P[")
    return body, positions


def test_ls_holds_exactly_the_planned_positions_speeds_and_arc_io(path: WeldPath) -> None:
    text = fanuc_ls_program(path, name="seam_job", uframe=3, utool=2, configuration="F U T, 0, 0, 1")
    assert text.startswith("/PROG  SEAM_JOB\n/ATTR\n")
    body, positions = parse_ls(text)
    assert f"LINE_COUNT\t= {len(body)};" in text
    waypoints = all_waypoints(path)
    motions = [MOTION.match(line) for line in body if line.startswith("L ")]
    assert all(motions) and len(motions) == len(waypoints) == len(positions)
    for n, (m, w) in enumerate(zip(motions, waypoints, strict=True), start=1):
        assert m is not None and int(m.group(1)) == n
        value, unit, term = int(m.group(2)), m.group(3), m.group(4)
        if w.kind is MoveKind.WELD:
            assert unit == "cm/min" and abs(value / 6000.0 - w.speed_m_s) <= 0.5 / 6000.0
        else:
            assert unit == "mm/sec" and abs(value / 1000.0 - w.speed_m_s) <= 0.5 / 1000.0
        assert term == ("FINE" if w.blend_m == 0 else "CNT15")  # 1.5 mm on weldcell's 10 mm = CNT100 scale
        uf, ut, config, *numbers = positions[n]
        assert (uf, ut, config) == ("3", "2", "F U T, 0, 0, 1")
        np.testing.assert_allclose(
            [float(v) for v in numbers], xyzwpr_mm_deg_from_X(w.X_base_tcp), rtol=0, atol=0.5e-3 + 1e-9
        )
    assert body[:3] == ["!weldcell 2 passes ;", "!track at 250.0 mm ;", "!TCP = contact tip ;"]
    events = [line for line in body if not line.startswith("!") and not line.startswith("L ")]
    expected = ["UFRAME_NUM=3 ;", "UTOOL_NUM=2 ;", "DO[3]=OFF ;"]
    expected += ["DO[3]=ON ;", "WAIT 0.20(sec) ;", "WAIT 0.35(sec) ;", "DO[3]=OFF ;"] * 2
    assert events == expected
    assert "!weld job 12 ;" in body and "!22.50 V ;" in body


def test_ls_sanitises_names_and_comments(path: WeldPath) -> None:
    text = fanuc_ls_program(path, name=HOSTILE, comment=HOSTILE)
    assert text.splitlines()[0] == "/PROG  X_DO_1_ON_END_END_SOCKET_OPEN_10_0_0"
    assert len("X_DO_1_ON_END_END_SOCKET_OPEN_10_0_0") == 36
    assert fanuc_ls_program(path, name=HOSTILE, max_name_len=8).splitlines()[0] == "/PROG  X_DO_1_O"
    assert text.count("/END") == 1 and text.count("/PROG") == 1 and text.count("/MN") == 1
    body, _ = parse_ls(text)
    allowed = re.compile(
        r"^(![A-Za-z0-9 _.,:=+\-()%\[\]]{1,32} ;|L P\[\d+\] \d+(mm/sec|cm/min) (FINE|CNT\d+) ;"
        r"|UFRAME_NUM=\d+ ;|UTOOL_NUM=\d+ ;|DO\[\d+\]=(ON|OFF) ;|WAIT \d+\.\d\d\(sec\) ;)$"
    )
    for line in body:
        assert allowed.match(line), line
    assert body.count("DO[3]=ON ;") == len(path.passes)
    assert "!x DO[1]=ON END end socket_open( ;" in body  # cut to 32 characters, nothing that ends a statement
    assert 'COMMENT\t\t= "x DO[1]=ON END e";' in text
    for bad in ("IDEA", "N U T, 0, 0, 0'; DO[1]=ON"):
        with pytest.raises(SafetyViolation, match="configuration"):
            fanuc_ls_program(path, name="A", configuration=bad)


# ------------------------------------------------------------------------------------------------ refusals
def with_travel_pose(path: WeldPath, X: np.ndarray) -> WeldPath:
    p = path.passes[0]
    wps = list(p.waypoints)
    wps[3] = dataclasses.replace(wps[3], X_base_tcp=X)
    return dataclasses.replace(path, passes=(dataclasses.replace(p, waypoints=tuple(wps)), *path.passes[1:]))


@pytest.mark.parametrize("export", [urscript_program, fanuc_ls_program])
def test_nan_inf_and_bad_poses_are_refused(path: WeldPath, export: Callable[..., str]) -> None:
    X = path.passes[0].waypoints[3].X_base_tcp.copy()
    X[0, 3] = np.nan
    with pytest.raises(SafetyViolation, match=r"pass 1 \(seam \d\) travel\[2\] pose: contains NaN or inf at \[0, 3\]"):
        export(with_travel_pose(path, X), name="p")
    X = path.passes[0].waypoints[3].X_base_tcp @ np.diag([1.0, -1.0, 1.0, 1.0])
    with pytest.raises(SafetyViolation, match="reflection"):
        export(with_travel_pose(path, X), name="p")
    p = path.passes[1]
    bad_speed = dataclasses.replace(
        p, waypoints=(dataclasses.replace(p.waypoints[0], speed_m_s=math.inf), *p.waypoints[1:])
    )
    with pytest.raises(SafetyViolation, match="inf"):
        export(dataclasses.replace(path, passes=(path.passes[0], bad_speed)), name="p")
    bad_blend = dataclasses.replace(
        p, waypoints=(*p.waypoints[:3], dataclasses.replace(p.waypoints[3], blend_m=math.nan), *p.waypoints[4:])
    )
    with pytest.raises(SafetyViolation, match="nan"):
        export(dataclasses.replace(path, passes=(path.passes[0], bad_blend)), name="p")
    bad_track = dataclasses.replace(
        path, passes=tuple(dataclasses.replace(q, track_position_m=math.nan) for q in path.passes)
    )
    with pytest.raises(SafetyViolation, match="track position is nan"):
        export(bad_track, name="p")


def test_speeds_that_print_as_zero_are_refused(path: WeldPath) -> None:
    p = path.passes[0]
    slow = dataclasses.replace(p, waypoints=(dataclasses.replace(p.waypoints[0], speed_m_s=1e-7), *p.waypoints[1:]))
    slow_path = dataclasses.replace(path, passes=(slow, path.passes[1]))
    with pytest.raises(SafetyViolation, match=r"prints as 0\.00000: must be > 0"):
        urscript_program(slow_path, name="p")
    with pytest.raises(SafetyViolation, match=r"approach: speed in mm/sec = 0\.0001 rounds to 0, below 1"):
        fanuc_ls_program(slow_path, name="p")


def test_a_path_across_track_positions_is_exported_in_parts() -> None:
    seams = world_seams(
        [seam(0, (0.5, 0.0, 0.0), (0.5, 0.1, 0.0), 0.0), seam(1, (0.5, 2.0, 0.0), (0.5, 2.1, 0.0), 0.0)]
    )
    geometry = CellGeometry(Reach(radius_m=0.9, preferred_m=0.6), TrackAxis(0.0, 3.0))
    path = plan_weld_path(seams, WeldParams(), geometry=geometry)
    assert len(path.track_positions_m) == 2
    for export in (urscript_program, fanuc_ls_program):
        with pytest.raises(ValueError, match="spans 2 track positions"):
            export(path, name="p")
    parts = path.split_at_track_moves()
    assert [q.track_positions_m for q in parts] == [(t,) for t in path.track_positions_m]
    for part in parts:
        assert urscript_program(part, name="p").count("set_standard_digital_out(0, True)") == 1
        assert fanuc_ls_program(part, name="p").count("DO[1]=ON") == 1


def test_sanitizers_and_number_format() -> None:
    assert sanitize_name("123abc", max_len=8) == "W123ABC"
    assert sanitize_name("", max_len=8) == "WELD"
    assert sanitize_name("___", max_len=8) == "WELD"
    assert sanitize_name("seam-job.final version", max_len=36) == "SEAM_JOB_FINAL_VERSION"
    assert sanitize_name("a" * 50, max_len=36) == "A" * 36
    assert sanitize_comment("one;\ntwo\"'#!\x00three", max_len=100) == "one two three"
    assert fmt_fixed(-1e-9, 3, "x") == "0.000"
    assert fmt_fixed(-0.0004, 3, "x") == "0.000"
    assert fmt_fixed(-0.0006, 3, "x") == "-0.001"
    assert fmt_fixed(1.23456, 4, "x") == "1.2346"
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(SafetyViolation, match="refusing to write it"):
            fmt_fixed(bad, 3, "value")
