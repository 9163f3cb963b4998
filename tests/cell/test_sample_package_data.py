"""weldcell demo from an installed wheel: the sample capture is package data of ``cell``, found via importlib."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import cell
from cell.commands.detect import sample_capture_dir

REPO = Path(__file__).resolve().parents[2]
CAPTURE_FILES = {"camera.json", "color.png", "depth.png", "ground_truth.json", "pose.json", "prompts.json"}


def test_the_sample_is_found_inside_the_cell_package():
    sample = sample_capture_dir()
    assert sample.parent.parent == Path(cell.__file__).parent
    assert {p.name for p in sample.iterdir()} == CAPTURE_FILES


def test_the_wheel_takes_every_file_of_the_sample_and_the_checkout_path_still_works():
    data = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    package_dir = Path(cell.__file__).parent
    shipped = {p for pattern in data["cell"] for p in package_dir.glob(pattern) if p.is_file()}
    # setuptools globs package-data the same way; the operator page (cell.operator_page) ships beside the sample
    assert {p.name for p in shipped} == CAPTURE_FILES | {"operator_page.html"}
    assert (REPO / "samples" / "ribs").resolve() == sample_capture_dir().resolve()


def test_weldcell_demo_runs_from_a_built_wheel(tmp_path):
    # the wheel as pip builds it (isolated build, the pinned setuptools), unpacked and imported instead of the
    # checkout: the demo must find its sample through importlib.resources inside the installed package
    wheels, target, source = tmp_path / "wheels", tmp_path / "site", tmp_path / "source"
    # from a copy: setuptools leaves build/ and *.egg-info in the source tree, and a stale build/lib would
    # go into the next wheel
    junk = (".venv", ".git", "build", "out", "bench-out", "*.egg-info", "__pycache__", ".mypy_cache", ".ruff_cache")
    shutil.copytree(REPO, source, ignore=shutil.ignore_patterns(*junk))
    pip = [sys.executable, "-m", "pip", "-qq"]
    subprocess.run([*pip, "wheel", "--no-deps", "-w", str(wheels), str(source)], check=True, timeout=300)
    (wheel,) = wheels.glob("weldcell-*.whl")
    subprocess.run([*pip, "install", "--no-deps", "--target", str(target), str(wheel)], check=True, timeout=300)
    code = (
        "import sys, cell; from cell.cli import main\n"
        f"assert cell.__file__.startswith({str(target)!r}), cell.__file__\n"
        f"sys.exit(main(['demo', '--out', {str(tmp_path / 'out')!r}]))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(target)}
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert re.search(r"against ground truth: [1-9]\d*/10 seams found", run.stdout), run.stdout
    assert (tmp_path / "out" / "seams.json").is_file()
