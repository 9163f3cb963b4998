"""Prometheus metrics of the cell through ``prometheus-client``: build info and a job-duration histogram.

One :class:`CellMetrics` per daemon, on its own registry (not the library's global one, so two daemons or a test
next to a daemon never share counters). The daemon (:mod:`cell.daemon`) creates it with a ``snapshot`` callable
(its counters at scrape time, a :class:`DaemonSnapshot`), calls :meth:`CellMetrics.observe_job` when a job ends
(the outcome names of ``weldcell_jobs_finished_total``, :data:`OUTCOMES`) and serves ``GET /metrics`` as
:meth:`CellMetrics.render` with content type :data:`CONTENT_TYPE`. Served, per daemon:

- ``weldcell_build_info``: weldcell's, Python's, OpenCV's and Open3D's versions;
- ``weldcell_job_duration_seconds``: a histogram of job wall times, by outcome;
- from the snapshot: ``weldcell_cell_state`` (1 for the state the cell is in), ``weldcell_jobs_finished_total`` by
  outcome, ``weldcell_jobs_queued``, ``weldcell_seams_welded_total``, ``weldcell_poses_sent_total``,
  ``weldcell_arc_seconds_total`` and ``weldcell_last_job_cycle_seconds`` by phase.

Units are SI as Prometheus wants them: seconds.
"""

from __future__ import annotations

import math
import platform
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from prometheus_client import CollectorRegistry, Histogram, Info, generate_latest
from prometheus_client import exposition as _exposition
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

OUTCOMES = ("welded", "dry_run", "rejected", "no_seam", "refused", "fault")
"""How a job ends, as the daemon counts them."""

JOB_DURATION_BUCKETS_S = (5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1200.0, 1800.0, 3600.0)
"""A dry run takes seconds, a welded part minutes, a big one an hour."""

CONTENT_TYPE = str(_exposition.CONTENT_TYPE_PLAIN_0_0_4)
"""What :func:`prometheus_client.generate_latest` writes: the text format 0.0.4."""


@dataclass(frozen=True)
class DaemonSnapshot:
    """The daemon's counters at one moment. ``states``: every cell state's name, with the current one; ``outcomes``:
    jobs finished by outcome (missing ones count 0); ``last_cycle_s``: the last finished job's time per phase."""

    states: tuple[str, ...]
    state: str
    outcomes: dict[str, int] = field(default_factory=dict)
    queued: int = 0
    seams_welded: int = 0
    poses_sent: int = 0
    arc_time_s: float = 0.0
    cycle_phases: tuple[str, ...] = ()
    last_cycle_s: dict[str, float] = field(default_factory=dict)


class _DaemonCollector(Collector):
    """The snapshot's values as metric families, read at every scrape."""

    def __init__(self, snapshot: Callable[[], DaemonSnapshot]) -> None:
        self._snapshot = snapshot

    def collect(self) -> Iterator[Metric]:
        snap = self._snapshot()
        state = GaugeMetricFamily(
            "weldcell_cell_state", "1 for the state the cell is in, 0 for the others.", labels=["state"]
        )
        for name in snap.states:
            state.add_metric([name], float(name == snap.state))
        yield state
        finished = CounterMetricFamily(
            "weldcell_jobs_finished", "Jobs finished since the daemon started, by outcome.", labels=["outcome"]
        )
        for outcome in OUTCOMES:
            finished.add_metric([outcome], float(snap.outcomes.get(outcome, 0)))
        yield finished
        yield GaugeMetricFamily("weldcell_jobs_queued", "Jobs waiting in the queue.", value=float(snap.queued))
        yield CounterMetricFamily(
            "weldcell_seams_welded", "Seams welded since the daemon started.", value=float(snap.seams_welded)
        )
        yield CounterMetricFamily(
            "weldcell_poses_sent", "Robot poses commanded since the daemon started.", value=float(snap.poses_sent)
        )
        yield CounterMetricFamily(
            "weldcell_arc_seconds", "Time with the arc on since the daemon started.", value=float(snap.arc_time_s)
        )
        cycle = GaugeMetricFamily(
            "weldcell_last_job_cycle_seconds", "Cycle time of the last finished job, by phase.", labels=["phase"]
        )
        for phase in (*snap.cycle_phases, "total"):
            cycle.add_metric([phase], float(snap.last_cycle_s.get(phase, 0.0)))
        yield cycle


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
    """The metrics of one cell daemon; ``snapshot``: its counters, read at every scrape (None: build info and the
    job-duration histogram only)."""

    def __init__(
        self, *, build: dict[str, str] | None = None, snapshot: Callable[[], DaemonSnapshot] | None = None
    ) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        if snapshot is not None:
            self.registry.register(_DaemonCollector(snapshot))
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
