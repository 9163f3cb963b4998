"""Seams found from the geometry of touching solids, for procedurally built weldments.

A fillet-type seam is where a face of one part meets a face of another part in a concave fold: an edge of
face a lies in the plane of face b, face a rises from face b towards the side face b's normal points to, and
face b continues under face a's outward side. That one rule gives T-joint and rib fillets (also the ribs'
end fillets), inside and outside fillets of a box, the vertical inside corners between walls, gussets and
lap edges. Each candidate edge is sampled every 0.5 mm and kept only where face b really is there beside it
and where the air wedge of the fold is not inside another solid (a rib running into another rib, a gusset
standing in a wall's fillet). A cylinder standing on a face gives its (curved) ring the same way.

Butt gaps and groove roots are not folds between two faces of touching solids; the families that build
them state those seams themselves.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from perception.transforms import invert_X, transform_points
from sim_fakes.hull import HullFace
from sim_fakes.scenes import CYL_SIDE, Part, SeamDef

FloatArray = NDArray[np.float64]

STEP_M = 0.0005
PLANE_TOL_M = 1e-7
PROBE_M = 0.0005  # how far beside the seam face b and the air wedge are tested

JointRule = Callable[[int, int, FloatArray, FloatArray], str]


def inside_solid(part: Part, p_world: FloatArray, *, margin_m: float = 1e-7) -> NDArray[np.bool_]:
    """(N,) whether world points are strictly inside ``part``."""
    p = np.asarray(p_world, dtype=np.float64).reshape(-1, 3)
    if part.hull_world is not None:
        return part.hull_world.contains(p, margin_m=margin_m)
    q = transform_points(invert_X(part.X_world_part), p)
    if part.shape == "cylinder":
        r, _, h = part.size
        return (np.hypot(q[:, 0], q[:, 1]) < r - margin_m) & (q[:, 2] > margin_m) & (q[:, 2] < h - margin_m)
    half = np.asarray(part.size) / 2 - margin_m
    return np.all(np.abs(q) < half, axis=1)


def planar_faces(part: Part) -> list[tuple[int, HullFace | None, FloatArray, float]]:
    """(face id, hull face or None for a cylinder cap, outward normal, offset) of each planar face."""
    if part.hull_world is not None:
        return [(k, f, f.normal, f.offset) for k, f in enumerate(part.hull_world.faces)]
    if part.shape == "cylinder":
        axis = part.X_world_part[:3, 2]
        o = part.X_world_part[:3, 3]
        top = o + axis * part.size[2]
        return [(1, None, -axis, float(axis @ o)), (2, None, axis, -float(axis @ top))]
    return []


def _in_face(part: Part, face: HullFace | None, face_id: int, p: FloatArray) -> NDArray[np.bool_]:
    if face is not None:
        return face.contains(p)
    # a cylinder cap: inside the disk
    q = transform_points(invert_X(part.X_world_part), p)
    return np.hypot(q[:, 0], q[:, 1]) <= part.size[0] + 1e-9


def _runs(ok: NDArray[np.bool_], *, closed: bool = False) -> list[NDArray[np.intp]]:
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > 1)
    runs = np.split(idx, breaks + 1)
    if closed and len(runs) > 1 and runs[0][0] == 0 and runs[-1][-1] == len(ok) - 1:
        runs = [np.concatenate([runs[-1], runs[0]]), *runs[1:-1]]
    return [r for r in runs if len(r) >= 2]


def _free(parts: Sequence[Part], p: FloatArray) -> NDArray[np.bool_]:
    free = np.ones(len(p), bool)
    for part in parts:
        free &= ~inside_solid(part, p)
    return free


def fold_seams(parts: Sequence[Part], *, joint_rule: JointRule | None = None) -> list[SeamDef]:
    """Every concave fold between faces of two different workpiece parts (world frame).

    ``joint_rule(part_a, part_b, into_a, into_b)`` names the joint (default: fillet).
    """
    rule = joint_rule or (lambda _a, _b, _da, _db: "fillet")
    out: list[SeamDef] = []
    work = [i for i, p in enumerate(parts) if p.workpiece]
    for ia in work:
        A = parts[ia]
        if A.hull_world is None:
            if A.shape == "cylinder":
                out += _cylinder_rings(parts, ia, work, rule)
            continue
        for fa_id, fa in enumerate(A.hull_world.faces):
            poly = fa.polygon
            c_a = fa.centroid()
            for k in range(len(poly)):
                p0, p1 = poly[k], poly[(k + 1) % len(poly)]
                length = float(np.linalg.norm(p1 - p0))
                e = (p1 - p0) / length
                into_a = np.cross(fa.normal, e)
                if np.dot(into_a, c_a - p0) < 0:
                    into_a = -into_a
                reach_a = float(np.max((poly - p0) @ into_a))
                for ib in work:
                    if ib == ia:
                        continue
                    B = parts[ib]
                    for fb_id, fb, n_b, d_b in planar_faces(B):
                        if abs(n_b @ p0 + d_b) > PLANE_TOL_M or abs(n_b @ p1 + d_b) > PLANE_TOL_M:
                            continue
                        if abs(float(fa.normal @ n_b)) > 1 - 1e-9 or float(into_a @ n_b) < 1e-6:
                            continue
                        into_b = fa.normal - (fa.normal @ n_b) * n_b
                        into_b /= np.linalg.norm(into_b)
                        n = max(2, int(np.ceil(length / STEP_M)) + 1)
                        s = p0 + np.linspace(0.0, length, n)[:, None] * e
                        ok = _in_face(B, fb, fb_id, s) & _in_face(B, fb, fb_id, s + PROBE_M * into_b)
                        wedge = s + PROBE_M * (into_a + into_b)
                        ok &= _free(parts, wedge)
                        for r in _runs(ok):
                            pts = s[[r[0], r[-1]]]
                            reach_b = float(np.max((fb.polygon - pts[0]) @ into_b)) if fb is not None else np.inf
                            joint = rule(ia, ib, into_a, into_b)
                            out.append(
                                SeamDef(
                                    f"{B.name}/{A.name}@{fa_id}.{k}",
                                    "linear",
                                    pts,
                                    ((ib, fb_id), (ia, fa_id)),
                                    np.tile(into_b, (2, 1)),
                                    np.tile(into_a, (2, 1)),
                                    joint=joint,
                                    reach_a_m=reach_b,
                                    reach_b_m=reach_a,
                                )
                            )
    return join_flush_seams(parts, dedupe_seams(out))


def join_flush_seams(parts: Sequence[Part], seams: list[SeamDef]) -> list[SeamDef]:
    """Linear folds along one face a that continue each other, onto faces b that are one plane (a wall's outer
    face flush with the end faces of the walls it stands between), are one seam: a welder runs it through."""
    def plane_of(face: tuple[int, int]) -> tuple[FloatArray, float] | None:
        part = parts[face[0]]
        for fid, _f, n, d in planar_faces(part):
            if fid == face[1]:
                return n, d
        return None

    out = list(seams)
    changed = True
    while changed:
        changed = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                s, t = out[i], out[j]
                if s.kind != "linear" or t.kind != "linear" or s.faces[0] != t.faces[0] or s.joint != t.joint:
                    continue
                ps, pt = plane_of(s.faces[1]), plane_of(t.faces[1])
                if ps is None or pt is None or float(ps[0] @ pt[0]) < 1 - 1e-9 or abs(ps[1] - pt[1]) > 1e-9:
                    continue
                ends = [(a, b) for a in (0, 1) for b in (0, 1) if np.linalg.norm(s.points[a] - t.points[b]) < 1e-7]
                if not ends:
                    continue
                a, b = ends[0]
                d = s.points[1 - a] - s.points[a]
                e = t.points[1 - b] - t.points[b]
                if np.linalg.norm(np.cross(d, e)) > 1e-9 * np.linalg.norm(d) * np.linalg.norm(e) or d @ e > 0:
                    continue
                longer = s if np.linalg.norm(d) >= np.linalg.norm(e) else t
                pts = np.array([s.points[1 - a], t.points[1 - b]])
                out[i] = replace(longer, points=pts, into_a=longer.into_a[:1].repeat(2, axis=0),
                                 into_b=longer.into_b[:1].repeat(2, axis=0))  # fmt: skip
                del out[j]
                changed = True
                break
            if changed:
                break
    return out


def _cylinder_rings(parts: Sequence[Part], ic: int, work: list[int], rule: JointRule) -> list[SeamDef]:
    """The ring where a cylinder's side meets a planar face its bottom (or top) cap lies on."""
    C = parts[ic]
    r, _, h = C.size
    axis = C.X_world_part[:3, 2]
    o = C.X_world_part[:3, 3]
    ex = C.X_world_part[:3, 0]
    ey = C.X_world_part[:3, 1]
    n = max(64, int(np.ceil(2 * np.pi * r / STEP_M)))
    ang = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    radial = np.cos(ang)[:, None] * ex + np.sin(ang)[:, None] * ey
    out: list[SeamDef] = []
    for centre, up in ((o, axis), (o + h * axis, -axis)):
        ring = centre + r * radial
        for ib in work:
            if ib == ic:
                continue
            B = parts[ib]
            for fb_id, fb, n_b, d_b in planar_faces(B):
                if float(n_b @ up) < 1 - 1e-9 or abs(n_b @ centre + d_b) > PLANE_TOL_M:
                    continue
                ok = _in_face(B, fb, fb_id, ring) & _in_face(B, fb, fb_id, ring + PROBE_M * radial)
                ok &= _free(parts, ring + PROBE_M * (radial + up))
                for run in _runs(ok, closed=True):
                    closed = len(run) == n
                    idx = np.append(run, run[0]) if closed else run
                    into_b = np.tile(up, (len(idx), 1))
                    out.append(
                        SeamDef(
                            f"{B.name}/{C.name}",
                            "curved",
                            ring[idx],
                            ((ib, fb_id), (ic, CYL_SIDE)),
                            radial[idx],
                            into_b,
                            joint=rule(ic, ib, up, radial[0]),
                            reach_b_m=h,
                        )
                    )
    return out


def dedupe_seams(seams: list[SeamDef]) -> list[SeamDef]:
    """A fold can be found from both of its faces' edges; keep the first per face pair and line."""
    kept: list[SeamDef] = []
    for s in seams:
        dup = False
        for k in kept:
            if {s.faces[0], s.faces[1]} != {k.faces[0], k.faces[1]}:
                continue
            if np.allclose(np.sort(s.points, axis=0), np.sort(k.points, axis=0), atol=1e-7):
                dup = True
                break
        if not dup:
            kept.append(s)
    return kept
