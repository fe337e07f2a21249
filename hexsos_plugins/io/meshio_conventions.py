"""meshio's conventions, as hexsos meets them in reading and writing: its printed output captured, the
dimensions of the cell types it does not know, and the node-order corrections of its format modules.

Node orders: hexsos holds every cell block in VTK's node order (the element registry,
:mod:`hexsos_plugins.cells.elements`), which is also meshio's own convention for every type. meshio 5.3.5 deviates
in two places, measured against VTK 9.7's own shape functions and Gmsh 4.15's reference elements:

* its VTK readers and writers (``vtk``, ``vtu``) swap the linear wedge's nodes ``(0, 2, 1, 3, 5, 4)``, following
  ``vtkWedge``'s documentation rather than its code: VTK's shape functions, ``vtkMeshQuality`` (volume) and
  ``vtkCellValidator`` all call the wedge whose nodes sit at VTK's parametric coordinates valid, and its
  mirror invalid. So meshio mirrors every wedge it reads from or writes to a VTK file; hexsos undoes it on
  reading (:func:`fix_read_order`) and redoes it before meshio writes (:func:`fix_write_order`), so the
  file's own node order is what the kernel sees and what is written.
* its Gmsh reader and writer have no permutation for ``wedge18`` (Gmsh's 18-node prism numbers its edge and
  face nodes differently from ``vtkBiQuadraticQuadraticWedge``); hexsos applies the registry's
  ``gmsh_to_vtk`` on reading and its inverse before writing. (``tetra10``, ``wedge15``, ``hexahedron20`` and
  ``hexahedron27`` meshio permutes as the registry does.)

Lagrange cells of orders 3-5: meshio names VTK's Lagrange cells by their VTK names (``VTK_LAGRANGE_TETRAHEDRON``,
``_HEXAHEDRON``, ``_WEDGE``, whatever their node count) and Gmsh's by ``tetra20``, ``hexahedron64``, ``wedge40``,
...; the registry uses the latter for both (its nodes in VTK's order, which is the Lagrange cells' order in a VTK
file). :func:`fix_read_order` renames VTK's blocks to the registry's names by node count, :func:`fix_write_order`
back. VTK 9.7 has no Lagrange pyramid class (``VTK_LAGRANGE_PYRAMID``, 74, is a type id only): a VTK file
cannot hold a pyramid of order 3 or more; :data:`VTK_LINEAR_PYRAMID_FROM` says which types the writers reduce to
their 5 corners (with a note). VTK's Lagrange hexahedron changed its node order in VTU file version 2.2 (the inner
nodes of edges 10 and 11, (2, 6) and (3, 7), exchanged); VTK's XML reader converts files of older versions. meshio
writes version 0.1 and reads the nodes as they are: so a Lagrange hexahedron goes into a version-0.1 file in the
old order (:func:`fix_write_order`) and comes out of one (``vtu_version`` below 2.2, :func:`fix_read_order`)
back in the current one; measured with VTK 9.7's reader, which then sees the registry's cell. VTK's legacy reader
does the same for files of version below 5.1: hexsos writes legacy 4.2, so the old order goes there too, and
hexsos's legacy reader (:mod:`hexsos_plugins.io.readers.legacy_vtk`, meshio reads no Lagrange cell from a legacy
file) converts by the file's version.

Imports the cells wing only; used by the readers and the writers alike.
"""

from __future__ import annotations

import contextlib
import io as _stdio
import re
import warnings as _warnings

import meshio
import numpy as np

from ..cells.elements import ELEMENTS
from ..cells.lagrange import gmsh_quad

__all__ = ["quiet_meshio", "shorten", "DIMS", "meshio_dimensions", "WEDGE_SWAP", "fix_read_order", "fix_write_order",
           "FORMAT_PACKAGES", "missing_package", "VTK_LAGRANGE_NAMES", "VTK_LINEAR_PYRAMID_FROM", "LEGACY_VTU_HEX",
           "vtu_version", "GMSH_EXTRA_2D", "LAGRANGE_2D", "vtk_quad_lattice", "lagrange_2d_block"]

#: meshio's names of VTK's Lagrange cells, by the registry's domain
VTK_LAGRANGE_NAMES = {"tet": "VTK_LAGRANGE_TETRAHEDRON", "cube": "VTK_LAGRANGE_HEXAHEDRON",
                      "prism": "VTK_LAGRANGE_WEDGE"}
_FROM_VTK_LAGRANGE = {(VTK_LAGRANGE_NAMES[el.domain], el.n_nodes): name for name, el in ELEMENTS.items()
                      if el.lagrange and el.domain in VTK_LAGRANGE_NAMES}
