"""The daemon's HTTP API (cell/http_api.py, cell.daemon) against hostile clients, loopback only.

Files outside the configured directories, cross-site requests, foreign Host headers, bodies too large or of the
wrong type, request smuggling and desynchronisation, slow and half-open clients, deep nesting, huge ids, jobs
over the cell's limits; and property-based tests (hypothesis) with random paths, methods, headers and bodies: the
daemon always answers with a complete HTTP response, never a 500, and the cell stays safe (arc off, nothing
moving, no job queued by accident). One daemon (the simulated FANUC cell) serves the whole module.
"""

from __future__ import annotations

import json
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cell.daemon import Daemon
from tests.cell.runner_rig import cell_config, job_text
from tests.cell.test_daemon import request

REQUEST_TIMEOUT_S = 1.0
MAX_BODY = 64 * 1024


class Served:
    def __init__(self, daemon: Daemon, jobs_dir: Path) -> None:
        self.daemon = daemon
        self.host, self.port = daemon.address
        self.base = f"http://{self.host}:{self.port}"
        self.jobs_dir = jobs_dir

    def raw(self, data: bytes, *, read_s: float = 5.0, head: bool = False) -> list[tuple[int, dict[str, str], bytes]]:
        """Send ``data`` on a fresh connection, half-close it and parse every response until the server closes."""
        with socket.create_connection((self.host, self.port), timeout=read_s) as sock:
            sock.sendall(data)
            sock.shutdown(socket.SHUT_WR)
            received = b""
            deadline = time.monotonic() + read_s
            while time.monotonic() < deadline:
                try:
                    chunk = sock.recv(65536)
                except TimeoutError:
                    break
                if not chunk:
                    break
                received += chunk
        return parse_responses(received, no_body=head)


def parse_responses(data: bytes, *, no_body: bool = False) -> list[tuple[int, dict[str, str], bytes]]:
    """Complete HTTP/1.1 responses (Content-Length framed; ``no_body``: answers to HEAD, without a body) in ``data``;
    AssertionError for a truncated one."""
    out = []
    while data:
        top, sep, rest = data.partition(b"\r\n\r\n")
        assert sep, f"a truncated response head: {data[:200]!r}"
        lines = top.decode("latin-1").split("\r\n")
        status = int(lines[0].split(" ")[1])
        headers = {k.strip().lower(): v.strip() for k, v in (line.split(":", 1) for line in lines[1:])}
        if "content-length" not in headers and not no_body:  # delimited by the close
            out.append((status, headers, rest))
            break
        n = 0 if no_body else int(headers["content-length"])
        assert len(rest) >= n, f"a truncated response body ({len(rest)} of {n} bytes)"
        out.append((status, headers, rest[:n]))
        data = rest[n:]
    return out


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    tmp = tmp_path_factory.mktemp("http")
    jobs_dir = tmp / "jobs"
    jobs_dir.mkdir()
    config = cell_config(
        tmp,
        "sim-cell-fanuc.toml",
        daemon={
            "port": 0,
            "jobs_dir": str(jobs_dir),
            "captures_dir": str(tmp / "captures"),
            "request_timeout_s": REQUEST_TIMEOUT_S,
            "max_body_bytes": MAX_BODY,
            "max_file_bytes": 16 * 1024,
        },
    )
    daemon = Daemon(config).start()
    try:
        yield Served(daemon, jobs_dir)
    finally:
        daemon.shutdown("test over")


def post_json(base: str, path: str, obj: Any, headers: dict[str, str] | None = None) -> tuple[int, Any]:
    return request(
        f"{base}{path}",
        method="POST",
        body=json.dumps(obj).encode(),
        headers={"Content-Type": "application/json", **(headers or {})},
    )


def assert_cell_safe(served: Served) -> None:
    st_ = served.daemon.status()
    assert st_["state"] == "idle" and st_["current_job"] is None and st_["queued"] == [], st_
    sims = served.daemon.cell.simulators
    assert sims is not None and not sims.robot.digital_output(1)  # the arc output as the controller holds it
    assert sims.robot.in_flight() == 0


# ============================================================================================== files
@pytest.mark.timeout(60)
@pytest.mark.parametrize("path", ["/etc/passwd", "/etc/shadow", "/proc/self/environ", "../../../../etc/passwd"])
def test_a_job_path_outside_the_jobs_directory_gets_a_400_naming_the_rule_not_the_content(
    served: Served, path: str
) -> None:
    status, answer = post_json(served.base, "/jobs", {"path": path})
    assert status == 400, answer
    assert "must lie inside the configured directories" in answer["error"]
    assert "root:" not in answer["error"] and "PATH=" not in answer["error"]


