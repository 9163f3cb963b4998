"""The operator page (cell/operator_page.html, cell.operator_page) in a real headless browser: Playwright for Python
driving Debian's Chromium (``apt-get install chromium``; ``scripts/bootstrap.sh test`` installs it as root), no
browser downloaded. Loopback only.

The page is driven through a simulated job on the FANUC cell with a token: it asks for approval, the operator
approves on the page, the seams are welded (seam k of n, the overlay marks them), a pause and a resume, then a
protective stop injected in the simulated controller: the page says so in one sentence with what to do, the operator
acknowledges on the page, and the history shows the job with its duration. Each step's screenshot is checked (size,
the state's colour in the header). ``WELDCELL_DOCS_SCREENSHOT=1`` also writes the welding one to
docs/operator-page.png.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from cell.daemon import Daemon
from tests.cell.runner_rig import REPO, cell_config, job_text
from tests.cell.test_daemon import TOKEN, request, wait_for

CHROMIUM = os.environ.get("WELDCELL_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
VIEWPORT = {"width": 1280, "height": 960}
# the page's state colours (cell/operator_page.html :root), RGB
COLOURS = {"idle": (0x54, 0x6E, 0x7A), "wait": (0xF9, 0xA8, 0x25), "weld": (0xEF, 0x6C, 0x00),
           "pause": (0x6A, 0x1B, 0x9A), "fault": (0xC6, 0x28, 0x28)}  # fmt: skip

try:
    from playwright import sync_api
except ImportError:  # pragma: no cover - a dev install has it
    sync_api = None  # type: ignore[assignment]

needs_browser = pytest.mark.skipif(
    sync_api is None or CHROMIUM is None,
    reason="no browser to drive: Playwright for Python ('.[dev]') and Chromium ('apt-get install chromium'; "
    "scripts/bootstrap.sh test installs it as root), or WELDCELL_CHROMIUM naming a Chromium binary",
)


def test_the_page_is_self_contained_and_served_without_the_token(tmp_path: Path) -> None:
    from cell.operator_page import page_html

    html = page_html()
    # nothing fetched from elsewhere: no absolute URL outside the SVG namespace name, no external script or style
    urls = set(re.findall(r"https?://[^\s\"')]+", html))
    assert urls == {"http://www.w3.org/2000/svg"}
    assert "<script src" not in html and '<link rel="stylesheet"' not in html
    config = cell_config(tmp_path, "sim-cell-fanuc.toml", daemon={"port": 0, "token": TOKEN})
    with Daemon(config) as d:
        host, port = d.address
        base = f"http://{host}:{port}"
        status, page = request(f"{base}/")
        assert status == 200 and page == html
        assert request(f"{base}/status")[0] == 401  # its data is not


@pytest.fixture
def cell(tmp_path: Path) -> Iterator[tuple[Daemon, str]]:
    config = cell_config(tmp_path, "sim-cell-fanuc.toml", daemon={"port": 0, "token": TOKEN})
    with Daemon(config, sim_faults=True) as d:
        host, port = d.address
        yield d, f"http://{host}:{port}"


def api(base: str, path: str, obj: Any = None, *, body: bytes | None = None) -> tuple[int, Any]:
    ctype = "application/toml" if body is not None else "application/json"
    headers = {"Authorization": f"Bearer {TOKEN}", "Content-Type": ctype}
    data = body if body is not None else (json.dumps(obj).encode() if obj is not None else None)
    return request(f"{base}{path}", method="GET" if data is None else "POST", body=data, headers=headers)


def header_share(png: bytes, rgb: tuple[int, int, int]) -> float:
    """The share of the header band's pixels (the top 60 px) within 6 of ``rgb``."""
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None and img.shape[:2] == (VIEWPORT["height"], VIEWPORT["width"]), "screenshot size"
    band = img[:60, :, ::-1].astype(int)  # BGR -> RGB
    return float(np.mean(np.all(np.abs(band - np.array(rgb)) <= 6, axis=2)))


