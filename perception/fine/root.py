"""A V-groove's open root, fitted as a profile to the pixels' ranges.

Across the groove the camera sees two bevels that stop at their lower edges, a root gap between the edges,
and below it the root faces and whatever lies beneath (the table, a backing bar). With the two bevel planes
fitted, one unknown fixes that profile: the height ``h`` of the lower edges above the bevels' intersection
(the plates' root faces are taken as equally high; the gap is then where the two bevels are at ``h``). For
each candidate height every pixel's ray is traced through the profile (a bevel above its edge; through the
gap onto a root face or the floor, the floor's depth the best of a few taken from the rays that pass the
gap) and its
measured range is compared with the traced one, in units of the noise and capped at three sigma. The root
is open at the best height when that explains the ranges clearly better than the closed root (the
intersection): by a log-likelihood ratio of ``OPEN_ROOT_MIN_GAIN``.

Near the intersection the floor seen through a narrow gap lies within the noise of both bevel planes, so no
count of single points can tell the gap from the faces; the traced ranges of all the rays along the seam
can.
"""

from __future__ import annotations

import numpy as np

from perception.fine.types import FloatArray, Surface

OPEN_ROOT_MIN_GAIN = 16.0  # in squared sigmas: a four-sigma preference over the closed root
HEIGHT_STEP_M = 5e-5
MAX_HEIGHT_M = 0.004
CAP_SIGMA = 3.0
FLOOR_QUANTILES = (50.0, 70.0, 90.0)


def open_root(q: FloatArray, sigma: FloatArray, line0: FloatArray, u: FloatArray, across: tuple[FloatArray, FloatArray],
              faces: tuple[Surface, Surface], span: tuple[float, float], *,
              radius_m: float) -> tuple[float, float] | None:  # fmt: skip
    """Where each bevel's lower edge lies (its distance from the intersection along ``across[i]``, the unit
    direction up bevel ``faces[i]``) when the root is open; None when the closed root explains the ranges as
    well. ``q``: (N, 3) camera-frame points near the seam (the camera at the origin), ``sigma`` their depth
    noise, ``line0``/``u`` the bevels' intersection, ``span`` the stretch along ``u`` (from ``line0``) to use,
    ``radius_m`` how far from the intersection (in the section) the profile is traced."""
    profile = _section_profile(q, sigma, line0, u, across, faces, span, radius_m=radius_m)
    if profile is None:
        return None
    bevels = profile.bevels
    heights = np.arange(0.0, min(MAX_HEIGHT_M, 0.5 * radius_m), HEIGHT_STEP_M)
    fixed, varying = profile.split(float(heights[-1]))  # the rays no candidate height changes cost the same at each
    costs = fixed + np.array([varying.cost(float(h)) for h in heights])
    lowest = np.flatnonzero(costs <= costs.min())
    if lowest[0] == 0 or costs[0] - costs.min() < OPEN_ROOT_MIN_GAIN:
        return None
    h = float(np.mean(heights[lowest]))  # the middle of the best heights (whole rays change sides in steps)
    return h / float(bevels[0][1]), h / float(bevels[1][1])


def _section_profile(q: FloatArray, sigma: FloatArray, line0: FloatArray, u: FloatArray,
                     across: tuple[FloatArray, FloatArray], faces: tuple[Surface, Surface],
                     span: tuple[float, float], *, radius_m: float) -> _Profile | None:  # fmt: skip
    """The rays of :func:`open_root`'s points in the groove's section frame; None when fewer than 50 lie within
    ``radius_m`` of the intersection along ``span`` or a bevel does not rise from it."""
    up = faces[0].normal + faces[1].normal
    up = up - (up @ u) * u
    up = up / max(float(np.linalg.norm(up)), 1e-12)
    x_axis = np.cross(u, up)
    rel = q - line0
    t = rel @ u
    section = np.stack([rel @ x_axis, rel @ up], axis=1)
    keep = (t >= min(span)) & (t <= max(span)) & (np.linalg.norm(section, axis=1) <= radius_m)
    if keep.sum() < 50:
        return None
    rng = np.linalg.norm(q[keep], axis=1)
    ray = np.stack([q[keep] @ x_axis, q[keep] @ up], axis=1) / rng[:, None]
    origin = np.array([-line0 @ x_axis, -line0 @ up])
    bevels = [np.array([v @ x_axis, v @ up]) for v in across]
    bevels = [b / max(float(np.linalg.norm(b)), 1e-12) for b in bevels]
    if min(float(b[1]) for b in bevels) < 0.05:
        return None  # a bevel that does not rise from the intersection: no groove to open
    return _Profile(origin, ray, rng, sigma[keep], bevels)


