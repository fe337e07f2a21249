"""The repair of curved and hex-free meshes (:mod:`hexsos_plugins.meshrepair.curved`, issue 24).

Every verdict is re-established by an independent call: the kernel (``hexsos_plugins.check``) on the file as
written, Gmsh's own ``minDetJac`` on it, the connectivity read back with meshio, the distance of boundary nodes
to the exact sphere -- never the repair's own bookkeeping.
"""

import subprocess
import sys

import meshio
import numpy as np
import pytest

import hexsos_plugins as hs
from hexsos_plugins.cells.elements import ELEMENTS
from hexsos_plugins.meshrepair import curved as cv
from conftest import tet_grid

gmsh = pytest.importorskip("gmsh")


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "hexsos_plugins", "repair", *map(str, args)], capture_output=True,
                          text=True, timeout=300)


@pytest.mark.parametrize("name", ["tetra", "tetra10", "wedge", "wedge15", "wedge18", "hexahedron20", "hexahedron27",
                                  "tetra20", "wedge40", "pyramid30", "hexahedron64", "hexahedron32"])
def test_the_optimizers_coefficients_are_the_kernels(name):
    # the barrier works on its own float coefficients: they must be det J's Bernstein coefficients, the ones the
    # kernel proves on (a wrong sample table, a transposed factor or a missed node would differ by O(1))
    rng = np.random.default_rng(3)
    R = ELEMENTS[name].reference_nodes
    P = (R[None] + 0.1 * rng.standard_normal((20, R.shape[0], 3))).reshape(-1, 3)
    conn = np.arange(P.shape[0]).reshape(20, -1)
    b = cv.fast_coefficients(P, name, conn)
    k = cv.kernel_coefficients(P, name, conn)
    assert b.shape == k.shape
    # order 3: the optimizer's float tables (collocation inverses of degree 3p - 1 = 8) are off by up to 2e-9 of the
    # largest coefficient (measured: pyramid30, hexahedron32); a wrong table is off by O(1)
    tol = 1e-9 if ELEMENTS[name].order <= 2 else 1e-7
    assert np.abs(b - k).max() <= tol * np.abs(k).max()
    assert (k.min(axis=1) < 0).any() or np.ptp(k) > 0.01  # the cells are not all the same


@pytest.mark.parametrize("name", ["tetra10", "hexahedron27"])
def test_the_barriers_gradient_is_its_derivative(name):
    rng = np.random.default_rng(4)
    R = ELEMENTS[name].reference_nodes
    P = (R[None] + 0.08 * rng.standard_normal((3, R.shape[0], 3))).reshape(-1, 3)
    conn = np.arange(P.shape[0]).reshape(3, -1)
    blocks = [(name, conn)]
    prob = cv.Problem(P, blocks, cv.cell_scales(P, blocks), [np.arange(3)], np.ones(P.shape[0], bool), None)
    y = 0.01 * rng.standard_normal(prob.ndof)
    _, g, _ = prob.energy(y, 0.1)
    for j in (0, 7, prob.ndof - 1):
        e = np.zeros(prob.ndof)
        e[j] = 1e-6
        fd = (prob.energy(y + e, 0.1, grad=False)[0] - prob.energy(y - e, 0.1, grad=False)[0]) / 2e-6
        assert g[j] == pytest.approx(fd, rel=1e-5, abs=1e-8)


def _shell(path):
    """Gmsh's own curving of a spherical shell r 0.9-1 (issue 24's input): tetra10, two cells inverted."""
    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.HighOrderOptimize", 0)
        a = gmsh.model.occ.addSphere(0, 0, 0, 1)
        b = gmsh.model.occ.addSphere(0, 0, 0, 0.9)
        gmsh.model.occ.cut([(3, a)], [(3, b)])
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.35)
        gmsh.model.mesh.generate(3)
        gmsh.model.mesh.setOrder(2)
        gmsh.model.addPhysicalGroup(3, [t for _, t in gmsh.model.getEntities(3)], 7, name="shell")
        gmsh.write(str(path))  # the physical volume's elements
    finally:
        gmsh.finalize()


