"""Memory and time of checking a large mesh (default: 2 million hexes), in process and through the CLI.

    python -m comparison.bench_scale [--n 126] [--jobs 1 2] [--cli] [--dask]

Builds an n^3 structured grid (126^3 = 2,000,376 hexes) with a deterministic perturbation (a smooth
twist plus noise, so that the hexes are not all alike; at the default size every one is valid), then

* in process: ``check`` with ``tracemalloc`` (peak of numpy allocations during the call) and the process's
  peak resident set size, for each ``--jobs``;
* with ``--cli``: writes the mesh as .vtu and .msh (as ``hexsos_plugins.io.write`` writes them) and runs
  ``hexsos check`` under ``/usr/bin/time -v`` (peak RSS of the whole command: reading the file, checking,
  printing), and a process that only reads the file and takes its orientation (what ``check`` does before the
  kernel runs).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import re  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402

import numpy as np  # noqa: E402


def big_mesh(n: int, seed: int = 0):
    from hexsos_plugins.examples import structured_grid

    P, H = structured_grid(n, size=(1.0, 1.0, 1.0))
    rng = np.random.default_rng(seed)
    z = P[:, 2]
    angle = 0.6 * z  # a smooth twist about the vertical axis
    x, y = P[:, 0] - 0.5, P[:, 1] - 0.5
    P = np.stack([0.5 + np.cos(angle) * x - np.sin(angle) * y, 0.5 + np.sin(angle) * x + np.cos(angle) * y, z], 1)
    P += (0.08 / n) * rng.standard_normal(P.shape)
    return P, H


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=126, help="grid size n (n^3 hexes; default 126: 2,000,376)")
    ap.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--cli", action="store_true", help="also run 'hexsos check' on a .vtu under /usr/bin/time -v")
    ap.add_argument("--dask", action="store_true", help="also check on a Dask LocalCluster of 1 and 2 workers")
    args = ap.parse_args(argv)

    from hexsos_plugins import check

    t = time.perf_counter()
    P, H = big_mesh(args.n)
    mb = (P.nbytes + H.nbytes) / 2**20
    print(f"mesh: {len(H):,} hexes, {len(P):,} points ({mb:.0f} MB of arrays), built in {time.perf_counter() - t:.1f} s")
    for jobs in args.jobs:
        tracemalloc.start()
        t = time.perf_counter()
        r = check(P, H, jobs=jobs)
        dt = time.perf_counter() - t
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"check jobs={jobs}: {dt:.2f} s ({len(H) / dt:,.0f} hexes/s), peak allocations during the call "
              f"{peak / 2**20:.0f} MB, process peak RSS so far {rss:.0f} MB; {r.counts()}")
    if args.dask:
        from dask.distributed import Client, LocalCluster

        seconds = {}
        for workers in (1, 2):
            with LocalCluster(n_workers=workers, threads_per_worker=1, dashboard_address=None) as lc, Client(lc) as c:
                check(*big_mesh(8), scheduler=c)  # start the workers' imports
                t = time.perf_counter()
                r = check(P, H, scheduler=c)
                seconds[workers] = time.perf_counter() - t
            print(f"check on a Dask LocalCluster, {workers} worker(s): {seconds[workers]:.2f} s; {r.counts()}")
        print(f"Dask speed-up from 1 to 2 workers: {seconds[1] / seconds[2]:.2f}x")
    if args.cli:
        import meshio

        from hexsos_plugins.io import write

        with tempfile.TemporaryDirectory() as tmp:
            for ext in (".vtu", ".msh"):
                path = os.path.join(tmp, "big" + ext)
                write(meshio.Mesh(P, [("hexahedron", H)]), path)
                print(f"wrote {path} ({os.path.getsize(path) / 2**20:.0f} MB)")
                for what, code in (("hexsos check", None), ("read + orientation", _READ_ONLY)):
                    cmd = ["/usr/bin/time", "-v", sys.executable]
                    cmd += ["-m", "hexsos_plugins", "check", path, "--json"] if code is None else ["-c", code, path]
                    out = subprocess.run(cmd, capture_output=True, text=True)
                    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", out.stderr)
                    wall = re.search(r"Elapsed \(wall clock\) time.*: (\S+)", out.stderr)
                    print(f"{what} {len(H):,} hexes from {ext}: wall {wall.group(1) if wall else '?'}, "
                          f"peak RSS {int(rss.group(1)) / 1024:.0f} MB" if rss else out.stderr[-500:])


_READ_ONLY = ("import sys; from hexsos_plugins.io import read; m = read(sys.argv[1]); m.orientation(); "
              "print(m.reader)")


if __name__ == "__main__":
    main()