# long: one browser session, step by step, as an operator goes through it
@needs_browser
@pytest.mark.timeout(180)
def test_the_page_drives_a_job_through_approval_welding_a_fault_and_its_acknowledgement(
    cell: tuple[Daemon, str], tmp_path: Path
) -> None:
    daemon, base = cell
    shots = tmp_path / "screenshots"
    shots.mkdir()
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport=VIEWPORT)
            errors: list[str] = []
            page.on("pageerror", lambda err: errors.append(str(err)))
            assert sync_api is not None
            expect = sync_api.expect

            def shot(name: str, colour: str) -> bytes:
                png = page.screenshot(path=str(shots / f"{name}.png"))
                assert header_share(png, COLOURS[colour]) > 0.5, f"{name}: the header is not {colour}"
                return png

            # without the token the page asks for it; with it (the address's #token=) it goes live
            page.goto(f"{base}/")
            expect(page.locator("#token-form")).to_be_visible()
            page.goto(f"{base}/?poll_ms=250#token={TOKEN}")
            expect(page.locator("#state")).to_have_text("idle")
            expect(page.locator("#arc")).to_have_text("off")
            expect(page.locator("#devices")).to_contain_text("Track")
            assert "token=" not in page.url  # the token does not stay in the address bar
            shot("1-idle", "idle")

            # a job that waits for an operator's approval: the page shows it and approves it
            status, answer = api(base, "/jobs", body=job_text(approval=True, travel_speed_m_s=0.03).encode())
            assert status == 201, answer
            job_id = int(answer["id"])
            expect(page.locator("#state")).to_have_text("awaiting approval", timeout=30_000)
            expect(page.locator("#approve")).to_be_enabled()
            expect(page.locator("#pause")).to_be_disabled()
            page.click("#approve")
            expect(page.locator("#message")).to_contain_text("Type your name first")
            page.fill("#operator", "Ada")
            page.click("#approve")
            expect(page.locator("#state")).to_have_text("welding", timeout=15_000)
            n = len(daemon.runner.current.path.passes)  # type: ignore[union-attr]
            expect(page.locator("#seam-text")).to_contain_text(f"Seam 1 of {n}")
            expect(page.locator("#pose-text")).to_contain_text("pose")
            expect(page.locator("#time-left")).to_contain_text("Time left: about")
            expect(page.locator("#arc")).to_have_text("ON", timeout=10_000)
            expect(page.locator("#overlay-svg polyline[data-status=current]")).to_have_count(1)
            assert page.locator("#overlay-svg polyline[data-status=pending]").count() == n - 1
            expect(page.locator("#overlay-img")).to_have_attribute("src", _blob())
            shot("2-welding", "weld")

            # on to the third seam: the first two are marked welded on the overlay
            expect(page.locator("#seam-text")).to_contain_text(f"Seam 3 of {n}", timeout=30_000)
            expect(page.locator("#seam-text")).to_contain_text("2 welded")
            expect(page.locator("#overlay-svg polyline[data-status=welded]")).to_have_count(2)
            welding = shot("3-two-welded", "weld")
            if os.environ.get("WELDCELL_DOCS_SCREENSHOT"):  # the picture in docs/operator-page.md
                (REPO / "docs" / "operator-page.png").write_bytes(welding)

            # pause (arm still, arc off) and resume, from the page, while the arc is on: in the middle of a seam's
            # travel (a pause that falls between two motions is not applied before the weld activity returns)
            expect(page.locator("#arc")).to_have_text("ON", timeout=10_000)
            page.click("#pause")
            expect(page.locator("#message")).to_contain_text("pause: done", timeout=10_000)
            expect(page.locator("#state")).to_have_text("paused")
            expect(page.locator("#arc")).to_have_text("off")
            assert daemon.sim is not None and daemon.sim.simulated_arc_on() is False
            shot("4-paused", "pause")
            page.click("#resume")
            expect(page.locator("#state")).to_have_text("welding")
            # a protective stop in the simulated controller: the page says what happened and what to do
            assert api(base, "/sim/faults", {"device": "robot", "fault": "protective_stop"})[0] == 200
            expect(page.locator("#state")).to_have_text("fault", timeout=10_000)
            expect(page.locator("#fault-sentence")).to_have_text(
                "The robot stopped itself (protective stop): the arm is still and the arc is off."
            )
            expect(page.locator("#fault-action")).to_contain_text("then press Acknowledge")
            expect(page.locator("#acknowledge")).to_be_enabled()
            expect(page.locator("#arc")).to_have_text("off")
            shot("5-fault", "fault")
            assert api(base, "/sim/faults/clear", {})[0] == 200
            page.click("#acknowledge")
            # the daemon answers within its 30 s wait for the job runner; the message says how it went
            expect(page.locator("#message")).to_contain_text("acknowledge", timeout=45_000)
            assert page.locator("#message").inner_text().startswith("acknowledge: done"), page.locator(
                "#message"
            ).inner_text()
            expect(page.locator("#state")).to_have_text("idle", timeout=15_000)
            expect(page.locator("#fault-sentence")).to_contain_text("Last fault (acknowledged by Ada)")
            row = page.locator("#history tr").first
            expect(row).to_contain_text("failed")
            view = wait_for(lambda: api(base, f"/jobs/{job_id}")[1]["duration_s"], timeout_s=10, what="duration")
            cells = row.locator("td").all_inner_texts()
            assert cells[0] == str(job_id) and cells[2] == "failed" and cells[3] == "fault"
            assert cells[5] == (f"{round(view) // 60} min {round(view) % 60} s" if view >= 59.5 else f"{round(view)} s")
            shot("6-acknowledged", "idle")
            assert errors == []
        finally:
            browser.close()
    assert sorted(p.name for p in shots.iterdir()) == [
        "1-idle.png", "2-welding.png", "3-two-welded.png", "4-paused.png", "5-fault.png", "6-acknowledged.png",
    ]  # fmt: skip


def _blob() -> Any:
    return re.compile(r"^blob:")


@needs_browser
@pytest.mark.timeout(60)
def test_a_status_request_the_cell_never_answers_does_not_freeze_the_page(cell: tuple[Daemon, str]) -> None:
    _, base = cell
    held: list[Any] = []

    def hold_the_first(route: Any) -> None:
        if not held:
            held.append(route)  # never answered: the page gives it up after request_ms and polls again
        else:
            route.continue_()

    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.route("**/status", hold_the_first)
            page.goto(f"{base}/?poll_ms=250&request_ms=1000#token={TOKEN}")
            sync_api.expect(page.locator("#state")).to_have_text("idle", timeout=10_000)
            assert len(held) == 1
        finally:
            browser.close()
