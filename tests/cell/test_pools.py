"""cell.pools: worker processes started inside one_thread_children get one BLAS thread; the parent's
environment is as it was after."""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

import pytest

from cell.pools import ONE_THREAD_VARS, one_thread_children


def _child_env() -> dict[str, str | None]:
    return {var: os.environ.get(var) for var in ONE_THREAD_VARS}


@pytest.mark.timeout(120)
def test_a_spawned_worker_inherits_one_thread_and_the_parent_is_restored(monkeypatch) -> None:
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    ctx = multiprocessing.get_context("spawn")
    with one_thread_children(), ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        assert pool.submit(_child_env).result() == dict.fromkeys(ONE_THREAD_VARS, "1")
    assert os.environ["OPENBLAS_NUM_THREADS"] == "2" and "OMP_NUM_THREADS" not in os.environ
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:  # started outside: the parent's own
        assert pool.submit(_child_env).result()["OPENBLAS_NUM_THREADS"] == "2"
