"""A second process for work a detection splits into independent jobs (the fine stage's seams and its
inner-gap search): CPython runs one thread's NumPy calls at a time, and the detector's are many small ones
(the GIL is held between them), so two threads took as long as one; two processes do not.

The large arrays (the organized cloud, the colour image) reach the helper through one shared-memory block,
with the jobs' context pickled into the same block: pickling the 11 MB cloud of a 1280x720 capture through
a pool's pipe took 55-95 ms, more than the helper saves on a capture of a few seams. The block is kept from
run to run (grown when a run needs more) and stays mapped in the helper: a fresh block's pages fault in as
they are written (17-19 ms to fill one for a 1280x720 capture against 2 ms to refill a kept one). The jobs
are shared as they go: the helper claims them from the back of the list, this process from the front, until
the two ends meet. The results come back in the jobs' order and each job is the same function on the same
inputs in either process, so a detection is the same with a helper or without one.

A helper that has not started yet (its interpreter imports the detector for a second or two), that dies, or
that stops answering leaves its jobs to this process: never a lost or a different result, and never a wait
without a bound. A helper that failed is replaced on the next run.
"""

from __future__ import annotations

import logging
import os
import pickle
import signal
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import BrokenExecutor, Future, ProcessPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from contextlib import contextmanager, suppress
from multiprocessing import get_context
from multiprocessing.shared_memory import SharedMemory
from typing import Any

import numpy as np

logger = logging.getLogger(__name__)

ONE_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
WAIT_S = 30.0  # a job the helper holds is waited for this long past this process's own share, plus ...
WAIT_FACTOR = 4.0  # ... this many times as long as this process took for its share, then done here instead

# what the helper imports while it starts (the detector's steps import these only when first run); "package.*":
# every module of the package
PRELOAD = ("perception.detect_surfaces", "perception.fine.*", "scipy.ndimage", "cv2")

Job = Any
JobFn = Callable[[Any, dict[str, np.ndarray], Job], Any]  # (context, arrays, job) -> result


@contextmanager
def one_thread_children() -> Iterator[None]:
    """The thread-pool variables set to 1 for the processes started inside the block; restored after.

    A worker imports NumPy (and OpenBLAS starts its threads) before any code of the worker runs: only the
    environment it inherits reaches its BLAS, so the variables are set while its pool starts its processes.
    """
    saved = {var: os.environ.get(var) for var in ONE_THREAD_VARS}
    os.environ.update(dict.fromkeys(ONE_THREAD_VARS, "1"))
    try:
        yield
    finally:
        for var, value in saved.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value


