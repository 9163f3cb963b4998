"""``weldcell calibrate``: the hand-eye calibration wizard (``hand-eye``) and the printable board (``board``).

The wizard's logic lives in :mod:`calibration.wizard`; this module reads the config, builds the cell's drivers,
and shows the run with rich (progress lines on stdout, the one-line reason of a failure on stderr).
Exit codes: 0 done (verdict pass or marginal, file written); 1 calibration refused or failed, device error,
operator declined; 2 bad config or arguments; 130 interrupted (robot stopped, result file unchanged).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:
    from rich.console import Console
    from rich.progress import Progress, TaskID

    from calibration.handeye import HandEyeResult
    from calibration.verdict import Assessment, VerdictThresholds, Verification
    from calibration.views import CalibrationPlan, ViewRecord, WizardParams
    from calibration.wizard import DeviceReport
    from cell.config import CellConfig

EXIT_INTERRUPTED = 130


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="hand-eye calibration wizard and the printable ChArUco board",
        description="'hand-eye' runs the calibration wizard on the cell of a config; 'board' writes the "
        "printable board. See docs/calibration.md.",
    )
    actions = p.add_subparsers(dest="calibrate_action", metavar="ACTION")
    actions.required = True

    he = actions.add_parser(
        "hand-eye",
        help="calibrate the camera mount: plan, move, capture, solve, verify, write",
        description="Checks the devices, plans views of the ChArUco board of [hand_eye.calibration] inside its "
        "workspace, drives the robot through them (or, with --manual, lets the operator jog to each and press "
        "Enter), detects the board, solves the hand-eye transform, shows the per-view residuals, verifies on a "
        "held-out pose and gives a verdict; then writes the result file (JSON with X_tool_camera) atomically, "
        "keeping the previous one as FILE.prev. Ctrl-C stops the robot and writes nothing (exit 130). "
        "Exit codes: 0 written, 1 calibration failed or refused, 2 bad config/arguments, 130 interrupted.",
    )
    he.add_argument("--config", required=True, help="cell config file (TOML) with a [hand_eye.calibration] table")
    he.add_argument("--poses", type=int, help="views to solve from (default: [hand_eye.calibration] poses)")
    he.add_argument("--manual", action="store_true", help="jog the robot to each view yourself and press Enter")
    he.add_argument("--out", help="result file (default: the [hand_eye] path of the config)")
    he.add_argument("--yes", action="store_true", help="answer yes to every confirmation (tests, CI)")
    he.add_argument(
        "--eye-to-hand",
        action="store_true",
        help="camera fixed, board on the tool (default: the config's mode, normally eye-in-hand)",
    )
    he.add_argument(
        "--plan",
        help="JSON file {'X_base_tool': [4x4, ...]} of poses to use instead of the planner's (the last one is the "
        "held-out verification pose); checked before any motion",
    )
    he.add_argument("--seed", type=int, help="seed of the pose plan (default: [hand_eye.calibration] seed)")
    he.add_argument(
        "--with-sims",
        action="store_true",
        help="start the config's simulators in this process first (default: connect to a running 'weldcell sim up')",
    )
    he.set_defaults(func=run_hand_eye)

    board = actions.add_parser(
        "board",
        help="write the printable ChArUco board as a PNG",
        description="Writes the board at a whole number of pixels per square near --dpi, with its scale in the "
        "PNG (pHYs) so that it prints at 100 %%. The board comes from the config's [hand_eye.calibration.board] "
        "or from the options. Measure one printed square before use.",
    )
    board.add_argument("--out", required=True, help="PNG file, or a folder (a name stating the board is made up)")
    board.add_argument("--config", help="take the board from this config's [hand_eye.calibration.board]")
    board.add_argument("--squares", default="9x6", help="squares along x and y, e.g. 9x6 (default)")
    board.add_argument("--square-mm", type=float, default=30.0, help="square side, mm (default 30)")
    board.add_argument("--marker-mm", type=float, default=22.0, help="marker side, mm (default 22)")
    board.add_argument("--dictionary", default="DICT_5X5_100", help="ArUco dictionary (default DICT_5X5_100)")
    board.add_argument("--dpi", type=float, default=300.0, help="print resolution (default 300)")
    board.add_argument("--margin-mm", type=float, default=10.0, help="white margin, mm (default 10)")
    board.set_defaults(func=run_board)


# ================================================================================================ board
def run_board(args: argparse.Namespace) -> int:
    from calibration.board import CharucoBoardSpec, render_board_png
    from cell.config import load_config
    from cell.errors import ConfigError

    if args.config:
        config = load_config(args.config)
        calibration = config.hand_eye.calibration if config.hand_eye is not None else None
        if calibration is None:
            raise ConfigError(f"{config.where('hand_eye.calibration')}: no [hand_eye.calibration.board] table")
        spec = calibration.board.spec()
    else:
        try:
            squares_x, squares_y = (int(v) for v in args.squares.lower().split("x"))
        except ValueError as err:
            raise ConfigError(f"--squares must look like 9x6, got {args.squares!r}") from err
        spec = CharucoBoardSpec(
            squares_x=squares_x,
            squares_y=squares_y,
            square_length_m=args.square_mm / 1000.0,
            marker_length_m=args.marker_mm / 1000.0,
            dictionary=args.dictionary,
        )
    path = render_board_png(args.out, board=spec, dpi=args.dpi, margin_m=args.margin_mm / 1000.0)
    width_mm, height_mm = (v * 1000.0 for v in spec.size_m)
    print(
        f"wrote {path}: {spec.squares_x}x{spec.squares_y} squares of {spec.square_length_m * 1000:g} mm, markers "
        f"{spec.marker_length_m * 1000:g} mm, {spec.dictionary}; board {width_mm:g} x {height_mm:g} mm. "
        "Print at 100 % (no fit to page) and measure one square."
    )
    return 0


# ================================================================================================ hand-eye
def run_hand_eye(args: argparse.Namespace) -> int:
    from rich.console import Console

    from calibration.wizard import HandEyeWizard
    from cell.config import load_config
    from cell.factory import build_cell

    config = load_config(args.config)
    params, cell_config, out = wizard_setup(config, args)
    plan_poses = _read_plan(args.plan) if args.plan else None
    ui = RichUI(Console(highlight=False, soft_wrap=True), yes=args.yes)
    ui.console.print(
        f"[bold]weldcell calibrate hand-eye[/] ({params.mode.value}, {'manual' if args.manual else 'automatic'}) "
        f"with {config.source}; result to {out if out is not None else '(not written)'}"
    )
    try:
        with build_cell(cell_config, start_simulators=args.with_sims) as cell:
            wizard = HandEyeWizard(
                cell.robot,
                cell.camera,
                params,
                track=cell.track,
                ui=ui,
                manual=args.manual,
                out=out,
                plan_poses=plan_poses,
                source=str(config.source),
            )
            outcome = wizard.run()
    except KeyboardInterrupt:
        ui.close()
        unchanged = f"{out} unchanged" if out is not None else "nothing written"
        print(f"weldcell calibrate: interrupted {ui.where}; robot stopped, {unchanged}", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        ui.close()
    if outcome.written is not None:
        kept = f" (previous kept as {outcome.previous})" if outcome.previous is not None else ""
        ui.console.print(f"wrote {outcome.written}{kept}")
    return 0


def wizard_setup(config: CellConfig, args: argparse.Namespace) -> tuple[WizardParams, CellConfig, Path | None]:
    """The wizard's parameters from the config and the options, the config to build the cell from (with the
    nominal mount standing in for a result file that does not exist yet), and the result file."""
    from calibration.handeye import HandEyeMode
    from calibration.views import WizardParams
    from cell.errors import ConfigError

    he = config.hand_eye
    cal = he.calibration if he is not None else None
    if he is None or cal is None:
        raise ConfigError(
            f"{config.where('hand_eye.calibration')}: missing; the wizard needs the board, its nominal pose and "
            "the workspace there (see examples/sim-calib.toml)"
        )
    mode = HandEyeMode.EYE_TO_HAND if args.eye_to_hand else HandEyeMode(cal.mode)
    poses = cal.poses if args.poses is None else args.poses
    if poses < cal.min_views:
        raise ConfigError(f"--poses {poses} is below min_views = {cal.min_views} of [hand_eye.calibration]")
    speed = cal.speed_m_s if cal.speed_m_s is not None else config.robot.speed_m_s
    if speed > config.robot.max_speed_m_s:
        raise ConfigError(
            f"{config.where('hand_eye.calibration.speed_m_s')}: {speed} m/s exceeds robot.max_speed_m_s = "
            f"{config.robot.max_speed_m_s}"
        )

    cell_config = config
    result_file = config.resolve(he.path) if he.path is not None else None
    X_tool_camera_nominal = _matrix(cal.X_tool_camera)
    if result_file is not None and not result_file.exists():
        # first calibration: the cell is built with the nominal mount in place of the missing result file
        if X_tool_camera_nominal is None and mode is HandEyeMode.EYE_IN_HAND:
            raise ConfigError(
                f"{config.where('hand_eye.path')}: {result_file} does not exist yet and [hand_eye.calibration] "
                "has no nominal X_tool_camera; add the CAD mount there for the first calibration"
            )
        stand_in = cal.X_tool_camera if cal.X_tool_camera is not None else [list(r) for r in _identity()]
        cell_config = config.model_copy(
            update={"hand_eye": he.model_copy(update={"path": None, "X_tool_camera": stand_in})}
        )
    elif X_tool_camera_nominal is None and mode is HandEyeMode.EYE_IN_HAND:
        X_tool_camera_nominal = config.X_tool_camera()

    if args.out is not None:
        out: Path | None = Path(args.out)
    elif mode is HandEyeMode.EYE_TO_HAND:
        raise ConfigError("an eye-to-hand result (X_base_camera) is not what [hand_eye] path reads; give --out FILE")
    elif result_file is None:
        raise ConfigError(
            f"{config.where('hand_eye')}: X_tool_camera is given inline, so there is no result file to update; "
            "give --out FILE and then point [hand_eye] path at it"
        )
    else:
        out = result_file

    plan = cal.plan_params(poses)
    params = WizardParams(
        board=cal.board.spec(),
        workspace=cal.workspace.workspace(),
        mode=mode,
        X_base_board=_matrix(cal.X_base_board),
        X_tool_camera=X_tool_camera_nominal,
        X_base_camera=_matrix(cal.X_base_camera),
        X_tool_board=_matrix(cal.X_tool_board),
        plan=plan,
        seed=cal.seed if args.seed is None else args.seed,
        speed_m_s=speed,
        accel_m_s2=cal.accel_m_s2 if cal.accel_m_s2 is not None else config.robot.accel_m_s2,
        capture_timeout_s=config.camera.timeout_s,
        settle_s=cal.settle_s,
        min_corners=cal.min_corners,
        min_views=cal.min_views,
    )
    return params, cell_config, out


def _matrix(value: Sequence[Sequence[float]] | None) -> Any:
    import numpy as np

    return None if value is None else np.asarray(value, dtype=np.float64)


def _identity() -> list[list[float]]:
    return [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]


def _read_plan(path: str) -> list[Any]:
    import numpy as np

    from cell.errors import ConfigError

    try:
        obj = json.loads(Path(path).read_text(encoding="utf-8"))
        poses = obj["X_base_tool"] if isinstance(obj, dict) else obj
        return [np.asarray(X, dtype=np.float64).reshape(4, 4) for X in poses]
    except OSError as err:
        raise ConfigError(f"--plan {path}: cannot read it: {err.strerror or err}") from err
    except (ValueError, KeyError, TypeError) as err:
        raise ConfigError(f"--plan {path}: expected {{'X_base_tool': [4x4, ...]}} in JSON ({err})") from err


# ================================================================================================ rich UI
class RichUI:
    """The wizard's operator on a terminal: stages as headings, tables for the plan and the residuals, one line
    per view, a progress bar while the views are collected (only on a terminal), questions on stdin."""

    def __init__(self, console: Console, *, yes: bool, stdin: TextIO | None = None) -> None:
        self.console = console
        self.yes = yes
        self.stdin = stdin if stdin is not None else sys.stdin
        self.where = "while starting"
        self._progress: Progress | None = None
        self._task: TaskID | None = None
        self._done = 0  # views finished in this stage (the bar is closed while the operator is asked something)

    # ------------------------------------------------------------------ WizardUI
    def stage(self, title: str) -> None:
        self.close()
        self._done = 0
        self.where = f"while {title[0].lower()}{title[1:]}"
        self.console.print(f"\n[bold]{title}[/]")

    def info(self, text: str) -> None:
        self.console.print(text)

    def warn(self, text: str) -> None:
        self.console.print(f"[yellow]warning:[/] {text}")

    def devices_ready(self, report: DeviceReport) -> None:
        x, y, z = (v * 1000.0 for v in report.X_base_tool_start[:3, 3])
        self.console.print(f"  robot   {report.robot.mode.value}, tool at ({x:.1f}, {y:.1f}, {z:.1f}) mm")
        if report.track is not None:
            self.console.print(f"  track   at {report.track.position_m * 1000:.1f} mm, no fault")
        k = report.intrinsics
        self.console.print(f"  camera  {k.width}x{k.height}, fx {k.fx:.1f} px, fy {k.fy:.1f} px")

    def plan_ready(self, plan: CalibrationPlan, params: WizardParams) -> None:
        from rich.table import Table

        p = params.plan
        table = Table(
            title=f"{plan.n_views} views + 1 held out; stand-off {p.standoff_m:g} m, tilt "
            f"{math.degrees(p.min_tilt_rad):g}-{math.degrees(p.max_tilt_rad):g} deg, seed {params.seed}",
            title_justify="left",
        )
        for name in ("view", "x mm", "y mm", "z mm", "board mm", "tilt deg"):
            table.add_column(name, justify="right")
        for i, X in enumerate([*plan.X_base_tool, plan.X_base_tool_holdout]):
            distance_m, tilt_deg = plan.view_geometry(i)
            label = str(i + 1) if i < plan.n_views else "held out"
            table.add_row(label, *(f"{v * 1000:.1f}" for v in X[:3, 3]), f"{distance_m * 1000:.0f}", f"{tilt_deg:.1f}")
        self.console.print(table)

    def confirm(self, question: str) -> bool:
        self.close()
        if self.yes:
            self.console.print(f"{question} yes (--yes)")
            return True
        self.console.print(f"{question} [y/N] ", end="")
        answer = self._read_line()
        return answer.strip().lower() in ("y", "yes")

    def ask_operator(self, text: str, X_base_tool_suggested: Any) -> str:
        self.close()
        if X_base_tool_suggested is not None:
            from scipy.spatial.transform import Rotation

            x, y, z = (v * 1000.0 for v in X_base_tool_suggested[:3, 3])
            rx, ry, rz = Rotation.from_matrix(X_base_tool_suggested[:3, :3]).as_rotvec(degrees=True)
            self.console.print(
                f"  suggested tool pose: ({x:.1f}, {y:.1f}, {z:.1f}) mm, rotation vector ({rx:.1f}, {ry:.1f}, "
                f"{rz:.1f}) deg"
            )
        self.console.print(f"{text}: ", end="")
        line = self._read_line()
        return line.strip() if line else "q"  # end of input: stop

    def view_started(self, index: int, total: int, what: str) -> None:
        self.where = f"at view {index + 1}/{total} ({what})" if index < total else f"at the held-out view ({what})"
        if index >= total:
            return
        if self._progress is None and self.console.is_terminal:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self._progress = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                console=self.console,
                transient=True,
            )
            self._progress.start()
            self._task = self._progress.add_task("views", total=total, completed=self._done)
        if self._progress is not None and self._task is not None:
            self._progress.update(self._task, description=f"view {index + 1}: {what}")

    def view_done(self, record: ViewRecord, total: int) -> None:
        label = f"view {record.index + 1:>2}/{total}"
        if record.usable and record.observation is not None:
            obs = record.observation
            z_mm = obs.X_camera_board[2, 3] * 1000.0
            self.console.print(f"  {label}  {obs.n_corners} corners, board fit {obs.rms_px:.3f} px, at {z_mm:.0f} mm")
        else:
            self.console.print(f"  {label}  [yellow]skipped[/]: {record.skipped}")
        self._done += 1
        if self._progress is not None and self._task is not None:
            self._progress.advance(self._task)

    def solved(self, result: HandEyeResult, views: Sequence[ViewRecord]) -> None:
        from rich.table import Table

        from calibration.verdict import solved_transforms

        assert result.view_residuals_px is not None and result.rms_px is not None
        table = Table(
            title=f"residuals per view ({result.method}, started from {result.start_method})", title_justify="left"
        )
        for name in ("view", "px", "mm", "deg"):
            table.add_column(name, justify="right")
        for v, px, mm, deg in zip(
            views, result.view_residuals_px, result.view_residuals_mm, result.view_residuals_deg, strict=True
        ):
            table.add_row(str(v.index + 1), f"{px:.3f}", f"{mm:.3f}", f"{deg:.4f}")
        table.add_row("RMS", f"{result.rms_px:.3f}", f"{result.rms_mm:.3f}", f"{result.rms_deg:.4f}", style="bold")
        self.console.print(table)
        X, Y = solved_transforms(result)
        names = (
            ("X_tool_camera", "X_base_board")
            if result.mode.value == "eye_in_hand"
            else ("X_base_camera", "X_tool_board")
        )
        for name, M in ((names[0], X), (names[1], Y)):
            rows = "\n".join("    [" + ", ".join(f"{v: .6f}" for v in row) + "]" for row in M)
            self.console.print(f"  {name} =\n{rows}")

    def verified(self, verification: Verification) -> None:
        v = verification
        self.console.print(
            f"  held-out view: {v.n_corners} corners seen {v.rms_px:.3f} px RMS (max {v.max_px:.3f} px) from where "
            f"the solution puts them; board pose {v.translation_mm:.3f} mm, {v.rotation_deg:.4f} deg off"
        )

    def assessed(self, assessment: Assessment, thresholds: VerdictThresholds) -> None:
        colour = {"pass": "green", "marginal": "yellow", "fail": "red"}[assessment.verdict.value]
        self.console.print(f"\n[bold {colour}]verdict: {assessment.verdict.value.upper()}[/]")
        for reason in assessment.reasons:
            self.console.print(f"  {reason}")
        t = thresholds
        self.console.print(
            f"  (pass: RMS <= {t.pass_rms_px:g} px, worst view <= {t.pass_worst_view_px:g} px, board RMS <= "
            f"{t.pass_rms_mm:g} mm and <= {t.pass_rms_deg:g} deg, held-out view <= {t.pass_holdout_rms_px:g} px)"
        )

    # ------------------------------------------------------------------ housekeeping
    def _read_line(self) -> str:
        """One line from stdin ("" at its end); a terminal echoes the Enter, piped input gets its newline here."""
        line = self.stdin.readline()
        if not self.stdin.isatty():
            self.console.print()
        return line

    def close(self) -> None:
        """End the progress bar (if one is shown)."""
        if self._progress is not None:
            self._progress.stop()
            self._progress = None
            self._task = None
