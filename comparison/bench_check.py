"""Throughput of the certified check against Gmsh's minDetJac, side by side in one run.

    python -m comparison.bench_check [--hexes 100000] [--ring 30] [--msh-n 61] [--sos 300] [--repeat 3]
                                     [--types 20000] [--skip NAME ...]

Prints, each beside Gmsh on the same cells:

* ``random``: 100k random hexes (the paper's family: unit cube + Gaussian noise, sigma 0.3): Gmsh's
  ``getElementQualities(tags, "minDetJac")`` and ``hexsos_plugins.check`` with 1 and 2 threads, ratios, sign
  agreement, gap, and where hexsos's time goes;
* ``mesh``: an all-valid Gmsh ring mesh (4 n^3 hexes);
* ``e2e``: end to end, a binary .msh of ~900k hexes written by Gmsh: ``hexsos check F --json`` (its default: every
  core) and with ``--jobs 1`` against a process
  that opens F in Gmsh and asks minDetJac (both whole processes, best of ``--repeat``);
* ``sos``: ``method="sos"`` milliseconds per hex (quad2 and the paper's relaxation);
* ``start``: the start of ``hexsos check`` on a one-hex file beyond Python's own start (warm), and the
  just-in-time compilation a build without the compiled extension pays once (cold);
* ``types``: every cell type, random cells, hexsos against Gmsh.

Gmsh and hexsos run single-threaded unless a row says otherwise (Gmsh's quality computation is not thread-safe).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

ROWS = ("random", "mesh", "e2e", "sos", "start", "types")


def _best(fn, repeat):
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def gmsh_min_det(points, cells, *, repeat=1):
    """Gmsh's minDetJac in our units and the best wall time of ``repeat`` runs."""
    from comparison.against_gmsh import gmsh_qualities

    qmin, _, seconds = gmsh_qualities(points, cells, repeat=repeat)
    return qmin, seconds


def hexsos_check(points, cells, *, repeat=1, jobs=1, **kw):
    from hexsos_plugins import check

    t, r = _best(lambda: check(points, cells, jobs=jobs, **kw), repeat)
    return r, t


def stages(points, hexes, repeat):
    """Seconds of the kernel's parts on these hexes: coefficients alone, the check without subdivision nor
    polish, without subdivision, and whole (one thread)."""
    from hexsos_plugins import kernel

    ids = np.arange(len(hexes))
    out = {}
    out["coefficients"], _ = _best(lambda: kernel.coefficients(points, hexes, ids, "hexahedron"), repeat)
    out["root bounds"], _ = _best(lambda: kernel.run_cells(points, hexes, ids, "hexahedron", max_iter=0,
                                                           polish_iter=0), repeat)
    out["+ polish"], _ = _best(lambda: kernel.run_cells(points, hexes, ids, "hexahedron", max_iter=0), repeat)
    out["+ subdivision"], r = _best(lambda: kernel.run_cells(points, hexes, ids, "hexahedron"), repeat)
    return out, int((r["depth"] > 0).sum()), int(r["boxes"].sum())


def compare(label, points, hexes, repeat):
    from hexsos_plugins.kernel import threads_for

    m = len(hexes)
    g, tg = gmsh_min_det(points, hexes, repeat=repeat)
    r1, t1 = hexsos_check(points, hexes, repeat=repeat, jobs=1)
    r2, t2 = hexsos_check(points, hexes, repeat=repeat, jobs=2)
    agree = np.sum((g > 0) == (r1.status == 1))
    gap = (r1.min_det - g) / r1.scale
    print(f"\n== {label}: {m:,} hexes ==")
    print(f"gmsh minDetJac            {tg:8.3f} s  {m / tg:12,.0f} hexes/s")
    print(f"hexsos check, 1 thread    {t1:8.3f} s  {m / t1:12,.0f} hexes/s   ratio hexsos/gmsh = {tg / t1:.2f}x")
    print(f"hexsos check, 2 threads   {t2:8.3f} s  {m / t2:12,.0f} hexes/s   ratio hexsos/gmsh = {tg / t2:.2f}x "
          f"(threads: {t1 / t2:.2f}x)")
    print(f"verdicts: {r1.counts()}; signs agree with Gmsh on {agree:,}/{m:,}; identical with 2 threads: "
          f"{np.array_equal(r1.status, r2.status) and np.array_equal(r1.min_det, r2.min_det)}")
    print(f"our min - Gmsh's bound, relative to scale: [{gap.min():.1e}, {gap.max():.1e}] (Gmsh stops within 1e-3); "
          f"bracket width (gap/scale) max {np.max(r1.gap / r1.scale):.1e}; settled by {r1.to_dict()['settled_by']}")
    with threads_for(1):
        st, nref, boxes = stages(points, hexes, repeat)
    tot = st["+ subdivision"]
    parts = {"coefficients": st["coefficients"], "root bounds": st["root bounds"] - st["coefficients"],
             "polish": st["+ polish"] - st["root bounds"], "subdivision": st["+ subdivision"] - st["+ polish"]}
    print("where the time goes (kernel, 1 thread): " + ", ".join(f"{k} {v:.3f} s ({100 * v / tot:.0f}%)"
                                                                 for k, v in parts.items())
          + f"; {nref:,} hexes subdivided, {boxes:,} boxes; the rest of check (units, arrays): {t1 - tot:.3f} s")
    return tg / t1


