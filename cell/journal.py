"""The cell's journal: every job and every state change in a SQLite file (stdlib ``sqlite3``).

Durability: WAL mode with ``synchronous=FULL``; every write is its own transaction, committed before the call
returns, so a process killed at any instant (``kill -9``) loses nothing it was told was written, and a power cut
loses nothing committed. Several threads may share a :class:`Journal`: one connection guarded by a lock.
Several processes may open the same file (SQLite locks it; writers wait up to ``busy_timeout_s``).

Jobs have their own states, distinct from the state machine's: ``queued`` -> ``running`` -> ``done`` |
``failed`` | ``cancelled`` | ``dry_run`` (a dry run that planned and validated its path, nothing moved); plus
``interrupted``: opening the journal marks every job found ``queued`` or
``running`` as interrupted (the process that owned it died) and lists them in :attr:`Journal.interrupted`.
Interrupted jobs are never resumed: a half-welded part needs an operator.

Times are Unix seconds (float). ``report`` is any JSON-serialisable dict, stored as text.
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

from cell.errors import WeldcellError

logger = logging.getLogger(__name__)

UNCLEAN_STOP = "unclean stop:"
"""How the reason of the fault after an unclean stop begins (:meth:`Journal.unclean_stop`)."""
_CHECK = "check the torch and the part"

JOB_STATES = ("queued", "running", "done", "failed", "cancelled", "dry_run", "interrupted")
FINAL_JOB_STATES = frozenset({"done", "failed", "cancelled", "dry_run", "interrupted"})

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id            INTEGER PRIMARY KEY AUTOINCREMENT,
    job_file      TEXT NOT NULL,
    submitted_s   REAL NOT NULL,
    started_s     REAL,
    finished_s    REAL,
    state         TEXT NOT NULL,
    report_json   TEXT,
    error         TEXT
);
CREATE TABLE IF NOT EXISTS events (
    id            INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id        INTEGER REFERENCES jobs(id),
    time_s        REAL NOT NULL,
    from_state    TEXT NOT NULL,
    to_state      TEXT NOT NULL,
    reason        TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS events_by_job ON events (job_id, id);
"""


class JournalError(WeldcellError):
    """The journal cannot be read or written (the cell must not run without it)."""


@dataclass(frozen=True)
class JobRecord:
    """One row of ``jobs``. Times: Unix seconds; ``report``: the decoded report JSON (None when not written)."""

    id: int
    job_file: str
    submitted_s: float
    started_s: float | None
    finished_s: float | None
    state: str
    report: dict[str, Any] | None
    error: str | None

    @property
    def final(self) -> bool:
        return self.state in FINAL_JOB_STATES


@dataclass(frozen=True)
class EventRecord:
    """One state change: ``job_id`` None for a change outside a job (calibration, acknowledging a fault...)."""

    id: int
    job_id: int | None
    time_s: float
    from_state: str
    to_state: str
    reason: str


