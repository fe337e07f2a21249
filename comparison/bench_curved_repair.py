"""Benchmark of ``hexsos repair`` on curved meshes beside Gmsh's own high-order optimizers.

    python -m comparison.bench_curved_repair [--kinds shell,cylinder,torus] [--timeout S] [--json OUT.json]

Inputs (:mod:`comparison.curved_meshes`): Gmsh 4.15 meshes with ``Mesh.HighOrderOptimize`` 0, then ``setOrder``
-- a spherical shell (tetra10), an all-hex cylinder (hexahedron27), a torus (tetra20). For each input and each
repair -- ``hexsos repair IN -o OUT.msh`` (the command line, default options) and Gmsh's
``optimize("HighOrderElastic")``, ``optimize("HighOrderFastCurving")``, ``optimize("HighOrder")`` on the same
mesh -- each in its own process with a time limit of ``--timeout`` seconds (wall clock, 2 cores shared):

* cells left invalid: not proven valid by our kernel (``hexsos_plugins.check`` on every cell), and Gmsh's
  ``minDetJac`` <= 0 on the file as written;
* seconds (the whole process: reading, repairing, writing), wall clock and CPU (user + system: what the
  process used, the fair figure on a shared machine);
* min curved scaled Jacobian (min / max of det J's Bernstein coefficients, the kernel's, lower bound of
  min det J / max det J over the element);
* the largest distance of a node that lay on the exact surface to it after the repair, relative to the
  bounding-box diagonal (the issue asks <= 1e-3).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from comparison.curved_meshes import KINDS, diagonal, generate, true_distance

GMSH_METHODS = ("HighOrderElastic", "HighOrderFastCurving", "HighOrder")

_GMSH_SCRIPT = """
import sys, gmsh
sys.path.insert(0, {root!r})
from comparison.curved_meshes import build
gmsh.initialize(["-noenv"], readConfigFiles=False)
gmsh.option.setNumber("General.Terminal", 0)
build({kind!r})
gmsh.model.mesh.optimize({method!r})
gmsh.write({out!r})
gmsh.finalize()
"""


def gmsh_min_det(path):
    import gmsh

    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(path)
        _, tags, _ = gmsh.model.mesh.getElements(3)
        return np.asarray(gmsh.model.mesh.getElementQualities(np.concatenate(tags), "minDetJac"))
    finally:
        gmsh.finalize()


def measure(kind, src, out):
    """The figures of one result file against the input."""
    from hexsos_plugins import check, read
    from hexsos_plugins.meshrepair.curved import curved_scaled_jacobian

    m0, m1 = read(src), read(out)
    row = {"cells": m1.n_cells, "gmsh_invalid": int((gmsh_min_det(out) <= 0).sum())}
    if m1.skipped:
        row["note"] = f"cell types not in the registry: {m1.skipped}"
    if m1.n_cells:
        r = check(m1.points, m1.cells, jobs=2)
        row["invalid"] = int((r.status != 1).sum())
        row["min_curved_sj"] = float(curved_scaled_jacobian(m1.points, m1.cells).min())
    on = true_distance(kind, m0.points) < 1e-7
    if m0.points.shape == m1.points.shape:
        row["surface_distance_rel"] = float(true_distance(kind, m1.points[on]).max() / diagonal(kind))
        row["input_surface_distance_rel"] = float(true_distance(kind, m0.points[on]).max() / diagonal(kind))
    return row


def run(kinds, timeout):
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind in kinds:
            src = os.path.join(tmp, f"{kind}.msh")
            generate(kind, src)
            row_in = {"kind": kind, "method": "input", "seconds": 0.0}
            row_in.update(measure(kind, src, src))
            rows.append(row_in)
            print(_line(row_in), flush=True)
            jobs = [("hexsos repair", [sys.executable, "-m", "hexsos_plugins", "repair", src, "-o",
                                       os.path.join(tmp, f"{kind}.hexsos.msh")], os.path.join(tmp, f"{kind}.hexsos.msh"))]
            for method in GMSH_METHODS:
                out = os.path.join(tmp, f"{kind}.{method}.msh")
                jobs.append((f"Gmsh {method}", [sys.executable, "-c", _GMSH_SCRIPT.format(root=root, kind=kind,
                                                                                          method=method, out=out)], out))
            for name, cmd, out in jobs:
                row = {"kind": kind, "method": name}
                t = time.perf_counter()
                cpu0 = _children_cpu()
                try:
                    p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
                    row["seconds"] = time.perf_counter() - t
                    row["cpu_seconds"] = _children_cpu() - cpu0
                    row["exit"] = p.returncode
                    if os.path.exists(out):
                        row.update(measure(kind, src, out))
                except subprocess.TimeoutExpired:
                    row["seconds"] = None
                    row["note"] = f"did not finish in {timeout:g} s"
                rows.append(row)
                print(_line(row), flush=True)
    return rows


def _children_cpu():
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def _line(r):
    def f(k, fmt):
        v = r.get(k)
        return "-" if v is None else format(v, fmt)

    return (f"{r['kind']:<9} {r['method']:<28} invalid (kernel) {f('invalid', 'd'):>5}  invalid (Gmsh) "
            f"{f('gmsh_invalid', 'd'):>5}  seconds {f('seconds', '.1f'):>6} (CPU {f('cpu_seconds', '.1f'):>6})  min curved SJ {f('min_curved_sj', '.4f'):>8}"
            f"  surface distance / diagonal {f('surface_distance_rel', '.2e'):>9}  {r.get('note', '')}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", default="shell", help=f"comma-separated, of {', '.join(KINDS)} (default shell)")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per repair (default 300)")
    ap.add_argument("--json", metavar="OUT", help="write the rows as JSON")
    a = ap.parse_args(argv)
    rows = run(a.kinds.split(","), a.timeout)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
