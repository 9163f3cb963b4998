"""Every seams.json the tests write is validated against ``weldcell schema seams`` (tests/conftest.py)."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

import jsonschema

from perception.seams_schema import seams_json_schema

NOT_SEAMS = frozenset({"ground_truth.json"})  # the capture format's truth file also has a "seams" list
ON_PURPOSE = "invalid-on-purpose"  # a folder for files a test makes non-conforming deliberately


@cache
def _validator() -> jsonschema.protocols.Validator:
    schema = seams_json_schema()
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    return cls(schema)


def seams_json_errors(doc: Any) -> list[str]:
    """Schema violations of one parsed seams.json, as 'path: message' lines (empty when valid)."""
    return [
        f"{'/'.join(str(p) for p in err.absolute_path) or '(top level)'}: {err.message}"
        for err in _validator().iter_errors(doc)
    ]


def seams_files_under(root: Path) -> list[Path]:
    """JSON files under ``root`` that are seams.json documents: an object with a 'seams' list, by content, so
    that a file named s.json or batch output counts too."""
    found = []
    for path in sorted(root.rglob("*.json")):
        if path.name in NOT_SEAMS or ON_PURPOSE in path.relative_to(root).parts or not path.is_file():
            continue
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            continue
        if isinstance(doc, dict) and isinstance(doc.get("seams"), list) and "frame" in doc:
            found.append(path)
    return found


def invalid_seams_files(root: Path) -> dict[Path, list[str]]:
    out = {}
    for path in seams_files_under(root):
        errors = seams_json_errors(json.loads(path.read_text(encoding="utf-8")))
        if errors:
            out[path] = errors
    return out
