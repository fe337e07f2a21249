"""The cells a user hands over, in whatever shape their own tools keep them.

:func:`cell_pairs` turns meshio's ``CellBlock`` lists (``meshio.read(...).cells``), a ``meshio.Mesh``, a hexsos
:class:`~hexsos_plugins.io.mesh.Mesh` and ``{cell_type: conn}`` mappings into ``(cell_type, conn)`` pairs, which
:func:`hexsos_plugins.check`, :func:`hexsos_plugins.scaled_jacobian` and the pictures take. As
:func:`hexsos_plugins.read` does with a file, blocks of cells that are not 3-D (vertices, lines, triangles,
quadrilaterals: a Gmsh mesh's boundary) are left out of a ``CellBlock`` list or ``meshio.Mesh`` and counted in
``not_checked``; 3-D blocks of a type hexsos does not check are passed on, for the caller to reject by name.
Connectivity is taken as given, in VTK node order (meshio's own order for every type but the 18-node wedge; linear
wedges read by meshio from VTK files come mirrored: :func:`hexsos_plugins.read` reads files in VTK order).

Imports numpy, :mod:`.elements` and :mod:`hexsos_plugins.errors` only: meshio's objects and hexsos's meshes are
recognised by what they hold (a ``CellBlock`` has ``type`` and ``data``; a mesh ``points`` and ``cells``).
:func:`checked_block` checks one (type, connectivity) pair against the registry and the points.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from ..errors import InvalidInputError
from .elements import ELEMENTS

__all__ = ["CHECKABLE", "is_3d", "cell_pairs", "mesh_points_and_cells", "checked_block"]

#: meshio cell type names hexsos checks (``voxel`` as a hexahedron)
CHECKABLE = tuple(ELEMENTS) + ("voxel",)

_3D_PREFIXES = ("tetra", "hexahedron", "wedge", "pyramid", "polyhedron", "voxel", "VTK_LAGRANGE_TETRA",
                "VTK_LAGRANGE_HEXA", "VTK_LAGRANGE_WEDGE", "VTK_LAGRANGE_PYRA")


def is_3d(cell_type: str) -> bool:
    """Is a meshio cell type name a 3-D cell (checked or not)?"""
    return str(cell_type).startswith(_3D_PREFIXES)


def _is_block(item) -> bool:
    return hasattr(item, "data") and isinstance(getattr(item, "type", None), str)


def _is_mesh(obj) -> bool:
    """A meshio.Mesh or a hexsos Mesh: points, and cells (CellBlocks or (type, conn) pairs)."""
    return (not isinstance(obj, (np.ndarray, list, tuple, dict)) and hasattr(obj, "points")
            and isinstance(getattr(obj, "cells", None), (list, tuple)))


def cell_pairs(cells):
    """``(pairs, not_checked)``: ``cells`` as ``[(cell_type, conn), ...]`` and ``{cell_type: count}`` of the
    blocks left out (not 3-D); ``(None, {})`` when ``cells`` is none of the shapes above (an (M, 8) array, or
    pairs already)."""
    skipped_before = {}
    if _is_mesh(cells):
        skipped_before = dict(getattr(cells, "skipped", {}) or {})  # a hexsos Mesh: what its file held unchecked
        cells = list(cells.cells)
        if cells and all(isinstance(c, tuple) and len(c) == 2 and isinstance(c[0], str) for c in cells):
            return cells, skipped_before
    if isinstance(cells, dict):
        return [(str(k), v) for k, v in cells.items()], {}
    if isinstance(cells, (list, tuple)) and cells and all(_is_block(b) for b in cells):
        pairs, skipped = [], Counter(skipped_before)
        for block in cells:
            if block.type in CHECKABLE or is_3d(block.type):
                pairs.append((block.type, np.asarray(block.data)))
            else:
                skipped[block.type] += len(block.data)
        return pairs, dict(skipped)
    return None, {}


def mesh_points_and_cells(points, cells):
    """``check(mesh)``: a ``meshio.Mesh`` or hexsos ``Mesh`` given alone stands for its points and cells."""
    if cells is None and _is_mesh(points):
        return points.points, points
    return points, cells


def checked_block(k: int, name, conn, n_points: int) -> np.ndarray:
    """``conn`` of ``cells[k]`` as int64 (M, n), after checking that ``name`` is a registry type, ``conn`` an integer
    array with its node count per row and every index a point (``InvalidInputError`` saying which otherwise)."""
    if name not in ELEMENTS:
        raise InvalidInputError(f"cells[{k}]: expected a 3-D cell type ({', '.join(ELEMENTS)}), found {name!r}")
    conn = np.asarray(conn)
    n = ELEMENTS[name].n_nodes
    if conn.ndim != 2 or conn.shape[1] != n or (conn.size and conn.dtype.kind not in "iu"):
        raise InvalidInputError(f"cells[{k}] ({name}): expected an integer array of shape (M, {n}), found shape "
                                f"{conn.shape} and dtype {conn.dtype}")
    conn = np.ascontiguousarray(conn, dtype=np.int64)
    if conn.size and (conn.min() < 0 or conn.max() >= n_points):
        raise InvalidInputError(f"cells[{k}] ({name}): node index out of range 0..{n_points - 1} (found "
                                f"{int(conn.min())}..{int(conn.max())})")
    return conn
