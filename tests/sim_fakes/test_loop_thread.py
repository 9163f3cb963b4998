"""The fakes' shared loop thread (sim_fakes/loop_thread.py): start, calls on the loop, bind failures, stop."""

from __future__ import annotations

import asyncio
import concurrent.futures
import socket
import threading

import pytest

from sim_fakes.loop_thread import LoopThreadFake


class EchoFake(LoopThreadFake):
    """A one-line echo server on loopback: just enough of a fake to drive the base class."""

    fake_name = "echo fake"

    def __init__(self, port: int = 0) -> None:
        super().__init__()
        self.want_port = port
        self.server: asyncio.Server | None = None
        self.closed = 0

    async def _setup(self, ready: concurrent.futures.Future[int]) -> None:
        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            writer.write(await reader.readline())
            await writer.drain()
            writer.close()

        self.server = await asyncio.start_server(serve, "127.0.0.1", self.want_port)
        ready.set_result(self.server.sockets[0].getsockname()[1])

    async def _close_servers(self) -> None:
        assert self.server is not None
        self.server.close()
        await self.server.wait_closed()
        self.closed += 1


@pytest.mark.timeout(20)
def test_start_blocks_until_listening_and_calls_run_on_the_loops_thread() -> None:
    with EchoFake() as fake:
        assert fake.port > 0
        with socket.create_connection(("127.0.0.1", fake.port), timeout=5.0) as sock:
            sock.sendall(b"weld\n")
            assert sock.makefile("rb").readline() == b"weld\n"
        assert fake._call(lambda: threading.current_thread().name) == "echo-fake"
        assert fake._call(lambda: 6 * 7) == 42
        with pytest.raises(RuntimeError, match="echo fake already started"):
            fake.start()
    assert fake.closed == 1 and fake._thread is None
    fake.stop()  # a second stop is a no-op
    assert fake.closed == 1
    with pytest.raises(RuntimeError, match=r"echo fake is not running; call start\(\) first"):
        fake._call(lambda: 1)
    with pytest.raises(OSError), socket.create_connection(("127.0.0.1", fake.port), timeout=2.0):
        pass  # nothing listens any more


@pytest.mark.timeout(20)
def test_a_bind_failure_is_raised_by_start_and_leaves_the_fake_stopped() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        fake = EchoFake(port=taken.getsockname()[1])
        with pytest.raises(OSError, match="address already in use"):
            fake.start()
    assert fake._thread is None and fake._loop is None and fake.port == 0
    with EchoFake() as again:  # and the class still starts on a free port afterwards
        assert again.port > 0


@pytest.mark.timeout(20)
def test_a_call_that_raises_raises_in_the_caller_and_the_loop_keeps_serving() -> None:
    def boom() -> int:
        raise ValueError("no such register")

    with EchoFake() as fake:
        with pytest.raises(ValueError, match="no such register"):
            fake._call(boom)
        assert fake._call(lambda: "still here") == "still here"