def _gmsh_min_det(path):
    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        _, tags, _ = gmsh.model.mesh.getElements(3)
        return np.asarray(gmsh.model.mesh.getElementQualities(np.concatenate(tags), "minDetJac"))
    finally:
        gmsh.finalize()


def test_gmshs_inverted_curved_shell_is_repaired_certified_on_the_sphere(tmp_path):
    src, out = tmp_path / "shell.msh", tmp_path / "out.msh"
    _shell(src)
    m_in = meshio.read(src)
    P0 = m_in.points
    T0 = m_in.get_cells_type("tetra10")
    assert (_gmsh_min_det(src) <= 0).sum() >= 1  # the input is what Gmsh inverts
    before = hs.check(P0, [("tetra10", T0)])
    assert (before.status != 1).sum() >= 1

    r = _cli(src, "-o", out)
    assert r.returncode == 0, r.stderr + r.stdout
    m_out = meshio.read(out)
    # connectivity and the physical group untouched, every cell valid for the kernel and for Gmsh
    assert np.array_equal(m_out.get_cells_type("tetra10"), T0)
    assert np.array_equal(m_out.cell_data_dict["gmsh:physical"]["tetra10"],
                          m_in.cell_data_dict["gmsh:physical"]["tetra10"])
    assert set(np.unique(m_out.cell_data_dict["gmsh:physical"]["tetra10"])) == {7}
    assert (hs.check(m_out.points, [("tetra10", T0)]).status == 1).all()
    assert (_gmsh_min_det(out) > 0).all()
    moved = np.linalg.norm(m_out.points - P0, axis=1) > 0
    assert moved.any()
    # nodes on the outer sphere stay within 1e-3 of the diagonal of it (sliding within the curved faces)
    on = np.abs(np.linalg.norm(P0, axis=1) - 1.0) < 1e-9
    dist = np.abs(np.linalg.norm(m_out.points[on], axis=1) - 1.0)
    assert dist.max() <= 1e-3 * 2 * np.sqrt(3.0)


def test_a_linear_tet_mesh_with_inverted_tets_is_repaired_and_certified():
    P, T = tet_grid(3)
    P = P.copy()
    inner = np.flatnonzero(np.all((P > 0) & (P < 3), axis=1))
    P[inner[0]] += [1.6, 0.3, 0.2]  # across its neighbours: tets inverted
    before = hs.check(P, [("tetra", T)])
    assert (before.status == 0).sum() >= 2
    res = hs.repair(P, np.zeros((0, 8), dtype=np.int64), cells=[("tetra", T)])
    assert res.stats["method"] == "curved"
    assert res.success
    after = hs.check(res.points, [("tetra", T)])  # independent of the result's own certificate
    assert (after.status == 1).all()
    # boundary nodes stay on their cube faces
    for a in range(3):
        for face in (0.0, 3.0):
            on = P[:, a] == face
            assert np.all(res.points[on, a] == face)


def test_a_tet_mesh_far_from_unit_size_is_repaired_at_a_power_of_two_scale_and_certified_at_its_own():
    P, T = tet_grid(3)
    P = P.astype(np.float64)
    inner = np.flatnonzero(np.all((P > 0) & (P < 3), axis=1))
    P[inner[0]] += [1.6, 0.3, 0.2]
    for size in (1e-140, 1e140):
        res = hs.repair(P * size, np.zeros((0, 8), dtype=np.int64), cells=[("tetra", T)])
        assert res.stats["method"] == "curved" and res.stats["repair_scale"] != 1.0
        assert res.success and (hs.check(res.points, [("tetra", T)]).status == 1).all(), res.message
        assert res.stats["invalid_after"] == 0 and 0 < res.stats["max_displacement"] < 3 * size


def _one_bad_tetra10():
    el = ELEMENTS["tetra10"]
    P = el.reference_nodes.copy()
    P[4] = [0.1, 0.0, 0.0]  # the mid-node of edge 0-1 pulled to the corner: det J < 0 at corner 0, > 0 inside
    return P, np.arange(10)[None]


