"""Experiment 8: every 3-D cell type against Gmsh's minDetJac and against dense sampling on VTK's shape functions.

    python -m comparison.cell_types [--quick | --tiny] [--out DIR]

Per type (tetra, tetra10, pyramid, pyramid13, pyramid14, wedge, wedge15, wedge18, hexahedron, hexahedron20,
hexahedron27):

* random cells (the type's reference cell, every node moved by Gaussian noise: sigma 0.15, quadratic cells 0.05)
  and meshes made by Gmsh (a box of
  tetrahedra, an extruded triangle mesh of prisms, a transfinite box of hexahedra, at order 1, 2 and 2
  incomplete; pyramids: each hexahedron of the Gmsh box cut into 6 pyramids at its centre, since this Gmsh does
  not make pyramids of a box itself; quadratic pyramids: those, raised to order 2 by Gmsh's ``setOrder``) with
  their interior nodes moved by a third of an edge (seeded);
* against Gmsh's ``getElementQualities(tags, "minDetJac")`` (divided by the type's ``gmsh_factor``: our units):
  sign agreement, how often Gmsh's bound sits above our minimum (never, beyond rounding, except for quadratic
  pyramids), the gap. For quadratic pyramids Gmsh's bound does sit above our minimum: Gmsh's *own* det J
  (``getJacobian``) at our argmin (below the apex: t <= 1 - 1e-7) is then evaluated, and lies below Gmsh's bound
  (``gmsh_det_below_its_bound``), so the bound is not one there;
* against dense sampling of det J (a subset) with VTK's ``InterpolateDerivs`` (quadratic pyramids: Gmsh's
  shape-function gradients, see :mod:`comparison.vtk_sampling`): the sampled minimum is never below our lower
  bound nor below our minimum, and a cell we call valid never samples <= 0;
* throughput of both on the same cells in one process, one thread each;
* the curved cells of orders 3-5 (tetrahedra, hexahedra, prisms, pyramids): :mod:`comparison.curved`.
"""

from __future__ import annotations

from comparison import common as C

import time  # noqa: E402

import numpy as np  # noqa: E402

NAME = "cell_types"
TITLE = "8. Every cell type against Gmsh and VTK sampling"
SEED = 8
PAPER_SIZE = "(not in the paper: hexahedra only)"
SIZES = {"tiny": {"linear": 300, "quadratic": 60, "sampled": 20, "mesh_n": 3},
         "quick": {"linear": 20_000, "quadratic": 2_000, "sampled": 60, "mesh_n": 5},
         "full": {"linear": 200_000, "quadratic": 20_000, "sampled": 300, "mesh_n": 8}}
TYPES = ("tetra", "tetra10", "pyramid", "pyramid13", "pyramid14", "wedge", "wedge15", "wedge18", "hexahedron",
         "hexahedron20", "hexahedron27")
QUADRATIC = ("tetra10", "pyramid13", "pyramid14", "wedge15", "wedge18", "hexahedron20", "hexahedron27")
QUADRATIC_PYRAMIDS = ("pyramid13", "pyramid14")
SIGMA = {"linear": 0.15, "quadratic": 0.05}  # (quadratic cells have 2-3x more nodes per edge length)


def random_cells(name, m, *, sigma=None, seed=SEED):
    """m copies of the type's reference cell with Gaussian noise on every node: points, connectivity."""
    from comparison.vtk_sampling import reference_nodes

    if sigma is None:
        sigma = SIGMA["quadratic" if name in QUADRATIC else "linear"]
    X0 = reference_nodes(name)
    rng = np.random.default_rng([seed, TYPES.index(name)])
    X = X0[None] + sigma * rng.standard_normal((m,) + X0.shape)
    return X.reshape(-1, 3), np.arange(m * X0.shape[0]).reshape(m, -1)


