"""Writing mesh files atomically, with meshio's writers and workarounds for meshio 5.3.5's traps.

``write(mesh, path)`` writes a ``meshio.Mesh`` (for instance ``Mesh.to_meshio(...)``) or a
:class:`~hexsos_plugins.io.mesh.Mesh` and returns warnings for the caller. It neither prints nor exits; failures
raise :class:`~hexsos_plugins.errors.MeshWriteError`.

Atomic: the file is written to a temporary file in the target directory, then renamed over the target
(``os.replace``); on any failure the temporary file is removed and an existing target is left as it was.

Node orders: the mesh's blocks are in VTK node order (hexsos's convention, :mod:`hexsos_plugins.io.mesh`); each
file gets its format's own order: VTK files VTK's (meshio's VTK writers would mirror linear wedges, so they
are handed the mirror), MSH files Gmsh's (meshio permutes tetra10, wedge15, hexahedron20 and hexahedron27
itself; wedge18 is permuted here, which meshio's writer does not do). See :mod:`hexsos_plugins.io.meshio_conventions`.

* ``.msh``: Gmsh MSH **4.1, binary**, by :mod:`hexsos_plugins.io.msh41`: meshio 5.3.5's MSH 2.2 reader cannot read
  ``$ElementData`` over more than one cell block (so its own 2.2 files with results do not open in it), and its
  4.1 writer needs ``gmsh:dim_tags`` and keeps one physical tag per block. The file keeps every cell in order,
  ``gmsh:physical`` / ``gmsh:geometrical`` per element (one entity per run of equal tags), ``gmsh:dim_tags``,
  cell and point data as ``$ElementData`` / ``$NodeData`` and ``[tag, dim]`` field data as ``$PhysicalNames``;
  meshio 5.3.5 and Gmsh 4.15 open it with every block, array and physical group (tested).
  Data arrays must have 1, 3 or 9 components: 2 -> padded to 3, 4..8 -> padded to 9 (zeros), more ->
  split into ``name_0``, ``name_1``, ... (with a warning). Tags are written as int32.
* ``.vtk``: legacy VTK **4.2, ASCII**. meshio's default 5.1 cannot be opened by Gmsh, and Gmsh 4.15's
  legacy reader cannot read *binary* legacy VTK at all (not even the files Gmsh writes itself: it reads
  the binary block one byte early). Field data is added as a dataset-level ``FIELD`` section after the
  cell types, which VTK and meshio read as field data and Gmsh skips.
* ``.vtu``: meshio's writer (binary, zlib); field data (which meshio's writer drops) is added as a
  ``<FieldData>`` element of the grid.
* ``.mesh`` / ``.meshb`` (Medit): holds one integer reference per vertex and per element, nothing else.
  The element reference is ``medit:ref`` if present, else ``gmsh:physical``, else 1; every other cell
  array, point array and field data is dropped **with a warning naming them**. Cell types Medit cannot
  hold are skipped with a warning.
* Every format: booleans are written as int8, float16 as float32; complex/object/string arrays are
  dropped with a warning; array names with spaces get underscores in ``.vtk``; ``voxel`` blocks are
  written as ``hexahedron`` blocks; Gmsh's incomplete cells of orders 3-4 go into VTK files as the complete
  Lagrange cells of the same geometry (:mod:`hexsos_plugins.io.incomplete_vtk`). MSH, VTK and VTU have no block
  boundaries of their own: consecutive
  blocks of the same cell type come back from them as one block (Medit keeps them apart).
"""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
from collections import Counter
from pathlib import Path

import meshio
import numpy as np

from ..cells.elements import VOXEL_TO_VTK
from ..errors import HexsosError, InvalidInputError, MeshWriteError
from .mesh import Mesh, copy_block, copy_mesh
from .formats import NO_WRITE, WRITE_ALIASES, WRITE_BY_EXT, ext_formats, few_exts, format_name, writer_formats
from .incomplete_vtk import incomplete_as_complete
from .msh41 import write_msh41
from .meshio_conventions import (VTK_LINEAR_PYRAMID_FROM, fix_write_order, meshio_dimensions, missing_package,
                                 quiet_meshio, shorten)
