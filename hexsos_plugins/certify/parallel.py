"""Running per-hex work on all cores or on a Dask cluster, with one interface.

``executor(jobs=1, scheduler=None)`` returns a context manager with

* ``imap(fn, items, *args)``: yields ``(index, fn(item, *args))`` as results complete. ``items`` may be a
  generator: it is consumed lazily, with a bounded number of tasks in flight, so a large mesh is never
  cut into blocks all at once;
* ``map(fn, items, *args, progress=None)``: the results in the order of ``items``.

Each item is one block of hexes' own data (their vertex coordinates, a few MB at most), so no task carries
the whole mesh.

* ``jobs=1`` (default): in this process.
* ``jobs=N``: N worker processes (started from a fork server that has imported the kernel; never forked from
  this process, whose kernel threads a fork would break).
* ``scheduler``: a ``dask.distributed.Client`` or a scheduler address such as ``"tcp://10.0.0.5:8786"``
  (optional extra ``dask``); the workers need hexsos installed.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

from ..errors import DependencyError, InvalidInputError

__all__ = ["executor", "SerialExecutor", "ProcessExecutor", "DaskExecutor"]


class SerialExecutor:
    workers = 1

    def imap(self, fn, items, *args):
        for i, item in enumerate(items):
            yield i, fn(item, *args)

    def map(self, fn, items, *args, progress=None):
        items = list(items)
        out = [None] * len(items)
        for done, (i, res) in enumerate(self.imap(fn, items, *args), 1):
            out[i] = res
            if progress is not None:
                progress(done, len(items))
        return out

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


class ProcessExecutor(SerialExecutor):
    def __init__(self, jobs: int):
        # never fork this process: the compiled kernel's thread pool is not fork-safe (a forked child that runs
        # a parallel loop the parent started aborts). A fork server starts clean, imports the kernel once and
        # forks the workers from there; where it does not exist, spawn.
        methods = multiprocessing.get_all_start_methods()
        if "forkserver" in methods:
            ctx = multiprocessing.get_context("forkserver")
            ctx.set_forkserver_preload(["hexsos_plugins.certify", "hexsos_plugins.kernel"])
        else:  # pragma: no cover - Windows
            ctx = multiprocessing.get_context("spawn")
        self.workers = jobs
        self._pool = ProcessPoolExecutor(max_workers=jobs, mp_context=ctx)

    def imap(self, fn, items, *args):
        pending = {}
        it = enumerate(items)
        try:
            for i, item in it:
                pending[self._pool.submit(fn, item, *args)] = i
                while len(pending) >= 2 * self.workers:
                    done, _ = wait(pending, return_when=FIRST_COMPLETED)
                    for fut in done:
                        yield pending.pop(fut), fut.result()
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    yield pending.pop(fut), fut.result()
        finally:
            for fut in pending:
                fut.cancel()

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

    def imap(self, fn, items, *args):
        from dask.distributed import as_completed as dask_completed

        pending = {}  # key -> (index, future)
        queue = dask_completed()
        limit = 4 * self.workers
        try:
            for i, item in enumerate(items):
                # send the block's data to a worker first (a task that embeds megabytes of data makes Dask
                # warn about a large graph and route the data through the scheduler)
                data = self.client.scatter(item, hash=False)
                fut = self.client.submit(fn, data, *args, pure=False)
                pending[fut.key] = (i, fut)
                queue.add(fut)
                while queue.count() >= limit:
                    fut = next(queue)
                    yield pending.pop(fut.key)[0], fut.result()
            for fut in queue:
                yield pending.pop(fut.key)[0], fut.result()
        finally:
            if pending:
                self.client.cancel([f for _, f in pending.values()])

    def __exit__(self, *exc):
        if self._own:
            self.client.close()
        return False


def executor(jobs: int = 1, scheduler=None):
    """The executor for ``jobs`` local processes or a Dask ``scheduler`` (see the module docstring)."""
    if scheduler is not None:
        return DaskExecutor(scheduler)
    if jobs is None or jobs == 0:
        from ..kernel import cores

        jobs = cores()
    if not isinstance(jobs, int) or jobs < 1:
        raise InvalidInputError(f"jobs: expected a positive number of processes (or 0 for all cores), found {jobs!r}")
    return SerialExecutor() if jobs == 1 else ProcessExecutor(jobs)
