"""The workpiece: the prompted surfaces and what touches them in space, never through the support; clutter's
folds are not seams."""

from __future__ import annotations

from functools import cache

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.spatial.transform import Rotation

from perception.fine.adjacency import adjacent_pairs
from perception.fine.folds import fold_seams
from perception.fine.noise import estimate_noise, local_planes
from perception.fine.support import find_support
from perception.fine.surfaces import segment_surfaces
from perception.fine.types import SurfaceSet
from perception.fine.workpiece import prompted_labels, workpiece_labels
from perception.transforms import make_X
from sim_fakes.hull import box_corners
from sim_fakes.render import RenderResult, render
from sim_fakes.scenes import Part

from .scenes import hull, scene_of

BASE, WEB, BOX1, BOX2 = 1, 2, 3, 4  # part indices (0 is the table)


@cache
def tee_and_clutter() -> tuple[RenderResult, np.ndarray, SurfaceSet, tuple, frozenset[int], object]:
    """The tee of the fine-stage tests and, 70 mm beside its base plate on the table, a tall box pushed through a
    flat one (real concave folds between them, and no weld)."""
    base = hull("base", box_corners(0.30, 0.24, 0.012))
    web = hull("web", box_corners(0.010, 0.16, 0.08), z=0.012)
    box1 = Part("box1", "hull", (0, 0, 0), make_X(np.eye(3), [0.02, -0.23, 0.0]), (0.5, 0.5, 0.5), workpiece=False,
                corners_part=box_corners(0.08, 0.08, 0.04))  # fmt: skip
    turned = make_X(Rotation.from_euler("z", 35, degrees=True).as_matrix(), [0.03, -0.22, 0.0])
    box2 = Part("box2", "hull", (0, 0, 0), turned, (0.5, 0.5, 0.5), workpiece=False,
                corners_part=box_corners(0.04, 0.04, 0.07))  # fmt: skip
    res = render(scene_of((base, web, box1, box2), eye=(-0.32, -0.30, 0.34), target=(0.0, -0.08, 0.02)), noise="none")
    p = res.capture.points_camera().astype(np.float64)
    lp = local_planes(p, window_px=7)
    nm = estimate_noise(p, lp)
    surf = segment_surfaces(p, lp, nm, factor=1)
    support = find_support(p, surf, nm)
    return res, p, surf, adjacent_pairs(surf, nm), support, nm


def click(res: RenderResult, part: int) -> list[float]:
    """The pixel (u, v) deepest inside the largest face of ``part`` seen: where an operator would click."""
    faces = res.face_index[res.part_index == part]
    face = int(np.bincount(faces[faces >= 0]).argmax())
    inside = distance_transform_edt((res.part_index == part) & (res.face_index == face))
    v, u = np.unravel_index(int(np.argmax(inside)), inside.shape)
    return [float(u), float(v)]


def part_of(res: RenderResult, surf: SurfaceSet, label: int) -> int:
    return int(np.bincount(res.part_index[surf.labels == label] + 1).argmax()) - 1


def test_a_prompt_names_the_surface_under_it_and_an_unlabelled_pixel_takes_its_neighbours() -> None:
    res, _, surf, _, _, _ = tee_and_clutter()
    u, v = click(res, WEB)
    web = int(surf.labels[int(v), int(u)])
    assert web >= 0 and part_of(res, surf, web) == WEB
    assert prompted_labels(np.array([[u, v]]), surf) == {web}
    holed = surf.labels.copy()
    holed[int(v), int(u)] = -1
    assert prompted_labels(np.array([[u, v]]), SurfaceSet(holed, 1, surf.surfaces)) == {web}
    assert prompted_labels(None, surf) == frozenset()
    assert prompted_labels(np.array([[1e5, 3.0]]), surf) == frozenset()  # off the image: nothing


def test_the_workpiece_is_the_prompted_faces_and_what_touches_them_never_the_clutter() -> None:
    res, p, surf, pairs, support, nm = tee_and_clutter()
    # only the base plate is clicked: the web joins it through their fold; the boxes touch only the table
    prompted = prompted_labels(np.array([click(res, BASE)]), surf)
    wp = workpiece_labels(p, surf, pairs, nm, prompted=prompted, support=support)
    assert wp is not None and not wp & support
    parts = {lab: part_of(res, surf, lab) for lab in range(len(surf.surfaces))}
    big = {lab for lab in parts if surf.surfaces[lab].n_points >= 200}
    assert {parts[lab] for lab in wp} <= {BASE, WEB}
    assert {lab for lab in big if parts[lab] in (BASE, WEB)} <= wp  # every sizeable face of the tee
    # the boxes make a concave fold of their own, a seam by geometry alone, which the workpiece rules out
    folds = fold_seams(p, surf, pairs, nm, support=support)
    box_folds = [f for f in folds if {parts[lab] for lab in f.surfaces} == {BOX1, BOX2}]
    tee_folds = [f for f in folds if {parts[lab] for lab in f.surfaces} == {BASE, WEB}]
    assert box_folds and tee_folds
    assert all(not set(f.surfaces) <= wp for f in box_folds)
    assert all(set(f.surfaces) <= wp for f in tee_folds)


