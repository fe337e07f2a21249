"""Running per-hex work on all cores or on a Dask cluster, with one interface.

``executor(jobs=1, scheduler=None)`` returns a context manager with ``map(fn, items, *args, progress=None)``:
results come back in the order of ``items``. Each item is one block of hexes' own data (their vertex
coordinates, a few hundred kB), so no task ever carries the whole mesh.

* ``jobs=1`` (default): in this process.
* ``jobs=N``: N worker processes (``fork`` where the platform has it, so workers start at once).
* ``scheduler``: a ``dask.distributed.Client`` or a scheduler address such as ``"tcp://10.0.0.5:8786"``
  (optional extra ``dask``); the workers need hexsos installed.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor, as_completed

from .errors import DependencyError, InvalidInputError

__all__ = ["executor", "SerialExecutor", "ProcessExecutor", "DaskExecutor"]


class SerialExecutor:
    workers = 1

    def map(self, fn, items, *args, progress=None):
        out = []
        for i, item in enumerate(items):
            out.append(fn(item, *args))
            if progress is not None:
                progress(i + 1, len(items))
        return out

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


class ProcessExecutor(SerialExecutor):
    def __init__(self, jobs: int):
        ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
        self.workers = jobs
        self._pool = ProcessPoolExecutor(max_workers=jobs, mp_context=ctx)

    def map(self, fn, items, *args, progress=None):
        futures = {self._pool.submit(fn, item, *args): i for i, item in enumerate(items)}
        out = [None] * len(items)
        try:
            for done, fut in enumerate(as_completed(futures), 1):
                out[futures[fut]] = fut.result()
                if progress is not None:
                    progress(done, len(items))
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise
        return out

    def __exit__(self, *exc):
        self._pool.shutdown(wait=True, cancel_futures=True)
        return False


class DaskExecutor(SerialExecutor):
    def __init__(self, scheduler):
        try:
            from dask.distributed import Client
        except ImportError as exc:
            raise DependencyError("a Dask scheduler needs dask.distributed: pip install 'hexsos[dask]'") from exc
        if isinstance(scheduler, str):
            try:
                self.client = Client(scheduler, timeout="20s")
            except (OSError, TimeoutError) as exc:
                raise InvalidInputError(f"scheduler: could not connect to the Dask scheduler at {scheduler!r}: {exc}") from exc
            self._own = True
        else:
            self.client = scheduler
            self._own = False
        info = self.client.scheduler_info()
        self.workers = max(1, len(info.get("workers", {})))

    def map(self, fn, items, *args, progress=None):
        from dask.distributed import as_completed as dask_completed

        futures = [self.client.submit(fn, item, *args, pure=False) for item in items]
        index = {f.key: i for i, f in enumerate(futures)}
        out = [None] * len(items)
        try:
            for done, fut in enumerate(dask_completed(futures), 1):
                out[index[fut.key]] = fut.result()
                if progress is not None:
                    progress(done, len(items))
        except BaseException:
            self.client.cancel(futures)
            raise
        return out

    def __exit__(self, *exc):
        if self._own:
            self.client.close()
        return False


def executor(jobs: int = 1, scheduler=None):
    """The executor for ``jobs`` local processes or a Dask ``scheduler`` (see the module docstring)."""
    if scheduler is not None:
        return DaskExecutor(scheduler)
    if jobs is None or jobs == 0:
        jobs = os.cpu_count() or 1
    if not isinstance(jobs, int) or jobs < 1:
        raise InvalidInputError(f"jobs: expected a positive number of processes (or 0 for all cores), found {jobs!r}")
    return SerialExecutor() if jobs == 1 else ProcessExecutor(jobs)
