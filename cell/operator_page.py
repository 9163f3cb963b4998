"""The operator page served at ``GET /`` (docs/operator-page.md): one self-contained HTML file, its style and
script inline, nothing fetched from elsewhere (the cell has no internet).

The page polls ``GET /status`` (every second; ``?poll_ms=`` changes it) and draws: the cell state, large and in
its colour; the current job's seam k of n, its pass (travel pose p of q) and the time left; the overlay of the
capture being welded with each seam marked welded, current or pending (an SVG over ``/status.png``); the robot, the
track, the camera and the arc output; the fault in one sentence with its cause and what to do; the job history
with durations. Its buttons (approve, reject, pause, resume, abort, acknowledge) POST the same JSON as any client,
with the operator's name, through the same guards: with ``[daemon] token`` the page asks for the token (or takes
it from ``#token=...`` in the address) and sends ``Authorization: Bearer`` with every request.
"""

from __future__ import annotations

from functools import cache
from importlib.resources import files

PAGE_FILE = "operator_page.html"


@cache
def page_html() -> str:
    """The page's HTML (package data next to this module)."""
    return files("cell").joinpath(PAGE_FILE).read_text(encoding="utf-8")
