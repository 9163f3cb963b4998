"""The fine stage's compiled kernels (:mod:`numba`; each module says what it compiles and why) run once on a
few points, so that a detection timed afterwards does not pay for their compilation (about 8 s the first time
on a machine, then loaded from numba's cache in about a second). Each kernel is called with one type of
argument only (contiguous float64 arrays), the type compiled here: tests/perception/fine/test_compiled.py."""

from __future__ import annotations

import numpy as np


def warm_up(*, coarse: bool = True) -> None:
    """Compile (or load from the cache) the compiled kernels of the fine stage: those a helper process's jobs
    use (the refinement's biweight, the inner-gap search's outline pixels, the line count), and with ``coarse``
    the others (the local planes', the disc dilation's, the cylinder fit's, the smooth pieces', the growth's)."""
    from perception.fine.adjacency import dilate_disc
    from perception.fine.biweight import biweight_plane
    from perception.fine.components import smooth_components
    from perception.fine.cylinder import fit_cylinder
    from perception.fine.gaps import outline_pixels
    from perception.fine.grow import grow
    from perception.fine.lines import best_line
    from perception.fine.noise import LocalPlanes, local_planes
    from perception.fine.types import NoiseModel, Surface

    p = np.zeros((4, 4, 3))
    p[..., 2] = 0.5
    floor = Surface(0, "plane", np.array([0.0, 0.0, -1.0]), 0.5, 0.0, 4, np.array([0.0, 0.0, 0.5]), 0.5)
    inside = np.ones((2, 2), bool)
    outline_pixels(p.astype(np.float32), 1, 1, inside, inside, floor.normal, floor.offset, 0.5, (1e-3, 5e-5), 0.0)
    biweight_plane(p.reshape(-1, 3), np.ones(16))
    best_line(np.eye(3), np.zeros(3), np.ascontiguousarray(p.reshape(-1, 3).T), 1e-3)
    if not coarse:
        return
    local_planes(p, window_px=3)
    dilate_disc(inside, 20)
    ang = np.linspace(0.0, np.pi, 40)
    around = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(40)])
    fit_cylinder(around * 0.02 + [0.0, 0.0, 0.5] + np.outer(np.arange(40) % 4, [0.0, 0.0, 0.01]), around)
    normal = np.zeros((4, 4, 3))
    normal[..., 2] = -1.0
    planes = LocalPlanes(np.full((4, 4), 9.0), normal, np.zeros((4, 4)), np.zeros((4, 4)), 3)
    noise = NoiseModel(sigma_1m_m=1e-3, floor_m=5e-5, pixel_angle_rad=1e-3)
    smooth_components(p, planes, noise, normal_turn_rad=0.7, jump_sigma=6.0)
    labels = np.full((4, 4), -1, np.int32)
    labels[:, 0] = 0
    grow(p, labels, [floor], np.full((4, 4), 1e-3), within_sigma=3.0, rings=2)
