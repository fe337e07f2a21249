"""Node orders, verified by building each cell in Gmsh and in VTK: the registry's VTK order and parametric
coordinates, its ``gmsh_to_vtk`` permutations and ``gmsh_factor`` values, the mirror permutations, and the wedge
convention (VTK's code calls the wedge at its parametric coordinates valid; meshio and Gmsh swap it in VTK files).

Each check has a case that must fail: a wrong permutation (two nodes exchanged) is detected for every type.
"""

from __future__ import annotations

import numpy as np
import pytest

from hexsos_plugins.cells.elements import ELEMENTS
from hexsos_plugins.io.mesh import FACE_NODES, MIRROR, Mesh

gmsh = pytest.importorskip("gmsh")
vtk = pytest.importorskip("vtk")

from comparison.against_gmsh import gmsh_local  # noqa: E402
from test_readers import KINDS, VTK_CELLS, sample_points, vtk_det, write_gmsh_meshes  # noqa: E402


def one_gmsh_cell(el, seed):
    """One cell of el's Gmsh type, its nodes Gmsh's reference nodes moved by seeded noise; returns the Gmsh-order
    coordinates and Gmsh's positions and det J at sample points (in Gmsh's reference coordinates)."""
    rng = np.random.default_rng(seed)
    pc = sample_points(el, 12, seed)
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(el.name)
        tag = gmsh.model.addDiscreteEntity(3)
        ref = np.asarray(gmsh.model.mesh.getElementProperties(el.gmsh_type)[4]).reshape(-1, 3)
        X = ref + 0.08 * rng.standard_normal(ref.shape)
        n = len(X)
        gmsh.model.mesh.addNodes(3, tag, list(range(1, n + 1)), X.ravel().tolist())
        gmsh.model.mesh.addElements(3, tag, [el.gmsh_type], [[1]], [list(range(1, n + 1))])
        _, dets, coord = gmsh.model.mesh.getJacobians(el.gmsh_type, gmsh_local(el, pc).ravel().tolist(), tag=tag)
        mindet = gmsh.model.mesh.getElementQualities([1], "minDetJac")[0]
    finally:
        gmsh.finalize()
    return X, pc, np.asarray(coord).reshape(-1, 3), np.asarray(dets), mindet


def vtk_positions(name, X, pc):
    cell = getattr(vtk, VTK_CELLS[name])()
    out = []
    for p in pc:
        x, w = [0.0] * 3, [0.0] * len(X)
        # EvaluateLocation reads the cell's points: set them
        cell.GetPoints().SetNumberOfPoints(len(X))
        for i, xi in enumerate(X):
            cell.GetPoints().SetPoint(i, *xi)
            cell.GetPointIds().SetId(i, i)
        cell.EvaluateLocation(vtk.reference(0), list(map(float, p)), x, w)
        out.append(x)
    return np.array(out), cell


QUADRATIC_PYRAMIDS = ("pyramid13", "pyramid14")


@pytest.mark.parametrize("name", [n for n, el in ELEMENTS.items() if el.order <= 2])  # 3-5: test_curved.py
def test_gmsh_to_vtk_and_the_registry_agree_with_gmsh_and_vtk(name):
    """A cell built in Gmsh, taken through gmsh_to_vtk: the registry's shape functions put every sample point where
    Gmsh's and VTK's do, det J is VTK's (InterpolateDerivs; pyramids: ours is VTK's / (1 - t)^2) and Gmsh's times
    1 / gmsh_factor, and Gmsh's minDetJac is our minimum times gmsh_factor. The quadratic pyramids follow Gmsh (VTK
    has no 14-node pyramid; its 13-node one is compared in the next test); Gmsh's minDetJac is no bound for them
    (experiment 8 measures it)."""
    el = ELEMENTS[name]
    X, pc, g_pos, g_det, g_min = one_gmsh_cell(el, seed=len(name))
    V = X[list(el.gmsh_to_vtk)]
    ours = el.shape_functions(pc) @ V
    assert np.allclose(ours, g_pos, atol=1e-12)
    d = el.det(V, pc)[0]
    assert np.allclose(g_det, d * el.gmsh_factor, rtol=1e-10)
    if name not in QUADRATIC_PYRAMIDS:
        v_pos, cell = vtk_positions(name, V, pc)
        assert np.allclose(ours, v_pos, atol=1e-12)
        dv = vtk_det(cell, V, pc)
        if el.domain == "pyramid":
            dv = dv / (1 - pc[:, 2]) ** 2
        assert np.allclose(d, dv, rtol=1e-10)
        grid = np.linspace(0, 1, 31)
        P = np.array(np.meshgrid(grid, grid, grid, indexing="ij")).reshape(3, -1).T
        P = P[{"cube": np.ones(len(P), bool), "tet": P.sum(1) <= 1, "prism": P[:, 0] + P[:, 1] <= 1,
               "pyramid": P[:, 2] < 1}[el.domain]]
        dense_min = el.det(V, P)[0].min()
        assert g_min <= dense_min * el.gmsh_factor * (1 + 1e-9) + 1e-12  # Gmsh's bound is a lower bound ...
        assert g_min >= dense_min * el.gmsh_factor - 2e-3 * abs(el.det(V, P)[0]).max() * el.gmsh_factor  # ... to 1e-3
    # negative case: exchanging two nodes (the first two mid-edge nodes, or two corners) moves the geometry
    k = el.corners if el.n_nodes >= el.corners + 2 else 0
    wrong = list(el.gmsh_to_vtk)
    wrong[k], wrong[k + 1] = wrong[k + 1], wrong[k]
    assert not np.allclose(el.shape_functions(pc) @ X[wrong], g_pos, atol=1e-6)


