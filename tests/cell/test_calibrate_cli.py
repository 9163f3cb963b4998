"""``weldcell calibrate``: the hand-eye wizard on the simulated FANUC cell from the command line (it writes the
file the cell reads and keeps the previous one; SIGINT exits 130 with one line and changes no file; too few
views, a degenerate plan and a declined plan exit 1 with one line; manual mode reads stdin; bad config exits 2),
and ``weldcell calibrate board``."""

from __future__ import annotations

import json
import logging
import os
import re
import signal
import subprocess
import sys
import threading
import time
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from calibration.board import CharucoBoardSpec, detect_board, read_png_scale_px_per_m
from cell.config import load_config
from tests.calibration.test_wizard import CAD_HAND_EYE, TOL_DEG, TOL_MM, calib_config, mount_error, true_mount

REPO = Path(__file__).resolve().parents[2]


def weldcell(*args: str) -> list[str]:
    return [sys.executable, "-m", "cell.cli", *args]


def run_weldcell(*args: str, stdin: str = "", timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(weldcell(*args), cwd=REPO, input=stdin, capture_output=True, text=True, timeout=timeout_s)


def run_in_process(capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture, *args: str):
    """``weldcell ARGS`` through ``cell.cli.main`` in this process, for commands that start no device: the same exit
    code, stdout and stderr (log records at WARNING and above, which the command line prints, count as stderr)."""
    from cell.cli import main

    caplog.set_level(logging.WARNING)
    try:
        code = main(list(args))
    except SystemExit as exit_:  # argparse's own refusals
        code = exit_.code if isinstance(exit_.code, int) else 1
    out = capsys.readouterr()
    logged = "".join(f"{r.levelname} {r.name}: {r.getMessage()}\n" for r in caplog.records)
    return subprocess.CompletedProcess(["weldcell", *args], code, out.out, out.err + logged)


def files_in(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def one_line(stderr: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


@pytest.mark.timeout(60)
def test_hand_eye_on_the_simulated_fanuc_writes_the_file_the_cell_reads(tmp_path: Path) -> None:
    previous = json.dumps(CAD_HAND_EYE)
    (tmp_path / "hand_eye.json").write_text(previous, encoding="utf-8")
    config = calib_config(tmp_path, poses=8)
    result = run_weldcell("calibrate", "hand-eye", "--config", str(config), "--with-sims", "--yes")
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    out = result.stdout
    for expected in (
        "Checking the devices",
        "  robot   idle, tool at (500.0, 0.0, 400.0) mm",
        "  camera  640x360, fx 460.0 px, fy 460.0 px",
        "8 views + 1 held out; stand-off 0.35 m, tilt 10-35 deg, seed 0",
        "Move the robot in straight lines through 8 views and one held-out view at 0.5 m/s",
        "  view  8/8  40 corners, board fit ",
        "residuals per view (refined, started from ",
        "  held-out view: ",
        "verdict: PASS",
        f"Write the result to {tmp_path / 'hand_eye.json'} (the current one is kept as "
        f"{tmp_path / 'hand_eye.json.prev'})? yes (--yes)",
        f"wrote {tmp_path / 'hand_eye.json'} (previous kept as {tmp_path / 'hand_eye.json.prev'})",
    ):
        assert expected in out, expected
    assert (tmp_path / "hand_eye.json.prev").read_text(encoding="utf-8") == previous
    # the cell now reads the calibrated mount, which is the simulator's true one
    cell_config = load_config(config)
    X_tool_camera = cell_config.X_tool_camera()
    assert X_tool_camera is not None
    err_mm, err_deg = mount_error(X_tool_camera, true_mount(cell_config))
    assert err_mm < TOL_MM and err_deg < TOL_DEG, (err_mm, err_deg)
    doc = json.loads((tmp_path / "hand_eye.json").read_text(encoding="utf-8"))
    assert doc["source"] == str(config) and doc["n_views"] == 8 and doc["verdict"] == "pass"


@pytest.mark.timeout(60)
def test_sigint_mid_motion_exits_130_with_one_line_and_changes_no_file(tmp_path: Path) -> None:
    (tmp_path / "hand_eye.json").write_text(json.dumps(CAD_HAND_EYE), encoding="utf-8")
    config = calib_config(tmp_path, poses=8, speed_m_s=0.05)  # slow moves: the signal lands in one
    before = files_in(tmp_path)
    proc = subprocess.Popen(
        weldcell("calibrate", "hand-eye", "--config", str(config), "--with-sims", "--yes"),
        cwd=REPO,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    seen: list[str] = []
    collecting = threading.Event()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            seen.append(line.rstrip("\n"))
            if line.startswith("Collecting the views"):
                collecting.set()

    reader = threading.Thread(target=read, name="calibrate-reader", daemon=True)
    reader.start()
    try:
        assert collecting.wait(timeout=30), seen
        time.sleep(0.5)  # on its way to view 1 (0.05 m/s)
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=15)
        reader.join(timeout=5)
        assert proc.stderr is not None
        stderr = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
    assert code == 130
    assert one_line(stderr) == (
        f"weldcell calibrate: interrupted at view 1/8 (moving); robot stopped, {tmp_path / 'hand_eye.json'} unchanged"
    )
    assert not any(line.lstrip().startswith("view  1/8") for line in seen)  # no view was captured
    assert files_in(tmp_path) == before


@pytest.mark.timeout(60)
def test_too_few_usable_views_exits_1_with_the_reason(tmp_path: Path) -> None:
    (tmp_path / "hand_eye.json").write_text(json.dumps(CAD_HAND_EYE), encoding="utf-8")
    config = calib_config(tmp_path, poses=8, board_shift_x_m=0.36)
    before = files_in(tmp_path)
    result = run_weldcell("calibrate", "hand-eye", "--config", str(config), "--with-sims", "--yes")
    assert result.returncode == 1
    reason = one_line(result.stderr)
    assert reason.startswith("weldcell calibrate: only ")
    assert "of 8 views are usable, at least 6 are needed (view" in reason
    assert "skipped: board view rejected: " in result.stdout
    assert files_in(tmp_path) == before


@pytest.mark.timeout(60)
def test_a_degenerate_plan_file_is_refused_before_any_motion(tmp_path: Path) -> None:
    config = calib_config(tmp_path, result_file=None)
    # 9 poses over the board, tool pointing straight down, translated only
    poses = []
    for k in range(9):
        X = np.diag([1.0, -1.0, -1.0, 1.0])
        X[:3, 3] = [0.45 + 0.03 * (k % 3), -0.03 + 0.03 * (k // 3), 0.40]
        poses.append(X.tolist())
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"X_base_tool": poses}), encoding="utf-8")
    out = tmp_path / "out.json"
    result = run_weldcell(
        "calibrate", "hand-eye", "--config", str(config), "--with-sims", "--yes", "--plan", str(plan), "--out", str(out)
    )
    assert result.returncode == 1
    assert one_line(result.stderr).startswith(
        "weldcell calibrate: plan refused before any motion: pure translations: the robot only translated"
    )
    assert "Collecting the views" not in result.stdout and "Move the robot" not in result.stdout
    assert not out.exists()


@pytest.mark.timeout(60)
def test_manual_mode_reads_enter_from_stdin(tmp_path: Path) -> None:
    config = calib_config(tmp_path, poses=6, result_file=None)
    out = tmp_path / "out.json"
    # nobody jogs the robot: Enter six times captures the same pose six times
    result = run_weldcell(
        "calibrate", "hand-eye", "--config", str(config), "--with-sims", "--yes", "--manual", "--out", str(out),
        stdin="\n" * 6,
    )  # fmt: skip
    assert result.returncode == 1
    assert result.stdout.count("  suggested tool pose: (") == 6
    assert result.stdout.count("skipped: same pose as view 1; move and rotate the tool") == 5
    assert re.search(r"\n  view  1/6  \d\d corners, board fit ", result.stdout)
    assert one_line(result.stderr).startswith(
        "weldcell calibrate: only 1 of 6 views are usable, at least 6 are needed "
        "(views 2, 3, 4, 5, 6: same pose as view 1; move and rotate the tool)"
    )
    assert not out.exists()


@pytest.mark.timeout(60)
def test_declining_the_plan_exits_1_and_moves_nothing(tmp_path: Path) -> None:
    config = calib_config(tmp_path, result_file=None)
    result = run_weldcell(
        "calibrate", "hand-eye", "--config", str(config), "--with-sims", "--out", str(tmp_path / "o.json"), stdin="n\n"
    )
    assert result.returncode == 1
    assert one_line(result.stderr) == (
        "weldcell calibrate: calibration cancelled by the operator before any motion; nothing written"
    )
    assert "Move the robot in straight lines through 8 views" in result.stdout
    assert "Collecting the views" not in result.stdout


@pytest.mark.timeout(30)
def test_config_mistakes_exit_2(tmp_path: Path, capsys, caplog) -> None:
    run = partial(run_in_process, capsys, caplog)  # nothing starts before these refusals: no interpreter of its own
    result = run("calibrate", "hand-eye", "--config", str(REPO / "examples" / "sim-cell-fanuc.toml"))
    assert result.returncode == 2
    assert one_line(result.stderr) == (
        f"weldcell calibrate: {REPO / 'examples' / 'sim-cell-fanuc.toml'}: hand_eye.calibration: missing; the "
        "wizard needs the board, its nominal pose and the workspace there (see examples/sim-calib.toml)"
    )
    config = calib_config(tmp_path)
    result = run("calibrate", "hand-eye", "--config", str(config), "--poses", "4")
    assert result.returncode == 2
    assert one_line(result.stderr) == "weldcell calibrate: --poses 4 is below min_views = 6 of [hand_eye.calibration]"
    inline = calib_config(tmp_path, result_file=None, name="inline.toml")
    result = run("calibrate", "hand-eye", "--config", str(inline))
    assert result.returncode == 2
    assert "X_tool_camera is given inline, so there is no result file to update; give --out FILE" in result.stderr


@pytest.mark.timeout(30)
def test_board_command_writes_a_printable_detectable_board(tmp_path: Path, capsys, caplog) -> None:
    out = tmp_path / "board.png"
    run = partial(run_in_process, capsys, caplog)  # the board command starts nothing: in this process
    result = run("calibrate", "board", "--out", str(out), "--config", str(REPO / "examples" / "sim-calib.toml"))
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(
        f"wrote {out}: 9x6 squares of 30 mm, markers 22 mm, DICT_5X5_100; board 270 x 180 mm"
    )
    px_per_m = read_png_scale_px_per_m(out)
    assert px_per_m is not None and abs(px_per_m * 0.0254 - 300.0) < 3.0  # 300 dpi, whole pixels per square
    import cv2

    image = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    assert image is not None
    board = CharucoBoardSpec(squares_x=9, squares_y=6, square_length_m=0.030, marker_length_m=0.022)
    # seen straight on from 1 m by a camera with f = px_per_m: every corner is found
    K = np.array([[px_per_m, 0.0, image.shape[1] / 2], [0.0, px_per_m, image.shape[0] / 2], [0.0, 0.0, 1.0]])
    assert detect_board(image, board=board, K=K).n_corners == board.n_corners
    result = run("calibrate", "board", "--out", str(tmp_path / "b.png"), "--squares", "nine")
    assert result.returncode == 2
    assert one_line(result.stderr) == "weldcell calibrate: --squares must look like 9x6, got 'nine'"
