"""sim_fakes/fake_ur/controller.py: the controller's dashboard answers.

No fake process here: tests/drivers/test_ur.py runs the whole fake against the real ur-rtde client.
"""

from __future__ import annotations

from sim_fakes.fake_ur.controller import Controller, FakeURConfig


def test_the_dashboard_answers_as_a_cb3_does() -> None:
    ctl = Controller(FakeURConfig(host="127.0.0.1"))
    assert ctl.dashboard("robotmode") == "Robotmode: RUNNING"
    assert ctl.dashboard("safetystatus") == "Safetystatus: NORMAL"
    assert ctl.dashboard("PolyscopeVersion") == "URSoftware 3.15.8.106339 (Jan 01 2024)"
    assert ctl.dashboard("is in remote control").startswith("could not understand")  # a CB3 has no such command


def test_the_rtde_watchdog_counts_the_controllers_running_time_not_its_own_stalls() -> None:
    # The host kicks every 50 ms; the fake's process is not scheduled for 0.35 s (a loaded machine), and its first
    # cycle after that runs before the kicks queued in its socket are read: no trip. Once the host is silent, the
    # program stops after 0.3 s of the controller's cycles, and the event says how long it was silent.
    import time

    from drivers.ur_protocol import RUNTIME_PLAYING, RUNTIME_STOPPED
    from sim_fakes.fake_ur.control_script import ControlScript

    ctl = Controller(FakeURConfig(host="127.0.0.1", program_stop_outputs_low=(0,)))
    ctl.program = ControlScript("def rtde_control():\nend\n", 0.0)
    ctl.runtime_state, ctl.digital_out = RUNTIME_PLAYING, 1
    ctl.set_rtde_watchdog("input_int_register_0", 1.0 / 0.3, "stop")
    kick = {"input_int_register_0": 0}
    for cycle in range(40):  # 0.32 s of 8 ms cycles, kicked every 6th
        ctl.tick(0.008)
        if cycle % 6 == 5:
            ctl.apply_inputs(kick)
    time.sleep(0.35)  # the fake's process stands still
    ctl.tick(0.05)  # its late cycle (the server passes at most 50 ms) ...
    for _ in range(7):
        ctl.apply_inputs(kick)  # ... and only then the kicks that came meanwhile
    assert ctl.runtime_state == RUNTIME_PLAYING
    assert not [e for e in ctl.log.events if e["kind"] == "rtde_watchdog"]
    for _ in range(37):  # the host goes silent: 0.296 s
        ctl.tick(0.008)
    assert ctl.runtime_state == RUNTIME_PLAYING
    ctl.tick(0.008)  # 0.304 s
    assert ctl.runtime_state == RUNTIME_STOPPED and ctl.digital_out == 0
    (trip,) = [e for e in ctl.log.events if e["kind"] == "rtde_watchdog"]
    assert abs(trip["silent_s"] - 0.304) < 1e-9 and trip["action"] == "stop"
