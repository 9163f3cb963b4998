"""Adjacency: surfaces that meet across a fold are neighbours; surfaces far apart in space are not."""

from __future__ import annotations

import numpy as np

from perception.fine.adjacency import adjacent_pairs, plane_partners

from .scenes import rendered, work


def label_of(res, surf, part: int) -> int:
    f = np.bincount(res.face_index[res.part_index == part]).argmax()
    m = (res.part_index == part) & (res.face_index == f) & (surf.labels >= 0)
    return int(np.bincount(surf.labels[m]).argmax())


def test_the_web_and_the_base_meet_and_their_contact_lies_along_the_fold() -> None:
    res = rendered("tee")
    p, _, nm, surf = work("tee")
    web, base = label_of(res, surf, 2), label_of(res, surf, 1)
    pairs = {(q.a, q.b): q for q in adjacent_pairs(surf, nm)}
    key = (min(web, base), max(web, base))
    assert key in pairs
    # the contact pixels lie within the reach (6 mm) of the true fold line, at the pixels' range
    seam = res.ground_truth[0].points_camera
    u = (seam[1] - seam[0]) / np.linalg.norm(seam[1] - seam[0])
    ys, xs = pairs[key].contact_px[:, 0], pairs[key].contact_px[:, 1]
    mine = np.isin(surf.labels[ys, xs], [web, base])
    q = p[ys[mine], xs[mine]]
    d = q - seam[0]
    dist = np.linalg.norm(d - np.outer(d @ u, u), axis=1)
    # most of the two surfaces' contact is at the fold; the rest is where the web's top edge is seen against
    # the base behind it (neighbours in the image, far apart in space: the folds step measures that)
    close = dist < 0.010
    assert close.mean() > 0.5
    # and the close contact runs along the whole fold (2 mm bins)
    length = float(np.linalg.norm(seam[1] - seam[0]))
    t = d[close] @ u
    hit = np.bincount(np.clip((t / 0.002).astype(int), 0, int(length / 0.002)), minlength=int(length / 0.002) + 1)
    assert np.mean(hit[: int(length / 0.002)] > 0) > 0.9


def test_no_pair_without_contact() -> None:
    _, _, nm, surf = work("tee")
    labels = {s.label for s in surf.surfaces}
    for q in adjacent_pairs(surf, nm):
        assert q.a < q.b and {q.a, q.b} <= labels and len(q.contact_px) >= 6


def test_pairs_among_some_surfaces_are_exactly_those_of_all_pairs() -> None:
    _, _, nm, surf = work("tee")
    every = adjacent_pairs(surf, nm)
    among = {every[0].a, every[0].b}
    some = adjacent_pairs(surf, nm, among=among)
    expected = [q for q in every if {q.a, q.b} <= among]
    assert [(q.a, q.b) for q in some] == [(q.a, q.b) for q in expected]
    assert all(np.array_equal(q.contact_px, e.contact_px) for q, e in zip(some, expected, strict=True))


def test_plane_partners_are_the_planes_with_a_plane_at_the_cosine_asked_for() -> None:
    _, _, _, surf = work("tee")
    planes = [s for s in surf.surfaces if s.kind == "plane"]
    cos = {(s.label, t.label): float(s.normal @ t.normal) for s in planes for t in planes if s.label != t.label}
    for lo, hi in ((0.99, 1.0), (np.cos(np.radians(60.0)), np.cos(np.radians(3.0))), (-1.0, 1.0)):
        expected = {a for (a, _), c in cos.items() if lo <= c <= hi}
        assert plane_partners(surf, min_cos=lo, max_cos=hi) == expected
    assert plane_partners(surf, min_cos=-1.0, exclude={planes[0].label}) <= {s.label for s in planes[1:]}