from .readers.tokens import Cursor

__all__ = ["write"]


def _write_format(path: Path, file_format) -> str:
    writable = writer_formats()
    if file_format is not None:
        fmt = WRITE_ALIASES.get(str(file_format).lower(), str(file_format).lower())
        if fmt in NO_WRITE:
            raise MeshWriteError(f"{path}: cannot write {fmt}: {NO_WRITE[fmt]}")
        if fmt not in writable:
            raise MeshWriteError(f"{path}: expected a meshio writer name, found file_format={file_format!r}; "
                                 f"known: {', '.join(sorted(writable))}")
        return fmt
    ext, fmts = ext_formats(path)
    fmt = WRITE_BY_EXT.get(ext, fmts[0] if fmts else None)
    if fmt in NO_WRITE:
        raise MeshWriteError(f"{path}: cannot write {fmt}: {NO_WRITE[fmt]}")
    if fmt is None or fmt not in writable:
        shown = f"extension '{ext}'" if ext else "no extension"
        raise MeshWriteError(f"{path}: cannot tell the mesh format to write from {shown}; expected one of "
                             f"{few_exts(write=True)}, or pass file_format=")
    return fmt


def write(mesh, path, *, file_format=None) -> list:
    """Write a mesh atomically; return warnings (strings) about what the format could not hold.

    Parameters
    ----------
    mesh : meshio.Mesh or Mesh
        A Mesh is written as ``mesh.to_meshio()``. The object is never modified.
    path : str or PathLike
        The target; its extension picks the format unless ``file_format`` is given.
    file_format : str, optional
        A meshio writer name; ``"gmsh"``/``"gmsh22"``/``"gmsh41"`` mean MSH 4.1 binary and ``"vtk"``/``"vtk42"``
        legacy VTK 4.2 ASCII (see the module docstring for why).

    Returns
    -------
    list of str
        One sentence per thing that was converted or dropped (empty when the file holds everything).

    Raises
    ------
    MeshWriteError
        unknown extension/format, missing directory, or the writer failed (no partial file is left).
    InvalidInputError
        ``mesh`` is not a meshio.Mesh / HexMesh.
    """
    if isinstance(mesh, Mesh):
        mesh = mesh.to_meshio()
    if not isinstance(mesh, meshio.Mesh):
        raise InvalidInputError(f"expected a meshio.Mesh or hexsos Mesh to write, found {type(mesh).__name__}")
    try:
        p = Path(os.fspath(path))
    except TypeError as exc:
        raise MeshWriteError(f"expected a file path, found {type(path).__name__}") from exc
    if p.is_dir():
        raise MeshWriteError(f"{p}: is a directory, expected a file path to write")
    fmt = _write_format(p, file_format)
    directory = p.parent if str(p.parent) else Path(".")
    if not directory.is_dir():
        raise MeshWriteError(f"{p}: cannot write, the directory {directory} does not exist")

    notes: list = []
    try:
        out, kwargs, post = _prepare(mesh, fmt, notes)
    except HexsosError:
        raise
    except Exception as exc:
        raise MeshWriteError(f"{p}: cannot prepare the mesh for {format_name(fmt)}: {exc}") from exc
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=p.suffix or ".tmp", dir=str(directory))
        os.close(fd)
    except OSError as exc:
        raise MeshWriteError(f"{p}: cannot create a file in {directory} ({exc.strerror or exc})") from exc
    log: list = []
    try:
        with quiet_meshio() as log, meshio_dimensions([b.type for b in out.cells]):
            if fmt == "gmsh":
                write_msh41(tmp, out, **kwargs)
            else:
                meshio.write(tmp, out, file_format=fmt, **kwargs)
        for fix in post:
            fix(tmp)
        os.chmod(tmp, _new_file_mode(p))
        os.replace(tmp, p)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        if isinstance(exc, HexsosError):
            raise
        dep = missing_package(exc, f"{p}: writing {format_name(fmt)}")
        if dep is not None:
            raise dep from None
        if isinstance(exc, (Exception, SystemExit)):
            said = "; ".join(m for m in log if not m.startswith("Info"))
            reason = str(exc) or said or type(exc).__name__
            if isinstance(exc, KeyError) and exc.args and exc.args[0] in {b.type for b in out.cells}:
                # meshio's writers look each cell type up in their own table
                reason = (f"{format_name(fmt)} holds no cells of type {exc.args[0]!r} (meshio has no such "
                          "cell type for it); Gmsh MSH (.msh) holds every type hexsos reads")
            raise MeshWriteError(f"{p}: writing {format_name(fmt)} failed: {shorten(reason)}") from exc
        raise
    for m in log:
        if any(s in m for s in _NOISE):
            continue
        notes.append("meshio: " + m.split(":", 1)[-1].strip())
    return notes


