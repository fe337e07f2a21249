"""``HexMesh``: the hexahedra of a mesh file as arrays, with everything else kept aside.

Data flows one way: a mesh file (or a ``meshio.Mesh``) becomes a :class:`HexMesh` -- ``points`` (N, 3) and
``hexes`` (M, 8) in VTK node order for the kernel -- while the mesh as read stays untouched in ``source``
(every cell block, point/cell/field data). Result arrays of the kernel go back onto a *new*
``meshio.Mesh`` with :meth:`HexMesh.to_meshio`, ready to be written with :func:`hexsos_plugins.io.write`.

Node order (VTK, the same in meshio, Gmsh type 5 and Medit; see :mod:`hexsos_plugins.hexahedron`)::

            7-----------6
           /|          /|       face (outward, right-hand rule)
          / |         / |         bottom w=0: 0 3 2 1    top    w=1: 4 5 6 7
         4-----------5  |         front  v=0: 0 1 5 4    back   v=1: 2 3 7 6
         |  3--------|--2         left   u=0: 0 4 7 3    right  u=1: 1 2 6 5
         | /         | /
         |/          |/         w  v
         0-----------1          | /
                                |/__ u

Which blocks are hexahedra
--------------------------
* ``hexahedron`` blocks: trilinear 8-node hexahedra, taken as they are.
* ``voxel`` blocks (VTK cell type 11, nodes in lexicographic order, x fastest): converted with
  :data:`~hexsos_plugins.hexahedron.VOXEL_TO_VTK`; :attr:`HexMesh.voxel_rows` says which rows came from
  voxels. meshio 5.3.5 has no voxel cell type (``meshio.CellBlock("voxel", ...)`` raises), so such blocks
  only come from :func:`hexsos_plugins.io.read`'s legacy-VTK reader; they are kept as ``voxel`` in ``source``.
* ``hexahedron20``, ``hexahedron27``, ... (higher order) are *not* trilinear: they are kept in ``source`` and
  written back, but not checked.

Everything here is pure numpy (no gmsh, no vtk).
"""

from __future__ import annotations

import copy
from collections import Counter
from dataclasses import dataclass

import meshio
import numpy as np

from .errors import InvalidInputError, NoHexahedraError
from .hexahedron import VOXEL_TO_VTK, det_at, gather_t

__all__ = ["HexMesh", "HEX_FACES", "FLIP", "INT_FILL", "HEX_TYPES", "hexes_to_mesh"]

#: The six faces of a hexahedron (VTK node order), each ordered so that the right-hand-rule normal points
#: out of a positively oriented hex.
HEX_FACES = np.array(
    [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [0, 4, 7, 3], [1, 2, 6, 5]], dtype=np.int64
)
#: Node permutation that mirrors a hex (swaps nodes 1<->3 and 5<->7, i.e. exchanges u and v): it turns a
#: negatively oriented hex into a positively oriented one and back. It is its own inverse.
FLIP = np.array([0, 3, 2, 1, 4, 7, 6, 5], dtype=np.int64)
#: Fill value of integer cell data on the cells that are not hexahedra (see :meth:`HexMesh.to_meshio`).
INT_FILL = -2
#: meshio cell types that hold trilinear hexahedra.
HEX_TYPES = ("hexahedron", "voxel")

_CENTRE_CHUNK = 65536
_CENTRE = np.array([0.5, 0.5, 0.5])


def _where(path) -> str:
    return f"{path}: " if path else ""


def _check_points(points, path=None) -> np.ndarray:
    """Points as a float64 (N, 3) array; raises InvalidInputError naming the first bad point."""
    try:
        arr = np.asarray(points)
    except Exception as exc:  # ragged lists and the like
        raise InvalidInputError(f"{_where(path)}expected points as an (N, 3) array, found {type(points).__name__} "
                                f"that numpy cannot convert ({exc})") from exc
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InvalidInputError(f"{_where(path)}expected points of shape (N, 3), found shape {arr.shape}")
    if arr.dtype.kind not in "biuf":
        raise InvalidInputError(f"{_where(path)}expected real point coordinates, found dtype {arr.dtype}")
    arr = np.array(arr, dtype=np.float64)  # always a private copy
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InvalidInputError(
            f"{_where(path)}expected finite point coordinates, found point {i} = {tuple(arr[i].tolist())} "
            f"({int(bad.sum())} non-finite point(s) in all)"
        )
    return arr


