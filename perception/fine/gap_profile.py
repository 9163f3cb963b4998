"""A butt gap's far edge, fitted to the pixels' ranges.

Across the gap the camera sees the top of one plate, the gap, and the top of the other. Seen obliquely, the
rays that enter the gap run on towards the far plate and meet its edge face (square to the top) below the top,
or pass under it. Every ray's crossing with the top's plane follows from its pixel alone, not from the noisy
range; so for a candidate far edge each ray's range is traced: the top's where it crosses outside the gap, the
far edge face's where it crosses between that edge and the near plate's. The measured ranges are compared
with the traced ones in units of the noise, capped at three sigma (a ray that passes under the far plate, a
mixed pixel, costs the cap), and the edge with the least cost is the far edge, when it explains the rays
clearly better (:data:`MIN_GAIN`) than the edge the counts of the plate's pixels and of the holes placed.

Those counts place the far edge inside the gap (the rays that meet the face within the noise of the top pass
for the plate, the deeper ones cross the top's plane short of the edge); the near plate's edge face is not
seen, and its edge is where its top's pixels end. Choosing the face's points by how deep they lie behind the
top would choose the noise: where the face is seen only a sigma or two deep (a narrow gap), the points past a
depth cut are those the noise pushed along their rays, and the rays run across the gap, into the far plate.
The traced ranges of all the rays have no such bias.
"""

from __future__ import annotations

import numpy as np

from perception.fine.types import FloatArray, Surface

CAP_SIGMA = 3.0
STEP_M = 5e-5
MIN_FACE_RAYS = 10  # a fit needs this many rays that meet the far plate's face
MIN_GAIN = 16.0  # in squared sigmas: the fitted edge must explain the rays this much better than the counts'


def gap_edges(q: FloatArray, sigma: FloatArray, top: Surface, c3: FloatArray, across: FloatArray,
              start: tuple[float, float], *, reach_m: float = 0.0025) -> tuple[float, float] | None:  # fmt: skip
    """The far edge of a gap (its offset along ``across`` from ``c3``, in the top plane ``top``) fitted to the
    ranges of the camera-frame points ``q`` (camera at the origin; ``sigma`` their range noise) near the gap,
    with the near edge as given: (far, near). ``start``: the counts' edges (far, near; the far plate is the one
    the camera's rays run towards). The far edge is searched from ``reach_m`` beyond the start's to the start's
    middle. None when fewer than 50 rays cross the top there, the rays run along the top, fewer than
    :data:`MIN_FACE_RAYS` rays would meet the face (a gap seen as holes: its rays have no range to fit), or no
    edge explains the rays by :data:`MIN_GAIN` better than the start's."""
    far0, near0 = start
    sign = 1.0 if near0 > far0 else -1.0  # offsets counted from the far plate towards the near one
    rng = np.sqrt(np.einsum("ij,ij->i", q, q))
    ray = q / rng[:, None]
    rn = ray @ top.normal
    ok = np.abs(rn) > 1e-6
    rho_c = np.where(ok, -top.offset / np.where(ok, rn, 1.0), np.nan)  # the range where the ray crosses the top
    c = sign * ((rho_c[:, None] * ray - c3) @ across)  # the crossing's offset (far -> near positive)
    ra = sign * (ray @ across)  # the ray's run across per unit range (negative: towards the far plate)
    f0, n0 = sign * far0, sign * near0
    mid0 = 0.5 * (f0 + n0)
    keep = ok & np.isfinite(c) & (c > f0 - reach_m) & (c < n0 + reach_m) & (rho_c > 0)
    if keep.sum() < 50 or float(np.median(ra[keep])) >= -1e-3:
        return None  # too few rays, or rays that do not run towards a far plate's face
    c, ra, rho_c, rho, sig = c[keep], ra[keep], rho_c[keep], rng[keep], sigma[keep]
    order = np.argsort(c)
    c, ra, rho_c, rho, sig = c[order], ra[order], rho_c[order], rho[order], sig[order]
    cost_top = np.minimum(((rho - rho_c) / sig) ** 2, CAP_SIGMA**2)
    in_gap_near = c <= n0  # the near plate's top begins at its own edge, which the counts place (see above)

    def gain(e: float) -> tuple[float, int]:
        """How much the face at ``e`` lowers the cost of the rays crossing from ``e`` to the near edge (below
        zero: it explains them better than the top), and how many they are."""
        inside = (c >= e) & in_gap_near
        if not inside.any():
            return 0.0, 0
        rho_face = rho_c[inside] + (e - c[inside]) / np.minimum(ra[inside], -1e-6)  # the face x = e, past the top
        cost_face = np.minimum(((rho[inside] - rho_face) / sig[inside]) ** 2, CAP_SIGMA**2)
        return float(np.sum(cost_face - cost_top[inside])), int(inside.sum())

    candidates = np.arange(f0 - reach_m, mid0 + 1e-12, STEP_M)
    gains = [gain(float(e)) for e in candidates]
    k = int(np.argmin([g for g, _ in gains]))
    at_start = min(gain(f0)[0], 0.0)
    if gains[k][0] >= 0.0 or gains[k][1] < MIN_FACE_RAYS or gains[k][0] > at_start - MIN_GAIN:
        return None  # no face, the gap's rays without range, or no clear gain over the counts' edge
    return sign * float(candidates[k]), near0