_NOISE = ("only meant for debugging", "Appending zeros to replace the missing")


def _new_file_mode(p: Path) -> int:
    try:
        return p.stat().st_mode & 0o7777
    except OSError:
        mask = os.umask(0)
        os.umask(mask)
        return 0o666 & ~mask


def _prepare(mesh: meshio.Mesh, fmt: str, notes: list):
    """A private copy of mesh, ready for meshio's writer of fmt; returns (mesh, writer kwargs, post-fixes)."""
    voxels = [b for b in mesh.cells if b.type == "voxel"]
    cells = []
    for b in mesh.cells:
        if b.type == "voxel":
            cells.append(copy_block(b, np.asarray(b.data)[:, VOXEL_TO_VTK], cell_type="hexahedron"))
        else:
            cells.append(copy_block(b))
    m = copy_mesh(mesh, cells=cells)
    if fmt in ("vtu", "vtk42", "vtk51", "vtk"):
        incomplete_as_complete(m, notes)  # Gmsh's incomplete cells of orders 3-4: VTK has none
    if fmt in ("vtu", "vtk42", "vtk51", "vtk") and any(b.type == "pyramid14" for b in m.cells):
        _pyramid14_as_13(m, notes)
    if fmt in ("vtu", "vtk42", "vtk51", "vtk") and any(b.type in VTK_LINEAR_PYRAMID_FROM for b in m.cells):
        _high_order_pyramids_as_linear(m, notes)
    fix_write_order(m, fmt)
    if voxels:
        notes.append(f"{len(voxels)} voxel block(s) written as hexahedron blocks (VTK node order): "
                     "meshio has no voxel cell type")
    # Gmsh 4 entity topology (meshio's msh4 reader): the entities are written anew from the cells' tags
    m.cell_sets.pop("gmsh:bounding_entities", None)
    if m.points.dtype.kind != "f" or m.points.dtype.itemsize < 4:
        m.points = m.points.astype(np.float64)
    _sanitize_dtypes(m, notes)
    kwargs, post = {}, []
    if fmt == "gmsh":
        kwargs["node_dim_tags"] = _prepare_gmsh(m, notes)
    elif fmt == "vtk42":
        _prepare_vtk42(m, notes, post)
        kwargs["binary"] = False
    elif fmt == "vtu":
        if m.field_data:
            fd = _numeric_field_data(m, notes, "VTU")
            m.field_data = {}
            if fd:
                post.append(lambda tmp, fd=fd: _inject_vtu_field_data(tmp, fd, notes))
    elif fmt == "medit":
        _prepare_medit(m, notes)
    elif fmt == "exodus":
        _prepare_exodus(m, notes, post)
    if fmt not in ("gmsh", "vtk42", "vtu", "medit"):
        post.append(lambda tmp, m=m, fmt=fmt: _name_what_is_missing(tmp, m, fmt, notes))
    return m, kwargs, post


