"""Benchmark of ``hexsos repair``: the default repair (untangle, quality, certify) beside the paper's Algorithm 2
and Gmsh's own untangler, on generated meshes and the paper's bunny.

    python -m comparison.bench_repair [--quick] [--no-gmsh] [--json OUT.json] [--samples] [--table1]
    python -m comparison.bench_repair --published [--local] [--mesh REL ...] [--json OUT.json]
    python -m comparison.bench_repair --published --starts N [--mesh REL ...]
    python -m comparison.bench_repair --published --perturbed | --scattered [--mesh REL ...]
    python -m comparison.bench_repair --subdivided [--jobs N]
    python -m comparison.bench_repair --corner-loops [--mesh REL ...]

``--published``: the default repair on the published meshes of ``../shared/data`` (the seven HexaLab meshes and the
bunny, read in place): before / after (cells not proven valid, scaled Jacobian min / p1 / mean), Hausdorff, max
move, moved vertices (and how many by more than 1% of the diagonal), seconds per stage, and the load average.

Meshes (generated, seeded; :mod:`comparison.stress`): graded curved Gmsh solids (``graded_solid``) with a few
interior vertices moved (ordinary) or 50-90% of the interior vertices moved by up to an edge length (stress
tests); Gmsh ring meshes with 2% of the interior vertices moved by half an edge (the paper's kind of damage);
a box with one fold inside a corner-valid hex; a hex + prism block; and the paper's *bunny*
(``../shared/data/bunny.vtk``, read in place, skipped when absent).

For each mesh and each repair: hexes, cells not proven valid before / after, the corner scaled Jacobian (min, 1st
percentile, mean) before / after, the Hausdorff distance of the boundary to the input's (pymeshlab, % of the
bounding-box diagonal), the largest vertex move (% of the diagonal), seconds. Gmsh 4.15's
``optimize("UntangleMeshGeometry", force=True)`` runs on a discrete model (boundary quads as a discrete
surface, kept fixed), on meshes up to ``--gmsh-max-hexes``, its result checked by our kernel.

``--perturbed``: the same meshes with every interior vertex moved by up to 1.5 and 3 edge lengths (HexOpt's stress
tests); ``--scattered``: with every interior vertex at the centroid, and anywhere in the bounding box
(:func:`comparison.stress.scatter_interior`), the column "harmonic start" saying whether the untangling started
from the sweeps' fixed point (:func:`hexsos_plugins.meshrepair.driver.harmonic_untangle`).

``--subdivided``: the default repair on Gmsh's all-hex meshes of CAD solids (tetrahedra split into hexes, singular
edges everywhere; :func:`comparison.stress.subdivided_solid`) with a share of their boundary vertices slid along the
surface (:func:`comparison.stress.slide_boundary`): boundary hexes folded as a pipeline's projection folds them.

``--corner-loops``: stage 1's corner term on hexes, the general loop against the hex loop the repair runs (one
thread each, the same process, the same coordinates; :func:`corner_loops`).

``--samples`` measures stage 1's sample points (corners only, corners + the Bernstein coefficients of the hexes
that need them -- the default --, corners + every hex's coefficients) on stress tests. ``--table1`` prints the
paper's Table 1 columns for ``method="paper"`` against the paper's times.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from hexsos_plugins import check, repair
from hexsos_plugins.examples import gmsh_mesh, gmsh_model, structured_grid
from hexsos_plugins.meshrepair.boundary import TILT_DEGREES
from hexsos_plugins.meshrepair.fidelity import boundary_fidelity, boundary_quads
from hexsos_plugins.meshrepair import check_cells
from hexsos_plugins.meshrepair.paper import boundary_vertex_mask, hex_edge_length
from hexsos_plugins.cells.quality import edge_ratio_summary, scaled_jacobian, summary

BUNNY = os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "bunny.vtk"))

#: The paper's Table 1: name, hexes, invalid, outer iterations, (SOSD) steps, (R) steps, minutes.
PAPER = [
    ("bunny", 2832, 40, 19, 8173, 123, 4.05),
    ("torus", 7380, 121, 12, 21157, 1471, 12.13),
    ("bust", 5258, 30, 49, 20020, 643, 9.20),
    ("block", 2520, 19, 11, 5353, 83, 2.29),
    ("rockerarm", 1858, 11, 7, 2616, 47, 1.24),
    ("cat", 2604, 1, 12, 2818, 22, 1.41),
    ("fertility", 21016, 20, 21, 24998, 1168, 9.83),
    ("dolphin", 4788, 2, 2, 4838, 3, 2.45),
    ("horse", 44145, 73, 12, 53986, 457, 22.15),
    ("elephant", 46525, 90, 11, 60159, 301, 24.85),
]


def paper_reference(name, hexes):
    """The Table 1 row of the same mesh, or else the one nearest in hex count (log scale)."""
    for row in PAPER:
        if row[0] == name:
            return row
    return min(PAPER, key=lambda r: abs(np.log(r[1] / hexes)))


def perturbed_ring(n, *, frac=0.02, amp=0.5, seed=0):
    P, H = gmsh_mesh("ring", n)
    P = P.copy()
    interior = np.flatnonzero(~boundary_vertex_mask(H, len(P)))
    rng = np.random.default_rng(seed)
    pick = rng.choice(interior, size=max(1, int(frac * interior.size)), replace=False)
    h = float(np.median(hex_edge_length(P[H])))
    P[pick] += amp * h * rng.standard_normal((pick.size, 3))
    return P, H


def gmsh_untangle(P, H):
    """Gmsh's untangler on a discrete model: boundary quads on a discrete surface (fixed), the rest free."""
    with gmsh_model("hexsos-untangle") as gmsh:
        q = boundary_quads(H)
        bnodes = np.unique(q)
        inner = np.setdiff1d(np.arange(len(P)), bnodes)
        s = gmsh.model.addDiscreteEntity(2)
        v = gmsh.model.addDiscreteEntity(3, -1, [s])
        gmsh.model.mesh.addNodes(2, s, bnodes + 1, P[bnodes].ravel())
        gmsh.model.mesh.addNodes(3, v, inner + 1, P[inner].ravel())
        gmsh.model.mesh.addElementsByType(s, 3, [], (q + 1).ravel())
        gmsh.model.mesh.addElementsByType(v, 5, [], (H + 1).ravel())
        t0, c0 = time.perf_counter(), time.process_time()
        gmsh.model.mesh.optimize("UntangleMeshGeometry", force=True)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        tags, coords, _ = gmsh.model.mesh.getNodes()
        Q = P.copy()
        Q[np.asarray(tags, dtype=np.int64) - 1] = np.asarray(coords).reshape(-1, 3)
        # the untangler may rewrite the hexes' node lists (measured on the bunny): read them back too
        etags, enodes = gmsh.model.mesh.getElementsByType(5)
        H2 = np.asarray(enodes, dtype=np.int64).reshape(-1, 8) - 1
        order = np.argsort(np.asarray(etags))
        return Q, H2[order], wall, cpu


