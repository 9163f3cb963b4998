"""Two parallel planes a plate apart, grown into one surface, split in two (a thin plate lying on another)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from perception.fine.types import FloatArray, NoiseModel, Surface
from perception.fits import median

SPLIT_RMS_SHARE = 0.7  # each part's rms at most this share of the one plane's


def split_parallel(p: FloatArray, labels: NDArray[np.int32], surfaces: list[Surface], normals: FloatArray,
                   noise: NoiseModel, *, min_pixels: int) -> tuple[NDArray[np.int32], list[Surface]]:  # fmt: skip
    """Planes that are two parallel planes a plate apart (a thin plate lying on another, its edge face too
    narrow to break the growth between their tops) split in two. The common normal starts as the median
    of the pixels' local normals (one plane through both tops tilts; the tops' own normals do not), then
    the model is fitted alternately: the points split at the middle between the two groups' offsets along
    the normal, the normal from the two groups' pooled scatter, starting from the best two-class split of
    the heights along the median normal (a split at the median would cut the larger plate in two). It is
    kept when each group fits within the noise (rms at most :data:`SPLIT_RMS_SHARE` of the one plane's), the
    groups lie at least six sigma apart and each holds a tenth of the points: one plane's Gaussian noise
    split so lies about 1.6 sigma apart."""
    flat = labels.reshape(-1)
    pts = p.reshape(-1, 3)
    out = list(surfaces)
    for S in surfaces:
        sig = float(noise.sigma_m(S.z_m))
        # two planes six sigma apart, the smaller holding a tenth, fitted as one leave an rms of at least
        # 6 sigma * sqrt(0.1 * 0.9) = 1.8 sigma: a plane that fits better is one plane
        if S.kind != "plane" or S.n_points < 4 * min_pixels or S.rms_m < 1.8 * sig:
            continue
        idx = np.flatnonzero(flat == S.label)
        q = pts[idx]
        local = normals.reshape(-1, 3)[idx]
        local = local[np.all(np.isfinite(local), axis=1)]
        if len(local) < min_pixels:
            continue
        n = np.median(np.where((local @ S.normal)[:, None] < 0, -local, local), axis=0)
        n /= max(float(np.linalg.norm(n)), 1e-12)
        h0 = q @ n
        part = h0 > _two_class_threshold(h0)
        for _ in range(30):
            if part.sum() < min_pixels or (~part).sum() < min_pixels:
                break
            c0, c1 = q[~part].mean(axis=0), q[part].mean(axis=0)
            d = np.where(part[:, None], q - c1, q - c0)
            _w, v = np.linalg.eigh(d.T @ d)
            n = v[:, 0] if v[:, 0] @ S.normal > 0 else -v[:, 0]
            h = q @ n
            new_part = h > 0.5 * (float(c0 @ n) + float(c1 @ n))
            if np.array_equal(new_part, part):
                break
            part = new_part
        if min(part.sum(), (~part).sum()) < max(min_pixels, 0.1 * len(q)):
            continue
        h = q @ n
        o0, o1 = -float(np.mean(h[~part])), -float(np.mean(h[part]))
        rms0, rms1 = float(np.std(h[~part])), float(np.std(h[part]))
        if abs(o1 - o0) < 6.0 * sig or max(rms0, rms1) > SPLIT_RMS_SHARE * S.rms_m:
            continue
        lab = len(out)
        out[S.label] = replace(S, normal=n, offset=o0, rms_m=rms0, n_points=int((~part).sum()),
                               centroid=q[~part].mean(axis=0), z_m=float(np.median(q[~part][:, 2])))  # fmt: skip
        out.append(Surface(lab, "plane", n, o1, rms1, int(part.sum()), q[part].mean(axis=0),
                           float(median(q[part][:, 2]))))  # fmt: skip
        flat[idx[part]] = lab
    return labels, out


def _two_class_threshold(h: FloatArray, bins: int = 256) -> float:
    """The value splitting ``h`` into two classes of the largest between-class variance (Otsu's rule)."""
    counts, edges = np.histogram(h, bins=bins)
    centres = 0.5 * (edges[:-1] + edges[1:])
    w0 = np.cumsum(counts).astype(np.float64)
    w1 = w0[-1] - w0
    s0 = np.cumsum(counts * centres)
    m0 = s0 / np.maximum(w0, 1.0)
    m1 = (s0[-1] - s0) / np.maximum(w1, 1.0)
    between = w0 * w1 * (m0 - m1) ** 2
    return float(edges[int(np.argmax(between[:-1])) + 1])