def _high_order_pyramids_as_linear(m: meshio.Mesh, notes: list) -> None:
    """VTK has no Lagrange pyramid (VTK 9.7): pyramids of order >= 3 are written as linear pyramids (their 5
    corners, the first nodes in Gmsh's order as in VTK's), with a note; the cell arrays stay on them."""
    n = Counter()
    for b in m.cells:
        if b.type in VTK_LINEAR_PYRAMID_FROM:
            n[b.type] += len(b.data)
            b.type, b.data = "pyramid", np.ascontiguousarray(np.asarray(b.data)[:, :5])
    what = ", ".join(f"{k} {t}" for t, k in n.items())
    notes.append(f"{what} cells written as linear pyramids (their 5 corners; VTK has no Lagrange pyramid): their "
                 "other nodes are not in this file (write .msh to keep them)")


def _pyramid14_as_13(m: meshio.Mesh, notes: list) -> None:
    """VTK has no 14-node pyramid: write Gmsh's pyramid14 as VTK's 13-node quadratic pyramid (its base-centre
    node dropped), in VTK's order (meshio's Gmsh permutation of pyramid13)."""
    from meshio.gmsh.common import _gmsh_to_meshio_order

    n = 0
    for b in m.cells:
        if b.type == "pyramid14":
            b.data = np.ascontiguousarray(_gmsh_to_meshio_order("pyramid13", np.asarray(b.data)[:, :13]))
            b.type = "pyramid13"
            n += len(b.data)
    notes.append(f"{n} pyramid14 cells written as 13-node pyramids (VTK has no 14-node pyramid): the node at "
                 "the centre of each base is dropped (the cell changes unless that node sat where the base's "
                 "8-node quadrilateral puts its centre)")


def _sanitize_dtypes(m: meshio.Mesh, notes: list) -> None:
    as_int8, dropped = [], []
    for where, store in (("point", m.point_data), ("cell", m.cell_data)):
        for name in list(store):
            arrays = store[name] if where == "cell" else [store[name]]
            kinds = {np.asarray(a).dtype.kind for a in arrays}
            if kinds <= set("iuf") and not any(np.asarray(a).dtype == np.float16 for a in arrays):
                continue
            if kinds - set("biuf"):
                dropped.append(f"{name} ({where} data, dtype {np.asarray(arrays[0]).dtype})")
                del store[name]
                continue
            fixed = []
            for a in arrays:
                a = np.asarray(a)
                fixed.append(a.astype(np.int8) if a.dtype.kind == "b" else
                             a.astype(np.float32) if a.dtype == np.float16 else a)
            if "b" in kinds:
                as_int8.append(name)
            store[name] = fixed if where == "cell" else fixed[0]
    if as_int8:
        notes.append(f"boolean arrays written as int8: {', '.join(as_int8)}")
    if dropped:
        notes.append(f"arrays that no mesh format can hold were dropped: {', '.join(dropped)}")


def _components(arr: np.ndarray) -> np.ndarray:
    return arr.reshape(len(arr), -1) if arr.ndim > 2 else arr