def _disp(P, Q):
    n = np.linalg.norm(Q - P, axis=1)
    return float(n.max()), float(n[n > 0].mean()) if (n > 0).any() else 0.0


def meshes(quick=False):
    """(name, points, hexes, other cells) of the benchmark."""
    from comparison.stress import graded_solid, hex_prism_block, single_fold, stress

    out = []
    if os.path.exists(BUNNY):
        from hexsos_plugins.io import read

        m = read(BUNNY)
        out.append(("bunny", m.points, m.hexes, []))
    else:
        print(f"(bunny skipped: {BUNNY} absent)", file=sys.stderr)
    sizes = (6, 10) if quick else (8, 12, 20)
    for n in sizes:
        P, H = graded_solid(n)
        out.append((f"graded{n} ordinary", stress(P, H, frac=0.03, amp=0.8, seed=n), H, []))
    for n, frac in (((6, 0.9),) if quick else ((8, 0.5), (8, 0.9), (12, 0.8), (20, 0.8))):
        P, H = graded_solid(n)
        out.append((f"graded{n} stress {int(100 * frac)}%", stress(P, H, frac=frac, amp=1.0, seed=n), H, []))
    for n in ((8,) if quick else (12, 20)):
        P, H = perturbed_ring(n)
        out.append((f"ring{n}", P, H, []))
    P, H, _ = single_fold(5)
    out.append(("fold5", P, H, []))
    P, cells = hex_prism_block(6)
    out.append(("hex+prism", P, cells[0][1], cells[1:]))
    return out