class HelperProcess:
    """One helper process, started at construction (it warms up while the caller goes on); :meth:`run`
    shares a list of jobs with it. Not for several threads at once: one run at a time.

    The jobs are claimed under a lock the two processes share, from the two ends of the list (two counters
    in shared memory, with the run's number: a late helper never claims a later run's jobs); the helper
    returns its results together when the list is used up."""

    def __init__(self, *, preload: Sequence[str] = PRELOAD) -> None:
        self._preload = tuple(preload)
        self._block: SharedMemory | None = None  # the runs' shared block, kept (grown when a run needs more)
        self._pool: ProcessPoolExecutor | None = None
        self._warm: Future[int] | None = None
        self._start()

    def _start(self) -> None:
        ctx = get_context("spawn")  # a clean interpreter (no inherited threads, open3d or GUI state)
        self._lock = ctx.Lock()
        self._ends = ctx.RawArray("q", 3)  # the next job from the front, one past the next from the back, the run
        with one_thread_children():
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_init_helper,
                                             initargs=(self._lock, self._ends))  # fmt: skip
            self._warm = self._pool.submit(_preload, self._preload)

    @property
    def ready(self) -> bool:
        """Whether the helper has started and imported the detector (until then runs do every job here)."""
        w = self._warm
        return w is not None and w.done() and not w.cancelled() and w.exception() is None

    def wait_ready(self, timeout_s: float = 60.0) -> bool:
        """Wait (at most ``timeout_s``) until the helper is ready; whether it is."""
        if self._warm is not None:
            try:
                self._warm.result(timeout=timeout_s)
            except Exception:  # a helper that cannot start is not used: runs do the jobs here
                return False
        return self.ready

    def close(self) -> None:
        """Stop the helper (a job it is running is not waited for)."""
        pool, self._pool, self._warm = self._pool, None, None
        if pool is not None:
            _stop(pool)
        self._release_block()

    def __enter__(self) -> HelperProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def run(self, fn: JobFn, context: Any, arrays: dict[str, np.ndarray], jobs: Sequence[Job]) -> list[Any]:
        """``[fn(context, arrays, job) for job in jobs]``, the jobs shared with the helper when it is ready.
        ``fn`` must be a module-level function (the helper imports it by name); ``context`` and the jobs
        picklable. Jobs the helper claimed and did not return (it failed one, died or took too long) are done
        here (and raise here if they fail here)."""
        if self._pool is None:
            self._start()
        if not self.ready or len(jobs) < 2:
            return [fn(context, arrays, job) for job in jobs]
        assert self._pool is not None
        t0 = time.perf_counter()
        name, layout = self._share(context, arrays)
        run = int(self._ends[2]) + 1
        self._ends[0], self._ends[1], self._ends[2] = 0, len(jobs), run
        fut = self._pool.submit(_helper_share, (name, layout), fn, list(jobs), run)
        results: dict[int, Any] = {}
        while (k := self._claim_front()) is not None:
            results[k] = fn(context, arrays, jobs[k])
        # the helper is done with the block when this returns: it returned its share, or it was stopped
        results |= self._collect(fut, time.perf_counter() + WAIT_S + WAIT_FACTOR * (time.perf_counter() - t0))
        return [results[k] if k in results else fn(context, arrays, jobs[k]) for k in range(len(jobs))]

    def _share(self, context: Any, arrays: dict[str, np.ndarray]) -> tuple[str, Layout]:
        """``arrays`` and the pickled ``context`` written into the kept block (a larger one first when they do not
        fit: with a quarter to spare, so that the next capture a little larger fits too); its name and where
        each lies in it."""
        blob = pickle.dumps(context, protocol=pickle.HIGHEST_PROTOCOL)
        entries, offset = [], 0
        for name, a in arrays.items():
            entries.append((name, offset, tuple(a.shape), a.dtype.str))
            offset += -(-a.nbytes // 64) * 64  # each array on a 64-byte boundary
        size = max(offset + len(blob), 1)
        if self._block is None or self._block.size < size:
            self._release_block()
            self._block = SharedMemory(create=True, size=size + size // 4, name=f"weldcell-{uuid.uuid4().hex[:16]}")
        buf = self._block.buf
        assert buf is not None  # an open block has its buffer
        for (_, off, shape, dtype), a in zip(entries, arrays.values(), strict=True):
            np.ndarray(shape, dtype=dtype, buffer=buf, offset=off)[...] = a
        buf[offset : offset + len(blob)] = blob
        return self._block.name, (tuple(entries), offset, len(blob))

    def _release_block(self) -> None:
        block, self._block = self._block, None
        if block is not None:
            block.close()
            with suppress(FileNotFoundError):
                block.unlink()

    def _claim_front(self) -> int | None:
        """The next job from the front of the list, or None when the two ends have met (or the lock is held past
        any bound: a helper that died holding it is stopped, and what it claimed is done here)."""
        if not self._lock.acquire(timeout=WAIT_S):
            logger.warning("the helper process holds the job list's lock: it is replaced")
            self.close()
            return None
        try:
            lo, hi = int(self._ends[0]), int(self._ends[1])
            if lo >= hi:
                return None
            self._ends[0] = lo + 1
            return lo
        finally:
            self._lock.release()

    def _collect(self, fut: Future[dict[int, Any]], deadline: float) -> dict[int, Any]:
        """The helper's results, or none when it failed a job or took too long (a helper that died or stopped
        answering is stopped, and replaced on the next run)."""
        try:
            return fut.result(timeout=max(deadline - time.perf_counter(), 0.0))
        except FutureTimeout:
            logger.warning("the helper process did not answer in time: its jobs are done here and it is replaced")
            self.close()
        except Exception as err:  # any failure there (a dead process too): its jobs are done here
            logger.warning("the helper process failed a job (%s: %s): its jobs are done here", type(err).__name__, err)
            if isinstance(err, BrokenExecutor):
                self.close()
        return {}


def _stop(pool: ProcessPoolExecutor) -> None:
    """Shut ``pool`` down without waiting for a job it is running: its process is terminated."""
    procs = list(getattr(pool, "_processes", {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        if proc.is_alive():
            proc.terminate()
    for proc in procs:
        proc.join(timeout=5.0)
        if proc.is_alive():
            proc.kill()


Layout = tuple[tuple[tuple[str, int, tuple[int, ...], str], ...], int, int]  # arrays, context offset and size


# --- in the helper process -------------------------------------------------------------------------------

_attached: dict[str, tuple[SharedMemory, int, Any, dict[str, np.ndarray]]] = {}  # the block, its last run read


def preload(modules: Sequence[str] = PRELOAD, *, coarse: bool = True) -> None:
    """Import ``modules`` ("package.*": every module of the package) in this process: the helper's first job,
    and a one-off run's before it is timed (the detector's steps import their modules when first run: a second).
    With the fine stage among them, its compiled kernels run once (:func:`perception.fine.compiled.warm_up`;
    ``coarse``: the coarse stage's too, which a helper's jobs do not use)."""
    import importlib
    import pkgutil

    for name in modules:
        mod = importlib.import_module(name.removesuffix(".*"))
        if name.endswith(".*"):
            for sub in pkgutil.iter_modules(mod.__path__):
                importlib.import_module(f"{mod.__name__}.{sub.name}")
    if "perception.fine.*" in modules:
        from perception.fine.compiled import warm_up

        warm_up(coarse=coarse)


def _preload(modules: tuple[str, ...]) -> int:
    preload(modules, coarse=False)
    return os.getpid()


def _init_helper(lock: Any, ends: Any) -> None:
    """The helper's share of the job list: its lock and its ends (:class:`HelperProcess`); and a watch on its
    parent: a helper whose process died without closing it (killed, or crashed) exits within a poll, instead
    of living on holding the parent's output pipes and a share of the memory."""
    global _lock, _ends
    _lock, _ends = lock, ends
    # Ctrl-C in the terminal reaches the whole process group: the parent stops the helper (or the watch below
    # sees the parent gone), and the helper does not die on its own with a traceback on the operator's screen
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_exit_with_parent, args=(os.getppid(),), name="helper-parent-watch", daemon=True).start()


PARENT_POLL_S = 0.2


def _exit_with_parent(parent: int) -> None:
    """Exit this process as soon as its parent ``parent`` is gone (it is then another process's child)."""
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_S)
    os._exit(0)


_lock: Any = None
_ends: Any = None


def _helper_share(key: tuple[str, Layout], fn: JobFn, jobs: list[Job], run: int) -> dict[int, Any]:
    """The helper's share of run ``run``: jobs claimed from the back of the list until the ends meet."""
    out: dict[int, Any] = {}
    while True:
        with _lock:
            if int(_ends[2]) != run or int(_ends[1]) <= int(_ends[0]):
                return out
            k = int(_ends[1]) - 1
            _ends[1] = k
        out[k] = _helper_job(key, fn, jobs[k], run)


def _helper_job(key: tuple[str, Layout], fn: JobFn, job: Job, run: int) -> Any:
    """One job in the helper of run ``run``: the block opened (once; a previous block closed when a new one
    comes), the run's context and arrays read from it (once per run: a kept block holds each run's), then
    ``fn``."""
    name, (entries, off, size) = key
    if name not in _attached:
        for old in list(_attached):
            done = _attached.pop(old)[0]  # its arrays (views of the block) go with the entry, then it is unmapped
            with suppress(BufferError):  # a view still held elsewhere: the mapping goes when that view goes
                done.close()
        _attached[name] = (SharedMemory(name=name), -1, None, {})
    shm, seen, context, arrays = _attached[name]
    if seen != run:
        buf = shm.buf
        assert buf is not None  # an open block has its buffer
        arrays = {n: np.ndarray(shape, dtype=dtype, buffer=buf, offset=o) for n, o, shape, dtype in entries}
        context = pickle.loads(buf[off : off + size])
        _attached[name] = (shm, run, context, arrays)
    return fn(context, arrays, job)
