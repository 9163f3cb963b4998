"""``weldcell schema``: print the JSON Schema of a weldcell file format, or check files against it."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "schema",
        help="print the JSON Schema of seams.json (or check files against it with --check)",
        description="The JSON Schema (draft 2020-12) generated from weldcell's models of the format "
        "(perception/seams_schema.py; spec: capture-format.md). Exit 2 when a --check file does not conform.",
    )
    p.add_argument("format", choices=("seams",), help="seams: seams.json, the output of 'weldcell detect'")
    p.add_argument("--check", nargs="+", metavar="FILE", help="validate these files instead of printing the schema")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from perception.errors import BadCapture
    from perception.seams_schema import FORMAT_VERSION, SeamsFileModel, seams_json_schema

    if not args.check:
        print(json.dumps(seams_json_schema(), indent=2))
        return 0
    for name in args.check:
        path = Path(name)
        try:
            SeamsFileModel.model_validate_json(path.read_bytes())
        except OSError as err:
            raise BadCapture(f"cannot read it: {err.strerror}", path=path) from err
        except ValidationError as err:
            first = err.errors()[0]
            where = "/".join(str(x) for x in first["loc"]) or "(top level)"
            raise BadCapture(
                f"does not conform to seams.json {FORMAT_VERSION}: {where}: {first['msg']} "
                f"({err.error_count()} problem(s); 'weldcell schema seams' prints the schema)",
                path=path,
            ) from err
        print(f"{path}: ok")
    return 0
