"""weldcell detect CAPTURE... --out-dir: the batch gives the same seams as single runs, per capture, in order."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from cell.cli import main
from cell.commands.detect_batch import output_names

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "samples" / "ribs"


@pytest.fixture(scope="module")
def captures(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Three captures: the sample twice (under two names) and one without any seam (a lone plate on the table)."""
    from perception.capture import save_capture
    from sim_fakes.render import render
    from sim_fakes.scenes import Scene, t_joint

    root = tmp_path_factory.mktemp("captures")
    a, b = root / "a" / "ribs", root / "b" / "ribs"  # the same folder name twice: outputs must not collide
    shutil.copytree(SAMPLE, a)
    shutil.copytree(SAMPLE, b)
    tee = t_joint()
    plate = save_capture(render(Scene("plate", "", tee.parts[:2], (), tee.camera), noise="structured").capture,
                         root / "plate")  # fmt: skip
    return [a, b, plate]


def test_output_names_are_unique_and_named_after_the_capture():
    assert output_names(["x/ribs", "y/ribs/", "scan.ply", "z/ribs"]) == [
        "ribs.seams.json",
        "ribs-2.seams.json",
        "scan.seams.json",
        "ribs-3.seams.json",
    ]


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_batch_writes_what_single_runs_write_and_reports_each_failure(captures, tmp_path, capsys, jobs):
    single = tmp_path / "single.json"
    assert main(["detect", str(captures[0]), "--out", str(single)]) == 0
    capsys.readouterr()
    out = tmp_path / "batch"
    code = main(["detect", *map(str, captures), "--out-dir", str(out), "--jobs", str(jobs), "--json"])
    assert code == 3  # the only failure is a capture without a seam
    cap = capsys.readouterr()
    summary = json.loads(cap.out)
    assert cap.err.strip().splitlines()[-1].startswith("weldcell detect: 1 of 3 capture(s) failed (first: ")
    assert summary == json.loads((out / "batch.json").read_text())
    assert (summary["captures"], summary["failed"]) == (3, 1)
    first, second, plate = summary["results"]
    assert [first["source"], second["source"], plate["source"]] == [str(c) for c in captures]
    assert first["out"] == str(out / "ribs.seams.json") and second["out"] == str(out / "ribs-2.seams.json")
    assert not plate["ok"] and plate["exit"] == 3 and "none meets another" in plate["error"]
    want = json.loads(single.read_text())
    for name in ("ribs.seams.json", "ribs-2.seams.json"):
        got = json.loads((out / name).read_text())
        assert len(got["seams"]) == len(want["seams"]) == first["seams"]
        for g, w in zip(got["seams"], want["seams"], strict=True):
            np.testing.assert_array_equal(g["points"], w["points"])  # the same detector, the same numbers
    assert sorted(p.name for p in out.iterdir()) == ["batch.json", "ribs-2.seams.json", "ribs.seams.json"]


def test_a_clean_batch_exits_0_and_prints_a_table(captures, tmp_path, capsys):
    assert main(["detect", str(captures[0]), "--out-dir", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "1/1 captures with seams" in out and "ribs.seams.json" in out


def test_batch_arguments_are_checked(captures, tmp_path, capsys):
    two = [str(captures[0]), str(captures[1])]
    assert main(["detect", *two]) == 2
    assert "need --out-dir" in capsys.readouterr().err
    assert main(["detect", *two, "--out-dir", str(tmp_path), "--out", "x.json"]) == 2
    assert "--out is for a single capture" in capsys.readouterr().err
    assert main(["detect", *two, "--out-dir", str(tmp_path), "--jobs", "0"]) == 2
    assert "--jobs must be between 1 and 256" in capsys.readouterr().err


def test_without_ray_the_option_says_how_to_install_it(captures, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    assert main(["detect", str(captures[0]), "--out-dir", str(tmp_path), "--ray", "auto"]) == 2
    err = capsys.readouterr().err
    assert "pip install 'weldcell[ray]'" in err and err.count("\n") == 1


def test_on_a_local_ray_cluster_the_batch_gives_the_same_seams(captures, tmp_path, capsys):
    pytest.importorskip("ray", reason="ray is an optional extra (pip install 'weldcell[ray]')")
    out = tmp_path / "ray"
    assert main(["detect", str(captures[0]), str(captures[2]), "--out-dir", str(out), "--ray", "local", "--json"]) == 3
    summary = json.loads(capsys.readouterr().out)
    assert summary["workers"] == "ray"
    assert [r["ok"] for r in summary["results"]] == [True, False]
    pool = tmp_path / "pool"
    assert main(["detect", str(captures[0]), "--out-dir", str(pool), "--jobs", "1"]) == 0
    assert (
        json.loads((out / "ribs.seams.json").read_text())["seams"]
        == json.loads((pool / "ribs.seams.json").read_text())["seams"]
    )
