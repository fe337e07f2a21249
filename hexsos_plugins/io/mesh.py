"""``Mesh`` (alias ``HexMesh``): the 3-D cells of a mesh file as arrays, with everything else kept aside.

Data flows one way: a mesh file (or a ``meshio.Mesh``) becomes a :class:`Mesh` -- ``points`` (N, 3) and
``cells``, one ``(cell_type, conn)`` pair per checkable 3-D block, in VTK node order for the kernel -- while
the mesh as read stays untouched in ``source`` (every cell block, point/cell/field data). Result arrays of
the kernel go back onto a *new* ``meshio.Mesh`` with :meth:`Mesh.to_meshio`, ready to be written with
:func:`hexsos_plugins.io.write`.

Node order: VTK's, for every type, with VTK's parametric coordinates (:mod:`hexsos_plugins.cells.elements` lists
each node's coordinates). The trilinear hexahedron (the same in meshio, Gmsh type 5 and Medit)::

            7-----------6
           /|          /|       face (outward, right-hand rule)
          / |         / |         bottom w=0: 0 3 2 1    top    w=1: 4 5 6 7
         4-----------5  |         front  v=0: 0 1 5 4    back   v=1: 2 3 7 6
         |  3--------|--2         left   u=0: 0 4 7 3    right  u=1: 1 2 6 5
         | /         | /
         |/          |/         w  v
         0-----------1          | /
                                |/__ u

The wedge (VTK 13, the same as Gmsh's prism): triangle 0-1-2 at t = 0, counter-clockwise seen from the
triangle 3-4-5 above it (node k + 3 above node k)::

               5                     node   (r, s, t)
              /|\\                     0    (0, 0, 0)
             / | \\                    1    (1, 0, 0)
            3-----4                   2    (0, 1, 0)
            |  2  |                   3..5  the same at t = 1
            | / \\ |
            |/   \\|       t  s
            0-----1       | /
                          |/__ r

``source`` holds every block in VTK node order (meshio's own convention; the readers of
:mod:`hexsos_plugins.io.readers` undo where meshio's format modules deviate from it, the writers redo it).

Which blocks are checked
------------------------
* Every block of a type in :data:`hexsos_plugins.cells.elements.ELEMENTS` (``tetra``, ``tetra10``, ``pyramid``,
  ``pyramid13``, ``pyramid14``, ``wedge``, ``wedge15``, ``wedge18``, ``hexahedron``, ``hexahedron20``,
  ``hexahedron27``), as it is (``pyramid14``, which VTK lacks, in Gmsh's node order, as meshio keeps it).
* ``voxel`` blocks (VTK cell type 11, nodes in lexicographic order, x fastest): converted to
  ``hexahedron`` with :data:`~hexsos_plugins.cells.elements.VOXEL_TO_VTK`; :attr:`Mesh.voxel_rows` says which
  hexahedra came from voxels. meshio 5.3.5 has no voxel cell type, so such blocks only come from
  hexsos's readers; they are kept as ``voxel`` in ``source``.
* Other 3-D types (``polyhedron``, ``hexahedron24``, orders above 2, ...) are
  kept in ``source`` and written back, but not checked: :attr:`Mesh.skipped` counts them.
* 2-D and 1-D cells are kept in ``source`` only.

``hexes`` / ``hex_blocks`` are the linear hexahedra alone (``hexahedron`` and ``voxel`` blocks), as before
other cell types were checked; ``hex_cells`` gives their positions in the cell order.

Everything here is numpy and the compiled kernel (no gmsh, no vtk).
"""

from __future__ import annotations

import copy
from collections import Counter
from functools import cached_property

import meshio
import numpy as np

from ..cells.elements import CELL_TYPES, ELEMENTS, HEX_FACES, VOXEL_TO_VTK
from ..cells.topology import repeated_cells
from ..cells.inputs import CHECKABLE, is_3d  # noqa: F401 (re-exported: io.mesh.CHECKABLE, io.mesh.is_3d)
from ..errors import InvalidInputError, NoCellsError, NoHexahedraError  # noqa: F401 (NoHexahedraError re-exported)

__all__ = ["Mesh", "HexMesh", "HEX_FACES", "FLIP", "INT_FILL", "HEX_TYPES", "MIRROR", "FACE_NODES", "CHECKABLE",
           "hexes_to_mesh", "boundary_face_rows", "is_3d"]

#: Fill value of integer cell data on the cells that are not checked (see :meth:`Mesh.to_meshio`).
INT_FILL = -2
#: meshio cell types that hold trilinear hexahedra.
HEX_TYPES = ("hexahedron", "voxel")
#: meshio cell types that are checked: the registry's and ``voxel``.



def _mirror(el) -> np.ndarray:
    """The node permutation that exchanges the parametric coordinates r and s of a cell type."""
    where = {tuple(x): i for i, x in enumerate(el.nodes)}
    return np.array([where[(x[1], x[0], x[2])] for x in el.nodes], dtype=np.int64)


#: For each checkable type, the node permutation that mirrors a cell (exchanges r and s): it turns a
#: negatively oriented cell into a positively oriented one and back; each is its own inverse.
MIRROR = {name: _mirror(el) for name, el in ELEMENTS.items()}
#: Mirror permutation of a hexahedron (swaps nodes 1<->3 and 5<->7, i.e. exchanges u and v).
FLIP = MIRROR["hexahedron"]


def _face_nodes(el) -> tuple:
    """For each corner face of ``el.faces``, every node of the cell that lies on it (corners first, in the face's
    order, then the others in node order), from the exact parametric coordinates."""
    out = []
    X = [tuple(x) for x in el.nodes]
    for face in el.faces:
        a, b, c = (np.array(X[face[i]], dtype=object) for i in range(3))
        n = np.cross(b - a, c - a)  # exact (Fractions): the face's plane in parametric space
        on = [i for i in range(len(X)) if i not in face and np.dot(n, np.array(X[i], dtype=object) - a) == 0]
        out.append(tuple(face) + tuple(on))
    return tuple(out)


