"""The fake FANUC in a process of its own (sim_fakes/fake_fanuc_process.py): the handle forwards to the fake."""

from __future__ import annotations

import os

import pytest

from drivers.fanuc import FanucRobot
from sim_fakes.fake_fanuc import DEFAULT_START_XYZWPR_MM_DEG
from sim_fakes.fake_fanuc_process import FakeFanucProcess
from sim_fakes.fanuc_program import HeartbeatProgram
from sim_fakes.faults import FaultInjectable


@pytest.mark.timeout(60)
def test_the_fake_runs_in_its_own_process_and_its_handle_answers_for_it() -> None:
    with FakeFanucProcess(heartbeat=HeartbeatProgram(90, 0.3, (1,))) as fake:
        assert isinstance(fake, FaultInjectable) and fake.port > 0
        assert fake._proc is not None and fake._proc.pid != os.getpid()
        assert fake.xyzwpr_mm_deg() == pytest.approx(DEFAULT_START_XYZWPR_MM_DEG)
        robot = FanucRobot("127.0.0.1", port=fake.port, heartbeat_register=90)
        robot.connect()
        try:
            robot.set_digital_output(0, True)  # output 0 is DO[1]
            assert fake.digital_output(1) is True
            [write] = [e for e in fake.events() if e["kind"] == "dout"]
            assert (write["port"], write["value"]) == (1, True)
            assert write["xyz_mm"] == pytest.approx(DEFAULT_START_XYZWPR_MM_DEG[:3])
            robot.set_digital_output(0, False)
        finally:
            robot.disconnect()
        with pytest.raises(ValueError, match="does not support fault 'earthquake'"):
            fake.inject("earthquake")
        with pytest.raises(AttributeError, match="no method '_cmd_write_dout'"):
            fake._call("_cmd_write_dout", {})
    assert fake._proc is None
    with pytest.raises(RuntimeError, match="not running"):
        fake.digital_output(1)
