"""Seams kept where this shot sees both faces well enough to weld from it: both at less than
``max_incidence_rad`` to the camera's rays, in runs at least ``min_length_m`` long. A face seen at a grazing
angle is sampled sparsely and noisily; a seam there is left to a shot from another pose.

Between ``max_incidence_rad`` (75 degrees) and ``grazing_incidence_rad`` (78 degrees, where a face's samples
lie five times further apart than seen square on) a face still counts as seen when its fit shows that it is
one: its residual about its surface is within ``grazing_fit_sigma`` of the noise at its range. A plane fitted
to a grazing strip of mixed pixels along an occluding edge does not fit that well, and neither does a face
whose orientation the few samples cannot pin down. A gap's seam is never kept past 75 degrees: a face's
samples drop out in rows at grazing angles, and the rows look like gaps."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from perception.evaluate import resample_polyline
from perception.fine.runs import covered_runs
from perception.fine.types import NoiseModel, SeamCurve, SurfaceSet

MAX_INCIDENCE_RAD = np.radians(75.0)
GRAZING_INCIDENCE_RAD = np.radians(78.0)
GRAZING_FIT_SIGMA = 1.5
MIN_LENGTH_M = 0.015  # the fixed scenes' ground truth counts seams to 15 mm (the zoo's seen runs to 20)


def face_limits(
    seam: SeamCurve,
    surfaces: SurfaceSet | None,
    noise: NoiseModel | None,
    *,
    max_incidence_rad: float = MAX_INCIDENCE_RAD,
    grazing_incidence_rad: float = GRAZING_INCIDENCE_RAD,
    grazing_fit_sigma: float = GRAZING_FIT_SIGMA,
) -> tuple[float, float]:
    """The largest incidence (rad) at which each of ``seam``'s two faces counts as seen."""
    if surfaces is None or noise is None or seam.joint == "butt":
        return max_incidence_rad, max_incidence_rad
    out = []
    for label in seam.surfaces:
        ok = 0 <= label < len(surfaces.surfaces)
        if ok:
            s = surfaces.surfaces[label]
            ok = s.rms_m <= grazing_fit_sigma * float(noise.sigma_m(s.z_m))
        out.append(grazing_incidence_rad if ok else max_incidence_rad)
    return out[0], out[1]


def clip_to_view(
    seams: list[SeamCurve],
    surfaces: SurfaceSet | None = None,
    noise: NoiseModel | None = None,
    *,
    max_incidence_rad: float = MAX_INCIDENCE_RAD,
    min_length_m: float = MIN_LENGTH_M,
) -> list[SeamCurve]:
    """The parts of each (camera-frame) seam where both faces are seen: at under ``max_incidence_rad``, or,
    given the surfaces the seams were built from and the noise model, a face that fits its surface within
    the noise at under ``GRAZING_INCIDENCE_RAD``."""
    out: list[SeamCurve] = []
    for s in seams:
        lim_a, lim_b = face_limits(s, surfaces, noise, max_incidence_rad=max_incidence_rad,
                                   grazing_incidence_rad=max(max_incidence_rad, GRAZING_INCIDENCE_RAD))  # fmt: skip
        pts = resample_polyline(s.points, 0.001)
        seg = np.linalg.norm(np.diff(s.points, axis=0), axis=1)
        src = np.concatenate([[0.0], np.cumsum(seg)])
        dense = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
        na = np.column_stack([np.interp(dense, src, s.normals_a[:, k]) for k in range(3)])
        nb = np.column_stack([np.interp(dense, src, s.normals_b[:, k]) for k in range(3)])
        na /= np.linalg.norm(na, axis=1, keepdims=True)
        nb /= np.linalg.norm(nb, axis=1, keepdims=True)
        if s.from_boundary and surfaces is not None:  # located from the upper plate's top, not its edge face
            nb = np.tile(surfaces.surfaces[s.surfaces[1]].normal, (len(pts), 1))
        view = -pts / np.linalg.norm(pts, axis=1, keepdims=True)  # towards the camera at the origin
        ok = ((na * view).sum(axis=1) > np.cos(lim_a)) & ((nb * view).sum(axis=1) > np.cos(lim_b))
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
