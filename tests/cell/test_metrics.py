"""cell.metrics: the exposition text parsed back, bucket by bucket, against the durations observed."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from cell.metrics import JOB_DURATION_BUCKETS_S, OUTCOMES, CellMetrics

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
