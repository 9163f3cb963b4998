"""The house's size rules, measured with ``ast``: functions over 80 lines, modules over 700, modules without tests.

A function may be longer than 80 lines (decorators and docstring included) when it says why: a comment starting with
``# long:`` on its ``def`` line or in the comment lines directly above it. ``tests/test_architecture.py`` enforces the
rules on the packages and scripts/; run ``.venv/bin/python -m tests.house_size`` for the whole list, tests included.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("calibration", "cell", "drivers", "perception", "sim_fakes")
MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = 700
REASON = "# long:"


@dataclass(frozen=True)
class LongFunction:
    path: Path
    line: int  # of the def (or its first decorator)
    name: str  # qualified: Class.method, outer.inner
    lines: int
    reason: str | None  # the ``# long:`` comment's text, None when it has none

    def __str__(self) -> str:
        why = f"  ({self.reason})" if self.reason else "  (no reason given)"
        return f"{self.path.relative_to(REPO)}:{self.line} {self.name} {self.lines} lines{why}"


def python_files(*, tests: bool = False) -> list[Path]:
    """The product's modules (the packages and scripts/), with ``tests`` the test modules too."""
    roots = [*PACKAGES, "scripts", *(("tests",) if tests else ())]
    return sorted(p for root in roots for p in (REPO / root).rglob("*.py"))


def _reason(lines: list[str], node: ast.FunctionDef | ast.AsyncFunctionDef) -> str | None:
    """The ``# long:`` comment on the def line or in the comment block right above the def (and its decorators)."""
    first = min([node.lineno, *(d.lineno for d in node.decorator_list)]) - 1  # 0-based
    candidates = [lines[node.lineno - 1]]
    i = first - 1
    while i >= 0 and lines[i].lstrip().startswith("#"):
        candidates.append(lines[i])
        i -= 1
    for text in candidates:
        at = text.find(REASON)
        if at >= 0:
            return text[at + len(REASON) :].strip() or None
    return None


def long_functions(path: Path, *, limit: int = MAX_FUNCTION_LINES) -> list[LongFunction]:
    """Every function (methods and nested functions included) of ``path`` longer than ``limit`` lines."""
    text = path.read_text(encoding="utf-8")
    lines = text.splitlines()
    out: list[LongFunction] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                first = min([child.lineno, *(d.lineno for d in child.decorator_list)])
                assert child.end_lineno is not None
                n = child.end_lineno - first + 1
                if n > limit:
                    out.append(LongFunction(path, first, prefix + child.name, n, _reason(lines, child)))
                visit(child, f"{prefix}{child.name}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            else:
                visit(child, prefix)

    visit(ast.parse(text, filename=str(path)), "")
    return out


def module_lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def long_modules(paths: list[Path], *, limit: int = MAX_MODULE_LINES) -> list[tuple[Path, int]]:
    return [(p, n) for p in paths if (n := module_lines(p)) > limit]


def untested_modules() -> list[Path]:
    """Package modules with no ``tests/**/test_<name>.py`` or ``test_<name>_*.py`` (``test_run_command.py``,
    ``test_sim_cli.py``); ``__init__`` and modules of under 20 lines aside. By name only: a file of that name
    anywhere under tests/ counts, whatever it tests."""
    stems = [p.stem.removeprefix("test_") for p in (REPO / "tests").rglob("test_*.py")]
    out = []
    for package in PACKAGES:
        for p in sorted((REPO / package).rglob("*.py")):
            if p.stem == "__init__" or module_lines(p) < 20:
                continue
            if not any(stem == p.stem or stem.startswith(p.stem + "_") for stem in stems):
                out.append(p)
    return out


def main() -> None:
    files = python_files(tests=True)
    print(f"functions over {MAX_FUNCTION_LINES} lines:")
    for f in (f for p in files for f in long_functions(p)):
        print(f"  {f}")
    print(f"modules over {MAX_MODULE_LINES} lines:")
    for p, n in long_modules(files):
        print(f"  {p.relative_to(REPO)} {n}")
    print("package modules without a tests/**/test_<name>.py:")
    for p in untested_modules():
        print(f"  {p.relative_to(REPO)} ({module_lines(p)} lines)")


if __name__ == "__main__":
    main()
