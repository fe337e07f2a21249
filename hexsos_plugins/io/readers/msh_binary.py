"""Binary Gmsh MSH 2.2 and 4.1 read with numpy: the fast path.

Each block of nodes or elements is one ``np.frombuffer`` over the file's bytes; nothing is parsed in a Python
loop per node or per element. Measured (``python -m comparison.bench_read``, a 912,673-hex grid): MSH 4.1 in
about a third of meshio's time and of Gmsh's reader; MSH 2.2 (what :func:`hexsos_plugins.io.write` writes) about
1/100 of meshio's time (meshio's MSH 2.2 binary reader loops per element) and 1/10 of Gmsh's.

It gives what meshio's readers give for the files both read (tested): points in node-tag order (file order when
the tags ascend), cell blocks in VTK node order (per run of one element type for MSH 2.2, per entity block for
MSH 4.1, as meshio), ``gmsh:physical`` / ``gmsh:geometrical`` cell data, ``gmsh:dim_tags`` point data (MSH 4.1),
``$PhysicalNames`` as field data ``{name: [tag, dim]}``, ``$NodeData`` / ``$ElementData`` as point / cell data
(the last section of a name wins, as in meshio; cells a section does not cover get NaN).

It declines (and the next reader is tried) anything it does not read completely: ASCII files, other versions,
a data size other than 8, big-endian files, parametric nodes, more than two tags per MSH 2 element
(partitions), and sections other than $MeshFormat, $PhysicalNames, $Entities, $Nodes, $Elements, $NodeData,
$ElementData and $Comments. A file that is cut short or whose counts do not match its bytes is refused with
the section and what was expected.
"""

from __future__ import annotations

import mmap
from pathlib import Path

import meshio
import numpy as np

from ...cells.elements import ELEMENTS
from ..meshio_conventions import GMSH_EXTRA_2D
from .common import ParseError, make_block, node_indexer

__all__ = ["read_msh_binary"]

_KNOWN = {b"$MeshFormat", b"$PhysicalNames", b"$Entities", b"$Nodes", b"$Elements", b"$NodeData",
          b"$ElementData", b"$Comments"}


class _Decline(ParseError):
    """The file is not one the fast path reads (not an error of the file)."""


def _types():
    from meshio._common import num_nodes_per_cell
    from meshio.gmsh.common import _gmsh_to_meshio_order, _gmsh_to_meshio_type

    out = {}
    for g, name in _gmsh_to_meshio_type.items():
        k = num_nodes_per_cell.get(name)
        if k is None:
            continue
        if name in ELEMENTS:
            perm = np.array(ELEMENTS[name].gmsh_to_vtk)
        else:
            perm = np.asarray(_gmsh_to_meshio_order(name, np.arange(k)[None, :]))[0]
        out[int(g)] = (name, k, None if np.array_equal(perm, np.arange(k)) else perm)
    for name, el in ELEMENTS.items():  # the registry's types meshio lacks (pyramids of order >= 3, incomplete cells)
        if el.gmsh_type not in out:
            perm = np.array(el.gmsh_to_vtk)
            out[el.gmsh_type] = (name, el.n_nodes, None if np.array_equal(perm, np.arange(el.n_nodes)) else perm)
    for g, (name, k) in GMSH_EXTRA_2D.items():  # Gmsh's incomplete triangles and quadrilaterals (Gmsh's order)
        out.setdefault(g, (name, k, None))
    return out


_TYPES = None
_DIM = {"vertex": 0, "line": 1, "triangle": 2, "quad": 2, "polygon": 2}


def _dim(name: str) -> int:
    for prefix, d in (("vertex", 0), ("line", 1), ("triangle", 2), ("quad", 2)):
        if name.startswith(prefix):
            return d
    return 3


class _Bytes:
    def __init__(self, raw: bytes):
        self.raw = raw
        self.pos = 0

    def line(self, what: str) -> bytes:
        end = self.raw.find(b"\n", self.pos)
        if end < 0:
            raise ParseError(f"expected {what}, found the end of the file (truncated?)")
        s = self.raw[self.pos:end].strip()
        self.pos = end + 1
        return s

    def array(self, dtype, count: int, what: str) -> np.ndarray:
        dtype = np.dtype(dtype)
        nbytes = dtype.itemsize * count
        if count < 0 or self.pos + nbytes > len(self.raw):
            have = max(len(self.raw) - self.pos, 0) // max(dtype.itemsize, 1)
            raise ParseError(f"expected {count} binary values for {what}, found only {have} before the end of "
                              "the file (truncated?)")
        arr = np.frombuffer(self.raw, dtype=dtype, count=count, offset=self.pos)
        self.pos += nbytes
        return arr

    def end(self, section: bytes) -> None:
        tag = b"$End" + section[1:]
        s = self.line(tag.decode())
        while s == b"":
            s = self.line(tag.decode())
        if s != tag:
            raise ParseError(f"expected '{tag.decode()}', found {s[:40]!r} (do the counts match the data?)")


