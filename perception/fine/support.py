"""The surface the workpiece stands on (the table, a fixture plate): never a seam's face.

It is the plane below everything: nearly every valid point lies on it or on its camera side. Of the planes
that qualify, the one with the most support is taken, provided it holds a fair share of the image and is
not a surface the operator prompted as part of the workpiece.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from perception.fine.types import NoiseModel, SurfaceSet

ABOVE_SHARE = 0.97  # at least this share of all points lies on or above the support
MIN_SHARE = 0.08  # and it holds at least this share of the labelled pixels
FLATNESS_M = 0.001  # pieces of the support plane agree this well (a welding table is flat to a fraction of this)


def find_support(
    points: NDArray[np.floating],
    surfaces: SurfaceSet,
    noise: NoiseModel,
    *,
    prompted: frozenset[int] = frozenset(),
) -> frozenset[int]:
    """The labels of the support plane in an (h, w, 3) work cloud: the best qualifying plane and every
    other piece of the same plane (the table seen on both sides of the part); empty when none qualifies."""
    p = np.asarray(points, dtype=np.float64)
    valid = np.isfinite(p[..., 2])
    every = np.flatnonzero(valid)
    q = p.reshape(-1, 3)[every[:: max(1, len(every) // 40000)]]  # the sample, gathered alone
    tol = 6.0 * noise.sigma_m(q[:, 2]) + 0.002
    labelled = int((surfaces.labels >= 0).sum())
    best, best_n = None, 0
    for s in surfaces.surfaces:
        if s.kind != "plane" or s.label in prompted or s.n_points < MIN_SHARE * labelled:
            continue
        above = (q @ s.normal + s.offset) >= -tol
        if above.mean() >= ABOVE_SHARE and s.n_points > best_n:
            best, best_n = s.label, s.n_points
    if best is None:
        return frozenset()
    S = surfaces.surfaces[best]
    same = {best}
    for s in surfaces.surfaces:
        parallel = s.kind == "plane" and s.label != best and float(s.normal @ S.normal) > np.cos(np.radians(3.0))
        # the same plane: the piece's mean within a table's flatness of the plane (its noise averages out over
        # its points); a plate lying on the table is its thickness above it
        if parallel and abs(float(S.residual(s.centroid[None])[0])) <= FLATNESS_M + 3.0 * float(
            noise.sigma_m(s.z_m)
        ) / np.sqrt(max(s.n_points, 1)):
            same.add(s.label)
    return frozenset(same)
