"""``weldcell bench real``: the references' scoring rules on constructed cases, and (when the real data is
present) every item listed and none ending in an error."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cell.cli import main
from cell.real_bench import RealItem, _score, discover

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"


def ref(tol: float = 0.01) -> dict:
    return {"file": "r.json", "tolerance_m": tol, "seams": [{"points": [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]}]}


def test_a_reference_seam_is_covered_where_detected_points_lie_within_its_tolerance() -> None:
    item = RealItem("x", "cloud", seams=[{"kind": "linear", "length_m": 0.07}])
    # a detected path on the first 70 mm, 5 mm beside the line (tolerance 10 mm)
    path = np.column_stack([np.linspace(0.0, 0.07, 71), np.full(71, 0.005), np.zeros(71)])
    _score(item, [path], ref())
    # samples every mm on [0, 100]; those within 10 mm of a path point: x <= 70 + sqrt(10^2 - 5^2) = 78.66
    assert item.coverage == [pytest.approx(79 / 101, abs=1e-3)]
    assert item.false_seams == 0 and item.passed is True


def test_a_seam_far_from_every_reference_is_false_and_fails_the_item() -> None:
    item = RealItem("x", "cloud", seams=[{"kind": "linear", "length_m": 0.1}, {"kind": "linear", "length_m": 0.1}])
    on = np.column_stack([np.linspace(0.0, 0.1, 101), np.zeros(101), np.zeros(101)])
    off = on + np.array([0.0, 0.0, 0.0201])  # median 20.1 mm > twice the 10 mm tolerance
    _score(item, [on, off], ref())
    assert item.coverage == [1.0] and item.false_seams == 1 and item.passed is False
    assert item.seams[1]["median_to_reference_m"] == pytest.approx(0.0201, abs=1e-4)
    nothing = RealItem("y", "cloud")
    _score(nothing, [], ref())
    assert nothing.coverage == [0.0] and nothing.passed is False


def test_a_cloud_passes_again_with_points_dropped_and_a_wrong_reference_never(tmp_path: Path) -> None:
    """The rendered tee's cloud (.npy) with its fillet as the reference: every draw with 2% of the points
    dropped at random covers it within 3 mm (its path points lie 5 mm apart); the same line 30 mm off never."""
    from cell.real_bench import perturbed_passes
    from perception.capture import read_point_cloud
    from perception.transforms import make_X, transform_points
    from tests.perception.fine.scenes import rendered

    res = rendered("tee", "none")
    p = res.capture.points_camera().reshape(-1, 3)
    (gt,) = res.ground_truth
    X = make_X(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), [0.4, -0.2, 1.0])  # a z-up frame
    np.save(tmp_path / "tee.npy", transform_points(X, p[np.isfinite(p[:, 2])].astype(np.float64)))
    line = transform_points(X, gt.points_camera)
    cloud = read_point_cloud(tmp_path / "tee.npy")
    good = {"file": "tee.json", "tolerance_m": 0.003, "seams": [{"points": line.tolist()}]}
    assert perturbed_passes(cloud, good, draws=3, dropout=0.02, method="surfaces") == [True] * 3
    off = {**good, "seams": [{"points": (line + np.array([0.0, 0.0, 0.03])).tolist()}]}
    assert perturbed_passes(cloud, off, draws=2, dropout=0.02, method="surfaces") == [False] * 2


@pytest.mark.realdata
@pytest.mark.skipif(not REALDATA.is_dir(), reason="../shared/realdata is not present")
def test_bench_real_lists_every_item_and_none_ends_in_an_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    items = discover(REALDATA)
    kinds = {k for _, k in items}
    assert {"cloud", "rgbd frame", "photos", "mesh"} <= kinds
    # in this process (the CLI's own code path): a child interpreter would import numpy, SciPy and Open3D again
    assert main(["bench", "real", "--realdata", str(REALDATA), "--json", "--out", str(tmp_path)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [i["item"] for i in doc["items"]] == [rel for rel, _ in items]
    refs = {json.loads(f.read_text())["item"] for f in (REALDATA / "references").glob("*.json")}
    assert {i["item"] for i in doc["items"] if i["reference"]} == refs
    for i in doc["items"]:
        assert i["outcome"] in ("seams", "no_seam", "not_run"), (i["item"], i["reason"])
        assert i["outcome"] == "seams" or i["reason"]
        if i["kind"] in ("cloud", "rgbd frame"):
            assert Path(i["image"]).stat().st_size > 0
