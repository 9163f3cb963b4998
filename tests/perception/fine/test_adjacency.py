"""Adjacency: surfaces that meet across a fold are neighbours; surfaces far apart in space are not."""

from __future__ import annotations

import numpy as np

from perception.fine.adjacency import adjacent_pairs, dilate_disc, plane_partners

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


def test_dilate_disc_is_opencvs_dilation_by_its_ellipse_pixel_for_pixel() -> None:
    """Every reach from 1 to 30 pixels (OpenCV's own below OPENCV_MAX_R, the compiled one above), on random
    masks from a few scattered pixels to a third set, windows 1 to 150 pixels a side (the image's border
    counts as unset): the very pixels of ``cv2.dilate`` with the (2r + 1)-pixel ellipse."""
    import cv2

    rng = np.random.default_rng(0)
    for r in range(1, 31):
        ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        for _ in range(6):
            h, w = rng.integers(1, 150, 2)
            m = rng.uniform(size=(h, w)) < rng.uniform(0.0005, 0.3)
            assert np.array_equal(dilate_disc(m, r), cv2.dilate(m.astype(np.uint8), ker).astype(bool)), r


def test_dilate_disc_reaches_the_ellipses_half_width_at_each_row() -> None:
    # one pixel dilated by 12: the ellipse kernel itself, 12 pixels either side on its centre row, the pixel
    # alone on its top and bottom rows (12 above and below), nothing beyond; symmetric both ways
    m = np.zeros((41, 41), bool)
    m[20, 20] = True
    out = dilate_disc(m, 12)
    assert out[20].sum() == 25 and out[20, 8] and not out[20, 7]
    assert out[8].sum() == 1 and out[8, 20] and not out[7].any() and not out[33].any()
    assert np.array_equal(out, out[::-1]) and np.array_equal(out, out[:, ::-1])