def read_msh_binary(path) -> meshio.Mesh:
    """Read a binary MSH 2.2 / 4.1 file; raises ``ParseError`` (declining or refusing) otherwise.

    The file is mapped read-only, not copied into memory: its pages are read where the page cache holds them
    (a copy of a 100 MB file is 25,000 fresh pages, each a page fault). Every array of the result is a copy,
    so the mapping is closed before returning; a result that still viewed it (then it cannot be closed) is
    read again from a copy of the file: a mesh never changes with its file."""
    global _TYPES
    if _TYPES is None:
        _TYPES = _types()
    with open(path, "rb") as fh:
        try:
            raw = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        except (ValueError, OSError):  # an empty file, or one that cannot be mapped
            raw = fh.read()
    mesh = parse(raw)
    if isinstance(raw, mmap.mmap):
        try:
            raw.close()
        except BufferError:
            mesh = parse(Path(path).read_bytes())
    return mesh


def parse(raw) -> meshio.Mesh:
    cur = _Bytes(raw)
    first = cur.line("$MeshFormat")
    if first != b"$MeshFormat":
        raise _Decline("the numpy MSH reader declines this file: it does not start with $MeshFormat")
    head = cur.line("the MSH version").split()
    if len(head) < 3 or head[1] != b"1":
        raise _Decline("the numpy MSH reader declines this file: not binary")
    version = head[0].decode("latin-1")
    if version not in ("2.2", "4.1") or head[2] != b"8":
        raise _Decline(f"the numpy MSH reader declines this file: version {version}, data size {head[2].decode()}")
    one = cur.array("<i4", 1, "the endianness check")
    if int(one[0]) != 1:
        raise _Decline("the numpy MSH reader declines this file: not little-endian")
    cur.end(b"$MeshFormat")
    v4 = version == "4.1"
    st = {"field_data": {}, "entities": None, "nodes": None, "elements": None, "point_data": {}, "elem_data": {}}
    while True:
        s = cur.line("a section") if cur.pos < len(raw) else None
        if s is None:
            break
        if s == b"":
            continue
        if s not in _KNOWN:
            raise _Decline(f"the numpy MSH reader declines this file: section {s[:40].decode('latin-1')!r}")
        if s == b"$PhysicalNames":
            _physical_names(cur, st["field_data"])
        elif s == b"$Comments":
            at = raw.find(b"\n$EndComments", cur.pos)
            if at < 0:
                raise ParseError("expected '$EndComments', found the end of the file")
            cur.pos = at + 1
            cur.end(b"$Comments")
            continue
        elif s == b"$Entities":
            if not v4:
                raise _Decline("the numpy MSH reader declines this file: $Entities in MSH 2")
            st["entities"] = _entities(cur)
        elif s == b"$Nodes":
            st["nodes"] = _nodes4(cur) if v4 else _nodes2(cur)
        elif s == b"$Elements":
            st["elements"] = _elements4(cur) if v4 else _elements2(cur)
        else:
            name, tags, values = _data(cur, s)
            (st["point_data"] if s == b"$NodeData" else st["elem_data"])[name] = (tags, values)
        cur.end(s)
    if st["nodes"] is None or st["elements"] is None:
        raise ParseError("expected $Nodes and $Elements sections, found " +
                          ("neither" if st["nodes"] is None and st["elements"] is None else
                           "no $Nodes" if st["nodes"] is None else "no $Elements"))
    return _assemble(st, v4)


def _physical_names(cur: _Bytes, field_data: dict) -> None:
    n = int(cur.line("the number of physical names"))
    for _ in range(n):
        s = cur.line("a physical name").decode("latin-1")
        parts = s.split(maxsplit=2)
        if len(parts) < 3:
            raise ParseError(f"expected 'dim tag \"name\"' in $PhysicalNames, found {s[:40]!r}")
        field_data[parts[2].strip().strip('"')] = np.array([int(parts[1]), int(parts[0])])


def _entities(cur: _Bytes) -> dict:
    counts = cur.array("<u8", 4, "$Entities counts")
    out = {}  # (dim, tag) -> physical tags
    for dim, n in enumerate(counts.tolist()):
        for _ in range(int(n)):
            tag = int(cur.array("<i4", 1, "$Entities")[0])
            cur.array("<f8", 3 if dim == 0 else 6, "$Entities")
            nphys = int(cur.array("<u8", 1, "$Entities")[0])
            phys = cur.array("<i4", nphys, "$Entities")
            if dim > 0:
                nb = int(cur.array("<u8", 1, "$Entities")[0])
                cur.array("<i4", nb, "$Entities")
            out[(dim, tag)] = phys.tolist()
    cur.line("the end of the $Entities data")  # the newline after the binary data
    return out


