"""Gmsh MSH (every version Gmsh reads: 2.x, 4.x, ASCII and binary) through Gmsh's own C++ parser.

``gmsh.open`` + ``getNodes`` / ``getElements`` per entity. Used where meshio 5.3.5 fails, e.g. MSH 4.1 files with
quadratic serendipity cells (``wedge15``, ``hexahedron20``: meshio raises ``KeyError``), and 2.x files whose
``$ElementData`` spans several cell blocks. What it returns is what meshio's MSH 4.1 reader returns for the
files both read (tested):

* points: every node, in the order of the node tags (cells reference their index);
* one cell block per (entity, element type), entities in Gmsh's order (by dimension, then tag), in VTK node
  order (the element registry's ``gmsh_to_vtk`` for the checked types, meshio's permutations for the others);
* cell data ``gmsh:physical`` (the entity's first physical group, 0 if none) and ``gmsh:geometrical`` (the
  entity's tag); point data ``gmsh:dim_tags`` ([dim, tag] of each node's entity) for MSH 4 files;
* field data ``{physical name: [tag, dim]}``;
* ``$NodeData`` / ``$ElementData`` (Gmsh views) as point / cell data by name (the last time step, as meshio;
  cells a view does not cover get NaN); ``$ElementNodeData`` is refused (it would be lost).

Gmsh keeps global state: this reader runs only when the process has no Gmsh session of its own (otherwise it
declines and the next reader is tried), initializes Gmsh without its SIGINT handler and without reading
configuration files, and finalizes it afterwards (also after a failure: a failed ``gmsh.open`` leaves Gmsh
busy). Files that do not start with ``$MeshFormat`` are never handed to it (Gmsh would parse them as .geo
scripts).
"""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from ...cells.elements import ELEMENTS
from .common import ParseError, make_block, node_indexer
from ..meshio_conventions import GMSH_EXTRA_2D, shorten

__all__ = ["read_gmsh_api", "GMSH_TO_VTK"]

#: Gmsh element type -> (meshio name, permutation to VTK order or None) for the checked types.
GMSH_TO_VTK = {el.gmsh_type: (name, np.array(el.gmsh_to_vtk)) for name, el in ELEMENTS.items()}


def _meshio_name_and_order(gtype: int):
    if gtype in GMSH_TO_VTK:
        return GMSH_TO_VTK[gtype]
    from meshio.gmsh.common import _gmsh_to_meshio_order, _gmsh_to_meshio_type

    name = _gmsh_to_meshio_type.get(int(gtype))
    if name is None:
        # Gmsh's incomplete triangles and quadrilaterals, which meshio lacks: kept in Gmsh's order
        return GMSH_EXTRA_2D.get(int(gtype), (None, None))[0], None
    probe = np.arange(200)[None, :]
    try:
        order = np.asarray(_gmsh_to_meshio_order(name, probe))[0]
    except Exception:  # pragma: no cover - meshio's table has no such width
        order = None
    return name, order


def _version(raw_head: bytes) -> str:
    lines = raw_head.lstrip().split(b"\n")
    if not lines or lines[0].strip() != b"$MeshFormat" or len(lines) < 2:
        raise ParseError("expected '$MeshFormat' at the start of the file")
    parts = lines[1].split()
    return parts[0].decode("latin-1") if parts else "?"


def read_gmsh_api(path) -> meshio.Mesh:
    """Read a Gmsh MSH file with Gmsh's own reader; raises ``ParseError`` when Gmsh cannot (or may not)."""
    p = Path(path)
    with open(p, "rb") as f:
        version = _version(f.read(256))
    try:
        import gmsh
    except ImportError:
        raise ParseError("Gmsh's reader is not available (pip install gmsh)") from None
    if gmsh.isInitialized():
        raise ParseError("Gmsh's reader was not used: this process has a Gmsh session of its own")
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.logger.start()
        try:
            gmsh.open(str(p))
        except Exception as exc:
            said = [m.split(":", 1)[-1].strip() for m in gmsh.logger.get() if m.startswith("Error")]
            raise ParseError("Gmsh: " + shorten("; ".join(said) or str(exc), 200)) from None
        return _extract(gmsh, version.startswith("4"))
    finally:
        try:
            gmsh.logger.stop()
        finally:
            gmsh.finalize()


