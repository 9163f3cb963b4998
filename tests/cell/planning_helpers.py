"""Test helpers for the planner's tests: straight seams with exact torch poses, and the brute-force route oracle."""

from __future__ import annotations

import itertools
import math

import numpy as np

from perception.seams import Seam
from perception.transforms import make_X

DOWN = (0.0, 0.0, -1.0)


def make_seam(
    seam_id: int,
    p0: tuple[float, float, float],
    p1: tuple[float, float, float],
    *,
    z: tuple[float, float, float] = DOWN,
    step_m: float = 0.005,
    frame: str = "base",
    kind: str = "linear",
) -> Seam:
    """A straight seam from p0 to p1 with neutral torch poses: x along the seam, z as given (made orthogonal)."""
    a, b = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    n = max(2, math.ceil(np.linalg.norm(b - a) / step_m) + 1)
    pts = np.linspace(a, b, n)
    x = (b - a) / np.linalg.norm(b - a)
    zz = np.asarray(z, dtype=float)
    zz = zz - (zz @ x) * x
    zz /= np.linalg.norm(zz)
    y = np.cross(zz, x)
    R = np.column_stack([x, y, zz])
    poses = np.stack([make_X(R, p) for p in pts])
    return Seam(seam_id, kind, pts, poses, float(np.linalg.norm(b - a)), 0.9, frame=frame)  # type: ignore[arg-type]


def brute_force(entries: np.ndarray, exits: np.ndarray, p_start: np.ndarray | None) -> float:
    """The shortest air-move length over every order and every direction of every seam."""
    n = len(entries)
    C = np.linalg.norm(exits[:, :, None, None, :] - entries[None, None, :, :, :], axis=-1).tolist()
    S = [[0.0, 0.0]] * n if p_start is None else np.linalg.norm(entries - p_start, axis=-1).tolist()
    best = math.inf
    for perm in itertools.permutations(range(n)):
        for dirs in itertools.product((0, 1), repeat=n):
            cost = S[perm[0]][dirs[0]]
            for k in range(n - 1):
                cost += C[perm[k]][dirs[k]][perm[k + 1]][dirs[k + 1]]
            best = min(best, cost)
    return best
