"""Request values of the daemon's HTTP API read into Python values, with ConfigError (a 400) for bad ones."""

from __future__ import annotations

import json
from typing import Any

from cell.errors import ConfigError


def parse_flag(value: str, what: str) -> bool:
    """A query flag: ``1|true|yes`` or ``0|false|no`` (any case); ConfigError for anything else."""
    low = value.strip().lower()
    if low in ("1", "true", "yes"):
        return True
    if low in ("0", "false", "no"):
        return False
    raise ConfigError(f"{what} must be one of 1, true, yes, 0, false, no")


def parse_json_object(text: str) -> dict[str, Any]:
    """A JSON object from a request body; ConfigError for anything else (the position, never the text)."""
    try:
        obj = json.loads(text or "{}")
    except json.JSONDecodeError as err:
        raise ConfigError(f"the request body is not valid JSON (line {err.lineno}, column {err.colno})") from err
    except RecursionError as err:
        raise ConfigError("the request body is nested too deeply") from err
    if not isinstance(obj, dict):
        raise ConfigError("send a JSON object")
    return obj


def body_text(body: bytes) -> str:
    """A request body as text; ConfigError when it is not UTF-8."""
    try:
        return body.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError("the request body is not UTF-8 text") from err
