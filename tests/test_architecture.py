"""docs/architecture.md stays true: every cross-package import in the code is an arrow its table allows.

The allowed arrows are read from the document itself (the table between the ``arrows`` markers), so the page and
this test cannot drift apart. Imports are found with ``ast``, so imports inside functions (lazy imports) and
``TYPE_CHECKING`` blocks count too.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from tests.house_size import MAX_FUNCTION_LINES, MAX_MODULE_LINES, long_functions, long_modules, python_files

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "architecture.md"
PACKAGES = ("calibration", "cell", "drivers", "perception", "sim_fakes")

KNOWN_EXCEPTIONS: frozenset[tuple[str, str]] = frozenset()
"""(importer module, imported module) arrows still in the code that the document does not allow, each with the
issue that removes it; an exception that is no longer in the code fails the test, so the list only shrinks."""

Arrow = tuple[str, str]


def allowed_arrows(text: str) -> list[tuple[str, tuple[str, ...]]]:
    """The rows of the arrows table: (importer, names it may import), names as dotted module paths."""
    m = re.search(r"<!-- arrows:.*?-->\n(.*?)<!-- end of arrows -->", text, flags=re.S)
    if m is None:
        raise AssertionError(f"{DOC}: no arrows table between '<!-- arrows: ...-->' and '<!-- end of arrows -->'")
    rows = []
    for line in m.group(1).strip().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 2 or cells[0] in ("importer", "") or set(cells[0]) <= {"-"}:
            continue
        importer = cells[0].strip("`")
        names = tuple(n.strip().strip("`") for n in cells[1].split(",") if n.strip())
        rows.append((importer, names))
    return rows


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path) -> set[str]:
    """Every absolute module name ``path`` imports (``from a.b import c`` gives ``a.b`` and ``a.b.c``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                raise AssertionError(f"{path}: relative import (level {node.level}); weldcell imports absolutely")
            assert node.module is not None
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def within(module: str, name: str) -> bool:
    return module == name or module.startswith(name + ".")


def cross_package_arrows() -> set[Arrow]:
    arrows: set[Arrow] = set()
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            importer = module_name(path)
            for imported in imports_of(path):
                top = imported.split(".")[0]
                if top in PACKAGES and top != package:
                    arrows.add((importer, imported))
    return arrows


def existing_modules() -> set[str]:
    return {module_name(p) for package in PACKAGES for p in (REPO / package).rglob("*.py")}


def is_allowed(arrow: Arrow, rows: list[tuple[str, tuple[str, ...]]], modules: set[str]) -> bool:
    importer, imported = arrow
    # ``from perception.capture import Capture`` names an attribute, not a module: judge the module it is in
    target = imported if imported in modules else imported.rsplit(".", 1)[0]
    return any(within(importer, row) and any(within(target, name) for name in names) for row, names in rows)


def test_every_cross_package_import_is_an_arrow_the_document_allows() -> None:
    rows = allowed_arrows(DOC.read_text(encoding="utf-8"))
    modules = existing_modules()
    arrows = cross_package_arrows()
    # one arrow per (importer, module): ``from a.b import c, d`` is one arrow to a.b unless c is a module
    by_module = {(i, m if m in modules else m.rsplit(".", 1)[0]) for i, m in arrows}
    refused = sorted(a for a in by_module if not is_allowed(a, rows, modules) and a not in KNOWN_EXCEPTIONS)
    assert refused == [], "imports docs/architecture.md does not allow (importer -> imported):\n" + "\n".join(
        f"  {i} -> {m}" for i, m in refused
    )
    stale = sorted(a for a in KNOWN_EXCEPTIONS if a not in by_module)
    assert stale == [], f"known exceptions no longer in the code (remove them from KNOWN_EXCEPTIONS): {stale}"


def test_the_table_names_only_modules_that_exist_and_every_package() -> None:
    rows = allowed_arrows(DOC.read_text(encoding="utf-8"))
    modules = existing_modules()
    named = {row for row, _ in rows} | {n for _, names in rows for n in names}
    assert sorted(n for n in named if n not in modules) == []
    assert {row for row, _ in rows if row in PACKAGES} == set(PACKAGES)
    # the top of the house: nothing may import cell
    assert not any(within(n, "cell") for _, names in rows for n in names)


@pytest.mark.parametrize(
    ("arrow", "allowed"),
    [
        (("drivers.ur", "perception.transforms"), True),
        (("drivers.ur", "perception.detect"), False),  # a driver needs value types, not the detector
        (("perception.detect", "cell.config"), False),
        (("sim_fakes.fake_camera", "calibration.board"), False),  # the fake draws any BoardPicture
        (("calibration.simulate", "sim_fakes.board_render"), False),  # the renderer is handed in
        (("cell.commands.bench_calibration", "sim_fakes.board_render"), True),
        (("calibration.wizard", "drivers.protocols"), True),
        (("calibration.handeye", "drivers.protocols"), False),  # the solver stays pure
        (("cell.commands.simulate", "sim_fakes.render"), True),
        (("cell.runner", "sim_fakes.fake_ur"), False),
        (("cell.factory", "perception.capture.Capture"), True),
    ],
)
def test_the_rule_reads_the_table_as_written(arrow: Arrow, allowed: bool) -> None:
    rows = allowed_arrows(DOC.read_text(encoding="utf-8"))
    assert is_allowed(arrow, rows, existing_modules()) is allowed


KNOWN_LONG: frozenset[str] = frozenset()  # issue 15's three were split (score_capture, inner_gap_seams, dashboard)
"""Functions over the limit without a ``# long:`` reason, by "path:qualified name"; the list only shrinks."""


def test_no_function_over_80_lines_without_a_reason_and_no_module_over_700() -> None:
    files = python_files()
    unexplained = {f"{f.path.relative_to(REPO)}:{f.name}": f for p in files for f in long_functions(p) if not f.reason}
    new = sorted(str(f) for key, f in unexplained.items() if key not in KNOWN_LONG)
    assert new == [], (
        f"functions over {MAX_FUNCTION_LINES} lines: split them, or say why on the def line with '# long: ...':\n"
        + "\n".join(new)
    )
    assert sorted(KNOWN_LONG - set(unexplained)) == [], "no longer long or now explained: remove from KNOWN_LONG"
    assert [f"{p.relative_to(REPO)}: {n} lines" for p, n in long_modules(files)] == [], (
        f"modules over {MAX_MODULE_LINES} lines: split them by idea"
    )


def test_the_size_rules_count_what_they_say(tmp_path: Path) -> None:
    body = "\n".join(f"    x{i} = {i}" for i in range(79))
    short = f"def short():\n{body}\n"  # 80 lines with its def
    long = f"@staticmethod\ndef long():\n{body}\n    return 0\n"  # 82 with the decorator
    why = f"class C:\n    # long: a table of cases\n    def why(self):\n{body}\n        return 0\n"
    path = tmp_path / "m.py"
    path.write_text(short + long + why.replace("\n    x", "\n        x"), encoding="utf-8")
    found = {(f.name, f.lines, f.reason) for f in long_functions(path)}
    assert found == {("long", 82, None), ("C.why", 81, "a table of cases")}  # short (80) is within the rule
    assert long_modules([path], limit=245) == [] and long_modules([path], limit=244) == [(path, 245)]


def documented_modules(text: str) -> list[str]:
    m = re.search(r"<!-- modules:.*?-->\n(.*?)<!-- end of modules -->", text, flags=re.S)
    if m is None:
        raise AssertionError(f"{DOC}: no module tables between '<!-- modules: ...-->' and '<!-- end of modules -->'")
    return re.findall(r"^\| `([\w.]+)` \|", m.group(1), flags=re.M)


def test_the_document_names_every_module_once_and_no_other() -> None:
    documented = documented_modules(DOC.read_text(encoding="utf-8"))
    modules = {module_name(p) for package in PACKAGES for p in (REPO / package).rglob("*.py") if p.stem != "__init__"}
    assert sorted(m for m in modules if m not in documented) == [], "modules docs/architecture.md does not list"
    assert sorted(m for m in documented if m not in modules) == [], "docs/architecture.md lists modules that are gone"
    assert len(documented) == len(set(documented))
