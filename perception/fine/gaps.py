"""Butt gaps: two coplanar surfaces whose facing boundaries run parallel across a narrow strip with nothing on
their plane in it. The seam is the gap's centre line on the plates' top surface, with its width."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from perception.fine.runs import covered_runs
from perception.fine.types import NoiseModel, Pair, SeamCurve, SurfaceSet


@dataclass(frozen=True)
class GapParams:
    max_angle_rad: float = np.radians(4.0)
    max_step_m: float = 0.002  # the two plates' planes may be offset by this much
    max_gap_m: float = 0.006
    min_gap_m: float = 0.0002
    min_length_m: float = 0.015
    bin_m: float = 0.002


def gap_seams(
    points: NDArray[np.floating],
    surfaces: SurfaceSet,
    pairs: tuple[Pair, ...],
    noise: NoiseModel,
    *,
    support: frozenset[int],
    params: GapParams | None = None,
) -> list[SeamCurve]:
    from scipy.spatial import cKDTree

    gp = params or GapParams()
    p = np.asarray(points, dtype=np.float64)
    lab = surfaces.labels
    out: list[SeamCurve] = []
    for pair in pairs:
        if pair.a in support or pair.b in support:
            continue
        A, B = surfaces.surfaces[pair.a], surfaces.surfaces[pair.b]
        if A.kind != "plane" or B.kind != "plane" or float(A.normal @ B.normal) < np.cos(gp.max_angle_rad):
            continue
        ys, xs = pair.contact_px[:, 0], pair.contact_px[:, 1]
        la = lab[ys, xs]
        pa, pb = p[ys[la == A.label], xs[la == A.label]], p[ys[la == B.label], xs[la == B.label]]
        if len(pa) < 10 or len(pb) < 10:
            continue
        if abs(float(np.median(A.residual(pb)))) > gp.max_step_m:
            continue
        # facing boundaries: each side's points within the widest gap of the other side
        da, _ = cKDTree(pb).query(pa)
        db, _ = cKDTree(pa).query(pb)
        reach = gp.max_gap_m + 3.0 * float(noise.spacing_m(A.z_m))
        ea, eb = pa[da <= reach], pb[db <= reach]
        if len(ea) < 8 or len(eb) < 8:
            continue
        both = np.vstack([ea, eb])
        c = both.mean(axis=0)
        n = A.normal + B.normal
        n /= np.linalg.norm(n)
        _, v = np.linalg.eigh(np.cov((both - c).T))
        u = v[:, 2] - (v[:, 2] @ n) * n
        u /= np.linalg.norm(u)
        across = np.cross(n, u)
        if float((eb.mean(axis=0) - ea.mean(axis=0)) @ across) < 0:
            across = -across
        edge_a = float(np.percentile((ea - c) @ across, 90))
        edge_b = float(np.percentile((eb - c) @ across, 10))
        width = edge_b - edge_a
        if not (gp.min_gap_m <= width <= gp.max_gap_m):
            continue
        # nothing on the plane inside the strip (else it is one plate split by the segmentation)
        strip = p[ys, xs]
        strip = strip[np.isfinite(strip[:, 2])]
        off = (strip - c) @ across
        inside = (off > edge_a + 0.25 * width) & (off < edge_b - 0.25 * width)
        sig = float(noise.sigma_m(A.z_m))
        on_plane = np.abs(strip[inside] @ n + 0.5 * (A.offset + B.offset)) <= 3.0 * sig
        if inside.sum() and on_plane.mean() > 0.3:
            continue
        mid = 0.5 * (edge_a + edge_b)
        ta, tb = (ea - c) @ u, (eb - c) @ u
        lo, hi = max(ta.min(), tb.min()), min(ta.max(), tb.max())
        if hi - lo < gp.min_length_m:
            continue
        nbins = int(np.ceil((hi - lo) / gp.bin_m))
        ca = np.bincount(np.clip(((ta - lo) / gp.bin_m).astype(int), 0, nbins - 1), minlength=nbins)
        cb = np.bincount(np.clip(((tb - lo) / gp.bin_m).astype(int), 0, nbins - 1), minlength=nbins)
        for s0, s1 in covered_runs((ca > 0) & (cb > 0), 4):
            t0, t1 = lo + s0 * gp.bin_m, lo + s1 * gp.bin_m
            if t1 - t0 < gp.min_length_m:
                continue
            base = c + mid * across
            # the top surface: the plates' mean plane through the centre line
            base = base - (base @ n + 0.5 * (A.offset + B.offset)) * n
            pts = np.array([base + t0 * u, base + t1 * u])
            out.append(SeamCurve("linear", "butt", pts, np.tile(A.normal, (2, 1)), np.tile(B.normal, (2, 1)),
                                 (A.label, B.label), int(ca[s0:s1].sum() + cb[s0:s1].sum()), max(A.rms_m, B.rms_m),
                                 gap_m=width))  # fmt: skip
    return out