def _prepare_gmsh(m: meshio.Mesh, notes: list):
    if m.points.dtype != np.float64:
        m.points = m.points.astype(np.float64)
    for tag in ("gmsh:physical", "gmsh:geometrical"):
        if tag not in m.cell_data:
            m.cell_data[tag] = [np.zeros(len(b.data), dtype=np.int32) for b in m.cells]
            continue
        fixed = []
        for a in m.cell_data[tag]:
            a = np.asarray(a)
            a = a.reshape(len(a), -1)[:, 0] if a.ndim > 1 else a
            if a.dtype.kind == "f" and not (np.isfinite(a).all() and (a == np.round(a)).all()):
                fixed = None
                break
            fixed.append(a.astype(np.int32))
        if fixed is None:
            notes.append(f"cell data {tag} holds non-integer values; written as zeros (MSH element tags are int)")
            fixed = [np.zeros(len(b.data), dtype=np.int32) for b in m.cells]
        m.cell_data[tag] = fixed
    phys = [np.asarray(a) for a in m.cell_data["gmsh:physical"]]
    if any((a != 0).any() for a in phys) and any((a == 0).any() for a in phys):
        notes.append("cells without a physical group (gmsh:physical 0) are written in physical group 0: MSH 4 "
                     "gives physical groups to entities, and meshio reads them only when every entity has one")
    dim_tags = None
    if "gmsh:dim_tags" in m.point_data:
        dt = np.asarray(m.point_data.pop("gmsh:dim_tags"))
        if (dt.shape == (len(m.points), 2) and dt.dtype.kind in "iuf" and np.isfinite(dt).all()
                and (dt == np.round(dt)).all() and ((dt[:, 0] >= 0) & (dt[:, 0] <= 3)).all()):
            dim_tags = dt.astype(np.int64)
        else:
            notes.append(f"point data gmsh:dim_tags is not a (dim, tag) pair per node (shape {dt.shape}): "
                         "dropped, every node is written on one entity")
    for store, where in ((m.point_data, "point"), (m.cell_data, "cell")):
        for name in list(store):
            if name in ("gmsh:physical", "gmsh:geometrical", "cell_tags"):
                continue
            arrays = store[name] if where == "cell" else [store[name]]
            arrays = [_components(np.asarray(a)) for a in arrays]
            k = 1 if arrays[0].ndim == 1 else arrays[0].shape[1]
            if k in (1, 3, 9):
                store[name] = arrays if where == "cell" else arrays[0]
            elif k < 9:
                width = 3 if k < 3 else 9
                padded = [np.concatenate([a.astype(np.float64), np.zeros((len(a), width - k))], axis=1) for a in arrays]
                store[name] = padded if where == "cell" else padded[0]
                notes.append(f"{where} data {name} has {k} components; MSH allows 1, 3 or 9: "
                             f"padded with zeros to {width}")
            else:
                del store[name]
                for c in range(k):
                    cols = [a[:, c] for a in arrays]
                    store[f"{name}_{c}"] = cols if where == "cell" else cols[0]
                notes.append(f"{where} data {name} has {k} components; MSH allows 1, 3 or 9: written as "
                             f"{name}_0 .. {name}_{k - 1}")
    keep, dropped = {}, []
    for name, value in m.field_data.items():
        try:
            arr = np.asarray(value).ravel()
            if arr.size == 2 and np.all(arr == np.round(arr)):
                keep[name] = arr.astype(np.int64)
                continue
        except (TypeError, ValueError):
            pass
        dropped.append(name)
    m.field_data = keep
    if dropped:
        notes.append("field data that is not a [tag, dim] pair (MSH $PhysicalNames) was dropped: " + ", ".join(dropped))
    # meshio reads Gmsh physical groups as cell sets too; in the file they live on as gmsh:physical + $PhysicalNames
    _drop_sets(m, notes, "MSH", quiet=set(keep))
    return dim_tags


def _drop_sets(m: meshio.Mesh, notes: list, fmt: str, quiet=()) -> None:
    names = [n for n in list(m.point_sets) + list(m.cell_sets) if n not in quiet]
    m.point_sets, m.cell_sets = {}, {}
    if names:
        notes.append(f"point/cell sets are not stored in {fmt}: dropped {', '.join(names)}")


def _numeric_field_data(m: meshio.Mesh, notes: list, fmt: str, *, no_spaces: bool = False) -> dict:
    keep, dropped = {}, []
    for name, value in m.field_data.items():
        try:
            arr = np.asarray(value)
        except Exception:
            arr = None
        if arr is None or arr.dtype.kind not in "biuf":
            dropped.append(str(name))
            continue
        arr = arr.reshape(1) if arr.ndim == 0 else arr
        arr = arr.reshape(len(arr), -1) if arr.ndim > 2 else arr
        key = str(name)
        if no_spaces and re.search(r"\s", key):
            key = re.sub(r"\s+", "_", key)
            notes.append(f"legacy VTK array names cannot hold spaces: field data {name!r} written as {key!r}")
        keep[key] = arr.astype(np.int8) if arr.dtype.kind == "b" else arr
    if dropped:
        notes.append(f"non-numeric field data cannot be stored in {fmt}: dropped {', '.join(dropped)}")
    return keep