class _Profile:
    """The rays of one groove in its section frame (x across, z up, the intersection at the origin)."""

    def __init__(self, origin: FloatArray, ray: FloatArray, rng: FloatArray, sigma: FloatArray,
                 bevels: list[FloatArray]) -> None:  # fmt: skip
        self.origin, self.ray, self.rng, self.sigma, self.bevels = origin, ray, rng, sigma, bevels
        self.z_measured = origin[1] + rng * ray[:, 1]
        self.on_bevel = []  # per bevel: each ray's range where it crosses the bevel's line, and how far up it
        for b in bevels:
            n = np.array([-b[1], b[0]])
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = -(origin @ n) / (ray @ n)
            self.on_bevel.append((lam, (origin + lam[:, None] * ray) @ b))

    def split(self, h_max: float) -> tuple[float, _Profile]:
        """The summed cost of the rays whose trace is the same at every height up to ``h_max`` (each meets the bevel
        it meets first above that height's edge: a higher edge only takes hits away, and theirs stays the
        nearest), and the profile of the other rays."""
        lam_first = np.full(len(self.rng), np.inf)
        s_first = np.full(len(self.rng), -np.inf)
        for (lam, s), b in zip(self.on_bevel, self.bevels, strict=True):
            nearer = np.isfinite(lam) & (lam > 0) & (s >= 0.0) & (lam < lam_first)
            lam_first[nearer], s_first[nearer] = lam[nearer], s[nearer] * float(b[1])  # the hit's height
        same = np.isfinite(lam_first) & (s_first >= h_max)
        rest = _Profile(self.origin, self.ray[~same], self.rng[~same], self.sigma[~same], self.bevels)
        return self._cost_of(self.rng[same], lam_first[same], self.sigma[same]), rest

    def cost(self, h: float) -> float:
        traced = np.full(len(self.rng), np.inf)
        edges = [h / float(b[1]) for b in self.bevels]
        for (lam, s), edge in zip(self.on_bevel, edges, strict=True):
            hit = np.isfinite(lam) & (lam > 0) & (s >= edge)
            traced[hit] = np.minimum(traced[hit], lam[hit])
        x_edges = sorted(e * float(b[0]) for e, b in zip(edges, self.bevels, strict=True))
        with np.errstate(divide="ignore", invalid="ignore"):
            lam_gap = (h - self.origin[1]) / self.ray[:, 1]
        x_gap = self.origin[0] + lam_gap * self.ray[:, 0]
        through = ~np.isfinite(traced) & (x_gap > x_edges[0]) & (x_gap < x_edges[1])
        if through.sum() < 3:
            return self._cost(traced)
        # the floor's depth below the edges, a nuisance: profiled over the quantiles of the rays through the
        # gap (those that meet a root face come back shallower than the floor)
        best = np.inf
        for depth in np.percentile(h - self.z_measured[through], FLOOR_QUANTILES):
            below = self._below_gap(h, h - max(float(depth), 0.0), x_edges, lam_gap)
            best = min(best, self._cost(np.where(through, below, traced)))
        return best

    def _cost(self, traced: FloatArray) -> float:
        return self._cost_of(self.rng, traced, self.sigma)

    @staticmethod
    def _cost_of(rng: FloatArray, traced: FloatArray, sigma: FloatArray) -> float:
        r = (rng - traced) / sigma
        return float(np.where(np.isfinite(r), np.minimum(r * r, CAP_SIGMA**2), CAP_SIGMA**2).sum())

    def _below_gap(self, h: float, z_floor: float, x_edges: list[float], lam_gap: FloatArray) -> FloatArray:
        """Each ray's range to the root faces (vertical below the edges) or the floor between them."""
        o, d = self.origin, self.ray
        with np.errstate(divide="ignore", invalid="ignore"):
            lam_floor = (z_floor - o[1]) / d[:, 1]
            x_floor = o[0] + lam_floor * d[:, 0]
            out = np.where((x_floor >= x_edges[0]) & (x_floor <= x_edges[1]), lam_floor, np.inf)
            for x_wall in x_edges:
                lam_wall = (x_wall - o[0]) / d[:, 0]
                z_wall = o[1] + lam_wall * d[:, 1]
                on_wall = (lam_wall > lam_gap) & (z_wall >= z_floor) & (z_wall <= h)
                out = np.minimum(out, np.where(on_wall, lam_wall, np.inf))
        return np.asarray(out)