def gmsh_cells(name, n, *, seed=SEED):
    """A Gmsh-made mesh of cells of the type (see the module docstring), interior nodes moved: points, conn."""
    from hexsos_plugins.cells.elements import ELEMENTS
    from hexsos_plugins.examples import gmsh_model

    el = ELEMENTS[name]
    base = {"tet": "tetra", "prism": "wedge", "cube": "hexahedron", "pyramid": "hexahedron"}[el.domain]
    with gmsh_model(f"exp8-{name}") as gmsh:
        g = gmsh.model.geo
        pts = [g.addPoint(x, y, 0, 1.0 / n) for x, y in ((0, 0), (1, 0), (1, 1), (0, 1))]
        lines = [g.addLine(pts[i], pts[(i + 1) % 4]) for i in range(4)]
        surf = g.addPlaneSurface([g.addCurveLoop(lines)])
        if base == "hexahedron":
            for c in lines:
                g.mesh.setTransfiniteCurve(c, n + 1)
            g.mesh.setTransfiniteSurface(surf)
            g.mesh.setRecombine(2, surf)
            g.extrude([(2, surf)], 0, 0, 1, numElements=[n], recombine=True)
        elif base == "wedge":
            g.extrude([(2, surf)], 0, 0, 1, numElements=[n], recombine=True)  # triangles extruded: prisms
        else:
            g.extrude([(2, surf)], 0, 0, 1, numElements=[n])  # tetrahedra
        g.synchronize()
        gmsh.model.mesh.generate(3)
        if el.order == 2 and el.domain != "pyramid":
            gmsh.option.setNumber("Mesh.SecondOrderIncomplete", 1 if name in ("hexahedron20", "wedge15") else 0)
            gmsh.model.mesh.setOrder(2)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        order = np.argsort(tags)
        P = np.asarray(coords).reshape(-1, 3)[order]
        src = base if el.domain == "pyramid" else name
        _, enodes = gmsh.model.mesh.getElementsByType(ELEMENTS[src].gmsh_type)
        conn = np.searchsorted(np.asarray(tags)[order], np.asarray(enodes).reshape(-1, ELEMENTS[src].n_nodes))
        conn = conn[:, np.array(ELEMENTS[src].gmsh_to_vtk)]
    if el.domain == "pyramid":  # each hexahedron into 6 pyramids: its faces (outward) to its centre
        centre = P[conn].mean(axis=1)
        P = np.vstack([P, centre])
        apex = np.arange(len(conn)) + len(P) - len(conn)
        faces = np.array(ELEMENTS["hexahedron"].faces)  # outward: reversed, the base of a pyramid pointing inward
        conn = np.concatenate([np.column_stack([conn[:, f[::-1]], apex]) for f in faces])
        if el.order == 2:
            P, conn = _raise_pyramids(P, conn, name)
    # move the interior nodes (not on the box's boundary) by a third of an edge
    rng = np.random.default_rng([seed, 100 + TYPES.index(name)])
    inner = np.all((P > 1e-9) & (P < 1 - 1e-9), axis=1)
    P = P.copy()
    P[inner] += (1.0 / (3 * n)) * rng.standard_normal((int(inner.sum()), 3))
    return P, conn


def _raise_pyramids(P, conn, name):
    """Linear pyramids raised to order 2 by Gmsh (``setOrder`` on a discrete volume: straight edges): points, conn
    (VTK order; pyramid14: Gmsh's)."""
    from hexsos_plugins.cells.elements import ELEMENTS
    from hexsos_plugins.examples import gmsh_model

    el = ELEMENTS[name]
    with gmsh_model(f"exp8-{name}-order2") as gmsh:
        vol = gmsh.model.addDiscreteEntity(3)
        gmsh.model.mesh.addNodes(3, vol, np.arange(1, len(P) + 1), P.ravel())
        gmsh.model.mesh.addElementsByType(vol, ELEMENTS["pyramid"].gmsh_type, [], (conn + 1).ravel())
        gmsh.option.setNumber("Mesh.SecondOrderIncomplete", 1 if name == "pyramid13" else 0)
        gmsh.model.mesh.setOrder(2)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        order = np.argsort(tags)
        Q = np.asarray(coords).reshape(-1, 3)[order]
        _, enodes = gmsh.model.mesh.getElementsByType(el.gmsh_type)
        c = np.searchsorted(np.asarray(tags)[order], np.asarray(enodes).reshape(-1, el.n_nodes))
    return Q, c[:, np.array(el.gmsh_to_vtk)]


def _compare(name, P, conn, repeat, sampled, label):
    from hexsos_plugins import check
    from hexsos_plugins.kernel import threads_for

    from comparison.against_gmsh import gmsh_det_at, gmsh_qualities
    from comparison.vtk_sampling import ROUNDING, dense_min

    C.log(f"{NAME}: {name} {label}: Gmsh minDetJac on {len(conn):,} cells")
    gmin, _, tg = gmsh_qualities(P, [(name, conn)], repeat=repeat)
    C.log(f"{NAME}: {name} {label}: hexsos check")
    best, r = np.inf, None
    with threads_for(1):
        for _ in range(repeat):
            t = time.perf_counter()
            r = check(P, [(name, conn)])
            best = min(best, time.perf_counter() - t)
    scale = np.where(r.scale > 0, r.scale, 1.0)
    decided = r.status != -1
    rel = (r.min_det - gmin) / scale
    k = min(sampled, len(conn))
    d, _, _ = dense_min(name, P[conn[:k]])
    tol = ROUNDING.get(name, 0.0) * scale[:k]  # the sampler's own rounding
    above = np.flatnonzero(rel < -1e-9)
    own_below = 0
    if name in QUADRATIC_PYRAMIDS and above.size:  # Gmsh's own det J where its bound sits above our minimum
        x = r.argmin[above].copy()
        x[:, 2] = np.minimum(x[:, 2], 1 - 1e-7)
        own = gmsh_det_at(P, name, conn[above], x)
        own_below = int(np.sum(own < gmin[above] - 1e-9 * scale[above]))
    return {
        "type": name, "set": label, "cells": int(len(conn)), "invalid": int((r.status == 0).sum()),
        "inside_only": int(r.invalid_inside_only.sum()), "undecided": int((r.status == -1).sum()),
        "sign_disagreements": int(np.sum(decided & ((gmin > 0) != (r.status == 1)))),
        "gmsh_above_ours": int(np.sum(rel < -1e-9)), "max_gap": float(rel.max()), "max_bracket": float((r.gap / scale).max()),
        "sampled": int(k), "sampled_below_lower": int(np.sum(d < r.lower_bound[:k] - tol)),
        "sampled_below_min": int(np.sum(d < r.min_det[:k] - 1e-12 * scale[:k] - tol)),
        "valid_but_sampled_nonpositive": int(np.sum((r.status[:k] == 1) & (d <= 0))),
        "max_sampled_minus_min": float(((d - r.min_det[:k]) / scale[:k]).max()),
        "gmsh_det_below_its_bound": own_below,
        "gmsh_per_s": len(conn) / tg, "ours_per_s": len(conn) / best, "ratio": tg / best,
    }


