"""cell.request_parsing: query flags, JSON object bodies and UTF-8 text, each bad one a ConfigError (a 400)."""

from __future__ import annotations

import pytest

from cell.errors import ConfigError
from cell.request_parsing import body_text, parse_flag, parse_json_object


@pytest.mark.parametrize(("value", "flag"), [("1", True), ("TRUE", True), (" yes ", True), ("0", False),
                                             ("false", False), ("No", False)])  # fmt: skip
def test_flags(value: str, flag: bool) -> None:
    assert parse_flag(value, "?dry_run") is flag


def test_a_bad_flag_names_what_is_allowed() -> None:
    with pytest.raises(ConfigError, match=r"\?dry_run must be one of 1, true, yes, 0, false, no"):
        parse_flag("maybe", "?dry_run")


def test_json_objects() -> None:
    assert parse_json_object('{"a": [1, 2]}') == {"a": [1, 2]}
    assert parse_json_object("") == {}
    with pytest.raises(ConfigError, match=r"not valid JSON \(line 2, column 1\)"):
        parse_json_object('{"a": 1,\n}')
    with pytest.raises(ConfigError, match="send a JSON object"):
        parse_json_object("[1]")
    with pytest.raises(ConfigError, match="nested too deeply"):
        parse_json_object("[" * 100_000)


def test_body_text() -> None:
    assert body_text("grüß".encode()) == "grüß"
    with pytest.raises(ConfigError, match="not UTF-8"):
        body_text(b"\xff\xfe")
