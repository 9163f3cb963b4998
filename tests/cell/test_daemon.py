"""``weldcell serve`` (cell.daemon) against the fakes, loopback only.

Jobs submitted over HTTP run one at a time and are journaled; status, jobs, metrics and the status page answer; a
configured bearer token is required; a SIGTERM while a job welds stops the motion and leaves the arc off; a daemon
killed mid-job reports that job as interrupted when it starts again, and never resumes it.
"""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
import tomllib
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from cell.config import CellConfig, config_from_dict, load_config
from cell.daemon import Daemon
from cell.errors import ConfigError
from cell.factory import Simulators, build_cell, start_simulators
from cell.journal import Journal
from tests.cell.runner_rig import EXAMPLES, REPO, cell_config, job_text
from tests.config_text import free_port, replace_each_once

TOKEN = "s3cret-token-for-tests"


def request(
    url: str, *, method: str = "GET", body: bytes | None = None, headers: dict[str, str] | None = None
) -> tuple[int, Any]:
    """(status, decoded JSON or text) of one HTTP request; a JSON object body goes as ``application/json`` unless
    ``headers`` say otherwise (urllib's default is form-encoded, which the JSON routes refuse)."""
    headers = dict(headers or {})
    if body is not None and body[:1] == b"{" and not any(k.lower() == "content-type" for k in headers):
        headers["Content-Type"] = "application/json"
    req = urllib.request.Request(url, data=body, method=method, headers=headers)
    try:
        with urllib.request.urlopen(req, timeout=10) as resp:
            status, data, ctype = resp.status, resp.read(), resp.headers.get("Content-Type", "")
    except urllib.error.HTTPError as err:
        status, data, ctype = err.code, err.read(), err.headers.get("Content-Type", "")
    if "json" in ctype:
        return status, json.loads(data)
    return status, data if "image" in ctype else data.decode()


def metric_samples(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    """Every sample of a Prometheus exposition, by (name, sorted labels)."""
    from prometheus_client.parser import text_string_to_metric_families

    out = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            out[(sample.name, tuple(sorted(sample.labels.items())))] = sample.value
    return out


def wait_for(check: Callable[[], Any], *, timeout_s: float, what: str) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"{what} did not happen within {timeout_s} s")


def finished_job(base: str, job_id: int) -> dict[str, Any] | None:
    """The job's view once it is final and its report is stored (the report follows the last state change)."""
    view = request(f"{base}/jobs/{job_id}")[1]
    final = ("done", "failed", "cancelled", "dry_run")
    return view if view["state"] in final and view["report"] is not None else None


def settled_status(base: str) -> dict[str, Any] | None:
    """GET /status once the worker holds no job."""
    st = request(f"{base}/status")[1]
    return st if st["current_job"] is None else None


def job_state(base: str, job_id: int, headers: dict[str, str] | None = None) -> str:
    status, view = request(f"{base}/jobs/{job_id}", headers=headers)
    assert status == 200, view
    return str(view["state"])


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[tuple[Daemon, str]]:
    config = cell_config(tmp_path, "sim-cell-fanuc.toml", daemon={"port": 0})
    d = Daemon(config).start()
    host, port = d.address
    try:
        yield d, f"http://{host}:{port}"
    finally:
        d.shutdown("test over")


