"""The surface the workpiece stands on (the table, a fixture plate): never a seam's face.

It is the plane below everything: nearly every valid point lies on it or on its camera side. Of the planes
that qualify (holding a fair share of the image), the largest one the operator did not prompt as part of the
workpiece is taken; the largest of all when every one was prompted (a stray click on the table's border).
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
    qualify = []
    for s in surfaces.surfaces:
        if s.kind != "plane" or s.n_points < MIN_SHARE * labelled:
            continue
        above = (q @ s.normal + s.offset) >= -tol
        if above.mean() >= ABOVE_SHARE:
            qualify.append(s)
    # the faces of an inside corner seen from in front each have every point on their camera side: of those
    # that qualify, one the operator did not click is the table (a click on the table itself, a stray one on
    # a thin face's border, does not make a wall the support)
    unclicked = [s for s in qualify if s.label not in prompted]
    if not qualify:
        return frozenset()
    best = max(unclicked or qualify, key=lambda s: s.n_points).label
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
