"""``weldcell run`` after an unclean stop: the cell starts in fault, as ``weldcell serve`` does, and runs nothing
until an operator acknowledges; the refusal holds for every run until then (it is journaled)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cell.cli import main
from cell.journal import Journal
from tests.cell.runner_rig import BARE_TABLE_CAPTURE, EXAMPLES, job_text


def fanuc_config(tmp_path: Path) -> Path:
    text = (EXAMPLES / "sim-cell-fanuc.toml").read_text(encoding="utf-8")
    text = text.replace("port = 16001", "port = 0").replace("port = 5020", "port = 0")
    text = text.replace('journal = "../out/weldcell-fanuc-journal.sqlite3"', f'journal = "{tmp_path / "j.sqlite3"}"')
    path = tmp_path / "cell.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.timeout(120)
def test_an_unclean_stop_refuses_every_run_until_an_operator_acknowledges(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = fanuc_config(tmp_path)
    with Journal(tmp_path / "j.sqlite3") as journal:  # a process that died while its job welded
        crashed = journal.submit("ribs.toml")
        journal.record_state_change(crashed, "idle", "homing", "job started", job_state="running")
    job = tmp_path / "job.toml"
    job.write_text(job_text(capture=BARE_TABLE_CAPTURE), encoding="utf-8")

    assert main(["run", str(job), "--config", str(config), "--yes"]) == 1
    err = capsys.readouterr().err
    assert f"weldcell run: the cell is in fault: unclean stop: job {crashed} was running" in err
    assert "--acknowledge --operator NAME" in err
    with Journal(tmp_path / "j.sqlite3") as journal:
        assert [r.id for r in journal.recent_jobs()] == [crashed]  # nothing else was submitted
        assert journal.job(crashed).state == "interrupted" and journal.interrupted == ()
        [fault] = [e for e in journal.events(None) if e.to_state == "fault"]
        assert fault.reason.startswith(f"unclean stop: job {crashed}")
        # the next run is refused too: the fault is journaled
        assert journal.unclean_stop(then="run again with --acknowledge --operator NAME") == fault.reason

    # acknowledged: the job runs (no seam on the bare table: exit 3) and the cell is clean for the next run
    assert main(["run", str(job), "--config", str(config), "--acknowledge", "--operator", "ann"]) == 3
    assert "no seam found" in capsys.readouterr().err
    with Journal(tmp_path / "j.sqlite3") as journal:
        cell_events = journal.events(None)
        assert cell_events[-1].from_state == "fault" and "acknowledged by ann" in cell_events[-1].reason
        assert len(journal.recent_jobs()) == 2
        assert journal.unclean_stop(then="acknowledge") is None
