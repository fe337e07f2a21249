"""Throughput of the certified check against Gmsh's minDetJac, on the same hexes in one process.

    python -m comparison.bench_check [--hexes 100000] [--ring 40] [--sos 300] [--repeat 3]

Prints, for 100k random hexes (the paper's family: unit cube + Gaussian noise, sigma 0.3) and a large
all-valid Gmsh mesh: hexes/s of Gmsh's ``getElementQualities(tags, "minDetJac")`` and of
``hexsos_plugins.check``, their ratio, whether their signs agree, and where hexsos spends its time; then
``method="sos"`` milliseconds per hex. Both run single-threaded (BLAS and Gmsh limited to one thread).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402


def gmsh_min_det(points, hexes, *, repeat=1):
    """Gmsh's minDetJac (times 8, in [0, 1]^3 units) and the best wall time of ``repeat`` runs."""
    import gmsh

    gmsh.initialize(["-noenv"], readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", 1)
    try:
        gmsh.model.add("bench")
        gmsh.model.addDiscreteEntity(3, 1)
        gmsh.model.mesh.addNodes(3, 1, np.arange(1, len(points) + 1), np.asarray(points, float).ravel())
        tags = np.arange(1, len(hexes) + 1)
        gmsh.model.mesh.addElementsByType(1, 5, tags, (np.asarray(hexes) + 1).ravel())
        best = np.inf
        for _ in range(repeat):
            t = time.perf_counter()
            q = gmsh.model.mesh.getElementQualities(tags, "minDetJac")
            best = min(best, time.perf_counter() - t)
        return 8.0 * np.asarray(q), best
    finally:
        gmsh.finalize()


def hexsos_check(points, hexes, *, repeat=1, **kw):
    from hexsos_plugins import check

    best, result = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        result = check(points, hexes, **kw)
        best = min(best, time.perf_counter() - t)
    return result, best


def stages(points, hexes):
    """Seconds per stage of the auto pipeline (one run), for the 'where the time goes' line."""
    from hexsos_plugins import bernstein as bn
    from hexsos_plugins import hexahedron as hx
    from hexsos_plugins.certify import _CHUNK

    out = dict.fromkeys(("gather", "bernstein coefficients", "branch-and-bound", "polish", "witness values"), 0.0)
    nref = boxes = 0
    PT = np.ascontiguousarray(np.asarray(points, float).T)
    for s in range(0, len(hexes), _CHUNK):  # as check does: chunk by chunk
        t = time.perf_counter()
        X = hx.gather_t(PT, hexes[s : s + _CHUNK])
        out["gather"] += time.perf_counter() - t
        t = time.perf_counter()
        st = {}
        B, err = hx.det_bernstein(X, layout="soa", stats=st)
        out["bernstein coefficients"] += time.perf_counter() - t
        t = time.perf_counter()
        br = bn.bracket(B, err, stats=st)
        out["branch-and-bound"] += time.perf_counter() - t
        idx = np.flatnonzero(br.depth > 0)
        t = time.perf_counter()
        if idx.size:
            x, _ = bn.polish(B[:, idx], br.argmin[idx])
        out["polish"] += time.perf_counter() - t
        t = time.perf_counter()
        if idx.size:
            hx.det_at(X[:, :, idx], x, layout="soa")
        out["witness values"] += time.perf_counter() - t
        nref += idx.size
        boxes += br.boxes
    return out, nref, boxes


def compare(label, points, hexes, repeat):
    m = len(hexes)
    g, tg = gmsh_min_det(points, hexes, repeat=repeat)
    r, th = hexsos_check(points, hexes, repeat=repeat)
    ratio = tg / th
    agree = np.sum((g > 0) == (r.status == 1))
    gap = (r.min_det - g) / r.scale
    print(f"\n== {label}: {m:,} hexes ==")
    print(f"gmsh minDetJac        {tg:8.3f} s  {m / tg:12,.0f} hexes/s")
    print(f"hexsos check (auto)   {th:8.3f} s  {m / th:12,.0f} hexes/s   ratio hexsos/gmsh = {ratio:.2f}x")
    print(f"verdicts: {r.counts()}; signs agree with Gmsh on {agree:,}/{m:,}; "
          f"our min - Gmsh's bound, relative to scale: [{gap.min():.1e}, {gap.max():.1e}] (Gmsh stops within 1e-3)")
    print(f"bracket width (gap/scale) max {np.max(r.gap / r.scale):.1e}; settled by {r.to_dict()['settled_by']}")
    st, nref, boxes = stages(points, hexes)
    tot = sum(st.values())
    print("where the time goes: " + ", ".join(f"{k} {v:.3f} s ({100 * v / tot:.0f}%)" for k, v in st.items())
          + f"; {nref:,} hexes subdivided, {boxes:,} boxes")
    return ratio


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hexes", type=int, default=100_000, help="random hexes (default 100000)")
    ap.add_argument("--ring", type=int, default=40, help="ring mesh size n: 4 n^3 hexes (default 40: 256,000)")
    ap.add_argument("--sos", type=int, default=300, help="hexes for the method='sos' timing (default 300)")
    ap.add_argument("--repeat", type=int, default=3, help="best of this many runs (default 3)")
    args = ap.parse_args(argv)

    from hexsos_plugins import examples

    print(f"single thread (OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}, Gmsh NumThreads 1)")
    X = examples.random_hexes(args.hexes, sigma=0.3, seed=0)
    P, H = examples.hexes_to_mesh(X)
    compare("random hexes, sigma 0.3 (seed 0)", P, H, args.repeat)

    t = time.perf_counter()
    P, H = examples.gmsh_mesh("ring", args.ring)
    print(f"\n(ring mesh generated by Gmsh in {time.perf_counter() - t:.1f} s)")
    compare(f"all-valid Gmsh ring mesh (n={args.ring})", P, H, args.repeat)

    if args.sos:
        from hexsos_plugins import check

        X = examples.random_hexes(args.sos, sigma=0.3, seed=1)
        P, H = examples.hexes_to_mesh(X)
        for rel in ("quad2", "paper"):
            n = args.sos if rel == "quad2" else max(20, args.sos // 10)
            t = time.perf_counter()
            r = check(P[: 8 * n], H[:n], method="sos", relaxation=rel)
            dt = time.perf_counter() - t
            print(f"\nmethod='sos', relaxation={rel!r}: {1e3 * dt / n:.2f} ms per hex over {n} hexes "
                  f"(paper: 22 ms with Mosek); statuses {np.bincount(r.sos_status, minlength=3)[1:3].tolist()} "
                  "(Solved, AlmostSolved)")


if __name__ == "__main__":
    main()