@pytest.mark.timeout(60)
def test_a_symlink_out_of_the_jobs_directory_is_refused_too(served: Served) -> None:
    link = served.jobs_dir / "innocent.toml"
    if not link.exists():
        os.symlink("/etc/passwd", link)
    status, answer = post_json(served.base, "/jobs", {"path": "innocent.toml"})
    assert status == 400 and "must lie inside the configured directories" in answer["error"], answer
    assert "root:" not in answer["error"]


@pytest.mark.timeout(60)
def test_prompts_files_outside_the_directories_get_the_same_answer_whether_they_exist_or_not(served: Served) -> None:
    answers = []
    for prompts in ("/etc/passwd", "/no/such/file.json"):
        text = job_text().replace('prompts = "camera"', f'prompts = "{prompts}"')
        status, answer = request(f"{served.base}/jobs", method="POST", body=text.encode())
        assert status == 400, answer
        answers.append(answer["error"].replace(prompts, "<path>"))
    assert answers[0] == answers[1] and "must lie inside the configured directories" in answers[0]


@pytest.mark.timeout(60)
def test_a_job_file_in_the_jobs_directory_runs_and_a_large_one_is_refused(served: Served) -> None:
    (served.jobs_dir / "ribs.toml").write_text(job_text(), encoding="utf-8")
    status, answer = post_json(served.base, "/jobs", {"path": "ribs.toml", "dry_run": True})
    assert status == 201 and answer["dry_run"] is True, answer
    wait_settled(served)
    (served.jobs_dir / "big.toml").write_text(job_text() + "#" * 20_000, encoding="utf-8")
    status, answer = post_json(served.base, "/jobs", {"path": "big.toml"})
    assert status == 400 and "more than the 16384 bytes allowed" in answer["error"], answer


def wait_settled(served: Served, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        st_ = served.daemon.status()
        if st_["current_job"] is None and not st_["queued"]:
            return
        time.sleep(0.1)
    raise AssertionError("the daemon did not settle")


# ============================================================================================== limits
@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        ("travel_speed_m_s = 0.25", "travel_speed_m_s = 5.0", "[safety] max_speed_m_s = 0.6"),
        ("travel_speed_m_s = 0.25", "travel_speed_m_s = 1e308", "[safety] max_speed_m_s"),
        ("travel_speed_m_s = 0.25", "travel_speed_m_s = inf", "finite"),
        ("arc_output = 0", "arc_output = 99", "welding.arc_output: 99 is not the cell's arc output"),
        ("track_position_m = 0.0", "track_position_m = -5.0", "outside the track's soft limits"),
        ("xyz_m = [-0.29854,", "xyz_m = [1e6,", "[safety] reach_radius_m"),
        ('kinds = ["linear"]', f'kinds = ["linear"]\nids = [{2**70}]', "not a seam id"),
        ("accel_m_s2 = 1.0", "accel_m_s2 = 50.0", "[safety] max_accel_m_s2"),
    ],
)
def test_a_job_over_the_cells_limits_is_refused_at_submission_naming_the_limit(
    served: Served, old: str, new: str, words: str
) -> None:
    text = job_text()
    assert old in text
    status, answer = request(f"{served.base}/jobs", method="POST", body=text.replace(old, new).encode())
    assert status == 400, answer
    assert words in answer["error"], answer["error"]
    assert served.daemon.status()["queued"] == []


@pytest.mark.timeout(60)
@pytest.mark.parametrize("flag", ["false", "true", 0, 1, None, [], {}])
def test_dry_run_must_be_a_json_boolean(served: Served, flag: Any) -> None:
    status, answer = post_json(served.base, "/jobs", {"toml": job_text(), "dry_run": flag})
    assert status == 400 and '"dry_run" must be a JSON boolean' in answer["error"], answer


@pytest.mark.timeout(60)
def test_a_dry_run_query_flag_must_be_one_of_the_known_words(served: Served) -> None:
    status, answer = request(f"{served.base}/jobs?dry_run=maybe", method="POST", body=job_text().encode())
    assert status == 400 and "?dry_run must be one of" in answer["error"]


