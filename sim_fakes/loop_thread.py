"""A fake device whose state lives on its own asyncio loop, run in a daemon thread.

Subclasses implement ``_setup`` (open the listening server(s) on the loop and report the bound port)
and ``_close_servers`` (close them and their client connections); everything else, starting, stopping,
running a function on the loop and the context manager, is shared.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import threading
from collections.abc import Callable
from typing import Self, TypeVar

T = TypeVar("T")


class LoopThreadFake:
    #: Name of the loop thread and of the fake in messages.
    fake_name = "fake device"

    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self.port = 0

    async def _setup(self, ready: concurrent.futures.Future[int]) -> None:
        """Open the server(s) on the running loop; ``ready.set_result(bound_port)`` when listening."""
        raise NotImplementedError

    async def _close_servers(self) -> None:
        """Close the server(s) and every client connection (runs on the loop)."""
        raise NotImplementedError

    def start(self) -> Self:
        """Start the loop thread and block until the fake listens (or raise why it cannot)."""
        if self._thread is not None:
            raise RuntimeError(f"{self.fake_name} already started")
        loop = asyncio.new_event_loop()
        ready: concurrent.futures.Future[int] = concurrent.futures.Future()

        def run() -> None:
            asyncio.set_event_loop(loop)
            try:
                loop.run_until_complete(self._setup(ready))
            except BaseException as err:  # report a bind failure to start()
                if not ready.done():
                    ready.set_exception(err)
                loop.close()
                return
            loop.run_forever()
            loop.close()

        self._loop = loop
        self._thread = threading.Thread(target=run, name=self.fake_name.replace(" ", "-"), daemon=True)
        self._thread.start()
        try:
            self.port = ready.result(timeout=5.0)
        except BaseException:
            self._thread.join(timeout=5.0)
            self._loop = None
            self._thread = None
            raise
        return self

    def stop(self) -> None:
        """Close every socket, stop the loop and join its thread. Safe to call twice."""
        loop, thread = self._loop, self._thread
        if loop is None or thread is None:
            return
        if loop.is_running():
            with contextlib.suppress(concurrent.futures.TimeoutError, RuntimeError):
                asyncio.run_coroutine_threadsafe(self._shutdown(), loop).result(timeout=5.0)
            loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout=5.0)
        self._loop = None
        self._thread = None

    async def _shutdown(self) -> None:
        await self._close_servers()
        current = asyncio.current_task()
        tasks = [t for t in asyncio.all_tasks() if t is not current]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    def _call(self, fn: Callable[[], T], *, timeout_s: float = 5.0) -> T:
        """Run ``fn`` on the fake's loop (where all its state lives) and return its result."""
        loop = self._loop
        if loop is None:
            raise RuntimeError(f"{self.fake_name} is not running; call start() first")

        async def call() -> T:
            return fn()

        return asyncio.run_coroutine_threadsafe(call(), loop).result(timeout=timeout_s)

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
