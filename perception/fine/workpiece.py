"""Which surfaces are the workpiece: those the operator's prompts touch, and every surface that touches one of
them in space, except the support (the paper's coarse stage: point prompts say what is to be welded).

A clutter box on the table, a second part beside the fixture, two boxes leaning on each other: their concave
corners are real folds, and only the prompts tell them from the part. A face the operator did not click (a
rib's narrow end, a gusset) still belongs to the part when it meets a prompted face: the surfaces are joined
through the adjacency graph, but only by pairs whose points come within reach of each other in space (an
object in front of the part in the image is not joined to it) and never through the support, nor across a gap
the support shows in (a box on the table whose corner comes a few millimetres from the part), except two plates
in one plane (a butt joint's gap may show the table). Without prompts
every surface counts (None).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from perception.fine.cylinder import axis_basis
from perception.fine.folds import contact_points_px
from perception.fine.types import FloatArray, NoiseModel, Pair, Surface, SurfaceSet
from perception.fits import median

PROMPT_RADIUS_PX = 2  # a prompt on an unlabelled work pixel (an edge, a dropout) takes the labels this near it
TOUCH_M = 0.006  # two surfaces touch when their points come this close (plus noise and spacing)
TOUCH_TRIES = 64  # point pairs within reach looked at for one with no support between them


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
    aim: bool = True,
) -> frozenset[int] | None:
    """The prompted surfaces and every surface joined to one by touching pairs (not through the support).

    Without prompts, when the support is seen, the camera's aim stands for a prompt (a cell's capture poses
    look at the part): the surface nearest the image centre, what touches it, and whatever stands on or under
    that over the support (:func:`_over_footprint`: a pipe whose walls are not seen, by its top). Boxes and
    fixtures beside it on the table are not the workpiece. None (every surface may be the workpiece's) when
    nothing is prompted and either no support is seen or the camera is not ``aim``-ed at the part (a cloud's
    virtual view), or when nothing prompted lies off the support."""
    auto = not prompted
    if auto:
        centre = centre_label(surfaces, support) if aim and support else None
        start = frozenset() if centre is None else frozenset({centre})
    else:
        start = prompted - support
    if not start:
        return None
    p = np.asarray(points, dtype=np.float64)
    neighbours: dict[int, set[int]] = {}
    for pair in pairs:
        if pair.a in support or pair.b in support or not _touch(p, surfaces, pair, noise, support):
            continue
        neighbours.setdefault(pair.a, set()).add(pair.b)
        neighbours.setdefault(pair.b, set()).add(pair.a)
    seen = _reached(start, neighbours)
    if auto:
        seen = _over_footprint(p, surfaces, seen, neighbours, support)
    return frozenset(seen)


def _reached(start: frozenset[int], neighbours: dict[int, set[int]]) -> set[int]:
    """``start`` and every label joined to one through ``neighbours``."""
    seen = set(start)
    todo = list(start)
    while todo:
        for n in neighbours.get(todo.pop(), ()):
            if n not in seen:
                seen.add(n)
                todo.append(n)
    return seen


FOOTPRINT_SHARE = 0.1  # a group joins the part when this share of it lies over the part's footprint, or the
# part's over the group's


def _over_footprint(p: FloatArray, surfaces: SurfaceSet, part: set[int], neighbours: dict[int, set[int]],
                    support: frozenset[int]) -> set[int]:  # fmt: skip
    """``part`` and every group of touching surfaces (not the support) that stands over its footprint on the
    support plane or under which it stands, the footprint (the convex hull of the points dropped onto the
    support, grown by :data:`TOUCH_M`) growing with each group taken, until none is left to take."""
    from perception.fine.support import footprint_share

    e1, e2 = axis_basis(surfaces.surfaces[min(support)].normal)  # the support plane's own axes
    lab = surfaces.labels
    flat = p.reshape(-1, 3)

    def dropped(labels: set[int]) -> FloatArray:
        idx = np.flatnonzero(np.isin(lab.reshape(-1), sorted(labels)))
        q = flat[idx[:: max(1, len(idx) // 2000)]]
        q = q[np.isfinite(q[:, 2])]
        return np.column_stack([q @ e1, q @ e2])

    def inside(xy: FloatArray, of: FloatArray) -> float:
        """The share of ``xy`` within the footprint of the points ``of``."""
        return footprint_share(xy, of, TOUCH_M)

    groups: list[set[int]] = []
    left = {s.label for s in surfaces.surfaces if s.label not in support and s.label not in part}
    while left:
        g = _reached(frozenset({min(left)}), neighbours) & left
        groups.append(g)
        left -= g
    part = set(part)
    changed = True
    while changed and groups:
        changed = False
        mine = dropped(part)
        for g in list(groups):
            theirs = dropped(g)
            if min(len(theirs), len(mine)) and max(inside(theirs, mine), inside(mine, theirs)) >= FOOTPRINT_SHARE:
                part |= g
                groups.remove(g)
                changed = True
                break
    return part


def centre_label(surfaces: SurfaceSet, support: frozenset[int]) -> int | None:
    """The surface (not the support) whose pixel lies nearest the centre of the work image; None if none."""
    lab = surfaces.labels
    ok = lab >= 0
    for k in support:
        ok &= lab != k
    if not ok.any():
        return None
    ys, xs = np.nonzero(ok)
    h, w = lab.shape
    k = int(np.argmin((ys - 0.5 * (h - 1)) ** 2 + (xs - 0.5 * (w - 1)) ** 2))
    return int(lab[ys[k], xs[k]])


def _touch(p: FloatArray, surfaces: SurfaceSet, pair: Pair, noise: NoiseModel, support: frozenset[int]) -> bool:
    """Whether the two surfaces' points among the pair's contact pixels come within reach in space with no
    support seen between them: of the point pairs within reach (nearest first, up to :data:`TOUCH_TRIES`), one
    whose pixels the support does not lie between. A blurred corner band between two faces of the part is not
    the table; a gap where the table shows is two objects side by side (a box on the table beside the part,
    its corner a few millimetres from the part's edge)."""
    from scipy.spatial import cKDTree

    lab = surfaces.labels
    pa, pb, px_a, px_b = contact_points_px(p, lab, pair)
    if len(pa) == 0 or len(pb) == 0:
        return False
    z = float(median(np.concatenate([pa[:, 2], pb[:, 2]])))
    reach = TOUCH_M + 3.0 * float(noise.sigma_m(z)) + 2.0 * float(noise.spacing_m(z))
    d, j = cKDTree(pb).query(pa, distance_upper_bound=reach)
    near = np.flatnonzero(np.isfinite(d))
    if not support or _butt_partners(surfaces.surfaces[pair.a], surfaces.surfaces[pair.b], pb):
        return len(near) > 0  # plates side by side in one plane: a butt joint's gap may show the table
    is_support = np.zeros(len(surfaces.surfaces) + 1, dtype=bool)  # indexed by label + 1 (-1: none)
    is_support[[k + 1 for k in support if k < len(surfaces.surfaces)]] = True
    for i in near[np.argsort(d[near], kind="stable")][:TOUCH_TRIES]:
        if not _support_between(lab, is_support, px_a[i], px_b[j[i]]):
            return True
    return False


def _butt_partners(a: Surface, b: Surface, pb: FloatArray) -> bool:
    """Whether planes ``a`` and ``b`` are the two plates of a butt joint as :mod:`perception.fine.gaps` models
    one: parallel within its angle and ``b``'s contact points ``pb`` on ``a``'s plane within its step."""
    from perception.fine.gaps import GapParams

    gp = GapParams()
    return (a.kind == "plane" and b.kind == "plane" and abs(float(a.normal @ b.normal)) >= np.cos(gp.max_angle_rad)
            and abs(float(median(a.residual(pb)))) <= gp.max_step_m)  # fmt: skip


def _support_between(lab: NDArray[np.int32], is_support: NDArray[np.bool_], a: NDArray[np.int64],
                     b: NDArray[np.int64]) -> bool:  # fmt: skip
    """Whether a support pixel lies on the image segment between pixels ``a`` and ``b`` (row, col)."""
    n = int(max(abs(int(b[0]) - int(a[0])), abs(int(b[1]) - int(a[1])))) + 1
    t = np.linspace(0.0, 1.0, n + 1)
    rows = np.rint(a[0] + t * (b[0] - a[0])).astype(np.intp)
    cols = np.rint(a[1] + t * (b[1] - a[1])).astype(np.intp)
    return bool(is_support[lab[rows, cols] + 1].any())