class _PerType(dict):
    """{type name: fn(element)}, each computed on first use (exact arithmetic that every start would pay)."""

    def __init__(self, fn):
        super().__init__()
        self._fn = fn

    def __missing__(self, name):
        if name not in ELEMENTS:
            raise KeyError(name)
        value = self[name] = self._fn(ELEMENTS[name])
        return value


#: For each checkable type, per corner face: all the cell's nodes on that face (corners first).
FACE_NODES = _PerType(_face_nodes)


def _where(path) -> str:
    return f"{path}: " if path else ""


def _check_points(points, path=None, copy=True) -> np.ndarray:
    """Points as a float64 (N, 3) array (a private copy unless ``copy=False`` and already float64); raises
    InvalidInputError naming the first bad point."""
    try:
        arr = np.asarray(points)
    except Exception as exc:  # ragged lists and the like
        raise InvalidInputError(f"{_where(path)}expected points as an (N, 3) array, found {type(points).__name__} "
                                f"that numpy cannot convert ({exc})") from exc
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InvalidInputError(f"{_where(path)}expected points of shape (N, 3), found shape {arr.shape}")
    if arr.dtype.kind not in "biuf":
        raise InvalidInputError(f"{_where(path)}expected real point coordinates, found dtype {arr.dtype}")
    if copy or arr.dtype != np.float64:
        arr = np.array(arr, dtype=np.float64)
    else:
        arr = arr.view()
        arr.flags.writeable = False  # shared with source
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InvalidInputError(
            f"{_where(path)}expected finite point coordinates, found point {i} = {tuple(arr[i].tolist())} "
            f"({int(bad.sum())} non-finite point(s) in all)"
        )
    return arr


def _as_index_array(data, what, path=None, k=8, copy=True) -> np.ndarray:
    try:
        arr = np.asarray(data)
    except Exception as exc:
        raise InvalidInputError(f"{_where(path)}{what}: expected an (M, {k}) integer array ({exc})") from exc
    if arr.ndim != 2 or arr.shape[1] != k:
        raise InvalidInputError(f"{_where(path)}{what}: expected shape (M, {k}), found shape {arr.shape}")
    if arr.dtype.kind == "f":
        if not (np.isfinite(arr).all() and (arr == np.round(arr)).all()):
            raise InvalidInputError(f"{_where(path)}{what}: expected integer node indices, found non-integer values")
    elif arr.dtype.kind not in "iu":
        raise InvalidInputError(f"{_where(path)}{what}: expected integer node indices, found dtype {arr.dtype}")
    if not copy and arr.dtype == np.int64 and arr.flags.c_contiguous:
        arr = arr.view()
        arr.flags.writeable = False  # shared with source: neither may change the other
        return arr
    return np.array(arr, dtype=np.int64)


def _check_indices(conn, n_points, label, path=None, what="cells") -> int:
    """Raise InvalidInputError naming the first cell (by its label) that references a missing point."""
    if conn.size == 0:
        return 0
    if int(conn.min()) >= 0 and int(conn.max()) < n_points:
        return 0
    bad = (conn < 0) | (conn >= n_points)
    row = int(np.flatnonzero(bad.any(axis=1))[0])
    col = int(np.flatnonzero(bad[row])[0])
    raise InvalidInputError(
        f"{_where(path)}{label(row)} references point {int(conn[row, col])} (node {col}), but the mesh has "
        f"{n_points} points (valid indices 0..{n_points - 1}); {int(bad.any(axis=1).sum())} {what} "
        "reference missing points in all"
    )


def copy_block(block, data=None, cell_type=None):
    """A copy of a meshio CellBlock without calling its constructor (which rejects e.g. ``voxel``)."""
    new = copy.copy(block)
    new.data = copy.deepcopy(block.data) if data is None else data
    new.tags = list(getattr(block, "tags", []) or [])
    if cell_type is not None:
        new.type = cell_type
    return new


def copy_mesh(src: meshio.Mesh, *, points=None, cells=None) -> meshio.Mesh:
    """A deep copy of a meshio.Mesh (optionally with new points / cell blocks) built without re-validation."""
    new = meshio.Mesh.__new__(meshio.Mesh)
    new.points = np.array(src.points if points is None else points)
    new.cells = [copy_block(b) for b in src.cells] if cells is None else cells
    new.point_data = {k: np.array(v) for k, v in src.point_data.items()}
    new.cell_data = {k: [np.array(a) for a in v] for k, v in src.cell_data.items()}
    new.field_data = copy.deepcopy(src.field_data)
    new.point_sets = copy.deepcopy(getattr(src, "point_sets", {}) or {})
    new.cell_sets = copy.deepcopy(getattr(src, "cell_sets", {}) or {})
    new.gmsh_periodic = copy.deepcopy(getattr(src, "gmsh_periodic", None))
    new.info = copy.deepcopy(getattr(src, "info", None))
    return new


def _check_array(name, values, n_rows, what, rows_word):
    arr = np.asarray(values)
    if arr.ndim == 0 or arr.shape[0] not in n_rows:
        expect = " or ".join(f"{w} = {n}" for w, n in zip(rows_word, n_rows))
        raise InvalidInputError(
            f"{what}[{name!r}]: expected an array of shape (M,) or (M, k) with {expect}, found shape {arr.shape}"
        )
    kind = arr.dtype.kind
    if kind == "b":
        arr = arr.astype(np.int8)
    elif kind == "u":
        arr = arr.astype(np.int64)
    elif kind not in "if":
        raise InvalidInputError(f"{what}[{name!r}]: expected a real or integer array, found dtype {arr.dtype}")
    return arr


def _spread(arr, rows_by_block, blocks):
    """Per-block list of a cell array: its rows on the blocks of ``rows_by_block`` ({block: (start, stop)}),
    NaN / INT_FILL on the others."""
    fill = np.nan if arr.dtype.kind == "f" else INT_FILL
    out = []
    for b, block in enumerate(blocks):
        if b in rows_by_block:
            start, stop = rows_by_block[b]
            out.append(np.array(arr[start:stop]))
        else:
            out.append(np.full((len(block.data),) + arr.shape[1:], fill, dtype=arr.dtype))
    return out


