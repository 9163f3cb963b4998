"""A point cloud's picture with seams drawn on it: plan and side views along the cloud's principal axes, and
the cloud as the detector saw it (from its viewpoint, shaded as by a lamp there). ``weldcell bench real``
draws one per item, and ``weldcell detect CLOUD --overlay`` one per cloud, seams found or not."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

MAX_POINTS = 60_000  # drawn: a random sample of the cloud this large at most


def _from_viewpoint(points: np.ndarray, eye: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(N, 3) points seen by a pinhole at ``eye`` looking at ``centre`` (the detector's virtual camera,
    :func:`perception.cloud_view.view_axes`): image x, y (right, up) and range."""
    from perception.cloud_view import view_axes

    z = centre - eye
    q = (points - eye) @ view_axes(z / np.linalg.norm(z))
    depth = np.maximum(q[:, 2], 1e-9)
    return np.column_stack([q[:, 0] / depth, -q[:, 1] / depth, depth])


def _headlight(points: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """How squarely each of (N, 3) ``points`` faces ``eye`` (|cos| of its local plane's normal with the ray,
    the plane from its 12 nearest neighbours): a lamp at the viewpoint shows folds and faces apart."""
    from scipy.spatial import cKDTree

    _, idx = cKDTree(points).query(points, k=min(12, len(points)))
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)
    _, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    ray = points - eye
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    return np.asarray(np.abs(np.einsum("ni,ni->n", vec[:, :, 0], ray)))


def draw_cloud(cloud: Any, paths: Sequence[np.ndarray], joints: Sequence[str], path: str | Path, *, title: str,
               viewpoint: Sequence[float] | None = None, reference: dict[str, Any] | None = None) -> None:  # fmt: skip
    """Write to ``path`` (PNG) the views of ``cloud`` (a :class:`perception.capture.PointCloud`; its own colours
    in the third view when it has them) with the detected seams' ``paths`` (each (N, 3), in the cloud's frame)
    in red, labelled with their index and ``joints``, and the ``reference``'s seams (``{"seams": [{"points":
    ...}]}``) in green. The third view, from ``viewpoint``, only when it is given."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if cloud is None or len(cloud.points) == 0:
        return
    rng = np.random.default_rng(0)
    pick = rng.choice(len(cloud.points), min(len(cloud.points), MAX_POINTS), replace=False)
    pts = cloud.points[pick]
    rgb = None if cloud.colors is None else np.clip(np.asarray(cloud.colors)[pick], 0.0, 1.0)
    c = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
    views = [("plan (principal axes 1-2)", lambda q: ((q - c) @ vt.T)[:, [0, 1]] * 1000),
             ("side (axes 1-3)", lambda q: ((q - c) @ vt.T)[:, [0, 2]] * 1000)]  # fmt: skip
    if viewpoint is not None:
        eye, centre = np.asarray(viewpoint, dtype=np.float64), np.median(pts, axis=0)
        views.append(("from the detector's viewpoint", lambda q: _from_viewpoint(q, eye, centre)[:, :2]))
    fig, axes = plt.subplots(1, len(views), figsize=(7 * len(views), 6))
    for k_ax, (ax, (view_title, project)) in enumerate(zip(axes, views, strict=True)):
        if k_ax == 2:  # far points first, so that the near ones are drawn over them
            seen = _from_viewpoint(pts, eye, centre)
            q, order = seen[:, :2], np.argsort(-seen[:, 2])
            lit = _headlight(pts, eye)
            if rgb is None:
                ax.scatter(q[order, 0], q[order, 1], s=0.5, c=lit[order], cmap="gray", vmin=0, vmax=1)
            else:  # the points' own colours, darker where a face turns from the viewpoint
                ax.scatter(q[order, 0], q[order, 1], s=0.5, c=(rgb * (0.4 + 0.6 * lit)[:, None])[order])
            ax.set_xticks([])
            ax.set_yticks([])
        else:
            q = project(pts)
            ax.scatter(q[:, 0], q[:, 1], s=0.3, c="0.6")
            ax.set_xlabel("mm")
        for s in (reference or {}).get("seams", []):
            r = project(np.asarray(s["points"], dtype=np.float64))
            ax.plot(r[:, 0], r[:, 1], "-", color="limegreen", lw=5, alpha=0.6)
        for k, p in enumerate(paths):
            r = project(np.asarray(p, dtype=np.float64))
            ax.plot(r[:, 0], r[:, 1], "-", color="red", lw=1.5)
            # the joint named too: a "v_groove" on a flat table is plainly false to anyone who looks
            joint = joints[k] if k < len(joints) else ""
            ax.text(r[len(r) // 2, 0], r[len(r) // 2, 1], f"{k} {joint}".strip(), color="red")
        ax.set_aspect("equal")
        ax.set_title(view_title)
    fig.suptitle(title, wrap=True)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
