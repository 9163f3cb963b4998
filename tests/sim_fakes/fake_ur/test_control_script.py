"""sim_fakes/fake_ur/control_script.py: the path ur-rtde injects into its control script.

No fake process here: tests/drivers/test_ur.py runs the whole fake against the real ur-rtde client.
"""

from __future__ import annotations

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