def _row(name, P0, H, cells, Q, H2, seconds, success=None):
    diag = float(np.linalg.norm(P0.max(axis=0) - P0.min(axis=0)))
    r0, r1 = check(P0, H), check(Q, H2)
    o0, o1 = check_cells(P0, cells), check_cells(Q, cells)
    bad0 = int((r0.status != 1).sum()) + sum(int((o["status"] != 1).sum()) for o in o0)
    bad1 = int((r1.status != 1).sum()) + sum(int((o["status"] != 1).sum()) for o in o1)
    blocks = [("hexahedron", H)] + list(cells)
    s0 = summary(scaled_jacobian(P0, blocks))
    s1 = summary(scaled_jacobian(Q, [("hexahedron", H2)] + list(cells)))
    f = _fid(P0, Q, H, cells)
    fid = None if f is None else f["hausdorff_max"]
    crossing = None if f is None else (f["self_intersecting_before"], f["self_intersecting_after"])
    move = float(np.linalg.norm(Q - P0, axis=1).max())
    return {"mesh": name, "hexes": int(len(H)), "other_cells": int(sum(len(c) for _, c in cells)),
            "edge_ratio_before": edge_ratio_summary(P0, H), "edge_ratio_after": edge_ratio_summary(Q, H2),
            "bad_before": bad0,
            "bad_after": bad1, "certified": bad1 == 0 if success is None else bool(success),
            "sj_before": s0, "sj_after": s1, "hausdorff_pct": None if fid is None else 100 * fid / diag,
            "self_intersecting": crossing,
            "max_move_pct": 100 * move / diag, "seconds": seconds}


def _published_meshes(names=None):
    """(name, hexsos Mesh) of each published mesh (paths under ../shared/data, default :data:`PUBLISHED`), read in
    place; an absent one is skipped with a line on stderr."""
    from hexsos_plugins.io import read
    from hexsos_plugins.io.handedness import right_handed

    for rel in names or PUBLISHED:
        path = os.path.join(SHARED, rel)
        if not os.path.exists(path):
            print(f"({rel} skipped: {path} absent)", file=sys.stderr)
            continue
        # as `hexsos repair --fix-orientation`: the repair refuses a mesh folded by its node order
        m, _, flipped = right_handed(read(path), True, folded=True)
        if flipped.any():
            print(f"({rel}: {int(flipped.sum())} cells written in the other handedness than their neighbours "
                  "flipped first, as `hexsos repair --fix-orientation` does)", file=sys.stderr)
        yield os.path.splitext(os.path.basename(rel))[0], m


def starts(n, names=None, jobs=0, feature_angle=45.0):
    """The default repair on each published mesh from ``n`` starts perturbed by 1e-12 of its diagonal (seeds 1..n):
    the certified minimum scaled Jacobian of each and their median (a change of rounding alone moves a single run's
    minimum by up to 0.08), the least shortest / longest edge of a hex of each, and the farthest boundary vertex
    from the input surface (``boundary_max_distance``) over them; and the least min det J / max |det J| of a hex
    (``det_ratio_after``: where det J nearly vanishes inside a hex whose corners look fine) per start."""
    print("| mesh | min SJ per start | median | least shortest / longest edge per start | least min det J / max "
          "per start | farthest boundary vertex (of diag) |\n|---|---|---|---|---|---|")
    for name, m in _published_meshes(names):
        diag = float(np.linalg.norm(m.points.max(axis=0) - m.points.min(axis=0)))
        got, ratio, det, far = [], [], [], 0.0
        for seed in range(1, n + 1):
            P = m.points + 1e-12 * diag * np.random.default_rng(seed).standard_normal(m.points.shape)
            r = repair(P, m.hexes, jobs=jobs, feature_angle=feature_angle)  # 0: every core, as `hexsos repair`
            got.append(r.stats["min_sj_after"] if r.success else float("nan"))
            ratio.append(edge_ratio_summary(r.points, m.hexes)[0])
            det.append(r.stats["det_ratio_after"])
            far = max(far, r.stats.get("boundary_max_distance", 0.0) / diag)
        print(f"| {name} | {' / '.join(f'{x:.3f}' for x in got)} | {np.median(got):.3f} | "
              f"{' / '.join(f'{x:.4f}' for x in ratio)} | {' / '.join(f'{x:.4f}' for x in det)} | {100 * far:.2f}% |",
              flush=True)


def _stage_seconds(st):
    """'untangle / quality / vertex steps / joint steps / certify' seconds of a repair's ``stage_seconds``."""
    parts = " / ".join(f"{st.get(k, 0.0):.1f}" for k in ("untangle", "quality", "local", "joint", "certify"))
    return parts + (f" (+ fallback {st['fallback']:.1f})" if "fallback" in st else "")