_TO_VTK_LAGRANGE = {name: vtk for (vtk, _), name in _FROM_VTK_LAGRANGE.items()}


def vtk_quad_lattice(q):
    """VTK's Lagrange quadrilateral of order q (lattice points, integer coordinates): corners, edges 0-1, 1-2, 3-2,
    0-3 (each from its lower end), then the inside row by row (x fastest).

    >>> vtk_quad_lattice(3)[4:]
    [(1, 0), (2, 0), (3, 1), (3, 2), (1, 3), (2, 3), (0, 1), (0, 2), (1, 1), (2, 1), (1, 2), (2, 2)]
    """
    out = [(0, 0), (q, 0), (q, q), (0, q)]
    out += [(i, 0) for i in range(1, q)] + [(q, i) for i in range(1, q)]
    out += [(i, q) for i in range(1, q)] + [(0, i) for i in range(1, q)]
    out += [(i, j) for j in range(1, q) for i in range(1, q)]
    return out


def _quad_g2v(q):
    gm = {x: k for k, x in enumerate(gmsh_quad(q))}
    return np.array([gm[x] for x in vtk_quad_lattice(q)])


#: Gmsh's complete triangles and quadrilaterals of orders 3-5 (meshio's names, Gmsh's node order, as boundary
#: blocks of curved meshes) -> VTK's Lagrange triangle and quadrilateral. Triangles: the same order (corners, edges
#: 01, 12, 20, the inner triangle recursively); quadrilaterals: the permutation Gmsh -> VTK
LAGRANGE_2D = {"triangle10": "VTK_LAGRANGE_TRIANGLE", "triangle15": "VTK_LAGRANGE_TRIANGLE",
               "triangle21": "VTK_LAGRANGE_TRIANGLE", "quad16": "VTK_LAGRANGE_QUADRILATERAL",
               "quad25": "VTK_LAGRANGE_QUADRILATERAL", "quad36": "VTK_LAGRANGE_QUADRILATERAL"}
_G2V_2D = {"quad16": _quad_g2v(3), "quad25": _quad_g2v(4), "quad36": _quad_g2v(5)}
_FROM_VTK_2D = {("VTK_LAGRANGE_TRIANGLE", 10): "triangle10", ("VTK_LAGRANGE_TRIANGLE", 15): "triangle15",
                ("VTK_LAGRANGE_TRIANGLE", 21): "triangle21", ("VTK_LAGRANGE_QUADRILATERAL", 16): "quad16",
                ("VTK_LAGRANGE_QUADRILATERAL", 25): "quad25", ("VTK_LAGRANGE_QUADRILATERAL", 36): "quad36"}


def lagrange_2d_block(vtk_name: str, data):
    """A block of VTK's Lagrange triangles or quadrilaterals (meshio's ``VTK_LAGRANGE_TRIANGLE`` /
    ``_QUADRILATERAL``) of orders 3-5 as (meshio's Gmsh name, connectivity in Gmsh's order); None for any other
    block."""
    data = np.asarray(data)
    name = _FROM_VTK_2D.get((vtk_name, data.shape[1] if data.ndim == 2 else -1))
    if name is None:
        return None
    if name in _G2V_2D:
        out = np.empty_like(data)
        out[:, _G2V_2D[name]] = data
        data = out
    return name, data


# the Lagrange types whose VTK order is not Gmsh's (meshio permutes none of them)
_LAGRANGE_G2V = {name: np.array(el.gmsh_to_vtk) for name, el in ELEMENTS.items()
                 if el.order >= 3 and list(el.gmsh_to_vtk) != list(range(el.n_nodes))}


def _legacy_hex(el):
    """The permutation exchanging the inner nodes of edges 10 and 11 of a Lagrange hexahedron (VTU < 2.2)."""
    k = el.order - 1
    perm = np.arange(el.n_nodes)
    a, b = 8 + 10 * k, 8 + 11 * k
    perm[a:a + k], perm[b:b + k] = np.arange(b, b + k), np.arange(a, a + k)
    return perm


#: per Lagrange hexahedron type, the node permutation between VTU versions < 2.2 and >= 2.2 (its own inverse)
LEGACY_VTU_HEX = {name: _legacy_hex(el) for name, el in ELEMENTS.items() if el.lagrange and el.domain == "cube"}
#: The registry's pyramids a VTK file cannot hold (order >= 3): written as linear pyramids (their 5 corners).
VTK_LINEAR_PYRAMID_FROM = tuple(name for name, el in ELEMENTS.items() if el.domain == "pyramid" and el.order >= 3)


@contextlib.contextmanager
def quiet_meshio():
    """Capture what meshio prints (it prints errors and warnings) and silence Python warnings."""
    out, err = _stdio.StringIO(), _stdio.StringIO()
    log = []
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore")
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                yield log
            finally:
                log.extend(split_messages(out.getvalue() + "\n" + err.getvalue()))


