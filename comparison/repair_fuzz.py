"""The repair on damaged pieces of the published meshes: no traceback, no warning, no false certificate.

    python -m comparison.repair_fuzz                 # 56 runs, 4 per damage, 20 s each at most
    python -m comparison.repair_fuzz --runs 140 --seed 1000

Each run cuts a piece of 20-600 hexes out of a published mesh of ``../shared/data`` (read in place; an absent mesh
is skipped), grown hex by hex from a random hex (from a hex below 0.1 more often than not: where the meshes are
bad), damages it one way (:data:`DAMAGES`) and repairs it as ``repair()`` does by default, or with one of the
options users set (:data:`OPTIONS`), within ``--time-limit`` seconds. Every outcome is one of:

- certified: ``success`` and every hex proven valid by a check of its own (:func:`hexsos_plugins.check`);
- refused: a typed :class:`hexsos_plugins.errors.HexsosError` (what the command line turns into one line, exit 2);
- not finished: no ``success``, a message naming the cells left, and the best mesh seen returned;
- or a failure of the harness's demands: an exception of another type (a traceback), ``success`` the check does
  not confirm, numpy's ``RuntimeWarning`` reaching the caller, or a result without the input's points.

Prints one line per run on stderr and a Markdown table per damage on stdout; exits 1 on any failure.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback
import warnings

import numpy as np

from comparison.bench_repair import PUBLISHED, SHARED

__all__ = ["DAMAGES", "OPTIONS", "piece", "damage", "run_one", "fuzz", "main"]

#: The damages, each a function (points, hexes, rng) -> (points, hexes) of :func:`damage`
DAMAGES = ("none", "coincident corners", "one hex at a point", "hex named twice", "moved far away", "shrunk 1e-9",
           "grown 1e9", "all points moved", "a tenth moved", "flattened", "unused far point", "an edge collapsed",
           "a face's diagonal collapsed", "the hex's diagonal collapsed")
#: The options a run may take (30% of runs: one of these; else the defaults)
OPTIONS = ({"local": True}, {"boundary": "fixed"}, {"min_sj": 0.6}, {"method": "paper"}, {"boundary": "free"})


def piece(P, H, rng, n):
    """``n`` hexes of (P, H) grown from one by shared vertices, breadth first, and their points renumbered: from a
    hex below 0.1 (scaled Jacobian) with probability 0.6 where there is one, else from any."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order

    from hexsos_plugins.cells.quality import scaled_jacobian

    M = H.shape[0]
    A = coo_matrix((np.ones(H.size), (np.repeat(np.arange(M), 8), H.ravel())), shape=(M, P.shape[0])).tocsr()
    low = np.flatnonzero(np.asarray(scaled_jacobian(P, [("hexahedron", H)])).reshape(M, -1).min(axis=1) < 0.1)
    start = int(rng.choice(low)) if low.size and rng.random() < 0.6 else int(rng.integers(M))
    order = breadth_first_order((A @ A.T).tocsr(), start, directed=False, return_predecessors=False)[:n]
    used, inv = np.unique(H[order], return_inverse=True)
    return P[used].copy(), inv.reshape(-1, 8)


