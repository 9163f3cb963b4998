"""Process pools of detector workers, one per core: each worker's BLAS on one thread.

A worker imports NumPy (and OpenBLAS starts its threads) while it unpickles its initializer or, under
forkserver, in the server that preloads the detector: before any code of the worker runs. Only the
environment the worker (or its server) inherits reaches its BLAS, so the variables are set while the pool
starts its processes. N two-thread BLAS pools on N cores spend their spinning threads' CPU time: a third
more per capture on the detector's small matrix products. The detector's own helper process
(:mod:`perception.helper_process`) starts the same way; the context manager is kept there.
"""

from __future__ import annotations

from perception.helper_process import ONE_THREAD_VARS, one_thread_children

__all__ = ["ONE_THREAD_VARS", "one_thread_children"]
