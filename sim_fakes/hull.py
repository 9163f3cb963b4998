"""Convex polyhedra for the simulator: faces with exact planes and polygons, from a list of vertices.

A solid part of a weldment (a plate, a bevelled plate, a gusset, a rotated rib) is the convex hull of its
corner points. The hull's triangles are grouped into planar faces; each face carries its exact outward
plane ``n . p + d = 0`` and its polygon (vertices ordered around the face), so that rendered depth and
seam ground truth can be computed analytically instead of from the float32 mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

_PLANE_DIGITS = 9  # triangles whose (n, d) agree to 1e-9 belong to one face


@dataclass(frozen=True)
class HullFace:
    """One planar face of a convex solid (frame of the vertices given, metres).

    normal: (3,) outward unit normal; offset: d in ``normal . p + offset = 0``;
    polygon: (K, 3) corners ordered around the face (K >= 3).
    """

    normal: FloatArray
    offset: float
    polygon: FloatArray

    def centroid(self) -> FloatArray:
        return np.asarray(self.polygon.mean(axis=0))

    def contains(self, p: FloatArray, *, tol_m: float = 1e-9) -> NDArray[np.bool_]:
        """(N,) whether points (N, 3), taken as lying in the face's plane, are inside its polygon."""
        q = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        inside = np.ones(len(q), bool)
        c = self.centroid()
        k = len(self.polygon)
        for i in range(k):
            a, b = self.polygon[i], self.polygon[(i + 1) % k]
            w = np.cross(self.normal, b - a)
            w /= np.linalg.norm(w)
            if np.dot(w, c - a) < 0:
                w = -w
            inside &= (q - a) @ w >= -tol_m
        return inside


@dataclass(frozen=True)
class Hull:
    """A convex solid: its faces and a triangulation with the face id of each triangle."""

    vertices: FloatArray  # (V, 3)
    triangles: NDArray[np.int32]  # (T, 3) indices into vertices
    triangle_face: NDArray[np.int32]  # (T,)
    faces: tuple[HullFace, ...]

    def contains(self, p: FloatArray, *, margin_m: float = 0.0) -> NDArray[np.bool_]:
        """(N,) whether points are inside the solid by more than ``margin_m``."""
        q = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        inside = np.ones(len(q), bool)
        for f in self.faces:
            inside &= q @ f.normal + f.offset < -margin_m
        return inside


def convex_hull(vertices: FloatArray) -> Hull:
    """The convex hull of (V, 3) points (V >= 4, not coplanar), faces merged from coplanar triangles."""
    from scipy.spatial import ConvexHull

    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    hull = ConvexHull(v)
    keys: dict[tuple[float, ...], int] = {}
    tri_face = np.empty(len(hull.simplices), np.int32)
    planes: list[FloatArray] = []
    for t, eq in enumerate(hull.equations):
        key = tuple(np.round(eq, _PLANE_DIGITS) + 0.0)
        if key not in keys:
            keys[key] = len(planes)
            planes.append(eq)
        tri_face[t] = keys[key]
    faces = []
    for fid, eq in enumerate(planes):
        n = eq[:3] / np.linalg.norm(eq[:3])
        idx = np.unique(hull.simplices[tri_face == fid].ravel())
        pts = v[idx]
        # exact plane through the face's own corners (the hull's equations carry round-off)
        c = pts.mean(axis=0)
        _, _, vt = np.linalg.svd(pts - c)
        n_fit = vt[2] if np.dot(vt[2], n) > 0 else -vt[2]
        d_fit = -float(np.dot(n_fit, c))
        e1 = vt[0]
        e2 = np.cross(n_fit, e1)
        ang = np.arctan2((pts - c) @ e2, (pts - c) @ e1)
        faces.append(HullFace(n_fit, d_fit, pts[np.argsort(ang)]))
    # re-triangulate each face as a fan over its ordered polygon, so that triangles and faces agree exactly
    index = {tuple(p): i for i, p in enumerate(v)}
    tris: list[tuple[int, int, int]] = []
    tface: list[int] = []
    for fid, f in enumerate(faces):
        ids = [index[tuple(p)] for p in f.polygon]
        for k in range(1, len(ids) - 1):
            tris.append((ids[0], ids[k], ids[k + 1]))
            tface.append(fid)
    return Hull(v, np.array(tris, np.int32), np.array(tface, np.int32), tuple(faces))


def prism(polygon_xz: FloatArray, length_y: float) -> FloatArray:
    """(2K, 3) corners of a prism: a convex polygon in the x-z plane, extruded over y in [-L/2, L/2]."""
    p = np.asarray(polygon_xz, dtype=np.float64).reshape(-1, 2)
    half = length_y / 2
    lo = np.column_stack([p[:, 0], np.full(len(p), -half), p[:, 1]])
    hi = np.column_stack([p[:, 0], np.full(len(p), half), p[:, 1]])
    return np.vstack([lo, hi])


def box_corners(sx: float, sy: float, sz: float) -> FloatArray:
    """(8, 3) corners of a box of size (sx, sy, sz) with its bottom face on z = 0, centred in x and y."""
    return np.array([[x, y, z] for x in (-sx / 2, sx / 2) for y in (-sy / 2, sy / 2) for z in (0.0, sz)])
