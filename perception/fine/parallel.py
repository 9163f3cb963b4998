"""Two parallel planes a plate apart, grown into one surface, split in two (a thin plate lying on another)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from perception.fine.types import FloatArray, NoiseModel, Surface
from perception.fits import median

SPLIT_RMS_SHARE = 0.7  # each part's rms at most this share of the one plane's
COHERENT_APART = 3.0  # sigmas: groups nearer than six sigma split a plane only if they lie in two regions ...
COHERENT_SHARE = 0.95  # ... where this share of the pixels is in the group most of its neighbours are in
COHERENT_RADIUS_PX = 2
COHERENT_FIRST = 0.75  # ... and a plane is only tried for such a split when its first split is this coherent


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
    split so lies about 1.6 sigma apart. Groups three to six sigma apart (a 3 mm plate seen by a noisy
    stereo camera) are kept when they are two regions of the image (:func:`_coherence`): one plane's noise
    split so is salt and pepper."""
    from scipy import ndimage

    flat = labels.reshape(-1)
    pts = p.reshape(-1, 3)
    out = list(surfaces)
    boxes = ndimage.find_objects(labels + 1)  # each label's rows and columns, found once
    for S in surfaces:
        sig = float(noise.sigma_m(S.z_m))
        # two planes three sigma apart, the smaller holding a tenth, fitted as one leave an rms of at least
        # 3 sigma * sqrt(0.1 * 0.9) = 0.9 sigma: a plane that fits better is one plane
        if S.kind != "plane" or S.n_points < 4 * min_pixels or S.rms_m < COHERENT_APART * 0.3 * sig:
            continue
        # a plane that fits as well as two planes six sigma apart would leave: two nearer planes split it only
        # as two regions, and its first split (heights along its own normal, tilted between the two) is
        # already more than half way from salt and pepper (about 0.6 of the pixels with their majority) to that
        if S.rms_m < 1.8 * sig and not _first_split_coherent(p, labels, S.label, boxes[S.label], S.normal):
            continue
        idx = np.flatnonzero(flat == S.label)
        q = pts[idx]
        grid = _in_box(idx, boxes[S.label], labels.shape[1])
        local = normals.reshape(-1, 3)[idx]
        local = local[np.all(np.isfinite(local), axis=1)]
        if len(local) < min_pixels:
            continue
        n = np.median(np.where((local @ S.normal)[:, None] < 0, -local, local), axis=0)
        n /= max(float(np.linalg.norm(n)), 1e-12)
        n, part = _two_planes(q, n, S.normal, grid, sig, min_pixels)
        if min(part.sum(), (~part).sum()) < max(min_pixels, 0.1 * len(q)):
            continue
        h = q @ n
        o0, o1 = -float(np.mean(h[~part])), -float(np.mean(h[part]))
        rms0, rms1 = float(np.std(h[~part])), float(np.std(h[part]))
        # the one plane's misfit on all its points (its fit's own rms is over the inliers it was fitted on,
        # which a surface's first fit may have taken within a scale its two layers widened)
        one = max(S.rms_m, float(np.sqrt(np.mean((q @ S.normal + S.offset) ** 2))))
        if abs(o1 - o0) >= 6.0 * sig:
            if max(rms0, rms1) > SPLIT_RMS_SHARE * one:
                continue
        elif (abs(o1 - o0) < COHERENT_APART * max(sig, rms0, rms1)
              or max(rms0, rms1) > max(SPLIT_RMS_SHARE * one, 1.25 * sig)
              or _coherence(grid, part)[0] < COHERENT_SHARE):  # fmt: skip
            # the groups, each pixel with most of its neighbours, lie three of their own sigma apart (a face seen
            # obliquely is noisier than the capture's sigma at its range) and each fits within the noise (their
            # rms is not cut at the middle, as the groups of planes six sigma apart nearly are)
            continue
        lab = len(out)
        out[S.label] = replace(S, normal=n, offset=o0, rms_m=rms0, n_points=int((~part).sum()),
                               centroid=q[~part].mean(axis=0), z_m=float(np.median(q[~part][:, 2])))  # fmt: skip
        out.append(Surface(lab, "plane", n, o1, rms1, int(part.sum()), q[part].mean(axis=0),
                           float(median(q[part][:, 2]))))  # fmt: skip
        flat[idx[part]] = lab
    return labels, out


@dataclass(frozen=True)
class _Grid:
    """A surface's pixels as flat indices ``idx`` into an image of ``shape`` (its bounding box), with how many
    of the surface's pixels lie within :data:`COHERENT_RADIUS_PX` of each (itself included), counted once."""

    shape: tuple[int, int]
    idx: NDArray[np.intp]
    count: FloatArray


