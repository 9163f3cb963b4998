"""``GET /jobs/{id}/export/{format}`` (cell.job_exports through cell.daemon and cell.http_api): a finished job's
seams and path in the five formats of ``weldcell export``, token-guarded, with their media types; the programs are
exactly those of the path the job ran; 404 for an unknown job or format, 409 for a job that has not finished or
planned nothing. One daemon (the simulated FANUC cell), loopback only."""

from __future__ import annotations

import io
import json
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cell.daemon import Daemon
from cell.programs import fanuc_ls_program, urscript_program
from tests.cell.runner_rig import BARE_TABLE_CAPTURE, cell_config, job_text
from tests.cell.test_daemon import TOKEN, request, wait_for

AUTH = {"Authorization": f"Bearer {TOKEN}"}


def get(base: str, path: str) -> tuple[int, str, bytes]:
    import urllib.error
    import urllib.request

    req = urllib.request.Request(f"{base}{path}", headers=AUTH)
    try:
        with urllib.request.urlopen(req, timeout=20) as resp:
            return resp.status, resp.headers.get("Content-Type", ""), resp.read()
    except urllib.error.HTTPError as err:
        return err.code, err.headers.get("Content-Type", ""), err.read()


def done(base: str, job_id: int) -> dict[str, Any] | None:
    view = request(f"{base}/jobs/{job_id}", headers=AUTH)[1]
    final = ("done", "failed", "cancelled", "dry_run")
    return view if view["state"] in final and view["report"] is not None else None


def submit(base: str, text: str) -> int:
    status, answer = request(
        f"{base}/jobs", method="POST", body=text.encode(), headers={**AUTH, "Content-Type": "application/toml"}
    )
    assert status == 201, answer
    return int(answer["id"])


@pytest.fixture(scope="module")
def welded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Daemon, str, int, Any]]:
    tmp = tmp_path_factory.mktemp("exports")
    config = cell_config(tmp, "sim-cell-fanuc.toml", daemon={"port": 0, "token": TOKEN})
    with Daemon(config) as d:
        host, port = d.address
        base = f"http://{host}:{port}"
        job_id = submit(base, job_text(min_length_m=0.1))
        view = wait_for(lambda: done(base, job_id), timeout_s=60, what="the job")
        assert view["report"]["outcome"] == "welded"
        assert d.runner.current is not None and d.runner.current.path is not None
        yield d, base, job_id, d.runner.current.path


def test_the_programs_are_those_of_the_path_the_job_ran(welded: tuple[Daemon, str, int, Any]) -> None:
    _d, base, job_id, path = welded
    assert len(path.split_at_track_moves()) == 1  # one program each (the ribs fit at one track position)
    status, ctype, body = get(base, f"/jobs/{job_id}/export/urscript")
    assert status == 200, body
    assert ctype == "text/plain; charset=utf-8"
    assert body.decode() == urscript_program(path, name="ribs", comment=f"weldcell job {job_id}")
    status, ctype, body = get(base, f"/jobs/{job_id}/export/ls")
    assert status == 200 and ctype == "text/plain; charset=utf-8"
    assert body.decode() == fanuc_ls_program(path, name="ribs", comment=f"weldcell job {job_id}")


def test_the_bag_the_scene_and_the_page_hold_the_jobs_seams(
    welded: tuple[Daemon, str, int, Any], tmp_path: Path
) -> None:
    import trimesh
    from rosbags.highlevel import AnyReader

    d, base, job_id, path = welded
    seams = {s.id: s for s in d.runner.current.seams}  # type: ignore[union-attr]
    status, ctype, body = get(base, f"/jobs/{job_id}/export/rosbag2")
    assert status == 200 and ctype == "application/zip"
    zipfile.ZipFile(io.BytesIO(body)).extractall(tmp_path)
    arrays, routes = [], []
    with AnyReader([tmp_path / f"job{job_id}-bag"]) as reader:
        for conn, _t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            (arrays if conn.topic == "/weldcell/seams" else routes).append(msg)
    assert [len(a.poses) for a in arrays] == [len(s.points_world) for s in seams.values()]
    assert len(routes) == 1 and len(routes[0].poses) == sum(len(p.waypoints) for p in path.passes)
    first = routes[0].poses[0].pose.position
    np.testing.assert_allclose([first.x, first.y, first.z], path.passes[0].approach.X_base_tcp[:3, 3], atol=1e-9)

    status, ctype, body = get(base, f"/jobs/{job_id}/export/gltf")
    assert status == 200 and ctype == "model/gltf-binary"
    scene = trimesh.load(io.BytesIO(body), file_type="glb")
    names = set(scene.geometry)
    assert {f"seam_{i}" for i in seams} <= names and "cloud_crop" in names
    assert len(scene.geometry["cloud_crop"].vertices) > 100

    status, ctype, body = get(base, f"/jobs/{job_id}/export/html")
    assert status == 200 and ctype == "text/html; charset=utf-8"
    data = json.loads(body.decode().split("const DATA = ", 1)[1].split(";\n", 1)[0])
    assert sorted(s["id"] for s in data["seams"]) == sorted(seams) and data["frame"] == "base"


def test_unknown_unfinished_and_empty_jobs_are_refused(welded: tuple[Daemon, str, int, Any]) -> None:
    d, base, job_id, _path = welded
    status, _ctype, body = get(base, f"/jobs/{job_id}/export/step")
    assert status == 404 and "urscript, ls, rosbag2, gltf, html" in json.loads(body)["error"]
    assert get(base, "/jobs/999/export/urscript")[0] == 404
    status, _ = request(f"{base}/jobs/{job_id}/export/urscript")  # no token
    assert status == 401
    waiting = submit(base, job_text(approval=True))
    wait_for(lambda: request(f"{base}/status", headers=AUTH)[1]["state"] == "awaiting_approval", timeout_s=30,
             what="the approval request")  # fmt: skip
    status, _ctype, body = get(base, f"/jobs/{waiting}/export/urscript")
    assert status == 409 and "is running" in json.loads(body)["error"]
    assert d.answer_approval(waiting, None)
    wait_for(lambda: done(base, waiting), timeout_s=20, what="the rejection")
    assert get(base, f"/jobs/{waiting}/export/ls")[0] == 200  # rejected, but its path was planned
    empty = submit(base, job_text(capture=BARE_TABLE_CAPTURE))
    wait_for(lambda: done(base, empty), timeout_s=30, what="the job without seams")
    status, _ctype, body = get(base, f"/jobs/{empty}/export/gltf")
    assert status == 409 and "no kept result" in json.loads(body)["error"]
    assert request(f"{base}/acknowledge", method="POST", body=b'{"operator": "t"}', headers=AUTH)[0] == 200


def test_only_the_newest_results_are_kept(tmp_path: Path) -> None:
    from cell.job_exports import prune_results

    for job_id in (3, 12, 7, 100, 9):
        (tmp_path / str(job_id)).mkdir()
        (tmp_path / str(job_id) / "plan.json").write_text("{}")
    (tmp_path / "notes").mkdir()
    assert prune_results(tmp_path, keep=2) == [3, 7, 9]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["100", "12", "notes"]
    assert prune_results(tmp_path, keep=2) == []
