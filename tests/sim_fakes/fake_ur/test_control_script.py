"""sim_fakes/fake_ur/control_script.py: the path ur-rtde injects into its control script.

No fake process here: tests/drivers/test_ur.py runs the whole fake against the real ur-rtde client.
"""

from __future__ import annotations

import time

import numpy as np

from sim_fakes.fake_ur import Waypoint
from sim_fakes.fake_ur.control_script import parse_injected_path


def test_the_path_ur_rtde_injects_into_its_control_script() -> None:
    script = (
        "def rtde_control():\n# inject move path\n"
        "\tmovel(p[0.1,0.2,0.3,0.0,3.14,0.0],a=1.2,v=0.25,r=0.0)\n\tsignal_async_progress(0)\n"
        "\tmovel(p[0.2,0.2,0.3,0.0,3.14,0.0],a=1.2,v=0.25,r=0.01)\nend\n"
    )
    path, error = parse_injected_path(script)
    assert error == ""
    assert path == [
        Waypoint((0.1, 0.2, 0.3, 0.0, 3.14, 0.0), 0.25, 1.2, 0.0),
        Waypoint((0.2, 0.2, 0.3, 0.0, 3.14, 0.0), 0.25, 1.2, 0.01),
    ]
    _, error = parse_injected_path("# inject move path\n\tmovej([0,0,0,0,0,0],a=1,v=1,r=0)\n")
    assert error == "movej with joint angles in a path is not emulated"
    assert parse_injected_path("def other():\nend\n") == ([], "")


def test_a_move_waits_unanswered_while_its_reach_is_checked_and_the_cycle_goes_on() -> None:
    # the server checks a path's reach in a thread (Controller.reach_check): the command gets no "done" and the arm
    # does not move until the check answers; meanwhile the controller keeps cycling. A path out of reach halts the
    # program with the check's reason, as the check in the cycle did.
    from concurrent.futures import Future

    from drivers.ur_protocol import CMD_MOVEL, DONE_WITH_CMD, RUNTIME_PLAYING, RUNTIME_STOPPED
    from sim_fakes.fake_ur.controller import Controller, FakeURConfig
    from sim_fakes.fake_ur.kinematics import ur_pose

    for problem in ("", "no inverse kinematics solution on the way to waypoint 0 (pose [...])"):
        ctl = Controller(FakeURConfig(host="127.0.0.1"))
        checks: list[Future[str]] = []

        def held(segments: object, q: object, checks: list[Future[str]] = checks) -> Future[str]:
            checks.append(Future())
            return checks[-1]

        ctl.reach_check = held
        ctl.run_program("rtde_control", "def rtde_control():\nend\n")
        time.sleep(0.06)  # the script starts program_start_delay_s (0.05 s) after it arrived, and signals ready
        ctl.tick(0.008)
        ctl.tick(0.008)
        assert ctl.runtime_state == RUNTIME_PLAYING
        down = np.array([0.0, 0.0, -0.01])
        target = ur_pose(ctl.p + down, ctl.R)
        for i, v in enumerate(target):
            ctl.regs[f"input_double_register_{i}"] = v
        ctl.regs["input_double_register_6"], ctl.regs["input_double_register_7"] = 0.1, 1.0
        ctl.regs["input_int_register_1"] = 1  # asynchronous
        ctl.regs["input_int_register_0"] = CMD_MOVEL
        p0, t0 = ctl.p.copy(), ctl.now()
        for _ in range(5):
            ctl.tick(0.008)
        assert len(checks) == 1 and ctl.motion is None and np.array_equal(ctl.p, p0)
        assert ctl.regs["output_int_register_0"] != DONE_WITH_CMD
        checks[0].set_result(problem)
        ctl.tick(0.008)
        if problem:
            assert ctl.runtime_state == RUNTIME_STOPPED and ctl.log.errors == [problem]
        else:
            assert ctl.regs["output_int_register_0"] == DONE_WITH_CMD and ctl.motion is not None
            for _ in range(100):
                ctl.tick(0.008)
            np.testing.assert_allclose(ctl.p, p0 + down, atol=1e-9)
        assert ctl.now() > t0
