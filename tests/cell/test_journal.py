"""The SQLite journal: every committed write survives a kill -9 of the writer; interrupted jobs are reported."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import pytest

from cell.journal import Journal, JournalError

REPO = Path(__file__).resolve().parents[2]


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        self.t += 1.0
        return self.t


def test_a_job_and_its_state_changes_are_recorded(tmp_path: Path) -> None:
    clock = Clock()
    with Journal(tmp_path / "j.sqlite", clock=clock) as j:
        assert j.interrupted == ()
        job = j.submit("jobs/bracket.toml")
        rec = j.job(job)
        assert (rec.state, rec.job_file, rec.submitted_s, rec.started_s, rec.finished_s) == (
            "queued",
            "jobs/bracket.toml",
            1002.0,  # 1001: opening the journal
            None,
            None,
        )
        j.record_state_change(job, "idle", "homing", "job started", job_state="running")
        j.record_state_change(job, "homing", "moving_to_capture", "homing finished")
        j.set_report(job, {"seams": 3, "weld_length_m": 0.42})
        j.record_state_change(job, "retracting", "done", "retracting finished", job_state="done")
        # later events of a finished job are recorded but do not change its state
        j.record_state_change(job, "done", "fault", "late fault", job_state="failed", error="late")
        j.record_state_change(None, "idle", "calibrating", "calibration requested")
        rec = j.job(job)
        assert rec.state == "done" and rec.final and rec.error is None
        assert rec.started_s == 1003.0 and rec.finished_s == 1005.0
        assert rec.report == {"seams": 3, "weld_length_m": 0.42}
        events = j.events(job)
        assert [(e.from_state, e.to_state, e.reason) for e in events] == [
            ("idle", "homing", "job started"),
            ("homing", "moving_to_capture", "homing finished"),
            ("retracting", "done", "retracting finished"),
            ("done", "fault", "late fault"),
        ]
        assert [e.time_s for e in events] == sorted(e.time_s for e in events)
        assert [(e.job_id, e.to_state) for e in j.events(None)] == [(None, "calibrating")]
        second = j.submit("jobs/frame.toml")
        assert second > job
        assert [r.id for r in j.recent_jobs(10)] == [second, job]
        assert [r.id for r in j.recent_jobs(1)] == [second]
        assert j.recent_events(1)[0].to_state == "calibrating"
        with pytest.raises(ValueError, match="job_state must be one of"):
            j.record_state_change(job, "a", "b", "c", job_state="exploded")
        with pytest.raises(JournalError, match="no job 999"):
            j.set_report(999, {})
        with pytest.raises(KeyError):
            j.job(999)
    # WAL mode is on the file, as another reader sees it
    db = sqlite3.connect(tmp_path / "j.sqlite")
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    db.close()


def test_reopening_marks_unfinished_jobs_interrupted_and_lists_them(tmp_path: Path) -> None:
    path = tmp_path / "j.sqlite"
    with Journal(path) as j:
        queued = j.submit("a.toml")
        running = j.submit("b.toml")
        j.record_state_change(running, "idle", "homing", "job started", job_state="running")
        j.record_state_change(running, "homing", "welding", "x")
        done = j.submit("c.toml")
        j.record_state_change(done, "idle", "homing", "started", job_state="running")
        j.record_state_change(done, "retracting", "done", "finished", job_state="done")
    with Journal(path) as j:
        assert [(r.id, r.state) for r in j.interrupted] == [(queued, "interrupted"), (running, "interrupted")]
        assert j.interrupted[1].error == "interrupted: the cell stopped while the job was running"
        assert j.interrupted[0].error == "interrupted: the cell stopped while the job was queued"
        assert j.job(done).state == "done"
        last = j.events(running)[-1]
        assert (last.from_state, last.to_state) == ("running", "interrupted")
        assert [r.id for r in j.jobs_in_state("interrupted")] == [queued, running]
    with Journal(path) as j:  # nothing more to interrupt: never resumed, never reported twice
        assert j.interrupted == ()


def test_threads_share_one_journal(tmp_path: Path) -> None:
    with Journal(tmp_path / "j.sqlite") as j:
        job = j.submit("t.toml")

        def writer(k: int) -> None:
            for i in range(50):
                j.record_state_change(job, f"s{k}", f"s{k}", f"{k}:{i}")

        threads = [threading.Thread(target=writer, args=(k,)) for k in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=20)
        assert not any(t.is_alive() for t in threads)
        reasons = [e.reason for e in j.events(job)]
        assert sorted(reasons) == sorted(f"{k}:{i}" for k in range(4) for i in range(50))
        for k in range(4):  # each thread's own writes in its order
            assert [r for r in reasons if r.startswith(f"{k}:")] == [f"{k}:{i}" for i in range(50)]


CHILD = textwrap.dedent(
    """
    import sys
    from cell.journal import Journal

    j = Journal(sys.argv[1])
    job = j.submit("killed.toml")
    j.record_state_change(job, "idle", "homing", "job started", job_state="running")
    print(f"job {job}", flush=True)
    i = 0
    while True:
        j.record_state_change(job, "welding", "welding", f"progress {i}")
        if i % 3 == 0:
            j.set_report(job, {"progress": i})
        print(f"committed {i}", flush=True)  # only after the write returned
        i += 1
    """
)


@pytest.mark.timeout(60)
def test_every_acknowledged_write_survives_kill_9(tmp_path: Path) -> None:
    path = tmp_path / "j.sqlite"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, text=True, cwd=REPO, env=env
    )
    try:
        assert child.stdout is not None
        first = child.stdout.readline()
        assert first.startswith("job "), first
        job = int(first.split()[1])
        acknowledged = -1
        while acknowledged < 300:
            line = child.stdout.readline()
            assert line.startswith("committed "), line
            acknowledged = int(line.split()[1])
        child.send_signal(signal.SIGKILL)  # mid-stream: it is writing as fast as it can
        child.wait(timeout=10)
        for line in child.stdout:  # lines it printed before dying were acknowledged too
            acknowledged = int(line.split()[1])
    finally:
        if child.poll() is None:
            child.kill()
            child.wait(timeout=10)
        if child.stdout is not None:
            child.stdout.close()
    assert child.returncode == -signal.SIGKILL
    with Journal(path) as j:
        reasons = [e.reason for e in j.events(job)]
        progress = [int(r.split()[1]) for r in reasons if r.startswith("progress ")]
        assert progress[: acknowledged + 1] == list(range(acknowledged + 1))
        assert len(progress) in (acknowledged + 1, acknowledged + 2)  # at most the one in flight besides
        rec = j.job(job)
        assert rec.report is not None and rec.report["progress"] >= acknowledged - acknowledged % 3
        assert [r.id for r in j.interrupted] == [job]
        assert rec.state == "interrupted" and rec.error is not None and "running" in rec.error
        assert reasons[-1] == "journal reopened: the previous process stopped"


def test_an_unopenable_journal_is_an_error(tmp_path: Path) -> None:
    (tmp_path / "dir.sqlite").mkdir()
    with pytest.raises(JournalError, match="cannot open the journal"):
        Journal(tmp_path / "dir.sqlite")
