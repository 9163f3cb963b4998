"""perception/helper_process.py: jobs shared with a second process come back exactly as done in this one and in
order; both processes take some; the shared memory is kept from run to run and gone after the helper is
closed; a helper that dies or stops answering
leaves its jobs to this process (the same results, within a bound), and a new helper takes its place."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import perception.helper_process as hp
from perception.helper_process import HelperProcess

pytestmark = pytest.mark.timeout(120)

PARENT = os.getpid()


def scaled_sum(context: dict[str, float], arrays: dict[str, np.ndarray], job: int) -> tuple[int, float, int]:
    """Job ``job``: its number, the sum of row ``job`` of ``arrays["a"]`` times the context's scale, and the
    process that did it (each job takes 20 ms, so that both processes get some)."""
    time.sleep(0.02)
    return job, float(arrays["a"][job].sum()) * context["scale"], os.getpid()


def dies_in_helper(context: dict[str, Any], arrays: dict[str, np.ndarray], job: int) -> tuple[int, float, int]:
    """:func:`scaled_sum`, except that the helper process exits abruptly (a crash) on its first job."""
    if os.getpid() != context["parent"]:
        Path(context["flag"]).touch()
        os._exit(3)
    _wait_for_the_helper(context)
    return scaled_sum(context, arrays, job)


def hangs_in_helper(context: dict[str, Any], arrays: dict[str, np.ndarray], job: int) -> tuple[int, float, int]:
    """:func:`scaled_sum`, except that the helper process never answers (a hang)."""
    if os.getpid() != context["parent"]:
        Path(context["flag"]).touch()
        time.sleep(3600)
    _wait_for_the_helper(context)
    return scaled_sum(context, arrays, job)


def _wait_for_the_helper(context: dict[str, Any]) -> None:
    """In this process: wait (20 s at most) until the helper has claimed a job, so that it surely holds one
    (on a loaded machine it took longer to claim one than this process took for all ten)."""
    t0 = time.perf_counter()
    while not Path(context["flag"]).exists() and time.perf_counter() - t0 < 20.0:
        time.sleep(0.01)


def _leftover_blocks() -> list[str]:
    shm = Path("/dev/shm")
    return sorted(p.name for p in shm.glob("weldcell-*")) if shm.is_dir() else []


@pytest.fixture(scope="module")
def helper() -> HelperProcess:
    h = HelperProcess(preload=())
    assert h.wait_ready(60.0)
    yield h
    h.close()


def _arrays() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(7)
    return {"a": rng.normal(size=(40, 1000)), "mask": rng.integers(0, 2, (40, 3)).astype(bool)}


def test_jobs_shared_with_the_helper_come_back_exactly_and_in_order(helper: HelperProcess) -> None:
    arrays, context = _arrays(), {"scale": 0.5, "parent": PARENT}
    before = _leftover_blocks()
    out = helper.run(scaled_sum, context, arrays, list(range(40)))
    assert [job for job, _, _ in out] == list(range(40))
    assert [v for _, v, _ in out] == [float(arrays["a"][k].sum()) * 0.5 for k in range(40)]  # bit for bit
    pids = {pid for _, _, pid in out}
    assert PARENT in pids and len(pids) == 2  # both processes took jobs
    assert helper._block is not None  # the runs' block is kept for the next run, the only one added
    assert sorted(set(_leftover_blocks()) - set(before)) == [helper._block.name]


def test_a_single_job_or_a_helper_not_yet_started_does_everything_here() -> None:
    h = HelperProcess(preload=())
    try:
        out = h.run(scaled_sum, {"scale": 2.0, "parent": PARENT}, _arrays(), list(range(6)))
        if not h.ready:  # the helper was still starting: this process did all of them
            assert {pid for _, _, pid in out} == {PARENT}
        assert [v for _, v, _ in out] == [float(_arrays()["a"][k].sum()) * 2.0 for k in range(6)]
        assert h.wait_ready(60.0)
        (one,) = h.run(scaled_sum, {"scale": 2.0, "parent": PARENT}, _arrays(), [3])
        assert one[2] == PARENT
    finally:
        h.close()


def test_a_helper_that_dies_leaves_its_jobs_here_and_is_replaced(tmp_path: Path) -> None:
    h = HelperProcess(preload=())
    try:
        assert h.wait_ready(60.0)
        arrays, context = _arrays(), {"scale": 1.0, "parent": PARENT, "flag": str(tmp_path / "claimed")}
        out = h.run(dies_in_helper, context, arrays, list(range(20)))
        assert [v for _, v, _ in out] == [float(arrays["a"][k].sum()) for k in range(20)]
        assert {pid for _, _, pid in out} == {PARENT}
        assert not h.ready  # stopped; the next run starts a new one
        assert h.run(scaled_sum, context, arrays, [0, 1])[0][1] == float(arrays["a"][0].sum())
        assert h.wait_ready(60.0)
        out = h.run(scaled_sum, context, arrays, list(range(40)))
        assert len({pid for _, _, pid in out}) == 2  # the new helper takes jobs again
    finally:
        h.close()


def test_a_helper_that_stops_answering_is_waited_for_within_a_bound(monkeypatch: pytest.MonkeyPatch,
                                                                   tmp_path: Path) -> None:
    monkeypatch.setattr(hp, "WAIT_S", 0.5)
    monkeypatch.setattr(hp, "WAIT_FACTOR", 0.0)
    h = HelperProcess(preload=())
    try:
        assert h.wait_ready(60.0)
        arrays, context = _arrays(), {"scale": 1.0, "parent": PARENT, "flag": str(tmp_path / "claimed")}
        t0 = time.perf_counter()
        out = h.run(hangs_in_helper, context, arrays, list(range(10)))
        assert time.perf_counter() - t0 < 10.0
        assert [v for _, v, _ in out] == [float(arrays["a"][k].sum()) for k in range(10)]
        assert not h.ready
    finally:
        h.close()


def test_the_helper_keeps_only_the_last_runs_block_mapped(helper: HelperProcess) -> None:
    """A daemon's helper runs for months: each run's block is unmapped when the next run's arrives."""
    assert helper._warm is not None
    pid = helper._warm.result()
    arrays, context = _arrays(), {"scale": 1.0, "parent": PARENT}
    for _ in range(4):
        out = helper.run(scaled_sum, context, arrays, list(range(40)))
        assert pid in {p for _, _, p in out}
    maps = Path(f"/proc/{pid}/maps").read_text()
    assert len({line.split()[-1] for line in maps.splitlines() if "weldcell-" in line}) == 1