def _grid(shape: tuple[int, int], idx: NDArray[np.intp]) -> _Grid:
    ones = np.ones(len(idx))
    return _Grid(shape, idx, np.maximum(_neighbour_sum(shape, idx, ones), 1.0))


def _neighbour_sum(shape: tuple[int, int], idx: NDArray[np.intp], values: FloatArray) -> FloatArray:
    """Per pixel ``idx``: the sum of ``values`` over the pixels ``idx`` within :data:`COHERENT_RADIUS_PX`."""
    import cv2

    k = 2 * COHERENT_RADIUS_PX + 1
    image = np.zeros(shape, np.float64)
    image.reshape(-1)[idx] = values
    return np.asarray(cv2.boxFilter(image, -1, (k, k), normalize=False).reshape(-1)[idx])


def _coherence(grid: _Grid, part: NDArray[np.bool_]) -> tuple[float, NDArray[np.bool_]]:
    """The share of a surface's pixels that lie in the group (``part`` or not) most of their neighbours of the
    surface lie in (about one where the groups are two regions of the image, nearer a half where they are one
    plane's noise), and that majority group per pixel."""
    majority = _neighbour_sum(grid.shape, grid.idx, part.astype(np.float64)) / grid.count > 0.5
    return float(np.mean(majority == part)), majority


def _in_box(idx: NDArray[np.intp], box: tuple[slice, slice] | None, width: int) -> _Grid:
    """A surface's pixels (flat indices ``idx`` into an image ``width`` wide) on the grid of its bounding
    ``box``: the neighbourhood sums are taken there."""
    assert box is not None
    rows, cols = np.divmod(idx, width)
    shape = (box[0].stop - box[0].start, box[1].stop - box[1].start)
    return _grid(shape, (rows - box[0].start) * shape[1] + (cols - box[1].start))


def _two_planes(q: FloatArray, n: FloatArray, ref: FloatArray, grid: _Grid,
                sigma_m: float, min_pixels: int) -> tuple[FloatArray, NDArray[np.bool_]]:  # fmt: skip
    """Two parallel planes through the points ``q`` (pixels ``grid``): their common normal (on ``ref``'s
    side) and which points lie on the nearer one, fitted alternately from the two-class split of the heights
    along ``n``. Groups nearer than six sigma are split as regions of the image: from the heights averaged
    over each pixel's neighbours, and with each pixel going with most of its neighbours."""
    h0 = q @ n
    part = h0 > _two_class_threshold(h0)
    near = _apart(q, part, n) < 6.0 * sigma_m
    if near:
        # a plate a few sigma thick over a small share of the surface stands out of the noise so (split one by
        # one, the larger plate's noise competes with it)
        h0 = _neighbour_sum(grid.shape, grid.idx, h0) / grid.count
        part = h0 > _two_class_threshold(h0)
    for _ in range(30):
        if part.sum() < min_pixels or (~part).sum() < min_pixels:
            break
        c0, c1 = q[~part].mean(axis=0), q[part].mean(axis=0)
        d = np.where(part[:, None], q - c1, q - c0)
        _w, v = np.linalg.eigh(d.T @ d)
        n = v[:, 0] if v[:, 0] @ ref > 0 else -v[:, 0]
        new_part = q @ n > 0.5 * (float(c0 @ n) + float(c1 @ n))
        if near:
            # a plate a few sigma thick leaves some of the other's points beyond the middle, and fitted as the
            # plate's they tilt the normal, which takes in more
            new_part = _coherence(grid, new_part)[1]
        if np.array_equal(new_part, part):
            break
        part = new_part
    return n, part


def _apart(q: FloatArray, part: NDArray[np.bool_], n: FloatArray) -> float:
    """How far apart along ``n`` the means of the two groups of points ``q`` lie (inf when one is empty)."""
    if part.all() or not part.any():
        return float("inf")
    return abs(float(q[part].mean(axis=0) @ n) - float(q[~part].mean(axis=0) @ n))


def _first_split_coherent(p: FloatArray, labels: NDArray[np.int32], label: int, box: tuple[slice, slice] | None,
                          normal: FloatArray) -> bool:  # fmt: skip
    """Whether a surface's pixels (inside its bounding ``box``) split by height along ``normal`` are
    :data:`COHERENT_FIRST` coherent, measured on every other row and column (a quarter of the cost).
    ``p`` (H, W, 3), ``labels`` (H, W)."""
    if box is None:
        return False
    window = slice(box[0].start, box[0].stop, 2), slice(box[1].start, box[1].stop, 2)
    mine = labels[window] == label
    idx = np.flatnonzero(mine)
    if len(idx) < 16:
        return True
    h = p[window][mine] @ normal
    return _coherence(_grid(mine.shape, idx), h > _two_class_threshold(h))[0] >= COHERENT_FIRST


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