# ---------------------------------------------------------------------------------------------- in process
@pytest.mark.timeout(60)
def test_jobs_submitted_over_http_run_in_order_and_are_reported(daemon: tuple[Daemon, str]) -> None:
    _, base = daemon
    status, answer = request(f"{base}/jobs", method="POST", body=job_text(min_length_m=0.1).encode())
    assert status == 201 and answer["state"] == "queued"
    first = int(answer["id"])
    body = json.dumps({"toml": job_text(approval=True), "dry_run": False}).encode()
    status, answer = request(f"{base}/jobs", method="POST", body=body, headers={"Content-Type": "application/json"})
    assert status == 201
    second = int(answer["id"])
    status, answer = request(f"{base}/jobs", method="POST", body=b'workpiece = "x"\n[welding]\ncurrent_a = 180\n')
    assert status == 400 and "welding.current_a: unknown key" in answer["error"]

    # an operator pauses the first job while it welds (motion stopped, arc off) and resumes it
    wait_for(lambda: request(f"{base}/status")[1]["state"] == "welding", timeout_s=20, what="welding")
    status, answer = request(f"{base}/pause", method="POST", body=b'{"operator": "Ada"}')
    assert status == 200 and answer["state"] == "paused", answer
    sims = daemon[0].cell.simulators
    assert sims is not None and not sims.robot.digital_output(1)
    assert request(f"{base}/pause", method="POST", body=b'{"operator": "Ada"}')[0] == 409
    status, answer = request(f"{base}/resume", method="POST", body=b'{"operator": "Ada"}')
    assert status == 200 and answer["state"] == "welding", answer
    view = wait_for(lambda: finished_job(base, first), timeout_s=30, what="the first job")
    assert view["state"] == "done"
    assert view["report"]["outcome"] == "welded" and view["report"]["seams_welded"] >= 2
    states = [e["to"] for e in view["events"] if e["from"] != e["to"]]
    assert states[0] == "homing" and states[-1] == "done" and "paused" in states

    # the second job waits for an operator, who refuses its path: it ends cancelled, nothing welded
    wait_for(
        lambda: (request(f"{base}/status")[1]["current_job"] or {}).get("awaiting_approval"),
        timeout_s=20,
        what="the approval request",
    )
    status, answer = request(f"{base}/jobs/{second}/approve", method="POST", body=b"{}")
    assert status == 400 and "operator" in answer["error"]
    status, answer = request(f"{base}/jobs/{second}/reject", method="POST", body=b'{"operator": "Ada"}')
    assert status == 200 and answer == {"id": second, "approved": False, "operator": "Ada"}
    wait_for(lambda: job_state(base, second) == "cancelled", timeout_s=10, what="the rejection")

    st = wait_for(lambda: settled_status(base), timeout_s=10, what="the worker to finish")
    assert st["state"] == "idle" and st["queued"] == []
    assert [j["id"] for j in st["recent_jobs"]] == [second, first]
    status, answer = request(f"{base}/acknowledge", method="POST", body=b'{"operator": "Ada"}')
    assert status == 409 and "not in fault" in answer["error"]
    status, metrics = request(f"{base}/metrics")
    assert status == 200
    samples = metric_samples(metrics)
    assert samples[("weldcell_jobs_finished_total", (("outcome", "welded"),))] == 1.0
    assert samples[("weldcell_jobs_finished_total", (("outcome", "rejected"),))] == 1.0
    assert samples[("weldcell_cell_state", (("state", "idle"),))] == 1.0
    assert samples[("weldcell_seams_welded_total", ())] == view["report"]["seams_welded"]
    status, page = request(f"{base}/")
    assert status == 200 and '<div id="state" data-testid="state">' in page
    status, png = request(f"{base}/status.png")
    assert status == 200 and png[:8] == b"\x89PNG\r\n\x1a\n"
    assert request(f"{base}/jobs/999")[0] == 404


@pytest.mark.timeout(90)
def test_an_unclean_stop_holds_the_cell_in_fault_over_restarts_until_acknowledged(tmp_path: Path) -> None:
    config = cell_config(tmp_path, "sim-cell-fanuc.toml", daemon={"port": 0})
    with Journal(config.resolve(config.daemon.journal)) as journal:  # a process that died while its job welded
        crashed = journal.submit("ribs.toml")
        journal.record_state_change(crashed, "idle", "homing", "job started", job_state="running")
    for start in ("first", "second"):  # the second start: nobody acknowledged after the first
        with Daemon(config) as d:
            host, port = d.address
            base = f"http://{host}:{port}"
            st = request(f"{base}/status")[1]
            assert st["state"] == "fault", start
            assert st["fault_reason"].startswith(f"unclean stop: job {crashed} was running"), start
            assert st["fault_reason"].endswith("then acknowledge (POST /acknowledge)")
            X_before = d.cell.robot.get_X_base_tool()
            status, answer = request(f"{base}/jobs?dry_run=1", method="POST", body=job_text().encode())
            assert status == 201, answer
            time.sleep(0.5)  # what would move, would have begun by now
            assert job_state(base, int(answer["id"])) == "queued"
            assert (d.cell.robot.get_X_base_tool() == X_before).all()  # not a micrometre
    with Daemon(config) as d:  # acknowledged: the queue runs, and the next start is clean
        host, port = d.address
        base = f"http://{host}:{port}"
        assert request(f"{base}/status")[1]["state"] == "fault"
        status, answer = request(f"{base}/acknowledge", method="POST", body=b'{"operator": "ann"}')
        assert status == 200 and answer["state"] == "idle", answer
    with Daemon(config) as d:
        host, port = d.address
        assert request(f"http://{host}:{port}/status")[1]["state"] == "idle"


