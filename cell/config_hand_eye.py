"""The ``[hand_eye]`` table of the cell config: the camera's pose on the tool (inline or the result file of
``weldcell calibrate hand-eye``) and ``[hand_eye.calibration]``, how that command calibrates it (the board, the
nominal poses, the workspace and the spread of the views; degrees in the file, radians in :class:`PlanParams`)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import Field, model_validator

from cell.sections import Section, check_matrix
from perception.transforms import TransformError, check_X

if TYPE_CHECKING:
    from calibration.planner import PlanParams

HandEyeModeName = Literal["eye_in_hand", "eye_to_hand"]


class BoardConfig(Section):
    """``[hand_eye.calibration.board]``: the printed ChArUco board (:class:`calibration.board.CharucoBoardSpec`).

    ``squares_x`` × ``squares_y`` squares of ``square_length_m`` with markers of ``marker_length_m`` (measure the
    print: a wrong size scales every translation), ``dictionary`` a ``cv2.aruco.DICT_*`` name.
    """

    squares_x: int = Field(ge=2)
    squares_y: int = Field(ge=2)
    square_length_m: float = Field(gt=0)
    marker_length_m: float = Field(gt=0)
    dictionary: str = "DICT_5X5_100"
    legacy_pattern: bool = False

    @model_validator(mode="after")
    def _check_board(self) -> BoardConfig:
        from calibration.errors import CalibrationError

        try:
            self.spec()
        except CalibrationError as err:
            raise ValueError(str(err)) from err
        return self

    def spec(self) -> Any:
        """The :class:`calibration.board.CharucoBoardSpec` of this table."""
        from calibration.board import CharucoBoardSpec

        return CharucoBoardSpec(
            squares_x=self.squares_x,
            squares_y=self.squares_y,
            square_length_m=self.square_length_m,
            marker_length_m=self.marker_length_m,
            dictionary=self.dictionary,
            legacy_pattern=self.legacy_pattern,
        )


class WorkspaceConfig(Section):
    """``[hand_eye.calibration.workspace]``: where the tool frame origin may go while calibrating (base frame,
    metres): within ``reach_radius_m`` of ``reach_center_base`` (e.g. the shoulder), beyond ``min_radius_m``, and
    inside the box ``box_min_base`` .. ``box_max_base`` when given (keep its floor above the table and fixtures)."""

    reach_center_base: list[float] = Field(min_length=3, max_length=3)
    reach_radius_m: float = Field(gt=0)
    min_radius_m: float = Field(default=0.0, ge=0)
    box_min_base: list[float] | None = Field(default=None, min_length=3, max_length=3)
    box_max_base: list[float] | None = Field(default=None, min_length=3, max_length=3)

    @model_validator(mode="after")
    def _check_workspace(self) -> WorkspaceConfig:
        from calibration.errors import CalibrationError

        try:
            self.workspace()
        except CalibrationError as err:
            raise ValueError(str(err)) from err
        return self

    def workspace(self) -> Any:
        """The :class:`calibration.planner.Workspace` of this table."""
        from calibration.planner import Workspace

        def xyz(v: list[float] | None) -> tuple[float, float, float] | None:
            return None if v is None else (float(v[0]), float(v[1]), float(v[2]))

        center = xyz(self.reach_center_base)
        assert center is not None
        return Workspace(
            reach_center_base=center,
            reach_radius_m=self.reach_radius_m,
            min_radius_m=self.min_radius_m,
            box_min_base=xyz(self.box_min_base),
            box_max_base=xyz(self.box_max_base),
        )


class CalibrationConfig(Section):
    """``[hand_eye.calibration]``: how ``weldcell calibrate hand-eye`` calibrates (see docs/calibration.md).

    ``mode``: ``"eye_in_hand"`` (camera on the tool, board fixed; default) or ``"eye_to_hand"`` (camera fixed,
    board on the tool). Nominal (CAD) poses the plan aims with, metres; a few mm and degrees off is fine:
    eye-in-hand ``X_base_board`` (required) and ``X_tool_camera`` (default: the ``[hand_eye]`` result);
    eye-to-hand ``X_base_camera`` and ``X_tool_board`` (both required). ``poses``: views to solve from (one more is
    taken to verify the result); ``seed``: of the pose plan. The views sit ``standoff_m`` ± ``standoff_jitter_m``
    from the board centre, tilted ``min_tilt_deg``..``max_tilt_deg`` from its normal and rolled up to
    ± ``max_roll_deg``. ``speed_m_s``/``accel_m_s2``: tool motion between views (default: ``[robot]``'s);
    ``settle_s``: wait after each move before the capture. ``min_corners``: a view with fewer board corners is
    skipped; ``min_views``: fewer usable views stop the calibration.
    """

    mode: HandEyeModeName = "eye_in_hand"
    board: BoardConfig
    workspace: WorkspaceConfig
    X_base_board: list[list[float]] | None = None
    X_tool_camera: list[list[float]] | None = None
    X_base_camera: list[list[float]] | None = None
    X_tool_board: list[list[float]] | None = None
    poses: int = Field(default=12, ge=3, le=200)
    seed: int = 0
    standoff_m: float = Field(default=0.40, gt=0)
    standoff_jitter_m: float = Field(default=0.05, ge=0)
    min_tilt_deg: float = Field(default=10.0, ge=0)
    max_tilt_deg: float = Field(default=35.0, ge=0)
    max_roll_deg: float = Field(default=40.0, ge=0)
    speed_m_s: float | None = Field(default=None, gt=0)
    accel_m_s2: float | None = Field(default=None, gt=0)
    settle_s: float = Field(default=0.2, ge=0)
    min_corners: int = Field(default=12, ge=4)
    min_views: int = Field(default=6, ge=3)

    @model_validator(mode="after")
    def _check_calibration(self) -> CalibrationConfig:
        for name in ("X_base_board", "X_tool_camera", "X_base_camera", "X_tool_board"):
            check_matrix(getattr(self, name), name)
        needed = ("X_base_board",) if self.mode == "eye_in_hand" else ("X_base_camera", "X_tool_board")
        missing = [name for name in needed if getattr(self, name) is None]
        if missing:
            raise ValueError(f"mode = {self.mode!r} needs the nominal {' and '.join(missing)}")
        if self.min_views > self.poses:
            raise ValueError(f"poses = {self.poses} is below min_views = {self.min_views}")
        from calibration.errors import CalibrationError

        try:
            self.plan_params(self.poses)
        except CalibrationError as err:
            raise ValueError(str(err)) from err
        return self

    def plan_params(self, n_poses: int) -> PlanParams:
        """The planner's :class:`calibration.planner.PlanParams` for ``n_poses`` views: the file's degrees
        converted to radians here, the one place they are."""
        from calibration.planner import PlanParams

        return PlanParams(
            n_poses=n_poses,
            standoff_m=self.standoff_m,
            standoff_jitter_m=self.standoff_jitter_m,
            min_tilt_rad=math.radians(self.min_tilt_deg),
            max_tilt_rad=math.radians(self.max_tilt_deg),
            max_roll_rad=math.radians(self.max_roll_deg),
        )


class HandEyeConfig(Section):
    """``[hand_eye]``: the camera pose on the tool, ``X_tool_camera`` (4x4, metres), given inline or as
    ``path`` to a hand-eye result file as ``weldcell calibrate hand-eye`` writes it (``"format":
    "weldcell-hand-eye/1"`` and an ``"X_tool_camera"`` key; read by :mod:`calibration.result_file`).
    ``calibration``: how that command calibrates it (optional)."""

    path: str | None = Field(default=None, min_length=1)
    X_tool_camera: list[list[float]] | None = None
    calibration: CalibrationConfig | None = None

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
