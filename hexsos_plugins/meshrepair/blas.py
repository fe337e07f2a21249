"""One BLAS thread while the repair runs.

The optimizer's BLAS calls are small (dot products and axpys on vectors of 10^4-10^5 entries, L-BFGS-B's
updates). With OpenBLAS's default threads each call wakes its thread pool, and the pools of numpy's and scipy's
OpenBLAS copies spin between calls: measured on 2 cores, a 32,000-hex repair spent 47% of its samples in
``blas_thread_server`` and took 120 s, against 91 s with ``OPENBLAS_NUM_THREADS=1``. The environment variable
works only before numpy is imported, so :func:`single_thread` sets the thread count of every OpenBLAS loaded in
the process through its own ``*_set_num_threads`` function (as ``threadpoolctl`` does) and restores it on exit.
Libraries it does not find are left alone.
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib
import os

_PAIRS = (("openblas_get_num_threads", "openblas_set_num_threads"),
          ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
          ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
          ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"))

_LIBS = {}  # path -> (get, set) or None


def _loaded():
    """(get, set) ctypes functions of every OpenBLAS mapped into this process (Linux; elsewhere none)."""
    try:
        with open("/proc/self/maps") as f:
            paths = sorted({line.split()[-1] for line in f if "openblas" in line.lower() and "/" in line})
    except OSError:
        paths = []
    for p in paths:
        if p not in _LIBS:
            _LIBS[p] = _functions(p)
    return [_LIBS[p] for p in paths if _LIBS[p] is not None]


def _functions(path):
    if not os.path.isfile(path):
        return None
    try:
        lib = ctypes.CDLL(path)
    except OSError:
        return None
    for g, s in _PAIRS:
        try:
            get, set_ = getattr(lib, g), getattr(lib, s)
        except AttributeError:
            continue
        get.restype = ctypes.c_int
        get.argtypes = []
        set_.argtypes = [ctypes.c_int]
        set_.restype = None
        return get, set_
    return None


@contextlib.contextmanager
def single_thread():
    """Within the block every loaded OpenBLAS runs on the calling thread (restored after). scipy's own OpenBLAS is
    loaded first (its optimizers are what the block runs), so a first call before anything imported scipy sets it
    too."""
    importlib.import_module("scipy.optimize")
    saved = []
    try:
        for get, set_ in _loaded():
            try:
                n = int(get())
                if n > 1:
                    set_(1)
                    saved.append((set_, n))
            except Exception:  # noqa: BLE001 - a library that refuses keeps its threads
                pass
    except Exception:  # noqa: BLE001
        saved = []
    try:
        yield
    finally:
        for set_, n in saved:
            try:
                set_(n)
            except Exception:  # noqa: BLE001
                pass


def thread_counts():
    """The thread count of every OpenBLAS loaded in this process that this module can read and set."""
    return [int(get()) for get, _ in _loaded()]
