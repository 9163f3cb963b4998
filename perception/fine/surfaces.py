"""Surfaces first: the work image split into fitted planes and cylinders, with thresholds from its noise.

1. A pixel is *smooth* when its window's residual about the local plane is within a few sigma of the
   measured noise at its range; folds, edges and flying pixels are not.
2. Smooth pixels are joined to their 4-neighbours unless the normal turns or the depth jumps between them
   (both thresholds scale with the noise and the sample spacing); each connected piece is a patch.
3. Each patch is fitted with a plane, or, when its normals fan out about one axis, a cylinder; a patch that
   neither fits is dropped.
4. Each surface then grows, pixel ring by pixel ring, into the unassigned pixels next to it whose points lie
   on it within the noise: the blurred band around a fold is shared out to the two surfaces up to the
   corner, so that their supports meet where the seam is.
5. Planes whose pixels touch and which are one plane within the noise are merged (a face split by a
   specular hole or a shadow is one face).
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from perception.fine.components import smooth_components
from perception.fine.cylinder import MAX_RADIUS_M, fit_cylinder, normals_follow, turns
from perception.fine.groups import Groups
from perception.fine.grow import grow
from perception.fine.noise import LocalPlanes
from perception.fine.parallel import split_parallel
from perception.fine.types import NoiseModel, Surface, SurfaceSet
from perception.fits import mean_rows, median, percentile, sum_rows

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SurfaceParams:
    smooth_sigma: float = 3.0  # a pixel is smooth when its local plane residual is within this many sigma
    normal_turn_rad: float = np.radians(40.0)  # a fold: normals one window apart turn more than this
    jump_sigma: float = 6.0  # a depth jump between neighbours beyond this many sigma (plus spacing) splits
    min_pixels: int = 25  # smallest patch kept (work resolution)
    inlier_sigma: float = 4.0  # a point lies on a surface within this many sigma of the noise at its range
    plane_share: float = 0.97  # a patch is one plane when this share of it lies on its best plane
    grow_sigma: float = 3.0
    grow_rings: int = 10
    cylinder_min_turn_rad: float = np.radians(20.0)  # a patch whose normals spread less is not a cylinder
    merge_angle_rad: float = np.radians(3.0)
    min_width_px: float = 1.5  # a plane's support must be this wide (RMS across its narrow direction)
    narrow_min_pixels: int = 12
    narrow_min_width_px: float = 0.8


EDGE_ON_RAD = np.radians(5.0)  # a plane whose normal is this near square to the camera's ray is seen edge-on


def _fit_plane(p: FloatArray, weights: FloatArray | None = None) -> tuple[FloatArray, float, float]:
    """Least-squares plane of (N, 3) points, each weighted by ``weights`` when given: unit normal (towards the
    camera), offset, RMS residual."""
    return fit_plane_rows(p, np.ascontiguousarray(p.T), weights)


def fit_plane_rows(p: FloatArray, rows: FloatArray, weights: FloatArray | None = None, *,
                   work: tuple[FloatArray, FloatArray] | None = None) -> tuple[FloatArray, float, float]:  # fmt: skip
    """:func:`_fit_plane` of (N, 3) points ``p`` also given as their (3, N) coordinate rows ``rows`` (a fit
    that refits the same points keeps both). The centroid is summed over ``p``
    (:func:`perception.fits.sum_rows`) and the points are centred and weighted in ``rows``, where that is one
    pass along each row (on (N, 3) rows it is a loop three values wide, ten times slower); the values are the
    ones the (N, 3) arithmetic gives, to rounding (BLAS is handed the same matrices in the other layout, and
    OpenBLAS picks its kernel, so its order of summing, by the CPU). ``work``: two (3, N) arrays the centred
    and the weighted rows are written to (a fit repeated on the same points reuses them: a fresh array of
    that size costs its page faults)."""
    if weights is None:
        c = mean_rows(p)
        q = np.subtract(rows, c[:, None], out=None if work is None else work[0])
        w, v = np.linalg.eigh(q @ q.T / max(len(p), 1))
    else:
        total = weights.sum()
        c = sum_rows(p, weights) / total
        q = np.subtract(rows, c[:, None], out=None if work is None else work[0])
        qw = np.multiply(q, weights, out=None if work is None else work[1])
        w, v = np.linalg.eigh(qw @ q.T)
        w = w / total
    n = v[:, 0]
    if n @ c > 0:  # towards the camera
        n = -n
    return n, -float(n @ c), float(np.sqrt(max(w[0], 0.0)))


def _two_dimensional(q: FloatArray, spacing_m: float, sp: SurfaceParams) -> bool:
    """A plane needs support in two directions: points along a strip a pixel or two wide fit any plane
    through their line (a face seen at a grazing angle, a thin edge)."""
    c = np.ascontiguousarray(q.T) - mean_rows(q)[:, None]  # centred in (3, N) rows (see fit_plane_rows)
    w = np.linalg.eigvalsh(c @ c.T / max(len(q), 1))
    return bool(np.sqrt(max(w[1], 0.0)) >= sp.min_width_px * spacing_m)


def _robust_plane(p: FloatArray, tol: float) -> tuple[FloatArray, float, float, NDArray[np.bool_]]:
    keep = np.ones(len(p), bool)
    n, d, rms = _fit_plane(p)
    for _ in range(3):
        res = np.abs(p @ n + d)
        new = res <= max(tol, 2.5 * rms)
        if new.sum() < 10 or np.array_equal(new, keep):
            break
        keep = new
        n, d, rms = _fit_plane(p[keep])
    return n, d, rms, keep


def _ransac_planes(q: FloatArray, tol: FloatArray, min_points: int, rng: np.random.Generator, *,
                   pixels: NDArray[np.int64] | None, width: int, max_planes: int = 8,
                   trials: int = 150) -> list[NDArray[np.int64]]:  # fmt: skip
    """Index sets of the planes found one after another (largest first) in (N, 3) points; each plane keeps
    only its largest connected piece of pixels (scattered inliers of a tilted plane are not a surface), when
    the points' flat pixel indices ``pixels`` are given."""
    left = np.arange(len(q))
    out: list[NDArray[np.int64]] = []
    dist = np.empty((0, 0))
    within = np.empty((0, 0), dtype=bool)
    while len(left) >= min_points and len(out) < max_planes:
        sample = left if len(left) <= 3000 else rng.choice(left, 3000, replace=False)
        tri = rng.integers(0, len(sample), (trials, 3))
        a, b, c = q[sample[tri[:, 0]]], q[sample[tri[:, 1]]], q[sample[tri[:, 2]]]
        nn = np.cross(b - a, c - a)
        norm = np.linalg.norm(nn, axis=1)
        good = norm > 1e-9
        nn = nn[good] / norm[good, None]
        dd = -(nn * a[good]).sum(axis=1)
        # every trial's distances in one (sample, trials) matrix, worked on in place and kept for the next
        # plane's trials: a few MB per temporary, and each fresh one costs its page faults (it was 8x slower)
        if dist.shape != (len(sample), len(nn)):
            dist, within = np.empty((len(sample), len(nn))), np.empty((len(sample), len(nn)), dtype=bool)
        np.matmul(q[sample], nn.T, out=dist)
        dist += dd
        np.abs(dist, out=dist)
        cnt = np.less_equal(dist, tol[sample, None], out=within).sum(axis=0)
        if cnt.size == 0:
            break
        k = int(np.argmax(cnt))
        best_n, best_d, best_cnt = nn[k], dd[k], int(cnt[k])
        if best_cnt < 0.5 * min_points * len(sample) / len(left):
            break
        # the points left, gathered once for both takes (all of them, as they are, before the first plane)
        q_left, tol_left = (q, tol) if len(left) == len(q) else (q[left], tol[left])
        inl = left[np.abs(q_left @ best_n + best_d) <= tol_left]
        if len(inl) < min_points:
            break
        # refine on the inliers and take them again
        n2, d2, _ = _fit_plane(q[inl])
        inl = left[np.abs(q_left @ n2 + d2) <= tol_left]
        if len(inl) < min_points:
            break
        piece = inl if pixels is None else inl[_largest_piece(pixels[inl], width)]
        if len(piece) >= min_points:
            out.append(piece)
            left = _without(left, piece, len(q))
            continue
        left = _without(left, inl, len(q))
    return out


