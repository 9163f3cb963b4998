"""seams.json's schema (perception/seams_schema.py, `weldcell schema seams`) against the writer and the spec."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cell.cli import main
from perception.errors import BadCapture
from perception.seams import DetectionResult, Seam, read_seams_json, seams_to_json, write_seams_json
from tests.seams_validation import ON_PURPOSE, invalid_seams_files, seams_files_under, seams_json_errors


def _result() -> DetectionResult:
    pts = np.array([[0.5, 0.0, 0.02], [0.5, 0.005, 0.02], [0.5, 0.01, 0.02]])
    poses = np.repeat(np.eye(4)[None], 3, axis=0)
    poses[:, :3, 3] = pts
    seam = Seam(id=0, kind="linear", points=pts, poses=poses, length_m=0.01, confidence=0.9, surfaces=(0, 1))
    return DetectionResult(
        frame="base", seams=(seam,), point_counts={"raw": 10, "cropped": 5, "downsampled": 3}, timing_s={"total": 0.1}
    )


def test_the_printed_schema_is_the_models_schema_and_states_version_and_units(capsys):
    assert main(["schema", "seams"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    props = schema["properties"]
    assert props["format_version"]["const"] == "1.1"
    assert props["units"]["const"] == "m"
    assert props["frame"]["enum"] == ["camera", "base"]
    assert set(schema["required"]) == {"format_version", "units", "frame", "seams"}
    seam = schema["$defs"]["SeamModel"]
    assert set(seam["required"]) == {"id", "kind", "points", "poses", "length_m", "confidence"}
    assert seam["properties"]["joint"]["enum"] == ["fillet", "inside_corner", "lap", "v_groove", "butt"]
    assert seam["properties"]["poses"]["items"]["minItems"] == 7
    # extra keys are allowed at every level (capture-format.md: readers ignore them)
    assert schema["additionalProperties"] is True and seam["additionalProperties"] is True


def test_the_writer_writes_version_1_1_in_metres_and_conforms(tmp_path):
    path = write_seams_json(_result(), tmp_path / "seams.json")
    doc = json.loads(path.read_text())
    assert (doc["format_version"], doc["units"], doc["frame"]) == ("1.1", "m", "base")
    assert seams_json_errors(doc) == []
    assert main(["schema", "seams", "--check", str(path)]) == 0


@pytest.mark.parametrize(
    ("change", "where"),
    [
        (lambda d: d.pop("format_version"), "(top level)"),
        (lambda d: d.update(units="mm"), "units"),
        (lambda d: d.update(frame="world"), "frame"),
        (lambda d: d["seams"][0]["poses"][0].pop(), "seams/0/poses/0"),
        (lambda d: d["seams"][0].update(points=[[0.0, 0.0, 0.0]]), "seams/0/points"),
        (lambda d: d["seams"][0].update(confidence=1.5), "seams/0/confidence"),
        (lambda d: d["seams"][0].update(joint="weld"), "seams/0/joint"),
    ],
)
def test_a_non_conforming_file_is_caught_by_the_schema_and_the_check(tmp_path, capsys, change, where):
    doc = seams_to_json(_result())
    change(doc)
    errors = seams_json_errors(doc)
    assert len(errors) == 1 and errors[0].startswith(f"{where}: ")
    folder = tmp_path / ON_PURPOSE
    folder.mkdir()
    (folder / "seams.json").write_text(json.dumps(doc))
    assert invalid_seams_files(folder) == {folder / "seams.json": errors}  # what the suite-wide hook sees
    assert invalid_seams_files(tmp_path) == {}  # ... and skips in a folder named invalid-on-purpose
    assert main(["schema", "seams", "--check", str(folder / "seams.json")]) == 2
    err = capsys.readouterr().err
    assert "does not conform to seams.json 1.1" in err and err.count("\n") == 1


def test_extra_keys_are_allowed_and_a_pose_count_mismatch_is_refused_by_the_model(tmp_path):
    doc = seams_to_json(_result())
    doc["vendor"] = {"anything": 1}
    doc["seams"][0]["note"] = "kept"
    assert seams_json_errors(doc) == []
    doc["seams"][0]["poses"] = doc["seams"][0]["poses"][:2]  # JSON Schema cannot say "as many as points"
    folder = tmp_path / ON_PURPOSE
    folder.mkdir()
    (folder / "s.json").write_text(json.dumps(doc))
    assert main(["schema", "seams", "--check", str(folder / "s.json")]) == 2


def test_the_hook_finds_seams_files_by_content_not_name(tmp_path):
    write_seams_json(_result(), tmp_path / "a" / "s.json")
    (tmp_path / "a" / "ground_truth.json").write_text(json.dumps({"frame": "camera", "seams": []}))
    (tmp_path / "a" / "other.json").write_text(json.dumps({"seams": 3}))
    assert seams_files_under(tmp_path) == [tmp_path / "a" / "s.json"]


def test_the_reader_refuses_another_major_version_or_unit_and_reads_files_from_before_the_field(tmp_path):
    folder = tmp_path / ON_PURPOSE
    folder.mkdir()
    doc = seams_to_json(_result())
    for key, value, message in (("format_version", "2.0", "is not 1.x"), ("units", "mm", "in metres")):
        (folder / "s.json").write_text(json.dumps({**doc, key: value}))
        with pytest.raises(BadCapture, match=message):
            read_seams_json(folder / "s.json")
    old = {k: v for k, v in doc.items() if k not in ("format_version", "units")}
    (folder / "old.json").write_text(json.dumps(old))
    assert np.allclose(read_seams_json(folder / "old.json").points[0], _result().seams[0].points)


def test_the_spec_example_conforms():
    # capture-format.md's example, with its alternatives resolved
    example = {
        "format_version": "1.1",
        "units": "m",
        "frame": "camera",
        "seams": [
            {
                "id": 0,
                "kind": "linear",
                "joint": "fillet",
                "points": [[0.0, 0.0, 0.5], [0.0, 0.005, 0.5]],
                "poses": [[0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0], [0.0, 0.005, 0.5, 0.0, 0.0, 0.0, 1.0]],
                "length_m": 0.2,
                "confidence": 0.97,
            }
        ],
        "points": {"raw": 921600, "cropped": 61234, "downsampled": 8123},
        "timing_s": {"coarse": 0.05, "fine": 0.11, "total": 0.17},
    }
    assert seams_json_errors(example) == []


def test_demo_output_conforms(tmp_path: Path):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    assert seams_files_under(tmp_path) == [tmp_path / "seams.json"]
    assert invalid_seams_files(tmp_path) == {}
