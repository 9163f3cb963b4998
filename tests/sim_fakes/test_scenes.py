"""The fixed synthetic weldments (sim_fakes/scenes.py), without rendering: each seam's exact definition against its
parts' faces, resampling, the prompt surfaces, the camera and the scene list. (tests/sim_fakes/test_render.py
checks the rendered pictures and their truth.)"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from perception.transforms import make_X
from sim_fakes.hull import box_corners
from sim_fakes.scenes import CYL_SIDE, SCENES, CameraSetup, Part, SeamDef, get_scene, with_resolution
from tests.sim_fakes.test_render import surface_distance


@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_seam_lies_on_both_its_faces_with_unit_in_face_directions(name: str) -> None:
    scene = get_scene(name)
    assert scene.name == name and scene.seams
    for seam in scene.seams:
        (pa, fa), (pb, fb) = seam.faces
        assert pa != pb and "table" not in (scene.parts[pa].name, scene.parts[pb].name)
        a, b = scene.parts[pa], scene.parts[pb]
        on_a, on_b = surface_distance(a, fa, seam.points), surface_distance(b, fb, seam.points)
        # on both faces' planes (a butt seam: on the plates' common top plane, half a gap from each edge)
        assert on_a.max() < 1e-12 and on_b.max() < 1e-12, (seam.name, on_a.max(), on_b.max())
        for into, part, face in ((seam.into_a, a, fa), (seam.into_b, b, fb)):
            assert np.linalg.norm(into, axis=1) == pytest.approx(1.0, abs=1e-12)
            if part.shape == "box":  # lying in the face: perpendicular to its normal
                assert np.abs(into @ part.face_normal_world(face)).max() < 1e-12
        # and across the seam: perpendicular to the centre line
        if seam.kind == "linear":
            d = np.diff(seam.points, axis=0)[0]
            assert abs(float(seam.into_a[0] @ d)) < 1e-12 and abs(float(seam.into_b[0] @ d)) < 1e-12


def test_the_t_joints_fillets_run_along_the_web_at_the_base_plates_top() -> None:
    scene = get_scene("t_joint")
    near, far = scene.seams
    assert (near.name, far.name) == ("web-x", "web+x")
    assert near.points == pytest.approx(np.array([[-0.005, -0.10, 0.010], [-0.005, 0.10, 0.010]]), abs=1e-15)
    assert far.points[:, 0].tolist() == pytest.approx([0.005, 0.005], abs=1e-15)
    assert near.faces == ((1, 5), (2, 0)) and far.faces == ((1, 5), (2, 1))  # base top, the web's -x / +x
    assert near.into_a.tolist() == [[-1.0, 0.0, 0.0]] * 2 and near.into_b.tolist() == [[0.0, 0.0, 1.0]] * 2
    assert near.joint == "fillet" and near.gap_m == 0.0


def test_the_joints_are_named_as_the_capture_format_names_them() -> None:
    joints = {name: sorted({s.joint for s in SCENES[name]().seams}) for name in SCENES}
    assert joints == {
        "t_joint": ["fillet"], "ribs": ["fillet"], "lap_joint": ["lap"], "inside_corner": ["fillet", "inside_corner"],
        "open_box": ["fillet", "inside_corner"], "pipe_on_plate": ["fillet"], "butt_joint": ["butt"],
    }  # fmt: skip
    assert [len(SCENES[n]().seams) for n in SCENES] == [2, 10, 1, 3, 8, 1, 1]


def test_a_seam_is_resampled_at_its_step_with_unit_directions() -> None:
    bend = SeamDef(
        "bend", "curved", np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.1, 0.1, 0.0]]), ((0, 5), (1, 0)),
        np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]), np.tile([0.0, 0.0, 1.0], (3, 1)),
    )  # fmt: skip
    pts, into_a, into_b = bend.sample(0.05)
    assert pts == pytest.approx(np.array([[0, 0, 0], [0.05, 0, 0], [0.1, 0, 0], [0.1, 0.05, 0], [0.1, 0.1, 0]]))
    # halfway along the second leg the in-face direction is the normalized mean of its two ends
    s = np.sqrt(0.5)
    assert into_a == pytest.approx(np.array([[0, 1, 0], [0, 1, 0], [0, 1, 0], [-s, s, 0], [-1, 0, 0]]), abs=1e-12)
    assert into_b.tolist() == [[0.0, 0.0, 1.0]] * 5
    short, _, _ = bend.sample(1.0)  # a step longer than the seam still gives both ends
    assert short == pytest.approx(np.array([[0, 0, 0], [0.1, 0.1, 0]]))


def test_a_gaps_edges_lie_half_a_gap_out_along_the_faces_or_their_across_directions() -> None:
    butt = get_scene("butt_joint").seams[0]
    assert butt.gap_m == 0.0015
    da, db = butt.edge_offsets(butt.into_a, butt.into_b)
    assert da == pytest.approx(np.array([[-0.00075, 0, 0]] * 2))
    assert db == pytest.approx(np.array([[0.00075, 0, 0]] * 2))
    bevel = replace(butt, across_a=np.array([-0.6, 0.0, 0.8]))
    da, db = bevel.edge_offsets(butt.into_a, butt.into_b)
    assert da == pytest.approx(np.array([[-0.00045, 0, 0.0006]] * 2))  # 0.6 and 0.8 of half the gap
    assert db == pytest.approx(np.array([[0.00075, 0, 0]] * 2))
    fillet = get_scene("t_joint").seams[0]
    assert [o.tolist() for o in fillet.edge_offsets(fillet.into_a, fillet.into_b)] == [[[0.0, 0.0, 0.0]] * 2] * 2


def test_the_prompt_surfaces_are_the_seams_faces_in_first_seen_order_unless_given() -> None:
    scene = get_scene("inside_corner")
    assert scene.surfaces() == ((1, 5), (2, 0), (3, 2))
    assert replace(scene, prompt_faces=((2, 0),)).surfaces() == ((2, 0),)


def test_face_normals_of_boxes_cylinders_and_hulls_in_the_world_frame() -> None:
    turned = make_X(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), [0.1, 0.0, 0.0])  # 90 deg about z
    box = Part("box", "box", (0.1, 0.2, 0.3), turned, (0.5, 0.5, 0.5))
    assert box.face_normal_world(1).tolist() == pytest.approx([0.0, 1.0, 0.0])  # part +x is world +y
    assert box.face_normal_world(2).tolist() == pytest.approx([1.0, 0.0, 0.0])  # part -y is world +x
    pipe = Part("pipe", "cylinder", (0.04, 0.04, 0.1), np.eye(4), (0.5, 0.5, 0.5))
    assert pipe.face_normal_world(1).tolist() == [0.0, 0.0, -1.0] and pipe.face_normal_world(2).tolist() == [0, 0, 1]
    with pytest.raises(ValueError, match="the cylinder side has no single normal"):
        pipe.face_normal_world(CYL_SIDE)
    hull = Part("rib", "hull", (0.0, 0.0, 0.0), turned, (0.5, 0.5, 0.5), corners_part=box_corners(0.1, 0.2, 0.3))
    assert hull.hull_world is not None and len(hull.hull_world.faces) == 6
    assert sorted(tuple(np.round(hull.face_normal_world(i), 12) + 0.0) for i in range(6)) == sorted(
        [(1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, -1.0)]
    )
    assert hull.hull_world.vertices[:, 0].min() == pytest.approx(0.0)  # x from 0.1 - 0.1 to 0.1 + 0.1 (turned)
    with pytest.raises(ValueError, match="part 'rib': a hull needs corners_part"):
        Part("rib", "hull", (0.0, 0.0, 0.0), turned, (0.5, 0.5, 0.5))


def test_another_resolution_scales_the_focal_lengths_with_the_width_and_keeps_the_pose() -> None:
    scene = get_scene("ribs")
    small = with_resolution(scene, 640, 360)
    cam, c = scene.camera, small.camera
    assert (cam.width, cam.height, cam.fx) == (1280, 720, 920.0)
    assert (c.width, c.height, c.fx, c.fy) == (640, 360, 460.0, 460.0)
    assert (c.cx, c.cy) == (319.5, 179.5)
    assert np.array_equal(c.X_world_camera, cam.X_world_camera)
    look = CameraSetup(eye=(0.0, 0.0, 1.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)).X_world_camera
    assert look[:3, 2].tolist() == pytest.approx([0.0, 0.0, -1.0])  # the optical axis points at the target
    assert look[:3, 3].tolist() == [0.0, 0.0, 1.0]


def test_an_unknown_scene_is_refused_with_the_list() -> None:
    with pytest.raises(KeyError, match="unknown scene 'teapot'; choose one of: t_joint, ribs, lap_joint"):
        get_scene("teapot")
