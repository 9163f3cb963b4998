"""Which surfaces meet: each surface's pixels dilated by a reach in metres (converted to pixels at its range),
and the pairs whose dilations overlap, with where they do. Surfaces that meet across a blurred corner band or
a strip with no data still count as neighbours."""

from __future__ import annotations

from collections.abc import Collection

import numpy as np
from numpy.typing import NDArray

from perception.fine.types import NoiseModel, Pair, SurfaceSet

REACH_M = 0.006
MIN_CONTACT_PX = 6


def adjacent_pairs(surfaces: SurfaceSet, noise: NoiseModel, *, reach_m: float = REACH_M,
                   among: Collection[int] | None = None) -> tuple[Pair, ...]:  # fmt: skip
    """Pairs (a < b) of surfaces within ``reach_m`` of each other in the image, with their contact pixels;
    only pairs of the labels ``among`` when given (the others are not dilated: a caller that looks at a few
    kinds of pair pays for those only)."""
    import cv2
    from scipy import ndimage

    lab = surfaces.labels
    h, w = lab.shape
    dil: dict[int, tuple[tuple[int, int, int, int], NDArray[np.bool_]]] = {}
    for k, sl in enumerate(ndimage.find_objects(lab + 1)):
        if sl is None or k >= len(surfaces.surfaces) or (among is not None and k not in among):
            continue
        s = surfaces.surfaces[k]
        r = int(np.clip(np.ceil(reach_m / float(noise.spacing_m(s.z_m))), 2, 25))
        y0, y1 = max(sl[0].start - r, 0), min(sl[0].stop + r, h)
        x0, x1 = max(sl[1].start - r, 0), min(sl[1].stop + r, w)
        m = (lab[y0:y1, x0:x1] == k).astype(np.uint8)
        ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        dil[k] = ((y0, y1, x0, x1), cv2.dilate(m, ker).astype(bool))
    out: list[Pair] = []
    keys = sorted(dil)
    for i, a in enumerate(keys):
        (ya0, ya1, xa0, xa1), da = dil[a]
        for b in keys[i + 1 :]:
            (yb0, yb1, xb0, xb1), db = dil[b]
            y0, y1, x0, x1 = max(ya0, yb0), min(ya1, yb1), max(xa0, xb0), min(xa1, xb1)
            if y0 >= y1 or x0 >= x1:
                continue
            both = da[y0 - ya0 : y1 - ya0, x0 - xa0 : x1 - xa0] & db[y0 - yb0 : y1 - yb0, x0 - xb0 : x1 - xb0]
            if int(both.sum()) < MIN_CONTACT_PX:
                continue
            ys, xs = np.nonzero(both)
            out.append(Pair(a, b, np.column_stack([ys + y0, xs + x0]).astype(np.int64)))
    return tuple(out)


def plane_partners(surfaces: SurfaceSet, *, min_cos: float, max_cos: float = 1.0,
                   exclude: Collection[int] = ()) -> frozenset[int]:  # fmt: skip
    """The labels of the planes (less ``exclude``) with another such plane whose normal makes a cosine in
    [min_cos, max_cos] with theirs: every plane of a pair a caller accepts by that cosine, and a few more (the
    bounds are widened by 1e-9 against rounding), for :func:`adjacent_pairs`' ``among``."""
    planes = [s for s in surfaces.surfaces if s.kind == "plane" and s.label not in exclude]
    if len(planes) < 2:
        return frozenset()
    n = np.array([s.normal for s in planes])
    c = n @ n.T
    ok = (c >= min_cos - 1e-9) & (c <= max_cos + 1e-9)
    np.fill_diagonal(ok, False)
    return frozenset(s.label for s, has in zip(planes, ok.any(axis=1), strict=True) if has)