def _prepare_vtk42(m: meshio.Mesh, notes: list, post: list) -> None:
    renamed = []
    for store, where in ((m.point_data, "point"), (m.cell_data, "cell")):
        for name in list(store):
            arrays = store[name] if where == "cell" else [store[name]]
            arrays = [_components(np.asarray(a)) for a in arrays]
            if arrays[0].ndim == 2 and arrays[0].shape[1] == 2:
                arrays = [np.concatenate([a, np.zeros((len(a), 1), dtype=a.dtype)], axis=1) for a in arrays]
                notes.append(f"{where} data {name} has 2 components; legacy VTK vectors have 3: padded with zeros")
            value = arrays if where == "cell" else arrays[0]
            new = re.sub(r"\s+", "_", str(name))
            del store[name]
            if new != name:
                renamed.append(f"{name!r} -> {new!r}")
            store[new] = value
    if renamed:
        notes.append("legacy VTK array names cannot hold spaces: renamed " + ", ".join(renamed))
    if m.field_data:
        fd = _numeric_field_data(m, notes, "legacy VTK", no_spaces=True)
        m.field_data = {}
        if fd:
            n_cells = sum(len(b.data) for b in m.cells)
            post.append(lambda tmp, fd=fd: _inject_vtk_field_data(tmp, fd, n_cells))
    _drop_sets(m, notes, "legacy VTK")


_VTK_NAMES = {"i1": "char", "u1": "unsigned_char", "i2": "short", "u2": "unsigned_short", "i4": "int",
              "u4": "unsigned_int", "i8": "long", "u8": "unsigned_long", "f4": "float", "f8": "double"}
_VTU_NAMES = {"i1": "Int8", "u1": "UInt8", "i2": "Int16", "u2": "UInt16", "i4": "Int32", "u4": "UInt32",
              "i8": "Int64", "u8": "UInt64", "f4": "Float32", "f8": "Float64"}


def _text_values(arr: np.ndarray) -> str:
    return " ".join(repr(x) if isinstance(x, float) else str(x) for x in arr.ravel().tolist())


def _inject_vtk_field_data(tmp: str, fd: dict, n_cells: int) -> None:
    """Add 'FIELD FieldData k' after CELL_TYPES (dataset-level field data; Gmsh stops reading before it)."""
    with open(tmp, "rb") as f:
        data = f.read()
    at = data.find(b"\nCELL_TYPES ")
    if at < 0:
        raise MeshWriteError("meshio's legacy VTK output has no CELL_TYPES section to put the field data after")
    pos = data.find(b"\n", at + 1) + 1
    cur = Cursor(data)
    cur.pos = pos
    cur.take(n_cells)
    pos = cur.pos
    if n_cells and data[pos - 1:pos] != b"\n":
        nl = data.find(b"\n", pos)
        pos = len(data) if nl < 0 else nl + 1
    lines = [f"FIELD FieldData {len(fd)}"]
    for name, arr in fd.items():
        ncomp = 1 if arr.ndim == 1 else arr.shape[1]
        lines.append(f"{name} {ncomp} {len(arr)} {_VTK_NAMES[arr.dtype.str[1:]]}")
        lines.append(_text_values(arr))
    block = ("\n".join(lines) + "\n").encode()
    with open(tmp, "wb") as f:
        f.write(data[:pos] + block + data[pos:])


