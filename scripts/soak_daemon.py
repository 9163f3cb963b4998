"""``weldcell serve`` as the soak's child process, and the soak's HTTP client (scripts/soak.py)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


# ================================================================================================ the daemon
class ServedDaemon:
    """``weldcell serve --config CONFIG --port 0 --sim-faults`` as a child process; its output goes to ``log``; with
    ``memory_log`` it records its memory after each job there (``WELDCELL_MEMORY_SNAPSHOTS``, cell/memory.py)."""

    def __init__(self, config: Path, log: Path, *, memory_log: Path | None = None) -> None:
        exe = Path(sys.executable).with_name("weldcell")
        cmd = [str(exe)] if exe.is_file() else [sys.executable, "-m", "cell.cli"]
        self.cmd = [*cmd, "serve", "--config", str(config), "--port", "0", "--sim-faults"]
        self.log = log.open("w", encoding="utf-8")
        self.proc = subprocess.Popen(
            self.cmd,
            cwd=REPO,
            env={
                **os.environ,
                "PYTHONUNBUFFERED": "1",
                **({"WELDCELL_MEMORY_SNAPSHOTS": str(memory_log)} if memory_log is not None else {}),
            },
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        self.exit_s: float | None = None
        self._new_line = threading.Condition()
        self._reader = threading.Thread(target=self._read, name="soak-daemon-output", daemon=True)
        self._reader.start()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.log.write(line)
            self.log.flush()
            with self._new_line:
                self.lines.append(line.rstrip("\n"))
                self._new_line.notify_all()
        with self._new_line:
            self._new_line.notify_all()

    def wait_line(self, pattern: str, timeout_s: float) -> re.Match[str]:
        """The first output line matching ``pattern`` (a regex), waiting up to ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        seen = 0
        with self._new_line:
            while True:
                for line in self.lines[seen:]:
                    found = re.search(pattern, line)
                    if found:
                        return found
                seen = len(self.lines)
                left = deadline - time.monotonic()
                if left <= 0 or (self.proc.poll() is not None and not self._reader.is_alive()):
                    tail = "\n".join(self.lines[-15:])
                    raise RuntimeError(f"the daemon printed no {pattern!r} within {timeout_s:.0f} s:\n{tail}")
                self._new_line.wait(min(left, 0.5))

    def proc_status(self) -> tuple[float, int]:
        """(resident memory MiB, threads) of the daemon now, from /proc/PID/status."""
        fields = {}
        for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
            name, _, rest = line.partition(":")
            fields[name] = rest.split()
        return int(fields["VmRSS"][0]) / 1024.0, int(fields["Threads"][0])

    def settled_status(self, *, hold_s: float = 0.5, limit_s: float = 5.0) -> tuple[float, int]:
        """The daemon's (RSS, threads) once its thread count has held for ``hold_s``: the last requests'
        handler threads end some time after their answer, later on a loaded machine (a fixed 0.3 s wait saw
        one still alive under CI load). A leaked thread never ends, so it still shows after ``limit_s``."""
        rss, threads = self.proc_status()
        t_end = time.monotonic() + limit_s
        held_since = time.monotonic()
        while time.monotonic() < t_end and time.monotonic() - held_since < hold_s:
            time.sleep(0.1)
            rss, now = self.proc_status()
            if now != threads:
                threads, held_since = now, time.monotonic()
        return rss, threads

    def stop(self, timeout_s: float = 60.0) -> int:
        """SIGTERM, then wait for the exit code (after ``timeout_s`` SIGUSR1, so that the daemon's log shows where
        each of its threads waits, then SIGKILL: the code is negative). :attr:`exit_s` says how long it took."""
        t0 = time.monotonic()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.send_signal(signal.SIGUSR1)  # weldcell serve prints every thread's stack
                time.sleep(2.0)
                self.proc.kill()
                self.proc.wait(timeout=10)
        self.exit_s = time.monotonic() - t0
        self._reader.join(timeout=5)
        return int(self.proc.returncode)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self._reader.join(timeout=5)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self.log.close()


class Client:
    """JSON over HTTP to the daemon at ``base`` (with its bearer ``token`` if it has one)."""

    def __init__(self, base: str, token: str | None = None) -> None:
        self.base = base
        self.headers = {"Authorization": f"Bearer {token}"} if token else {}

    def call(
        self,
        method: str,
        path: str,
        body: bytes | None = None,
        content_type: str = "application/json",
        extra_headers: dict[str, str] | None = None,
    ) -> Any:
        """(status, decoded JSON body)."""
        headers = {**self.headers, **(extra_headers or {})}
        if body is not None:
            headers["Content-Type"] = content_type
        req = urllib.request.Request(self.base + path, data=body, method=method, headers=headers)
        try:
            with urllib.request.urlopen(req, timeout=30) as resp:
                status, data = resp.status, resp.read()
        except urllib.error.HTTPError as err:
            status, data = err.code, err.read()
        return status, (json.loads(data) if data[:1] in (b"{", b"[") else data.decode())

    def get(self, path: str) -> Any:
        status, answer = self.call("GET", path)
        if status != 200:
            raise RuntimeError(f"GET {path}: {status} {answer}")
        return answer

    def post(self, path: str, obj: Any) -> tuple[int, Any]:
        status, answer = self.call("POST", path, json.dumps(obj).encode())
        return int(status), answer
