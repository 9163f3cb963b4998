"""Seams kept where this shot sees both faces well enough to weld from it: both at less than
``max_incidence_rad`` to the camera's rays, in runs at least ``min_length_m`` long. A face seen at a grazing
angle is sampled sparsely and noisily; a seam there is left to a shot from another pose."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from perception.evaluate import resample_polyline
from perception.fine.runs import covered_runs
from perception.fine.types import SeamCurve

MAX_INCIDENCE_RAD = np.radians(75.0)
MIN_LENGTH_M = 0.015  # the fixed scenes' ground truth counts seams to 15 mm (the zoo's seen runs to 20)


def clip_to_view(
    seams: list[SeamCurve], *, max_incidence_rad: float = MAX_INCIDENCE_RAD, min_length_m: float = MIN_LENGTH_M
) -> list[SeamCurve]:
    """The parts of each (camera-frame) seam where both faces are seen at under ``max_incidence_rad``."""
    out: list[SeamCurve] = []
    cos_max = np.cos(max_incidence_rad)
    for s in seams:
        pts = resample_polyline(s.points, 0.001)
        seg = np.linalg.norm(np.diff(s.points, axis=0), axis=1)
        src = np.concatenate([[0.0], np.cumsum(seg)])
        dense = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
        na = np.column_stack([np.interp(dense, src, s.normals_a[:, k]) for k in range(3)])
        nb = np.column_stack([np.interp(dense, src, s.normals_b[:, k]) for k in range(3)])
        na /= np.linalg.norm(na, axis=1, keepdims=True)
        nb /= np.linalg.norm(nb, axis=1, keepdims=True)
        view = -pts / np.linalg.norm(pts, axis=1, keepdims=True)  # towards the camera at the origin
        ok = ((na * view).sum(axis=1) > cos_max) & ((nb * view).sum(axis=1) > cos_max)
        for a, b in covered_runs(ok, 0):
            if dense[b - 1] - dense[a] < min_length_m:
                continue
            if a == 0 and b == len(pts):
                out.append(s)
                continue
            keep = slice(a, b)
            pts_k = pts[keep] if s.kind == "curved" else pts[[a, b - 1]]
            na_k = na[keep] if s.kind == "curved" else na[[a, b - 1]]
            nb_k = nb[keep] if s.kind == "curved" else nb[[a, b - 1]]
            out.append(replace(s, points=pts_k, normals_a=na_k, normals_b=nb_k))
    return out