def _as_index_array(data, what, path=None) -> np.ndarray:
    try:
        arr = np.asarray(data)
    except Exception as exc:
        raise InvalidInputError(f"{_where(path)}{what}: expected an (M, 8) integer array ({exc})") from exc
    if arr.ndim != 2 or arr.shape[1] != 8:
        raise InvalidInputError(f"{_where(path)}{what}: expected shape (M, 8), found shape {arr.shape}")
    if arr.dtype.kind == "f":
        if not (np.isfinite(arr).all() and (arr == np.round(arr)).all()):
            raise InvalidInputError(f"{_where(path)}{what}: expected integer node indices, found non-integer values")
    elif arr.dtype.kind not in "iu":
        raise InvalidInputError(f"{_where(path)}{what}: expected integer node indices, found dtype {arr.dtype}")
    return np.array(arr, dtype=np.int64)


def _check_indices(hexes, n_points, labels, path=None) -> None:
    """Raise InvalidInputError naming the first hex (by its label) that references a missing point."""
    if hexes.size == 0:
        return
    bad = (hexes < 0) | (hexes >= n_points)
    if bad.any():
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        col = int(np.flatnonzero(bad[row])[0])
        raise InvalidInputError(
            f"{_where(path)}{labels(row)} references point {int(hexes[row, col])} (node {col}), but the mesh has "
            f"{n_points} points (valid indices 0..{n_points - 1}); {int(bad.any(axis=1).sum())} hexahedra "
            "reference missing points in all"
        )


def _block_to_vtk(cell_type: str, data) -> np.ndarray:
    data = np.asarray(data)
    return data[:, VOXEL_TO_VTK] if cell_type == "voxel" else data


def _copy_block(block, data=None, cell_type=None):
    """A copy of a meshio CellBlock without calling its constructor (which rejects e.g. ``voxel``)."""
    new = copy.copy(block)
    new.data = copy.deepcopy(block.data) if data is None else data
    new.tags = list(getattr(block, "tags", []) or [])
    if cell_type is not None:
        new.type = cell_type
    return new


def _copy_mesh(src: meshio.Mesh, *, points=None, cells=None) -> meshio.Mesh:
    """A deep copy of a meshio.Mesh (optionally with new points / cell blocks) built without re-validation."""
    new = meshio.Mesh.__new__(meshio.Mesh)
    new.points = np.array(src.points if points is None else points)
    new.cells = [_copy_block(b) for b in src.cells] if cells is None else cells
    new.point_data = {k: np.array(v) for k, v in src.point_data.items()}
    new.cell_data = {k: [np.array(a) for a in v] for k, v in src.cell_data.items()}
    new.field_data = copy.deepcopy(src.field_data)
    new.point_sets = copy.deepcopy(getattr(src, "point_sets", {}) or {})
    new.cell_sets = copy.deepcopy(getattr(src, "cell_sets", {}) or {})
    new.gmsh_periodic = copy.deepcopy(getattr(src, "gmsh_periodic", None))
    new.info = copy.deepcopy(getattr(src, "info", None))
    return new


def _spread(name, values, n_rows, hex_blocks, blocks, what="cell_data"):
    """Per-block list of a hex cell array: hex rows on hex blocks, NaN / INT_FILL on the others."""
    arr = np.asarray(values)
    if arr.ndim == 0 or arr.shape[0] != n_rows:
        raise InvalidInputError(
            f"{what}[{name!r}]: expected an array of shape (M,) or (M, k) with M = {n_rows} hexahedra, "
            f"found shape {arr.shape}"
        )
    kind = arr.dtype.kind
    if kind == "b":
        arr = arr.astype(np.int8)
    elif kind == "u":
        arr = arr.astype(np.int64)
    elif kind not in "if":
        raise InvalidInputError(f"{what}[{name!r}]: expected a real or integer array, found dtype {arr.dtype}")
    fill = np.nan if arr.dtype.kind == "f" else INT_FILL
    by_block = {b: (start, stop) for b, start, stop in hex_blocks}
    out = []
    for b, block in enumerate(blocks):
        if b in by_block:
            start, stop = by_block[b]
            out.append(np.array(arr[start:stop]))
        else:
            out.append(np.full((len(block.data),) + arr.shape[1:], fill, dtype=arr.dtype))
    return out


