"""cell.sections: the strict Section base and the messages that say what a TOML file got wrong."""

from __future__ import annotations

import tomllib

import pytest
from pydantic import Field, ValidationError

from cell.sections import Section, check_matrix, describe_validation_error, toml_context


class Inner(Section):
    speed_m_s: float = Field(gt=0)
    name: str = "a"


class Root(Section):
    inner: Inner
    items: list[Inner] = Field(default_factory=list)


def messages(data: dict) -> list[str]:
    with pytest.raises(ValidationError) as info:
        Root.model_validate(data)
    return [describe_validation_error(e, Root) for e in info.value.errors(include_url=False)]


def test_each_pydantic_error_becomes_key_and_problem() -> None:
    assert messages({"inner": {"speed_m_s": 1.0, "nmae": "x"}}) == [
        "inner.nmae: unknown key (allowed: speed_m_s, name)"
    ]
    assert messages({"inner": {}}) == ["inner.speed_m_s: required key is missing"]
    assert messages({"inner": {"speed_m_s": -2.0}}) == ["inner.speed_m_s: Input should be greater than 0 (got -2.0)"]
    assert messages({"inner": {"speed_m_s": "fast"}}) == [
        "inner.speed_m_s: Input should be a valid number (got 'fast')"
    ]
    assert messages({"inner": {"speed_m_s": 1.0}, "items": [{"speed_m_s": 1.0, "x": 1}]}) == [
        "items[0].x: unknown key (allowed: speed_m_s, name)"
    ]


def test_sections_are_strict_and_frozen() -> None:
    inner = Inner(speed_m_s=1)  # an integer where a float is expected is fine
    assert inner.speed_m_s == 1.0
    with pytest.raises(ValidationError):
        inner.name = "b"  # type: ignore[misc]
    with pytest.raises(ValidationError):
        Inner(speed_m_s=float("inf"))


def test_a_toml_syntax_error_names_the_key_and_shows_the_line() -> None:
    text = '[robot]\nhost = "x"\n\n[track]\nport = 50 2\n'
    with pytest.raises(tomllib.TOMLDecodeError) as info:
        tomllib.loads(text)
    assert toml_context(info.value, text) == f"{info.value}; track.port (line 5: 'port = 50 2')"


def test_check_matrix_passes_none_and_rigid_transforms_only() -> None:
    check_matrix(None, "X_a_b")
    check_matrix([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]], "X_a_b")
    with pytest.raises(ValueError, match=r"^X_a_b: expected shape \(4, 4\), got \(1, 1\)$"):
        check_matrix([[1.0]], "X_a_b")