def test_without_prompts_the_part_the_camera_is_aimed_at_is_the_workpiece() -> None:
    """The camera looks at the tee's base plate (the image centre); the boxes 70 mm beside it on the table,
    with their own concave folds, are not the workpiece. Not aimed (a cloud's virtual view): every surface."""
    res, p, surf, pairs, support, nm = tee_and_clutter()
    wp = workpiece_labels(p, surf, pairs, nm, prompted=frozenset(), support=support)
    parts = {lab: part_of(res, surf, lab) for lab in range(len(surf.surfaces))}
    big = {lab for lab in parts if surf.surfaces[lab].n_points >= 200}
    assert wp is not None and {parts[lab] for lab in wp} <= {BASE, WEB}
    assert {lab for lab in big if parts[lab] in (BASE, WEB)} <= wp
    assert {lab for lab in big if parts[lab] in (BOX1, BOX2)}  # the boxes are seen, and left out
    assert workpiece_labels(p, surf, pairs, nm, prompted=frozenset(), support=support, aim=False) is None
    # a prompt on the table alone names no workpiece: the support is never one
    assert workpiece_labels(p, surf, pairs, nm, prompted=support, support=support) is None


def test_what_stands_over_the_part_joins_it_without_touching_and_what_stands_beside_it_does_not() -> None:
    """With no pair touching (as when a part's walls are not seen, only its top), the web still joins the base
    plate the camera is aimed at, because it stands over the plate's footprint on the table; the boxes beside
    the plate do not."""
    res, p, surf, _, support, nm = tee_and_clutter()
    wp = workpiece_labels(p, surf, (), nm, prompted=frozenset(), support=support)
    parts = {lab: part_of(res, surf, lab) for lab in range(len(surf.surfaces))}
    big = {lab for lab in parts if surf.surfaces[lab].n_points >= 200}
    assert wp is not None
    assert {lab for lab in big if parts[lab] == WEB} and {lab for lab in big if parts[lab] == WEB} <= wp
    assert not {lab for lab in wp if parts[lab] in (BOX1, BOX2)}


def _work_of(parts: tuple[Part, ...], eye: tuple[float, float, float], target: tuple[float, float, float]):
    res = render(scene_of(parts, eye=eye, target=target), noise="none")
    p = res.capture.points_camera().astype(np.float64)
    lp = local_planes(p, window_px=7)
    nm = estimate_noise(p, lp)
    surf = segment_surfaces(p, lp, nm, factor=1)
    return res, p, surf, adjacent_pairs(surf, nm), find_support(p, surf, nm), nm


def test_a_slab_whose_corner_comes_within_reach_of_the_part_does_not_join_it_across_the_table() -> None:
    """A slab on the table, turned 30 degrees, one corner 4 mm from the tee's base plate: within the touching
    reach (6 mm plus noise and spacing), but the table shows between them, so it is another object."""
    turned = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    corners = np.array([turned @ [sx * 0.04, sy * 0.04, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    x = -0.15 - 0.004 - float(corners[:, 0].max())  # its farthest corner 4 mm short of the plate's -x end
    slab = Part("slab", "hull", (0, 0, 0), make_X(turned, [x, -0.02, 0.0]), (0.5, 0.5, 0.5), workpiece=False,
                corners_part=box_corners(0.08, 0.08, 0.02))  # fmt: skip
    base = hull("base", box_corners(0.30, 0.24, 0.012))
    web = hull("web", box_corners(0.010, 0.16, 0.08), z=0.012)
    res, p, surf, pairs, support, nm = _work_of((base, web, slab), (-0.12, -0.10, 0.55), (-0.08, 0.0, 0.0))
    parts = {lab: part_of(res, surf, lab) for lab in range(len(surf.surfaces))}
    slab_labels = {lab for lab in parts if parts[lab] == 3}
    assert slab_labels and support
    # the slab's faces come within reach of the plate's top: the old test (reach alone) joined them
    assert any({pair.a, pair.b} & slab_labels and {parts[pair.a], parts[pair.b]} == {BASE, 3} for pair in pairs)
    wp = workpiece_labels(p, surf, pairs, nm, prompted=prompted_labels(np.array([click(res, BASE)]), surf),
                          support=support)  # fmt: skip
    assert wp is not None and {parts[lab] for lab in wp} == {BASE, WEB}


def test_two_plates_of_a_butt_joint_join_across_their_gap_where_the_table_shows() -> None:
    """Two 4 mm plates 5 mm apart, seen from above the gap (the table shows in it, between every pair of their
    points within reach): a butt joint's plates, one clicked, are one workpiece."""
    left = hull("left", box_corners(0.12, 0.20, 0.004), x=-0.06 - 0.0025)
    right = hull("right", box_corners(0.12, 0.20, 0.004), x=0.06 + 0.0025)
    res, p, surf, pairs, support, nm = _work_of((left, right), (0.0, -0.05, 0.45), (0.0, 0.0, 0.0))
    parts = {lab: part_of(res, surf, lab) for lab in range(len(surf.surfaces))}
    wp = workpiece_labels(p, surf, pairs, nm, prompted=prompted_labels(np.array([click(res, 1)]), surf),
                          support=support)  # fmt: skip
    assert support and wp is not None and {parts[lab] for lab in wp} == {1, 2}
