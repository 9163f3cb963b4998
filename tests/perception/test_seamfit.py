"""Seam refinement on synthetic point sets with exact geometry."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from perception.seamfit import FullRes, SeamParams, refine_linear


def _fillet_points(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A base plate (z = 0) with two upright faces in line along x: x 0..40 mm at y = 0 and x 100..140 mm at
    y = 5 mm, both facing -y. Points every 0.5 mm, 0.05 mm noise. Returns points, normals, mask labels (the
    segmenter gave both faces one label, as it can for two parts of one colour)."""
    step = 0.0005
    gx, gy = np.meshgrid(np.arange(-0.02, 0.16, step), np.arange(-0.03, 0.005, step))
    face_y = np.where(gx < 0.07, 0.0, 0.005)
    keep = gy < face_y
    base = np.column_stack([gx[keep], gy[keep], np.zeros(keep.sum())])
    faces = []
    for x0, y in ((0.0, 0.0), (0.10, 0.005)):
        fx, fz = np.meshgrid(np.arange(x0, x0 + 0.04, step), np.arange(step, 0.03, step))
        faces.append(np.column_stack([fx.ravel(), np.full(fx.size, y), fz.ravel()]))
    face = np.vstack(faces)
    pts = np.vstack([base, face]) + rng.normal(0.0, 5e-5, (len(base) + len(face), 3))
    normals = np.vstack([np.tile([0.0, 0.0, 1.0], (len(base), 1)), np.tile([0.0, -1.0, 0.0], (len(face), 1))])
    labels = np.concatenate([np.zeros(len(base), np.int32), np.ones(len(face), np.int32)])
    return pts, normals, labels


def test_pieces_of_a_split_seam_are_each_fitted_on_their_own_faces() -> None:
    pts, normals, labels = _fillet_points(np.random.default_rng(7))
    full = FullRes(pts, np.full(len(pts), -1, np.int32), cKDTree(pts), np.zeros((0, 3)), normals, labels)
    # the coarse line (from the two masks' common border) spans both pieces
    line = np.array([[0.005, 0.0, 0.0], [0.135, 0.005, 0.0]])
    out = refine_linear(
        full, (), (), line, np.array([0.0, 0.0, 1.0]), np.array([0.0, -1.0, 0.0]), SeamParams(),
        np.array([0.06, -0.3, 0.3]), seed_labels=(0, 1),
    )  # fmt: skip
    assert out is not None and len(out) == 2
    pieces = sorted(out, key=lambda piece: piece[0][:, 0].min())
    for (ends, n_base, n_face, _rms), (x0, y) in zip(pieces, ((0.0, 0.0), (0.10, 0.005)), strict=True):
        # each piece lies on its own true line (y, z = 0) and spans its face less the end trim
        assert np.abs(ends[:, 1] - y).max() < 5e-5, ends
        assert np.abs(ends[:, 2]).max() < 5e-5, ends
        assert abs(ends[:, 0].min() - x0) < 0.003 and abs(ends[:, 0].max() - (x0 + 0.04)) < 0.003, ends
        assert n_base @ [0, 0, 1] > np.cos(np.radians(0.2)) and n_face @ [0, -1, 0] > np.cos(np.radians(0.2))