def _extract(gmsh, v4: bool) -> meshio.Mesh:
    tags, xyz, _ = gmsh.model.mesh.getNodes(returnParametricCoord=False)
    tags = np.asarray(tags, dtype=np.int64)
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    if len(tags) == 0:
        raise ParseError("Gmsh read no nodes")
    order = np.argsort(tags, kind="stable")
    sorted_tags = tags[order]
    if (sorted_tags[1:] == sorted_tags[:-1]).any():
        raise ParseError("the file repeats node tags")
    points = xyz[order]
    find = node_indexer(sorted_tags, "the file")

    def index(node_tags):
        return find(node_tags, "an element")

    parts = []  # (name, dim, conn, physical tag, entity tag, element tags)
    entities = gmsh.model.getEntities()
    dim_tags = np.zeros((len(points), 2), dtype=np.int64) if v4 else None
    for dim, etag in entities:
        if v4:
            nt, _, _ = gmsh.model.mesh.getNodes(dim, etag, includeBoundary=False, returnParametricCoord=False)
            if len(nt):
                dim_tags[index(nt)] = (dim, etag)
        phys = gmsh.model.getPhysicalGroupsForEntity(dim, etag)
        ptag = int(phys[0]) if len(phys) else 0
        if len(phys) > 1 and not v4:
            raise ParseError(f"entity ({dim}, {etag}) is in several physical groups: MSH 2 physical tags per "
                              "element cannot be recovered through Gmsh's reader")
        types, etags, enodes = gmsh.model.mesh.getElements(dim, etag)
        for gtype, et, en in zip(types, etags, enodes):
            if len(et) == 0:
                continue
            name, perm = _meshio_name_and_order(int(gtype))
            if name is None:
                gname = gmsh.model.mesh.getElementProperties(int(gtype))[0]
                raise ParseError(f"Gmsh element type {int(gtype)} ({gname}) has no meshio cell type")
            # the node count from the registry where it has the type: Gmsh 4.15 cannot give the properties of
            # prisms of order >= 3 ("FaceClosureFull not implemented"), though it reads and stores them
            k = len(et) and len(en) // len(et)
            conn = index(en).reshape(-1, k)
            if perm is not None and len(perm) >= k and not np.array_equal(perm[:k], np.arange(k)):
                conn = np.ascontiguousarray(conn[:, perm[:k]])
            parts.append((name, dim, conn, ptag, etag, np.asarray(et, dtype=np.int64)))
    cells, physical, geometrical, elem_tags = _file_order(parts, by_entity=v4)
    field_data = {}
    for dim, ptag in gmsh.model.getPhysicalGroups():
        name = gmsh.model.getPhysicalName(dim, ptag)
        if name:
            field_data[name] = np.array([ptag, dim])
    point_data = {"gmsh:dim_tags": dim_tags} if v4 else {}
    cell_data = {"gmsh:physical": physical, "gmsh:geometrical": geometrical}
    _views(gmsh, points, index, cells, elem_tags, point_data, cell_data)
    mesh = meshio.Mesh.__new__(meshio.Mesh)
    mesh.points, mesh.cells = points, cells
    mesh.point_data, mesh.cell_data, mesh.field_data = point_data, cell_data, field_data
    mesh.point_sets, mesh.cell_sets, mesh.gmsh_periodic, mesh.info = {}, {}, None, None
    return mesh