def split_messages(text: str) -> list:
    """meshio's rich console output, one message per 'Warning:' / 'Info:' / 'Error:', lines joined."""
    text = " ".join(text.split())
    if not text:
        return []
    parts = re.split(r"(?=\b(?:Warning|Info|Error):)", text)
    return [p.strip() for p in parts if p.strip()]



def shorten(msg: str, limit: int = 240) -> str:
    msg = " ".join(str(msg).split())
    return msg if len(msg) <= limit else msg[: limit - 3] + "..."



#: Gmsh's incomplete triangles and quadrilaterals of orders 3 to 5 (the boundary of its incomplete cells, see
#: :mod:`hexsos_plugins.cells.incomplete`), which meshio 5.3.5 does not know: Gmsh type -> (name, nodes). Kept as
#: blocks in Gmsh's node order (corners, then the edges' inner nodes); "quad16i" and "triangle15i" because meshio's
#: "quad16" and "triangle15" are Gmsh's complete quadrilateral of order 3 and triangle of order 4 (types 36, 23).
GMSH_EXTRA_2D = {20: ("triangle9", 9), 22: ("triangle12", 12), 24: ("triangle15i", 15), 39: ("quad12", 12),
                 40: ("quad16i", 16), 41: ("quad20", 20)}

DIMS = {"vertex": 0, "line": 1, "line3": 1, "line4": 1, "triangle": 2, "quad": 2, "polygon": 2, "triangle6": 2,
         "triangle7": 2, "quad8": 2, "quad9": 2, "quad6": 2}
DIMS.update({name: 2 for name, _ in GMSH_EXTRA_2D.values()})


def _missing_dimensions() -> dict:
    """Cell types meshio 5.3.5's format modules know but its table of topological dimensions lacks (``wedge15``,
    ``pyramid13``, ...): its CellBlock constructor raises KeyError for them, which makes meshio fail on MSH 4.1
    and VTU files holding them."""
    from meshio._mesh import topological_dimension as table

    names = set()
    with contextlib.suppress(Exception):
        from meshio._vtk_common import vtk_to_meshio_type

        names |= set(vtk_to_meshio_type.values())
    with contextlib.suppress(Exception):
        from meshio.gmsh.common import _gmsh_to_meshio_type

        names |= set(_gmsh_to_meshio_type.values())
    out = {}
    for t in names - set(table):
        if t.startswith(("tetra", "hexahedron", "wedge", "pyramid", "polyhedron")):
            out[t] = 3
        elif t.startswith(("line", "vertex")):
            out[t] = 0 if t.startswith("vertex") else 1
        else:
            out[t] = 2
    return out


@contextlib.contextmanager
def meshio_dimensions(extra=()):
    """Within: meshio's table of topological dimensions holds every cell type its formats know (and ``extra``
    names); restored afterwards."""
    from meshio._mesh import topological_dimension as table

    add = _missing_dimensions()
    for t in extra:
        if t not in table and t not in add:
            add[t] = 3 if t.startswith(("tetra", "hexahedron", "wedge", "pyramid", "polyhedron", "voxel")) \
                else DIMS.get(t, 2)
    for t, d in add.items():
        table[t] = d
    # the registry's types meshio's Gmsh tables lack (pyramids of order >= 3): their Gmsh ids and node counts
    from meshio._common import num_nodes_per_cell
    from meshio.gmsh.common import _meshio_to_gmsh_type as to_gmsh

    from meshio.gmsh.common import _gmsh_to_meshio_type as from_gmsh

    extra = {name: (g, k, 2) for g, (name, k) in GMSH_EXTRA_2D.items()}
    extra.update({name: (el.gmsh_type, el.n_nodes, 3) for name, el in ELEMENTS.items() if el.gmsh_type > 0})
    gadd = {name: v for name, v in extra.items() if name not in to_gmsh}
    fadd = {g: name for name, (g, _, _) in gadd.items() if g not in from_gmsh}
    nadd = {name: k for name, (_, k, _) in extra.items() if name not in num_nodes_per_cell}
    tadd = [name for name in gadd if name not in table]
    for name, (g, _, dim) in gadd.items():
        to_gmsh[name] = g
        table.setdefault(name, dim)
    from_gmsh.update(fadd)
    num_nodes_per_cell.update(nadd)
    try:
        yield
    finally:
        for t in add:
            table.pop(t, None)
        for t in gadd:
            to_gmsh.pop(t, None)
        for t in tadd:
            table.pop(t, None)
        for g in fadd:
            from_gmsh.pop(g, None)
        for t in nadd:
            num_nodes_per_cell.pop(t, None)