def _nodes2(cur: _Bytes):
    n = int(cur.line("the number of nodes"))
    rec = cur.array(np.dtype([("tag", "<i4"), ("x", "<f8", (3,))]), n, "$Nodes")
    cur.line("the end of the $Nodes data")
    return rec["tag"].astype(np.int64), rec["x"].astype(np.float64), None


def _nodes4(cur: _Bytes):
    nblocks, total, _, _ = (int(v) for v in cur.array("<u8", 4, "$Nodes counts"))
    tags, xyz, dimtag = [], [], []
    for _ in range(nblocks):
        dim, etag, parametric = (int(v) for v in cur.array("<i4", 3, "a $Nodes block"))
        if parametric:
            raise _Decline("the numpy MSH reader declines this file: parametric nodes")
        n = int(cur.array("<u8", 1, "a $Nodes block")[0])
        tags.append(cur.array("<u8", n, "$Nodes tags").astype(np.int64))
        xyz.append(cur.array("<f8", 3 * n, "$Nodes coordinates").reshape(n, 3))
        dimtag.append((dim, etag, n))
    cur.line("the end of the $Nodes data")
    t = np.concatenate(tags) if tags else np.zeros(0, dtype=np.int64)
    if len(t) != total:
        raise ParseError(f"$Nodes announces {total} nodes, its blocks hold {len(t)}")
    x = np.concatenate(xyz) if xyz else np.zeros((0, 3))
    dt = np.repeat(np.array([(d, e) for d, e, _ in dimtag], dtype=np.int64).reshape(-1, 2),
                   [k for _, _, k in dimtag], axis=0)
    return t, x, dt


