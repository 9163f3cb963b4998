"""sim_fakes/process_fake.py: a fake's handle starts its child, asks it with a deadline and stops it."""

from __future__ import annotations

from multiprocessing.connection import Connection

import pytest

from sim_fakes.process_fake import ProcessFake


def echo_child(conn: Connection, greeting: str) -> None:
    """Ready with ``greeting``; answers ("echo", x) with x, ("fail",) with an error, ("hang",) never."""
    if greeting == "refuse":
        conn.send(("error", "port taken"))
        return
    conn.send(("ready", greeting))
    while True:
        try:
            request = conn.recv()
        except EOFError:
            return
        if request[0] == "shutdown":
            conn.send(("ok", None))
            return
        if request[0] == "echo":
            conn.send(("ok", request[1]))
        elif request[0] == "fail":
            conn.send(("error", "ValueError: no such fault"))


class Echo(ProcessFake):
    def __init__(self, greeting: str) -> None:
        super().__init__(echo_child, (greeting,), label="echo fake", startup_timeout_s=20.0, request_timeout_s=0.3)
        self.greeting = ""

    def _on_ready(self, detail: object) -> None:
        self.greeting = str(detail)


@pytest.mark.timeout(60)
def test_a_process_fake_answers_errs_times_out_and_stops() -> None:
    with Echo("hello") as fake:
        assert fake.greeting == "hello"
        assert fake._request("echo", [1, 2.5]) == [1, 2.5]
        with pytest.raises(ValueError, match="no such fault"):
            fake._request("fail")
        with pytest.raises(TimeoutError, match=r"echo fake did not answer 'hang' within 0\.3 s"):
            fake._request("hang")
        proc = fake._proc
    assert proc is not None and not proc.is_alive() and fake._proc is None
    with pytest.raises(RuntimeError, match="echo fake is not running"):
        fake._request("echo", 1)
    with pytest.raises(RuntimeError, match="echo fake could not start: port taken"):
        Echo("refuse").start()
