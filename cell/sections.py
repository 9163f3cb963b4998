"""Typed TOML tables: the :class:`Section` base every table of a cell config or a job file derives from, and the
messages that say what a file got wrong (which key, what was expected, the offending line)."""

from __future__ import annotations

import re
import tomllib
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict

from perception.transforms import TransformError, check_X


def check_matrix(value: list[list[float]] | None, name: str) -> None:
    """ValueError (for pydantic) unless ``value`` is None or a proper 4x4 rigid transform."""
    if value is None:
        return
    try:
        check_X(np.asarray(value, dtype=np.float64), name=name)
    except (TransformError, ValueError) as err:
        raise ValueError(str(err)) from err


class Section(BaseModel):
    """Base of every config table: strict types, unknown keys refused, immutable once read."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)


def toml_context(err: tomllib.TOMLDecodeError, text: str) -> str:
    """The decoder's message, the dotted key being written when it failed, and the offending line."""
    msg = str(err)
    found = re.search(r"at line (\d+)", msg)
    lines = text.splitlines()
    if found is None or not 1 <= int(found.group(1)) <= len(lines):
        return msg
    lineno = int(found.group(1))
    line = lines[lineno - 1].strip()
    table = ""
    for previous in reversed(lines[: lineno - 1]):
        header = re.match(r"\s*\[+\s*([^\]]+?)\s*\]+", previous)
        if header:
            table = header.group(1)
            break
    assigned = re.match(r"\s*([A-Za-z0-9_\-.\"']+)\s*=", line)
    key = ".".join(k for k in (table, assigned.group(1) if assigned else "") if k)
    where = f"{key} " if key else ""
    return f"{msg}; {where}(line {lineno}: {line!r})"


def describe_validation_error(error: Any, root: type[BaseModel]) -> str:
    """One pydantic error as 'where: what' for a TOML file whose schema is ``root`` (cell or job)."""
    loc = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in error["loc"]).replace(".[", "[")
    kind = error["type"]
    msg = str(error["msg"])
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    if kind == "extra_forbidden":
        allowed = _allowed_keys(error["loc"][:-1], root)
        hint = f" (allowed: {', '.join(allowed)})" if allowed else ""
        return f"{loc}: unknown key{hint}"
    if kind == "missing":
        return f"{loc}: required key is missing"
    if kind in ("model_type", "dict_type") and not loc:
        return f"the file must be a table of sections, got {type(error['input']).__name__}"
    got = error.get("input")
    shown = (
        ""
        if isinstance(got, dict) or kind.startswith("value_error") or kind == "assertion_error"
        else f" (got {got!r})"
    )
    return f"{loc or 'file'}: {msg}{shown}"


def _allowed_keys(loc: tuple[Any, ...], root: type[BaseModel]) -> list[str]:
    model = root
    for part in loc:
        if isinstance(part, int):
            continue  # an index into a list of tables
        field = model.model_fields.get(str(part))
        if field is None:
            return []
        inner = _model_of(field.annotation)
        if inner is None:
            return []
        model = inner
    return list(model.model_fields)


def _model_of(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()):
        inner = _model_of(arg)
        if inner is not None:
            return inner
    return None
