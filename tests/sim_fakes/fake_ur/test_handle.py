"""sim_fakes/fake_ur/handle.py: the handle's checks before it starts a process.

No fake process here: tests/drivers/test_ur.py runs the whole fake against the real ur-rtde client.
"""

from __future__ import annotations

import pytest

from sim_fakes.fake_ur import FakeURController


def test_the_handle_refuses_what_the_fake_cannot_be_before_starting_a_process() -> None:
    with pytest.raises(ValueError, match="only serves on loopback addresses"):
        FakeURController("192.168.1.5")
    with pytest.raises(ValueError, match="unknown robot model"):
        FakeURController("127.0.0.1", model="UR3")
    with pytest.raises(ValueError, match="q_home needs 6 joint angles"):
        FakeURController("127.0.0.1", q_home=(0.0,) * 5)
    with pytest.raises(ValueError, match="standard outputs are 0-7"):
        FakeURController("127.0.0.1", program_stop_outputs_low=(8,))
