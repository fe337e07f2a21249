"""Curved cells of orders 3-5 against Gmsh's minDetJac and VTK's Lagrange cells (part of experiment 8).

    python -m comparison.curved [--quick | --tiny] [--out DIR] [--types tetra20,tetra35 | --types tet]

Per type and order (tetrahedra, hexahedra, prisms, pyramids of orders 3, 4, 5): random cells (the straight
reference cell, every node moved by Gaussian noise of sigma s / p^2, two levels: mostly valid and about half
invalid) checked by hexsos and bounded by Gmsh's ``getElementQualities(tags, "minDetJac")`` on the same cells, one
thread each, best of ``repeat``:

* throughput (cells/s) of both and their ratio; hexsos' table build (the exact rational tables, first use in a
  process, or their load from ``kernel/tables.npz``) and the tables' size;
* verdicts: where Gmsh's bound is decisive (|minDetJac| > 1e-3 of the cell's scale), sign disagreements; how
  often Gmsh's bound sits above our certified minimum (beyond 1e-9 of the scale); hexsos' undecided cells;
* soundness on a subset: det J sampled with VTK's Lagrange cells (``InterpolateDerivs``; pyramids, which VTK 9.7
  lacks, with Gmsh's ``getJacobians`` below the apex) never below our lower bound.

``--types``: only these cell types (comma-separated names, run whatever their order) or domains (``tet``,
``cube``, ``prism``, ``pyramid``: their complete types of the size's orders). Gmsh's incomplete cells
(``tetra16``, ``hexahedron32``, ...: :mod:`hexsos_plugins.cells.incomplete`) run by name; their dense samples are
VTK's (pyramids: Gmsh's) det J of the complete cell of the same map, and Gmsh's minDetJac only where Gmsh takes them
(tetrahedra, hexahedron32).

Gmsh 4.15 cannot evaluate prisms of order >= 3 ("FaceClosureFull not implemented for prisms of order 3"): their
rows have no Gmsh columns.
"""

from __future__ import annotations

import time

import numpy as np

from comparison import common as C

NAME = "curved"
TITLE = "8b. Curved cells (orders 3-5) against Gmsh and VTK"
SEED = 23
SIZES = {"tiny": {"cells": 20, "sampled": 4, "repeat": 1, "orders": (3,)},
         "quick": {"cells": 150, "sampled": 30, "repeat": 1, "orders": (3, 4)},
         "full": {"cells": 5000, "sampled": 200, "repeat": 3, "orders": (3, 4, 5)}}
LEVELS = (("mostly valid", 0.08), ("about half invalid", 0.25))


def random_cells(name, m, s, seed=SEED):
    from comparison.lagrange_oracle import reference_cell
    from hexsos_plugins.cells.elements import CELL_TYPES, ELEMENTS

    X0 = reference_cell(name)
    rng = np.random.default_rng([seed, CELL_TYPES.index(name), int(s * 1000)])
    X = X0[None] + s / ELEMENTS[name].order ** 2 * rng.standard_normal((m,) + X0.shape)
    return X


def compare(name, X, repeat, sampled, label):
    from comparison.against_gmsh import gmsh_qualities
    from comparison.lagrange_oracle import domain_points, gmsh_can_evaluate, gmsh_det, vtk_det
    from hexsos_plugins import check, kernel
    from hexsos_plugins.cells.elements import ELEMENTS
    from hexsos_plugins.cells.incomplete import COMPLETE

    el = ELEMENTS[name]
    P = X.reshape(-1, 3)
    conn = np.arange(len(P)).reshape(len(X), -1)
    t = time.perf_counter()
    tab = kernel.tables(name)
    t_tables = time.perf_counter() - t
    kernel.set_threads(1)
    check(P[: 2 * el.n_nodes], [(name, conn[:2])])  # warm
    best, r = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        r = check(P, [(name, conn)])
        best = min(best, time.perf_counter() - t)
    out = {"type": name, "order": el.order, "set": label, "cells": len(X), "nb": int(tab.nb),
           "table_seconds": round(t_tables, 3),
           "table_mb": round(sum(np.asarray(getattr(tab, f)).nbytes for f in ("S", "Snz", "M", "xi", "xj", "xw", "di",
                                                                            "dj", "dw")) / 2**20, 2),
           "valid": int(np.sum(r.status == 1)), "invalid": int(np.sum(r.status == 0)),
           "undecided": int(np.sum(r.status == -1)), "ours_per_s": len(X) / best}
    if gmsh_can_evaluate(name):
        gmin, _, tg = gmsh_qualities(P, [(name, conn)], repeat=repeat)
        decisive = np.abs(gmin) > 1e-3 * r.scale
        out.update(gmsh_per_s=len(X) / tg, ratio=round(tg and best and (len(X) / best) / (len(X) / tg), 2),
                   decisive=int(decisive.sum()),
                   sign_disagreements=int(np.sum(decisive & ((gmin > 0) != (r.status == 1)))),
                   gmsh_above_ours=int(np.sum(gmin > r.min_det + 1e-9 * r.scale)))
    else:
        out.update(gmsh_per_s=None, ratio=None, decisive=0, sign_disagreements=None, gmsh_above_ours=None)
    sub = np.arange(min(sampled, len(X)))
    pc = np.vstack([domain_points(name, 400, seed=1),
                    el.reference_nodes[el.reference_nodes[:, 2] < 1] if el.domain == "pyramid" else el.reference_nodes])
    oracle, Xs = name, X[sub]
    if name in COMPLETE:  # an incomplete cell: sampled as the complete cell of the same map (VTK or Gmsh has that)
        oracle = COMPLETE[name]
        Xs = np.einsum("qn,mna->mqa", el.shape_functions(ELEMENTS[oracle].reference_nodes), Xs)
    dense = vtk_det(oracle, Xs, pc) if el.domain != "pyramid" else gmsh_det(oracle, Xs, pc)
    out["sampled_below_lower"] = int(np.sum(dense.min(axis=1) < r.lower_bound[sub] - 1e-9 * r.scale[sub]))
    out["max_bracket"] = float(np.max((r.min_det - r.lower_bound) / r.scale))
    return out


