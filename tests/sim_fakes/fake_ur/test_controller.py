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