def run(quick: bool = False, out="comparison-out", jobs: int = 1, *, size: str | None = None):
    """Run experiment 8 in this process (Gmsh is not thread-safe; throughput is measured on one thread)."""
    t0 = time.perf_counter()
    size = C.resolve_size(quick, size)
    cfg = SIZES[size]
    res = []
    for name in TYPES:
        m = cfg["quadratic" if name in QUADRATIC else "linear"]
        P, conn = random_cells(name, m)
        sigma = SIGMA["quadratic" if name in QUADRATIC else "linear"]
        res.append(_compare(name, P, conn, 3 if size != "tiny" else 1, cfg["sampled"], f"random, sigma {sigma}"))
        P, conn = gmsh_cells(name, cfg["mesh_n"])
        res.append(_compare(name, P, conn, 1, cfg["sampled"], "Gmsh mesh, interior moved"))
    rows = [[s["type"], s["set"], s["cells"], s["invalid"], s["inside_only"], s["undecided"], s["sign_disagreements"],
             s["gmsh_above_ours"], s["gmsh_det_below_its_bound"], s["max_gap"], s["max_bracket"],
             f"{s['sampled_below_lower']} / {s['valid_but_sampled_nonpositive']}", s["max_sampled_minus_min"]]
            for s in res]
    trow = [[s["type"], s["cells"], round(s["gmsh_per_s"]), round(s["ours_per_s"]), s["ratio"]]
            for s in res if s["set"].startswith("random")]
    bounded = [s for s in res if s["type"] not in QUADRATIC_PYRAMIDS]  # where Gmsh's minDetJac is a bound
    pyr = [s for s in res if s["type"] in QUADRATIC_PYRAMIDS]
    summary = {NAME: {
        "cells": sum(s["cells"] for s in res),
        "sign_disagreements": sum(s["sign_disagreements"] for s in bounded),
        "gmsh_above_ours": sum(s["gmsh_above_ours"] for s in bounded),
        "quadratic_pyramids": {"cells": sum(s["cells"] for s in pyr),
                               "sign_disagreements": sum(s["sign_disagreements"] for s in pyr),
                               "gmsh_above_ours": sum(s["gmsh_above_ours"] for s in pyr),
                               "gmsh_det_below_its_bound": sum(s["gmsh_det_below_its_bound"] for s in pyr)},
        "sampled_below_lower": sum(s["sampled_below_lower"] for s in res),
        "valid_but_sampled_nonpositive": sum(s["valid_but_sampled_nonpositive"] for s in res),
        "max_bracket": max(s["max_bracket"] for s in res),
        "sets": res, "seed": SEED, "sigma": SIGMA,
    }}
    md = [
        C.table(["type", "cells", "count", "invalid", "inside only", "undecided", "sign disagreements with Gmsh",
                 "Gmsh bound > our min", "there Gmsh's own det J < its bound", "max gap / scale", "max bracket / scale", "sampled < lower bound / valid but "
                 "sampled <= 0", "max (sampled - min) / scale"], rows,
                "Every cell type on random and Gmsh-made cells: Gmsh's minDetJac (in our units) against our certified "
                "minimum (the gap is how far Gmsh's bound sits below it: Gmsh stops within 1e-3; for quadratic "
                "pyramids its bound lies above its own det J at our argmin), and dense sampling with VTK's shape "
                "functions (quadratic pyramids: Gmsh's) on a subset (the sampled minimum may exceed ours by the grid's "
                "resolution, never fall below it)."),
        C.table(["type", "cells", "Gmsh cells/s", "hexsos cells/s", "ratio hexsos / Gmsh"], trow,
                "Throughput on the same random cells in one process, one thread each (hexsos: the certified check with "
                "argmin; Gmsh: minDetJac), best of 3."),
    ]
    # the curved cells of orders 3-5 (comparison.curved): the same comparisons on random cells
    from comparison import curved

    cres = curved.run_sets(size)
    summary[NAME]["curved"] = {"sets": cres, "sampled_below_lower": sum(s["sampled_below_lower"] for s in cres),
                               "undecided": sum(s["undecided"] for s in cres)}
    md.append(curved.tables_md(cres))
    return C.result(NAME, TITLE, summary, "\n".join(md) + "\n", [], t0)


def main(argv=None):
    return C.standalone(run, __doc__, argv)


if __name__ == "__main__":
    raise SystemExit(main())
