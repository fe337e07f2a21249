"""Curved cells of orders 3-5 (complete Lagrange tetrahedra, hexahedra, wedges; pyramids in Bergot's space): node
orders verified against Gmsh (``getElementProperties``, ``getJacobians``) and VTK (``vtkLagrange*``:
parametric coordinates, ``EvaluateLocation``, ``InterpolateDerivs``), and the kernel's verdicts: the reference cell
(det J = 1), its mirror, a flat cell, a cell valid at every node but invalid inside, random perturbed cells against
VTK's and Gmsh's det J, exact arithmetic on adversarial cells.

Orders 3 and 4 run here; order 5 only where it is cheap (node orders, the reference cell); the rest of order 5 in
``python -m comparison.curved``.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

import exact_reference as ref
from hexsos_plugins import check, kernel
from hexsos_plugins.cells import lagrange
from hexsos_plugins.cells.elements import ELEMENTS
from hexsos_plugins.cells.jacobian import factor_tables
from hexsos_plugins.io.mesh import MIRROR

gmsh = pytest.importorskip("gmsh")
vtk = pytest.importorskip("vtk")

from comparison import lagrange_oracle as LO  # noqa: E402

ALL = [row[0] for row in lagrange.TYPES]
FAST = [n for n in ALL if ELEMENTS[n].order <= 4]
THREE = [n for n in ALL if ELEMENTS[n].order == 3]
VTK_TYPES = [n for n in ALL if ELEMENTS[n].domain != "pyramid"]
GMSH_TYPES = [n for n in ALL if LO.gmsh_can_evaluate(n)]


def _run(name, X):
    X = np.asarray(X, float)
    if X.ndim == 2:
        X = X[None]
    conn = np.arange(X.shape[0] * X.shape[1]).reshape(X.shape[0], -1)
    return check(X.reshape(-1, 3), [(name, conn)])


def _perturbed(name, m, seed, sigma=None):
    el = ELEMENTS[name]
    rng = np.random.default_rng(seed)
    sigma = 0.08 / el.order ** 2 if sigma is None else sigma
    X0 = LO.reference_cell(name)
    return X0[None] + sigma * rng.standard_normal((m,) + X0.shape)


# --- node orders --------------------------------------------------------------------------------------------------
def test_the_generators_reproduce_the_hand_written_quadratic_orders():
    """At order 2 the generated orders are the registry's hand-written ones, which test_node_orders checks against
    Gmsh and VTK: the same nodes in VTK's order and the same gmsh_to_vtk."""
    for name, dom in (("tetra10", "tet"), ("hexahedron27", "cube"), ("wedge18", "prism")):
        el = ELEMENTS[name]
        assert lagrange.reference_nodes(dom, 2, "vtk") == el.nodes, name
        gm = lagrange.reference_nodes(dom, 2, "gmsh")
        assert tuple(gm.index(x) for x in el.nodes) == tuple(el.gmsh_to_vtk), name
    assert lagrange.reference_nodes("pyramid", 2) == ELEMENTS["pyramid14"].nodes
    # a wrong rule is seen: VTK's hexahedron edges in Gmsh's order differ
    assert lagrange.reference_nodes("cube", 2, "gmsh") != ELEMENTS["hexahedron27"].nodes


@pytest.mark.parametrize("name", [n for n in ALL if ELEMENTS[n].domain != "prism"])
def test_gmsh_builds_our_nodes_in_gmsh_order(name):
    """Gmsh's reference nodes of the type (getElementProperties), mapped to VTK's parametric coordinates, are the
    registry's nodes taken through gmsh_to_vtk."""
    from comparison.against_gmsh import gmsh_local

    el = ELEMENTS[name]
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        loc = np.asarray(gmsh.model.mesh.getElementProperties(el.gmsh_type)[4]).reshape(-1, 3)
    finally:
        gmsh.finalize()
    ours = gmsh_local(el, el.reference_nodes)  # Gmsh's coordinates of our nodes, VTK order
    assert np.allclose(loc[list(el.gmsh_to_vtk)], ours, atol=1e-12)
    swapped = list(el.gmsh_to_vtk)
    swapped[-1], swapped[-2] = swapped[-2], swapped[-1]
    assert not np.allclose(loc[swapped], ours, atol=1e-12)


def test_gmsh_cannot_build_prisms_of_order_three():
    """Gmsh 4.15 has no prism of order >= 3 (its node order is then Gmsh's source's, gmshGenerateMonomialsPrism);
    if a Gmsh gains them, this test says so, and the prisms join the test above."""
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        with pytest.raises(Exception, match="FaceClosureFull"):
            gmsh.model.mesh.getElementProperties(ELEMENTS["wedge40"].gmsh_type)
    finally:
        gmsh.finalize()


