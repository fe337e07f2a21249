"""Cells no placement of the points makes valid, told by their connectivity alone.

A linear cell that names one point at both ends of one of its edges is collapsed: the edge has no length wherever
the point is, so det J is 0 at its corners there and the cell is never valid (a wedge written as a hexahedron, its
nodes merged in pairs, say). A cell that names the same points as another overlaps it wherever they are. A repair
refuses both by name, before it moves anything (as it refuses a mesh folded by its node order,
:mod:`hexsos_plugins.meshrepair.orientation`): untangling around them could not succeed, and moved the rest of the
mesh trying (a 3^3 grid with one hex's nodes 0 and 1 merged: the boundary 13.6% of the diagonal from the input's,
the hex still invalid).
"""

from __future__ import annotations

import numpy as np

from ..cells.elements import ELEMENTS
from ..errors import InvalidInputError

__all__ = ["refuse_collapsed", "collapsed_cells", "repeated_cells", "edges", "LINEAR"]

#: The cell types whose every node is a corner: a repeated node on an edge makes det J 0 there
LINEAR = ("hexahedron", "tetra", "wedge", "pyramid")


def edges(name):
    """(E, 2) the corner pairs of the edges of cell type ``name`` (from its faces), sorted."""
    pairs = set()
    for f in ELEMENTS[name].faces:
        for j in range(len(f)):
            a, b = f[j], f[(j + 1) % len(f)]
            pairs.add((min(a, b), max(a, b)))
    return np.array(sorted(pairs), dtype=np.int64)


def collapsed_cells(name, conn) -> np.ndarray:
    """(M,) bool: the cells of a block of ``name`` (a linear type of :data:`LINEAR`; others: none) with the same
    point at both ends of an edge."""
    conn = np.asarray(conn, dtype=np.int64)
    if name not in LINEAR or conn.shape[0] == 0:
        return np.zeros(conn.shape[0], dtype=bool)
    e = edges(name)
    return (conn[:, e[:, 0]] == conn[:, e[:, 1]]).any(axis=1)


def repeated_cells(conn) -> np.ndarray:
    """(M,) int: for each cell of a block, the index of the first earlier cell of the block with the same set of
    points, -1 where there is none (two blocks of one type are read apart)."""
    conn = np.asarray(conn, dtype=np.int64)
    out = np.full(conn.shape[0], -1, dtype=np.int64)
    if conn.shape[0] < 2:
        return out
    key = np.sort(conn, axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    owner = first[inverse.ravel()]
    later = owner != np.arange(conn.shape[0])
    out[later] = owner[later]
    return out


def _shown(rows, offset, limit=5):
    return ", ".join(str(int(r) + offset) for r in rows[:limit]) + (", ..." if len(rows) > limit else "")


def refuse_collapsed(blocks) -> None:
    """Raise :class:`~hexsos_plugins.errors.InvalidInputError` naming the cells of ``blocks`` (a list of (type,
    conn); cells numbered across the blocks, in their order) that are collapsed (:func:`collapsed_cells`) or repeat
    another cell's points (:func:`repeated_cells`)."""
    offset = 0
    for name, conn in blocks:
        conn = np.asarray(conn)
        bad = np.flatnonzero(collapsed_cells(name, conn))
        if bad.size:
            row = conn[bad[0]]
            e = edges(name)
            a, b = e[np.flatnonzero(row[e[:, 0]] == row[e[:, 1]])[0]]
            raise InvalidInputError(
                f"{bad.size} {name} cell{'s name' if bad.size != 1 else ' names'} one point at both ends of an edge "
                f"(cells {_shown(bad, offset)}; cell {int(bad[0]) + offset}: point {int(row[a])} as its nodes {a} "
                f"and {b}): the edge has no length wherever the point is, so det J is 0 there and no repair makes "
                f"the cell valid. Expected distinct points at the ends of every edge: write a collapsed cell as "
                "the type it is (a wedge, a pyramid) or leave it out")
        twin = repeated_cells(conn)
        later = np.flatnonzero(twin >= 0)
        if later.size:
            k, first = int(later[0]) + offset, int(twin[later[0]]) + offset
            raise InvalidInputError(
                f"{later.size} {name} cell{'s name' if later.size != 1 else ' names'} the same points as an earlier "
                f"cell (cells {_shown(later, offset)}; cell {k} names those of cell {first}): "
                "two cells on the same points overlap wherever the points are, and no repair makes them a mesh. "
                "Expected each cell once: leave the copies out")
        offset += len(conn)