def _file_order(parts, *, by_entity: bool):
    """Blocks in the file's element order (element tags ascending), one block per run of one type (and, for MSH 4,
    one entity), as meshio's MSH 2.2 (runs of one type) and 4.1 (entity blocks) readers make them."""
    if not parts:
        return [], [], [], []
    first = [int(p[5][0]) for p in parts]
    in_order = all(int(a[5][-1]) < b for a, b in zip(parts[:-1], first[1:])) and all(
        len(p[5]) < 2 or (np.diff(p[5]) > 0).all() for p in parts)
    if in_order:
        runs = parts
    else:
        tags = np.concatenate([p[5] for p in parts])
        order = np.argsort(tags, kind="stable")
        part_of = np.repeat(np.arange(len(parts)), [len(p[5]) for p in parts])[order]
        row_of = np.concatenate([np.arange(len(p[5])) for p in parts])[order]
        cut = np.flatnonzero(part_of[1:] != part_of[:-1]) + 1
        runs = []
        for s, e in zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(order)]])):
            p = parts[int(part_of[s])]
            rows = row_of[s:e]
            runs.append((p[0], p[1], p[2][rows], p[3], p[4], p[5][rows]))
    cells, physical, geometrical, elem_tags = [], [], [], []
    for name, dim, conn, ptag, etag, et in runs:
        same = cells and cells[-1].type == name and not by_entity
        if same:
            cells[-1].data = np.concatenate([cells[-1].data, conn])
            physical[-1] = np.concatenate([physical[-1], np.full(len(conn), ptag, dtype=np.int64)])
            geometrical[-1] = np.concatenate([geometrical[-1], np.full(len(conn), etag, dtype=np.int64)])
            elem_tags[-1] = np.concatenate([elem_tags[-1], et])
            continue
        cells.append(make_block(name, conn, dim))
        physical.append(np.full(len(conn), ptag, dtype=np.int64))
        geometrical.append(np.full(len(conn), etag, dtype=np.int64))
        elem_tags.append(et)
    return cells, physical, geometrical, elem_tags


def _views(gmsh, points, index, cells, elem_tags, point_data, cell_data) -> None:
    """$NodeData / $ElementData sections (Gmsh views) as point / cell data."""
    if not len(gmsh.view.getTags()):
        return
    all_tags = np.concatenate(elem_tags) if elem_tags else np.zeros(0, dtype=np.int64)
    where = np.argsort(all_tags, kind="stable")
    sorted_elems = all_tags[where]
    sizes = [len(t) for t in elem_tags]
    for i, vtag in enumerate(gmsh.view.getTags()):
        name = gmsh.option.getString(f"View[{i}].Name")
        steps = int(gmsh.option.getNumber(f"View[{i}].NbTimeStep"))
        kind, tags, data, _, ncomp = gmsh.view.getHomogeneousModelData(vtag, max(steps - 1, 0))
        tags = np.asarray(tags, dtype=np.int64)
        data = np.asarray(data, dtype=np.float64)
        ncomp = int(ncomp)
        if kind == "NodeData":
            arr = np.full((len(points), ncomp), np.nan)
            arr[index(tags)] = data.reshape(-1, ncomp)
            point_data[name] = arr[:, 0] if ncomp == 1 else arr
        elif kind == "ElementData":
            pos = np.searchsorted(sorted_elems, tags)
            pos[pos >= len(sorted_elems)] = 0
            if len(tags) and not (sorted_elems[pos] == tags).all():
                raise ParseError(f"$ElementData {name!r} names elements the file does not define")
            flat = np.full((len(all_tags), ncomp), np.nan)
            flat[where[pos]] = data.reshape(-1, ncomp)
            if ncomp == 1:
                flat = flat[:, 0]
            cell_data[name] = np.split(flat, np.cumsum(sizes)[:-1]) if sizes else []
        else:
            raise ParseError(f"{kind} {name!r} (per-node values of each element) is not read by hexsos; "
                              "it would be lost")
