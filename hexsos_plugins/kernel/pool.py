"""The kernel's threads: its chunk functions release the GIL, so cells run in parallel on Python threads of one
pool; each task owns its scratch arrays and nothing is pickled; a small call runs in the calling thread at once.

Owns: the thread count (:func:`set_threads`, :func:`threads`), :func:`spread`. Imports nothing of hexsos.
"""

from __future__ import annotations

import os
import threading
from contextlib import contextmanager
from concurrent.futures import ThreadPoolExecutor

__all__ = ["cores", "set_threads", "threads", "threads_for", "spread", "last_threads", "CHUNK", "LIGHT_CHUNK"]

CHUNK = 4096  # cells per task on a thread (each task allocates its scratch once)
_THREADS = 1  # threads the kernel may use (set_threads); chunks of CHUNK cells are spread over them
LIGHT_CHUNK = 32768  # cells per task of a pass of a few nanoseconds a cell (the verdicts): ~0.3 ms of work
_POOL = None
#: The Python threads that have run the kernel's chunks since this was last reset to an empty set (for tests and
#: benchmarks: a light pass's short tasks may all go to one thread, so one call alone proves little).
last_threads: set = set()


def cores() -> int:
    """The cores this process may run on (its CPU affinity, which a container or ``taskset`` narrows)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not on Linux
        return os.cpu_count() or 1


def threads() -> int:
    """The number of threads the kernel may use now."""
    return _THREADS


def set_threads(n: int) -> int:
    """Let the kernel use n threads (its chunk functions release the GIL); returns the previous setting."""
    global _THREADS
    old, _THREADS = _THREADS, max(1, int(n))
    return old


def spread(fn, n_ids, args_of, min_chunk=CHUNK):
    """fn(*args_of(start, stop)) over chunks of cells: inline for one thread or a small input, else on a pool,
    each task at least ``min_chunk`` cells (more for a light pass, whose cells take nanoseconds)."""
    global _POOL
    if _THREADS <= 1 or n_ids <= min_chunk:
        fn(*args_of(0, n_ids))
        return
    if _POOL is None or _POOL._max_workers != _THREADS:
        _POOL = ThreadPoolExecutor(max_workers=_THREADS, thread_name_prefix="hexsos-kernel")
    # about four chunks per thread keeps them busy without many tiny tasks
    size = max(min_chunk, -(-n_ids // (4 * _THREADS)))
    seen = set()

    def task(start, stop):
        seen.add(threading.get_ident())
        fn(*args_of(start, stop))

    futures = [_POOL.submit(task, s, min(s + size, n_ids)) for s in range(0, n_ids, size)]
    for f in futures:
        f.result()
    last_threads.update(seen)



@contextmanager
def threads_for(jobs):
    """The kernel's thread count inside the block (restored afterwards); 0: one per core."""
    want = cores() if jobs == 0 else max(1, int(jobs))
    old = set_threads(want)
    try:
        yield want
    finally:
        set_threads(old)