def test_a_mesh_that_cannot_be_repaired_exits_1_with_the_best_mesh_written(tmp_path):
    P, T = _one_bad_tetra10()
    assert hs.check(P, [("tetra10", T)]).status[0] == 0
    src, out = tmp_path / "bad.vtu", tmp_path / "out.vtu"
    meshio.write(src, meshio.Mesh(P, [("tetra10", T)]))
    # every node of a lone cell is on the boundary: fixed, nothing may move
    r = _cli(src, "-o", out, "--boundary", "fixed")
    assert r.returncode == 1, r.stderr + r.stdout
    assert "NOT every cell proven valid" in r.stdout
    written = meshio.read(out)
    assert np.array_equal(written.points, P)
    # the same mesh with a free boundary is repaired
    r = _cli(src, "-o", out, "--boundary", "free")
    assert r.returncode == 0, r.stderr + r.stdout
    written = meshio.read(out)
    assert hs.check(written.points, [("tetra10", T)]).status[0] == 1
    assert np.array_equal(written.get_cells_type("tetra10"), T)


def test_the_paraview_filter_repairs_a_curved_tet_and_says_so():
    pytest.importorskip("vtkmodules.vtkCommonDataModel")
    from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkUnstructuredGrid

    from vtk_filter import HexSOSRepairFilter

    P, T = _one_bad_tetra10()
    g = vtkUnstructuredGrid()
    pts = vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(P), deep=1))
    g.SetPoints(pts)
    g.InsertNextCell(24, 10, [int(i) for i in T[0]])  # VTK_QUADRATIC_TETRA
    f = HexSOSRepairFilter()
    f.SetInputDataObject(0, g)
    assert f.Update()
    r = f.GetResult()
    assert r.success and r.stats["method"] == "curved"
    out = f.GetOutputDataObject(0)
    new = vtk_to_numpy(out.GetPoints().GetData()).astype(np.float64)
    assert hs.check(new, [("tetra10", T)]).status[0] == 1  # the kernel again, on the filter's output
    assert vtk_to_numpy(out.GetCellData().GetArray("hexsos_status")).tolist() == [1]
    # the mid-edge node slid along its (straight) feature edge: it stays on the x axis
    assert np.all(new[4, 1:] == 0.0) and new[4, 0] > 0.1


def _cylinder_rim_patch(path):
    """Issue 24's all-hex cylinder (Gmsh: r 1, h 1, subdivision, size 0.35, order 2), cut down to the hexahedra
    around one sliver at the rim whose *corners* are folded (its straight-sided hex is inverted, det J's
    coefficients down to -21 times its largest), with two rings of cells around it. Returns (points, hex27
    connectivity, nodes on the cut faces, nodes on the exact cylinder)."""
    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.HighOrderOptimize", 0)
        gmsh.model.occ.addCylinder(0, 0, 0, 0, 0, 1, 1)
        gmsh.option.setNumber("Mesh.SubdivisionAlgorithm", 2)
        gmsh.option.setNumber("Mesh.RecombineAll", 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.35)
        gmsh.model.mesh.generate(3)
        gmsh.model.mesh.setOrder(2)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    m = hs.read(path)
    (name, C), = m.cells
    P = m.points
    H = np.ascontiguousarray(C[:, :8])
    b = cv.kernel_coefficients(P, "hexahedron", H)
    rel = b.min(axis=1) / np.abs(b).max(axis=1)
    worst = int(np.argmin(rel))
    # the worst folded hex and the folded hexes sharing a node with it (the sliver's subdivision), two rings more
    core = (rel <= 0) & np.isin(H, H[worst]).any(axis=1)
    sel = core
    for _ in range(2):
        sel = np.isin(C, C[sel]).any(axis=1)
    sub = C[sel]
    used = np.unique(sub)
    remap = np.full(P.shape[0], -1)
    remap[used] = np.arange(used.size)
    Q, T = P[used], remap[sub]
    rho = np.hypot(Q[:, 0], Q[:, 1])
    on = (np.abs(rho - 1.0) < 1e-9) | (np.abs(Q[:, 2]) < 1e-9) | (np.abs(Q[:, 2] - 1.0) < 1e-9)
    cut = (cv.curved_boundary(Q, [(name, T)]).kind >= 0) & ~on
    return Q, T, cut, on, int(core.sum())