def test_vtk_13_node_pyramid_agrees_on_every_face_and_differs_inside():
    """vtkQuadraticPyramid and the registry's (Gmsh's) 13-node pyramid: the same nodes at the same parametric
    coordinates, the same points on all five faces, different points inside (VTK's functions leave the pyramid
    space: see hexsos_plugins.cells.elements)."""
    el = ELEMENTS["pyramid13"]
    cell = vtk.vtkQuadraticPyramid()
    pcoords = np.array([cell.GetParametricCoords()[i] for i in range(39)]).reshape(13, 3)
    assert np.array_equal(pcoords, el.reference_nodes)
    rng = np.random.default_rng(7)
    X = el.reference_nodes + 0.1 * rng.standard_normal((13, 3))
    u = rng.uniform(0.05, 0.95, (20, 3))
    faces = [np.c_[u[:, 0], u[:, 1], 0 * u[:, 0]], np.c_[u[:, 0], 0 * u[:, 0], u[:, 2]],
             np.c_[1 + 0 * u[:, 0], u[:, 1], u[:, 2]], np.c_[u[:, 0], 1 + 0 * u[:, 0], u[:, 2]],
             np.c_[0 * u[:, 0], u[:, 1], u[:, 2]]]
    for pc in faces:
        v_pos, _ = vtk_positions("pyramid13", X, pc)
        assert np.allclose(el.shape_functions(pc) @ X, v_pos, atol=1e-12)
    v_pos, _ = vtk_positions("pyramid13", X, u)
    assert np.abs(el.shape_functions(u) @ X - v_pos).max() > 1e-3


def test_pyramid13_order_of_meshio_matches_vtk():
    """The 13-node pyramid is not checked, but written to VTK files: meshio's Gmsh permutation of it puts every node
    where vtkQuadraticPyramid expects it (positions at VTK's node parametric coordinates)."""
    from meshio.gmsh.common import _gmsh_to_meshio_order

    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        ref = np.asarray(gmsh.model.mesh.getElementProperties(19)[4]).reshape(-1, 3)  # Gmsh's 13-node pyramid
    finally:
        gmsh.finalize()
    vtk_order = np.asarray(_gmsh_to_meshio_order("pyramid13", np.arange(13)[None]))[0]
    cell = vtk.vtkQuadraticPyramid()
    pcoords = np.array([cell.GetParametricCoords()[i] for i in range(39)]).reshape(13, 3)
    el = ELEMENTS["pyramid"]
    want = gmsh_local(el, pcoords)  # VTK node k's position in Gmsh's reference pyramid
    assert np.allclose(ref[vtk_order], want, atol=1e-12)
    # negative case: Gmsh's own numbering is not VTK's
    assert not np.allclose(ref, want, atol=1e-6)


