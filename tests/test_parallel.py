"""check on threads, on several processes and on a Dask cluster gives the single-process result."""

import numpy as np
import pytest

import hexsos_plugins as hs
from hexsos_plugins import cli
from hexsos_plugins.examples import hexes_to_mesh, random_hexes


@pytest.fixture(scope="module")
def sample():
    P, H = hexes_to_mesh(np.concatenate([random_hexes(30000, sigma=0.3, seed=60), random_hexes(50, sigma=0.8, seed=61)]))
    return P, H, hs.check(P, H)


def _same(a, b):
    # the same compiled kernel on the same cells: identical to the last bit, wherever it ran
    for name in ("status", "min_det", "lower_bound", "argmin", "method"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_two_threads_run_in_the_kernel_and_agree(sample):
    from hexsos_plugins import kernel

    P, H, ref = sample
    kernel.last_threads.clear()
    two = hs.check(P, H, jobs=2)
    assert len(kernel.last_threads) == 2  # the kernel's chunks really ran on two threads
    _same(ref, two)
    kernel.last_threads.clear()
    hs.check(P, H, jobs=1)
    assert kernel.last_threads == set()  # one thread: inline, no pool


def test_sos_on_two_threads_agrees_bit_for_bit(monkeypatch):
    """method="sos" with jobs=2: the relaxation runs on two threads (Clarabel releases the GIL), one solver per
    thread, and every array is the single-threaded one; with jobs=1 no SOS thread is started."""
    import threading

    from hexsos_plugins.kernel import sos

    P, H = hexes_to_mesh(random_hexes(64, sigma=0.3, seed=62))
    seen = set()
    solve = sos.SOSSolver.solve_many

    def spy(self, *a, **k):
        seen.add(threading.current_thread().name)
        return solve(self, *a, **k)

    monkeypatch.setattr(sos.SOSSolver, "solve_many", spy)
    one = hs.check(P, H, method="sos", jobs=1)
    assert seen == {threading.current_thread().name}
    seen.clear()
    two = hs.check(P, H, method="sos", jobs=2)
    assert len(seen) == 2 and all(n.startswith("hexsos-sos") for n in seen)
    _same(one, two)
    for name in ("recovery_ratio", "sos_status"):
        assert np.array_equal(getattr(one, name), getattr(two, name), equal_nan=True), name
    assert (one.sos_status == 1).sum() > 50
    # the paper's relaxation (25 ms a hex) takes threads from two hexes on; quad2 not for so few
    seen.clear()
    P2, H2 = hexes_to_mesh(random_hexes(2, sigma=0.3, seed=63))
    one = hs.check(P2, H2, method="sos", relaxation="paper", jobs=1)
    seen.clear()
    two = hs.check(P2, H2, method="sos", relaxation="paper", jobs=2)
    assert len(seen) == 2 and all(n.startswith("hexsos-sos") for n in seen)
    _same(one, two)
    seen.clear()
    hs.check(P2, H2, method="sos", jobs=2)
    assert seen == {threading.current_thread().name}


def test_processes(sample):
    P, H, ref = sample
    calls = []
    r = hs.check(P, H, processes=2, block_size=5000, progress=lambda d, t: calls.append((d, t)))
    _same(ref, r)
    assert calls[-1] == (len(H), len(H)) and len(calls) == 7  # one report per block


def test_jobs_rejects_nonsense():
    with pytest.raises(hs.InvalidInputError, match="jobs"):
        hs.check(*hexes_to_mesh(random_hexes(2)), jobs=-3)
    with pytest.raises(hs.InvalidInputError, match="processes"):
        hs.check(*hexes_to_mesh(random_hexes(2)), processes=-1)


def test_dask_local_cluster_client_and_address(sample):
    distributed = pytest.importorskip("dask.distributed")  # the 'dask' extra, installed by the test command
    P, H, ref = sample
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as lc:
        with distributed.Client(lc) as client:
            with distributed.get_task_stream(client) as stream:
                r = hs.check(P, H, scheduler=client, block_size=8000)
            _same(ref, r)
            # one task per block of 8000 hexes, run by the cluster's workers
            tasks = [t for t in stream.data if "_check_task" in t["key"]]
            assert len(tasks) == 4 and {t["worker"] for t in tasks} <= set(client.scheduler_info()["workers"])
        r = hs.check(P[: 8 * 500], H[:500], scheduler=lc.scheduler_address)  # an address string
        assert np.array_equal(r.status, ref.status[:500])


def test_cli_jobs_and_processes_reach_the_kernel(tmp_path, capsys, monkeypatch):
    import meshio

    from hexsos_plugins import kernel
    from hexsos_plugins.certify import parallel

    P, H = hexes_to_mesh(random_hexes(3000, seed=62))
    path = tmp_path / "m.vtu"
    meshio.write(path, meshio.Mesh(P, [("hexahedron", H)]))
    seen = {}
    threads, make = kernel.threads_for, parallel.executor

    def spy_threads(jobs):
        seen["threads"] = jobs
        return threads(jobs)

    def spy_executor(processes=1, scheduler=None):
        seen["processes"] = processes
        return make(processes, scheduler)

    monkeypatch.setattr(kernel, "threads_for", spy_threads)
    monkeypatch.setattr(parallel, "executor", spy_executor)
    assert cli.main(["check", str(path), "--jobs", "2", "--processes", "2", "--json"]) == 1
    out = capsys.readouterr().out
    assert '"hexes": 3000' in out and seen == {"threads": 2, "processes": 2}


def test_repair_on_processes_and_dask_matches_the_serial_repair():
    distributed = pytest.importorskip("dask.distributed")
    from comparison.bench_repair import perturbed_ring
    import importlib

    repair_paper = importlib.import_module("hexsos_plugins.meshrepair.paper")

    P, H = perturbed_ring(12)  # 174 invalid hexes: the paper's first iterations are spread over the workers
    ref = hs.repair(P, H, method="paper")
    assert ref.success and ref.stats["invalid_before"] >= 2 * repair_paper.PARALLEL_MIN
    two = hs.repair(P, H, method="paper", jobs=2)
    assert two.success and two.stats["outer_iterations"] == ref.stats["outer_iterations"]
    assert np.allclose(two.points, ref.points, rtol=0, atol=1e-9)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as lc:
        with distributed.Client(lc) as client:
            with distributed.get_task_stream(client) as stream:
                d = hs.repair(P, H, method="paper", scheduler=client)
            assert d.success and np.allclose(d.points, ref.points, rtol=0, atol=1e-9)
            assert any("_pi_task" in t["key"] for t in stream.data)  # Algorithm 1 ran on the workers


def test_run_all_runs_its_calls_at_once_on_the_kernels_threads_and_in_order_inline():
    """``kernel.pool.run_all``: with two threads allowed, two calls that each wait for the other (a barrier) both
    finish, so they ran at the same time; their results come back in the calls' order. With one thread they run in
    the calling thread, one after the other (the same barrier would then never open)."""
    import threading

    from hexsos_plugins.kernel import pool

    old = pool.set_threads(2)
    try:
        gate = threading.Barrier(2, timeout=20)
        pool.last_threads.clear()
        out = pool.run_all([lambda: (gate.wait(), "a")[1], lambda: (gate.wait(), "b")[1], lambda: "c"])
        assert out == ["a", "b", "c"] and len(pool.last_threads) == 2
        pool.set_threads(1)
        pool.last_threads.clear()
        me = threading.get_ident()
        assert pool.run_all([lambda: threading.get_ident(), lambda: 7]) == [me, 7]
        assert pool.last_threads == set()
        one = threading.Barrier(2, timeout=0.5)
        with pytest.raises(threading.BrokenBarrierError):
            pool.run_all([one.wait, one.wait])
    finally:
        pool.set_threads(old)