def _start_rows(starts, column, names=None, jobs=0, extra=()):
    """The default repair on the published meshes from the starts ``starts(points, hexes)`` -> [(label, P)]: one
    row each, the start's label in ``column``; ``extra``: more columns after "certified", (header, text(result,
    diagonal))."""
    print(f"| mesh | hexes | {column} | not valid before -> after | certified | "
          + "".join(f"{h} | " for h, _ in extra)
          + "SJ after min / p1 / mean | shortest / longest edge of a hex, least | "
            "seconds: untangle / quality / vertex steps / joint steps / certify / total |\n"
          + "|---" * (8 + len(extra)) + "|")
    for name, m in _published_meshes(names):
        diag = float(np.linalg.norm(m.points.max(axis=0) - m.points.min(axis=0)))
        for label, P in starts(m.points, m.hexes):
            t0 = time.perf_counter()
            r = repair(P, m.hexes, jobs=jobs)  # 0: every core, as `hexsos repair`
            t = time.perf_counter() - t0
            print(f"| {name} | {len(m.hexes):,} | {label} | "
                  f"{r.stats['invalid_before'] + r.stats['undecided_before']:,} -> "
                  f"{r.stats['invalid_after'] + r.stats['undecided_after']:,} | {'yes' if r.success else 'NO'} | "
                  + "".join(f"{text(r, diag)} | " for _, text in extra)
                  + f"{r.stats['min_sj_after']:.3f} / {r.stats['p1_sj_after']:.3f} / {r.stats['mean_sj_after']:.3f} | "
                  f"{r.stats['edge_ratio_after']:.4f} | {_stage_seconds(r.stats['stage_seconds'])} / {t:.1f} |",
                  flush=True)


#: The column of the boundary quads turned over (``stats["turned_quads_after"]``: the surface folded there)
TURNED = (f"boundary quads turned over (tilted more than {TILT_DEGREES:g} degrees)",
          lambda r, diag: f"{r.stats.get('turned_quads_after', 0):,} ({r.stats.get('tilted_quads_after', 0):,})")


def perturbed(names=None, amps=(1.5, 3.0), jobs=0):
    """The default repair on the published meshes perturbed as HexOpt's stress tests: every interior vertex moved
    by up to ``amp`` edge lengths (:func:`comparison.stress.stress`, seed 0 for 1.5, 1 otherwise)."""
    from comparison.stress import stress

    _start_rows(lambda P, H: [(f"{amp:g}", stress(P, H, frac=1.0, amp=amp, seed=0 if amp == 1.5 else 1))
                              for amp in amps], "moved by (edge lengths)", names, jobs, (TURNED,))


def scattered(names=None, wheres=("centroid", "box"), jobs=0):
    """The default repair on the published meshes with every interior vertex at the centroid, or anywhere in the
    bounding box (:func:`comparison.stress.scatter_interior`, seed 0): nothing of the interior kept but its
    connectivity."""
    from comparison.stress import scatter_interior

    labels = {"centroid": "at the centroid", "box": "anywhere in the box"}
    extra = (("harmonic start", lambda r, diag: "yes" if r.stats["harmonic_start"] else "no"),
             ("farthest boundary vertex (of diag)",
              lambda r, diag: f"{100 * r.stats.get('boundary_max_distance', 0.0) / diag:.2f}%"), TURNED)
    _start_rows(lambda P, H: [(labels[w], scatter_interior(P, H, where=w, seed=0)) for w in wheres],
                "interior vertices", names, jobs, extra)


#: ``--subdivided``'s cases: (solid, largest tetrahedron edge, share of the boundary vertices slid, by how many edge
#: lengths, seed)
SUBDIVIDED = (("sphere", 0.25, 0.1, 0.8, 0), ("cone", 0.15, 0.2, 1.2, 3), ("holed_box", 0.12, 0.1, 0.8, 2),
              ("torus", 0.12, 0.1, 0.8, 1), ("torus", 0.08, 0.3, 1.5, 6))


