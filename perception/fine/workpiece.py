"""Which surfaces are the workpiece: those the operator's prompts touch, and every surface that touches one of
them in space, except the support (the paper's coarse stage: point prompts say what is to be welded).

A clutter box on the table, a second part beside the fixture, two boxes leaning on each other: their concave
corners are real folds, and only the prompts tell them from the part. A face the operator did not click (a
rib's narrow end, a gusset) still belongs to the part when it meets a prompted face: the surfaces are joined
through the adjacency graph, but only by pairs whose points come within reach of each other in space (an
object in front of the part in the image is not joined to it) and never through the support. Without prompts
every surface counts (None).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from perception.fine.folds import contact_points
from perception.fine.types import FloatArray, NoiseModel, Pair, SurfaceSet
from perception.fits import median

PROMPT_RADIUS_PX = 2  # a prompt on an unlabelled work pixel (an edge, a dropout) takes the labels this near it
TOUCH_M = 0.006  # two surfaces touch when their points come this close (plus noise and spacing)


def prompted_labels(prompts_px: FloatArray | None, surfaces: SurfaceSet) -> frozenset[int]:
    """The labels under the prompts ((N, 2) full-resolution pixels (u, v), pixel centres at integers)."""
    if prompts_px is None or len(prompts_px) == 0:
        return frozenset()
    lab = surfaces.labels
    h, w = lab.shape
    r = PROMPT_RADIUS_PX
    out: set[int] = set()
    for u, v in np.asarray(prompts_px, dtype=np.float64):
        col, row = round(u / surfaces.factor), round(v / surfaces.factor)
        if not (0 <= row < h and 0 <= col < w):
            continue
        if lab[row, col] >= 0:
            out.add(int(lab[row, col]))
            continue
        win = lab[max(row - r, 0) : row + r + 1, max(col - r, 0) : col + r + 1]
        labels, counts = np.unique(win[win >= 0], return_counts=True)
        if len(labels):
            out.add(int(labels[np.argmax(counts)]))
    return frozenset(out)


def workpiece_labels(
    points: NDArray[np.floating],
    surfaces: SurfaceSet,
    pairs: tuple[Pair, ...],
    noise: NoiseModel,
    *,
    prompted: frozenset[int],
    support: frozenset[int],
) -> frozenset[int] | None:
    """The prompted surfaces and every surface joined to one by touching pairs (not through the support); None
    when nothing is prompted (every surface may then be the workpiece's)."""
    start = prompted - support
    if not start:
        return None
    p = np.asarray(points, dtype=np.float64)
    neighbours: dict[int, set[int]] = {}
    for pair in pairs:
        if pair.a in support or pair.b in support or not _touch(p, surfaces, pair, noise):
            continue
        neighbours.setdefault(pair.a, set()).add(pair.b)
        neighbours.setdefault(pair.b, set()).add(pair.a)
    seen = set(start)
    todo = list(start)
    while todo:
        for n in neighbours.get(todo.pop(), ()):
            if n not in seen:
                seen.add(n)
                todo.append(n)
    return frozenset(seen)


def _touch(p: FloatArray, surfaces: SurfaceSet, pair: Pair, noise: NoiseModel) -> bool:
    """Whether the two surfaces' points among the pair's contact pixels come within reach in space."""
    from scipy.spatial import cKDTree

    pa, pb = contact_points(p, surfaces.labels, pair)
    if len(pa) == 0 or len(pb) == 0:
        return False
    z = float(median(np.concatenate([pa[:, 2], pb[:, 2]])))
    reach = TOUCH_M + 3.0 * float(noise.sigma_m(z)) + 2.0 * float(noise.spacing_m(z))
    d, _ = cKDTree(pb).query(pa, distance_upper_bound=reach)
    return bool(np.isfinite(d).any())
