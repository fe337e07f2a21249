"""Gmsh's complete triangles and quadrilaterals of orders 3-5 (the boundary blocks of curved Gmsh meshes) in VTK
files: written as VTK's Lagrange triangle and quadrilateral, verified by VTK's own cells at parametric points, and
read back in Gmsh's order. A quadrilateral written without the permutation (two nodes exchanged) is caught."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

from hexsos_plugins.io import read
from hexsos_plugins.io.writers import write

gmsh = pytest.importorskip("gmsh")
vtk = pytest.importorskip("vtk")

# meshio's name -> (Gmsh type, order, quadrilateral)
TYPES = {"triangle10": (21, 3, False), "triangle15": (23, 4, False), "triangle21": (25, 5, False),
         "quad16": (36, 3, True), "quad25": (37, 4, True), "quad36": (38, 5, True)}


def _gmsh_nodes(gtype):
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        return np.asarray(gmsh.model.mesh.getElementProperties(gtype)[4], dtype=np.float64).reshape(-1, 2)
    finally:
        gmsh.finalize()


def _map(uv):
    """A curved map of degree 2 (exact in every cell of order >= 2), from the unit square / triangle."""
    u, v = uv[:, 0], uv[:, 1]
    return np.stack([u + 0.15 * v * v, v + 0.1 * u * v, 0.2 * u * u - 0.1 * v], axis=1)


def _unit(name, local):
    # Gmsh's quadrilateral lives on [-1, 1]^2, its triangle on the unit triangle; VTK's on [0, 1]^2 and the unit
    # triangle
    return (local + 1.0) / 2.0 if TYPES[name][2] else local


def _vtk_positions(path, pc):
    r = vtk.vtkXMLUnstructuredGridReader() if str(path).endswith(".vtu") else vtk.vtkUnstructuredGridReader()
    r.SetFileName(str(path))
    r.Update()
    cell = r.GetOutput().GetCell(0)
    out = []
    for p in pc:
        x, w = [0.0] * 3, [0.0] * cell.GetNumberOfPoints()
        cell.EvaluateLocation(vtk.reference(0), [float(p[0]), float(p[1]), 0.0], x, w)
        out.append(x)
    return cell.GetCellType(), np.array(out)


@pytest.mark.parametrize("name", list(TYPES))
def test_gmsh_2d_lagrange_cells_go_to_vtk_as_vtks_lagrange_cells(tmp_path, name):
    gtype, p, quad = TYPES[name]
    local = _gmsh_nodes(gtype)
    X = _map(_unit(name, local))
    conn = np.arange(len(X))[None]
    rng = np.random.default_rng(p)
    pc = rng.random((12, 2))
    if not quad:
        pc = pc[pc.sum(axis=1) <= 1.0]
    path = tmp_path / f"{name}.vtu"
    tet = np.eye(4, 3) + 2.0  # a tetrahedron beside it: hexsos reads files with 3-D cells
    write(meshio.Mesh(np.vstack([X, tet]), [(name, conn), ("tetra", len(X) + np.arange(4)[None])]), path)
    ctype, pos = _vtk_positions(path, pc)
    assert ctype == (vtk.VTK_LAGRANGE_QUADRILATERAL if quad else vtk.VTK_LAGRANGE_TRIANGLE)
    assert np.abs(pos - _map(pc)).max() < 1e-12
    # read back, from .vtu and from legacy .vtk (hexsos' own reader: meshio reads no Lagrange cell there): Gmsh's
    # order and name again
    legacy = tmp_path / f"{name}.vtk"
    write(meshio.Mesh(np.vstack([X, tet]), [(name, conn), ("tetra", len(X) + np.arange(4)[None])]), legacy)
    assert np.abs(_vtk_positions(legacy, pc)[1] - _map(pc)).max() < 1e-12  # VTK's legacy reader: the same cell
    for f in (path, legacy):
        m = read(f)
        block = [b for b in m.source.cells if b.type == name]
        assert len(block) == 1 and np.array_equal(np.asarray(block[0].data), conn), f
        assert np.allclose(m.points[: len(X)], X)
    # two inner (edge or face) nodes exchanged: VTK sees another cell
    Y = X.copy()
    Y[[len(X) - 1, len(X) - 2]] = Y[[len(X) - 2, len(X) - 1]]
    bad = tmp_path / f"{name}_bad.vtu"
    write(meshio.Mesh(np.vstack([Y, tet]), [(name, conn), ("tetra", len(X) + np.arange(4)[None])]), bad)
    assert np.abs(_vtk_positions(bad, pc)[1] - _map(pc)).max() > 1e-4


def test_a_curved_gmsh_mesh_with_its_boundary_groups_converts_to_vtu(tmp_path):
    # Gmsh's order-3 mixed mesh with a physical group on its bottom (complete triangles and quadrilaterals of
    # order 3 there): the check writes every block, the boundary as VTK's Lagrange cells ("writing VTK XML (vtu)
    # failed: 'quad16'" before)
    import subprocess
    import sys

    from comparison.curved_mixed import write_mixed

    src, out = tmp_path / "m.msh", tmp_path / "out.vtu"
    write_mixed(str(src), 3, noise=0.04, incomplete=False, bottom=True)
    p = subprocess.run([sys.executable, "-m", "hexsos_plugins", "check", str(src), "-o", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode in (0, 1), p.stderr
    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(out))
    r.Update()
    types = {r.GetOutput().GetCellType(i) for i in range(r.GetOutput().GetNumberOfCells())}
    assert {vtk.VTK_LAGRANGE_QUADRILATERAL, vtk.VTK_LAGRANGE_TRIANGLE, vtk.VTK_LAGRANGE_HEXAHEDRON} <= types


def test_a_format_without_the_cell_type_says_which_type(tmp_path):
    from hexsos_plugins.errors import MeshWriteError

    X = _map(_unit("quad16", _gmsh_nodes(36)))
    mesh = meshio.Mesh(np.vstack([X, np.eye(4, 3) + 2.0]), [("quad16", np.arange(16)[None]),
                                                            ("tetra", 16 + np.arange(4)[None])])
    with pytest.raises(MeshWriteError, match="XDMF holds no cells of type 'quad16'.*Gmsh MSH"):
        write(mesh, tmp_path / "m.xdmf")
    assert not (tmp_path / "m.xdmf").exists()


def test_a_legacy_lagrange_quadrilateral_of_no_known_order_is_refused(tmp_path):
    # VTK's Lagrange quadrilateral (70) with 5 nodes is no order's: the reader says so, naming the cell
    from hexsos_plugins.errors import HexsosError

    pts = "\n".join(f"{x} {y} {z}" for x, y, z in [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0)])
    for nodes, ok in (("5 0 1 4 2 3", False), ("4 0 1 4 2", True)):
        f = tmp_path / f"q{ok}.vtk"
        f.write_text("# vtk DataFile Version 4.2\nq\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 5 double\n" + pts
                     + f"\nCELLS 2 {5 + len(nodes.split())}\n4 0 1 2 3\n{nodes}\nCELL_TYPES 2\n10\n"
                     + ("9" if ok else "70") + "\n")
        if ok:  # the same file with a linear quadrilateral reads (the check can pass)
            assert read(f).n_cells == 1
        else:
            with pytest.raises(HexsosError, match="cell 1 has VTK cell type 70 .*quadrilateral.* with 5 nodes"):
                read(f)
