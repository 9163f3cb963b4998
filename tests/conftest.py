"""Suite-wide checks: every seams.json a test writes conforms to the published schema (tests/seams_validation.py).

A test that writes a non-conforming seams.json on purpose puts it in a folder named ``invalid-on-purpose``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.seams_validation import invalid_seams_files


def _report(bad: dict[Path, list[str]]) -> str:
    return "; ".join(f"{path}: {errors[0]} ({len(errors)} problem(s))" for path, errors in bad.items())


@pytest.fixture(autouse=True)
def _seams_json_written_by_this_test_conforms(request: pytest.FixtureRequest) -> Iterator[None]:
    # requested before the test runs, so that tmp_path is still there when this fixture tears down
    tmp_path = request.getfixturevalue("tmp_path") if "tmp_path" in request.fixturenames else None
    yield
    if tmp_path is not None:
        bad = invalid_seams_files(tmp_path)
        if bad:
            pytest.fail(f"seams.json written by this test does not conform to 'weldcell schema seams': {_report(bad)}")


@pytest.fixture(autouse=True, scope="session")
def _seams_json_written_anywhere_conforms(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    # also the files written into tmp_path_factory folders, which the per-test check does not see
    yield
    bad = invalid_seams_files(tmp_path_factory.getbasetemp())
    if bad:
        pytest.fail(f"seams.json written by the tests does not conform to 'weldcell schema seams': {_report(bad)}")
