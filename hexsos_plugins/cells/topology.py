"""What the connectivity alone tells: cells no placement of the points makes valid, cells written twice.

A linear cell that names one point at both ends of one of its edges is collapsed: the edge has no length wherever
the point is, so det J is 0 at its corners there and the cell is never valid (a wedge written as a hexahedron, its
nodes merged in pairs, say). A repair refuses it by name, before it moves anything (as it refuses a mesh folded by
its node order, :mod:`hexsos_plugins.meshrepair.orientation`): untangling around it could not succeed, and moved
the rest of the mesh trying (a 3^3 grid with one hex's nodes 0 and 1 merged: the boundary 13.6% of the diagonal
from the input's, the hex still invalid).

A cell on the same points as an earlier one of its type is a copy: Gmsh's MSH 2 writes an element once per physical
group it is in. ``check`` names the copies (each is valid or not as its original is, but a solver reading the cells
as they are counts the element twice), the faces between cells read each cell once
(:meth:`hexsos_plugins.io.mesh.Mesh.copies`) and the repair moves each cell once
(:mod:`hexsos_plugins.meshrepair.copies`).
"""

from __future__ import annotations

import numpy as np

from .elements import ELEMENTS
from ..errors import InvalidInputError

__all__ = ["refuse_collapsed", "collapsed_cells", "face_diagonals", "repeated_cells", "repeated_words", "edges",
           "LINEAR"]

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


def face_diagonals(name):
    """(D, 2) the corner pairs across the diagonals of the quadrilateral faces of cell type ``name``, sorted."""
    pairs = set()
    for f in ELEMENTS[name].faces:
        if len(f) == 4:
            pairs.update((min(a, b), max(a, b)) for a, b in ((f[0], f[2]), (f[1], f[3])))
    return np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)


def collapsed_cells(name, conn, pairs=None) -> np.ndarray:
    """(M,) bool: the cells of a block of ``name`` (a linear type of :data:`LINEAR`; others: none) with the same
    point at both ends of one of ``pairs`` of corners ((P, 2); None: its edges, :func:`edges`)."""
    conn = np.asarray(conn, dtype=np.int64)
    if name not in LINEAR or conn.shape[0] == 0:
        return np.zeros(conn.shape[0], dtype=bool)
    e = edges(name) if pairs is None else pairs
    if e.shape[0] == 0:
        return np.zeros(conn.shape[0], dtype=bool)
    return (conn[:, e[:, 0]] == conn[:, e[:, 1]]).any(axis=1)


def _hashes(conn):
    """(M,) uint64: the hash of each cell's set of points (``conn`` (M, k) int64, not negative), whatever their
    order: the sum of the squares of its point numbers as unsigned 64-bit integers (wrapping), one pass over the
    connectivity. Cells of equal hashes are compared point by point, so any hash is exact (a test makes every hash
    equal); a grid's numbering gives every cell its own."""
    u = conn.view(np.uint64)
    return np.einsum("ij,ij->i", u, u)


def repeated_cells(blocks) -> np.ndarray:
    """(M,) int over the cells of ``blocks`` (a list of (type, conn), cells numbered across them in their order):
    for each cell, the number of the first earlier cell of its type with the same set of points, -1 where there is
    none. Blocks of one type are read together (a cell written in two physical groups is found). Only cells whose
    hash (:func:`_hashes`) another shares are compared point by point: about 25 ms a million hexes (numpy's unique
    rows over all of them: 0.7 s)."""
    blocks = [(name, np.asarray(conn, dtype=np.int64)) for name, conn in blocks]
    sizes = [conn.shape[0] for _, conn in blocks]
    out = np.full(sum(sizes), -1, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    counts = {}
    for name, conn in blocks:
        counts[name] = counts.get(name, 0) + conn.shape[0]
    if max(counts.values(), default=0) < 2:
        return out
    for name in dict.fromkeys(name for name, _ in blocks):
        mine = [k for k, (n, _) in enumerate(blocks) if n == name]
        conn = np.concatenate([blocks[k][1] for k in mine]) if len(mine) > 1 else blocks[mine[0]][1]
        if conn.shape[0] < 2:
            continue
        h = _hashes(conn)
        ordered = np.sort(h)
        shared_values = ordered[1:][ordered[1:] == ordered[:-1]]
        if not shared_values.size:
            continue
        cand = np.flatnonzero(np.isin(h, shared_values))  # in cell order: the first of equal rows is the earliest
        _, first, inverse = np.unique(np.sort(conn[cand], axis=1), axis=0, return_index=True, return_inverse=True)
        owner = cand[first[inverse.ravel()]]
        later = owner != cand
        number = np.concatenate([np.arange(starts[k], starts[k + 1]) for k in mine])
        out[number[cand[later]]] = number[owner[later]]
    return out


def repeated_words(twin) -> str:
    """The words on the cells :func:`repeated_cells` found (``twin`` its result; "" where there are none)."""
    later = np.flatnonzero(np.asarray(twin) >= 0)
    if not later.size:
        return ""
    k, first = int(later[0]), int(twin[later[0]])
    return (f"{later.size} cell{'s name' if later.size != 1 else ' names'} the same points as an earlier cell "
            f"(cells {_shown(later, 0)}; cell {k} names those of cell {first})")


def _shown(rows, offset, limit=5):
    return ", ".join(str(int(r) + offset) for r in rows[:limit]) + (", ..." if len(rows) > limit else "")


def refuse_collapsed(blocks) -> None:
    """Raise :class:`~hexsos_plugins.errors.InvalidInputError` naming the cells of ``blocks`` (a list of (type,
    conn); cells numbered across the blocks, in their order) that are collapsed (:func:`collapsed_cells`): one point
    at both ends of an edge, or else at two corners across a quadrilateral face (:func:`face_diagonals`: the face's
    other two corners then have two edges alike, so det J is 0 at them wherever the point is)."""
    for pairs_of, where, why in (
            (edges, "at both ends of an edge", "the edge has no length wherever the point is, so det J is 0 there"),
            (face_diagonals, "at two corners across a face",
             "the face's other two corners then have two edges alike wherever the point is, so det J is 0 at them")):
        offset = 0
        for name, conn in blocks:
            conn = np.asarray(conn)
            e = pairs_of(name) if name in LINEAR else np.zeros((0, 2), dtype=np.int64)  # others: never collapsed
            bad = np.flatnonzero(collapsed_cells(name, conn, e))
            if bad.size:
                row = conn[bad[0]]
                a, b = e[np.flatnonzero(row[e[:, 0]] == row[e[:, 1]])[0]]
                raise InvalidInputError(
                    f"{bad.size} {name} cell{'s name' if bad.size != 1 else ' names'} one point {where} "
                    f"(cells {_shown(bad, offset)}; cell {int(bad[0]) + offset}: point {int(row[a])} as its nodes "
                    f"{a} and {b}): {why}, and no repair makes the cell valid. Expected distinct points at the "
                    "corners of every edge and face: write a collapsed cell as the type it is (a wedge, a pyramid) "
                    "or leave it out")
            offset += len(conn)