_GMSH_MINDET = """
import sys, time, gmsh, numpy as np
gmsh.initialize(["-noenv"], readConfigFiles=False)
gmsh.option.setNumber("General.Terminal", 0)
gmsh.option.setNumber("General.NumThreads", 1)
gmsh.open(sys.argv[1])
tags = np.concatenate([gmsh.model.mesh.getElementsByType(t)[0] for t in gmsh.model.mesh.getElementTypes(3)])
q = gmsh.model.mesh.getElementQualities(tags, "minDetJac")
print(len(q), int((np.asarray(q) <= 0).sum()))
gmsh.finalize()
"""


def end_to_end(n, repeat):
    """hexsos check F --json against Gmsh opening F and asking minDetJac, on a Gmsh-written binary .msh."""
    import gmsh

    from hexsos_plugins.examples import gmsh_mesh

    P, H = gmsh_mesh("ring", n)
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "ring.msh")
        gmsh.initialize(["-noenv"], readConfigFiles=False)
        try:
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.option.setNumber("Mesh.Binary", 1)
            gmsh.model.add("ring")
            gmsh.model.addDiscreteEntity(3, 1)
            gmsh.model.mesh.addNodes(3, 1, np.arange(1, len(P) + 1), P.ravel())
            gmsh.model.mesh.addElementsByType(1, 5, np.arange(1, len(H) + 1), (H + 1).ravel())
            gmsh.write(path)
        finally:
            gmsh.finalize()
        size = os.path.getsize(path) / 1e6
        script = os.path.join(d, "mindet.py")
        with open(script, "w") as f:
            f.write(_GMSH_MINDET)
        env = dict(os.environ, HEXSOS_NO_RECORD="1")
        env.pop("PYTHONDONTWRITEBYTECODE", None)  # both sides with Python's bytecode cache, as users run them

        def run(cmd):
            t = time.perf_counter()
            p = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if p.returncode not in (0, 1):
                raise RuntimeError(f"{' '.join(cmd)} failed: {p.stderr.strip()[-300:]}")
            return time.perf_counter() - t, p.stdout

        run([sys.executable, script, path])  # each side once first: the bytecode cache written, the file in memory
        run([sys.executable, "-m", "hexsos_plugins", "check", path, "--json", "--no-progress"])
        tg = min(run([sys.executable, script, path])[0] for _ in range(repeat))
        hx = [run([sys.executable, "-m", "hexsos_plugins", "check", path, "--json", "--no-progress"])
              for _ in range(repeat)]
        t2 = min(t for t, _ in hx)
        t1 = min(run([sys.executable, "-m", "hexsos_plugins", "check", path, "--json", "--no-progress", "--jobs", "1"])[0]
                 for _ in range(repeat))
        d1 = json.loads(hx[0][1])
        from hexsos_plugins.kernel import cores

        print(f"\n== end to end: {len(H):,} hexes, binary .msh of {size:.0f} MB written by Gmsh ==")
        print(f"gmsh (open + minDetJac)        {tg:7.2f} s")
        print(f"hexsos check F --json --jobs 1 {t1:7.2f} s   ratio {tg / t1:.2f}x   ({d1['valid']:,} valid)")
        print(f"hexsos check F --json          {t2:7.2f} s   ratio {tg / t2:.2f}x   (the default: {cores()} threads)")