#: the packages meshio's formats import when they are used (the optional ``formats`` extra of hexsos)
FORMAT_PACKAGES = {"netCDF4": "netCDF4", "h5py": "h5py"}


def missing_package(exc: BaseException, doing: str):
    """A DependencyError naming what to install when ``exc`` is meshio failing to import a format's package, else
    None. ``doing``: what needed it ("reading Exodus")."""
    from ..errors import DependencyError

    seen, e = set(), exc
    while e is not None and id(e) not in seen:  # the import error may be the cause of what meshio raised
        seen.add(id(e))
        name = getattr(e, "name", None) if isinstance(e, ImportError) else None
        root = (name or "").split(".")[0]
        if root in FORMAT_PACKAGES:
            pkg = FORMAT_PACKAGES[root]
            return DependencyError(f"{doing} needs the Python package {pkg}, which is not installed: "
                                   f"pip install {pkg} (or pip install \"hexsos[formats]\", which [all] includes)")
        e = e.__cause__ or e.__context__
    return None


WEDGE_SWAP = np.array([0, 2, 1, 3, 5, 4])
#: Gmsh's 18-node prism to VTK's (``vtk = gmsh[:, WEDGE18_G2V]``) and back.
WEDGE18_G2V = np.array(ELEMENTS["wedge18"].gmsh_to_vtk)
WEDGE18_V2G = np.argsort(WEDGE18_G2V)
_VTK_FORMATS = ("vtk", "vtu", "vtk42", "vtk51")
_GMSH_FORMATS = ("gmsh", "gmsh22", "gmsh4", "gmsh41")


def vtu_version(path) -> tuple:
    """The ``version`` of a VTU file's ``VTKFile`` element, as a tuple ((0, 1) when it has none)."""
    with open(path, "rb") as f:
        head = f.read(4096)
    m = re.search(rb"<VTKFile[^>]*\sversion\s*=\s*[\"']([0-9]+)\.([0-9]+)", head)
    return (int(m.group(1)), int(m.group(2))) if m else (0, 1)


def _permute(mesh: meshio.Mesh, cell_type: str, perm: np.ndarray) -> None:
    for block in mesh.cells:
        if block.type == cell_type and len(block.data):
            block.data = np.ascontiguousarray(np.asarray(block.data)[:, perm])


def fix_read_order(mesh: meshio.Mesh, fmt: str, vtu_version=(0, 1)) -> meshio.Mesh:
    """Blocks of a mesh meshio just read as ``fmt``, in place, in VTK node order (see the module docstring)."""
    if fmt in _VTK_FORMATS:
        _permute(mesh, "wedge", WEDGE_SWAP)
        for block in mesh.cells:
            key = (block.type, np.shape(block.data)[1] if np.ndim(block.data) == 2 else -1)
            name = _FROM_VTK_LAGRANGE.get(key)
            if name is not None:
                block.type = name
            got = lagrange_2d_block(block.type, block.data)
            if got is not None:  # back to Gmsh's order, as the blocks of a Gmsh file are held
                block.type, block.data = got
        if fmt == "vtu" and vtu_version < (2, 2):
            for name, perm in LEGACY_VTU_HEX.items():
                _permute(mesh, name, perm)
    elif fmt in _GMSH_FORMATS:
        _permute(mesh, "wedge18", WEDGE18_G2V)
        for name, perm in _LAGRANGE_G2V.items():  # meshio keeps Gmsh's order for these
            _permute(mesh, name, perm)
    return mesh


def fix_write_order(mesh: meshio.Mesh, fmt: str) -> meshio.Mesh:
    """Blocks of a private copy (VTK node order), in place, in the order meshio's ``fmt`` writer expects so that
    the file comes out in the format's own order."""
    if fmt in _VTK_FORMATS:
        _permute(mesh, "wedge", WEDGE_SWAP)
        if fmt in ("vtu", "vtk42"):  # VTU version 0.1 and legacy 4.2 (meshio's): the Lagrange hexahedron's old
            # order, which VTK's readers convert (the swap is an involution)
            for name, perm in LEGACY_VTU_HEX.items():
                _permute(mesh, name, perm)
        for block in mesh.cells:
            if block.type in LAGRANGE_2D:
                if block.type in _G2V_2D:
                    block.data = np.asarray(block.data)[:, _G2V_2D[block.type]]
                block.type = LAGRANGE_2D[block.type]
            block.type = _TO_VTK_LAGRANGE.get(block.type, block.type)
    elif fmt in _GMSH_FORMATS:
        _permute(mesh, "wedge18", WEDGE18_V2G)
        for name, perm in _LAGRANGE_G2V.items():
            _permute(mesh, name, np.argsort(perm))
    return mesh