class Journal:
    """Open (creating if needed) the journal at ``path``; jobs left ``queued``/``running`` become ``interrupted``.

    ``clock``: returns Unix seconds (injectable for tests). Use as a context manager or call :meth:`close`.
    """

    def __init__(
        self, path: str | os.PathLike[str], *, clock: Callable[[], float] = time.time, busy_timeout_s: float = 10.0
    ) -> None:
        self.path = Path(path)
        self._clock = clock
        self._lock = threading.Lock()
        try:
            if self.path.parent and not self.path.parent.exists():
                self.path.parent.mkdir(parents=True, exist_ok=True)
            # isolation_level=None: no implicit transactions; every write below opens and commits its own
            self._db = sqlite3.connect(self.path, timeout=busy_timeout_s, isolation_level=None, check_same_thread=False)
            mode = self._db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise JournalError(f"{self.path}: cannot switch the journal to WAL mode (got {mode!r})")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._db.executescript(_SCHEMA)
        except sqlite3.Error as err:
            raise JournalError(f"{self.path}: cannot open the journal: {err}") from err
        self.interrupted: tuple[JobRecord, ...] = self._mark_interrupted()
        """The jobs this open found queued or running and marked interrupted (their ``error`` says which)."""

    # ------------------------------------------------------------------------------------------ plumbing
    def _write(self, sql_and_params: list[tuple[str, tuple[Any, ...]]]) -> list[sqlite3.Cursor]:
        """Run the statements in one immediate transaction, committed before returning."""
        with self._lock:
            try:
                self._db.execute("BEGIN IMMEDIATE")
                try:
                    cursors = [self._db.execute(sql, params) for sql, params in sql_and_params]
                except BaseException:
                    self._db.execute("ROLLBACK")
                    raise
                self._db.execute("COMMIT")
                return cursors
            except sqlite3.Error as err:
                raise JournalError(f"{self.path}: journal write failed: {err}") from err

    def _read(self, sql: str, params: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
        with self._lock:
            try:
                return list(self._db.execute(sql, params).fetchall())
            except sqlite3.Error as err:
                raise JournalError(f"{self.path}: journal read failed: {err}") from err

    def _mark_interrupted(self) -> tuple[JobRecord, ...]:
        now = self._clock()
        with self._lock:
            try:
                self._db.execute("BEGIN IMMEDIATE")
                try:
                    found = self._db.execute(
                        "SELECT id, job_file, state FROM jobs WHERE state IN ('queued', 'running') ORDER BY id"
                    ).fetchall()
                    for job_id, _job_file, state in found:
                        self._db.execute(
                            "UPDATE jobs SET state = 'interrupted', finished_s = ?, "
                            "error = COALESCE(error, ?) WHERE id = ?",
                            (now, f"interrupted: the cell stopped while the job was {state}", job_id),
                        )
                        self._db.execute(
                            "INSERT INTO events (job_id, time_s, from_state, to_state, reason) VALUES (?, ?, ?, ?, ?)",
                            (job_id, now, state, "interrupted", "journal reopened: the previous process stopped"),
                        )
                    rows = [
                        self._db.execute(f"SELECT {_JOB_COLUMNS} FROM jobs WHERE id = ?", (job_id,)).fetchone()
                        for job_id, _f, _s in found
                    ]
                except BaseException:
                    self._db.execute("ROLLBACK")
                    raise
                self._db.execute("COMMIT")
            except sqlite3.Error as err:
                raise JournalError(f"{self.path}: cannot recover interrupted jobs: {err}") from err
        for job_id, job_file, state in found:
            logger.warning(
                "job %d (%s) was %s when the cell stopped: marked interrupted, not resumed", job_id, job_file, state
            )
        return tuple(_job(row) for row in rows)

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def __enter__(self) -> Journal:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------ writes
    def submit(self, job_file: str) -> int:
        """Record a new ``queued`` job; returns its id (ids are never reused)."""
        cur = self._write(
            [
                (
                    "INSERT INTO jobs (job_file, submitted_s, state) VALUES (?, ?, 'queued')",
                    (str(job_file), self._clock()),
                )
            ]
        )[0]
        job_id = cur.lastrowid
        assert job_id is not None
        return int(job_id)

    def record_state_change(
        self,
        job_id: int | None,
        from_state: str,
        to_state: str,
        reason: str,
        *,
        job_state: str | None = None,
        error: str | None = None,
    ) -> None:
        """Record a state change and, in the same transaction, the job's new ``job_state`` (if given).

        ``running`` sets the start time (once); a final state sets the finish time and ``error``. A job already
        in a final state keeps it: later events are still recorded.
        """
        now = self._clock()
        stmts: list[tuple[str, tuple[Any, ...]]] = [
            (
                "INSERT INTO events (job_id, time_s, from_state, to_state, reason) VALUES (?, ?, ?, ?, ?)",
                (job_id, now, str(from_state), str(to_state), str(reason)),
            )
        ]
        if job_state is not None:
            if job_id is None:
                raise ValueError("job_state needs a job_id")
            if job_state not in JOB_STATES:
                raise ValueError(f"job_state must be one of {JOB_STATES}, got {job_state!r}")
            if job_state in FINAL_JOB_STATES:
                stmts.append(
                    (
                        "UPDATE jobs SET state = ?, finished_s = ?, error = COALESCE(?, error) "
                        "WHERE id = ? AND state NOT IN ('done', 'failed', 'cancelled', 'dry_run', 'interrupted')",
                        (job_state, now, error, job_id),
                    )
                )
            else:
                stmts.append(
                    (
                        "UPDATE jobs SET state = ?, started_s = COALESCE(started_s, ?) "
                        "WHERE id = ? AND state NOT IN ('done', 'failed', 'cancelled', 'dry_run', 'interrupted')",
                        (job_state, now if job_state == "running" else None, job_id),
                    )
                )
        self._write(stmts)

    def set_report(self, job_id: int, report: dict[str, Any]) -> None:
        """Store the job's report (replacing an earlier one)."""
        text = json.dumps(report, sort_keys=True, allow_nan=False)
        cur = self._write([("UPDATE jobs SET report_json = ? WHERE id = ?", (text, job_id))])[0]
        if cur.rowcount != 1:
            raise JournalError(f"{self.path}: no job {job_id} to attach a report to")

    # ------------------------------------------------------------------------------------------ queries
    def job(self, job_id: int) -> JobRecord:
        rows = self._read(f"SELECT {_JOB_COLUMNS} FROM jobs WHERE id = ?", (job_id,))
        if not rows:
            raise KeyError(f"no job {job_id} in {self.path}")
        return _job(rows[0])

    def recent_jobs(self, limit: int = 20) -> list[JobRecord]:
        """The ``limit`` most recently submitted jobs, newest first."""
        return [_job(r) for r in self._read(f"SELECT {_JOB_COLUMNS} FROM jobs ORDER BY id DESC LIMIT ?", (limit,))]

    def jobs_in_state(self, state: str) -> list[JobRecord]:
        return [_job(r) for r in self._read(f"SELECT {_JOB_COLUMNS} FROM jobs WHERE state = ? ORDER BY id", (state,))]

    def events(self, job_id: int | None) -> list[EventRecord]:
        """Every state change of job ``job_id`` (None: the changes outside jobs), oldest first."""
        cols = "id, job_id, time_s, from_state, to_state, reason"
        if job_id is None:
            rows = self._read(f"SELECT {cols} FROM events WHERE job_id IS NULL ORDER BY id")
        else:
            rows = self._read(f"SELECT {cols} FROM events WHERE job_id = ? ORDER BY id", (job_id,))
        return [
            EventRecord(int(r[0]), None if r[1] is None else int(r[1]), float(r[2]), r[3], r[4], r[5]) for r in rows
        ]

    def unclean_stop(self, *, then: str) -> str | None:
        """Why the cell must start in ``fault``, or None: a job was running when the previous process stopped, found
        by this open or by an earlier one and not acknowledged since (the last change outside jobs is that fault).
        ``then``: what the operator does about it, ending the returned reason."""
        unclean = [r.id for r in self.interrupted if r.started_s is not None]
        if unclean:
            jobs = ", ".join(map(str, unclean))
            return f"{UNCLEAN_STOP} job {jobs} was running when the previous process stopped; {_CHECK}, then {then}"
        for event in reversed(self.events(None)):  # newest first; later faults (a failed acknowledge) do not count
            if event.from_state == "fault" and event.to_state != "fault":
                return None  # the cell left fault since: acknowledged
            if event.to_state == "fault" and event.reason.startswith(UNCLEAN_STOP):
                known = event.reason.split(f"; {_CHECK}")[0]  # the instruction is this caller's own
                return f"{known}; {_CHECK}, then {then}"
        return None

    def recent_events(self, limit: int = 50) -> list[EventRecord]:
        """The ``limit`` latest state changes of any job, newest first."""
        rows = self._read(
            "SELECT id, job_id, time_s, from_state, to_state, reason FROM events ORDER BY id DESC LIMIT ?", (limit,)
        )
        return [
            EventRecord(int(r[0]), None if r[1] is None else int(r[1]), float(r[2]), r[3], r[4], r[5]) for r in rows
        ]


_JOB_COLUMNS = "id, job_file, submitted_s, started_s, finished_s, state, report_json, error"


def _job(row: tuple[Any, ...]) -> JobRecord:
    return JobRecord(
        id=int(row[0]),
        job_file=row[1],
        submitted_s=float(row[2]),
        started_s=None if row[3] is None else float(row[3]),
        finished_s=None if row[4] is None else float(row[4]),
        state=row[5],
        report=None if row[6] is None else json.loads(row[6]),
        error=row[7],
    )
