"""A small synthetic cell shared by the calibration tests: board, camera, true mounts, workspace."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.board import CharucoBoardSpec
from calibration.planner import Workspace
from perception.transforms import make_X


@dataclass(frozen=True)
class Cell:
    board: CharucoBoardSpec
    K: np.ndarray
    image_size: tuple[int, int]
    workspace: Workspace
    X_tool_camera: np.ndarray  # truth, eye-in-hand
    X_base_board: np.ndarray  # truth, eye-in-hand
    X_base_camera: np.ndarray  # truth, eye-to-hand
    X_tool_board: np.ndarray  # truth, eye-to-hand


@pytest.fixture(scope="session")
def cell() -> Cell:
    board = CharucoBoardSpec(squares_x=9, squares_y=6, square_length_m=0.030, marker_length_m=0.022)
    w, h = board.size_m
    # Board face up on the table centred at (0.6, 0, 0): board z points down into the table.
    X_base_board = make_X(np.diag([1.0, -1.0, -1.0]), [0.6 - w / 2, h / 2, 0.0])
    X_tool_camera = make_X(
        Rotation.from_euler("xyz", [1.5, -2.0, 91.0], degrees=True).as_matrix(), [0.061, -0.029, 0.083]
    )
    # Eye-to-hand: camera 0.95 m up looking down at the table; the board faces it from 0.1 m along the
    # tool z axis of a wrist pointing up (board z = -tool z, board centre on the tool z axis).
    X_base_camera = make_X(Rotation.from_euler("xyz", [180.0, 2.0, 3.0], degrees=True).as_matrix(), [0.6, 0.02, 0.95])
    R_tool_board = Rotation.from_euler("xyz", [180.0, 0.0, 1.0], degrees=True).as_matrix()
    X_tool_board = make_X(R_tool_board, np.array([0.0, 0.0, 0.1]) - R_tool_board @ np.array([w / 2, h / 2, 0.0]))
    return Cell(
        board=board,
        K=np.array([[1000.0, 0.0, 639.5], [0.0, 1000.0, 399.5], [0.0, 0.0, 1.0]]),
        image_size=(1280, 800),
        workspace=Workspace(
            reach_center_base=(0.0, 0.0, 0.163),
            reach_radius_m=0.85,
            min_radius_m=0.25,
            box_min_base=(0.1, -0.6, 0.05),
            box_max_base=(1.0, 0.6, 0.9),
        ),
        X_tool_camera=X_tool_camera,
        X_base_board=X_base_board,
        X_base_camera=X_base_camera,
        X_tool_board=X_tool_board,
    )