def test_the_kept_block_carries_each_runs_arrays_and_context_grows_and_goes_at_close() -> None:
    """Runs one after another with other arrays and another context each (the helper reads each run's, not
    the last it saw), a run larger than the block (a new block; the old one unlinked), and close (no block of
    the helper's left in /dev/shm)."""
    h = HelperProcess(preload=())
    before = set(_leftover_blocks())
    try:
        assert h.wait_ready(60.0)
        rng = np.random.default_rng(3)
        names = []
        for rows, scale in ((40, 1.0), (40, -3.0), (400, 0.25), (40, 7.0)):
            arrays = {"a": rng.normal(size=(rows, 1000))}
            out = h.run(scaled_sum, {"scale": scale, "parent": PARENT}, arrays, list(range(rows)))
            assert [v for _, v, _ in out] == [float(arrays["a"][k].sum()) * scale for k in range(rows)]
            assert len({pid for _, _, pid in out}) == 2  # the helper took some of each run's jobs
            assert h._block is not None
            names.append(h._block.name)
            assert sorted(set(_leftover_blocks()) - before) == [h._block.name]
        assert names[0] == names[1] != names[2] == names[3]  # kept; grown once for the 400 rows; kept again
    finally:
        h.close()
    assert set(_leftover_blocks()) - before == set()


def test_a_helper_whose_parent_is_killed_exits_with_it(tmp_path: Path) -> None:
    """A daemon killed with SIGKILL cannot close its helper: the helper sees its parent gone and exits (it held
    the daemon's output pipes open, so that whoever read them waited forever)."""
    import signal
    import subprocess
    import sys

    script = (
        "from perception.helper_process import HelperProcess\n"
        "import sys, time\n"
        "h = HelperProcess(preload=())\n"
        "assert h.wait_ready(60)\n"
        "print(h._warm.result(), flush=True)\n"
        "time.sleep(600)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        helper_pid = int(proc.stdout.readline())
        assert Path(f"/proc/{helper_pid}").exists()
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        t0 = time.perf_counter()
        assert proc.stdout.read() == ""  # EOF: no process holds the pipe any more
        gone = time.perf_counter() - t0
        assert gone < 5.0
        deadline = time.perf_counter() + 5.0
        while time.perf_counter() < deadline and _alive(helper_pid):
            time.sleep(0.05)
        assert not _alive(helper_pid)
    finally:
        proc.kill()
        proc.wait(timeout=10)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def test_ctrl_c_in_the_terminal_does_not_kill_the_helper(helper: HelperProcess) -> None:
    """SIGINT reaches every process of the terminal's group: the helper ignores it (its parent decides)."""
    import signal

    assert helper._warm is not None
    pid = helper._warm.result()
    os.kill(pid, signal.SIGINT)
    time.sleep(0.3)
    assert _alive(pid) and helper.ready
    out = helper.run(scaled_sum, {"scale": 1.0, "parent": PARENT}, _arrays(), list(range(40)))
    assert pid in {p for _, _, p in out}