# ============================================================================================== origin, host, token
@pytest.mark.timeout(60)
def test_a_cross_origin_post_gets_403_and_a_same_origin_one_goes_through(served: Served) -> None:
    body = {"operator": "mallory"}
    for headers in ({"Origin": "http://evil.example"}, {"Origin": "null"}, {"Sec-Fetch-Site": "cross-site"}):
        status, answer = post_json(served.base, "/acknowledge", body, headers)
        assert status == 403 and "cross-origin" in answer["error"], (headers, answer)
        status, answer = request(f"{served.base}/jobs", method="POST", body=job_text().encode(), headers=headers)
        assert status == 403
    assert served.daemon.status()["queued"] == []
    status, answer = post_json(served.base, "/acknowledge", body, {"Origin": served.base})
    assert status == 409 and "not in fault" in answer["error"]  # got through the guard: the cell is idle
    assert request(f"{served.base}/status", headers={"Origin": "http://evil.example"})[0] == 200  # reading is fine


@pytest.mark.timeout(60)
def test_a_foreign_host_header_is_refused(served: Served) -> None:
    req = f"GET /status HTTP/1.1\r\nHost: evil.example:{served.port}\r\nConnection: close\r\n\r\n".encode()
    [(status, _, body)] = served.raw(req)
    assert status == 400 and "Host header" in json.loads(body)["error"]
    req = f"GET /status HTTP/1.1\r\nHost: localhost:{served.port}\r\nConnection: close\r\n\r\n".encode()
    assert served.raw(req)[0][0] == 200


@pytest.mark.timeout(60)
def test_the_token_guards_every_route_the_openapi_document_included(tmp_path: Path) -> None:
    token = "a-token-for-the-http-tests"
    config = cell_config(tmp_path, "sim-cell-fanuc.toml", daemon={"port": 0, "token": token})
    with Daemon(config) as d:
        host, port = d.address
        base = f"http://{host}:{port}"
        paths = ("/status", "/jobs", "/jobs/1", "/jobs/1/export/urscript", "/metrics", "/status.png", "/openapi.json")
        for path in (*paths, "/nope", "/index.html", "//"):
            status, answer = request(f"{base}{path}")
            assert status == 401 and "bearer token" in answer["error"], path
        # but the operator page's HTML, which holds no data (it sends the token with each of its requests)
        status, page = request(f"{base}/")
        assert status == 200 and "<title>weldcell operator</title>" in page
        status, answer = request(f"{base}/", method="POST", body=b"{}")
        assert status == 401
        status, doc = request(f"{base}/openapi.json", headers={"Authorization": f"Bearer {token}"})
        assert status == 200
        assert {"/jobs", "/jobs/{job_id}", "/acknowledge", "/pause", "/status", "/metrics"} <= set(doc["paths"])


# ============================================================================================== the wire
@pytest.mark.timeout(60)
def test_errors_are_json_with_the_right_status(served: Served) -> None:
    status, answer = request(f"{served.base}/status", method="DELETE")
    assert status == 405 and "DELETE is not allowed" in answer["error"]
    status, answer = request(f"{served.base}/jobs", method="PUT", body=b"x")
    assert status == 405
    status, answer = request(f"{served.base}/nowhere")
    assert status == 404 and answer["error"] == "no such resource /nowhere"
    status, answer = request(f"{served.base}/jobs/99999999999999999999999")
    assert status == 404 and "no job" in answer["error"]
    status, answer = request(f"{served.base}/jobs/abc")
    assert status == 404
    status, answer = request(
        f"{served.base}/jobs", method="POST", body=b"\x89PNG", headers={"Content-Type": "image/png"}
    )
    assert status == 415 and "application/toml" in answer["error"]
    status, answer = request(f"{served.base}/jobs", method="POST", body=b"x" * (MAX_BODY + 1))
    assert status == 413


@pytest.mark.timeout(60)
def test_head_on_a_get_route_answers_its_headers_without_a_body(served: Served) -> None:
    host = f"{served.host}:{served.port}"
    for path in ("/status", "/jobs", "/metrics", "/", "/openapi.json"):
        [(get_status, get_headers, body)] = served.raw(f"GET {path} HTTP/1.1\r\nHost: {host}\r\n\r\n".encode())
        data = f"HEAD {path} HTTP/1.1\r\nHost: {host}\r\n\r\n".encode()
        [(status, headers, rest)] = served.raw(data, head=True)
        assert (status, get_status, rest) == (200, 200, b""), path
        assert headers["content-type"] == get_headers["content-type"], path
        if path != "/metrics":  # the metrics change between the two requests (uptime, requests served)
            assert int(headers["content-length"]) == len(body) > 0, path
    [(status, headers, rest)] = served.raw(f"HEAD /pause HTTP/1.1\r\nHost: {host}\r\n\r\n".encode(), head=True)
    assert (status, headers["allow"], rest) == (405, "POST", b"")
    [(status, _, rest)] = served.raw(f"HEAD /nowhere HTTP/1.1\r\nHost: {host}\r\n\r\n".encode(), head=True)
    assert (status, rest) == (404, b"")