def selected(size, types=None):
    """The (name, domain, order) rows of the curved types a run covers: the size's orders, or ``types`` (names,
    any order; domains, the size's orders), a comma-separated string or a list."""
    from hexsos_plugins.cells.incomplete import TYPES as INCOMPLETE
    from hexsos_plugins.cells.lagrange import TYPES

    orders = SIZES[size]["orders"]
    want = [w.strip() for w in (types.split(",") if isinstance(types, str) else types or []) if w.strip()]
    known = {row[0] for row in TYPES} | {row[1] for row in TYPES} | {row[0] for row in INCOMPLETE}
    unknown = [w for w in want if w not in known]
    if unknown:
        raise ValueError(f"types: expected curved cell types or domains ({', '.join(sorted(known))}), found "
                         f"{', '.join(unknown)}")
    rows = []
    for name, dom, p, *_ in TYPES:
        if (name in want) or (p in orders and (not want or dom in want)):
            rows.append((name, dom, p))
    rows += [(name, dom, p) for name, dom, p, *_ in INCOMPLETE if name in want]  # Gmsh's incomplete cells: by name
    return rows


def run_sets(size, types=None):
    cfg = SIZES[size]
    res = []
    for name, dom, p in selected(size, types):
        for label, s in LEVELS:
            C.log(f"{NAME}: {name} ({label})")
            res.append(compare(name, random_cells(name, cfg["cells"], s), cfg["repeat"], cfg["sampled"],
                               f"{label}, s {s}"))
    return res


def tables_md(res):
    rows = [[s["type"], s["order"], s["set"], s["cells"], s["valid"], s["invalid"], s["undecided"],
             C.fmt(s["decisive"]), "-" if s["sign_disagreements"] is None else s["sign_disagreements"],
             "-" if s["gmsh_above_ours"] is None else s["gmsh_above_ours"], s["sampled_below_lower"],
             C.fmt(s["max_bracket"])] for s in res]
    trow = [[s["type"], s["order"], s["set"], s["nb"], s["table_seconds"], s["table_mb"], round(s["ours_per_s"]),
             "-" if s["gmsh_per_s"] is None else round(s["gmsh_per_s"]), "-" if s["ratio"] is None else s["ratio"]]
            for s in res]
    return "\n".join([
        C.table(["type", "order", "cells", "count", "valid", "invalid", "undecided", "Gmsh decisive",
                 "sign disagreements", "Gmsh bound > our min", "VTK sampled < our lower bound", "max bracket / scale"],
                rows, "Curved cells: hexsos' certified verdicts against Gmsh's minDetJac where it is decisive "
                "(prisms: Gmsh 4.15 cannot evaluate them), and dense sampling of det J with VTK's Lagrange cells "
                "(pyramids: Gmsh's getJacobians)."),
        C.table(["type", "order", "cells", "det J coefficients", "tables s", "tables MB", "hexsos cells/s",
                 "Gmsh cells/s", "ratio hexsos / Gmsh"], trow,
                "Throughput on the same cells, one thread each (hexsos: certified minimum with argmin and proof, to "
                "1e-9 of the scale; Gmsh: minDetJac, to 1e-3), best of the repeats; the tables' build or load time "
                "in a fresh process and their size."),
    ])


def run(quick: bool = False, out="comparison-out", jobs: int = 1, *, size: str | None = None, types=None):
    t0 = time.perf_counter()
    size = C.resolve_size(quick, size)
    res = run_sets(size, types)
    bounded = [s for s in res if s["sign_disagreements"] is not None and not s["type"].startswith("pyramid")]
    summary = {NAME: {"cells": sum(s["cells"] for s in res),
                      "sign_disagreements_tets_hexes": sum(s["sign_disagreements"] for s in bounded),
                      "sampled_below_lower": sum(s["sampled_below_lower"] for s in res),
                      "undecided": sum(s["undecided"] for s in res), "sets": res, "seed": SEED}}
    return C.result(NAME, TITLE, summary, tables_md(res) + "\n", [], t0)


def main(argv=None):
    return C.standalone(run, __doc__, argv, extra=lambda ap: ap.add_argument(
        "--types", default=None, help="only these curved cell types or domains, comma-separated (tet, cube, prism, "
        "pyramid; a named type runs whatever its order)"))


if __name__ == "__main__":
    raise SystemExit(main())
