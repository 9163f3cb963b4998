"""sim_fakes/fake_ur/server.py: the script ports' program framing.

No fake process here: tests/drivers/test_ur.py runs the whole fake against the real ur-rtde client.
"""

from __future__ import annotations

from sim_fakes.fake_ur.server import split_programs


def test_programs_on_the_script_ports_are_framed_by_def_and_end() -> None:
    buffer = "textmsg(1)\ndef a():\n  x = 1\nend\nsec b():\nend\ndef c():\n  y"
    programs, rest, dropped = split_programs(buffer)
    assert programs == [("a", "def a():\n  x = 1\nend\n"), ("b", "sec b():\nend\n")]
    assert rest == "def c():\n  y" and dropped == ["textmsg(1)"]
