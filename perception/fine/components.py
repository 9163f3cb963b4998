"""Connected pieces of smooth pixels: the work image's pixels whose local plane is defined and does not turn at a
fold, linked to their right and lower neighbours unless depth jumps between them (beyond the noise and the
spacing stretched by the obliquity). The surfaces are fitted on these pieces (:mod:`perception.fine.surfaces`).

The per-pixel tests run compiled (:mod:`numba`), in one pass: as NumPy expressions over the whole image they
took 21 ms of a median dev capture (0.42 s), a dozen passes over 230 000 pixels."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from perception.fine.noise import LocalPlanes
from perception.fine.types import FloatArray, NoiseModel


def smooth_components(p: FloatArray, planes: LocalPlanes, noise: NoiseModel, *, normal_turn_rad: float,
                      jump_sigma: float) -> tuple[NDArray[np.int32], NDArray[np.int64]]:  # fmt: skip
    """(h, w) connected-component labels (-1: none) of the smooth pixels of the (h, w, 3) work cloud ``p``, and
    each component's pixel count. A pixel is smooth when its window's normal is defined and turns by at most
    ``normal_turn_rad`` between the pixels one window apart on either side, along its row and down its column
    (window-mean normals blur a fold over about a window, so neighbours alone turn too little); two 4-neighbours
    are linked unless their points lie further apart along the first one's normal than ``jump_sigma`` times
    the noise plus half the spacing at its range."""
    limit = (float(jump_sigma), noise.sigma_1m_m, noise.floor_m, noise.pixel_angle_rad)
    comp, n_comp = _linked_pieces(np.ascontiguousarray(p, dtype=np.float64),
                                  np.ascontiguousarray(planes.normal, dtype=np.float64), limit,
                                  max(1, planes.window_px // 2), float(np.cos(normal_turn_rad)))  # fmt: skip
    counts = np.bincount(comp[comp >= 0].ravel(), minlength=n_comp)
    return comp, counts


@njit(cache=True)
def _dot(a: FloatArray, y0: int, x0: int, b: FloatArray, y1: int, x1: int) -> float:
    """The dot product of the 3-vectors a[y0, x0] and b[y1, x1], a NaN component taken as 0 (``np.nan_to_num``),
    summed x, y, z in turn (``np.einsum`` over the last axis)."""
    s = 0.0
    for k in range(3):
        u, v = a[y0, x0, k], b[y1, x1, k]
        s += (0.0 if np.isnan(u) else u) * (0.0 if np.isnan(v) else v)
    return s


@njit(cache=True)
def _root(parent: NDArray[np.int64], i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]  # halving the path on the way
        i = parent[i]
    return i


@njit(cache=True)
def _linked_pieces(p: FloatArray, normal: FloatArray, limit: tuple[float, float, float, float], st: int,
                   cos_t: float) -> tuple[NDArray[np.int32], int]:  # fmt: skip
    """The pieces' labels (h, w; -1 off the smooth pixels), numbered in the order of their first pixel in raster
    order (as ``cv2.connectedComponents`` numbers them), and their number. ``limit``: (jump_sigma, and the noise
    model's sigma at 1 m, floor and pixel angle), a link's limit at range z taken per pixel as
    ``jump_sigma * noise.sigma_m(z) + 0.5 * noise.spacing_m(z)`` takes it (the same operations in order)."""
    h, w = p.shape[0], p.shape[1]
    jump, sigma_1m, floor, angle = limit
    ok = np.zeros((h, w), np.bool_)
    for y in range(h):
        for x in range(w):
            if not (np.isfinite(p[y, x, 2]) and np.isfinite(normal[y, x, 0])):
                continue
            if st <= x < w - st and _dot(normal, y, x + st, normal, y, x - st) < cos_t:
                continue  # a fold along the row
            if st <= y < h - st and _dot(normal, y + st, x, normal, y - st, x) < cos_t:
                continue  # a fold down the column
            ok[y, x] = True
    parent = np.arange(h * w)
    for y in range(h):
        for x in range(w):
            if not ok[y, x]:
                continue
            for dy, dx in ((0, 1), (1, 0)):
                ny, nx = y + dy, x + dx
                if ny >= h or nx >= w or not ok[ny, nx]:
                    continue
                off = 0.0
                for k in range(3):
                    d = p[ny, nx, k] - p[y, x, k]
                    off += (0.0 if np.isnan(d) else d) * normal[y, x, k]
                z = p[y, x, 2]
                if abs(off) < jump * max(sigma_1m * (z * z), floor) + 0.5 * (z * angle):
                    a, b = _root(parent, y * w + x), _root(parent, ny * w + nx)
                    if a != b:
                        parent[max(a, b)] = min(a, b)
    comp = np.full((h, w), -1, np.int32)
    number = np.full(h * w, -1, np.int64)
    n = 0
    for y in range(h):
        for x in range(w):
            if ok[y, x]:
                r = _root(parent, y * w + x)
                if number[r] < 0:
                    number[r] = n
                    n += 1
                comp[y, x] = number[r]
    return comp, n