def test_a_sliver_at_the_rim_with_folded_corners_is_untangled_on_its_straight_sided_skeleton(tmp_path):
    # Gmsh's subdivision leaves hexahedra whose corners are folded (a face collapsed to a sliver, turned inside
    # out where the rim's nodes went onto the circle); untangling them on the curved cells' 216 coefficients
    # stalls (6 of these 364 cells were left after 20 s), the skeleton stage untangles the corners first
    P, T, cut, on, n_core = _cylinder_rim_patch(tmp_path / "cylinder.msh")
    assert n_core >= 2
    from hexsos_plugins.meshrepair import skeleton as sk

    lin = sk.linear_blocks([("hexahedron27", T)])
    assert sk.folded_cells(P, lin, cv.cell_scales(P, lin))[0].sum() >= n_core  # the straight-sided hexes fold
    before = hs.check(P, [("hexahedron27", T)])
    assert (before.status == 0).sum() >= n_core
    res = hs.repair(P, np.zeros((0, 8), dtype=np.int64), cells=[("hexahedron27", T)], pinned=cut, time_limit=60)
    assert res.success, res.message
    assert "skeleton" in res.stats["stage_seconds"]
    after = hs.check(res.points, [("hexahedron27", T)])  # the kernel again, independently of the result
    assert (after.status == 1).all()
    assert np.array_equal(res.points[cut], P[cut])  # the cut faces were pinned
    # nodes on the exact cylinder stay within 1e-3 of the diagonal of it (they slid within the curved faces)
    X = res.points[on]
    rho = np.hypot(X[:, 0], X[:, 1])
    dist = np.minimum(np.abs(rho - 1.0), np.minimum(np.abs(X[:, 2]), np.abs(X[:, 2] - 1.0)))
    assert dist.max() <= 1e-3 * np.sqrt(9.0)
    assert np.abs(res.points - P).max() > 0


def test_the_skeleton_puts_high_order_nodes_back_on_moved_corners_with_their_curving():
    from hexsos_plugins.meshrepair import skeleton as sk

    el = ELEMENTS["hexahedron27"]
    R = el.reference_nodes
    P0 = np.concatenate([R, R + [1.0, 0.0, 0.0]])
    C = np.arange(54).reshape(2, 27)
    P0[C[0, 8]] += [0.0, -0.05, 0.0]  # curving of one edge node of the first cell
    V = P0.copy()
    V[C[1, 1]] += [0.1, 0.2, 0.0]  # a corner of the second cell only
    moved = np.zeros(54, dtype=bool)
    moved[C[1, 1]] = True
    W = sk.place_high_order(V, P0, [("hexahedron27", C)], moved)
    S = sk.straight_points(V, [("hexahedron27", C)])
    assert np.allclose(W[C[1, 8:]], S[C[1, 8:]])  # the moved cell: straight-sided on its new corners
    assert np.array_equal(W[C[0]], P0[C[0]])  # the other cell and its curving untouched
    assert not np.allclose(W[C[1, 8:]], P0[C[1, 8:]])  # (a node of the moved cell did move)
    moved0 = np.zeros(54, dtype=bool)
    moved0[C[0, 0]] = True
    W0 = sk.place_high_order(V, P0, [("hexahedron27", C)], moved0)
    assert np.allclose(W0[C[0, 8]], S[C[0, 8]] + [0.0, -0.05, 0.0])  # the curving carried over
    pin = np.zeros(54, dtype=bool)
    pin[C[0, 8]] = True
    Wp = sk.place_high_order(V, P0, [("hexahedron27", C)], moved0, pin=pin)
    assert np.array_equal(Wp[C[0, 8]], V[C[0, 8]])  # a pinned node stays


