"""Suite-wide checks: every seams.json a test writes conforms to the published schema (tests/seams_validation.py).

A test that writes a non-conforming seams.json on purpose puts it in a folder named ``invalid-on-purpose``.
"""

from __future__ import annotations

import signal
import warnings
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.seams_validation import invalid_seams_files

# The slowest files, slowest first (wall seconds measured with --durations=0): scripts/bootstrap.sh runs the suite
# with pytest-xdist's --dist loadfile --no-loadscope-reorder, which hands out whole files in collection order, so
# these start first and no worker is left alone with a long file at the end. An ordering hint only: a file missing
# here runs later, in its usual order; a stale list costs time, never a result.
SLOW_FILES_FIRST = (
    "tests/cell/test_runner.py",
    "tests/cell/test_daemon.py",
    "tests/cell/test_soak.py",
    "tests/drivers/test_ur.py",
    "tests/cell/test_real_bench.py",
    "tests/cell/test_sample_package_data.py",
    "tests/perception/test_detect.py",
    "tests/cell/test_seam_bench.py",
    "tests/sim_fakes/test_render.py",
    "tests/cell/test_operator_page.py",
    "tests/calibration/test_wizard.py",
    "tests/cell/test_calibrate_cli.py",
    "tests/perception/fine/test_grooves.py",
    "tests/perception/fine/test_surfaces.py",
    "tests/cell/test_sim_cli.py",
    "tests/sim_fakes/test_zoo.py",
    "tests/cell/test_daemon_ur.py",
)


def pytest_configure(config: pytest.Config) -> None:
    # a suite started as a background job of a shell without job control inherits SIGINT ignored (POSIX), and so
    # would every command the tests start: the Ctrl-C tests (the calibration wizard's, `weldcell calibrate`'s)
    # need it delivered as at a terminal. In each xdist worker too (each runs this hook).
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    rank = {config.rootpath / path: k for k, path in enumerate(SLOW_FILES_FIRST)}
    items.sort(key=lambda item: rank.get(item.path, len(rank)))  # stable: the rest keep their order


@pytest.fixture(autouse=True)
def _stop_signal_handlers_are_left_as_found(request: pytest.FixtureRequest) -> Iterator[None]:
    """A test that leaves SIGINT or SIGTERM ignored or rerouted in this process (an in-process command's signal
    handling that did not unwind) would make the later tests of the same worker, and the commands they start as
    child processes (which inherit an ignored signal), deaf to Ctrl-C: put back, and said in the warnings."""
    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield
    for sig, handler in before.items():
        now = signal.getsignal(sig)
        if now is not handler and now != handler:
            signal.signal(sig, handler)
            warnings.warn(f"{request.node.nodeid} left {sig.name} at {now!r}: put back", stacklevel=1)


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


@pytest.fixture(autouse=True, scope="session")
def _compiled_kernels_ready() -> None:
    """The detector's compiled kernels loaded (or compiled, on a machine's first run: about 10 s) once per test
    process before any test, as the daemon, the demo and the helper do when they start: a test that waits a
    bounded time for a job must not wait for a compiler (scripts/bootstrap.sh compiles them at setup)."""
    from perception.fine.compiled import warm_up

    warm_up()
