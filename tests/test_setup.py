"""The setup's pins: constraints.txt bounds every dependency of pyproject.toml, and bootstrap.sh uses it."""

from __future__ import annotations

import tomllib
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]


def _declared() -> dict[str, Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    reqs = list(project["dependencies"])
    for extra in project.get("optional-dependencies", {}).values():
        reqs.extend(extra)
    return {canonicalize_name(Requirement(r).name): Requirement(r) for r in reqs}


def _constraints() -> dict[str, Requirement]:
    out: dict[str, Requirement] = {}
    for line in (ROOT / "constraints.txt").read_text(encoding="utf-8").splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            req = Requirement(line)
            name = canonicalize_name(req.name)
            assert name not in out, f"constraints.txt names {name} twice"
            out[name] = req
    return out


def test_every_declared_dependency_has_a_major_bound_in_constraints():
    declared, constraints = _declared(), _constraints()
    missing = sorted(set(declared) - set(constraints))
    assert not missing, f"add a line '<name><<next major>' to constraints.txt for: {missing}"
    stale = sorted(set(constraints) - set(declared))
    assert not stale, f"constraints.txt bounds packages pyproject.toml no longer declares: {stale}"
    for name, req in constraints.items():
        uppers = [s for s in req.specifier if s.operator == "<"]
        assert len(uppers) == 1, f"{name}: a constraint is one upper bound '<X', got '{req.specifier}'"
        bound = Version(uppers[0].version)
        # a major bound: X (or 0.Y for 0.x packages), never a patch-level pin
        assert bound.micro == 0 and (bound.minor == 0 or bound.major == 0), f"{name}: '<{bound}' is not a major bound"


def test_the_installed_versions_satisfy_the_constraints():
    for name, req in _constraints().items():
        try:
            installed = version(name)
        except PackageNotFoundError:
            continue  # an extra (ray) or the other platform's open3d
        assert req.specifier.contains(installed, prereleases=True), f"{name} {installed} violates '{req}'"


def test_bootstrap_installs_with_the_constraints_and_opencv_is_4():
    script = (ROOT / "scripts" / "bootstrap.sh").read_text(encoding="utf-8")
    assert "-c constraints.txt" in script
    assert "constraints.txt" in script.split("stamp_want=", 1)[1].splitlines()[0]  # a change reinstalls
    assert str(_constraints()["opencv-contrib-python-headless"].specifier) == "<5"


def test_version_is_the_pyproject_version(capsys):
    from cell.cli import main

    expected = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["version"]
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"weldcell {expected}"