def hexes_to_mesh(X):
    """Separate hexes (M, 8, 3) as a mesh: points (8 M, 3) and hexes (M, 8) (no shared vertices)."""
    X = np.asarray(X, dtype=np.float64).reshape(-1, 8, 3)
    return X.reshape(-1, 3).copy(), np.arange(X.shape[0] * 8, dtype=np.int64).reshape(-1, 8)


def boundary_face_rows(hexes):
    """All hex faces ``(6 M, 4)`` (face f of hex m at row 6 m + f, in :data:`HEX_FACES` order) and the rows
    of those that belong to exactly one hex (the boundary quads), sorted."""
    hexes = np.asarray(hexes, dtype=np.int64)
    faces = hexes[:, HEX_FACES].reshape(-1, 4)
    key = np.sort(faces, axis=1)
    order = np.lexsort(key.T[::-1])  # sort the face node tuples; equal faces become neighbours
    sk = key[order]
    differs = (sk[1:] != sk[:-1]).any(axis=1)
    first = np.concatenate([[True], differs])  # start of a run of equal faces
    last = np.concatenate([differs, [True]])  # end of a run
    return faces, np.sort(order[first & last])  # runs of length 1: faces of exactly one hex


@dataclass(eq=False, repr=False)
class HexMesh:
    """The trilinear hexahedra of a mesh, and the mesh they came from.

    Attributes
    ----------
    points : ndarray, shape (N, 3), float64
        Every point of the mesh (points used by no hexahedron included).
    hexes : ndarray, shape (M, 8), int64
        Every hexahedron of the mesh in VTK node order: the ``hexahedron`` and ``voxel`` blocks of
        ``source`` concatenated in block order, voxels converted to VTK order.
    source : meshio.Mesh
        The mesh as read, untouched: every cell block, point/cell/field data. Not to be mutated.
    hex_blocks : list of (int, int, int)
        ``(block index in source.cells, start row in hexes, stop row)`` for each hexahedron/voxel block.
    path : str or None
        The file the mesh was read from.
    file_format : str or None
        The meshio format name it was read as (``"vtk"``, ``"vtu"``, ``"gmsh"``, ``"medit"``, ...).

    Build one with :meth:`from_arrays`, :meth:`from_meshio` or :func:`hexsos_plugins.io.read`; they validate.
    """

    points: np.ndarray
    hexes: np.ndarray
    source: meshio.Mesh
    hex_blocks: list
    path: str | None = None
    file_format: str | None = None

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_arrays(cls, points, hexes) -> "HexMesh":
        """A HexMesh from a point array (N, 3) and a hexahedron array (M, 8) in VTK node order.

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
        _check_indices(hx, len(pts), lambda r: f"hexes[{r}]")
        source = meshio.Mesh(pts.copy(), [("hexahedron", hx.copy())])
        return cls(pts, hx, source, [(0, 0, len(hx))])

    @classmethod
    def from_meshio(cls, mesh: meshio.Mesh, path=None) -> "HexMesh":
        """The hexahedra of a ``meshio.Mesh``; the mesh itself is kept, untouched, as ``source``.

        ``hexahedron`` and ``voxel`` blocks (converted to VTK order) are collected in block order;
        higher-order ``hexahedron*`` blocks and every other cell type are kept but not checked.

        Raises
        ------
        NoHexahedraError
            no ``hexahedron`` / ``voxel`` block with at least one cell; the message lists the cell types found.
        InvalidInputError
            points not (N, 3), NaN/inf coordinates, node indices out of range (naming the first offender).
        """
        if not isinstance(mesh, meshio.Mesh):
            raise InvalidInputError(f"{_where(path)}expected a meshio.Mesh, found {type(mesh).__name__}")
        parts, hex_blocks, start = [], [], 0
        for b, block in enumerate(mesh.cells):
            if block.type not in HEX_TYPES or len(block.data) == 0:
                continue
            data = _as_index_array(block.data, f"cell block {b} ({block.type})", path)
            parts.append(_block_to_vtk(block.type, data))
            hex_blocks.append((b, start, start + len(data)))
            start += len(data)
        if not parts:
            counts = Counter()
            for block in mesh.cells:
                counts[block.type] += len(block.data)
            found = ", ".join(f"{n} {t}" for t, n in counts.items()) or "no cells at all"
            higher = [t for t in counts if t.startswith("hexahedron")]
            note = (f" ({', '.join(higher)} are higher-order hexahedra, which are not checked)" if higher else "")
            raise NoHexahedraError(
                f"{_where(path)}expected hexahedra (8-node 'hexahedron' or 'voxel' cells), found {found}{note}"
            )
        hexes = np.concatenate(parts) if len(parts) > 1 else parts[0]
        points = _check_points(mesh.points, path)

        def label(row):
            for b, s, e in hex_blocks:
                if s <= row < e:
                    return f"hexahedron {row} (cell {row - s} of block {b}, {mesh.cells[b].type})"
            return f"hexahedron {row}"  # pragma: no cover

        _check_indices(hexes, len(points), label, path)
        return cls(points, hexes, mesh, hex_blocks, None if path is None else str(path))

    # ------------------------------------------------------------------ basic facts
    @property
    def n_points(self) -> int:
        return int(len(self.points))

    @property
    def n_hexes(self) -> int:
        return int(len(self.hexes))

    @property
    def voxel_rows(self) -> np.ndarray:
        """Boolean mask (M,): which rows of ``hexes`` came from ``voxel`` blocks (converted to VTK order)."""
        mask = np.zeros(len(self.hexes), dtype=bool)
        for b, start, stop in self.hex_blocks:
            if self.source.cells[b].type == "voxel":
                mask[start:stop] = True
        return mask

    def __repr__(self) -> str:
        kinds = ", ".join(f"{len(b.data)} {b.type}" for b in self.source.cells)
        where = f", path={self.path!r}" if self.path else ""
        return f"HexMesh({self.n_points} points, {self.n_hexes} hexahedra; blocks: {kinds}{where})"

    def _centre_det(self) -> np.ndarray:
        # in chunks: the vertex coordinates of all hexes at once would be 192 bytes per hex, twice
        PT = np.ascontiguousarray(self.points.T)
        out = np.empty(len(self.hexes))
        for s in range(0, len(self.hexes), _CENTRE_CHUNK):
            X = gather_t(PT, self.hexes[s : s + _CENTRE_CHUNK])
            out[s : s + _CENTRE_CHUNK] = det_at(X, _CENTRE, layout="soa")[0]
        return out

    # ------------------------------------------------------------------ orientation
    def orientation(self) -> str:
        """``"right-handed"``, ``"left-handed"`` or ``"mixed"``, from det J at the centre (1/2, 1/2, 1/2).

        ``"left-handed"``: some hexes have det J < 0 at the centre and none > 0 (the file uses the mirrored
        node order; see :meth:`flipped`). ``"mixed"``: some < 0 and some > 0. ``"right-handed"``: none < 0.
        Hexes with det J exactly 0 at the centre count as neither. One vectorized pass, no certification.
        """
        d = self._centre_det()
        neg, pos = bool((d < 0).any()), bool((d > 0).any())
        if neg and pos:
            return "mixed"
        return "left-handed" if neg else "right-handed"

    def _replace_hex_blocks(self, hexes, points=None) -> meshio.Mesh:
        """Copy of source with every hex block's data taken from ``hexes`` (in the block's own node order)."""
        by_block = {b: (s, e) for b, s, e in self.hex_blocks}
        cells = []
        for b, block in enumerate(self.source.cells):
            if b in by_block:
                s, e = by_block[b]
                data = hexes[s:e]
                if block.type == "voxel":
                    data = data[:, VOXEL_TO_VTK]  # VOXEL_TO_VTK is its own inverse
                cells.append(_copy_block(block, np.array(data, dtype=np.asarray(block.data).dtype)))
            else:
                cells.append(_copy_block(block))
        return _copy_mesh(self.source, points=points, cells=cells)

    def flipped(self) -> "HexMesh":
        """A copy with every hex mirrored (nodes 1<->3 and 5<->7 swapped): left-handed becomes right-handed.

        The copy's ``source`` has its hex blocks flipped too (voxel blocks in voxel order), so writing it
        gives a file with the corrected node order. ``self`` is not modified.
        """
        hexes = np.ascontiguousarray(self.hexes[:, FLIP])
        return HexMesh(self.points.copy(), hexes, self._replace_hex_blocks(hexes), list(self.hex_blocks),
                       self.path, self.file_format)

    def with_points(self, points) -> "HexMesh":
        """A copy with new coordinates (N, 3) and the same connectivity; ``source`` gets the new points too."""
        pts = _check_points(points)
        if len(pts) != len(self.points):
            raise InvalidInputError(
                f"expected {len(self.points)} points (the mesh's point count), found {len(pts)}"
            )
        src_pts = np.asarray(self.source.points)
        src = _copy_mesh(self.source, points=pts.astype(src_pts.dtype) if src_pts.dtype.kind == "f" else pts)
        return HexMesh(pts, self.hexes.copy(), src, list(self.hex_blocks), self.path, self.file_format)

    # ------------------------------------------------------------------ back to meshio
    def to_meshio(self, cell_data=None, point_data=None) -> meshio.Mesh:
        """A new ``meshio.Mesh``: the source with this mesh's points and hexes, plus result arrays.

        * Every cell block of ``source``, in order. ``voxel`` blocks are written back as ``hexahedron``
          blocks (VTK order): meshio 5.3.5 has no voxel cell type -- none of its writers can write one and
          ``meshio.CellBlock("voxel", ...)`` raises -- while the converted hexahedron is the same cell.
        * ``source``'s point_data, cell_data, field_data (and point/cell sets) are kept (copied).
        * ``cell_data``: name -> array (M,) or (M, k) over ``hexes``; spread onto the hex blocks. On every
          other block the array is filled with **NaN** (float arrays) or **-2** (:data:`INT_FILL`, integer
          arrays), so meshio's per-block lists stay consistent. Booleans are stored as int8 and unsigned
          integers as int64 (so that -2 fits). A name already in the source's cell data is replaced.
        * ``point_data``: name -> array (N,) or (N, k); replaces a source array of the same name.

        Neither ``self`` nor ``source`` is modified.
        """
        blocks = []
        by_block = {b: (s, e) for b, s, e in self.hex_blocks}
        for b, block in enumerate(self.source.cells):
            if b in by_block:
                s, e = by_block[b]
                blocks.append(_copy_block(block, np.array(self.hexes[s:e]), cell_type="hexahedron"))
            else:
                blocks.append(_copy_block(block))
        out = _copy_mesh(self.source, points=self.points, cells=blocks)
        for name, values in (cell_data or {}).items():
            out.cell_data[str(name)] = _spread(name, values, len(self.hexes), self.hex_blocks, blocks)
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
    def _outward_sign(self) -> bool:
        """True if faces must be reversed: the mesh has more negatively than positively oriented hexes."""
        d = self._centre_det()
        return int((d < 0).sum()) > int((d > 0).sum())

    def boundary_faces(self, *, return_hex: bool = False):
        """The quadrilateral faces that belong to exactly one hexahedron, oriented outward.

        Returns
        -------
        faces : ndarray (F, 4), int64
            Node indices; the right-hand-rule normal (``(p1 - p0) x (p3 - p0)``, or of the two diagonals)
            points out of the mesh. Faces follow the local order of :data:`HEX_FACES`, which is outward for
            positively oriented hexes; in a mesh whose hexes are mostly negatively oriented (a left-handed
            file) every face is reversed, so they are outward there too. Faces come in hex order.
        hex_ids : ndarray (F,), int64
            Only with ``return_hex=True``: the row of ``hexes`` each face belongs to.
        """
        M = len(self.hexes)
        faces, rows = boundary_face_rows(self.hexes)
        out = faces[rows]
        if M and self._outward_sign():
            out = out[:, ::-1].copy()
        out = np.ascontiguousarray(out, dtype=np.int64)
        if return_hex:
            return out, (rows // 6).astype(np.int64)
        return out

    def boundary_vertices(self) -> np.ndarray:
        """Boolean mask (N,): the points on a boundary face of the hexahedra."""
        mask = np.zeros(len(self.points), dtype=bool)
        mask[self.boundary_faces().ravel()] = True
        return mask
