"""``weldcell serve`` killed with SIGKILL in the middle of a weld on the simulated UR5 cell: the controller's own
watchdog (``setWatchdog``/``kickWatchdog``, docs/controller-watchdogs.md) stops the program, and the installation
drives the arc output low, within 1 s; the restarted daemon starts in ``fault`` and moves nothing before an
operator acknowledges. The fake UR (in a process of its own) is the independent reader of the arc output.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from cell.config import CellConfig
from cell.factory import Simulators, start_simulators
from sim_fakes.loopback import free_loopback_host
from tests.cell.runner_rig import job_text
from tests.cell.test_daemon import Served, config_from_example, job_state, request, wait_for

pytest.importorskip("rtde_control", reason="the UR driver needs ur-rtde")

ARC = 0  # [welding] arc_output of job_text(): the UR's standard digital output 0


def served_ur_config(tmp_path: Path) -> tuple[Path, CellConfig]:
    """The UR5 example on this session's loopback address and free ports (simulators here, the daemon a child)."""
    return config_from_example(tmp_path, "sim-cell.toml", {'host = "127.0.0.41"': f'host = "{free_loopback_host()}"'})


@pytest.fixture
def ur_sims(tmp_path: Path) -> Iterator[tuple[Path, CellConfig, Simulators]]:
    path, config = served_ur_config(tmp_path)
    with start_simulators(config) as running:
        yield path, config, running


def arc_reads_on(running: Simulators) -> bool:
    return bool(running.robot.snapshot()["digital_outputs"][ARC])


@pytest.mark.timeout(180)
def test_a_daemon_killed_mid_weld_on_the_ur5_leaves_the_arc_off_and_restarts_in_fault_until_acknowledged(
    ur_sims: tuple[Path, CellConfig, Simulators],
) -> None:
    path, config, running = ur_sims
    base = f"http://127.0.0.1:{config.daemon.port}"
    served = Served(path)
    try:
        served.wait_line("listening on", timeout_s=60)
        body = job_text(min_length_m=0.1, travel_speed_m_s=0.05).encode()
        status, answer = request(f"{base}/jobs", method="POST", body=body)
        assert status == 201, answer
        job_id = int(answer["id"])

        def arc_on() -> bool:
            view = request(f"{base}/jobs/{job_id}")[1]
            assert view["state"] in ("queued", "running"), view["error"]
            return arc_reads_on(running)

        wait_for(arc_on, timeout_s=60, what="arc on")
        time.sleep(0.2)  # the arm travels along the seam with the arc on
        assert running.robot.snapshot()["moving"]
        t_kill = time.monotonic()
        served.proc.kill()  # SIGKILL: no chance to clean up
        wait_for(lambda: not arc_reads_on(running), timeout_s=1.0, what="arc off after kill -9")
        arc_off_s = time.monotonic() - t_kill
        wait_for(lambda: not running.robot.snapshot()["moving"], timeout_s=2.0, what="the arm stopped")
        stopped_s = time.monotonic() - t_kill
        served.proc.wait(timeout=10)
    finally:
        served.close()
    assert arc_off_s < 1.0, arc_off_s
    assert stopped_s < 2.0, stopped_s
    X_stopped = running.robot.X_base_tool()
    events = running.robot.events()
    stops = [e for e in events if e["kind"] == "digital_output" and "program stop" in e.get("cause", "")]
    assert [e["index"] for e in stops][-1:] == [ARC]
    # the controller's own watchdog drove it low, not the host: read from the controller's log, not from the time
    # since the kill (a host starved by a loaded machine may have missed its 0.3 s kick just before the kill)
    assert "RTDE watchdog" in stops[-1]["cause"], stops[-1]

    restarted = Served(path)
    try:
        assert f"job {job_id}" in restarted.wait_line("was interrupted", timeout_s=60)
        wait_for(lambda: request(f"{base}/status")[0] == 200, timeout_s=30, what="the restarted daemon")
        st = request(f"{base}/status")[1]
        assert st["state"] == "fault" and "unclean stop" in st["fault_reason"] and str(job_id) in st["fault_reason"]
        assert job_state(base, job_id) == "interrupted" and not arc_reads_on(running)
        status, answer = request(f"{base}/jobs?dry_run=1", method="POST", body=job_text().encode())
        assert status == 201, answer
        waiting = int(answer["id"])
        time.sleep(1.0)
        assert job_state(base, waiting) == "queued"
        np.testing.assert_allclose(running.robot.X_base_tool(), X_stopped, atol=1e-6)  # not a micrometre
        status, answer = request(f"{base}/acknowledge", method="POST", body=b'{"operator": "ann"}')
        assert status == 200 and answer["state"] == "idle", answer
        wait_for(lambda: job_state(base, waiting) != "queued", timeout_s=30, what="the job after acknowledging")
    finally:
        restarted.proc.send_signal(signal.SIGTERM)
        restarted.proc.wait(timeout=30)
        restarted.close()
