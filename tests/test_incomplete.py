"""Gmsh's incomplete cells of orders 3 to 5 (``Mesh.SecondOrderIncomplete``: tetra16/22/28, hexahedron32/44/56,
wedge24/33/42, pyramid21/29/37): node positions and spaces against Gmsh (``getElementProperties``,
``getBasisFunctions``, ``getJacobian`` on a mesh Gmsh made), the kernel's verdicts (reference cell, mirror, a cell
valid at its nodes but invalid inside, exact arithmetic), and Gmsh mixed meshes of orders 3 and 4 through the CLI,
.msh and .vtu (order 5: nodes, spaces, det J against Gmsh, the reference cell and its mirror).
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

import exact_reference as ref
from hexsos_plugins import check
from hexsos_plugins.cells.elements import ELEMENTS, Element, eval_exact
from hexsos_plugins.cells.incomplete import COMPLETE, TYPES, incomplete_nodes, space_exponents
from hexsos_plugins.io.mesh import MIRROR

gmsh = pytest.importorskip("gmsh")

from comparison import lagrange_oracle as LO  # noqa: E402
from comparison.against_gmsh import gmsh_local  # noqa: E402

ALL = [row[0] for row in TYPES]
FAST = [n for n in ALL if ELEMENTS[n].order <= 4]
EVALUATED = [n for n in ALL if ELEMENTS[n].domain in ("tet", "cube")]  # what Gmsh 4.15 can interpolate


def _run(name, X):
    X = np.asarray(X, float)
    if X.ndim == 2:
        X = X[None]
    conn = np.arange(X.shape[0] * X.shape[1]).reshape(X.shape[0], -1)
    return check(X.reshape(-1, 3), [(name, conn)])


def _session():
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    gmsh.option.setNumber("General.Terminal", 0)


def _gmsh_basis(gtype, local):
    _, bf, _ = gmsh.model.mesh.getBasisFunctions(gtype, np.asarray(local, float).ravel().tolist(), "Lagrange")
    return np.asarray(bf).reshape(len(local), -1)


# --- what Gmsh makes ------------------------------------------------------------------------------------------------
def test_gmsh_makes_these_incomplete_types_at_orders_three_and_four():
    """A mixed mesh (hexahedra, prisms, tetrahedra, pyramids) with SecondOrderIncomplete at orders 3 to 5: Gmsh's 3-D
    element types are exactly the registry's incomplete ones, its 2-D ones the incomplete triangles and
    quadrilaterals hexsos keeps as blocks."""
    from comparison.curved_mixed import build_mixed
    from hexsos_plugins.io.meshio_conventions import GMSH_EXTRA_2D

    for p in (3, 4, 5):
        _session()
        try:
            build_mixed(gmsh, p, incomplete=True)
            types = set(int(t) for t in gmsh.model.mesh.getElementTypes(3))
            types2 = set(int(t) for t in gmsh.model.mesh.getElementTypes(2))
        finally:
            gmsh.finalize()
        assert types == {row[3] for row in TYPES if row[2] == p}, (p, types)
        assert types2 <= set(GMSH_EXTRA_2D) and len(types2) == 2


@pytest.mark.parametrize("name", [n for n in ALL if ELEMENTS[n].domain != "prism"])
def test_gmsh_reference_nodes_are_ours(name):
    """getElementProperties' local coordinates are the registry's nodes (Gmsh's order); two nodes exchanged differ."""
    el = ELEMENTS[name]
    _session()
    try:
        loc = np.asarray(gmsh.model.mesh.getElementProperties(el.gmsh_type)[4]).reshape(-1, 3)
    finally:
        gmsh.finalize()
    ours = gmsh_local(el, el.reference_nodes)
    assert loc.shape == ours.shape and np.allclose(loc, ours, atol=1e-12)
    assert not np.allclose(loc[list(range(el.n_nodes - 2)) + [el.n_nodes - 1, el.n_nodes - 2]], ours, atol=1e-12)


def test_gmsh_cannot_evaluate_its_incomplete_prisms():
    """Gmsh 4.15 has no basis for its prisms of order >= 3, incomplete ones included (if a Gmsh gains one, this test
    says so and the prisms join the span test); their nodes are the complete prism's first corners and edges."""
    from hexsos_plugins.cells import lagrange

    _session()
    try:
        for name in ("wedge24", "wedge33", "wedge42"):
            with pytest.raises(Exception, match="FaceClosureFull"):
                gmsh.model.mesh.getElementProperties(ELEMENTS[name].gmsh_type)
    finally:
        gmsh.finalize()
    for name in ("wedge24", "wedge33", "wedge42"):
        el = ELEMENTS[name]
        assert el.nodes == lagrange.reference_nodes("prism", el.order, "gmsh")[: el.n_nodes]


def test_gmsh_has_no_interpolation_for_its_incomplete_pyramids():
    """Gmsh 4.15's getBasisFunctions for its 21-, 29- and 37-node pyramids: the same values at every point, the
    first corner included, where an interpolating basis is (1, 0, ..., 0) (its 13-node pyramid, for contrast, sums
    to 1 and varies): there is no Gmsh space to compare with; if a Gmsh gains one, this test says so."""
    pts = np.array([[-1.0, -1.0, 0.0], [0.1, -0.2, 0.3], [-0.3, 0.25, 0.5], [0.0, 0.0, 0.1]])
    _session()
    try:
        for gtype in (125, 126, 127):
            B = _gmsh_basis(gtype, pts)
            assert np.allclose(B, B[0]) and not np.allclose(B[0], np.eye(len(B[0]))[0], atol=1e-3)
        B = _gmsh_basis(19, pts)
        assert np.allclose(B.sum(axis=1), 1) and not np.allclose(B, B[0])
    finally:
        gmsh.finalize()


def test_gmsh_cannot_take_back_its_incomplete_hexahedra_of_order_4_and_pyramids(tmp_path):
    """Gmsh 4.15 makes hexahedron44/56 and the incomplete pyramids (setOrder) but cannot take them back: adding a
    44- or 56-node hexahedron through its API kills the process (segmentation fault; a 32-node one is fine), and
    gmsh.open of its own file holding one of these fails ("Could not create element ... of type 100 / 125").
    Gmsh's minDetJac is therefore compared on the other types only; those hexahedra against getJacobian on the
    model Gmsh made. If a Gmsh takes them back, this test says so."""
    import os
    import subprocess
    import sys

    from comparison.curved_mixed import write_mixed

    code = ("import numpy as np; from comparison.against_gmsh import gmsh_qualities; "
            "from comparison import lagrange_oracle as LO; X = LO.reference_cell('{0}'); "
            "print(gmsh_qualities(X, [('{0}', np.arange(len(X))[None])])[0][0])")
    runs = {n: subprocess.run([sys.executable, "-c", code.format(n)], capture_output=True, text=True,
                              env=os.environ.copy(), timeout=120)
            for n in ("hexahedron32", "hexahedron44", "hexahedron56")}
    assert runs["hexahedron32"].returncode == 0 and float(runs["hexahedron32"].stdout) == pytest.approx(1.0)
    assert runs["hexahedron44"].returncode != 0 and runs["hexahedron56"].returncode != 0
    for p, gtype in ((3, 125), (4, 100)):
        f = write_mixed(tmp_path / f"m{p}.msh", p, incomplete=True)
        _session()
        try:
            with pytest.raises(Exception, match=f"type {gtype}"):
                gmsh.open(str(f))
        finally:
            gmsh.finalize()


# --- the spaces ---------------------------------------------------------------------------------------------------
def _element(name, exps):
    """The type's nodes with another monomial space (tetrahedra, hexahedra)."""
    el = ELEMENTS[name]
    return Element(name + "-other", -1, el.gmsh_type, el.domain, el.order, el.nodes, el.corners, el.faces,
                   tuple({tuple(e): Fraction(1)} for e in exps), el.gmsh_to_vtk, el.gmsh_factor)


@pytest.mark.parametrize("name", EVALUATED)
def test_the_space_is_gmshs(name):
    """Gmsh's shape functions at random points are ours (the same nodes, so the same space means the same
    functions): the spans are equal. A space with one monomial replaced (the first mixed one by rs for the
    tetrahedra, r^2 s^2 for the hexahedra) is not Gmsh's, and its functions differ."""
    el = ELEMENTS[name]
    pts = LO.domain_points(name, 80, seed=4)
    _session()
    try:
        B = _gmsh_basis(el.gmsh_type, gmsh_local(el, pts))
    finally:
        gmsh.finalize()
    ours = el.shape_functions(pts)
    assert np.allclose(B, ours, atol=1e-9)
    assert np.linalg.matrix_rank(np.hstack([B, ours]), tol=1e-8) == el.n_nodes
    exps = space_exponents(el.domain, el.order)
    mixed = next(i for i, e in enumerate(exps) if sum(v > 0 for v in e) >= 2)
    tried = 0
    for repl in ((1, 1, 0), (2, 1, 0), (2, 2, 0)):
        if repl in exps:
            continue
        wrong = list(exps)
        wrong[mixed] = repl
        try:
            other = _element(name, wrong).shape_functions(pts)
        except StopIteration:  # (not even unisolvent at these nodes)
            continue
        tried += 1
        assert not np.allclose(B, other, atol=1e-6)
        assert np.linalg.matrix_rank(np.hstack([B, other]), tol=1e-8) > el.n_nodes
    assert tried


def test_at_order_two_the_rules_give_the_quadratic_serendipity_cells():
    """The spaces' rules at p = 2 are the registry's order-2 cells: tetra10 (P2), hexahedron20, wedge15 and
    pyramid13 (the same shape functions at the same nodes), so the incomplete family extends Gmsh's order-2 one."""
    pts = np.random.default_rng(3).random((30, 3)) * [1, 1, 0.9]
    for dom, name in (("tet", "tetra10"), ("cube", "hexahedron20"), ("prism", "wedge15"), ("pyramid", "pyramid13")):
        el = ELEMENTS[name]
        nodes = incomplete_nodes(dom, 2)
        exps = space_exponents(dom, 2)
        if dom == "pyramid":
            omt = {(0, 0, 0): Fraction(1), (0, 0, 1): Fraction(-1)}
            basis = []
            for i, j, k in exps:
                f = {(i, j, k): Fraction(1)}
                for _ in range(max(i, j)):
                    g = {}
                    for e1, c1 in f.items():
                        for e2, c2 in omt.items():
                            e = tuple(a + b for a, b in zip(e1, e2))
                            g[e] = g.get(e, 0) + c1 * c2
                    f = {e: c for e, c in g.items() if c}
                basis.append(f)
        else:
            basis = [{tuple(e): Fraction(1)} for e in exps]
        ours = Element("p2", -1, 0, dom, 2, nodes, el.corners, el.faces, tuple(basis), tuple(range(len(nodes))))
        assert sorted(nodes) == sorted(el.nodes), name
        perm = [nodes.index(x) for x in el.nodes]  # the registry's node order
        assert np.allclose(ours.shape_functions(pts)[:, perm], el.shape_functions(pts), atol=1e-12), name
    # a pyramid rule without the k <= p - max(i, j) bound is another space (not even unisolvent at 13 nodes)
    assert len([e for e in space_exponents("pyramid", 2) if e[:2] == (0, 0)]) == 3


@pytest.mark.parametrize("order", [3, 4, 5])
def test_det_j_is_gmshs_on_a_mesh_gmsh_made(order):
    """getJacobian on the perturbed incomplete tetrahedra and hexahedra of a Gmsh mixed mesh (the model itself,
    SecondOrderIncomplete) is our det J at the same points (its units: gmsh_factor); a node order reversed on the
    edges is not. Sampled densely, Gmsh's det J never lies below hexsos' proven bound, and a cell with a negative
    sample is invalid by hexsos (both verdicts occur)."""
    from comparison.curved_mixed import build_mixed

    seen = set()
    _session()
    try:
        build_mixed(gmsh, order, incomplete=True, noise=0.04)
        tags, xyz, _ = gmsh.model.mesh.getNodes()
        where = {int(t): i for i, t in enumerate(tags)}
        xyz = np.asarray(xyz).reshape(-1, 3)
        for name in (n for n in EVALUATED if ELEMENTS[n].order == order):
            el = ELEMENTS[name]
            _, nodes = gmsh.model.mesh.getElementsByType(el.gmsh_type)
            conn = np.array([where[int(t)] for t in nodes]).reshape(-1, el.n_nodes)[:40]
            pc = LO.domain_points(name, 7, seed=6)
            dets = []
            for e in gmsh.model.mesh.getElementsByType(el.gmsh_type)[0][:40]:
                _, d, _ = gmsh.model.mesh.getJacobian(int(e), gmsh_local(el, pc).ravel().tolist())
                dets.append(d)
            g = np.asarray(dets) / el.gmsh_factor
            ours = el.det(xyz[conn], pc)
            assert np.allclose(g, ours, rtol=1e-8, atol=1e-12 * np.abs(g).max()), name
            # Gmsh's det J sampled densely: never below hexsos' proven bound; a negative sample, an invalid verdict
            pcd = np.vstack([LO.domain_points(name, 60, seed=2), el.reference_nodes])
            gd = np.array([gmsh.model.mesh.getJacobian(int(e), gmsh_local(el, pcd).ravel().tolist())[1]
                           for e in gmsh.model.mesh.getElementsByType(el.gmsh_type)[0][:40]])
            gd = gd.min(axis=1) / el.gmsh_factor
            r = check(xyz, [(name, conn)])
            assert np.all(gd >= r.lower_bound - 1e-9 * r.scale) and np.all(r.min_det <= gd + 1e-9 * r.scale)
            assert ((gd < 0) <= (r.status == 0)).all(), name
            seen |= set(r.status.tolist())
            k = el.corners
            bad = conn.copy()
            bad[:, k:] = bad[:, k:][:, ::-1]
            assert not np.allclose(g, el.det(xyz[bad], pc), rtol=1e-3), name
    finally:
        gmsh.finalize()
    assert seen == {0, 1}  # valid and invalid cells both met


# --- verdicts -----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ALL)
def test_reference_cell_is_valid_and_its_mirror_invalid(name):
    X = LO.reference_cell(name)
    r = _run(name, X)
    assert r.status[0] == 1 and abs(r.min_det[0] - 1) < 1e-12 and abs(r.lower_bound[0] - 1) < 1e-7
    m = _run(name, X[MIRROR[name]])
    assert m.status[0] == 0 and abs(m.min_det[0] + 1) < 1e-12


@pytest.mark.parametrize("name", FAST)
def test_a_cell_valid_at_every_node_but_invalid_inside(name):
    X = LO.valid_at_nodes_invalid_inside(name)
    assert X is not None, f"no such {name} on the ladder"
    r = _run(name, X)
    assert r.status[0] == 0 and r.min_det[0] < 0
    el = ELEMENTS[name]
    assert np.linalg.norm(el.reference_nodes - r.argmin[0], axis=1).min() > 1e-3
    assert el.det(X, r.argmin[:1])[0, 0] <= r.min_det[0] + 1e-9 * r.scale[0]


@pytest.mark.parametrize("name", ["tetra16", "hexahedron32", "wedge24", "pyramid21"])
def test_verdicts_are_proofs_in_exact_arithmetic(name):
    """Adversarial cells (perturbed, valid at the nodes but invalid inside, tiny, huge, nearly flat): the lower bound
    is <= the exact det J at the corners, the argmin and random points; a valid cell is positive there, an invalid
    one has det J <= 0 exactly at its argmin; the exact decision (kernel.exact.decide) gives the same verdicts."""
    from hexsos_plugins.kernel.exact import decide

    el = ELEMENTS[name]
    rng = np.random.default_rng(5)
    X0 = LO.reference_cell(name)
    base = X0 + 0.1 / el.order * rng.standard_normal(X0.shape)
    cells = [X0 + 0.3 / el.order * rng.standard_normal(X0.shape) for _ in range(2)]
    cells += [LO.valid_at_nodes_invalid_inside(name), base * 1e-150, base * 1e100, base * [1, 1, 1e-9]]
    for X in cells:
        r = _run(name, X)
        pts = [tuple(x) for x in el.nodes[: el.corners] if x[2] < 1] + [tuple(Fraction(float(v)) for v in r.argmin[0])]
        at = len(pts) - 1
        for x in LO.domain_points(name, 4, seed=int(rng.integers(100))):
            pts.append(tuple(Fraction(float(v)).limit_denominator(2**20) for v in x))
        vals = [ref.exact_det(X, name, q) for q in pts]
        low = Fraction(float(r.lower_bound[0]))
        assert all(low <= v for v in vals)
        if r.status[0] == 1:
            assert all(v > 0 for v in vals)
        elif r.status[0] == 0:
            assert vals[at] <= 0  # at the argmin
    good = X0 + 0.02 / el.order * rng.standard_normal(X0.shape)
    for X, want in ((good, 1), (cells[2], 0)):
        st, lower, witness, value, _ = decide(X, name)
        assert st == want == _run(name, X).status[0]
        if st == 0:
            assert value <= 0 and ref.exact_det(X, name, [Fraction(v) for v in witness]) <= 0


# --- files and the CLI --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    """Gmsh mixed meshes with SecondOrderIncomplete at orders 3 and 4, perturbed, with their boundary (bottom)."""
    from comparison.curved_mixed import write_mixed

    d = tmp_path_factory.mktemp("incomplete")
    return {p: write_mixed(d / f"mixed{p}.msh", p, noise=0.04, incomplete=True, bottom=True) for p in (3, 4)}


def _dets(points, cells, key):
    """{key[type]: det J of every cell of the types in key at fixed points, in the cells' order}."""
    out = {}
    for t, conn in cells:
        if t in key:
            d = ELEMENTS[t].det(points[conn], LO.domain_points(t, 12, seed=4)[:4])
            k = key[t]
            out[k] = np.concatenate([out[k], d]) if k in out else d
    return out


@pytest.mark.parametrize("order", [3, 4])
def test_mixed_mesh_through_the_cli_msh_and_vtu(mixed, order, tmp_path):
    """`hexsos check F.msh -o OUT.vtu --json`: no cell "not checked", the four incomplete types reported; every
    tetrahedron's and hexahedron's verdict agrees with Gmsh's minDetJac where that is decisive. OUT.vtu holds the
    tetrahedra, hexahedra and prisms as VTK Lagrange cells (71, 72, 73) with the same det J, a note says so; a .msh
    round trip keeps every type, the boundary's incomplete triangles and quadrilaterals included."""
    import json
    import os
    import subprocess
    import sys

    import hexsos_plugins as hs
    from comparison.against_gmsh import gmsh_qualities

    out = tmp_path / "out.vtu"
    p = subprocess.run([sys.executable, "-m", "hexsos_plugins", "check", str(mixed[order]), "-o", str(out), "--json"],
                       capture_output=True, text=True, env=os.environ.copy(), timeout=600)
    assert p.returncode in (0, 1), p.stderr
    rep = json.loads(p.stdout)
    names = {row[0] for row in TYPES if row[2] == order}
    assert rep["not_checked"] == {} and rep["undecided"] == 0 and set(rep["by_type"]) == names
    assert rep["valid"] > 0 and rep["invalid"] > 0
    assert any("complete Lagrange cells" in w for w in rep["warnings"])
    mesh = hs.read(mixed[order])
    res = hs.check(mesh.points, mesh.cells)
    kinds = np.asarray(hs.CELL_TYPES)[res.cell_type]
    # (Gmsh 4.15 cannot take a hexahedron44 back: see test_gmsh_cannot_take_back_...; test_det_j_is_gmshs has it)
    sel = [(t, c) for t, c in mesh.cells if ELEMENTS[t].domain == "tet" or t == "hexahedron32"]
    gmin, _, _ = gmsh_qualities(mesh.points, sel)
    mask = np.isin(kinds, [t for t, _ in sel])
    decisive = np.abs(gmin) > 1e-3 * res.scale[mask]
    assert decisive.sum() > 100 and ((gmin > 0) == (res.status[mask] == 1))[decisive].all()
    # .vtu: the complete cells of the same geometry
    from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridReader

    r = vtkXMLUnstructuredGridReader()
    r.SetFileName(str(out))
    r.Update()
    g = r.GetOutput()
    assert {g.GetCellType(i) for i in range(g.GetNumberOfCells())} >= {71, 72, 73}
    back = hs.read(out)
    d0 = _dets(mesh.points, mesh.cells, {t: t for t in names})
    d1 = _dets(back.points, back.cells, {COMPLETE[t]: t for t in names if ELEMENTS[t].domain != "pyramid"})
    assert set(d1) == {t for t in names if ELEMENTS[t].domain != "pyramid"}
    for t in d1:  # (the float evaluators, in monomial form, keep about 8 digits at order 4)
        assert np.allclose(d0[t], d1[t], rtol=0, atol=1e-7 * np.abs(d0[t]).max()), t
        # exactly: the first cell's map at a rational point, incomplete and complete, to the points' rounding
        x = [Fraction(1, 3), Fraction(1, 7), Fraction(1, 5)]
        a = next(c for k, c in mesh.cells if k == t)[0]
        b = next(c for k, c in back.cells if k == COMPLETE[t])[0]
        for P, c, k in ((mesh.points, a, t), (back.points, b, COMPLETE[t])):
            shapes = ELEMENTS[k].shape_polynomials
            v = [sum(eval_exact(N, x) * Fraction(float(P[c[i], d])) for i, N in enumerate(shapes)) for d in range(3)]
            if k == t:
                first = v
        assert max(abs(float(u - w)) for u, w in zip(first, v)) < 1e-14, t
    # .msh round trip
    notes = hs.write(mesh, tmp_path / "a.msh")
    assert not notes
    again = hs.read(tmp_path / "a.msh")
    assert {t for t, _ in again.cells} == names
    assert {b.type for b in again.source.cells} == {b.type for b in mesh.source.cells}
    d2 = _dets(again.points, again.cells, {t: t for t in names})
    assert all(np.allclose(d0[t], d2[t], rtol=1e-12, atol=1e-12) for t in d0)


def test_gmsh_panel_checks_every_incomplete_element_of_a_model():
    """gmsh_plugin's check_model on a model Gmsh made with SecondOrderIncomplete at order 3 (its prisms, which Gmsh
    cannot describe, too): every element checked, the four incomplete types, the verdicts those of hexsos.check on
    the model's nodes and elements."""
    import hexsos_plugins as hs
    from comparison.curved_mixed import build_mixed
    from gmsh_plugin.model import check_model

    _session()
    try:
        build_mixed(gmsh, 3, incomplete=True, noise=0.04)
        res = check_model(post_views=False)
        tags, xyz, _ = gmsh.model.mesh.getNodes()
        where = {int(t): i for i, t in enumerate(tags)}
        cells = []
        for name in ("tetra16", "hexahedron32", "wedge24", "pyramid21"):
            el = ELEMENTS[name]
            _, nodes = gmsh.model.mesh.getElementsByType(el.gmsh_type)
            cells.append((name, np.array([where[int(t)] for t in nodes]).reshape(-1, el.n_nodes)))
    finally:
        gmsh.finalize()
    assert not res.extra["gmsh"].skipped
    assert set(np.asarray(hs.CELL_TYPES)[res.cell_type]) == {"tetra16", "hexahedron32", "wedge24", "pyramid21"}
    ref_ = hs.check(np.asarray(xyz).reshape(-1, 3), cells)
    assert len(res.status) == len(ref_.status) and (ref_.status == 0).any() and (ref_.status == 1).any()
    assert sorted(res.min_det.tolist()) == pytest.approx(sorted(ref_.min_det.tolist()), rel=1e-12, abs=1e-12)
