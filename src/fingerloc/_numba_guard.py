"""One lock around every numba parallel region of fingerloc (private).

numba's default threading layer ("workqueue") must not be entered by two
Python threads at once: it aborts the whole process ("Concurrent access has
been detected"). The threading layer is shared by the whole process, so every
parallel kernel of fingerloc (alignment, mixtures) takes this one lock:

* :func:`parallel_region` (blocking): the alignment kernels, which have no
  serial twin, wait for their turn; results do not depend on it.
* :func:`try_parallel` (non-blocking): :mod:`fingerloc.mog`, whose kernels
  have a serial twin, runs that one instead when the lock is busy.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import numba

__all__ = ["PARALLEL_LOCK", "parallel_region", "try_parallel"]

#: Held while a numba parallel kernel runs.
PARALLEL_LOCK = threading.RLock()


@contextmanager
def parallel_region(n_threads: int) -> Iterator[None]:
    """Hold :data:`PARALLEL_LOCK` (waiting for it) with numba set to ``n_threads`` threads."""
    with PARALLEL_LOCK:
        old = numba.get_num_threads()
        numba.set_num_threads(n_threads)
        try:
            yield
        finally:
            numba.set_num_threads(old)


@contextmanager
def try_parallel() -> Iterator[bool]:
    """Yield True with :data:`PARALLEL_LOCK` held if it was free, else False (run the serial kernel)."""
    got = PARALLEL_LOCK.acquire(blocking=False)
    try:
        yield got
    finally:
        if got:
            PARALLEL_LOCK.release()