def sos_rows(m):
    from hexsos_plugins import check
    from hexsos_plugins.examples import hexes_to_mesh, random_hexes

    X = random_hexes(m, sigma=0.3, seed=1)
    P, H = hexes_to_mesh(X)
    check(P[:80], H[:10], method="sos")  # the solvers built once
    check(P[:800], H[:100], method="sos", jobs=2)
    for rel in ("quad2", "paper"):
        n = m if rel == "quad2" else max(20, m // 10)
        t = time.perf_counter()
        r = check(P[: 8 * n], H[:n], method="sos", relaxation=rel)
        dt = time.perf_counter() - t
        t = time.perf_counter()
        r2 = check(P[: 8 * n], H[:n], method="sos", relaxation=rel, jobs=2)
        dt2 = time.perf_counter() - t
        same = all(np.array_equal(getattr(r, k), getattr(r2, k)) for k in ("status", "min_det", "lower_bound"))
        print(f"\nmethod='sos', relaxation={rel!r}: {1e3 * dt / n:.2f} ms per hex over {n} hexes, 1 thread; "
              f"{1e3 * dt2 / n:.2f} ms with 2 threads (identical: {same}) (paper: 22 ms with Mosek); statuses Solved "
              f"{int((r.sos_status == 1).sum())}, other {int((r.sos_status > 1).sum())}")


def start_rows(repeat):
    import meshio

    from hexsos_plugins import kernel
    from hexsos_plugins.examples import unit_cube

    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "cube.vtu")
        meshio.write(path, meshio.Mesh(unit_cube(), [("hexahedron", np.arange(8)[None])]))
        env = dict(os.environ, HEXSOS_NO_RECORD="1")
        # a warm start is one with Python's bytecode cache (an environment that turns it off compiles every
        # module at every start: 0.1 s here)
        nopyc = env.pop("PYTHONDONTWRITEBYTECODE", None)

        def run(cmd, extra=None):
            t = time.perf_counter()
            subprocess.run(cmd, capture_output=True, env=dict(env, **(extra or {})))
            return time.perf_counter() - t

        py = min(run([sys.executable, "-c", "pass"]) for _ in range(max(repeat, 5)))
        run([sys.executable, "-m", "hexsos_plugins", "check", path])  # writes the bytecode cache if it is missing
        warm = min(run([sys.executable, "-m", "hexsos_plugins", "check", path]) for _ in range(max(repeat, 5)))
        print(f"\n== start: hexsos check on a one-hex file (kernel: {kernel.implementation()}) ==")
        print(f"python -c pass {py:.3f} s; hexsos check {warm:.3f} s: {warm - py:.3f} s above Python's own start"
              + (" (bytecode cache on; this environment had it off)" if nopyc else ""))
        cache = os.path.join(d, "numba-cache")
        cold = run([sys.executable, "-m", "hexsos_plugins", "check", path],
                   {"HEXSOS_KERNEL": "jit", "NUMBA_CACHE_DIR": cache})
        warm_jit = min(run([sys.executable, "-m", "hexsos_plugins", "check", path],
                           {"HEXSOS_KERNEL": "jit", "NUMBA_CACHE_DIR": cache}) for _ in range(3))
        print(f"without the compiled extension (numba just in time): first run {cold:.1f} s (compiles and caches), "
              f"then {warm_jit:.2f} s")


def type_rows(m):
    from comparison.cell_types import QUADRATIC, TYPES, random_cells

    print("\n== every cell type, random cells, one thread ==")
    print(f"{'type':14s} {'cells':>8s} {'Gmsh cells/s':>14s} {'hexsos cells/s':>15s} {'ratio':>6s} {'max gap/scale':>14s}")
    for name in TYPES:
        n = m // 10 if name in QUADRATIC else m
        P, conn = random_cells(name, n)
        g, tg = gmsh_min_det(P, [(name, conn)], repeat=2)
        r, t = hexsos_check(P, [(name, conn)], repeat=2)
        gap = np.max((r.min_det - g) / np.where(r.scale > 0, r.scale, 1))
        print(f"{name:14s} {n:8,d} {n / tg:14,.0f} {n / t:15,.0f} {tg / t:6.2f} {gap:14.1e}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hexes", type=int, default=100_000, help="random hexes (default 100000)")
    ap.add_argument("--ring", type=int, default=30, help="ring mesh size n: 4 n^3 hexes (default 30: 108,000)")
    ap.add_argument("--msh-n", type=int, default=61, help="end-to-end ring size (default 61: 907,924 hexes)")
    ap.add_argument("--sos", type=int, default=300, help="hexes for the method='sos' timing (default 300)")
    ap.add_argument("--types", type=int, default=20_000, help="random cells per linear type (quadratic: a tenth)")
    ap.add_argument("--repeat", type=int, default=3, help="best of this many runs (default 3)")
    ap.add_argument("--skip", nargs="*", default=[], choices=ROWS, help="rows to leave out")
    args = ap.parse_args(argv)

    from hexsos_plugins import examples
    from hexsos_plugins import kernel

    print(f"kernel: {kernel.implementation()}; Gmsh NumThreads 1; this machine: {os.cpu_count()} CPUs")
    if "random" not in args.skip:
        X = examples.random_hexes(args.hexes, sigma=0.3, seed=0)
        P, H = examples.hexes_to_mesh(X)
        compare("random hexes, sigma 0.3 (seed 0)", P, H, args.repeat)
    if "mesh" not in args.skip:
        t = time.perf_counter()
        P, H = examples.gmsh_mesh("ring", args.ring)
        print(f"\n(ring mesh generated by Gmsh in {time.perf_counter() - t:.1f} s)")
        compare(f"all-valid Gmsh ring mesh (n={args.ring})", P, H, args.repeat)
    if "e2e" not in args.skip:
        end_to_end(args.msh_n, args.repeat)
    if "sos" not in args.skip and args.sos:
        sos_rows(args.sos)
    if "start" not in args.skip:
        start_rows(args.repeat)
    if "types" not in args.skip:
        type_rows(args.types)


if __name__ == "__main__":
    main()
