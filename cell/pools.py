"""Process pools of detector workers, one per core: each worker's BLAS on one thread.

A worker imports NumPy (and OpenBLAS starts its threads) while it unpickles its initializer or, under
forkserver, in the server that preloads the detector: before any code of the worker runs. Only the
environment the worker (or its server) inherits reaches its BLAS, so the variables are set while the pool
starts its processes. N two-thread BLAS pools on N cores spend their spinning threads' CPU time: a third
more per capture on the detector's small matrix products.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

ONE_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextmanager
def one_thread_children() -> Iterator[None]:
    """The thread-pool variables set to 1 for the processes started inside the block; restored after."""
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