def _inject_vtu_field_data(tmp: str, fd: dict, notes: list) -> None:
    """Add a <FieldData> element (ASCII DataArrays) as the first child of <UnstructuredGrid>."""
    with open(tmp, "rb") as f:
        data = f.read()
    tag = b"<UnstructuredGrid>"
    at = data.find(tag)
    if at < 0:
        notes.append("field data could not be added to the VTU file (no <UnstructuredGrid> element): dropped "
                     + ", ".join(fd))
        return
    parts = ["<FieldData>"]
    for name, arr in fd.items():
        ncomp = "" if arr.ndim == 1 else f' NumberOfComponents="{arr.shape[1]}"'
        safe = name.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")
        parts.append(f'<DataArray type="{_VTU_NAMES[arr.dtype.str[1:]]}" Name="{safe}" '
                     f'NumberOfTuples="{len(arr)}"{ncomp} format="ascii">{_text_values(arr)}</DataArray>')
    parts.append("</FieldData>")
    with open(tmp, "wb") as f:
        f.write(data[: at + len(tag)] + "".join(parts).encode() + data[at + len(tag):])


_MEDIT_TYPES = {"line", "triangle", "quad", "tetra", "wedge", "pyramid", "hexahedron"}


def _prepare_medit(m: meshio.Mesh, notes: list) -> None:
    if m.points.dtype not in (np.float32, np.float64):
        m.points = m.points.astype(np.float64)
    skip = [b for b, blk in enumerate(m.cells) if blk.type not in _MEDIT_TYPES]
    if skip:
        desc = ", ".join(f"{len(m.cells[b].data)} {m.cells[b].type}" for b in skip)
        notes.append(f"Medit cannot hold {desc} cells: skipped")
        keep = [b for b in range(len(m.cells)) if b not in skip]
        m.cells = [m.cells[b] for b in keep]
        m.cell_data = {k: [v[b] for b in keep] for k, v in m.cell_data.items()}

    def pick(store, candidates, per_block):
        for name in candidates:
            if name in store:
                arrays = store[name] if per_block else [store[name]]
                arrays = [np.asarray(a) for a in arrays]
                if all(a.ndim == 1 and (a.dtype.kind in "iu" or (a.dtype.kind == "f" and np.isfinite(a).all()
                                                                 and (a == np.round(a)).all())) for a in arrays):
                    return name, [a.astype(np.int64) for a in arrays]
        return None, None

    cname, cref = pick(m.cell_data, ("medit:ref", "gmsh:physical"), True)
    dropped_c = [n for n in m.cell_data if n != cname]
    m.cell_data = {"medit:ref": cref} if cname else {}
    pname, pref = pick(m.point_data, ("medit:ref",), False)
    dropped_p = [n for n in m.point_data if n != pname]
    m.point_data = {"medit:ref": pref[0]} if pname else {}
    if dropped_c:
        kept = f" (kept {cname!r} as the element reference)" if cname else ""
        notes.append(f"Medit .mesh cannot hold cell data: dropped {', '.join(dropped_c)}{kept}")
    if dropped_p:
        notes.append(f"Medit .mesh cannot hold point data: dropped {', '.join(dropped_p)}")
    if m.field_data:
        notes.append(f"Medit .mesh cannot hold field data: dropped {', '.join(map(str, m.field_data))}")
        m.field_data = {}
    _drop_sets(m, notes, "Medit")


# ------------------------------------------------------------------------------------------------ Exodus II
_EXODUS_NAME = 32  # len_string 33: 32 characters and the terminator


def _prepare_exodus(m: meshio.Mesh, notes: list, post: list) -> None:
    """meshio's Exodus writer writes no element variables: take the cell data out (one scalar element variable
    per component, ``nameX``/``Y``/``Z`` for 3 components, which VTK's Exodus reader joins back into the vector
    ``name``, ``name_0``..
    otherwise) and add them to the written file."""
    variables, split, dropped = [], [], []
    for name, arrays in m.cell_data.items():
        arrays = [_components(np.asarray(a)) for a in arrays]
        if arrays and any(a.dtype.kind not in "biuf" for a in arrays):
            dropped.append(name)
            continue
        k = 1 if not arrays or arrays[0].ndim == 1 else arrays[0].shape[1]
        if k == 1:
            variables.append((str(name), [a.reshape(len(a)).astype(np.float64) for a in arrays]))
            continue
        suffixes = ("X", "Y", "Z") if k == 3 else tuple(f"_{c}" for c in range(k))
        for c, suffix in enumerate(suffixes):
            variables.append((f"{name}{suffix}", [a[:, c].astype(np.float64) for a in arrays]))
        split.append(f"{name} -> {name}{suffixes[0]} .. {name}{suffixes[-1]}")
    m.cell_data = {}
    long = [n for n, _ in variables if len(n) > _EXODUS_NAME]
    if long:
        dropped += long
        variables = [(n, v) for n, v in variables if len(n) <= _EXODUS_NAME]
    if split:
        notes.append("Exodus element variables are scalars: cell data with components written as one variable "
                     "per component: " + ", ".join(split))
    if dropped:
        notes.append(f"Exodus cannot hold these cell arrays (not numeric, or names longer than {_EXODUS_NAME} "
                     f"characters): dropped {', '.join(map(str, dropped))}")
    if variables:
        post.insert(0, lambda tmp: _inject_exodus_element_variables(tmp, variables))


