"""Which surfaces meet: each surface's pixels dilated by a reach in metres (converted to pixels at its range),
and the pairs whose dilations overlap, with where they do. Surfaces that meet across a blurred corner band or
a strip with no data still count as neighbours.

The dilation by a disc runs compiled (:mod:`numba`) in time proportional to the window, whatever the reach:
OpenCV's dilation by the (2r + 1)-pixel ellipse visits each of the kernel's pixels (about 2 000 at 25 pixels);
the V-groove search dilates the nearly parallel plates by up to 25 pixels (ribs: 36 of a capture's 48 ms)."""

from __future__ import annotations

from collections.abc import Collection
from functools import cache

import numpy as np
from numba import njit
from numpy.typing import NDArray

from perception.fine.types import NoiseModel, Pair, SurfaceSet

REACH_M = 0.006
MIN_CONTACT_PX = 6
OPENCV_MAX_R = 8  # up to this reach OpenCV's dilation is the faster (0.2 against 0.4 ms on 300 x 400 pixels)


def adjacent_pairs(surfaces: SurfaceSet, noise: NoiseModel, *, reach_m: float = REACH_M,
                   among: Collection[int] | None = None) -> tuple[Pair, ...]:  # fmt: skip
    """Pairs (a < b) of surfaces within ``reach_m`` of each other in the image, with their contact pixels;
    only pairs of the labels ``among`` when given (the others are not dilated: a caller that looks at a few
    kinds of pair pays for those only)."""
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
        dil[k] = ((y0, y1, x0, x1), dilate_disc(lab[y0:y1, x0:x1] == k, r))
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


def dilate_disc(mask: NDArray[np.bool_], r: int) -> NDArray[np.bool_]:
    """``mask`` dilated by OpenCV's (2r + 1)-pixel ellipse (``cv2.getStructuringElement(cv2.MORPH_ELLIPSE, ...)``),
    the very pixels of ``cv2.dilate`` with it (outside the image counts as unset), in time proportional to the
    image: a pixel is set when, in some column, the set pixel nearest it vertically lies within the ellipse's
    half-width at that vertical distance (the half-width shrinks with the distance, so the nearest is the one
    that reaches farthest across). Up to OPENCV_MAX_R pixels by OpenCV itself."""
    if r <= OPENCV_MAX_R:
        import cv2

        ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        return np.asarray(cv2.dilate(mask.astype(np.uint8), ker), dtype=bool)
    return _dilate_disc(np.ascontiguousarray(mask, dtype=np.bool_), _half_widths(int(r)))


@cache
def _half_widths(r: int) -> NDArray[np.int64]:
    """The ellipse's half-width at each vertical distance 0 .. r from its centre row."""
    import cv2

    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return np.array([int(np.flatnonzero(ker[r + d]).max()) - r for d in range(r + 1)], dtype=np.int64)


@njit(cache=True)
def _dilate_disc(mask: NDArray[np.bool_], half: NDArray[np.int64]) -> NDArray[np.bool_]:
    """:func:`dilate_disc` with the half-widths ``half`` (vertical distance 0 .. r)."""
    h, w = mask.shape
    r = len(half) - 1
    far = r + 1
    # per pixel: the vertical distance to its column's nearest set pixel (at most r + 1), row by row down and up
    near = np.empty((h, w), np.int32)
    last = np.full(w, -far, np.int32)
    for y in range(h):
        for x in range(w):
            if mask[y, x]:
                last[x] = y
            near[y, x] = min(y - last[x], far)
    last[:] = h + far
    for y in range(h - 1, -1, -1):
        for x in range(w):
            if mask[y, x]:
                last[x] = y
            near[y, x] = min(near[y, x], last[x] - y)
    out = np.zeros((h, w), np.bool_)
    edges = np.zeros(w + 1, np.int32)  # each row's spans as +1 at their starts and -1 past their ends
    for y in range(h):
        edges[:] = 0
        for x in range(w):
            d = near[y, x]
            if d <= r:
                edges[max(x - half[d], 0)] += 1
                edges[min(x + half[d] + 1, w)] -= 1
        run = np.int32(0)
        for x in range(w):
            run += edges[x]
            out[y, x] = run > 0
    return out
