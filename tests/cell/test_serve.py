"""``weldcell serve`` (cell/commands/serve.py) around a stand-in daemon: what it is handed, the lines it prints, the
signal that stops it, the exit code from the arc read back. (tests/cell/test_daemon.py runs the real service in a
child process; this file checks the command's own logic in a fraction of a second.)"""

from __future__ import annotations

import os
import signal
from pathlib import Path
from types import SimpleNamespace
from typing import Any, ClassVar

import pytest

import cell.daemon
from cell.cli import main

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "sim-cell-fanuc.toml"


class StandInDaemon:
    """Records how the command drives it; ``start`` sends this process the stop signal (the command is armed by
    then), as an operator's Ctrl-C or a service manager's SIGTERM would."""

    made: ClassVar[list[StandInDaemon]] = []
    arc_reads: bool | None = False
    stop_with = signal.SIGTERM

    def __init__(self, config: Any, *, start_simulators: bool, sim_faults: bool) -> None:
        self.config, self.start_simulators, self.sim_faults = config, start_simulators, sim_faults
        self.address = ("127.0.0.1", 41234)
        self.journal = SimpleNamespace(path=Path("/var/weldcell/journal.sqlite3"))
        self.interrupted = [SimpleNamespace(id=7, job_file="jobs/ribs.toml")]
        self.runner = SimpleNamespace(arc_output=3)
        self.arc_on_at_exit = type(self).arc_reads
        self.calls: list[str] = []
        StandInDaemon.made.append(self)

    def start(self) -> None:
        self.calls.append("start")
        os.kill(os.getpid(), self.stop_with)

    def shutdown(self, received: str) -> None:
        self.calls.append(f"shutdown {received}")


@pytest.fixture
def daemon(monkeypatch: pytest.MonkeyPatch) -> type[StandInDaemon]:
    StandInDaemon.made = []
    monkeypatch.setattr(cell.daemon, "Daemon", StandInDaemon)
    return StandInDaemon


@pytest.mark.timeout(20)
def test_serve_starts_prints_where_it_listens_stops_on_sigterm_and_says_the_arc_reads_off(
    daemon: type[StandInDaemon], capsys: pytest.CaptureFixture[str]
) -> None:
    before = signal.getsignal(signal.SIGTERM)
    assert main(["serve", "--config", str(EXAMPLE), "--port", "0"]) == 0
    [d] = daemon.made
    assert (d.config.daemon.port, d.start_simulators, d.sim_faults) == (0, True, False)
    assert d.calls == ["start", "shutdown SIGTERM"]
    assert capsys.readouterr().out.splitlines() == [
        "weldcell serve: listening on http://127.0.0.1:41234 (journal /var/weldcell/journal.sqlite3)",
        "weldcell serve: job 7 (jobs/ribs.toml) was interrupted: not resumed",
        "weldcell serve: SIGTERM received, stopping safely",
        "weldcell serve: stopped; arc output 3 reads off",
    ]
    assert signal.getsignal(signal.SIGTERM) == before  # the handlers are back


@pytest.mark.timeout(20)
@pytest.mark.parametrize(("reads", "code", "said"), [(True, 1, "STILL READS ON"), (None, 0, "could not be read back")])
def test_an_arc_that_still_reads_on_exits_1(
    daemon: type[StandInDaemon], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
    reads: bool | None, code: int, said: str,
) -> None:  # fmt: skip
    monkeypatch.setattr(StandInDaemon, "arc_reads", reads)
    monkeypatch.setattr(StandInDaemon, "stop_with", signal.SIGINT)
    assert main(["serve", "--config", str(EXAMPLE), "--no-sims", "--sim-faults"]) == code
    [d] = daemon.made
    assert (d.config.daemon.port, d.start_simulators, d.sim_faults) == (8765, False, True)  # the config's port
    lines = capsys.readouterr().out.splitlines()
    assert lines[-2:] == [
        "weldcell serve: SIGINT received, stopping safely",
        f"weldcell serve: stopped; arc output 3 {said}",
    ]


def test_a_config_without_safety_is_refused_before_anything_starts(
    daemon: type[StandInDaemon], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = EXAMPLE.read_text(encoding="utf-8")
    start, end = text.index("[safety]"), text.index("[welding]")
    config = tmp_path / "no-safety.toml"
    config.write_text(text[:start] + text[end:], encoding="utf-8")
    assert main(["serve", "--config", str(config)]) == 2
    assert daemon.made == []
    err = capsys.readouterr().err
    assert "running jobs needs a [safety] table (workspace box, reach, limits); see examples/sim-cell.toml" in err