def _without(left: NDArray[np.int64], taken: NDArray[np.int64], n: int) -> NDArray[np.int64]:
    """The indices of ``left`` (sorted, distinct, below ``n``) not in ``taken`` (a subset of them), in order: the
    values of ``np.setdiff1d(left, taken, assume_unique=True)``, by a mask instead of a sort."""
    keep = np.ones(n, dtype=bool)
    keep[taken] = False
    return left[keep[left]]


def segment_surfaces(
    points: NDArray[np.floating],
    planes: LocalPlanes,
    noise: NoiseModel,
    *,
    factor: int,
    params: SurfaceParams | None = None,
) -> SurfaceSet:
    """Planes and cylinders of an (h, w, 3) work-resolution organized cloud (camera frame, NaN invalid)."""
    sp = params or SurfaceParams()
    p = np.asarray(points, dtype=np.float64)
    z = p[..., 2]
    sigma = noise.sigma_m(np.where(np.isfinite(z), z, 1.0))
    comp, counts = smooth_components(p, planes, noise, normal_turn_rad=sp.normal_turn_rad, jump_sigma=sp.jump_sigma)

    surfaces: list[Surface] = []
    labels = np.full(z.shape, -1, np.int32)
    order = _stable_order(comp.ravel(), len(counts))
    starts = np.searchsorted(comp.ravel()[order], np.arange(len(counts)))
    rng = np.random.default_rng(0)
    queue = deque(order[starts[c] : starts[c] + counts[c]] for c in np.flatnonzero(counts >= sp.min_pixels))
    while queue:
        found, left = _fit_patch(p, queue.popleft(), planes.normal.reshape(-1, 3), sigma.reshape(-1), noise, sp, rng)
        for s, members in found:
            labels.reshape(-1)[members] = len(surfaces)
            surfaces.append(replace(s, label=len(surfaces)))
        queue.extend(left)  # after every component: the random stream of the others stays as it was
    labels, surfaces = _complete(p, labels, surfaces, planes.normal, sigma, noise, sp)
    n_before = len(surfaces)
    labels, surfaces = split_parallel(p, labels, surfaces, planes.normal, noise, min_pixels=sp.min_pixels)
    if len(surfaces) > n_before:  # a split plate's part may be one plane with its neighbour (a strip by its edge)
        labels, surfaces = _merge_coplanar(p, labels, surfaces, noise, sp)
    return SurfaceSet(labels, factor, tuple(surfaces))


