"""The daemon's HTTP API (:mod:`cell.daemon`) on FastAPI/Starlette, served by uvicorn in a thread of its own.

Routes (the same as the hand-written server had; ``GET /openapi.json`` describes them)::

    POST /jobs, GET /jobs, GET /jobs/{id}, GET /jobs/{id}/export/{format}, POST /jobs/{id}/approve,
    POST /jobs/{id}/reject, POST /acknowledge, POST /pause, POST /resume, POST /abort, GET /status, GET /,
    GET /status.png, GET /metrics, and with ``--sim-faults`` GET /sim/faults, POST /sim/faults,
    POST /sim/faults/clear

What guards them, in order, for every request:

1. ``Host`` must name this daemon (its bound address, ``localhost``, ``127.0.0.1``, ``[::1]``, or one of
   ``[daemon] allowed_hosts``), with or without the port: a page from another site that rebinds its DNS name to the
   cell PC is refused (400).
2. With ``[daemon] token``, ``Authorization: Bearer <token>`` on every route, the OpenAPI document included (401),
   but ``GET /``: the operator page's HTML holds no data; the page sends the token with each of its requests.
3. Every request that changes state (POST) is refused (403) when it comes from a browser page of another origin:
   an ``Origin`` header that is not this daemon's own (or one of ``[daemon] allowed_origins``), or
   ``Sec-Fetch-Site: cross-site``. Clients that are not browsers send no ``Origin`` and are not affected.
4. Bodies: at most ``max_body_bytes`` (413, also for a chunked body that grows past it), read within
   ``request_timeout_s`` (408), of a type the route takes (415): ``application/json`` for the operator commands
   (a form-encoded body is refused there), JSON or a job's TOML text (``application/toml``, ``text/plain``) for
   ``POST /jobs``, where the ``application/x-www-form-urlencoded`` that curl -d and urllib send by default is read
   as TOML.

``HEAD`` is answered on every ``GET`` route as HTTP says: the status and headers ``GET`` would give, no body.

Errors are JSON ``{"error": "..."}`` with the right status (404 for an unknown path, 405 with ``Allow`` for a
wrong method, 500 for a bug, logged with its traceback here, never sent). The server side (uvicorn's h11 protocol)
frames each request by its ``Content-Length`` or chunked encoding, so an unread body is never parsed as the next
request; a request whose headers have not arrived within ``request_timeout_s`` gets ``408`` and the connection is
closed; at most ``max_connections`` connections are served at once (503 beyond).
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import json
import logging
import socket
import threading
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

import h11
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse, PlainTextResponse, Response
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException
from uvicorn.protocols.http.h11_impl import H11Protocol

from cell.errors import ConfigError, WeldcellError

if TYPE_CHECKING:
    from cell.daemon import Daemon
    from cell.sim_fault_api import SimFaultSwitch

logger = logging.getLogger(__name__)

MAX_JOB_ID = 2**63 - 1  # SQLite INTEGER
JSON_TYPES = ("application/json",)
JOB_TYPES = ("application/json", "application/toml", "text/plain", "text/x-toml", "application/x-www-form-urlencoded")


class HTTPError(Exception):
    """An error answered as ``{"error": message}`` with ``status`` (and extra headers)."""

    def __init__(self, status: int, message: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.message = message
        self.headers = headers or {}


def _error(status: int, message: str, headers: dict[str, str] | None = None) -> JSONResponse:
    headers = {"Cache-Control": "no-store", **(headers or {})}
    return JSONResponse({"error": message}, status_code=status, headers=headers)


# ============================================================================================== guards
def _split_host(value: str) -> str:
    """The host part of a ``Host`` header value (``[::1]:8765`` -> ``::1``), lower case."""
    value = value.strip().lower()
    if value.startswith("["):
        return value[1 : value.find("]")] if "]" in value else value
    return value.rsplit(":", 1)[0] if value.count(":") == 1 else value


class Guards:
    """Host, token, origin and body checks (see the module docstring)."""

    def __init__(self, daemon: Daemon, port: int) -> None:
        dc = daemon.config.daemon
        self.token = dc.token
        self.max_body_bytes = dc.max_body_bytes
        self.timeout_s = dc.request_timeout_s
        bound = dc.host.lower()
        self.hosts = {"localhost", "127.0.0.1", "::1", bound, *(h.lower() for h in dc.allowed_hosts)}
        with_port = {f"{h}:{port}" if ":" not in h else f"[{h}]:{port}" for h in self.hosts}
        self.origins = {f"http://{h}" for h in with_port} | {o.rstrip("/").lower() for o in dc.allowed_origins}
        if bound in ("0.0.0.0", "::"):  # bound to every interface: the configured allowed_hosts name it
            self.hosts.discard(bound)

    def host_ok(self, request: Request) -> bool:
        host = request.headers.get("host")
        return host is not None and _split_host(host) in self.hosts

    def authorized(self, request: Request) -> bool:
        if self.token is None:
            return True
        given = request.headers.get("authorization", "")
        return given.startswith("Bearer ") and hmac.compare_digest(given[7:].encode(), self.token.encode())

    def same_origin(self, request: Request) -> bool:
        if request.headers.get("sec-fetch-site", "").lower() == "cross-site":
            return False
        origin = request.headers.get("origin")
        return origin is None or origin.rstrip("/").lower() in self.origins

    async def body(self, request: Request, types: tuple[str, ...]) -> tuple[bytes, str]:
        """The request body (bounded in size and time) and its media type; HTTPError 413/415/408/400."""
        ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
        length = request.headers.get("content-length")
        if length is not None:
            if not length.isdigit():
                raise HTTPError(400, "Content-Length must be a number of bytes")
            if int(length) > self.max_body_bytes:
                raise HTTPError(413, f"the body is larger than the {self.max_body_bytes} bytes allowed")
        chunks: list[bytes] = []
        size = 0
        try:
            async with asyncio.timeout(self.timeout_s):
                async for chunk in request.stream():
                    size += len(chunk)
                    if size > self.max_body_bytes:
                        raise HTTPError(413, f"the body is larger than the {self.max_body_bytes} bytes allowed")
                    chunks.append(chunk)
        except TimeoutError as err:
            raise HTTPError(408, f"the body did not arrive within {self.timeout_s:.0f} s") from err
        body = b"".join(chunks)
        if body and ctype not in types:
            raise HTTPError(415, f"send the body as {' or '.join(types)}, not {ctype or 'no Content-Type'}")
        return body, ctype


# ============================================================================================== the app
PUBLIC_PATHS = frozenset({"/"})
"""Paths served without the token: the operator page's own HTML, which holds no data of the cell (the page asks for
the token and sends it with every request it makes, as any client does)."""


def build_app(daemon: Daemon, port: int) -> FastAPI:
    """The ASGI app of ``daemon`` listening on ``port`` (for the Host and Origin checks)."""
    guards = Guards(daemon, port)
    app = FastAPI(
        title="weldcell",
        summary="The welding cell's service: jobs, status, operator commands.",
        version="1",
        docs_url=None,
        redoc_url=None,
        openapi_url="/openapi.json",
    )

    @app.middleware("http")
    async def guard(request: Request, call_next: Callable[[Request], Awaitable[Response]]) -> Response:
        if not guards.host_ok(request):
            return _error(400, "the Host header does not name this cell's service")
        public = request.method in ("GET", "HEAD") and request.url.path in PUBLIC_PATHS
        if not public and not guards.authorized(request):
            return _error(
                401,
                "a bearer token is required: Authorization: Bearer <token>",
                {"WWW-Authenticate": 'Bearer realm="weldcell"'},
            )
        if request.method not in ("GET", "HEAD", "OPTIONS") and not guards.same_origin(request):
            return _error(403, "cross-origin requests may not change the cell's state")
        head = request.method == "HEAD"
        if head:  # routed as GET; the server (uvicorn) sends no body for a request it parsed as HEAD
            request.scope["method"] = "GET"
            request.scope["weldcell.head"] = True
        try:
            return await call_next(request)
        except HTTPError as err:
            return _error(err.status, err.message, err.headers)
        finally:
            if head:
                request.scope["method"] = "HEAD"

    _error_handlers(app)
    _reading_routes(app, daemon)
    _command_routes(app, daemon, guards)
    if daemon.sim is not None:
        _sim_fault_routes(app, daemon.sim, guards)
    return app


def _error_handlers(app: FastAPI) -> None:
    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        method = "HEAD" if request.scope.get("weldcell.head") else request.method
        message = {404: f"no such resource {request.url.path}", 405: f"{method} is not allowed here"}.get(
            exc.status_code, str(exc.detail)
        )
        return _error(exc.status_code, message, dict(exc.headers or {}))

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        return _error(404, f"no such resource {request.url.path}")

    @app.exception_handler(HTTPError)
    async def our_error(request: Request, exc: HTTPError) -> JSONResponse:
        return _error(exc.status, exc.message, exc.headers)

    @app.exception_handler(ConfigError)
    async def bad_request(request: Request, exc: ConfigError) -> JSONResponse:
        return _error(400, str(exc))

    @app.exception_handler(WeldcellError)
    async def unavailable(request: Request, exc: WeldcellError) -> JSONResponse:
        return _error(503, str(exc))

    @app.exception_handler(Exception)
    async def bug(request: Request, exc: Exception) -> JSONResponse:
        logger.error("http %s %s failed", request.method, request.url.path, exc_info=exc)
        return _error(500, "internal error (logged by the daemon)")


def _ok(obj: Any, status: int = 200) -> JSONResponse:
    return JSONResponse(obj, status_code=status, headers={"Cache-Control": "no-store"})


def _job_id(job_id: int) -> int:
    if not 0 <= job_id <= MAX_JOB_ID:
        raise HTTPError(404, f"no job {job_id}")
    return job_id


def _reading_routes(app: FastAPI, daemon: Daemon) -> None:
    @app.get("/status", summary="The cell's state, the current and queued jobs, recent and interrupted jobs")
    def status() -> JSONResponse:
        return _ok(daemon.status())

    @app.get("/jobs", summary="The recent jobs, newest first")
    def jobs() -> JSONResponse:
        return _ok(daemon.jobs_view())

    @app.get("/jobs/{job_id}", summary="One job: state, report, error and its journaled events")
    def job(job_id: int) -> JSONResponse:
        try:
            return _ok(daemon.job_view(_job_id(job_id)))
        except KeyError as err:
            raise HTTPError(404, f"no job {job_id}") from err

    @app.get(
        "/jobs/{job_id}/export/{fmt}",
        summary="A finished job's seams and path as urscript, ls, rosbag2 (a zip of the bag folder), gltf or html",
    )
    def export(job_id: int, fmt: str) -> Response:
        from cell.job_exports import FORMATS, NothingToExport
        from cell.runner import CellBusy

        if fmt not in FORMATS:
            raise HTTPError(404, f"no export format {fmt!r}; choose one of {', '.join(FORMATS)}")
        try:
            out = daemon.export(_job_id(job_id), fmt)
        except KeyError as err:
            raise HTTPError(404, f"no job {job_id}") from err
        except (CellBusy, NothingToExport) as err:
            raise HTTPError(409, str(err)) from err
        disposition = f'attachment; filename="{out.filename}"'
        return Response(out.body, media_type=out.media_type, headers={"Content-Disposition": disposition})

    @app.get("/metrics", summary="Prometheus text format", response_class=PlainTextResponse)
    def metrics() -> Response:
        from cell.metrics import CONTENT_TYPE

        return Response(daemon.metrics(), media_type=CONTENT_TYPE)

    @app.get("/", summary="The operator page (its data: /status, with the token)", response_class=HTMLResponse)
    def page() -> HTMLResponse:
        from cell.operator_page import page_html

        return HTMLResponse(page_html(), headers={"Cache-Control": "no-store"})

    @app.get("/status.png", summary="The overlay of the last capture (PNG)")
    def status_png() -> Response:
        try:
            return Response(
                daemon.status_image.read_bytes(), media_type="image/png", headers={"Cache-Control": "no-store"}
            )
        except OSError as err:
            raise HTTPError(404, "no capture yet") from err


def _command_routes(app: FastAPI, daemon: Daemon, guards: Guards) -> None:
    async def operator_of(request: Request) -> str:
        body, _ = await guards.body(request, JSON_TYPES)
        try:
            obj = json.loads(body.decode("utf-8") or "{}")
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
            obj = None
        name = obj.get("operator") if isinstance(obj, dict) else None
        if not isinstance(name, str) or not name.strip() or len(name) > 200:
            raise HTTPError(400, 'send {"operator": "<name>"}: an operator must be named')
        return name.strip()

    @app.post(
        "/jobs",
        status_code=201,
        summary="Queue a job: its TOML text, or JSON {\"path\": ...} (a file in the jobs directory) or "
        "{\"toml\": ...}; ?dry_run=1 or \"dry_run\": true plans and validates only",
    )
    async def submit(request: Request) -> JSONResponse:
        body, ctype = await guards.body(request, JOB_TYPES)
        query = request.query_params.get("dry_run")
        job, dry_run = await run_in_threadpool(daemon.job_from_request, body, ctype, query)
        job_id = await run_in_threadpool(daemon.submit, job, dry_run=dry_run)
        return _ok({"id": job_id, "state": "queued", "dry_run": dry_run}, 201)

    async def answer(job_id: int, request: Request, approve: bool) -> JSONResponse:
        operator = await operator_of(request)
        _job_id(job_id)
        if await run_in_threadpool(daemon.answer_approval, job_id, operator if approve else None):
            return _ok({"id": job_id, "approved": approve, "operator": operator})
        raise HTTPError(409, f"job {job_id} is not waiting for approval")

    @app.post("/jobs/{job_id}/approve", summary='{"operator": "name"}: approve the planned path of a waiting job')
    async def approve(job_id: int, request: Request) -> JSONResponse:
        return await answer(job_id, request, True)

    @app.post("/jobs/{job_id}/reject", summary='{"operator": "name"}: refuse it (the job ends cancelled)')
    async def reject(job_id: int, request: Request) -> JSONResponse:
        return await answer(job_id, request, False)

    @app.post("/acknowledge", summary='{"operator": "name"}: leave fault (latched device faults are cleared)')
    async def acknowledge(request: Request) -> JSONResponse:
        operator = await operator_of(request)
        code, obj = await run_in_threadpool(daemon.acknowledge, operator)
        return _ok(obj, code)

    for command in ("pause", "resume", "abort"):

        async def motion(request: Request, command: str = command) -> JSONResponse:
            operator = await operator_of(request)
            code, obj = await run_in_threadpool(daemon.motion_command, command, operator)
            return _ok(obj, code)

        app.add_api_route(
            f"/{command}",
            motion,
            methods=["POST"],
            summary=f'{{"operator": "name"}}: {command} the running job',
            name=command,
        )


def _sim_fault_routes(app: FastAPI, sim: SimFaultSwitch, guards: Guards) -> None:
    """Test only (``--sim-faults``)."""

    @app.get("/sim/faults", summary="Test only: the simulated devices and their faults")
    def sim_faults() -> JSONResponse:
        return _ok(sim.view())

    @app.post("/sim/faults", summary='Test only: {"device", "fault", "params"} switches a simulator fault on')
    async def inject(request: Request) -> JSONResponse:
        body, _ = await guards.body(request, JSON_TYPES)
        return _ok(await run_in_threadpool(sim.command, "/sim/faults", body))

    @app.post("/sim/faults/clear", summary='Test only: {"device"} or {}: switch simulator faults off')
    async def clear(request: Request) -> JSONResponse:
        body, _ = await guards.body(request, JSON_TYPES)
        return _ok(await run_in_threadpool(sim.command, "/sim/faults/clear", body))


# ============================================================================================== the server
def _protocol(header_timeout_s: float) -> type[H11Protocol]:  # long: one class, its methods share the deadline
    """uvicorn's h11 protocol with a deadline on each request's line and headers: a client that has not sent a
    whole request head within ``header_timeout_s`` (slowloris, a half-open request) gets 408 and is closed."""

    class Protocol(H11Protocol):
        _head_timer: asyncio.TimerHandle | None = None

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._arm()

        def data_received(self, data: bytes) -> None:
            super().data_received(data)
            if self.conn.their_state is h11.IDLE:
                if self._head_timer is None:
                    self._arm()
            else:
                self._disarm()

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            super().connection_lost(exc)

        def eof_received(self) -> bool:  # type: ignore[override]  # asyncio.Protocol's contract: True keeps it open
            # a client that half-closes after its request still gets the answer (asyncio would close the
            # transport at once); the connection closes after that response, or by the timers
            self._client_done = True
            idle = self.cycle is None or self.cycle.response_complete
            if idle and self.conn.their_state is h11.IDLE:
                if self._partial():  # a request head the client can no longer finish: answer now, not at the timer
                    self._disarm()
                    self._close_with(400, "Bad Request", "the client ended the connection inside a request's headers")
                else:
                    self.transport.close()
            return True

        def send_400_response(self, msg: str) -> None:
            # a request h11 cannot parse: the same JSON error shape as every other answer, framed, then close
            body = json.dumps({"error": f"malformed HTTP request: {msg}"}).encode()
            headers = [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"connection", b"close"),
            ]
            for event in (h11.Response(status_code=400, headers=headers, reason=b"Bad Request"), h11.Data(data=body)):
                self.transport.write(self.conn.send(event) or b"")
            self.transport.write(self.conn.send(h11.EndOfMessage()) or b"")
            self.transport.close()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if getattr(self, "_client_done", False) and self.conn.their_state is h11.IDLE and not self._partial():
                self.transport.close()

        def _arm(self) -> None:
            self._head_timer = self.loop.call_later(header_timeout_s, self._too_slow)

        def _disarm(self) -> None:
            if self._head_timer is not None:
                self._head_timer.cancel()
                self._head_timer = None

        def _too_slow(self) -> None:
            self._head_timer = None
            if self.transport.is_closing() or self.conn.their_state is not h11.IDLE:
                return
            if self.cycle is not None and not self.cycle.response_complete:
                return  # a response is on its way (pipelining): the keep-alive timer takes over
            if self.conn.our_state is h11.IDLE and self.conn.their_state is h11.IDLE and not self._partial():
                self.transport.close()  # an idle keep-alive connection: just close it
                return
            self._close_with(408, "Request Timeout", f"the request did not arrive within {header_timeout_s:.0f} s")

        def _close_with(self, status: int, phrase: str, message: str) -> None:
            # written by hand: h11 sends no response before it has read a request
            body = json.dumps({"error": message}).encode()
            head = (
                f"HTTP/1.1 {status} {phrase}\r\ncontent-type: application/json\r\n"
                f"content-length: {len(body)}\r\nconnection: close\r\n\r\n"
            )
            self.transport.write(head.encode() + body)
            self.transport.close()

        def _partial(self) -> bool:
            return bool(self.conn.trailing_data[0])

    return Protocol


class HttpServer:
    """uvicorn serving ``app`` on ``sock`` in a thread; :meth:`stop` ends it."""

    def __init__(self, app: FastAPI, sock: socket.socket, *, timeout_s: float, max_connections: int) -> None:
        import uvicorn

        self.sock = sock
        self.config = uvicorn.Config(
            app,
            http=_protocol(timeout_s),
            lifespan="off",
            log_level="warning",
            access_log=False,
            timeout_keep_alive=max(1, round(timeout_s)),
            limit_concurrency=max_connections,
            timeout_graceful_shutdown=2,
            h11_max_incomplete_event_size=64 * 1024,
        )
        self.server = uvicorn.Server(self.config)
        self.thread = threading.Thread(target=self._run, name="weldcell-http", daemon=True)

    def _run(self) -> None:
        self.server.run(sockets=[self.sock])

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        self.server.should_exit = True
        if self.thread.is_alive():
            self.thread.join(timeout=10.0)
        self.sock.close()


def listen(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host``:``port`` (0: a free port)."""
    family = socket.AF_INET6 if ":" in host and ipaddress.ip_address(host).version == 6 else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
        sock.listen(128)
    except OSError:
        sock.close()
        raise
    sock.set_inheritable(True)
    return sock
