"""The zoo benchmark: a few captures per family each end in seams or a clear NoSeamFound (never an error),
the scorer counts exactly, and the CLI prints the documented JSON. Accuracy figures belong to the bench."""

from __future__ import annotations

import json
from collections.abc import Iterator
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from cell.zoo_bench import CaptureScore, ensure_capture, score_capture
from perception.capture import JOINT_TYPES, load_capture
from sim_fakes import zoo
from sim_fakes.zoo import FAMILIES

KEYS = {"captures", "passed", "gt_seams", "found", "false_seams", "reported", "rmse_mm", "max_mm", "time_s_median"}


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The captures these tests render, at 640x360 instead of the zoo's 1280x720 (a quarter of the pixels to render
    and detect): what is checked here (seams or a clear NoSeamFound, exact counting, the cache) does not depend on
    the image size; the accuracy figures, which do, belong to `weldcell bench zoo`."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(zoo, "draw_capture", partial(zoo.draw_capture, width=640, height=360))
        yield tmp_path_factory.mktemp("zoo-cache")


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_a_zoo_capture_ends_in_seams_or_a_clear_no_seam_found(family: str, cache: Path) -> None:
    folder = ensure_capture(cache, family, 0)
    cap = load_capture(folder)  # the cache is an ordinary capture folder
    assert cap.ground_truth and all(g.joint in JOINT_TYPES for g in cap.ground_truth)
    score, _ = score_capture(folder)
    assert score.outcome in ("seams", "no_seam"), score.reason
    if score.outcome == "no_seam":
        assert score.reason and score.found == 0 and score.reported == 0
    assert 0 <= score.found <= score.gt_seams == len(cap.ground_truth)
    assert score.false_seams <= score.reported
    assert len(score.point_error_mm) == len(score.point_range_m) == len(score.point_incidence_rad)
    # a second call reads the cache: the same capture, bit for bit
    again = load_capture(ensure_capture(cache, family, 0))
    np.testing.assert_array_equal(again.depth_m, cap.depth_m)


def test_the_pass_rule_is_every_seam_no_false_rmse_and_max() -> None:
    base = dict(family="tee", seed=0, sensor="oakd", prompted=True, clutter=0, camera_distance_m=0.5, gt_seams=2,
                reported=2, split_seams=0, p95_mm=0.2, time_s=0.1, outcome="seams")  # fmt: skip
    assert CaptureScore(**base, found=2, false_seams=0, rmse_mm=0.29, max_mm=0.99).passed
    assert not CaptureScore(**base, found=1, false_seams=0, rmse_mm=0.1, max_mm=0.2).passed
    assert not CaptureScore(**base, found=2, false_seams=1, rmse_mm=0.1, max_mm=0.2).passed
    assert not CaptureScore(**base, found=2, false_seams=0, rmse_mm=0.31, max_mm=0.5).passed
    assert not CaptureScore(**base, found=2, false_seams=0, rmse_mm=0.2, max_mm=1.01).passed


