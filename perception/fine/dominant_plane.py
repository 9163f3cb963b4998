"""A face's plane taken from the plane most of its points lie on, when a robust fit through all of them is
pulled off it by another surface close beside it.

The refinement refits each face on the points near the seam within a few sigma of the face's current plane
(:mod:`perception.fine.refine`). Where the segmentation joined a narrow face with another one close to it (a
gusset's side with its edge face, seen a few pixels wide at a grazing angle), that plane is tilted between
the two, its gate keeps both, and Tukey's biweight, whose scale is the residuals' own spread, settles between
them too (dev gusset 46: the side's plane 11 degrees off, its seam 2.6 mm off at the ends; the least-squares
plane of the side's own points is 0.1 degrees off).

What tells the two apart is the noise across a face. A depth sensor's noise moves a point along its ray, so
across a face it is the depth noise times the cosine of the ray's incidence: a face seen at 70 degrees
scatters about its plane by a third of the depth noise, and a surface a few millimetres off it is many of
those away. When fewer than :data:`MIN_SHARE` of the points lie within :data:`INLIER_SIGMAS` of that noise
of the fitted plane, a RANSAC search (a fixed seed: the same points give the same plane) finds the plane
the most of them lie on. The caller refits the face on that plane's points, and keeps the fit when it holds
more of them and the points it leaves out lie on one side of it (:func:`one_sided`): another surface stands
on one side of a face, while the noise scatters to both (a sensor whose noise on a face is larger than its
noise model says leaves points out on both sides, and its face is left to the robust fit).
"""

from __future__ import annotations

import numpy as np

from perception.fine.types import FloatArray, NoiseModel

INLIER_SIGMAS = 2.5
MIN_SHARE = 0.8  # of a face's points within INLIER_SIGMAS of its plane: 98.8% for Gaussian noise
COS_FLOOR = 0.25  # a face seen past 75 degrees (the visibility limit) is taken as seen at 75
HYPOTHESES = 200
SCORE_POINTS = 4000  # the hypotheses are scored on at most this many of the points (every k-th)
ONE_SIDED_SHARE = 0.8  # of the points off a plane: this many on one side of it is another surface there


def normal_sigma(points: FloatArray, normal: FloatArray, noise: NoiseModel) -> FloatArray:
    """Per point of (N, 3) camera-frame ``points`` (the camera at the origin): the noise across a plane of unit
    ``normal``, the depth noise at its range (with the structured error the noise model measured) times the
    cosine of its ray's incidence on the plane (at least :data:`COS_FLOOR`)."""
    z = points[:, 2]
    depth = np.hypot(noise.sigma_m(z), noise.structure_1m_m * z * z)
    ray = points / np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-12)
    return np.asarray(depth * np.maximum(np.abs(ray @ normal), COS_FLOOR))


def within_noise(points: FloatArray, normal: FloatArray, offset: float, noise: NoiseModel) -> np.ndarray:
    """Per point: whether it lies within :data:`INLIER_SIGMAS` of the noise across the plane (``normal``,
    ``offset``: n . x + offset = 0) of that plane."""
    return np.asarray(np.abs(points @ normal + offset) <= INLIER_SIGMAS * normal_sigma(points, normal, noise))


def dominant_plane(points: FloatArray, normal: FloatArray, offset: float,
                   noise: NoiseModel) -> tuple[FloatArray, float] | None:  # fmt: skip
    """When the fitted plane (``normal``, ``offset``) holds fewer than :data:`MIN_SHARE` of ``points`` within
    the noise across it: the plane (unit normal, offset) through three of them that the most of them lie on, a
    start for a fit on those (which the caller keeps if it holds more than the fitted plane); else None."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) < 10:
        return None
    if within_noise(p, normal, offset, noise).sum() >= MIN_SHARE * len(p):
        return None
    q = p[:: max(1, -(-len(p) // SCORE_POINTS))]
    tol = INLIER_SIGMAS * normal_sigma(q, normal, noise)  # the noise across faces near this one's tilt
    rng = np.random.default_rng(0)
    tri = q[rng.integers(0, len(q), (HYPOTHESES, 3))]  # (H, 3, 3); a repeated point's triangle has no normal
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-12
    if not ok.any():
        return None
    n, a = n[ok] / norm[ok, None], tri[ok, 0]
    counts = (np.abs(q @ n.T - np.einsum("hk,hk->h", n, a)) <= tol[:, None]).sum(axis=0)
    best = int(np.argmax(counts))
    nb = n[best] if float(n[best] @ normal) >= 0 else -n[best]
    return nb, -float(nb @ a[best])


def one_sided(points: FloatArray, normal: FloatArray, offset: float, noise: NoiseModel) -> bool:
    """Whether at least :data:`ONE_SIDED_SHARE` of the ``points`` outside the noise across the plane (``normal``,
    ``offset``) lie on one side of it (and ten or more lie outside)."""
    r = points @ normal + offset
    off = ~within_noise(points, normal, offset, noise)
    if off.sum() < 10:
        return False
    front = int((r[off] > 0).sum())
    return max(front, int(off.sum()) - front) >= ONE_SIDED_SHARE * off.sum()