@pytest.mark.parametrize("name", [n for n, el in ELEMENTS.items() if el.order <= 2])  # 3-5: test_curved.py
def test_mirror_permutations_invert_and_are_involutions(name):
    el = ELEMENTS[name]
    X = el.reference_nodes.copy()
    if el.domain == "pyramid":
        X[4] = [0.5, 0.5, 1.0]  # the apex over the base's centre
    pc = sample_points(el)
    d = el.det(X, pc)[0]
    dm = el.det(X[MIRROR[name]], pc)[0]
    assert (d > 0).all() and np.allclose(dm, -d)
    assert np.array_equal(MIRROR[name][MIRROR[name]], np.arange(el.n_nodes))
    # the face nodes of the registry faces lie on them: every node of a face but its corners is off the corners
    for face, nodes in zip(el.faces, FACE_NODES[name]):
        assert nodes[: len(face)] == tuple(face) and len(set(nodes)) == len(nodes)
    # negative case: another relabelling is not a mirror (a 3-cycle of a simplex's corners, a transposition of
    # two corners of the others)
    bad = np.arange(el.n_nodes)
    if el.domain == "tet":
        bad[:3] = [1, 2, 0]
    else:
        bad[0], bad[1] = 1, 0
    assert not np.allclose(el.det(X[bad], pc)[0], -d)


def test_vtk_calls_the_wedge_at_its_parametric_coordinates_valid():
    """The wedge convention, measured with VTK itself: nodes at vtkWedge's parametric coordinates (triangle 0-1-2
    counter-clockwise seen from 3-4-5, Gmsh's prism) have positive volume and pass vtkCellValidator; the order
    meshio and Gmsh write into VTK files (nodes 1<->2, 4<->5 swapped) has negative volume and fails it."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    el = ELEMENTS["wedge"]
    cell = vtk.vtkWedge()
    pcoords = np.array([cell.GetParametricCoords()[i] for i in range(18)]).reshape(6, 3)
    assert np.array_equal(pcoords, el.reference_nodes)

    def quality(order):
        grid = vtk.vtkUnstructuredGrid()
        pts = vtk.vtkPoints()
        for p in el.reference_nodes:
            pts.InsertNextPoint(*p)
        grid.SetPoints(pts)
        grid.InsertNextCell(13, 6, [int(i) for i in order])
        q = vtk.vtkMeshQuality()
        q.SetInputData(grid)
        q.SetWedgeQualityMeasureToVolume()
        q.Update()
        v = vtk_to_numpy(q.GetOutput().GetCellData().GetArray("Quality"))[0]
        c = vtk.vtkCellValidator()
        c.SetInputData(grid)
        c.Update()
        return v, int(vtk_to_numpy(c.GetOutput().GetCellData().GetArray("ValidityState"))[0])

    vol, state = quality(range(6))
    assert vol > 0 and state == 0
    vol, state = quality([0, 2, 1, 3, 5, 4])
    assert vol < 0 and state != 0
    assert Mesh.from_cells(el.reference_nodes, [("wedge", [list(range(6))])]).orientation() == "right-handed"


@pytest.fixture(scope="module")
def gm(tmp_path_factory):
    return write_gmsh_meshes(str(tmp_path_factory.mktemp("orders")))


@pytest.mark.parametrize("kind", list(KINDS))
def test_gmsh_made_meshes_read_with_gmshs_own_det(gm, kind):
    """Every checked cell of Gmsh-made meshes, read through hexsos: det J at sample points equals Gmsh's own
    (getJacobians on Gmsh's model of the same file) divided by gmsh_factor."""
    import hexsos_plugins.io as hio

    m = hio.read(gm[kind]["41b"])
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(gm[kind]["41b"])
        for t, conn in m.cells:
            el = ELEMENTS[t]
            pc = sample_points(el, 4)
            tags, nodes = gmsh.model.mesh.getElementsByType(el.gmsh_type)
            gconn = (np.asarray(nodes, dtype=np.int64).reshape(len(tags), -1) - 1)[:, list(el.gmsh_to_vtk)]
            ours = el.det(m.points[conn], pc)
            rows = {tuple(r): i for i, r in enumerate(gconn.tolist())}
            idx = [rows[tuple(r)] for r in conn.tolist()]
            _, dets, _ = gmsh.model.mesh.getJacobians(el.gmsh_type, gmsh_local(el, pc).ravel().tolist())
            theirs = np.asarray(dets).reshape(len(tags), len(pc))[idx] / el.gmsh_factor
            assert np.allclose(ours, theirs, rtol=1e-9, atol=1e-12), t
            assert (ours > 0).all() or t in ("pyramid13", "pyramid14"), t  # Gmsh folds some of its order-2 pyramids
    finally:
        gmsh.finalize()
