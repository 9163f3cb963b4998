"""Prometheus metrics of the cell through ``prometheus-client``: build info and a job-duration histogram.

One :class:`CellMetrics` per daemon, on its own registry (not the library's global one, so two daemons or a test
next to a daemon never share counters). Wiring, for whoever owns :mod:`cell.daemon`:

- create ``CellMetrics()`` when the daemon starts;
- when a job ends, ``metrics.observe_job(duration_s, outcome)`` with the same outcome names as
  ``weldcell_jobs_finished_total`` (:data:`OUTCOMES`);
- serve ``GET /metrics`` as ``metrics.render()`` with content type :data:`CONTENT_TYPE` (the daemon's own
  hand-written lines can be appended: the metric names differ).

Units are SI as Prometheus wants them: seconds.
"""

from __future__ import annotations

import math
import platform

from prometheus_client import CollectorRegistry, Histogram, Info, generate_latest
from prometheus_client import exposition as _exposition

OUTCOMES = ("welded", "dry_run", "rejected", "no_seam", "refused", "fault")
"""How a job ends, as the daemon counts them."""

JOB_DURATION_BUCKETS_S = (5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1200.0, 1800.0, 3600.0)
"""A dry run takes seconds, a welded part minutes, a big one an hour."""

CONTENT_TYPE = str(_exposition.CONTENT_TYPE_LATEST)


def build_labels() -> dict[str, str]:
    """What ``weldcell_build_info`` reports: weldcell's version, Python's and the vision libraries'."""
    from importlib.metadata import PackageNotFoundError, version

    def dist(name: str) -> str:
        try:
            return version(name)
        except PackageNotFoundError:
            return "not installed"

    import cv2

    open3d = dist("open3d-cpu")
    return {
        "version": dist("weldcell"),
        "python": platform.python_version(),
        "opencv": str(cv2.__version__),
        "open3d": open3d if open3d != "not installed" else dist("open3d"),
    }


class CellMetrics:
    """The metrics of one cell daemon."""

    def __init__(self, *, build: dict[str, str] | None = None) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        self._build = Info("weldcell_build", "weldcell's version and its main libraries'.", registry=self.registry)
        self._build.info(build if build is not None else build_labels())
        self._job_duration = Histogram(
            "weldcell_job_duration_seconds",
            "Wall time of a job from its start to its end, by outcome.",
            labelnames=("outcome",),
            buckets=JOB_DURATION_BUCKETS_S,
            registry=self.registry,
        )
        for outcome in OUTCOMES:  # every series exists from the start, at 0, so rates work from the first job
            self._job_duration.labels(outcome=outcome)

    def observe_job(self, duration_s: float, outcome: str) -> None:
        """Record one finished job; ValueError for an unknown outcome or a duration that is not finite and >= 0."""
        if outcome not in OUTCOMES:
            raise ValueError(f"outcome {outcome!r} is not one of {', '.join(OUTCOMES)}")
        d = float(duration_s)
        if not (math.isfinite(d) and d >= 0.0):
            raise ValueError(f"job duration must be finite and >= 0 s, got {duration_s!r}")
        self._job_duration.labels(outcome=outcome).observe(d)

    def render(self) -> bytes:
        """The text exposition of every metric here (serve with :data:`CONTENT_TYPE`)."""
        return bytes(generate_latest(self.registry))
