"""Benchmark of the certified safe step (``hexsos_plugins.safe_step``) against the plain halving a user would write.

    python -m comparison.bench_step [--quick] [--json OUT.json] [--no-line-search | --line-search-only] [--limit S]

The plain way: check the moved mesh at t = 1, 1/2, 1/4, ... (``hexsos_plugins.check``, itself certified) and take
the first t where every cell is proven valid. It proves the mesh valid *at* that t, not on the way there: a cell
can invert between samples and come back. The safe step proves det J > 0 on the whole path [0, t*] and gives a
witness just past t* where validity is lost (rational arithmetic).

Meshes (Gmsh, seeded): the mixed linear mesh of :func:`hexsos_plugins.examples.mixed_msh` (hexahedra, tetrahedra,
pyramids, wedges), its quadratic versions (serendipity and complete) and a ring of curved hexahedra. Fields per
mesh and seed (amplitudes relative to the mesh's median edge length h):

* ``smooth``: three random Fourier modes per component, amplitude 1-4 h over the mesh;
* ``rough``: an independent Gaussian vector per node, 0.3-1.5 h;
* ``swirl``: the nodes rotated about the vertical axis by an angle that grows with height (a twisting part:
  90-200 degrees from bottom to top), the displacement the chord from x to the rotated x.

Per run: the safe step t* (``per_cell=False``: the mesh's t*, what the plain ways give), plain halving's t and
number of checks, and a plain bisection on check's verdict to the same resolution as t* (2^-24 relative: the
plain way to a tight step), seconds of each; a *miss* is a run where the plain t lies past the witness's t (an
inversion between samples, proven); halving's step / t* says how much of the safe step halving gives away. Dense sampling in (space, t) (every node's
reference point and 8 interior points per cell, 513 values of t) checks every run: no sampled loss before t*.

The line-search question (``--no-line-search`` skips it): the repair's stage 2 (:mod:`hexsos_plugins.meshrepair.optimize`)
backtracks by halving from the L-BFGS step while the barrier energy is infinite. The benchmark runs the default
repair on damaged meshes with the energy wrapped (nothing in the repair is changed), records every trial step, which
of them were rejected as infeasible and why (a scaled-Jacobian sample below the round's threshold, or a Bernstein
coefficient <= 0: only the latter is what a safe step answers), and times a safe step on the directions of the
line searches that backtracked, against the energy evaluations they spent.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

import numpy as np

from hexsos_plugins import check, read
from hexsos_plugins.cells.elements import ELEMENTS
from hexsos_plugins.kernel import det_at
from hexsos_plugins import safe_step


# --- meshes and fields ----------------------------------------------------------------------------------------
def meshes(quick):
    from hexsos_plugins.examples import gmsh_mesh, mixed_msh

    out = []
    size = 0.34 if quick else 0.25
    with tempfile.TemporaryDirectory() as d:
        for label, order, inc in (("mixed linear", 1, True), ("mixed serendipity", 2, True),
                                  ("mixed complete", 2, False)):
            path = os.path.join(d, "m.msh")
            mixed_msh(path, order=order, incomplete=inc, size=size)
            m = read(path)
            out.append((label, m.points.copy(), [(t, np.asarray(c)) for t, c in m.cells]))
    P, H = gmsh_mesh("ring", 4 if quick else 6)
    out.append(("hex ring", P, [("hexahedron", H)]))
    return out


def edge_length(P, cells):
    lens = [np.linalg.norm(P[conn[:, 1]] - P[conn[:, 0]], axis=1) for _, conn in cells]
    return float(np.median(np.concatenate(lens)))


def field(kind, P, h, seed):
    rng = np.random.default_rng(seed)
    lo, hi = P.min(axis=0), P.max(axis=0)
    X = (P - lo) / np.maximum(hi - lo, 1e-300)
    if kind == "smooth":
        D = np.zeros_like(P)
        for a in range(3):
            for _ in range(3):
                k = rng.uniform(0.5, 3.0, size=3)
                D[:, a] += np.sin(2 * np.pi * X @ k + rng.uniform(0, 2 * np.pi))
        return rng.uniform(1.0, 4.0) * h * D / 3.0
    if kind == "rough":
        return rng.uniform(0.3, 1.5) * h * rng.standard_normal(P.shape)
    if kind == "swirl":
        c = (lo + hi) / 2
        ang = np.radians(rng.uniform(90, 200)) * X[:, 2] + rng.uniform(0, 0.3)
        x, y = P[:, 0] - c[0], P[:, 1] - c[1]
        R = np.stack([c[0] + np.cos(ang) * x - np.sin(ang) * y, c[1] + np.sin(ang) * x + np.cos(ang) * y, P[:, 2]], 1)
        return R - P
    raise ValueError(kind)


# --- the plain way and the dense sampling -----------------------------------------------------------------------
def plain_halving(P, cells, D, max_halvings=40):
    """The first t of 1, 1/2, 1/4, ... where check proves every cell valid; (t, checks)."""
    t = 1.0
    for k in range(max_halvings + 1):
        r = check(P + t * D, cells)
        if bool(np.all(r.status == 1)):
            return t, k + 1
        t *= 0.5
    return 0.0, max_halvings + 1


def _timed_child(fn, args, limit):
    """fn(*args) in a forked child with a wall-clock limit: (result, seconds) or (None, None) past the limit
    (check's search can take very long on a cell whose minimum is nearly 0: such a run is reported, not waited
    for)."""
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    q = ctx.Queue()

    def target():
        t0 = time.perf_counter()
        out = fn(*args)
        q.put((out, time.perf_counter() - t0))

    p = ctx.Process(target=target)
    p.start()
    try:
        out = q.get(timeout=limit)
    except Exception:  # queue.Empty: past the limit
        out = (None, None)
    p.join(timeout=1)
    if p.is_alive():
        p.kill()
        p.join()
    return out


def plain_bisection(P, cells, D, rtol=2.0**-24):
    """Bisection on check's verdict between a valid t (0) and an invalid one (1), to rtol: (t, checks). Each
    sample is proven valid or not; what lies between samples is not looked at."""
    if bool(np.all(check(P + D, cells).status == 1)):
        return 1.0, 1
    lo, hi, n = 0.0, 1.0, 1
    while hi - lo > rtol * max(lo, 2.0**-40):
        mid = 0.5 * (lo + hi)
        n += 1
        if bool(np.all(check(P + mid * D, cells).status == 1)):
            lo = mid
        else:
            hi = mid
    return lo, n


def _sample_pcoords(name, n, rng):
    el = ELEMENTS[name]
    pts = [[float(v) for v in x] for x in el.nodes]
    while len(pts) < el.n_nodes + n:
        x = rng.random(3)
        if el.domain == "tet" and x.sum() > 1 or el.domain == "prism" and x[0] + x[1] > 1:
            continue
        if el.domain == "pyramid":
            x[2] *= 0.98
            x[:2] *= 1 - x[2]
        pts.append(list(x))
    return np.array(pts)


def dense_first_loss(P, cells, D, ts, seed=0):
    """The first t of ``ts`` where det J <= 0 at a sampled point of some cell (inf: none)."""
    rng = np.random.default_rng(seed)
    samples = {name: _sample_pcoords(name, 8, rng) for name, _ in cells}
    for t in ts:
        Y = P + t * D
        for name, conn in cells:
            for x in samples[name]:
                if np.any(det_at(Y, conn, name, x) <= 0):
                    return float(t)
    return np.inf


# --- the line-search measurement ----------------------------------------------------------------------------------
def line_search_study(quick):
    """Run the default repair with its barrier energy observed; see the module docstring."""
    from hexsos_plugins import repair
    from hexsos_plugins.meshrepair import optimize
    from hexsos_plugins.examples import gmsh_mesh
    from hexsos_plugins.meshrepair.paper import boundary_vertex_mask, hex_edge_length

    rows = []
    for n, frac, amp, seed in ((5, 0.05, 0.6, 0), (6, 0.3, 0.5, 1), (6, 0.6, 0.6, 2)) if quick else \
            ((5, 0.05, 0.6, 0), (6, 0.3, 0.5, 1), (6, 0.6, 0.6, 2), (8, 0.5, 0.6, 3)):
        P, H = gmsh_mesh("ring", n)
        P = P.copy()
        interior = np.flatnonzero(~boundary_vertex_mask(H, len(P)))
        rng = np.random.default_rng(seed)
        pick = rng.choice(interior, size=max(1, int(frac * interior.size)), replace=False)
        h = float(np.median(hex_edge_length(P[H])))
        P[pick] += amp * h * rng.standard_normal((pick.size, 3))
        log = {"evals": 0, "eval_seconds": 0.0, "infeasible": 0, "by_sj": 0, "by_bernstein": 0, "searches": [],
               "times": []}
        original = optimize.Problem.barrier_energy
        state = {"x": None, "trial": 0}

        def observed(self, x, t, *a, **k):
            t0 = time.perf_counter()
            out = original(self, x, t, *a, **k)
            log["eval_seconds"] += time.perf_counter() - t0
            log["times"].append(time.perf_counter() - t0)
            log["evals"] += 1
            if k.get("grad", True) is False:
                return out
            if not np.isfinite(out[0]):
                log["infeasible"] += 1
                V = self.full(x)
                sj_bad = any(v.size and float(v.min()) <= t for v in self.sj_samples(V))
                b_bad = any(bb is not None and bb.size and float(bb.min()) <= 0 for bb in self.bernstein(V))
                log["by_sj"] += int(sj_bad and not b_bad)
                log["by_bernstein"] += int(b_bad)
                if state["x"] is not None and len(log["searches"]) < 40:
                    log["searches"].append((self, state["x"].copy(), x.copy()))
            else:
                state["x"] = x.copy()
            return out

        original_pv = optimize.project_valid
        pv = {"calls": 0, "seconds": 0.0}

        def observed_pv(*a, **k):  # the boundary projection's own halving (vertices step back by halves)
            t0 = time.perf_counter()
            out = original_pv(*a, **k)
            pv["calls"] += 1
            pv["seconds"] += time.perf_counter() - t0
            return out

        optimize.Problem.barrier_energy = observed
        optimize.project_valid = observed_pv
        try:
            t0 = time.perf_counter()
            res = repair(P, H)
            seconds = time.perf_counter() - t0
        finally:
            optimize.Problem.barrier_energy = original
            optimize.project_valid = original_pv
        # a safe step on the directions of the rejected trials (from the last accepted point)
        ss_time, ss_fracs = 0.0, []
        for prob, x0, x1 in log["searches"][:20]:
            V0, V1 = prob.full(x0), prob.full(x1)
            cells = [(b["name"], b["conn"]) for b in prob.blocks]
            t1 = time.perf_counter()
            r = safe_step(V0, cells, V1 - V0, rtol=2.0**-12)
            ss_time += time.perf_counter() - t1
            ss_fracs.append(r.t)
        n_ss = max(1, min(20, len(log["searches"])))
        rows.append({"mesh": f"ring n={n}, {pick.size} nodes moved {amp} h", "hexes": int(H.shape[0]),
                     "repair_success": bool(res.success), "repair_seconds": seconds,
                     "projection_calls": pv["calls"], "projection_seconds": pv["seconds"],
                     "energy_evals": log["evals"], "infeasible_trials": log["infeasible"],
                     "infeasible_by_sj_only": log["by_sj"], "infeasible_by_bernstein": log["by_bernstein"],
                     "eval_ms": 1e3 * float(np.median(log["times"])) if log["times"] else float("nan"),
                     "safe_step_ms": 1e3 * ss_time / n_ss,
                     "safe_step_fraction_median": float(np.median(ss_fracs)) if ss_fracs else None})
    return rows


# --- the main comparison ------------------------------------------------------------------------------------------
def run(quick=False, line_search=True, limit=120.0):
    rows = []
    seeds = range(4) if quick else range(10)
    for label, P, cells in meshes(quick):
        h = edge_length(P, cells)
        ncells = sum(len(c) for _, c in cells)
        for kind in ("smooth", "rough", "swirl"):
            for seed in seeds:
                D = field(kind, P, h, 1000 * seed + len(label))
                t0 = time.perf_counter()
                r = safe_step(P, cells, D, per_cell=False)  # the mesh's t*, as plain halving gives
                t_safe = time.perf_counter() - t0
                res, t_plain = _timed_child(plain_halving, (P, cells, D), limit)
                tp, nchecks = res if res is not None else (None, None)
                res, t_bis = _timed_child(plain_bisection, (P, cells, D), limit)
                tb, nbis = res if res is not None else (None, None)
                ts = np.linspace(0.0, 1.0, 513)
                first = dense_first_loss(P, cells, D, ts)
                w = r.witness
                miss = w is not None and tp is not None and tp >= w["t"]
                miss_bis = w is not None and tb is not None and tb >= w["t"]
                rows.append({"mesh": label, "cells": ncells, "field": kind, "seed": seed, "t_safe": r.t,
                             "witness_t": None if w is None else w["t"], "t_plain": tp, "checks": nchecks,
                             "miss": bool(miss), "seconds_safe": t_safe, "seconds_plain": t_plain,
                             "t_bisection": tb, "bisection_checks": nbis, "bisection_miss": bool(miss_bis),
                             "seconds_bisection": t_bis,
                             "dense_first_loss": first, "dense_sound": bool(first >= r.t),
                             "check_valid": r.check_valid, "searched": r.stats["searched"]})
                fmt = lambda v, f: "timeout" if v is None else format(v, f)  # noqa: E731
                print(f"{label:18s} {kind:6s} seed {seed}: t* {r.t:.6g} plain {fmt(tp, '.6g')} ({nchecks} checks) "
                      f"{'MISS' if miss else ''} bisection {fmt(tb, '.6g')} ({nbis}) {'MISS' if miss_bis else ''} "
                      f"safe {t_safe:.2f}s plain {fmt(t_plain, '.2f')}s bisection {fmt(t_bis, '.2f')}s "
                      f"dense {first:.4g}", file=sys.stderr, flush=True)
    out = {"runs": rows, "limit_seconds": limit}
    if line_search:
        out["line_search"] = line_search_study(quick)
    return out


def _median(values):
    v = [x for x in values if x is not None]
    return float(np.median(v)) if v else float("nan")


def table(out) -> str:
    rows = out["runs"]
    lines = ["| mesh | field | runs | halving misses an inversion | halving's step / t* (median) | "
             "halving: checks | bisection misses | bisection: checks | safe step s | halving s | bisection s | "
             f"plain runs past {out.get('limit_seconds', 0):.0f} s | dense sampling sound |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for mesh in dict.fromkeys(r["mesh"] for r in rows):
        for kind in ("smooth", "rough", "swirl"):
            g = [r for r in rows if r["mesh"] == mesh and r["field"] == kind]
            if not g:
                continue
            ok = [r["t_plain"] / r["t_safe"] for r in g if r["t_plain"] is not None and not r["miss"]
                  and r["t_safe"] > 0]
            late = sum((r["t_plain"] is None) + (r["t_bisection"] is None) for r in g)
            lines.append(f"| {mesh} ({g[0]['cells']} cells) | {kind} | {len(g)} | {sum(r['miss'] for r in g)} | "
                         f"{_median(ok):.2f} | {_median(r['checks'] for r in g):.0f} | "
                         f"{sum(r['bisection_miss'] for r in g)} | {_median(r['bisection_checks'] for r in g):.0f} | "
                         f"{_median(r['seconds_safe'] for r in g):.3f} | {_median(r['seconds_plain'] for r in g):.3f} | "
                         f"{_median(r['seconds_bisection'] for r in g):.3f} | {late} | "
                         f"{sum(r['dense_sound'] for r in g)}/{len(g)} |")
    if out.get("line_search"):
        lines += ["", "| repair (default) on | hexes | repair s | energy evaluations | infeasible trials | of which SJ below "
                  "threshold only | Bernstein coefficient <= 0 | ms per evaluation (median) | ms per safe step | "
                  "median safe fraction | boundary projections (halving) s |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in out["line_search"]:
            med = r["safe_step_fraction_median"]
            lines.append(f"| {r['mesh']} | {r['hexes']} | {r['repair_seconds']:.1f} | {r['energy_evals']} | "
                         f"{r['infeasible_trials']} | "
                         f"{r['infeasible_by_sj_only']} | {r['infeasible_by_bernstein']} | {r['eval_ms']:.2f} | "
                         f"{'-' if med is None else format(r['safe_step_ms'], '.1f')} | {'-' if med is None else f'{med:.3g}'} | "
                         f"{r['projection_calls']} calls, {r['projection_seconds']:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m comparison.bench_step", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer seeds, coarser meshes")
    p.add_argument("--json", metavar="OUT", help="write every run as JSON")
    p.add_argument("--no-line-search", action="store_true", help="skip the repair's line-search measurement")
    p.add_argument("--line-search-only", action="store_true", help="only the repair's line-search measurement")
    p.add_argument("--limit", type=float, default=120.0, metavar="S",
                   help="wall-clock limit of one plain run (halving or bisection), default 120 s")
    a = p.parse_args(argv)
    if a.line_search_only:
        out = {"runs": [], "line_search": line_search_study(a.quick)}
    else:
        out = run(quick=a.quick, line_search=not a.no_line_search, limit=a.limit)
    print(table(out))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())