@pytest.mark.timeout(30)
def test_a_configured_token_is_required_and_a_non_loopback_host_needs_one(tmp_path: Path) -> None:
    data = tomllib.loads((EXAMPLES / "sim-cell-fanuc.toml").read_text(encoding="utf-8"))
    data["daemon"]["host"] = "0.0.0.0"
    with pytest.raises(ConfigError, match=r"daemon: host = '0\.0\.0\.0' is not a loopback address: set 'token'"):
        config_from_dict(data, source="cell.toml")

    config = cell_config(tmp_path, "sim-cell-fanuc.toml", daemon={"port": 0, "token": TOKEN})
    with Daemon(config) as d:
        host, port = d.address
        base = f"http://{host}:{port}"
        for headers in ({}, {"Authorization": "Bearer wrong-token-wrong-token"}, {"Authorization": TOKEN}):
            status, answer = request(f"{base}/status", headers=headers)
            assert status == 401 and "bearer token" in answer["error"]
        status, _ = request(f"{base}/jobs", method="POST", body=job_text().encode())
        assert status == 401
        auth = {"Authorization": f"Bearer {TOKEN}"}
        status, st = request(f"{base}/status", headers=auth)
        assert status == 200 and st["state"] == "idle"
        status, answer = request(f"{base}/jobs?dry_run=1", method="POST", body=job_text().encode(), headers=auth)
        assert status == 201 and answer["dry_run"] is True


@pytest.mark.timeout(30)
def test_fault_injection_is_off_by_default_and_refused_next_to_real_hardware(
    daemon: tuple[Daemon, str], tmp_path: Path
) -> None:
    _, base = daemon
    assert request(f"{base}/status")[1]["sim_faults"] is False
    for method, body in (("GET", None), ("POST", b'{"device": "robot", "fault": "protective_stop"}')):
        status, answer = request(f"{base}/sim/faults", method=method, body=body)
        assert status == 404 and "no such resource /sim/faults" in answer["error"]
    status, _ = request(f"{base}/sim/faults/clear", method="POST", body=b"{}")
    assert status == 404

    # a real device in the config: refused before the journal is opened or anything connects
    real = cell_config(tmp_path / "real", "sim-cell-fanuc.toml", robot={"kind": "fanuc", "port": 16001})
    with pytest.raises(
        ConfigError, match=r"--sim-faults is for simulated cells only, and robot.kind = 'fanuc' is real"
    ):
        Daemon(real, sim_faults=True)
    assert not (tmp_path / "real" / "journal.sqlite3").exists()
    # simulators of another process (weldcell sim up): their switches are not ours to throw
    fake = cell_config(tmp_path / "sims", "sim-cell-fanuc.toml", robot={"port": 16001}, track={"port": 5020})
    with pytest.raises(ConfigError, match="cannot be combined with --no-sims"):
        Daemon(fake, start_simulators=False, sim_faults=True)
    with build_cell(fake) as cell, pytest.raises(ConfigError, match="needs the simulators in this process"):
        cell.fault_injectors()


# ---------------------------------------------------------------------------------------------- subprocess
class Served:
    """``weldcell serve --no-sims`` as a child process, connected to simulators this test process runs."""

    def __init__(self, config: Path) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "cell.cli", "serve", "--config", str(config), "--no-sims"],
            cwd=REPO,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def wait_line(self, marker: str, timeout_s: float) -> str:
        deadline = time.monotonic() + timeout_s
        seen = []
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                if self.proc.poll() is not None:
                    break
                continue
            seen.append(line)
            if marker in line:
                return line
        raise AssertionError(f"no {marker!r} within {timeout_s} s: {seen}")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self.reader.join(timeout=2)


def served_config(tmp_path: Path) -> tuple[Path, CellConfig]:
    """The FANUC example on free fixed ports (the simulators run here, the daemon in a child process)."""
    return config_from_example(tmp_path, "sim-cell-fanuc.toml", {"port = 16001": f"port = {free_port()}"})


def config_from_example(tmp_path: Path, example: str, replacements: dict[str, str]) -> tuple[Path, CellConfig]:
    """``examples/<example>`` with each key of ``replacements`` (found exactly once) replaced, as tmp_path/cell.toml;
    the port, speed, journal and status image lines that every served config changes are replaced too."""
    text = (EXAMPLES / example).read_text(encoding="utf-8")
    text = re.sub(r'(?m)^journal = "[^"]*"', f'journal = "{tmp_path / "journal.sqlite3"}"', text, count=1)
    text = re.sub(r'(?m)^status_image = "[^"]*"', f'status_image = "{tmp_path / "status.png"}"', text, count=1)
    common = {
        "port = 5020": f"port = {free_port()}",
        "port = 8765": f"port = {free_port()}",
        "speed_m_s = 0.1                # default tool speed": "speed_m_s = 0.5",
        "max_speed_m_s = 0.30": "max_speed_m_s = 0.6",
    }
    text = replace_each_once(text, {**common, **replacements}.items())
    path = tmp_path / "cell.toml"
    path.write_text(text, encoding="utf-8")
    return path, load_config(path)


