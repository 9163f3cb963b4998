"""cell.metrics: the exposition text parsed back, bucket by bucket, against the durations observed."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from cell.metrics import CONTENT_TYPE, JOB_DURATION_BUCKETS_S, OUTCOMES, CellMetrics, DaemonSnapshot

REPO = Path(__file__).resolve().parents[2]


def _samples(metrics: CellMetrics) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    out = {}
    for family in text_string_to_metric_families(metrics.render().decode()):
        for s in family.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def test_build_info_names_the_installed_version():
    version = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    samples = _samples(CellMetrics())
    (key,) = [k for k in samples if k[0] == "weldcell_build_info"]
    labels = dict(key[1])
    assert labels["version"] == version and labels["opencv"].startswith("4.")
    assert samples[key] == 1.0


def test_job_durations_land_in_the_right_buckets_per_outcome():
    m = CellMetrics(build={"version": "x"})
    for d in (3.0, 5.0, 42.0, 700.0, 5000.0):
        m.observe_job(d, "welded")
    m.observe_job(2.5, "dry_run")
    s = _samples(m)

    def bucket(outcome: str, le: str) -> float:
        return s[("weldcell_job_duration_seconds_bucket", (("le", le), ("outcome", outcome)))]

    # cumulative: le=5 holds 3 s and 5 s (le is inclusive); 42 s is first counted at 60; 700 s at 1200;
    # 5000 s only in +Inf
    expected = {5.0: 2, 10.0: 2, 30.0: 2, 60.0: 3, 120.0: 3, 300.0: 3, 600.0: 3, 1200.0: 4, 1800.0: 4, 3600.0: 4}
    assert set(expected) == set(JOB_DURATION_BUCKETS_S)
    for le, count in expected.items():
        assert bucket("welded", str(le)) == count
    assert bucket("welded", "+Inf") == 5
    assert s[("weldcell_job_duration_seconds_count", (("outcome", "welded"),))] == 5
    assert s[("weldcell_job_duration_seconds_sum", (("outcome", "welded"),))] == pytest.approx(5750.0, abs=1e-9)
    assert s[("weldcell_job_duration_seconds_count", (("outcome", "dry_run"),))] == 1
    # every outcome is exposed from the start, at zero
    for outcome in OUTCOMES:
        assert ("weldcell_job_duration_seconds_count", (("outcome", outcome),)) in s
    assert s[("weldcell_job_duration_seconds_count", (("outcome", "fault"),))] == 0


def test_two_daemons_do_not_share_counters_and_bad_observations_are_refused():
    a, b = CellMetrics(build={"version": "x"}), CellMetrics(build={"version": "x"})
    a.observe_job(1.0, "fault")
    assert _samples(b)[("weldcell_job_duration_seconds_count", (("outcome", "fault"),))] == 0
    with pytest.raises(ValueError, match="not one of"):
        a.observe_job(1.0, "exploded")
    with pytest.raises(ValueError, match="finite and >= 0"):
        a.observe_job(float("nan"), "welded")
    with pytest.raises(ValueError, match="finite and >= 0"):
        a.observe_job(-1.0, "welded")


def test_the_daemon_snapshot_is_read_at_every_scrape():
    counts = {"welded": 2}
    snap = DaemonSnapshot(
        states=("idle", "welding"), state="welding", outcomes=counts, queued=3, seams_welded=7, poses_sent=120,
        arc_time_s=12.5, cycle_phases=("capture", "motion"), last_cycle_s={"capture": 1.5, "total": 9.0},
    )  # fmt: skip
    m = CellMetrics(build={"version": "x"}, snapshot=lambda: snap)
    s = _samples(m)
    assert s[("weldcell_cell_state", (("state", "welding"),))] == 1.0
    assert s[("weldcell_cell_state", (("state", "idle"),))] == 0.0
    assert s[("weldcell_jobs_finished_total", (("outcome", "welded"),))] == 2.0
    assert s[("weldcell_jobs_finished_total", (("outcome", "fault"),))] == 0.0
    assert s[("weldcell_jobs_queued", ())] == 3.0
    assert s[("weldcell_seams_welded_total", ())] == 7.0
    assert s[("weldcell_poses_sent_total", ())] == 120.0
    assert s[("weldcell_arc_seconds_total", ())] == 12.5
    assert s[("weldcell_last_job_cycle_seconds", (("phase", "capture"),))] == 1.5
    assert s[("weldcell_last_job_cycle_seconds", (("phase", "motion"),))] == 0.0
    assert s[("weldcell_last_job_cycle_seconds", (("phase", "total"),))] == 9.0
    counts["welded"] = 3  # the same snapshot object changed: the next scrape says so
    assert _samples(m)[("weldcell_jobs_finished_total", (("outcome", "welded"),))] == 3.0


@pytest.mark.timeout(60)
def test_a_daemon_serves_its_job_durations_and_build_info_after_a_job(tmp_path):
    from cell.daemon import Daemon
    from tests.cell.runner_rig import cell_config, job_text
    from tests.cell.test_daemon import finished_job, request, wait_for

    config = cell_config(tmp_path, "sim-cell-fanuc.toml", daemon={"port": 0})
    with Daemon(config) as d:
        host, port = d.address
        base = f"http://{host}:{port}"
        status, answer = request(f"{base}/jobs?dry_run=1", method="POST", body=job_text().encode())
        assert status == 201
        view = wait_for(lambda: finished_job(base, answer["id"]), timeout_s=40, what="the dry run")
        assert view["report"]["outcome"] == "dry_run"
        import urllib.request

        with urllib.request.urlopen(f"{base}/metrics", timeout=10) as resp:
            ctype, text = resp.headers["Content-Type"], resp.read().decode()
    assert ctype == CONTENT_TYPE == "text/plain; version=0.0.4; charset=utf-8"
    s = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            s[(sample.name, tuple(sorted(sample.labels.items())))] = sample.value
    total = view["report"]["cycle_s"]["total"]
    assert s[("weldcell_job_duration_seconds_count", (("outcome", "dry_run"),))] == 1.0
    assert s[("weldcell_job_duration_seconds_sum", (("outcome", "dry_run"),))] == pytest.approx(total, abs=1e-3)
    assert s[("weldcell_job_duration_seconds_count", (("outcome", "welded"),))] == 0.0
    le = min(b for b in JOB_DURATION_BUCKETS_S if b >= total)
    assert s[("weldcell_job_duration_seconds_bucket", (("le", str(le)), ("outcome", "dry_run")))] == 1.0
    assert s[("weldcell_jobs_finished_total", (("outcome", "dry_run"),))] == 1.0
    (info,) = [k for k in s if k[0] == "weldcell_build_info"]
    assert dict(info[1])["opencv"].startswith("4.") and s[info] == 1.0