@pytest.mark.timeout(60)
@pytest.mark.parametrize("path", ["/acknowledge", "/pause", "/jobs/1/approve"])
def test_a_form_encoded_body_on_a_json_route_is_415(served: Served, path: str) -> None:
    form = {"Content-Type": "application/x-www-form-urlencoded"}
    status, answer = request(f"{served.base}{path}", method="POST", body=b'{"operator": "Ada"}', headers=form)
    assert status == 415 and answer["error"] == (
        "send the body as application/json, not application/x-www-form-urlencoded"
    )
    status, answer = request(f"{served.base}{path}", method="POST", body=b"operator=Ada", headers=form)
    assert status == 415
    assert_cell_safe(served)


@pytest.mark.timeout(60)
def test_deep_nesting_gets_a_clean_400(served: Served) -> None:
    deep_toml = ("a = " + "[" * 5000 + "]" * 5000 + "\n").encode()
    status, answer = request(f"{served.base}/jobs", method="POST", body=deep_toml)
    assert status == 400 and "nested too deeply" in answer["error"], answer
    deep_json = ("[" * 5000 + "]" * 5000).encode()
    status, answer = request(
        f"{served.base}/jobs", method="POST", body=deep_json, headers={"Content-Type": "application/json"}
    )
    assert status == 400 and "nested too deeply" in answer["error"], answer


@pytest.mark.timeout(60)
def test_an_unread_or_chunked_body_is_never_parsed_as_the_next_request(served: Served) -> None:
    host = f"127.0.0.1:{served.port}"
    smuggled = f"POST /pause HTTP/1.1\r\nHost: {host}\r\nContent-Length: 20\r\n\r\n{{\"operator\": \"eve\"}}"
    # a rejected request (415) whose long body carries another request
    body = smuggled.encode()
    first = (
        f"POST /jobs HTTP/1.1\r\nHost: {host}\r\nContent-Type: image/png\r\nContent-Length: {len(body)}\r\n\r\n"
    ).encode() + body
    follow = f"GET /status HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode()
    responses = served.raw(first + follow)
    assert [r[0] for r in responses] == [415, 200]
    # the same inside a chunked body
    chunk = body
    chunked = (
        f"POST /jobs HTTP/1.1\r\nHost: {host}\r\nContent-Type: image/png\r\nTransfer-Encoding: chunked\r\n\r\n"
        f"{len(chunk):x}\r\n"
    ).encode() + chunk + b"\r\n0\r\n\r\n"
    responses = served.raw(chunked + follow)
    assert [r[0] for r in responses] == [415, 200]
    # both framings at once: a smuggling attempt, refused
    both = (
        f"POST /jobs HTTP/1.1\r\nHost: {host}\r\nContent-Length: 4\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n"
    ).encode()
    assert served.raw(both)[0][0] == 400
    assert not [e for e in served.daemon.journal.events(None) if "paused by eve" in e.reason]


@pytest.mark.timeout(60)
def test_slow_and_half_open_clients_get_408_and_do_not_hold_the_daemon(served: Served) -> None:
    host = f"127.0.0.1:{served.port}"
    socks = []
    try:
        for _ in range(200):  # half-open requests: a head that never ends (the issue had 300)
            s = socket.create_connection((served.host, served.port), timeout=5)
            s.sendall(f"GET /status HTTP/1.1\r\nHost: {host}\r\n".encode())
            socks.append(s)
        t0 = time.monotonic()
        status, _ = request(f"{served.base}/status")  # the daemon still answers at once
        assert status == 200 and time.monotonic() - t0 < 2.0
        time.sleep(REQUEST_TIMEOUT_S + 0.5)
        s = socks[0]
        data = b""
        while chunk := s.recv(65536):
            data += chunk
        [(status, headers, body)] = parse_responses(data)
        assert status == 408 and headers["connection"] == "close" and "did not arrive" in json.loads(body)["error"]
        # a body that stalls: 408 too
        s = socket.create_connection((served.host, served.port), timeout=5)
        socks.append(s)
        s.sendall(f"POST /jobs HTTP/1.1\r\nHost: {host}\r\nContent-Length: 100\r\n\r\nworkpiece".encode())
        s.settimeout(REQUEST_TIMEOUT_S + 5)
        data = b""
        while chunk := s.recv(65536):
            data += chunk
        assert parse_responses(data)[0][0] == 408
    finally:
        for s in socks:
            s.close()
    assert request(f"{served.base}/status")[0] == 200