def subdivided(cases=SUBDIVIDED, jobs=0):
    """The default repair on the :data:`SUBDIVIDED` cases (module docstring), one line of the README's table each."""
    from comparison.stress import slide_boundary, subdivided_solid

    print("| solid (largest tet edge) | hexes | boundary vertices slid (by, edge lengths) | not valid before -> after | "
          "certified | SJ before sliding -> slid, min | SJ after min / p1 / mean | Hausdorff (of diag) | "
          "farthest boundary vertex (of diag) | shortest / longest edge, least | seconds: untangle / quality / "
          "vertex steps / joint steps / certify / total |\n|---|---|---|---|---|---|---|---|---|---|---|")
    for shape, size, frac, amp, seed in cases:
        P0, H = subdivided_solid(shape, size)
        P = slide_boundary(P0, H, frac=frac, amp=amp, seed=seed)
        t0 = time.perf_counter()
        r = repair(P, H, jobs=jobs)  # 0: every core, as `hexsos repair`
        t = time.perf_counter() - t0
        st = r.stats
        diag = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
        f = _fid(P, r.points, H, [])
        haus = "n/a" if f is None or f["hausdorff_max"] is None else f"{100 * f['hausdorff_max'] / diag:.2f}%"
        sj0 = float(scaled_jacobian(P0, [("hexahedron", H)]).min())
        print(f"| {shape} ({size:g}) | {len(H):,} | {100 * frac:g}% ({amp:g}) | "
              f"{st['invalid_before'] + st['undecided_before']:,} -> {st['invalid_after'] + st['undecided_after']:,} | "
              f"{'yes' if r.success else 'NO'} | {sj0:.3f} -> {st['min_sj_before']:.3f} | "
              f"{st['min_sj_after']:.3f} / {st['p1_sj_after']:.3f} / {st['mean_sj_after']:.3f} | "
              f"{haus} | "
              f"{100 * st.get('boundary_max_distance', 0.0) / diag:.2f}% | {st['edge_ratio_after']:.4f} | "
              f"{_stage_seconds(st['stage_seconds'])} / {t:.1f} |", flush=True)


def _fid(P, Q, H, cells):
    """pymeshlab's boundary fidelity (:func:`boundary_fidelity`), None without pymeshlab."""
    try:
        return boundary_fidelity(P, Q, H, cells=cells)
    except Exception:  # noqa: BLE001 - pymeshlab absent: the table says n/a
        return None


def run(quick=False, use_gmsh=True, gmsh_max_hexes=10000, table1=False):
    rows = []
    for name, P, H, cells in meshes(quick):
        print(f"  {name}: {len(H)} hexes ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        res = repair(P, H, cells=cells)
        t = time.perf_counter() - t0
        entry = {"ours": _row(name, P, H, cells, res.points, H, t, res.success)}
        entry["ours"]["stage_seconds"] = res.stats["stage_seconds"]
        t0 = time.perf_counter()
        rp = repair(P, H, cells=cells, method="paper")
        entry["paper"] = _row(name, P, H, cells, rp.points, H, time.perf_counter() - t0, rp.success)
        entry["paper"]["outer_iterations"] = rp.stats["outer_iterations"]
        entry["paper"]["sos_steps"] = rp.stats["sos_steps"]
        entry["paper"]["projection_steps"] = rp.stats["projection_steps"]
        if use_gmsh and len(H) <= gmsh_max_hexes and not cells:
            try:
                Q, H2, wall, _ = gmsh_untangle(P, H)
                entry["gmsh"] = _row(name, P, H, cells, Q, H2, wall)
            except Exception as exc:  # pragma: no cover - depends on the Gmsh build
                entry["gmsh"] = {"error": f"{type(exc).__name__}: {exc}"}
        elif use_gmsh:
            entry["gmsh"] = {"skipped": "mixed mesh" if cells else f"more than {gmsh_max_hexes} hexes"}
        rows.append(entry)
        print(f"  {name}: ours {t:.1f} s, certified {res.success}, min SJ {entry['ours']['sj_after']['min']:.3f}",
              file=sys.stderr, flush=True)
    print_table(rows)
    if table1:
        _print_table1(rows)
    return rows


SHARED = os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))
#: The published meshes of ``../shared/data`` (read in place; skipped when absent).
PUBLISHED = ["hexalab/rockarm.vtk", "bunny.vtk", "hexalab/cat_2.mesh", "hexalab/Dolphin_2.mesh",
             "hexalab/hex_torus.vtk", "hexalab/dinopet_graded.mesh", "hexalab/warrior_graded.mesh",
             "hexalab/kitten_with_bifur_3.mesh"]


