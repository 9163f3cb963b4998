"""The fake UR's network side: RTDE sessions, the dashboard and script ports, and the process entry point.

Part of :mod:`sim_fakes.fake_ur` (its docstring describes the fake as a whole).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import re
import time
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from drivers.priority import enter_io_process
from sim_fakes import rtde_wire as wire
from sim_fakes.fake_ur.controller import Controller, FakeURConfig
from sim_fakes.fake_ur.kinematics import SUPPORTED_FAULTS

log = logging.getLogger("sim_fakes.fake_ur")


class RtdeSession:
    """One RTDE client connection: its protocol version, recipes and streaming schedule."""

    def __init__(self, writer: asyncio.StreamWriter, cfg: FakeURConfig) -> None:
        self.writer = writer
        self.cfg = cfg
        self.protocol = 1
        self.outputs: list[wire.Recipe] = []
        self.due: list[float] = []
        self.inputs: dict[int, wire.Recipe] = {}
        # output and input recipes are numbered separately, both from 1 (ur-rtde relies on it)
        self.next_output_id = 1
        self.next_input_id = 1
        self.started = False

    def handle(self, msg_type: int, payload: bytes, ctl: Controller, now: float) -> bytes:
        M = wire.MsgType
        if msg_type == M.REQUEST_PROTOCOL_VERSION:
            version = int.from_bytes(payload[:2], "big") if len(payload) >= 2 else 0
            accepted = version in wire.PROTOCOL_VERSIONS
            if accepted:
                self.protocol = version
            return wire.pack_message(msg_type, bytes([int(accepted)]))
        if msg_type == M.GET_URCONTROL_VERSION:
            return wire.pack_message(msg_type, b"".join(v.to_bytes(4, "big") for v in self.cfg.controller_version))
        if msg_type == M.CONTROL_PACKAGE_SETUP_OUTPUTS:
            if self.protocol >= 2:
                frequency = float(np.frombuffer(payload[:8], dtype=">f8")[0]) if len(payload) >= 8 else 0.0
                names = wire.parse_names(payload[8:])
            else:
                frequency, names = self.cfg.rate_hz, wire.parse_names(payload)
            types = [wire.output_type(n, self.cfg.controller_version) for n in names]
            ok = bool(names) and wire.NOT_FOUND not in types and 0.0 < frequency <= self.cfg.rate_hz
            recipe = wire.Recipe.build(self.next_output_id if ok else 0, names, types, frequency)
            if ok:
                self.next_output_id += 1
                self.outputs.append(recipe)
                self.due.append(now)
            else:
                log.debug("output setup refused: %s at %s Hz", names, frequency)
            reply = wire.setup_reply(recipe)
            return wire.pack_message(msg_type, reply if self.protocol >= 2 else reply[1:])
        if msg_type == M.CONTROL_PACKAGE_SETUP_INPUTS:
            names = wire.parse_names(payload)
            types = [wire.INPUT_TYPES.get(n, wire.NOT_FOUND) for n in names]
            ok = bool(names) and wire.NOT_FOUND not in types
            recipe = wire.Recipe.build(self.next_input_id if ok else 0, names, types)
            if ok:
                self.inputs[recipe.recipe_id] = recipe
                self.next_input_id += 1
            return wire.pack_message(msg_type, wire.setup_reply(recipe))
        if msg_type == M.CONTROL_PACKAGE_START:
            self.started = True
            self.due = [now] * len(self.outputs)
            return wire.pack_message(msg_type, b"\x01")
        if msg_type == M.CONTROL_PACKAGE_PAUSE:
            self.started = False
            return wire.pack_message(msg_type, b"\x01")
        if msg_type == M.DATA_PACKAGE:
            recipe_in = self.inputs.get(payload[0]) if payload else None
            if recipe_in is None or len(payload) < recipe_in.layout.size:
                return wire.text_message(1, f"data package for unknown input recipe {payload[:1].hex()}")
            ctl.apply_inputs(recipe_in.unpack(payload))
            return b""
        if msg_type == M.TEXT_MESSAGE:
            return b""
        return wire.text_message(1, f"unknown RTDE message type {msg_type}")


def split_programs(buffer: str) -> tuple[list[tuple[str, str]], str, list[str]]:
    """Complete top-level ``def``/``sec`` programs in ``buffer`` as (name, text), the unconsumed rest, and the
    non-empty top-level lines outside any program (which the fake does not run)."""
    programs: list[tuple[str, str]] = []
    dropped: list[str] = []
    lines = buffer.split("\n")
    start = None
    consumed = 0
    pos = 0
    for i, line in enumerate(lines[:-1]):  # the last piece has no newline yet
        stripped = line.rstrip("\r")
        if start is None and re.match(r"(def|sec)\s+\w+\s*\(\s*\)\s*:", stripped):
            start = i
        elif start is not None and stripped == "end":
            text = "\n".join(lines[start : i + 1]) + "\n"
            m = re.match(r"(?:def|sec)\s+(\w+)", lines[start])
            programs.append((m.group(1) if m else "", text))
            start = None
            consumed = pos + len(line) + 1
        elif start is None:
            consumed = pos + len(line) + 1
            if stripped.strip():
                dropped.append(stripped.strip())
        pos += len(line) + 1
    return programs, buffer[consumed:], dropped


class FakeURServer:
    """The asyncio side of the fake: listening sockets, client sessions, the control cycle and the handle's pipe."""

    def __init__(self, cfg: FakeURConfig, conn: Connection) -> None:
        self.cfg = cfg
        self.conn = conn
        self.ctl = Controller(cfg)
        # paths are checked for reach in a thread, the control cycle streams on meanwhile (Controller.reach_check)
        self._planner = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="fake-ur-reach")
        self.ctl.reach_check = lambda segments, q: self._planner.submit(self.ctl.check_reachable, segments, q)
        self.servers: list[asyncio.base_events.Server] = []
        self.sessions: set[RtdeSession] = set()
        self.writers: set[asyncio.StreamWriter] = set()
        self.answering = asyncio.Event()
        self.answering.set()
        self.dropped = False
        self.no_answer_on_next_program = False  # no_answer injected to come with the next program's arrival
        self.finished = asyncio.Event()
        self.tasks: set[asyncio.Task[Any]] = set()

    async def open(self) -> None:
        host = self.cfg.host
        self.servers.append(await asyncio.start_server(self._rtde, host, self.cfg.rtde_port, reuse_address=True))
        self.servers.append(
            await asyncio.start_server(self._dashboard, host, self.cfg.dashboard_port, reuse_address=True)
        )
        for port in self.cfg.script_ports:
            self.servers.append(await asyncio.start_server(self._script, host, port, reuse_address=True))

    def close_servers(self) -> None:
        for server in self.servers:
            server.close()
        self.servers = []

    def drop_clients(self) -> None:
        for writer in list(self.writers):
            with contextlib.suppress(Exception):
                writer.transport.abort()
        self.writers.clear()
        self.sessions.clear()

    async def run(self) -> None:
        try:
            await self.open()
        except OSError as err:
            self.close_servers()
            self.conn.send(("error", f"cannot listen on {self.cfg.host}: {err}"))
            return
        loop = asyncio.get_running_loop()
        loop.add_reader(self.conn.fileno(), self._on_pipe)
        self.conn.send(("ready", None))
        ticker = asyncio.create_task(self._cycle())
        await self.finished.wait()
        ticker.cancel()
        loop.remove_reader(self.conn.fileno())
        self.close_servers()
        self.drop_clients()
        self._planner.shutdown(wait=False, cancel_futures=True)
        await asyncio.sleep(0.05)  # let the client handlers see their connections end

    async def _cycle(self) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / self.cfg.rate_hz
        next_t = loop.time()
        last = time.monotonic()
        while True:
            next_t += period
            delay = next_t - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            else:
                next_t = loop.time()
                await asyncio.sleep(0)
            now = time.monotonic()
            dt, last = min(now - last, 0.05), now
            try:
                self.ctl.tick(dt)  # the controller runs on while its network does not answer
                if self.answering.is_set():
                    self._stream()
            except Exception as err:  # a bug in the fake must be visible, not kill the controller silently
                log.exception("fake UR cycle failed")
                self.ctl.log.errors.append(f"internal error: {err!r}")

    def _stream(self) -> None:
        values: dict[str, Any] | None = None
        now = self.ctl.now()
        for session in list(self.sessions):
            if not session.started:
                continue
            transport = session.writer.transport
            if transport.is_closing():
                continue
            if transport.get_write_buffer_size() > 4_000_000:  # client stopped reading
                transport.abort()
                continue
            for i, recipe in enumerate(session.outputs):
                if now + 1e-4 < session.due[i]:
                    continue
                if values is None:
                    values = self.ctl.rtde_values()
                session.writer.write(recipe.pack(values))
                step = 1.0 / recipe.frequency_hz
                session.due[i] = session.due[i] + step if now - session.due[i] < step else now + step

    async def _serve_client(self, writer: asyncio.StreamWriter) -> bool:
        if self.dropped:
            writer.transport.abort()
            return False
        self.writers.add(writer)
        return True

    async def _rtde(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if not await self._serve_client(writer):
            return
        session = RtdeSession(writer, self.cfg)
        self.sessions.add(session)
        try:
            while True:
                size, msg_type = wire.HEADER.unpack(await reader.readexactly(wire.HEADER.size))
                if size < wire.HEADER.size:
                    break
                payload = await reader.readexactly(size - wire.HEADER.size)
                await self.answering.wait()
                if writer.transport.is_closing():
                    break
                reply = session.handle(msg_type, payload, self.ctl, self.ctl.now())
                if reply:
                    writer.write(reply)
        except (asyncio.IncompleteReadError, ConnectionError, asyncio.CancelledError):
            pass  # the client left, or the fake is shutting down
        finally:
            self.sessions.discard(session)
            self.writers.discard(writer)
            writer.close()

    async def _dashboard(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if not await self._serve_client(writer):
            return
        try:
            await self.answering.wait()
            writer.write(b"Connected: Universal Robots Dashboard Server\n")
            while True:
                line = await reader.readline()
                if not line:
                    break
                await self.answering.wait()
                if writer.transport.is_closing():
                    break
                text = line.decode("utf-8", errors="replace").strip()
                reply = self.ctl.dashboard(text)
                self.ctl.record("dashboard", command=text, reply=reply)
                writer.write(reply.encode("utf-8") + b"\n")
                if text.lower() == "quit":
                    break
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            self.writers.discard(writer)
            writer.close()

    async def _script(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if not await self._serve_client(writer):
            return
        buffer = ""
        try:
            while True:
                data = await reader.read(65536)
                if not data:
                    break
                await self.answering.wait()
                buffer += data.decode("utf-8", errors="replace")
                programs, buffer, dropped = split_programs(buffer)
                for line in dropped:
                    self.ctl.log.errors.append(f"script line outside a program not run: {line[:80]!r}")
                for name, text in programs:
                    if self.no_answer_on_next_program:  # the controller goes silent as the program arrives
                        self.no_answer_on_next_program = False
                        self.ctl.record("fault", fault="no_answer", cause=f"program {name!r} arrived")
                        self.answering.clear()
                        continue
                    self.ctl.run_program(name, text)
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            self.writers.discard(writer)
            writer.close()

    # ------------------------------------------------------------------ the handle's pipe
    def _on_pipe(self) -> None:
        try:
            while self.conn.poll():
                request = self.conn.recv()
                task = asyncio.get_running_loop().create_task(self._answer(request))
                self.tasks.add(task)
                task.add_done_callback(self.tasks.discard)
        except (EOFError, OSError):  # the handle's process is gone: nobody can stop us, so stop now
            self.finished.set()

    async def _answer(self, request: tuple[Any, ...]) -> None:
        try:
            result = await self._do(request)
            self.conn.send(("ok", result))
        except Exception as err:
            self.conn.send(("error", f"{type(err).__name__}: {err}"))

    async def _do(self, request: tuple[Any, ...]) -> Any:
        op = request[0]
        ctl = self.ctl
        if op == "inject":
            fault, params = request[1], request[2]
            if fault not in SUPPORTED_FAULTS:
                raise ValueError(f"fault {fault!r} not supported; choose from {sorted(SUPPORTED_FAULTS)}")
            unknown = set(params) - ({"on_next_program"} if fault in ("protective_stop", "no_answer") else set())
            if unknown:
                raise ValueError(f"fault {fault!r} takes no parameter {sorted(unknown)}")
            ctl.record("fault", fault=fault, **params)
            if fault == "drop_connection":
                self.dropped = True
                self.close_servers()
                self.drop_clients()
            elif fault == "no_answer" and params.get("on_next_program"):
                self.no_answer_on_next_program = True
            elif fault == "no_answer":
                self.answering.clear()
            elif fault == "protective_stop" and params.get("on_next_program"):
                ctl.protective_on_next_program = True
            elif fault == "protective_stop":
                ctl.protective_stop("injected")
            elif fault == "emergency_stop":
                ctl.emergency_stop()
            return None
        if op == "clear":
            ctl.record("faults_cleared")
            await self._clear_network_faults()
            ctl.estop_pressed = False
            return None
        if op == "reset":
            await self._clear_network_faults()
            self.drop_clients()
            ctl.reset()
            return None
        if op == "snapshot":
            return ctl.snapshot()
        if op == "log":
            return {"events": list(ctl.log.events), "errors": list(ctl.log.errors)}
        if op == "programs":
            return list(ctl.log.programs)
        if op == "set_digital_input":
            index, value = int(request[1]), bool(request[2])
            if value:
                ctl.digital_in |= 1 << index
            else:
                ctl.digital_in &= ~(1 << index)
            return None
        if op == "shutdown":
            self.finished.set()
            return None
        raise ValueError(f"unknown request {op!r}")

    async def _clear_network_faults(self) -> None:
        self.no_answer_on_next_program = False
        self.answering.set()
        if self.dropped:
            self.dropped = False
            await self.open()


def _serve(conn: Connection, cfg: FakeURConfig) -> None:
    """Entry point of the fake's process."""
    # it stands in for a controller that never misses a cycle: the same priority as the driver's worker, where allowed
    enter_io_process()
    logging.basicConfig(level=logging.WARNING)
    try:
        asyncio.run(FakeURServer(cfg, conn).run())
    finally:
        conn.close()