@pytest.mark.parametrize("name", VTK_TYPES)
def test_vtk_lagrange_cells_have_our_nodes_positions_and_det(name):
    """VTK's Lagrange cell of the type: its parametric coordinates are the registry's nodes; on a perturbed cell
    EvaluateLocation puts every sample point where our shape functions do and InterpolateDerivs gives our det J.
    Two nodes exchanged: the positions differ."""
    el = ELEMENTS[name]
    assert np.allclose(LO.vtk_parametric_coords(name), el.reference_nodes, rtol=0, atol=1e-15)
    X = _perturbed(name, 1, 7)[0]
    pc = LO.domain_points(name, 12, seed=3)
    c = LO.vtk_cell(name)
    for i, x in enumerate(X):
        c.GetPoints().SetPoint(i, *x)
    pos = []
    for p in pc:
        x, w = [0.0] * 3, [0.0] * len(X)
        c.EvaluateLocation(vtk.reference(0), list(map(float, p)), x, w)
        pos.append(x)
    ours = el.shape_functions(pc) @ X
    assert np.allclose(ours, pos, atol=1e-9)
    # (order 5: the registry's float evaluator, in monomial form, keeps about 8 digits)
    assert np.allclose(el.det(X, pc)[0], LO.vtk_det(name, X[None], pc)[0], rtol=1e-6 if el.order == 5 else 1e-8)
    Y = X.copy()
    Y[[-1, -2]] = Y[[-2, -1]]
    assert not np.allclose(el.shape_functions(pc) @ Y, pos, atol=1e-9)


@pytest.mark.parametrize("name", [n for n in GMSH_TYPES if ELEMENTS[n].order <= 4])
def test_gmsh_jacobians_are_ours(name):
    """Gmsh's getJacobians on perturbed cells given in Gmsh's order is our det J (its units: gmsh_factor)."""
    el = ELEMENTS[name]
    X = _perturbed(name, 3, 11)
    pc = LO.domain_points(name, 10, seed=5)
    assert np.allclose(LO.gmsh_det(name, X, pc), el.det(X, pc), rtol=1e-8, atol=1e-9)


# --- the tables ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind,p", [("line", 5), ("tri", 4), ("tet", 3), ("tet", 2)])
def test_direct_factor_tables_are_the_inverse_ones(kind, p):
    """The closed-form child matrices and monomial matrix (used for factors of any degree) are exactly the ones
    obtained by inverting the Vandermonde matrix."""
    a, b = factor_tables(kind, p, direct=False), factor_tables(kind, p, direct=True)
    assert [s for s, _, _ in a["children"]] == [s for s, _, _ in b["children"]]
    assert a["M"] == b["M"]


@pytest.mark.parametrize("name", ["tetra20", "wedge40"])
def test_coefficients_lie_within_their_rounding_bound(name):
    """|b - b_exact| <= err for every Bernstein coefficient, b_exact from the independent exact reference (det J at
    the grid, exact collocation), on perturbed and adversarial cells (tiny, huge, far from the origin, nearly
    flat)."""
    X0 = _perturbed(name, 2, 21)
    cells = list(X0) + [X0[0] * 1e-150, X0[0] * 1e150, X0[0] + 1e6, X0[0] * np.array([1.0, 1.0, 1e-12])]
    for X in cells:
        conn = np.arange(len(X))[None]
        b, err, k, _ = kernel.coefficients(X, conn, [0], name)
        exact = ref.exact_coefficients(X, name)
        scale = Fraction(2) ** (-3 * int(k[0]))
        worst = max(abs(Fraction(float(bj)) - e * scale) for bj, e in zip(b[0], exact))
        assert worst <= Fraction(float(err[0])), (name, float(worst), float(err[0]))


# --- verdicts -----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ALL)
def test_reference_cell_is_valid_with_constant_det_and_its_mirror_invalid(name):
    X = LO.reference_cell(name)
    r = _run(name, X)
    assert r.status[0] == 1 and abs(r.min_det[0] - 1) < 1e-12 and abs(r.lower_bound[0] - 1) < 1e-7
    m = _run(name, X[MIRROR[name]])
    assert m.status[0] == 0 and abs(m.min_det[0] + 1) < 1e-12


@pytest.mark.parametrize("name", THREE)
def test_flat_cell_is_undecided(name):
    X = LO.reference_cell(name)
    X[:, 2] = 0.0
    r = _run(name, X)
    assert r.status[0] == -1 and r.min_det[0] == 0.0