def hexes_to_mesh(X):
    """Separate hexes (M, 8, 3) as a mesh: points (8 M, 3) and hexes (M, 8) (no shared vertices)."""
    X = np.asarray(X, dtype=np.float64).reshape(-1, 8, 3)
    return X.reshape(-1, 3).copy(), np.arange(X.shape[0] * 8, dtype=np.int64).reshape(-1, 8)


def _runs(key):
    """Rows of ``key`` (F, k), sorted node tuples, grouped by equal tuples: (order, starts, lengths), the rows in
    sorted order, where each run of equal rows starts in it and how long it is."""
    if len(key) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    n = int(key.max()) + 1
    if key.shape[1] in (3, 4) and key.min() >= 0 and n <= 3_000_000_000:
        # two packed columns: (a, b) and (c, d) each one int64 (n^2 < 2^63), sorted and compared as pairs,
        # a third of the time of sorting the four columns (a million hexes)
        key = np.ascontiguousarray(key, dtype=np.int64)
        cols = [key[:, 0] * n + key[:, 1], key[:, 2] * n + key[:, 3] if key.shape[1] == 4 else key[:, 2]]
    else:
        cols = list(key.T)
    order = np.lexsort(cols[::-1])  # sort the face node tuples; equal faces become neighbours
    change = np.zeros(len(key), dtype=bool)
    change[0] = True
    for c in cols:
        sc = c[order]
        change[1:] |= sc[1:] != sc[:-1]
    starts = np.flatnonzero(change)
    return order, starts, np.diff(np.append(starts, len(key)))


def _smaller_class(same, other, *, strict):
    """For the cells of :meth:`Mesh._handedness_classes` (their class labels ``same`` and ``other``): in a part
    split into two classes, whether the cell's class is the smaller (or, unless ``strict``, as large)."""
    counts = np.bincount(same, minlength=int(max(same.max(), other.max())) + 1)
    smaller = counts[same] < counts[other] if strict else counts[same] <= counts[other]
    return (same != other) & smaller


def _unique_rows(key):
    """Rows of ``key`` (F, k), sorted node tuples, that occur exactly once, sorted."""
    if len(key) == 0:
        return np.zeros(0, dtype=np.int64)
    order, starts, lengths = _runs(key)
    return np.sort(order[starts[lengths == 1]])  # runs of length 1: faces of exactly one cell


def boundary_face_rows(hexes):
    """All hex faces ``(6 M, 4)`` (face f of hex m at row 6 m + f, in :data:`HEX_FACES` order) and the rows
    of those that belong to exactly one hex (the boundary quads), sorted."""
    hexes = np.asarray(hexes, dtype=np.int64)
    faces = hexes[:, HEX_FACES].reshape(-1, 4)
    return faces, _unique_rows(np.sort(faces, axis=1))