def _stable_order(keys: NDArray[np.int32], n_keys: int) -> NDArray[np.intp]:
    """``np.argsort(keys, kind="stable")`` of labels -1 .. n_keys - 1: sorted as int16 when they fit (a stable
    sort's order is unique, and NumPy radix-sorts 16-bit keys, three times faster)."""
    return np.argsort(keys.astype(np.int16) if n_keys < 2**15 - 1 else keys, kind="stable")


def _fit_patch(p: FloatArray, idx: NDArray[np.int64], pn: FloatArray, sig_all: FloatArray, noise: NoiseModel,
               sp: SurfaceParams, rng: np.random.Generator
               ) -> tuple[list[tuple[Surface, NDArray[np.int64]]], list[NDArray[np.int64]]]:  # fmt: skip
    """The surfaces of one patch (flat pixel indices ``idx`` of the work image): one plane, a cylinder and
    the planes beside it, or several planes joined across soft edges; with their members, and the pieces
    of the patch a single plane leaves out that are large enough to be surfaces of their own (a plate's top
    joined to the table across its edge holds a few percent of the table's patch: within the plane's share
    of outliers, but a face)."""
    w = p.shape[1]
    q = p.reshape(-1, 3)[idx]
    zc = float(median(q[:, 2]))
    tol = sp.inlier_sigma * sig_all[idx]  # per point: the noise grows with range
    th = max(1, len(q) // 20000)  # fits on at most ~20k points; inliers are taken on all
    nrm, d, rms = _fit_plane(q[::th])
    for _ in range(3):
        inl = np.abs(q[::th] @ nrm + d) <= tol[::th]
        if inl.sum() < 10:
            break
        nrm, d, rms = _fit_plane(q[::th][inl])
    # a face seen obliquely is noisier than the range alone says: its own residual scale, up to 3x
    res = np.abs(q @ nrm + d)
    scale = np.clip(1.4826 * median(res) / np.maximum(median(sig_all[idx]), 1e-9), 1.0, 3.0)
    inl = res <= tol * scale
    spacing_c = float(noise.spacing_m(zc))
    if not _two_dimensional(q[::th], spacing_c, sp):
        return [], []
    if inl.mean() >= sp.plane_share:
        s = Surface(-1, "plane", nrm, d, rms, int(inl.sum()), mean_rows(q[inl]), zc)
        out_px = idx[~inl]
        return [(s, idx[inl])], [out_px[k] for k in _connected_pieces(out_px, w, sp.min_pixels)]
    out: list[tuple[Surface, NDArray[np.int64]]] = []
    rest = np.arange(len(q))
    found = _try_cylinder(q, pn[idx], tol, -1, zc, spacing_c, 0.6, sp.min_pixels, sp)
    if found is not None:
        out.append((found[0], idx[found[1]]))
        rest = np.flatnonzero(~found[1])
        if len(rest) < sp.min_pixels:
            return out, []
    # several planes joined across soft edges (a plate's top, its edge face and the table), or the planes
    # beside a cylinder: split them
    return out + _planes_of(q[rest], idx[rest], tol[rest], w, zc, spacing_c, sp, rng), []


def _planes_of(q: FloatArray, idx: NDArray[np.int64], tol: FloatArray, width: int, zc: float, spacing: float,
               sp: SurfaceParams, rng: np.random.Generator) -> list[tuple[Surface, NDArray[np.int64]]]:  # fmt: skip
    """The planes found one after another in the points ``q`` of a piece (flat pixel indices ``idx``), each
    its largest connected piece and two-dimensional, unlabelled, with their members."""
    out: list[tuple[Surface, NDArray[np.int64]]] = []
    for sub in _ransac_planes(q, tol, sp.min_pixels, rng, pixels=idx, width=width):
        qs = q[sub]
        if _two_dimensional(qs, spacing, sp):
            nrm, d, rms = _fit_plane(qs)
            out.append((Surface(-1, "plane", nrm, d, rms, len(sub), mean_rows(qs), zc), idx[sub]))
    return out


def _connected_pieces(pixels: NDArray[np.int64], width: int, min_size: int) -> list[NDArray[np.int64]]:
    """Index sets (into ``pixels``, flat pixel indices) of the 8-connected pieces of at least ``min_size``."""
    if len(pixels) < min_size:
        return []
    c, n = _piece_labels(pixels, width)
    sizes = np.bincount(c, minlength=n)
    order = np.argsort(c, kind="stable")
    starts = np.searchsorted(c[order], np.arange(n + 1))
    return [order[starts[k] : starts[k + 1]] for k in range(1, n) if sizes[k] >= min_size]


def _largest_piece(pixels: NDArray[np.int64], width: int) -> NDArray[np.intp]:
    """The index set (into ``pixels``, flat pixel indices) of their largest 8-connected piece, the first of
    equals: ``max(_connected_pieces(pixels, width, 1), key=len)``, without sorting every index by its piece."""
    c, n = _piece_labels(pixels, width)
    sizes = np.bincount(c, minlength=n)
    return np.flatnonzero(c == 1 + int(np.argmax(sizes[1:])))


def _piece_labels(pixels: NDArray[np.int64], width: int) -> tuple[NDArray[np.int32], int]:
    """Each of the (non-empty) ``pixels``' 8-connected piece, 1 to n - 1, and n."""
    import cv2

    ys, xs = np.divmod(pixels, width)
    y0, x0 = ys.min(), xs.min()
    m = np.zeros((ys.max() - y0 + 1, xs.max() - x0 + 1), np.uint8)
    m[ys - y0, xs - x0] = 1
    n, comp = cv2.connectedComponents(m, connectivity=8)
    return comp[ys - y0, xs - x0], int(n)


def _complete(p: FloatArray, labels: NDArray[np.int32], surfaces: list[Surface], normals: FloatArray,
              sigma: FloatArray, noise: NoiseModel,
              sp: SurfaceParams) -> tuple[NDArray[np.int32], list[Surface]]:  # fmt: skip
    """The surfaces grown into the corner bands, narrow faces recovered, coplanar pieces and a pipe's strips
    merged."""
    labels = grow(p, labels, surfaces, sigma, within_sigma=sp.grow_sigma, rings=sp.grow_rings)
    # narrow faces (a bevel, a lap plate's edge, seen a few pixels wide) lose their middle to the fold cuts
    # of both their edges; what is left between the grown surfaces is fitted again on its own
    n_before = len(surfaces)
    labels = _recover_narrow(p, labels, surfaces, sigma, noise, sp, normals)
    if len(surfaces) > n_before:
        labels = grow(p, labels, surfaces, sigma, within_sigma=sp.grow_sigma, rings=sp.grow_rings)
    labels, surfaces = _merge_coplanar(p, labels, surfaces, noise, sp)
    n_before = len(surfaces)
    labels, surfaces = _merge_cylinders(p, labels, surfaces, normals, sigma, noise, sp)
    if len(surfaces) < n_before:
        labels = grow(p, labels, surfaces, sigma, within_sigma=sp.grow_sigma, rings=sp.grow_rings)
    return labels, surfaces


def _try_cylinder(q: FloatArray, normals: FloatArray, tol: FloatArray, label: int, zc: float, spacing: float,
                  min_share: float, min_points: int, sp: SurfaceParams, *,
                  turning_start: bool = True) -> tuple[Surface, NDArray[np.bool_]] | None:  # fmt: skip
    """A cylinder through most of ``q`` (at least ``min_share`` within ``tol``), labelled ``label``, and its
    inliers; None when none fits or its radius is implausible (3 mm to MAX_RADIUS_M, 1 m). ``turning_start``: as
    :func:`perception.fine.cylinder.fit_cylinder`'s."""
    sel: NDArray[np.bool_] | None = None  # all of them (a copy of every point of a table's patch costs)
    for _ in range(3):  # refitted on its own points: other faces in ``q`` (a plate, a cap) pull the first fit
        on, on_normals = (q, normals) if sel is None else (q[sel], normals[sel])
        cyl = fit_cylinder(on, on_normals, turning_start=turning_start)
        if cyl is None or not 0.003 < cyl[2] < MAX_RADIUS_M:
            return None
        axis, centre, r, _ = cyl
        trial = Surface(-1, "cylinder", np.zeros(3), 0.0, 0.0, 0, mean_rows(q), zc, axis=axis, centre=centre,
                        radius=r)  # fmt: skip
        cres = np.abs(trial.residual(q))
        inl = cres <= tol
        if inl.mean() >= min_share:
            break
        if inl.mean() < 0.5 * min_share:
            return None  # not nearly a cylinder: refitting would not make it one
        sel = cres <= max(float(percentile(cres, 60)), float(median(tol)))
        if sel.sum() < max(min_points, 20):
            return None
    if inl.mean() < min_share or inl.sum() < min_points or not _two_dimensional(q[inl], spacing, sp):
        return None
    if not turns(trial, q[inl], sp.cylinder_min_turn_rad) or not normals_follow(trial, q[inl], normals[inl]):
        return None  # hardly bent, or bent only at its edges: a plane, or a blurred fold between two
    # a narrow flat face with its rounded edges bends like a wide cylinder: of the cylinder's own points, the
    # bend must explain at least a surface's worth (``min_points``) that the best plane leaves out. The planes
    # are found one after another: the first of two is the best one alone
    planes = _ransac_planes(q[inl], tol[inl], min_points, np.random.default_rng(0), pixels=None, width=0,
                            max_planes=2)  # fmt: skip
    if (len(planes[0]) if planes else 0) + min_points > inl.sum():
        return None
    crms = float(np.sqrt(np.mean(cres[inl] ** 2)))
    if _fold_fits_better(q[inl], planes, min_points, crms):
        return None
    return replace(trial, label=label, rms_m=crms, n_points=int(inl.sum()), centroid=mean_rows(q[inl])), inl


def _fold_fits_better(q: FloatArray, planes: list[NDArray[np.int64]], min_points: int, cylinder_rms: float) -> bool:
    """Whether the two ``planes`` found in ``q`` (:func:`_ransac_planes`, their index sets) meet at a fold
    (normals 30 degrees or more apart), take all but fewer than ``min_points`` of ``q`` and fit them better (a
    smaller RMS distance, each point to its nearer plane) than the cylinder does (``cylinder_rms``): a corner
    whose blurred band a cylinder bridges (a floor and the foot of a wall seen from afar), not a cylinder. The
    normals measured near the corner turn across it as on a pipe (the local planes are seven pixels wide), so
    only the fits tell the two apart."""
    if len(planes) < 2 or sum(len(k) for k in planes) + min_points <= len(q):
        return False
    (na, da, _), (nb, db, _) = (_fit_plane(q[k]) for k in planes)
    if abs(float(na @ nb)) > np.cos(np.radians(30.0)):
        return False
    nearer = np.minimum(np.abs(q @ na + da), np.abs(q @ nb + db))
    return float(np.sqrt(np.mean(nearer**2))) < cylinder_rms


def _recover_narrow(p: FloatArray, labels: NDArray[np.int32], surfaces: list[Surface], sigma: FloatArray,
                    noise: NoiseModel, sp: SurfaceParams, normals: FloatArray) -> NDArray[np.int32]:  # fmt: skip
    """Planes fitted to the connected pieces of valid pixels that no surface took (appends to ``surfaces``);
    a piece no plane fits may be a cylinder: a pipe of small radius seen from afar turns so fast that the
    fold cuts take all of it."""
    import cv2

    free = (np.isfinite(p[..., 2]) & (labels < 0)).astype(np.uint8)
    n, comp, stats, _ = cv2.connectedComponentsWithStats(free, connectivity=8)
    lab = labels.copy()
    flat_p = p.reshape(-1, 3)
    width = p.shape[1]
    for c in range(1, n):
        if stats[c, cv2.CC_STAT_AREA] < sp.narrow_min_pixels:
            continue
        y0, x0 = stats[c, cv2.CC_STAT_TOP], stats[c, cv2.CC_STAT_LEFT]
        ys, xs = np.nonzero(comp[y0 : y0 + stats[c, cv2.CC_STAT_HEIGHT], x0 : x0 + stats[c, cv2.CC_STAT_WIDTH]] == c)
        idx = (ys + y0) * width + xs + x0  # its flat pixel indices in raster order, found in its box
        q = flat_p[idx]
        zc = float(median(q[:, 2]))
        tol = sp.inlier_sigma * sigma.reshape(-1)[idx]
        nrm, d, rms = _fit_plane(q)
        for _ in range(3):
            inl = np.abs(q @ nrm + d) <= tol
            if inl.sum() < sp.narrow_min_pixels:
                break
            nrm, d, rms = _fit_plane(q[inl])
        inl = np.abs(q @ nrm + d) <= tol
        spacing = float(noise.spacing_m(zc))
        if inl.mean() < 0.85:
            # a piece left between grown surfaces is where a fold's blurred band ends up: its normals turn with
            # the blur, no evidence of a cylinder's radius (zoo dev open box 112: a 9 mm "cylinder" along two
            # walls' convex edge, which took their inside corner's seam); its fit starts from the circle alone
            found = _try_cylinder(q, normals.reshape(-1, 3)[idx], tol, len(surfaces), zc, spacing, 0.7,
                                  sp.min_pixels, sp, turning_start=False)  # fmt: skip
            if found is not None:
                surfaces.append(found[0])
                lab.reshape(-1)[idx[found[1]]] = found[0].label
                continue
            # several faces in one piece (a plate's top with the bands along its edges): their planes
            for plane, members in _planes_of(q, idx, tol, p.shape[1], zc, spacing, sp, np.random.default_rng(0)):
                lab.reshape(-1)[members] = len(surfaces)
                surfaces.append(replace(plane, label=len(surfaces)))
            continue
        if inl.sum() < sp.narrow_min_pixels:
            continue
        c_ = q[inl] - mean_rows(q[inl])
        w = np.linalg.eigvalsh(c_.T @ c_ / len(c_))
        if np.sqrt(max(w[1], 0.0)) < sp.narrow_min_width_px * spacing:
            continue
        k = len(surfaces)
        surfaces.append(Surface(k, "plane", nrm, d, rms, int(inl.sum()), mean_rows(q[inl]), zc))
        lab.reshape(-1)[idx[inl]] = k
    return lab


def _merge_cylinders(p: FloatArray, labels: NDArray[np.int32], surfaces: list[Surface], normals: FloatArray,
                     sigma: FloatArray, noise: NoiseModel,
                     sp: SurfaceParams) -> tuple[NDArray[np.int32], list[Surface]]:  # fmt: skip
    """Neighbouring planes that are strips of one cylinder become that cylinder. A pipe of small radius seen
    from afar turns so fast that the fold test cuts it into strips a few pixels wide, each flat within the
    noise: neighbours whose normals differ by less than a fold and whose union one cylinder fits are one. A
    plane seen edge-on (its normal within :data:`EDGE_ON_RAD` of square to the camera's ray) is no strip: the
    camera cannot measure a surface along its rays, and such a plane is a veil of mixed pixels past an
    occluding edge (a flat wall and the veil behind its silhouette fit one wide cylinder)."""
    from perception.fine.adjacency import adjacent_pairs, plane_partners

    edge_on = {s.label for s in surfaces if s.kind == "plane" and _edge_on(s)}
    plane_ids = [s.label for s in surfaces if s.kind == "plane" and s.label not in edge_on]
    if len(plane_ids) < 2:
        return labels, surfaces
    z_typ = float(median([s.z_m for s in surfaces]))
    lo_cos, hi_cos = np.cos(np.radians(60.0)), np.cos(sp.merge_angle_rad)
    surf = SurfaceSet(labels, 1, tuple(surfaces))
    among = plane_partners(surf, min_cos=float(lo_cos), max_cos=float(hi_cos), exclude=edge_on)
    pairs = adjacent_pairs(surf, noise, reach_m=4.0 * float(noise.spacing_m(z_typ)), among=among)
    groups_of = Groups(plane_ids)
    find = groups_of.find

    for pr in pairs:
        A, B = surfaces[pr.a], surfaces[pr.b]
        if pr.a not in among or pr.b not in among or not lo_cos < float(A.normal @ B.normal) < hi_cos:
            continue
        # strips of one convex (or one concave) surface: each lies behind (or in front of) the other's plane
        sa, sb = float(A.residual(B.centroid[None])[0]), float(B.residual(A.centroid[None])[0])
        if sa * sb <= 0:
            continue
        groups_of.join(pr.a, pr.b)
    groups: dict[int, list[int]] = {}
    for k in plane_ids:
        groups.setdefault(find(k), []).append(k)
    flat = labels.reshape(-1)
    new_surfaces = list(surfaces)
    gone: set[int] = set()
    lab = labels.copy()
    for members in groups.values():
        if len(members) < 2:
            continue
        idx = np.flatnonzero(np.isin(flat, members))
        q = p.reshape(-1, 3)[idx]
        zc = float(median(q[:, 2]))
        tol = sp.inlier_sigma * sigma.reshape(-1)[idx]
        found = _try_cylinder(q, normals.reshape(-1, 3)[idx], tol, len(new_surfaces), zc,
                              float(noise.spacing_m(zc)), 0.85, sp.min_pixels, sp)  # fmt: skip
        if found is None:
            continue
        new_surfaces.append(found[0])
        lab.reshape(-1)[idx] = -1
        lab.reshape(-1)[idx[found[1]]] = found[0].label
        gone.update(members)
    _merge_coaxial(p, lab, new_surfaces, gone, normals, sigma, noise, sp)
    if not gone:
        return labels, surfaces
    keep = [s for s in new_surfaces if s.label not in gone]
    remap = np.full(len(new_surfaces) + 1, -1, np.int32)
    for k, s in enumerate(keep):
        remap[s.label] = k
    return remap[lab], [replace(s, label=k) for k, s in enumerate(keep)]


def _edge_on(s: Surface) -> bool:
    """Whether plane ``s``'s normal is within :data:`EDGE_ON_RAD` of square to the ray to its centroid."""
    return bool(abs(float(s.normal @ s.centroid)) < np.sin(EDGE_ON_RAD) * float(np.linalg.norm(s.centroid)))


def _merge_coaxial(p: FloatArray, lab: NDArray[np.int32], surfaces: list[Surface], gone: set[int],
                   normals: FloatArray, sigma: FloatArray, noise: NoiseModel, sp: SurfaceParams) -> None:  # fmt: skip
    """Cylinder pieces of one pipe (strips on either side of a highlight or a cap's rim) become one: the larger
    piece's cylinder runs through the smaller one within the noise. Appends to ``surfaces``, relabels ``lab``
    and adds the merged pieces to ``gone``, in place."""
    cyl_ids = [s.label for s in surfaces if s.kind == "cylinder" and s.label not in gone]
    for i, a in enumerate(cyl_ids):
        for b in cyl_ids[i + 1 :]:
            if a in gone or b in gone:
                continue
            A, B = surfaces[a], surfaces[b]
            if abs(float(A.axis @ B.axis)) < np.cos(np.radians(10.0)):
                continue
            big, small = (A, B) if A.n_points >= B.n_points else (B, A)
            q_small = p.reshape(-1, 3)[lab.reshape(-1) == small.label]
            if float(median(np.abs(big.residual(q_small)))) > max(
                3.0 * float(noise.sigma_m(small.z_m)), 3.0 * big.rms_m
            ):
                continue  # the larger piece's cylinder does not run through the smaller one
            idx = np.flatnonzero(np.isin(lab.reshape(-1), [a, b]))
            q = p.reshape(-1, 3)[idx]
            zc = float(median(q[:, 2]))
            tol = sp.inlier_sigma * sigma.reshape(-1)[idx]
            found = _try_cylinder(q, normals.reshape(-1, 3)[idx], tol, len(surfaces), zc,
                                  float(noise.spacing_m(zc)), 0.85, sp.min_pixels, sp)  # fmt: skip
            if found is None:
                continue
            surfaces.append(found[0])
            lab.reshape(-1)[idx] = -1
            lab.reshape(-1)[idx[found[1]]] = found[0].label
            gone.update((a, b))
            cyl_ids.append(found[0].label)


def _merge_coplanar(p: FloatArray, labels: NDArray[np.int32], surfaces: list[Surface], noise: NoiseModel,
                    sp: SurfaceParams, *, rounds: int = 4) -> tuple[NDArray[np.int32], list[Surface]]:  # fmt: skip
    """Planes whose pixels touch and that are one plane within the noise become one surface; again with the
    merged planes (a strip that touches only strips merged into a plate is then tested against the plate)
    until nothing more merges, at most ``rounds`` times."""
    for _ in range(rounds):
        n = len(surfaces)
        labels, surfaces = _merge_coplanar_once(p, labels, surfaces, noise, sp)
        if len(surfaces) == n:
            break
    return labels, surfaces


def _merge_coplanar_once(p: FloatArray, labels: NDArray[np.int32], surfaces: list[Surface], noise: NoiseModel,
                         sp: SurfaceParams) -> tuple[NDArray[np.int32], list[Surface]]:  # fmt: skip
    """One round of :func:`_merge_coplanar`."""
    if len(surfaces) < 2:
        return labels, surfaces
    sets = Groups(range(len(surfaces)))
    find = sets.find

    touching: set[tuple[int, int]] = set()
    n_lab = len(surfaces)
    for dy, dx in ((0, 1), (1, 0)):
        a = labels[: labels.shape[0] - dy, : labels.shape[1] - dx]
        b = labels[dy:, dx:]
        m = (a >= 0) & (b >= 0) & (a != b)
        lo, hi = np.minimum(a[m], b[m]).astype(np.int64), np.maximum(a[m], b[m]).astype(np.int64)
        for code in np.unique(lo * n_lab + hi).tolist():
            touching.add((code // n_lab, code % n_lab))
    cos_m = np.cos(sp.merge_angle_rad)
    flat = labels.reshape(-1)
    pts_flat = p.reshape(-1, 3)

    keys = np.where(flat >= 0, flat, n_lab)
    order = _stable_order(keys, n_lab + 1)  # each label's pixels, found once
    starts = np.searchsorted(keys[order], np.arange(n_lab + 1))

    def sample(lab: int) -> FloatArray:
        idx = order[starts[lab] : starts[lab + 1]]
        return np.nan_to_num(pts_flat[idx[:: max(1, len(idx) // 2000)]])

    on_plane_of: dict[int, list[int]] = {}
    for u, v in sorted(touching):
        su, sv = surfaces[u], surfaces[v]
        if su.kind != "plane" or sv.kind != "plane":
            continue
        sig = float(noise.sigma_m(max(su.z_m, sv.z_m)))
        # the larger piece's plane must hold the smaller's points: a narrow strip's own plane is tilted by
        # its noise and, carried over the larger piece, leaves it (a strip of a plate along an edge)
        big, small = (su, v) if su.n_points >= sv.n_points else (sv, u)
        res = np.abs(big.residual(sample(small)))
        if float(su.normal @ sv.normal) >= cos_m:
            if median(res) <= 3.0 * sig:
                sets.join(u, v)
            continue
        # a smaller piece whose points fit its own plane far better than the noise lets a surface fit (one
        # or two scan lines: a LiDAR's rows, each smooth, the noise being the rows' offsets) fits a plane at
        # any tilt about them; when its points lie on the larger's plane as closely as the larger's own do,
        # that is its plane
        spread = max(sig, big.rms_m)
        if surfaces[small].rms_m <= 0.5 * sig and median(res) <= spread and percentile(res, 90) <= 2.5 * spread:
            on_plane_of.setdefault(small, []).append(big.label)
    # ... absorbed into that plane only when it is the one plane it lies on, it is joined to nothing else
    # (a piece in a fold's band lies on both faces' planes, and must not join them), and that plane is not
    # being absorbed itself (its plane may be a strip's: the next round tests against the merged plane)
    group_size = Counter(find(i) for i in range(len(surfaces)))
    for small, bigs in on_plane_of.items():
        if len(bigs) == 1 and group_size[find(small)] == 1 and bigs[0] not in on_plane_of:
            sets.join(small, bigs[0])
    roots = sorted({find(i) for i in range(len(surfaces))})
    if len(roots) == len(surfaces):
        return labels, surfaces
    new_of = {r: k for k, r in enumerate(roots)}
    remap = np.array([new_of[find(i)] for i in range(len(surfaces))] + [-1], np.int32)
    new_labels = remap[labels]  # label -1 indexes the appended -1
    merged: list[Surface] = []
    for k, r in enumerate(roots):
        members = [i for i in range(len(surfaces)) if find(i) == r]
        if len(members) == 1:
            s = surfaces[r]
            merged.append(Surface(k, s.kind, s.normal, s.offset, s.rms_m, s.n_points, s.centroid, s.z_m, s.axis,
                                  s.centre, s.radius))  # fmt: skip
            continue
        q = np.nan_to_num(p[new_labels == k])
        nrm, d, rms = _fit_plane(q[:: max(1, len(q) // 20000)])
        merged.append(Surface(k, "plane", nrm, d, rms, len(q), mean_rows(q), float(median(q[:, 2]))))
    return new_labels, merged