def _inject_exodus_element_variables(tmp: str, variables: list) -> None:
    import netCDF4

    with netCDF4.Dataset(tmp, "a") as nc:
        n_blocks = len(nc.dimensions["num_el_blk"])
        nc.createDimension("num_elem_var", len(variables))
        names = nc.createVariable("name_elem_var", "S1", ("num_elem_var", "len_string"))
        names.set_auto_mask(False)
        for k, (name, _) in enumerate(variables):
            raw = np.zeros(len(nc.dimensions["len_string"]), dtype="S1")
            raw[: len(name)] = [bytes([c]) for c in name.encode()]
            names[k] = raw
        table = nc.createVariable("elem_var_tab", "i4", ("num_el_blk", "num_elem_var"))
        table[:] = np.ones((n_blocks, len(variables)), dtype=np.int32)
        if len(nc.dimensions["time_step"]) == 0:
            nc.variables["time_whole"][0] = 0.0
        for k, (_, per_block) in enumerate(variables):
            for b in range(n_blocks):
                var = nc.createVariable(f"vals_elem_var{k + 1}eb{b + 1}", "f8", ("time_step", f"num_el_in_blk{b + 1}"))
                var[0] = per_block[b]


# ------------------------------------------------------------------------------------------ the other formats
def _name_what_is_missing(tmp: str, written: meshio.Mesh, fmt: str, notes: list) -> None:
    """For the formats hexsos hands to meshio as they are (Abaqus, Nastran, XDMF, MED, Exodus, ...): read the file
    back and name every array, field datum and set that is not in it (meshio's writers drop them silently)."""
    groups = {"point data": list(written.point_data), "cell data": list(written.cell_data),
              "field data": list(map(str, written.field_data)), "point sets": list(written.point_sets),
              "cell sets": list(written.cell_sets)}
    if fmt == "exodus":  # the element variables were taken out before meshio wrote the file; they are checked below
        groups["cell data"] = []
    try:
        with quiet_meshio():
            back = meshio.read(tmp, file_format=fmt)
    except BaseException as exc:  # noqa: BLE001 - meshio raises anything, SystemExit included
        if isinstance(exc, KeyboardInterrupt):
            raise
        listed = "; ".join(f"{g}: {', '.join(v)}" for g, v in groups.items() if v)
        if listed:
            notes.append(f"{format_name(fmt)} is written by meshio, which cannot read the file back to confirm what it "
                         f"holds ({shorten(str(exc) or type(exc).__name__)}); these may be missing: {listed}")
        return
    have = {"point data": set(back.point_data), "cell data": set(back.cell_data),
            "field data": set(map(str, back.field_data)), "point sets": set(back.point_sets),
            "cell sets": set(back.cell_sets)}
    for group, names in groups.items():
        missing = [n for n in names if n not in have[group]
                   and not any(re.fullmatch(re.escape(n) + r"(?:[XYZ]|_\d+)", h) for h in have[group])]
        if missing:
            notes.append(f"{format_name(fmt)} does not hold {group}: dropped {', '.join(missing)}")