class Mesh:
    """The checkable 3-D cells of a mesh, and the mesh they came from.

    Attributes
    ----------
    points : ndarray, shape (N, 3), float64
        Every point of the mesh (points used by no cell included).
    source : meshio.Mesh
        The mesh as read, untouched: every cell block (in VTK node order), point/cell/field data. Not to be
        mutated.
    path : str or None
        The file the mesh was read from.
    file_format : str or None
        The format it was read as (``"vtk"``, ``"vtu"``, ``"gmsh"``, ``"medit"``, ...).
    reader : str or None
        Which reader read it (``"meshio"``, ``"gmsh"``, ``"vtk"``, ``"numpy"``, ``"hexsos"``).

    The cells: :attr:`cells`, :attr:`cell_blocks`, :attr:`cell_types`, :attr:`n_cells`; the linear
    hexahedra alone: :attr:`hexes`, :attr:`hex_blocks`, :attr:`hex_cells`, :attr:`voxel_rows`; what is not
    checked: :attr:`skipped`.

    Build one with :meth:`from_arrays`, :meth:`from_cells`, :meth:`from_meshio` or
    :func:`hexsos_plugins.io.read`; they validate.
    """

    def __init__(self, points, source, blocks, *, path=None, file_format=None, skipped=None, reader=None):
        """Low level: ``blocks`` is a list of ``(source block index, cell_type, conn)`` (conn in VTK order, int64);
        no validation (use the ``from_*`` constructors)."""
        self.points = points
        self.source = source
        self._blocks = list(blocks)
        self.path = path
        self.file_format = file_format
        self.reader = reader
        self._skipped = dict(skipped or {})

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_arrays(cls, points, hexes) -> "Mesh":
        """A mesh from a point array (N, 3) and a hexahedron array (M, 8) in VTK node order.

        Raises
        ------
        InvalidInputError
            wrong shapes or dtypes, NaN/inf coordinates, indices out of range.
        NoHexahedraError
            ``hexes`` has no rows.

        >>> import numpy as np
        >>> cube = np.array([[0,0,0],[1,0,0],[1,1,0],[0,1,0],[0,0,1],[1,0,1],[1,1,1],[0,1,1]], float)
        >>> HexMesh.from_arrays(cube, [list(range(8))]).orientation()
        'right-handed'
        """
        pts = _check_points(points)
        hx = _as_index_array(hexes, "hexes")
        if len(hx) == 0:
            raise NoHexahedraError("expected at least one hexahedron, found an empty (0, 8) hexes array")
        _check_indices(hx, len(pts), lambda r: f"hexes[{r}]", what="hexahedra")
        source = meshio.Mesh(pts.copy(), [("hexahedron", hx.copy())])
        return cls(pts, source, [(0, "hexahedron", hx)])

    @classmethod
    def from_cells(cls, points, cells) -> "Mesh":
        """A mesh from points (N, 3) and ``cells``: a list of ``(cell_type, conn)`` in VTK node order (the
        kernel's input; ``cell_type`` one of :data:`CHECKABLE`), or a dict ``{cell_type: conn}``.

        >>> import numpy as np
        >>> tet = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
        >>> m = Mesh.from_cells(tet, [("tetra", [[0, 1, 2, 3]])])
        >>> m.n_cells, m.n_hexes, m.orientation()
        (1, 0, 'right-handed')
        """
        pts = _check_points(points)
        items = list(cells.items()) if isinstance(cells, dict) else list(cells)
        blocks = []
        for t, conn in items:
            if t not in CHECKABLE:
                raise InvalidInputError(f"cells: expected cell types among {', '.join(CHECKABLE)}, found {t!r}")
            k = 8 if t == "voxel" else ELEMENTS[t].n_nodes
            blocks.append(meshio.CellBlock("hexahedron", np.zeros((0, 8), dtype=np.int64)))
            blocks[-1].type = t
            blocks[-1].data = _as_index_array(conn, f"cells[{len(blocks) - 1}] ({t})", k=k)
        src = meshio.Mesh.__new__(meshio.Mesh)
        src.points, src.cells = pts.copy(), blocks
        src.point_data, src.cell_data, src.field_data = {}, {}, {}
        src.point_sets, src.cell_sets, src.gmsh_periodic, src.info = {}, {}, None, None
        return cls.from_meshio(src)

    @classmethod
    def from_meshio(cls, mesh: meshio.Mesh, path=None, *, copy: bool = True) -> "Mesh":
        """The checkable 3-D cells of a ``meshio.Mesh`` (blocks in VTK node order); the mesh itself is kept,
        untouched, as ``source``. With ``copy=False`` (the readers, whose meshes are their own) int64 cell blocks
        and float64 points are shared with ``source`` instead of copied, read-only, to save memory.

        Raises
        ------
        NoCellsError (a NoHexahedraError)
            no block of a checkable type with at least one cell; the message lists the cell types found.
        InvalidInputError
            points not (N, 3), NaN/inf coordinates, node indices out of range (naming the first offender).
        """
        if not isinstance(mesh, meshio.Mesh):
            raise InvalidInputError(f"{_where(path)}expected a meshio.Mesh, found {type(mesh).__name__}")
        blocks, skipped = [], Counter()
        for b, block in enumerate(mesh.cells):
            t, n = block.type, len(block.data)
            if t in CHECKABLE:
                if n == 0:
                    continue
                k = 8 if t == "voxel" else ELEMENTS[t].n_nodes
                data = _as_index_array(block.data, f"cell block {b} ({t})", path, k, copy=copy and t != "voxel")
                blocks.append((b, "hexahedron" if t == "voxel" else t, data[:, VOXEL_TO_VTK] if t == "voxel" else data))
            elif is_3d(t) and n:
                skipped[t] += n
        if not blocks:
            counts = Counter()
            for block in mesh.cells:
                counts[block.type] += len(block.data)
            found = ", ".join(f"{n} {t}" for t, n in counts.items()) or "no cells at all"
            note = (f" ({', '.join(skipped)} {'is' if len(skipped) == 1 else 'are'} not checked by hexsos)"
                    if skipped else "")
            raise NoCellsError(
                f"{_where(path)}expected 3-D cells hexsos can check ({', '.join(CHECKABLE)}), found {found}{note}"
            )
        points = _check_points(mesh.points, path, copy=copy)
        start = 0
        for b, t, conn in blocks:
            src_type = mesh.cells[b].type
            _check_indices(conn, len(points), lambda r, s=start, b=b, t=t, st=src_type:
                           f"{t} {s + r} (cell {r} of block {b}, {st})", path)
            start += len(conn)
        return cls(points, mesh, blocks, path=None if path is None else str(path), skipped=dict(skipped))

    # ------------------------------------------------------------------ basic facts
    @property
    def cells(self) -> list:
        """``[(cell_type, conn), ...]``: every checkable 3-D block in block order, conn (M_b, n) int64 in VTK node
        order; voxel blocks as ``hexahedron``. What the kernel's ``check(points, cells)`` takes."""
        return [(t, conn) for _, t, conn in self._blocks]

    @property
    def cell_blocks(self) -> list:
        """``[(source block index, cell_type, start, stop), ...]``: where each block of :attr:`cells` lies in the
        cell order (rows ``start:stop`` of arrays over all cells)."""
        out, s = [], 0
        for b, t, conn in self._blocks:
            out.append((b, t, s, s + len(conn)))
            s += len(conn)
        return out

    @property
    def n_cells(self) -> int:
        return int(sum(len(c) for _, _, c in self._blocks))

    @cached_property
    def cell_types(self) -> np.ndarray:
        """(n_cells,) int8: each cell's type as an index into :data:`hexsos_plugins.cells.elements.CELL_TYPES`."""
        out = np.empty(self.n_cells, dtype=np.int8)
        for _, t, s, e in self.cell_blocks:
            out[s:e] = CELL_TYPES.index(t)
        return out

    def counts_by_type(self) -> dict:
        """``{cell_type: number of cells}`` of the checked cells, in :data:`CELL_TYPES` order."""
        c = Counter()
        for _, t, conn in self._blocks:
            c[t] += len(conn)
        return {t: c[t] for t in CELL_TYPES if c[t]}

    @property
    def skipped(self) -> dict:
        """``{cell_type: count}`` of the 3-D cells of ``source`` that are not checked (types the element registry
        does not hold, e.g. ``pyramid13``, ``polyhedron``)."""
        return dict(self._skipped)

    @property
    def hex_blocks(self) -> list:
        """``(block index in source.cells, start row in hexes, stop row)`` for each hexahedron/voxel block."""
        out, s = [], 0
        for b, t, conn in self._blocks:
            if t == "hexahedron":
                out.append((b, s, s + len(conn)))
                s += len(conn)
        return out

    @cached_property
    def hexes(self) -> np.ndarray:
        """(M, 8) int64: every linear hexahedron (``hexahedron`` and ``voxel`` blocks in block order, voxels
        converted to VTK order); (0, 8) when there is none."""
        parts = [conn for _, t, conn in self._blocks if t == "hexahedron"]
        if not parts:
            return np.zeros((0, 8), dtype=np.int64)
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    @property
    def hex_cells(self) -> np.ndarray:
        """(M,) int64: the position of each row of :attr:`hexes` in the cell order (rows of arrays over all
        cells)."""
        parts = [np.arange(s, e, dtype=np.int64) for _, t, s, e in self.cell_blocks if t == "hexahedron"]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)

    @property
    def n_points(self) -> int:
        return int(len(self.points))

    @property
    def n_hexes(self) -> int:
        return int(len(self.hexes))

    @property
    def voxel_rows(self) -> np.ndarray:
        """Boolean mask (M,): which rows of ``hexes`` came from ``voxel`` blocks (converted to VTK order)."""
        mask = np.zeros(self.n_hexes, dtype=bool)
        for b, start, stop in self.hex_blocks:
            if self.source.cells[b].type == "voxel":
                mask[start:stop] = True
        return mask

    def __repr__(self) -> str:
        kinds = ", ".join(f"{len(b.data)} {b.type}" for b in self.source.cells)
        where = f", path={self.path!r}" if self.path else ""
        by = ", ".join(f"{n} {t}" for t, n in self.counts_by_type().items())
        skip = f"; not checked: {', '.join(f'{n} {t}' for t, n in self._skipped.items())}" if self._skipped else ""
        return (f"Mesh({self.n_points} points, {self.n_hexes} hexahedra, {self.n_cells} cells ({by}){skip}; "
                f"blocks: {kinds}{where})")

    # ------------------------------------------------------------------ orientation
    def _centre_det_block(self, t, conn) -> np.ndarray:
        from .. import kernel  # compiled, one pass over the nodes (no gathered copies of the cells)

        return kernel.det_at(self.points, conn, t, ELEMENTS[t].centre)

    def centre_det(self) -> np.ndarray:
        """(n_cells,) det J of every cell at its reference centre (:attr:`Element.centre`; pyramids: the measure
        det J / (1 - t)^2). No certification: its sign tells the orientation of a cell's node order."""
        if not self._blocks:
            return np.zeros(0)
        return np.concatenate([self._centre_det_block(t, conn) for _, t, conn in self._blocks])

    def _centre_det(self) -> np.ndarray:  # the hexes' alone (kept for callers of the hex-only mesh)
        return self.centre_det()[self.hex_cells] if self.n_hexes else np.zeros(0)

    @staticmethod
    def _handedness(d) -> str:
        neg, pos = bool((d < 0).any()), bool((d > 0).any())
        if neg and pos:
            return "mixed"
        return "left-handed" if neg else "right-handed"

    def orientation(self) -> str:
        """``"right-handed"``, ``"left-handed"`` or ``"mixed"``, from det J at each cell's reference centre.

        ``"left-handed"``: some cells have det J < 0 at the centre and none > 0 (the file uses the mirrored node
        order; see :meth:`flipped`). ``"mixed"``: some < 0 and some > 0. ``"right-handed"``: none < 0. Cells
        with det J exactly 0 at the centre count as neither. One vectorized pass, no certification. See
        :meth:`orientations` for one verdict per cell type (a file can mirror one type only).
        """
        return self._handedness(self.centre_det())

    def orientation_and_types(self, det=None) -> tuple:
        """``(orientation(), orientations())`` from one pass over the cells (the pass is most of their time), or
        from ``det``, :meth:`centre_det`'s values when the caller has them already."""
        d = self.centre_det() if det is None else np.asarray(det, dtype=np.float64)
        types = self.cell_types
        per_type = {t: self._handedness(d[types == CELL_TYPES.index(t)]) for t in self.counts_by_type()}
        return self._handedness(d), per_type

    def orientations(self) -> dict:
        """``{cell_type: "right-handed" | "left-handed" | "mixed"}`` for each checked cell type, as
        :meth:`orientation` per type. A type that is ``"left-handed"`` while others are not is a file that
        mirrors that type's node order (e.g. linear wedges written with nodes 1<->2 and 4<->5 swapped, as Gmsh
        and meshio write them to VTK files)."""
        return self.orientation_and_types()[1]

    def left_handed_types(self) -> list:
        """The cell types all of whose cells are negatively oriented (see :meth:`orientations`)."""
        return [t for t, o in self.orientations().items() if o == "left-handed"]

    def mirrored_cells(self, det=None, *, folded: bool = True) -> np.ndarray:
        """(n_cells,) bool: the cells written in the mirrored node order, told apart from inverted cells by the
        mesh's topology and blocks.

        Two cells that share a corner face see it in opposite directions when both are written in the same
        handedness (each face of :attr:`Element.faces` is outward for a positive cell), in the same direction
        when one of them is mirrored. Those relations split every face-connected part of the mesh into at most
        two classes of equal handedness. A class is mirrored when det J is negative at the centre of some of
        its cells and positive at none (:meth:`centre_det`) while the other class of its part has a cell
        positive there: a mirrored block glued to a right-handed one, a single cell written the wrong way
        round. So is every cell of a block (of the file's cell blocks) negative at some centres and positive at
        none: a block written mirrored, glued to nothing. An inverted cell of a tangled mesh stays in its
        neighbours' class and is not marked; nor is a part of its own inside a block (a hex that shares no face
        could be inverted as well as mirrored). Faces shared by more than two cells are ignored; a part whose
        relations contradict each other (no consistent handedness exists) has none of its cells marked by them.
        Unless the signs name cells of the larger class of a part, its smaller class is mirrored too
        (:meth:`folded_cells` with ``strict``): valid cell by cell, it folds over the larger one. That reads
        every face of the mesh (0.9-2.3 s for a million hexes, where the rest is a pass of :meth:`centre_det`,
        0.1 s), and ``folded=False`` leaves it out.

        Parameters
        ----------
        det : array (n_cells,), optional
            :meth:`centre_det`'s values, when the caller has them already.
        folded : bool, keyword-only
            Also the smaller class of each part, whatever its signs (default).
        """
        n = self.n_cells
        d = self.centre_det() if det is None else np.asarray(det, dtype=np.float64)
        if d.shape != (n,):
            raise InvalidInputError(f"det: expected one value per cell, shape ({n},), found shape {d.shape}")
        out = np.zeros(n, dtype=bool)
        if (d < 0).any():
            out = self._sign_mirrored(d)
        if folded:  # the smaller class of a part, unless the signs named cells of its larger one
            cell, same, other = self._handedness_classes()
            if len(cell):
                part = np.minimum(same, other)
                smaller = _smaller_class(same, other, strict=True)
                larger_named = np.zeros(int(max(same.max(), other.max())) + 1, dtype=bool)
                larger_named[part[out[cell] & (same != other) & ~smaller]] = True
                out[cell] |= smaller & ~larger_named[part]
        return self._as_originals(out, d)

    def _sign_mirrored(self, d):
        """:meth:`mirrored_cells` by the signs of ``d`` (the centres' det J, some negative) alone."""
        out = np.zeros(self.n_cells, dtype=bool)
        # only the faces whose nodes all belong to cells negative at their centres can matter
        near = np.zeros(len(self.points), dtype=bool)
        start = 0
        for _, _, conn in self._blocks:
            near[conn[d[start:start + len(conn)] < 0].ravel()] = True
            start += len(conn)
        cell, same, other = self._handedness_classes(near)
        if len(cell):
            m = int(max(same.max(), other.max())) + 1
            dc = d[cell]
            negative = np.bincount(same, weights=(dc < 0), minlength=m) > 0
            positive = np.bincount(same, weights=(dc > 0), minlength=m) > 0
            out[cell] |= (same != other) & negative[same] & ~positive[same] & positive[other]
        for _, _, start, end in self.cell_blocks:
            block = d[start:end]
            if (block < 0).any() and not (block > 0).any():
                out[start:end] = True
        return out

    def folded_cells(self, *, strict: bool = False) -> np.ndarray:
        """(n_cells,) bool: the cells written in the other handedness than most of their face-connected part,
        whatever their sign: in each part whose shared faces split its cells into two classes of opposite
        handedness (:meth:`mirrored_cells`), the cells of the smaller class (of both when they are as large,
        unless ``strict``). Once every cell is valid (det J > 0), a cell of one class lies on the same side of a
        face it shares with a cell of the other: the mesh folds over itself there, which no check of each cell
        on its own sees. Measured: kitten_with_bifur_3 (HexaLab) has 40 such hexes in six places, one of them
        negative at its centre, the others valid by every corner (scaled Jacobian up to 0.6); repaired as written
        they stayed folded over their neighbours, certified cell by cell."""
        out = np.zeros(self.n_cells, dtype=bool)
        cell, same, other = self._handedness_classes()
        if len(cell):
            out[cell] = _smaller_class(same, other, strict=strict)
        return self._as_originals(out)

    def copies(self) -> np.ndarray:
        """(n_cells,) int: for each cell, the first earlier cell of its type on the same points, -1 where there is
        none (:func:`hexsos_plugins.cells.topology.repeated_cells`; blocks of a type read together): Gmsh's MSH 2
        writes an element once per physical group it is in. The faces between cells see each cell once."""
        return repeated_cells(self.cells)

    def _as_originals(self, marked, det=None):
        """``marked`` with each copy (:meth:`copies`) marked as its original, or the other way where its node order
        mirrors the original's (det J at the centres, ``det``, of opposite signs): the faces left the copies out."""
        twin = self.copies()
        later = np.flatnonzero(twin >= 0)
        if later.size:
            d = self.centre_det() if det is None else det
            first = twin[later]
            marked[later] = marked[first] ^ (np.sign(d[later]) * np.sign(d[first]) < 0)
        return marked

    def _handedness_classes(self, near=None):
        """(cells, same, other): the cells that share a corner face with another (only the faces whose nodes are
        all ``near``, if given), the label of each one's class of equal handedness, and the label of the class of
        opposite handedness in its part (the same label when the part has no consistent split). None at all when
        every shared face is read in opposite directions (then every part has one class)."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        pairs = [np.zeros((0, 2), dtype=np.int64)]
        flips = [np.zeros(0, dtype=bool)]
        for k, (faces, owner) in self._corner_faces(near).items():
            if len(faces) == 0:
                continue
            order, starts, lengths = _runs(np.sort(faces, axis=1))
            two = starts[lengths == 2]
            a, b = order[two], order[two + 1]
            # a face's direction: the corner after its least corner (the same face read the same way round)
            first = np.argmin(faces, axis=1)
            succ = faces[np.arange(len(faces)), (first + 1) % k]
            pairs.append(np.stack([owner[a], owner[b]], axis=1))
            flips.append(succ[a] == succ[b])
        P, F = np.concatenate(pairs), np.concatenate(flips)
        if not F.any():  # every shared face read in opposite directions: one handedness in every part
            empty = np.zeros(0, dtype=np.int64)
            return empty, empty, empty
        cell, local = np.unique(P, return_inverse=True)  # the cells the shared faces join, numbered 0..c-1
        local = local.reshape(P.shape)
        c = len(cell)
        if not c:
            return cell, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        # every such cell twice, (i, same) and (i, mirrored); a shared face joins equal or opposite handedness
        i, j = local[:, 0], local[:, 1]
        src = np.concatenate([i, i + c])
        dst = np.concatenate([np.where(F, j + c, j), np.where(F, j, j + c)])
        graph = coo_matrix((np.ones(len(src), dtype=np.int8), (src, dst)), shape=(2 * c, 2 * c))
        _, labels = connected_components(graph, directed=False)
        return cell, labels[:c], labels[c:]

    def _source_with(self, conns, points=None) -> meshio.Mesh:
        """Copy of source with every checked block's data taken from ``conns`` (VTK order; voxels back in voxel
        order)."""
        by_block = {b: conn for (b, _, _), conn in zip(self._blocks, conns)}
        cells = []
        for b, block in enumerate(self.source.cells):
            if b in by_block:
                data = by_block[b]
                if block.type == "voxel":
                    data = data[:, VOXEL_TO_VTK]  # VOXEL_TO_VTK is its own inverse
                cells.append(copy_block(block, np.array(data, dtype=np.asarray(block.data).dtype)))
            else:
                cells.append(copy_block(block))
        return copy_mesh(self.source, points=points, cells=cells)

    def _replace(self, conns=None, points=None, source=None) -> "Mesh":
        blocks = [(b, t, c) for (b, t, _), c in zip(self._blocks, conns or [c for _, _, c in self._blocks])]
        return Mesh(self.points.copy() if points is None else points, source, blocks, path=self.path,
                    file_format=self.file_format, skipped=self._skipped, reader=self.reader)

    def flipped(self, cell_types=None, cells=None) -> "Mesh":
        """A copy with cells mirrored (:data:`MIRROR`: r and s exchanged; for hexahedra nodes 1<->3 and 5<->7):
        left-handed becomes right-handed.

        Parameters
        ----------
        cell_types : iterable of str, optional
            Mirror only the cells of these types (e.g. ``mesh.left_handed_types()``); default: every cell.
        cells : array of bool (n_cells,), optional
            Mirror only these cells (e.g. ``mesh.mirrored_cells()``); with ``cell_types``, the cells of those
            types and these.

        The copy's ``source`` has those blocks flipped too (voxel blocks in voxel order), so writing it gives a
        file with the corrected node order. ``self`` is not modified.
        """
        if cell_types is not None:
            cell_types = set(cell_types)
            unknown = cell_types - set(CELL_TYPES)
            if unknown:
                raise InvalidInputError(f"cell_types: expected names among {', '.join(CELL_TYPES)}, found "
                                        f"{', '.join(sorted(map(str, unknown)))}")
        if cells is None:
            mask = np.isin(self.cell_types, [CELL_TYPES.index(t) for t in cell_types]) \
                if cell_types is not None else np.ones(self.n_cells, dtype=bool)
        else:
            mask = np.asarray(cells)
            if mask.dtype != bool or mask.shape != (self.n_cells,):
                raise InvalidInputError(f"cells: expected a bool array of shape ({self.n_cells},) (one per cell), "
                                        f"found dtype {mask.dtype} and shape {mask.shape}")
            if cell_types is not None:
                mask = mask | np.isin(self.cell_types, [CELL_TYPES.index(t) for t in cell_types])
        conns, start = [], 0
        for _, t, c in self._blocks:
            rows = mask[start:start + len(c)]
            start += len(c)
            c = c.copy()
            c[rows] = c[rows][:, MIRROR[t]]
            conns.append(np.ascontiguousarray(c))
        return self._replace(conns, source=self._source_with(conns))

    def with_points(self, points) -> "Mesh":
        """A copy with new coordinates (N, 3) and the same connectivity; ``source`` gets the new points too."""
        pts = _check_points(points)
        if len(pts) != len(self.points):
            raise InvalidInputError(
                f"expected {len(self.points)} points (the mesh's point count), found {len(pts)}"
            )
        src_pts = np.asarray(self.source.points)
        src = copy_mesh(self.source, points=pts.astype(src_pts.dtype) if src_pts.dtype.kind == "f" else pts)
        return self._replace([c.copy() for _, _, c in self._blocks], points=pts, source=src)

    # ------------------------------------------------------------------ back to meshio
    def to_meshio(self, cell_data=None, point_data=None) -> meshio.Mesh:
        """A new ``meshio.Mesh``: the source with this mesh's points and cells, plus result arrays.

        * Every cell block of ``source``, in order. ``voxel`` blocks are written back as ``hexahedron``
          blocks (VTK order): meshio 5.3.5 has no voxel cell type -- none of its writers can write one and
          ``meshio.CellBlock("voxel", ...)`` raises -- while the converted hexahedron is the same cell.
        * ``source``'s point_data, cell_data, field_data (and point/cell sets) are kept (copied).
        * ``cell_data``: name -> array over **all checked cells** (``n_cells`` rows, in the cell order) or over
          the **hexahedra** (``n_hexes`` rows, as :attr:`hexes`), shape (M,) or (M, k); spread onto those
          blocks. On every other block the array is filled with **NaN** (float arrays) or **-2**
          (:data:`INT_FILL`, integer arrays), so meshio's per-block lists stay consistent. Booleans are stored
          as int8 and unsigned integers as int64 (so that -2 fits). A name already in the source's cell data
          is replaced.
        * ``point_data``: name -> array (N,) or (N, k); replaces a source array of the same name.

        Neither ``self`` nor ``source`` is modified.
        """
        by_block = {b: (t, c) for b, t, c in self._blocks}
        blocks = []
        for b, block in enumerate(self.source.cells):
            if b in by_block:
                t, c = by_block[b]
                blocks.append(copy_block(block, np.array(c), cell_type=t))
            else:
                blocks.append(copy_block(block))
        out = copy_mesh(self.source, points=self.points, cells=blocks)
        cell_rows = {b: (s, e) for b, _, s, e in self.cell_blocks}
        hex_rows = {b: (s, e) for b, s, e in self.hex_blocks}
        for name, values in (cell_data or {}).items():
            arr = _check_array(name, values, (self.n_hexes, self.n_cells), "cell_data", ("M", "M"))
            rows = hex_rows if len(arr) == self.n_hexes else cell_rows
            out.cell_data[str(name)] = _spread(arr, rows, blocks)
        for name, values in (point_data or {}).items():
            arr = np.asarray(values)
            if arr.ndim == 0 or arr.shape[0] != len(self.points):
                raise InvalidInputError(
                    f"point_data[{name!r}]: expected an array of shape (N,) or (N, k) with N = {len(self.points)} "
                    f"points, found shape {arr.shape}"
                )
            if arr.dtype.kind not in "biuf":
                raise InvalidInputError(
                    f"point_data[{name!r}]: expected a real or integer array, found dtype {arr.dtype}"
                )
            out.point_data[str(name)] = np.array(arr)
        return out

    # ------------------------------------------------------------------ boundary
    def _corner_faces(self, near=None):
        """``{3: (faces (T, 3), owner (T,)), 4: (faces (Q, 4), owner (Q,))}``: every corner face of every cell in
        its element's order (outward for a positive cell) and the cell it belongs to; with ``near`` (n_points,)
        bool, only the faces whose nodes are all ``near``."""
        parts = {3: [], 4: []}
        start = 0
        once = self.copies() < 0  # a cell written twice (a copy on the same points) has its faces read once
        for _, t, conn in self._blocks:
            ids = np.arange(start, start + len(conn), dtype=np.int64)
            mine = once[start:start + len(conn)]
            if not mine.all():
                conn, ids = conn[mine], ids[mine]
            for k in (3, 4):
                fs = [f for f in ELEMENTS[t].faces if len(f) == k]
                if not fs:
                    continue
                # one gather for the faces of a size, face by face as before (the faces of face 0, then 1, ...)
                faces = np.take(conn, np.asarray(fs).ravel(), axis=1).reshape(len(conn), len(fs), k)
                faces = faces.transpose(1, 0, 2).reshape(-1, k)
                owner = np.tile(ids, len(fs))
                if near is not None:
                    keep = near[faces].all(axis=1)
                    faces, owner = faces[keep], owner[keep]
                parts[k].append((faces, owner))
            start += len(mine)
        return {k: (np.concatenate([p[0] for p in ps]), np.concatenate([p[1] for p in ps])) if ps else
                (np.zeros((0, k), dtype=np.int64), np.zeros(0, dtype=np.int64)) for k, ps in parts.items()}

    def _all_faces(self):
        """The boundary faces by kind: ``{3: (faces, owner), 4: (faces, owner)}``, the faces of exactly one cell,
        reversed where their cell is negatively oriented."""
        sign = self.centre_det() < 0
        out = {}
        for k, (faces, owner) in self._corner_faces().items():
            if len(faces) == 0:
                out[k] = (faces, owner)
                continue
            rows = _unique_rows(np.sort(faces, axis=1))
            faces, owner = faces[rows], owner[rows]
            flip = sign[owner]
            faces[flip] = faces[flip][:, ::-1]
            out[k] = (np.ascontiguousarray(faces), owner)
        return out

    def boundary(self, *, return_cell: bool = False) -> dict:
        """The faces that belong to exactly one checked cell, oriented outward, by kind.

        Returns
        -------
        dict ``{"triangle": (T, 3), "quad": (Q, 4)}`` of corner-node indices (int64); each face's right-hand
        normal points out of the mesh (faces of negatively oriented cells are reversed). With
        ``return_cell=True`` also ``"triangle_cell"`` / ``"quad_cell"``: each face's cell in the cell order.
        A quadrilateral is matched with a neighbour by its four corners, a triangle by its three.
        """
        f = self._all_faces()
        out = {"triangle": f[3][0], "quad": f[4][0]}
        if return_cell:
            out["triangle_cell"], out["quad_cell"] = f[3][1], f[4][1]
        return out

    def boundary_faces(self, *, return_hex: bool = False):
        """The quadrilateral faces of hexahedra that belong to exactly one cell, oriented outward.

        Returns
        -------
        faces : ndarray (F, 4), int64
            Node indices; the right-hand-rule normal (``(p1 - p0) x (p3 - p0)``, or of the two diagonals)
            points out of the mesh. Faces follow the local order of :data:`HEX_FACES`, which is outward for
            positively oriented hexes; faces of negatively oriented hexes are reversed, so they are outward
            there too. Faces come in hex order. In a mixed mesh a hex face shared with another cell is not on
            the boundary; see :meth:`boundary` for every kind of face.
        hex_ids : ndarray (F,), int64
            Only with ``return_hex=True``: the row of ``hexes`` each face belongs to.
        """
        if set(t for _, t, _ in self._blocks) <= {"hexahedron"}:
            faces, rows = boundary_face_rows(self.hexes)
            out = faces[rows]
            hex_ids = (rows // 6).astype(np.int64)
            if len(out):
                d = self._centre_det()
                flip = d[hex_ids] < 0
                out[flip] = out[flip][:, ::-1]
            out = np.ascontiguousarray(out, dtype=np.int64)
            return (out, hex_ids) if return_hex else out
        b = self.boundary(return_cell=True)
        pos = np.full(self.n_cells, -1, dtype=np.int64)
        pos[self.hex_cells] = np.arange(self.n_hexes)
        keep = pos[b["quad_cell"]] >= 0
        faces, hex_ids = b["quad"][keep], pos[b["quad_cell"][keep]]
        order = np.argsort(hex_ids, kind="stable")
        faces, hex_ids = np.ascontiguousarray(faces[order]), hex_ids[order]
        return (faces, hex_ids) if return_hex else faces

    def boundary_vertices(self) -> np.ndarray:
        """Boolean mask (N,): the points on a boundary face of the checked cells (every node on such a face,
        mid-edge and mid-face nodes of quadratic cells included)."""
        mask = np.zeros(len(self.points), dtype=bool)
        if set(t for _, t, _ in self._blocks) <= {"hexahedron"}:
            mask[self.boundary_faces().ravel()] = True
            return mask
        b = self.boundary(return_cell=True)
        starts = {t: [] for t in ELEMENTS}
        for _, t, s, e in self.cell_blocks:
            starts[t].append((s, e))
        cell_block = np.empty(self.n_cells, dtype=np.int64)
        for k, (_, _, s, e) in enumerate(self.cell_blocks):
            cell_block[s:e] = k
        for kind in ("triangle", "quad"):
            faces, owners = b[kind], b[f"{kind}_cell"]
            if not len(faces):
                continue
            mask[faces.ravel()] = True
            for k, (_, t, s, e) in enumerate(self.cell_blocks):
                el = ELEMENTS[t]
                if el.order == 1:
                    continue
                sel = cell_block[owners] == k
                if not sel.any():
                    continue
                conn = self._blocks[k][2]
                rows = owners[sel] - s
                corner = np.sort(faces[sel], axis=1)
                for f, nodes in zip(el.faces, FACE_NODES[t]):
                    if len(f) != faces.shape[1]:
                        continue
                    mine = np.sort(conn[rows][:, list(f)], axis=1)
                    hit = (mine == corner).all(axis=1)
                    if hit.any():
                        mask[conn[rows[hit]][:, list(nodes)].ravel()] = True
        return mask


#: The name of the mesh model before it held every cell type; the same class.
HexMesh = Mesh