def _elements2(cur: _Bytes):
    total = int(cur.line("the number of elements"))
    blocks, done = [], 0
    while done < total:
        gtype, count, ntags = (int(v) for v in cur.array("<i4", 3, "an $Elements block header"))
        if gtype not in _TYPES:
            raise _Decline(f"the numpy MSH reader declines this file: element type {gtype}")
        if ntags > 2:
            raise _Decline("the numpy MSH reader declines this file: more than two tags per element")
        name, k, _ = _TYPES[gtype]
        if count <= 0 or done + count > total:
            raise ParseError(f"an $Elements block announces {count} elements of type {gtype}, but "
                              f"{total - done} remain of {total}")
        if count == 1:
            # Gmsh writes a header per element: read the run of records with the same header at once
            width = 4 + ntags + k
            cur.pos -= 12
            most = min(total - done, (len(cur.raw) - cur.pos) // (4 * width))
            if most < 1:
                raise ParseError(f"expected {total - done} more elements in $Elements, found the end of the file "
                                  "(truncated?)")
            view = np.frombuffer(cur.raw, dtype="<i4", count=most * width, offset=cur.pos).reshape(most, width)
            same = (view[:, 0] == gtype) & (view[:, 1] == 1) & (view[:, 2] == ntags)
            count = int(most if same.all() else np.argmin(same))
            rec = cur.array("<i4", count * width, "$Elements").reshape(count, width)[:, 3:]
        else:
            rec = cur.array("<i4", count * (1 + ntags + k), "$Elements").reshape(count, 1 + ntags + k)
        blocks.append((gtype, rec[:, 0].astype(np.int64), rec[:, 1 : 1 + ntags], rec[:, 1 + ntags :]))
        done += count
    cur.line("the end of the $Elements data")
    return blocks


def _elements4(cur: _Bytes):
    nblocks, total, _, _ = (int(v) for v in cur.array("<u8", 4, "$Elements counts"))
    blocks, done = [], 0
    for _ in range(nblocks):
        dim, etag, gtype = (int(v) for v in cur.array("<i4", 3, "an $Elements block header"))
        n = int(cur.array("<u8", 1, "an $Elements block header")[0])
        if gtype not in _TYPES:
            raise _Decline(f"the numpy MSH reader declines this file: element type {gtype}")
        name, k, _ = _TYPES[gtype]
        rec = cur.array("<u8", n * (1 + k), "$Elements").reshape(n, 1 + k)
        blocks.append((gtype, rec[:, 0].astype(np.int64), (dim, etag), rec[:, 1:]))
        done += n
    cur.line("the end of the $Elements data")
    if done != total:
        raise ParseError(f"$Elements announces {total} elements, its blocks hold {done}")
    return blocks


def _data(cur: _Bytes, section: bytes):
    what = section.decode()[1:]
    try:
        strings = [cur.line(what).decode("latin-1").strip().strip('"') for _ in range(int(cur.line(what)))]
        for _ in range(int(cur.line(what))):
            cur.line(what)
        ints = [int(cur.line(what)) for _ in range(int(cur.line(what)))]
        ncomp, n = ints[1], ints[2]
    except (ValueError, IndexError):
        raise ParseError(f"malformed ${what} header") from None
    if len(ints) > 3 and ints[3] != 0:
        raise _Decline("the numpy MSH reader declines this file: partitioned data")
    rec = cur.array(np.dtype([("tag", "<i4"), ("v", "<f8", (ncomp,))]), n, f"${what}")
    cur.line(f"the end of the ${what} data")
    name = strings[0] if strings else f"data_{cur.pos}"
    return name, rec["tag"].astype(np.int64), np.array(rec["v"], dtype=np.float64).reshape(n, ncomp)


def _assemble(st, v4: bool) -> meshio.Mesh:
    tags, xyz, dimtag = st["nodes"]
    if len(tags) < 2 or (tags[1:] > tags[:-1]).all():
        points, sorted_tags = np.ascontiguousarray(xyz), tags
    else:
        order = np.argsort(tags, kind="stable")
        points, sorted_tags = np.ascontiguousarray(xyz[order]), tags[order]
        dimtag = dimtag[order] if dimtag is not None else None
        if (sorted_tags[1:] == sorted_tags[:-1]).any():
            raise ParseError("the file repeats node tags")
    index = node_indexer(sorted_tags, "$Nodes")

    runs = []  # [name, dim, [conn], [physical], [geometrical], [element tags]]
    entities = st["entities"] or {}
    for gtype, etags, extra, nodes in st["elements"]:
        name, k, perm = _TYPES[gtype]
        if v4:
            dim, etag = extra
            phys = entities.get((dim, etag), [])
            p = np.full(len(nodes), phys[0] if phys else 0, dtype=np.int64)
            g = np.full(len(nodes), etag, dtype=np.int64)
        else:
            p = extra[:, 0].astype(np.int64) if extra.shape[1] >= 1 else np.zeros(len(nodes), dtype=np.int64)
            g = extra[:, 1].astype(np.int64) if extra.shape[1] >= 2 else np.zeros(len(nodes), dtype=np.int64)
        if not v4 and runs and runs[-1][0] == gtype:  # runs of one type are one block, as meshio's MSH 2.2 reader
            for i, a in zip((2, 3, 4, 5), (nodes, p, g, etags)):
                runs[-1][i].append(a)
            continue
        runs.append([gtype, name, [nodes], [p], [g], [etags]])
    cells, physical, geometrical, elem_tags = [], [], [], []
    for gtype, name, nodes, p, g, etags in runs:
        _, k, perm = _TYPES[gtype]
        cat = (lambda a: a[0] if len(a) == 1 else np.concatenate(a))
        conn = index(cat(nodes), f"an element of type {gtype}")
        if perm is not None:
            conn = np.ascontiguousarray(conn[:, perm])
        cells.append(make_block(name, conn, _dim(name)))
        physical.append(cat(p))
        geometrical.append(cat(g))
        elem_tags.append(cat(etags))
    point_data = {"gmsh:dim_tags": dimtag} if v4 else {}
    for name, (t, values) in st["point_data"].items():
        arr = np.full((len(points), values.shape[1]), np.nan)
        arr[index(t, f"$NodeData {name!r}")] = values
        point_data[name] = arr[:, 0] if arr.shape[1] == 1 else arr
    cell_data = {"gmsh:physical": physical, "gmsh:geometrical": geometrical}
    if st["elem_data"]:
        all_tags = np.concatenate(elem_tags) if elem_tags else np.zeros(0, dtype=np.int64)
        order = np.argsort(all_tags, kind="stable")
        sorted_elems = all_tags[order]
        sizes = [len(t) for t in elem_tags]
        for name, (t, values) in st["elem_data"].items():
            pos = np.searchsorted(sorted_elems, t)
            pos[pos >= len(sorted_elems)] = 0
            if len(t) and (not len(sorted_elems) or not (sorted_elems[pos] == t).all()):
                raise ParseError(f"$ElementData {name!r} names elements that $Elements does not define")
            flat = np.full((len(all_tags), values.shape[1]), np.nan)
            flat[order[pos]] = values
            if flat.shape[1] == 1:
                flat = flat[:, 0]
            cell_data[name] = np.split(flat, np.cumsum(sizes)[:-1])
    mesh = meshio.Mesh.__new__(meshio.Mesh)
    mesh.points, mesh.cells = points, cells
    mesh.point_data, mesh.cell_data, mesh.field_data = point_data, cell_data, st["field_data"]
    mesh.point_sets, mesh.cell_sets, mesh.gmsh_periodic, mesh.info = {}, {}, None, None
    return mesh
