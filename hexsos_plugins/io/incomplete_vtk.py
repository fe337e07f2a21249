"""Gmsh's incomplete cells in VTK files: written as the complete Lagrange cell of the same order and geometry.

VTK has no incomplete cell of order 3 or 4 (Gmsh's ``tetra16``, ``hexahedron32``, ``wedge24``, ... of
:mod:`hexsos_plugins.cells.incomplete`). Each such space lies in the complete space of its order, so the incomplete
cell's map *is* a map of the complete Lagrange cell: the one whose nodes are the incomplete map evaluated at the
complete lattice (its corner and edge nodes are the incomplete cell's own, its face and inner nodes new points).
VTK then draws the same cell (up to the rounding of the new points' coordinates, one evaluation in float64) and
hexsos reads back a complete cell with the same det J. The new points are per cell (two cells sharing a face each get
their own face nodes); floating-point point arrays are interpolated at them by the same shape functions, any other
point array gets 0 there (a note says which).

Gmsh's incomplete pyramids (VTK has no Lagrange pyramid at all) are left to the writers' linear pyramids, and
Gmsh's incomplete boundary triangles and quadrilaterals (``triangle9``, ``triangle12``, ``quad12``, ``quad16i``)
are written as their corners (linear triangles and quadrilaterals), with a note.

>>> import meshio, numpy as np
>>> from hexsos_plugins.cells.elements import ELEMENTS
>>> X = ELEMENTS["tetra16"].reference_nodes
>>> m = meshio.Mesh(X, [("tetra", np.arange(16)[None])])
>>> m.cells[0].type = "tetra16"  # (meshio 5.3.5 has no such type)
>>> notes = []
>>> incomplete_as_complete(m, notes)
>>> m.cells[0].type, m.cells[0].data.shape, len(m.points)
('tetra20', (1, 20), 20)
"""

from __future__ import annotations

from collections import Counter
from functools import lru_cache

import numpy as np

from ..cells.elements import ELEMENTS, eval_exact
from ..cells.incomplete import COMPLETE
from .meshio_conventions import GMSH_EXTRA_2D

__all__ = ["incomplete_as_complete", "EXTRA_2D_CORNERS"]

#: the corners of Gmsh's incomplete triangles and quadrilaterals (their first nodes) and the linear type
EXTRA_2D_CORNERS = {name: ("triangle", 3) if name.startswith("triangle") else ("quad", 4)
                    for name, _ in GMSH_EXTRA_2D.values()}


@lru_cache(maxsize=None)
def _weights(name):
    """(where, W): for each node of the complete cell (VTK order) the incomplete node it is (or -1), and the weights
    (new nodes, incomplete nodes) of the incomplete shape functions at the complete cell's other nodes."""
    el, full = ELEMENTS[name], ELEMENTS[COMPLETE[name]]
    index = {x: i for i, x in enumerate(el.nodes)}
    where = np.array([index.get(x, -1) for x in full.nodes], dtype=np.int64)
    new = [x for x, w in zip(full.nodes, where) if w < 0]
    # exact weights, rounded once (the float evaluator in monomial form would lose digits at order 4)
    W = [[float(eval_exact(N, x)) for N in el.shape_polynomials] for x in new]
    return where, np.array(W, dtype=np.float64).reshape(len(new), el.n_nodes)


def incomplete_as_complete(m, notes: list) -> None:
    """In place, on a private copy of a mesh about to be written to a VTK format: incomplete 3-D cells (not
    pyramids) become complete Lagrange cells, incomplete triangles and quadrilaterals their corners (see the module
    docstring); a note for each."""
    points = np.asarray(m.points, dtype=np.float64)
    extra, n_full, n_lin, idx_parts = [], Counter(), Counter(), []
    start = len(points)
    for b in m.cells:
        if b.type in EXTRA_2D_CORNERS:
            lin, k = EXTRA_2D_CORNERS[b.type]
            n_lin[b.type] += len(b.data)
            b.type, b.data = lin, np.ascontiguousarray(np.asarray(b.data)[:, :k])
            continue
        if b.type not in COMPLETE or ELEMENTS[b.type].domain == "pyramid":
            continue
        conn = np.asarray(b.data, dtype=np.int64)
        where, W = _weights(b.type)
        new = np.einsum("qn,mna->mqa", W, points[conn]) if len(conn) else np.zeros((0, len(W), 3))
        ids = start + np.arange(new.shape[0] * new.shape[1]).reshape(new.shape[:2])
        out = np.empty((len(conn), len(where)), dtype=np.int64)
        out[:, where >= 0] = conn[:, where[where >= 0]]
        out[:, where < 0] = ids
        extra.append(new.reshape(-1, 3))
        idx_parts.append((conn, W))
        start += ids.size
        n_full[b.type] += len(conn)
        b.type, b.data = COMPLETE[b.type], out
    if extra:
        zeroed = []
        for key, arr in list(m.point_data.items()):
            arr = np.asarray(arr)
            if arr.dtype.kind == "f":
                vals = [np.einsum("qn,mn...->mq...", W, arr[conn]).reshape((-1,) + arr.shape[1:])
                        for conn, W in idx_parts]
            else:
                vals = [np.zeros((conn.shape[0] * W.shape[0],) + arr.shape[1:], dtype=arr.dtype)
                        for conn, W in idx_parts]
                zeroed.append(key)
            m.point_data[key] = np.concatenate([arr] + vals)
        m.points = np.concatenate([points] + extra)
        what = ", ".join(f"{k} {t} as {COMPLETE[t]}" for t, k in n_full.items())
        notes.append(f"{what} cells written as complete Lagrange cells of the same geometry (VTK has no incomplete "
                     f"cell): {start - len(points)} points added at their face and inner nodes, the incomplete map "
                     "evaluated there" + (f"; point arrays {', '.join(zeroed)} are 0 at them" if zeroed else ""))
    if n_lin:
        what = ", ".join(f"{k} {t}" for t, k in n_lin.items())
        notes.append(f"{what} cells written as linear ones (their corners; VTK has no incomplete triangle or "
                     "quadrilateral): their edge nodes are not in this file (write .msh to keep them)")