def test_bench_zoo_prints_the_documented_json(cache: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from cell.cli import main  # in this process (one job): the captures are those the tests above rendered

    code = main(["bench", "zoo", "--split", "dev", "--n", "2", "--families", "butt,pipe", "--cache", str(cache),
                 "--json", "--out", str(tmp_path / "out")])  # fmt: skip
    out = capsys.readouterr()
    assert code == 0, out.err
    doc = json.loads(out.out)
    assert doc["split"] == "dev" and doc["captures"] == 2
    assert set(doc["families"]) == {"butt", "pipe"}
    for fam in doc["families"].values():
        assert set(fam) >= KEYS and fam["captures"] == 1
    assert set(doc["overall"]) >= KEYS
    assert doc["overall"]["gt_seams"] == sum(f["gt_seams"] for f in doc["families"].values())
    bench = json.loads((tmp_path / "out" / "bench.json").read_text())
    assert len(bench["per_capture"]) == 2
    assert (tmp_path / "out" / "errors.png").stat().st_size > 0
    assert len(list((tmp_path / "out" / "gallery").glob("*.png"))) == 2


def test_bench_zoo_refuses_an_unknown_family(capsys: pytest.CaptureFixture[str]) -> None:
    from cell.cli import main  # in this process: a refusal needs no interpreter of its own

    assert main(["bench", "zoo", "--families", "teapot"]) == 2 and "teapot" in capsys.readouterr().out


def test_errors_are_measured_to_the_whole_seam_and_the_stretch_beyond_the_seen_run_is_overreach(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import perception.detect as detect_mod
    from perception.evaluate import resample_polyline
    from perception.transforms import transform_points

    folder = ensure_capture(cache, "ribs", 5)  # its rib1 fillet is hidden for its first 21 mm
    meta = json.loads((folder / "zoo.json").read_text())
    X = load_capture(folder).X_base_camera  # detections come in the base frame when the capture has a pose
    ((k, truth),) = [(k, t) for k, t in enumerate(meta["truth"]) if t["name"] == "base/rib1@0.0"]
    seen = np.asarray(truth["points_camera"])
    whole = np.asarray(meta["seams"][truth["seam_index"]]["points_camera"])
    u = (seen[-1] - seen[0]) / np.linalg.norm(seen[-1] - seen[0])
    hidden = float(np.min(np.abs((whole[[0, -1]] - seen[0]) @ u)))
    assert hidden > 0.018
    side = np.cross(u, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    others = [np.asarray(t["points_camera"]) for j, t in enumerate(meta["truth"]) if j != k]

    class Found:
        def __init__(self, *paths: np.ndarray) -> None:
            paths = tuple(resample_polyline(p, 0.005) for p in paths)  # path points every 5 mm, as detect's
            self.seams = [type("S", (), {"points": p if X is None else transform_points(X, p), "joint": "fillet"})()
                          for p in paths]  # fmt: skip

    def score(*paths: np.ndarray) -> CaptureScore:
        monkeypatch.setattr(detect_mod, "detect", lambda *_a, **_k: Found(*paths, *others))
        return score_capture(folder)[0]

    exact = score(seen)
    assert exact.found == 3 and exact.false_seams == 0 and exact.max_mm < 1e-6 and exact.overreach_mm == 0.0
    assert exact.joint_named == 3 and exact.misnamed_joints == []  # the ribs' seams are fillets
    # 15 mm on into the hidden stretch, along the weldment's seam: not an error in position, but overreach
    longer = np.vstack([seen[0] - 0.015 * u, seen[-1]])
    s = score(longer)
    assert s.found == 3 and s.max_mm < 1e-6 and s.overreach_mm == pytest.approx(15.0 - 3.0, abs=1.5)  # 3 mm band
    assert s.max_seen_mm == pytest.approx(15.0, abs=0.1)
    # 2 mm to the side: 2 mm off both the seen run and the whole seam
    off = score(seen + 0.002 * side)
    assert off.max_mm == pytest.approx(2.0, abs=0.05) and off.max_seen_mm == pytest.approx(2.0, abs=0.05)
    # far from every seam of the weldment: false
    far = score(seen + 0.05 * side)
    assert far.false_seams == 1 and far.unseen_seams == 0 and far.found == 2


def test_a_detection_through_two_seen_runs_has_its_point_errors_counted_once() -> None:
    """One detection along a whole seam seen in two runs is assigned to both: its points are errors once,
    measured to the whole seam, and against the seen runs to the nearer run (not to the run it is far along)."""
    from types import SimpleNamespace

    from cell.zoo_bench import _point_errors

    whole = [np.array([[0.0, 0.0, 0.5], [0.2, 0.0, 0.5]])]
    normals = np.tile([0.0, 0.0, -1.0], (2, 1)).tolist()
    truth = [{"points_camera": [[0.0, 0.0, 0.5], [0.08, 0.0, 0.5]], "seam_index": 0, "normal_a_camera": normals,
              "normal_b_camera": normals},
             {"points_camera": [[0.15, 0.0, 0.5], [0.2, 0.0, 0.5]], "seam_index": 0, "normal_a_camera": normals,
              "normal_b_camera": normals}]  # fmt: skip
    x = np.linspace(0.0, 0.2, 21)
    det = np.column_stack([x, np.full_like(x, 0.0005), np.full_like(x, 0.5)])
    rows = [SimpleNamespace(index=0, detected_ids=(0,)), SimpleNamespace(index=1, detected_ids=(0,))]
    m = _point_errors(rows, truth, [det], whole)
    assert m.errors_mm.shape == (21,) and np.allclose(m.errors_mm, 0.5)
    # against the runs: 0.5 mm where a run is, up to 35 mm at the middle of the hidden stretch (0.115 m)
    assert m.errors_seen_mm.shape == (21,) and m.errors_seen_mm.max() == pytest.approx(np.hypot(30.0, 0.5), abs=1e-9)
    assert m.overreach_m == pytest.approx(0.064, abs=0.0015)  # the hidden stretch, more than 3 mm from a run


def test_a_sensor_override_is_cached_beside_the_drawn_captures_and_offered_by_the_cli() -> None:
    import argparse

    from cell.commands.bench_zoo import add_parser
    from cell.zoo_bench import ZOO_VERSION, capture_dir

    root = Path("/cache")
    assert capture_dir(root, "tee", 7) == root / f"v{ZOO_VERSION}" / "tee-7"
    assert capture_dir(root, "tee", 7, "oakd_median") == root / f"v{ZOO_VERSION}-oakd_median" / "tee-7"
    sub = argparse.ArgumentParser().add_subparsers()
    add_parser(sub)
    (choice,) = (a for a in sub.choices["zoo"]._actions if a.dest == "sensor")
    assert set(choice.choices or ()) == set(zoo.SENSORS)