def damage(P, H, rng, kind):
    """(points, hexes) of (P, H) damaged as ``kind`` (one of :data:`DAMAGES`)."""
    P, H = P.copy(), H.copy()
    d = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
    h = int(rng.integers(len(H)))
    if kind == "coincident corners":  # two corners of a hex at one point, their numbers distinct
        a, b = rng.choice(8, 2, replace=False)
        P[H[h, b]] = P[H[h, a]]
    elif kind == "one hex at a point":
        P[H[h]] = P[H[h, 0]]
    elif kind == "hex named twice":
        H = np.vstack([H, H[rng.choice(len(H), 3)]])
    elif kind == "moved far away":
        P = P + 1e6 * d
    elif kind == "shrunk 1e-9":
        P = P * 1e-9
    elif kind == "grown 1e9":
        P = P * 1e9
    elif kind == "all points moved":
        P = P + rng.normal(scale=float(rng.choice([0.01, 0.05, 0.2])) * d, size=P.shape)
    elif kind == "a tenth moved":
        k = rng.choice(len(P), max(1, len(P) // 10), replace=False)
        P[k] += rng.normal(scale=0.1 * d, size=(len(k), 3))
    elif kind == "flattened":
        P[:, 2] *= 1e-6
    elif kind == "unused far point":
        P = np.vstack([P, P.max(axis=0) + 100 * d])
    elif kind in ("an edge collapsed", "a face's diagonal collapsed", "the hex's diagonal collapsed"):
        a, b = {"an edge collapsed": (0, 1), "a face's diagonal collapsed": (0, 2),
                "the hex's diagonal collapsed": (0, 6)}[kind]
        H[h, b] = H[h, a]
    elif kind != "none":
        raise ValueError(f"unknown damage {kind!r}; expected one of {', '.join(DAMAGES)}")
    return P, H


def run_one(P, H, options, time_limit):
    """The outcome of ``repair(P, H, **options)`` (module docstring): a dict with ``outcome`` (certified, refused,
    not finished, or failure), ``why`` (the message, or what failed), ``seconds`` and ``min_sj`` (certified only)."""
    import hexsos_plugins as hs
    from hexsos_plugins.errors import HexsosError

    t = time.perf_counter()
    out = {"min_sj": None}
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            r = hs.repair(P, H, jobs=0, time_limit=time_limit, **options)
        except HexsosError as e:
            out.update(outcome="refused", why=f"{type(e).__name__}: {e}")
        except Exception as e:  # what the harness is here to find
            out.update(outcome="failure", why="traceback: " + "".join(traceback.format_exception(e))[-1500:])
        else:
            if r.points.shape != P.shape:
                out.update(outcome="failure", why=f"points {r.points.shape} returned for {P.shape}")
            elif r.success:
                ok = bool((hs.check(r.points, H).status == 1).all())
                out.update(outcome="certified" if ok else "failure",
                           why=r.message if ok else "success without every hex proven valid by check()",
                           min_sj=float(r.stats["min_sj_after"]))
            else:
                named = "not proven valid" in r.message or "not valid" in r.message
                out.update(outcome="not finished" if named else "failure",
                           why=r.message if named else f"no success and no cell named: {r.message!r}")
    numpy_warnings = [w for w in seen if issubclass(w.category, RuntimeWarning)]
    if numpy_warnings and out["outcome"] != "failure":
        out.update(outcome="failure", why=f"RuntimeWarning: {numpy_warnings[0].message} "
                                          f"({numpy_warnings[0].filename}:{numpy_warnings[0].lineno})")
    out["seconds"] = time.perf_counter() - t
    return out


def fuzz(runs, seed=0, time_limit=20.0, max_hexes=600, data=SHARED, log=sys.stderr):
    """``runs`` runs from seed ``seed`` on: each seed picks the mesh (in turn), the piece, the damage (in turn) and the
    options. Returns the list of rows (run, mesh, hexes, damage, options, and :func:`run_one`'s outcome)."""
    from hexsos_plugins.io import read
    from hexsos_plugins.io.handedness import right_handed

    meshes = []
    for rel in PUBLISHED:
        path = os.path.join(data, rel)
        if not os.path.exists(path):
            print(f"({rel} skipped: {path} absent)", file=log)
            continue
        m, _, _ = right_handed(read(path), True, folded=True)
        meshes.append((os.path.splitext(os.path.basename(rel))[0], m.points, m.hexes))
    rows = []
    if not meshes:
        return rows
    for i in range(seed, seed + runs):
        rng = np.random.default_rng(i)
        name, P0, H0 = meshes[i % len(meshes)]
        P, H = piece(P0, H0, rng, int(rng.integers(20, max_hexes + 1)))
        kind = DAMAGES[(i // len(meshes) + i) % len(DAMAGES)]
        P, H = damage(P, H, rng, kind)
        options = OPTIONS[int(rng.integers(len(OPTIONS)))] if rng.random() < 0.3 else {}
        row = {"run": i, "mesh": name, "hexes": int(len(H)), "damage": kind, "options": options,
               **run_one(P, H, options, time_limit)}
        rows.append(row)
        print(f"[{i}] {name} {len(H)} hexes, {kind}, {options or 'defaults'}: {row['outcome']} in "
              f"{row['seconds']:.1f} s: {row['why'][:160]}", file=log, flush=True)
    return rows


def table(rows) -> str:
    """The Markdown table of ``rows`` per damage: runs, each outcome's count, median seconds, least min SJ."""
    lines = ["| damage | runs | certified | refused | not finished | failures | median seconds | least min SJ "
             "certified |", "|---|---|---|---|---|---|---|---|"]
    for kind in DAMAGES:
        mine = [r for r in rows if r["damage"] == kind]
        if not mine:
            continue
        count = {o: sum(r["outcome"] == o for r in mine) for o in ("certified", "refused", "not finished", "failure")}
        sj = [r["min_sj"] for r in mine if r["min_sj"] is not None]
        lines.append(f"| {kind} | {len(mine)} | {count['certified']} | {count['refused']} | {count['not finished']} "
                     f"| {count['failure']} | {np.median([r['seconds'] for r in mine]):.1f} | "
                     f"{f'{min(sj):.3f}' if sj else '-'} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="the repair on damaged pieces of the published meshes (module "
                                             "docstring); exit 1 on a traceback, a warning or a false certificate")
    ap.add_argument("--runs", type=int, default=4 * len(DAMAGES), help="runs (default: 4 per damage)")
    ap.add_argument("--seed", type=int, default=0, help="the first run's seed (default 0)")
    ap.add_argument("--time-limit", type=float, default=20.0, help="seconds per repair (default 20)")
    ap.add_argument("--max-hexes", type=int, default=600, help="the largest piece (default 600 hexes)")
    ap.add_argument("--data", default=SHARED, help="the folder of the published meshes (default ../shared/data)")
    a = ap.parse_args(argv)
    rows = fuzz(a.runs, a.seed, a.time_limit, a.max_hexes, a.data)
    if not rows:
        print(f"no published mesh found under {a.data}", file=sys.stderr)
        return 2
    print(table(rows))
    bad = [r for r in rows if r["outcome"] == "failure"]
    for r in bad:
        print(f"FAILURE run {r['run']} ({r['mesh']}, {r['damage']}, {r['options']}): {r['why']}", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