def published(local=False, names=None, jobs=0, feature_angle=45.0):
    """The default repair (``local=True``: ``repair(..., local=True)``; ``feature_angle``: the repair's) on the
    published meshes: one row each with the counts, the scaled Jacobian before / after, Hausdorff, max move, moved
    vertices and seconds per stage."""
    from comparison.stress import single_fold

    # the compiled loops load (or compile, once per installation) before the clock starts: a fold inside a hex and
    # an inverted hex under a boundary face take every path of the default repair
    P, H, _ = single_fold(4)
    repair(P, H, local=local)
    P, H = structured_grid(4)
    P[(2 * 5 + 2) * 5 + 4, 2] -= 0.4
    repair(P, H, local=local)
    rows = []
    load0 = os.getloadavg()[0]
    for name, m in _published_meshes(names):
        print(f"  {name}: {len(m.hexes)} hexes ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        res = repair(m.points, m.hexes, local=local, jobs=jobs, feature_angle=feature_angle)  # 0: every core
        t = time.perf_counter() - t0
        row = _row(name, m.points, m.hexes, [], res.points, m.hexes, t, res.success)
        row.update(stage_seconds=res.stats["stage_seconds"], moved=res.stats["moved_vertices"],
                   points=int(len(m.points)), moved_over_1pct=res.stats["moved_over_1pct"], load=os.getloadavg()[0],
                   surface=TURNED[1](res, None), leash=res.stats.get("boundary_leash"))
        rows.append(row)
        print(f"  {name}: {t:.1f} s, certified {res.success}, min SJ {row['sj_after']['min']:.3f}, load "
              f"{row['load']:.1f}", file=sys.stderr, flush=True)
    print(f"\n(load average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end, on "
          f"{os.cpu_count()} cores)")
    print("\n| mesh | hexes | not valid before -> after | certified | SJ before min / p1 / mean | SJ after min / p1 / "
          "mean | Hausdorff (of diag) | max move (of diag) | moved vertices (> 1% of diag) | shortest / longest edge "
          "of a hex, least (hexes < 0.05): before -> after | self-intersecting boundary quads: before -> after | "
          f"{TURNED[0]} | "
          "seconds: untangle / quality / vertex steps / joint steps / certify / total |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        parts = _stage_seconds(r["stage_seconds"])
        (a0, n0), (a1, n1) = r["edge_ratio_before"], r["edge_ratio_after"]
        x = "n/a" if r["self_intersecting"] is None else "{:,} -> {:,}".format(*r["self_intersecting"])
        print(f"| {r['mesh']} | {r['hexes']:,} | {_fmt(r).rsplit(' | ', 1)[0]} | {r['moved']:,} of {r['points']:,} "
              f"({r['moved_over_1pct']:,}) | {a0:.4f} ({n0:,}) -> {a1:.4f} ({n1:,}) | {x} | "
              f"{r['surface']} | {parts} / "
              f"{r['seconds']:.1f} |")
    for r in rows:
        info = r.get("leash") or {}
        if info.get("vertices"):
            print(f"\n{r['mesh']}: the first run ended {100 * info['deviation']:.2f}% of the diagonal from the input "
                  f"surface (sampled); {info['vertices']} boundary vertices there "
                  + (f"held within {100 * info['radius']:g}% of their input positions in a second run of "
                     f"{info['seconds']:.1f} s: " + ("not certified" if info["deviation_leashed"] is None else
                                                     f"{100 * info['deviation_leashed']:.2f}%")
                     + f", min SJ {info['min_sj_free']:.3f} -> {info['min_sj_leashed']:.3f}, "
                     + ("kept (the stage seconds above are its own, the total both)" if info["kept"] else "not kept")
                     if info.get("run") else f"not held ({info.get('why')})"))
    return rows


def _fmt(r):
    if "mesh" not in r:
        return None
    h = "n/a" if r["hausdorff_pct"] is None else f"{r['hausdorff_pct']:.2f}%"
    return (f"{r['bad_before']:,} -> {r['bad_after']:,} | {'yes' if r['certified'] else 'NO'} | "
            f"{r['sj_before']['min']:.3f} / {r['sj_before']['p1']:.3f} / {r['sj_before']['mean']:.3f} | "
            f"{r['sj_after']['min']:.3f} / {r['sj_after']['p1']:.3f} / {r['sj_after']['mean']:.3f} | {h} | "
            f"{r['max_move_pct']:.2f}% | {r['seconds']:.1f}")


def print_table(rows):
    print("\n| mesh | hexes | repair | not valid before -> after | certified | SJ before min / p1 / mean | "
          "SJ after min / p1 / mean | Hausdorff (of diag) | max move (of diag) | seconds | shortest / longest edge "
          "of a hex, least: before -> after |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for e in rows:
        o = e["ours"]
        cells = f"{o['hexes']:,}" + (f" + {o['other_cells']:,} prisms" if o["other_cells"] else "")
        for key, label in (("ours", "hexsos (default)"), ("paper", "paper's Alg. 2"), ("gmsh", "Gmsh untangler")):
            r = e.get(key)
            if r is None:
                continue
            f = _fmt(r)
            if f is None:
                print(f"| {o['mesh']} | {cells} | {label} | {r.get('error') or r.get('skipped')} | | | | | | | |")
            else:
                print(f"| {o['mesh']} | {cells} | {label} | {f} | {r['edge_ratio_before'][0]:.4f} -> "
                      f"{r['edge_ratio_after'][0]:.4f} |")


def _print_table1(rows):
    print("\nthe paper's Algorithm 2 (method='paper') in Table 1's columns, against the paper's mesh nearest in size")
    print(f"{'mesh':22s} {'hexes':>6s} {'outer':>5s} {'SOS steps':>9s} {'(R) steps':>9s} {'seconds':>8s} "
          f"{'paper mesh':>10s} {'p.seconds':>9s}")
    for e in rows:
        p = e["paper"]
        ref = paper_reference(p["mesh"], p["hexes"])
        print(f"{p['mesh']:22s} {p['hexes']:6d} {p['outer_iterations']:5d} {p['sos_steps']:9d} "
              f"{p['projection_steps']:9d} {p['seconds']:8.2f} {ref[0]:>10s} {ref[6] * 60:9.1f}")


def samples(quick=False):
    """Stage 1's sample points, measured on stress tests: untangled?, stage-1 iterations and seconds."""
    from comparison.stress import graded_solid, stress, single_fold
    from hexsos_plugins.meshrepair import optimize as opt
    from hexsos_plugins.meshrepair.driver import cell_size

    cases = []
    for n, frac in (((6, 0.9),) if quick else ((8, 0.9), (12, 0.8))):
        P, H = graded_solid(n)
        cases.append((f"graded{n} stress {int(100 * frac)}%", stress(P, H, frac=frac, amp=1.0, seed=n), H))
    P, H, _ = single_fold(5)
    cases.append(("fold5", P, H))
    print("\n| mesh | stage-1 samples | untangled (all corners and coefficients > 0) | iterations | seconds |")
    print("|---|---|---|---|---|")
    for name, P, H in cases:
        for mode, label in (("none", "corners only"), ("flagged", "corners + 27 coefficients where needed"),
                            ("all", "corners + 27 coefficients of every hex")):
            prob = opt.Problem(P, [("hexahedron", H)], [cell_size(P, "hexahedron", H)], np.ones(len(P), bool))
            t0 = time.perf_counter()
            info = opt.untangle(prob, bernstein=mode)
            t = time.perf_counter() - t0
            full = opt.Problem(prob.V, [("hexahedron", H)], [cell_size(P, "hexahedron", H)], np.ones(len(P), bool))
            ok = full.feasible_valid(prob.V)
            cert = bool((check(prob.V, H).status == 1).all())
            print(f"| {name} | {label} | {'yes' if ok else 'no'} (kernel: {'all valid' if cert else 'not all valid'})"
                  f" | {info['iterations']} | {t:.2f} |")


def corner_loops(names=None):
    """Stage 1's corner term on hexes, the general loop (``kernels.untangle_corners``, every node of G) against the
    hex loop the repair runs (``kernels.untangle_edges``, each column a difference of two nodes), one thread each, in
    this process, on the same coordinates: a generated stress test (a 20^3 graded solid, every interior vertex moved
    by an edge length) and the published meshes so perturbed (1.5 edge lengths, seed 0, as ``--perturbed``); their
    energies and gradients are compared to the bit."""
    from comparison.stress import graded_solid, stress
    from hexsos_plugins.meshrepair import kernels as nb
    from hexsos_plugins.meshrepair import optimize as opt
    from hexsos_plugins.meshrepair.driver import cell_size

    nb.load()
    P, H = graded_solid(20)
    cases = [("graded20 stress 100%", stress(P, H, frac=1.0, amp=1.0, seed=20), H)]
    for name, m in _published_meshes(names):
        cases.append((name, stress(m.points, m.hexes, frac=1.0, amp=1.5, seed=0), m.hexes))
    print("| mesh | hexes | general loop (ms) | hex loop (ms) | ratio | the same numbers |\n|---|---|---|---|---|---|")
    for name, P, H in cases:
        H = np.ascontiguousarray(H, dtype=np.int64)
        prob = opt.Problem(P, [("hexahedron", H)], [cell_size(P, "hexahedron", H)], np.ones(len(P), dtype=bool))
        b = prob.blocks[0]
        head, tail = b["edges"]
        V = np.ascontiguousarray(prob.V)
        runs = {}
        loops = (("general", nb.untangle_corners, (b["Gw3"],)), ("hex", nb.untangle_edges, (head, tail)))
        for label, fn, args in loops:
            g = np.zeros_like(V)
            out = fn(V, b["conn"], *args, b["s"], 0.1, opt.THETA, g, True)
            reps = max(3, int(2e6 // len(H)))
            t0 = time.perf_counter()
            for _ in range(reps):
                fn(V, b["conn"], *args, b["s"], 0.1, opt.THETA, np.zeros_like(V), True)
            runs[label] = ((time.perf_counter() - t0) / reps, out, g)
        (tg, og, gg), (th, oh, gh) = runs["general"], runs["hex"]
        same = og == oh and np.array_equal(gg, gh)
        print(f"| {name} | {len(H):,} | {1e3 * tg:.2f} | {1e3 * th:.2f} | {tg / th:.2f}x | {'yes' if same else 'no'} |",
              flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller meshes (a minute or two)")
    ap.add_argument("--no-gmsh", action="store_true", help="skip Gmsh's untangler")
    ap.add_argument("--gmsh-max-hexes", type=int, default=10000,
                    help="run Gmsh's untangler only on meshes up to this many hexes (default 10000: it is slow)")
    ap.add_argument("--samples", action="store_true", help="measure stage 1's sample points instead")
    ap.add_argument("--table1", action="store_true", help="also print Table 1's columns for method='paper'")
    ap.add_argument("--json", metavar="OUT", help="also write the rows as JSON")
    ap.add_argument("--published", action="store_true",
                    help="the default repair on the published meshes of ../shared/data (the seven HexaLab meshes and "
                         "the bunny) instead, with moved vertices and seconds per stage")
    ap.add_argument("--local", action="store_true", help="--published: with repair(..., local=True)")
    ap.add_argument("--mesh", action="append", metavar="REL",
                    help="--published: only this mesh (path under ../shared/data; repeatable)")
    ap.add_argument("--starts", type=int, default=0, metavar="N",
                    help="--published: instead, the minimum scaled Jacobian of N starts perturbed by 1e-12 of the "
                         "diagonal (seeds 1..N) and their median: the minimum depends on rounding")
    ap.add_argument("--perturbed", action="store_true",
                    help="--published: instead, the same meshes with every interior vertex moved by up to 1.5 and 3 "
                         "edge lengths (HexOpt's stress tests)")
    ap.add_argument("--scattered", action="store_true",
                    help="--published: instead, the same meshes with every interior vertex at the centroid, and "
                         "anywhere in the bounding box")
    ap.add_argument("--jobs", type=int, default=0, metavar="N",
                    help="--published: the repair's threads (default 0: every core, as `hexsos repair`)")
    ap.add_argument("--feature-angle", type=float, default=45.0, metavar="DEGREES",
                    help="--published (and --starts): the repair's feature angle (default 45, the repair's)")
    ap.add_argument("--corner-loops", action="store_true",
                    help="stage 1's corner term: the general loop against the hex loop the repair runs")
    ap.add_argument("--subdivided", action="store_true",
                    help="instead, Gmsh's all-hex meshes of CAD solids with slid boundary vertices (module docstring)")
    args = ap.parse_args(argv)
    if args.corner_loops:
        corner_loops(args.mesh)
        return 0
    if args.subdivided:
        subdivided(jobs=args.jobs)
        return 0
    if args.published and args.scattered:
        scattered(args.mesh, jobs=args.jobs)
        return 0
    if args.published and args.perturbed:
        perturbed(args.mesh, jobs=args.jobs)
        return 0
    if args.published and args.starts > 0:
        starts(args.starts, args.mesh, jobs=args.jobs, feature_angle=args.feature_angle)
        return 0
    if args.published:
        rows = published(args.local, args.mesh, jobs=args.jobs, feature_angle=args.feature_angle)
        if args.json:
            with open(args.json, "w") as f:
                json.dump(rows, f, indent=1, default=float)
        return 0
    if args.samples:
        samples(args.quick)
        return 0
    rows = run(args.quick, use_gmsh=not args.no_gmsh, gmsh_max_hexes=args.gmsh_max_hexes, table1=args.table1)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())