# ============================================================================================== properties
PATHS = st.sampled_from(
    [
        "/", "/status", "/jobs", "/jobs/1", "/jobs/0", "/jobs/-1", "/jobs/99999999999999999999999", "/jobs/1/approve",
        "/jobs/1/reject", "/acknowledge", "/pause", "/resume", "/abort", "/metrics", "/status.png", "/openapi.json",
        "/sim/faults", "/sim/faults/clear", "/%00", "/..%2f..%2fetc%2fpasswd", "/jobs/%ff",
    ]
) | st.text(alphabet=st.characters(min_codepoint=0x21, max_codepoint=0x7E), max_size=40).map(lambda t: "/" + t)
METHODS = st.sampled_from(["GET", "POST", "PUT", "DELETE", "PATCH", "HEAD", "OPTIONS", "BREW"])
HEADER_NAMES = st.sampled_from(
    ["Content-Type", "Origin", "Accept", "Authorization", "Sec-Fetch-Site", "X-Forwarded-For", "Cookie", "Range"]
)
HEADER_VALUES = st.text(alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=60)
JSONISH = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)
BODIES = (
    st.binary(max_size=512)
    | JSONISH.map(lambda o: json.dumps(o).encode())
    | st.dictionaries(st.sampled_from(["path", "toml", "dry_run", "operator"]), JSONISH, max_size=3).map(
        lambda o: json.dumps(o).encode()
    )
    | st.text(max_size=300).map(lambda t: t.encode())
)


@pytest.mark.timeout(300)
@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(method=METHODS, path=PATHS, headers=st.dictionaries(HEADER_NAMES, HEADER_VALUES, max_size=4), body=BODIES)
def test_any_request_gets_a_complete_answer_and_leaves_the_cell_safe(
    served: Served, method: str, path: str, headers: dict[str, str], body: bytes
) -> None:
    lines = [f"{method} {path} HTTP/1.1", f"Host: 127.0.0.1:{served.port}", f"Content-Length: {len(body)}"]
    lines += [f"{k}: {v}" for k, v in headers.items()]
    lines.append("Connection: close")
    data = ("\r\n".join(lines) + "\r\n\r\n").encode() + body
    responses = served.raw(data, head=method == "HEAD")
    assert len(responses) == 1, responses  # exactly one complete response: never dropped, never doubled
    status, resp_headers, payload = responses[0]
    assert status < 500, (status, payload)
    if method != "HEAD" and status >= 400:
        assert resp_headers.get("content-type", "").startswith("application/json"), resp_headers
        assert "error" in json.loads(payload)
    # a random request can, at most, queue a job that is a real job: nothing here is one
    assert served.daemon.status()["queued"] == []
    wait_settled(served, timeout_s=5)
    assert_cell_safe(served)


@pytest.mark.timeout(30)
def test_a_client_that_half_closes_inside_the_headers_gets_400_at_once(served: Served) -> None:
    t0 = time.monotonic()
    [(status, headers, body)] = served.raw(f"GET /status HTTP/1.1\r\nHost: 127.0.0.1:{served.port}\r\nX-A".encode())
    assert status == 400 and headers["connection"] == "close"
    assert json.loads(body) == {"error": "the client ended the connection inside a request's headers"}
    assert time.monotonic() - t0 < REQUEST_TIMEOUT_S / 2  # not at the header timer
    assert request(f"{served.base}/status")[0] == 200


@pytest.mark.timeout(300)
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(garbage=st.binary(min_size=1, max_size=300))
def test_garbage_on_the_wire_gets_an_answer_or_a_clean_close(served: Served, garbage: bytes) -> None:
    with socket.create_connection((served.host, served.port), timeout=5) as sock:
        sock.sendall(garbage)
        sock.shutdown(socket.SHUT_WR)
        data = b""
        while True:
            try:
                chunk = sock.recv(65536)
            except (TimeoutError, ConnectionResetError):
                break
            if not chunk:
                break
            data += chunk
    if data:  # a malformed request gets a JSON 400; an incomplete one the client gave up on is closed
        for status, _headers, payload in parse_responses(data):
            assert status < 500
            if status >= 400:
                assert "error" in json.loads(payload), payload
    assert request(f"{served.base}/status")[0] == 200
    assert_cell_safe(served)