@pytest.fixture
def sims(tmp_path: Path) -> Iterator[tuple[Path, CellConfig, Simulators]]:
    path, config = served_config(tmp_path)
    with start_simulators(config) as running:
        yield path, config, running


def submit_and_wait_for_the_arc(base: str, sims: Simulators) -> int:
    status, answer = request(
        f"{base}/jobs", method="POST", body=job_text(min_length_m=0.1, travel_speed_m_s=0.05).encode()
    )
    assert status == 201, answer
    job_id = int(answer["id"])

    def arc_on() -> bool:
        view = request(f"{base}/jobs/{job_id}")[1]
        assert view["state"] in ("queued", "running"), view["error"]  # a job that ended before the arc: why
        return bool(sims.robot.digital_output(1))

    wait_for(arc_on, timeout_s=30, what="arc on")
    return job_id


@pytest.mark.timeout(60)
def test_sigterm_while_welding_stops_the_motion_and_leaves_the_arc_off(
    sims: tuple[Path, CellConfig, Simulators], tmp_path: Path
) -> None:
    path, config, running = sims
    served = Served(path)
    try:
        served.wait_line("listening on", timeout_s=30)
        base = f"http://127.0.0.1:{config.daemon.port}"
        job_id = submit_and_wait_for_the_arc(base, running)
        served.proc.send_signal(signal.SIGTERM)
        assert served.proc.wait(timeout=20) == 0
        assert not running.robot.digital_output(1)  # arc off
        assert running.robot.in_flight() == 0  # no motion left queued
        position = running.robot.xyzwpr_mm_deg()
        time.sleep(0.2)
        assert running.robot.xyzwpr_mm_deg() == position  # standing still
    finally:
        served.close()
    with Journal(tmp_path / "journal.sqlite3") as journal:
        assert journal.interrupted == ()
        record = journal.job(job_id)
        assert record.state == "failed" and record.error is not None and "SIGTERM" in record.error


@pytest.mark.timeout(120)
def test_a_daemon_killed_mid_weld_leaves_the_arc_off_and_restarts_in_fault_until_acknowledged(
    sims: tuple[Path, CellConfig, Simulators],
) -> None:
    path, config, running = sims
    fanuc = running.robot
    served = Served(path)
    try:
        served.wait_line("listening on", timeout_s=30)
        base = f"http://127.0.0.1:{config.daemon.port}"
        job_id = submit_and_wait_for_the_arc(base, running)
        t_kill = time.monotonic()
        served.proc.kill()  # SIGKILL: no chance to clean up
        # the controller's heartbeat watchdog (WC_HBEAT on the fake FANUC) switches the arc off, not the host
        wait_for(lambda: not fanuc.digital_output(1), timeout_s=1.0, what="arc off after kill -9")
        arc_off_s = time.monotonic() - t_kill
        assert arc_off_s < 1.0
        served.proc.wait(timeout=10)
    finally:
        served.close()
    position = fanuc.xyzwpr_mm_deg()
    restarted = Served(path)
    try:
        assert f"job {job_id}" in restarted.wait_line("was interrupted", timeout_s=30)
        base = f"http://127.0.0.1:{config.daemon.port}"
        wait_for(lambda: request(f"{base}/status")[0] == 200, timeout_s=10, what="the restarted daemon")
        assert not fanuc.digital_output(1)
        st = request(f"{base}/status")[1]
        # an unclean stop: the cell starts in fault, and nothing moves before an operator has acknowledged
        assert st["state"] == "fault" and "unclean stop" in st["fault_reason"] and str(job_id) in st["fault_reason"]
        assert st["current_job"] is None and st["queued"] == []
        assert [j["id"] for j in st["interrupted"]] == [job_id]
        assert job_state(base, job_id) == "interrupted"
        status, answer = request(f"{base}/jobs?dry_run=1", method="POST", body=job_text().encode())
        assert status == 201, answer
        waiting = int(answer["id"])
        time.sleep(1.0)
        assert job_state(base, waiting) == "queued"
        assert fanuc.xyzwpr_mm_deg() == position  # not a millimetre
        t_ack = time.time()
        status, answer = request(f"{base}/acknowledge", method="POST", body=b'{"operator": "ann"}')
        assert status == 200 and answer["state"] == "idle", answer
        # now it runs (a dry run from where the torch stands, on the part: it finds no depth there, which is fine)
        view = wait_for(lambda: finished_job(base, waiting), timeout_s=60, what="the job after acknowledging")
        assert view["started_s"] >= t_ack - 0.5 and view["report"]["dry_run"] is True
    finally:
        restarted.proc.send_signal(signal.SIGTERM)
        restarted.proc.wait(timeout=20)
        restarted.close()