_LAZY_CURVED_LOOPS = """
import json, sys
import numpy as np
sys.path.insert(0, "tests")
import hexsos_plugins.meshrepair.curvedkernels as ck
ck.load = lambda: None  # lazily compiled: each loop gets the types the curved repair really calls it with
import hexsos_plugins as hs
from conftest import tet_grid
from test_curved_repair import _one_bad_tetra10

P, T = tet_grid(3)
P[np.flatnonzero(np.all((P > 0) & (P < 3), axis=1))[0]] += [1.6, 0.3, 0.2]
assert hs.repair(P, np.zeros((0, 8), dtype=np.int64), cells=[("tetra", T)]).success
P, T = _one_bad_tetra10()
T = np.array(T)
T.flags.writeable = False  # as hexsos_plugins.read gives the connectivity: a read-only array
assert hs.repair(P, np.zeros((0, 8), dtype=np.int64), cells=[("tetra10", T)], boundary="free").success
print(json.dumps({name: [[str(t) for t in s] for s in getattr(ck, name).signatures] for name in ck.SIGNATURES}))
"""


def test_the_curved_loops_loaded_before_the_clock_are_the_ones_the_repair_calls():
    """``curvedkernels.load`` compiles (or loads) each loop for :data:`curvedkernels.SIGNATURES` before the curved
    repair's clock starts; in a fresh process where it does nothing, curved repairs (linear tetrahedra, a tetra10
    with a read-only connectivity) call every loop with exactly those types and no other (without the repair's
    private copy of the connectivity, the read-only one compiles both loops a second time)."""
    import json
    import os

    from hexsos_plugins.meshrepair import curvedkernels as ck

    out = subprocess.run([sys.executable, "-c", _LAZY_CURVED_LOOPS], capture_output=True, text=True, timeout=600,
                         cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    assert out.returncode == 0, out.stderr[-2000:]
    called = json.loads(out.stdout.strip().splitlines()[-1])
    for name, sig in ck.SIGNATURES.items():
        assert called[name] == [[str(t) for t in sig]], (name, called[name])


def test_the_curved_repairs_clock_starts_after_its_loops_are_loaded(monkeypatch):
    """A first compilation does not eat the curved repair's time limit: with a load of 3 s and a time limit of
    1 s, the tetrahedra are still untangled and certified (a clock started before the load would find its
    deadline gone before the first step), and ``stats`` says how long the load took."""
    import time as _time

    from hexsos_plugins.meshrepair import curvedkernels as ck

    real = ck.load

    def slow_load():
        real()
        _time.sleep(3.0)

    monkeypatch.setattr(ck, "load", slow_load)
    P, T = tet_grid(3)
    P[np.flatnonzero(np.all((P > 0) & (P < 3), axis=1))[0]] += [1.6, 0.3, 0.2]
    r = hs.repair(P, np.zeros((0, 8), dtype=np.int64), cells=[("tetra", T)], time_limit=1.0)
    assert r.stats["method"] == "curved" and r.stats["invalid_before"] >= 2
    assert r.success and (hs.check(r.points, [("tetra", T)]).status == 1).all()
    assert r.stats["load_seconds"] >= 3.0 and r.stats["seconds"] < r.stats["load_seconds"]


@pytest.mark.parametrize("first", [True, False])
def test_cli_says_when_the_curved_repair_compiles_its_loops(tmp_path, capsys, monkeypatch, first):
    """``hexsos repair`` on a curved mesh says on stderr that the curved repair's loops compile once, exactly when
    they would (asked of :mod:`curvedkernels`, not of the hexahedral repair's loops)."""
    from hexsos_plugins.cli import main
    from hexsos_plugins.meshrepair import curvedkernels as ck
    from hexsos_plugins.meshrepair import kernels as lo

    monkeypatch.setattr(ck, "compiles_at_first_use", lambda: first)
    monkeypatch.setattr(lo, "compiles_at_first_use", lambda: not first)
    P, T = _one_bad_tetra10()
    src, out = tmp_path / "in.vtu", tmp_path / "out.vtu"
    meshio.write(str(src), meshio.Mesh(P, [("tetra10", T)]))
    rc = main(["repair", str(src), "-o", str(out), "--boundary", "free", "--no-progress", "--no-fidelity"])
    err = capsys.readouterr().err
    assert rc == 0
    assert ("compiling the repair's loops, once" in err) == first, err