def _valid_at_nodes_invalid_inside(name):
    """A cell whose det J is > 0 at every node but < 0 somewhere inside (on a dense sample): the first of a
    seeded sequence of perturbed reference cells (growing noise) that is so."""
    el = ELEMENTS[name]
    nodes = el.reference_nodes  # (the pyramid's apex: the measure at (0, 0, 1))
    pts = LO.domain_points(name, 1500, seed=1)
    rng = np.random.default_rng(17)
    X0 = LO.reference_cell(name)
    for sigma in (0.05, 0.08, 0.1, 0.12, 0.15, 0.2):
        X = X0[None] + sigma / el.order * rng.standard_normal((200,) + X0.shape)
        ok = (el.det(X, nodes).min(axis=1) > 1e-3) & (el.det(X, pts).min(axis=1) < -1e-3)
        if ok.any():
            return X[int(np.argmax(ok))]
    return None


@pytest.mark.parametrize("name", FAST)
def test_a_cell_valid_at_every_node_but_invalid_inside(name):
    X = _valid_at_nodes_invalid_inside(name)
    assert X is not None, f"no such {name} on the ladder"
    r = _run(name, X)
    assert r.status[0] == 0 and r.min_det[0] < 0
    el = ELEMENTS[name]
    d = np.linalg.norm(el.reference_nodes - r.argmin[0], axis=1).min()
    assert d > 1e-3, (r.argmin[0], r.min_det[0])  # the minimum is not at a node
    assert el.det(X, r.argmin[:1])[0, 0] <= r.min_det[0] + 1e-9 * r.scale[0]  # a real point, a real value


@pytest.mark.parametrize("name", FAST)
def test_perturbed_cells_against_vtk_and_gmsh_sampling(name):
    """Random perturbed cells: no sampled det J (VTK's Lagrange shape functions; pyramids, which VTK lacks, by
    Gmsh) lies below the proven lower bound; min_det is attained (VTK's or Gmsh's det J at the argmin); the
    verdicts are the signs of those; Gmsh's getJacobians (every type it evaluates) agrees."""
    el = ELEMENTS[name]
    X = np.concatenate([_perturbed(name, 6, 31), _perturbed(name, 6, 32, sigma=0.5 / el.order ** 2)])
    r = _run(name, X)
    nodes = el.reference_nodes[el.reference_nodes[:, 2] < 1] if el.domain == "pyramid" else el.reference_nodes
    pc = np.vstack([LO.domain_points(name, 600, seed=9), nodes])  # inside and on the boundary
    dense = LO.vtk_det(name, X, pc) if el.domain != "pyramid" else LO.gmsh_det(name, X, pc)
    tol = 1e-9 * r.scale
    assert np.all(dense.min(axis=1) >= r.lower_bound - tol)
    assert np.all(r.min_det <= dense.min(axis=1) + tol)
    assert set(r.status.tolist()) <= {0, 1} and (r.status == 1).any() and (r.status == 0).any()
    assert np.array_equal(r.status == 1, r.lower_bound > 0)
    for m in range(len(X)):
        # (Gmsh's pyramid functions are rational, singular at the apex: there the registry's polynomial measure)
        at = (LO.vtk_det(name, X[m:m + 1], r.argmin[m:m + 1]) if el.domain != "pyramid"
              else LO.gmsh_det(name, X[m:m + 1], r.argmin[m:m + 1]) if r.argmin[m, 2] < 0.99
              else el.det(X[m], r.argmin[m:m + 1]))[0, 0]
        assert abs(at - r.min_det[m]) <= 1e-8 * r.scale[m]
    if LO.gmsh_can_evaluate(name):
        g = LO.gmsh_det(name, X, pc)
        assert np.all(g.min(axis=1) >= r.lower_bound - tol)


@pytest.mark.parametrize("name", ["tetra20", "hexahedron64"])
def test_exact_decisions_agree_with_the_kernel(name):
    """The exact rational decision (kernel.exact.decide, the fallback for cells float cannot settle) gives the
    kernel's verdicts on a valid and an invalid-inside cell, and its exact lower bound is <= det J sampled."""
    from hexsos_plugins.kernel.exact import decide

    bad = _valid_at_nodes_invalid_inside(name)
    good = _perturbed(name, 1, 41, sigma=0.02)[0]
    for X, want in ((good, 1), (bad, 0)):
        st, lower, witness, value, _ = decide(X, name)
        assert st == want
        if st == 1:
            assert float(lower) <= ELEMENTS[name].det(X, LO.domain_points(name, 200, seed=2))[0].min()
        else:
            assert value <= 0 and ELEMENTS[name].det(X, np.asarray(witness, float)[None])[0, 0] <= 1e-12
