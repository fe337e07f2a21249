"""The certified largest safe step (hexsos_plugins.safe_step, hexsos_plugins.certify.safe_step): soundness against exact rational arithmetic and
dense sampling in (space, t), on single cells of every type and on Gmsh meshes moved by smooth and rough fields.

Single-cell cases use dyadic nodes and displacements with few bits, so that x + t d at a dyadic t (every t the
step returns is one) is exactly a float array: the independent rational reference of tests/exact_reference.py
and the exact subdivision of hexsos_plugins.exact then judge the very geometry the proof is about.
"""

from fractions import Fraction

import numpy as np
import pytest

import hexsos_plugins as hs
from exact_reference import exact_det
from hexsos_plugins import kernel
from hexsos_plugins.cells.elements import ELEMENTS
from hexsos_plugins.kernel import exact
from hexsos_plugins.errors import InvalidInputError
from hexsos_plugins.certify.safe_step import exact_det_at, safe_step

#: Every type of orders 1-2, and one simplex and one tensor type of order 3 (the higher orders cost minutes here;
#: the safe step runs on them with the same proofs).
TYPES = [n for n, el in ELEMENTS.items() if el.order <= 2] + ["tetra20", "hexahedron64"]
LINEAR = ("tetra", "pyramid", "wedge", "hexahedron")


def reference_cell(name):
    return 2.0 * np.array([[float(v) for v in x] for x in ELEMENTS[name].nodes])


def dyadic_case(name, seed):
    """A reference cell (scaled by 2) and a seeded displacement in multiples of 1/16 that inverts it before t = 1
    (the first seed from ``seed`` on that does)."""
    X = reference_cell(name)
    for s in range(seed, seed + 200):
        rng = np.random.default_rng(s)
        D = rng.integers(-24, 25, size=X.shape) / 16.0
        r = hs.check(X + D, [(name, [list(range(X.shape[0]))])])
        if r.status[0] == 0:
            return X, D
    raise AssertionError("no inverting displacement found")


def sample_points(name, n=40, seed=0):
    """The element's nodes and seeded points inside its reference element (pcoords)."""
    el = ELEMENTS[name]
    pts = [[float(v) for v in x] for x in el.nodes]
    rng = np.random.default_rng(seed)
    while len(pts) < el.n_nodes + n:
        x = rng.random(3)
        if el.domain == "tet" and x.sum() > 1:
            continue
        if el.domain == "prism" and x[0] + x[1] > 1:
            continue
        if el.domain == "pyramid":
            x[2] *= 0.98  # away from the apex
            x[:2] *= 1 - x[2]
        pts.append(list(x))
    return np.array(pts)


def dense_first_loss(P, D, name, conn, ts, pcoords):
    """Per cell, the first t of ``ts`` where det J (pyramids: the measure) is <= 0 at one of ``pcoords`` (inf: none)."""
    first = np.full(conn.shape[0], np.inf)
    for t in ts:
        Y = P + t * D
        bad = np.zeros(conn.shape[0], dtype=bool)
        for x in pcoords:
            bad |= kernel.det_at(Y, conn, name, x) <= 0
        first = np.where(bad & np.isinf(first), t, first)
    return first


@pytest.mark.parametrize("name", TYPES)
def test_single_cell_every_type(name):
    """t* is proven: the exact subdivision decides the exact cell at t* valid, and the independent rational
    reference puts det J <= 0 at the witness, a step just past t* (orders 1-2; for orders 3-5 t* is proven and the
    witness proven invalid, but the search's default budget does not close the gap between them to 1e-6);
    dense sampling finds no loss before t*."""
    X, D = dyadic_case(name, 1)
    cells = [(name, [list(range(X.shape[0]))])]
    r = safe_step(X, cells, D)
    assert 0.0 < r.t < 1.0 and r.check_valid
    assert r.cell_t[0] == r.t
    w = r.witness
    assert w is not None and w["cell"] == 0
    assert r.t < w["t"] and (w["t"] <= r.t * (1 + 1e-6) or ELEMENTS[name].order >= 3)
    Yw = X + w["t"] * D
    assert np.array_equal(Yw - X, w["t"] * D)  # exact: the reference judges the same geometry
    assert exact_det(Yw, name, [Fraction(v) for v in w["point"]]) <= 0
    # the cell exactly at t* is valid (exact subdivision), and just as the check finds it
    Yt = X + r.t * D
    if name in LINEAR or name == "tetra10":
        st, lower, *_ = exact.decide(Yt, name, max_boxes=3000)
        assert st == 1 and lower > 0
    assert hs.check(Yt, cells).status[0] == 1
    assert hs.check(Yw, cells).status[0] == 0
    # dense sampling in (space, t): no loss up to t*, a loss at the witness's t
    conn = np.arange(X.shape[0])[None]
    ts = np.linspace(0.0, r.t, 33)
    assert np.isinf(dense_first_loss(X, D, name, conn, ts, sample_points(name))[0])


def test_whole_step_safe_and_zero_step():
    X = reference_cell("hexahedron")
    cells = [("hexahedron", [list(range(8))])]
    r = safe_step(X, cells, 0.05 * np.ones_like(X))  # a translation: nothing changes shape
    assert r.t == 1.0 and r.safe and r.witness is None and r.check_valid
    r = safe_step(X, cells, np.zeros_like(X))
    assert r.t == 1.0 and r.witness is None


def test_interior_loss_found():
    """A cell that folds inside while its corners stay positive: the witness is inside, not at a vertex, and
    rational arithmetic confirms it."""
    from hexsos_plugins.examples import folding_twist

    X0 = np.round(folding_twist(np.radians(90)) * 64) / 64
    D = np.round((folding_twist(np.radians(170)) - X0) * 64) / 64
    cells = [("hexahedron", [list(range(8))])]
    assert hs.check(X0 + D, cells).status[0] == 0
    r = safe_step(X0, cells, D)
    assert 0 < r.t < 1
    w = r.witness
    x = np.asarray(w["point"])
    assert exact_det(X0 + w["t"] * D, "hexahedron", [Fraction(v) for v in x]) <= 0
    corners = hs.check(X0 + w["t"] * D, cells).corner_min_det[0]
    assert corners > 0  # the corners alone would call this step safe
    assert np.any((x > 0) & (x < 1))  # not a vertex of the element


def test_invalid_start():
    X = reference_cell("tetra")
    X[[1, 2]] = X[[2, 1]]  # inverted already
    r = safe_step(X, [("tetra", [[0, 1, 2, 3]])], np.zeros_like(X))
    assert r.t == 0.0 and not r.check_valid
    assert r.witness["t"] == 0.0 and r.witness["exact_det"] < 0
    # one cell folded inside at the start, beside a valid one: no step is safe, whatever the displacement
    from hexsos_plugins.examples import inside_invalid_hex, unit_cube

    P = np.concatenate([inside_invalid_hex(), unit_cube() + 10.0])
    H = np.arange(16).reshape(2, 8)
    r = safe_step(P, H, np.ones_like(P))
    assert r.t == 0.0 and r.cell_t[0] == 0.0 and r.cell_t[1] == 1.0 and r.witness["cell"] == 0


def test_bad_input():
    X = reference_cell("tetra")
    with pytest.raises(InvalidInputError, match="shape"):
        safe_step(X, [("tetra", [[0, 1, 2, 3]])], np.zeros((3, 3)))
    with pytest.raises(InvalidInputError, match="finite"):
        safe_step(X, [("tetra", [[0, 1, 2, 3]])], np.full_like(X, np.nan))


def test_exact_det_at_matches_reference():
    """The witness's exact evaluation agrees with the independent reference (shape functions' derivatives)."""
    rng = np.random.default_rng(3)
    for name in TYPES:
        X = reference_cell(name) + rng.integers(-3, 4, size=(ELEMENTS[name].n_nodes, 3)) / 16.0
        for x in sample_points(name, n=2, seed=1)[-2:]:
            x = np.round(x * 8) / 8
            assert exact_det_at(X, name, x) == exact_det(X, name, [Fraction(v) for v in x]), name


def _blocks(cells):
    s = 0
    for name, conn in cells:
        yield name, conn, s
        s += len(conn)


def _offset(cells, name):
    return next(s for n, _, s in _blocks(cells) if n == name)


@pytest.fixture(scope="module", params=[(1, True), (2, True), (2, False)], ids=["linear", "serendipity", "complete"])
def gmsh_mesh(request, tmp_path_factory):
    pytest.importorskip("gmsh")
    from hexsos_plugins.examples import mixed_msh

    order, incomplete = request.param
    path = tmp_path_factory.mktemp("step") / "m.msh"
    mixed_msh(path, order=order, incomplete=incomplete, size=0.5)
    m = hs.read(str(path))
    return m.points, m.cells


@pytest.mark.parametrize("field", ["smooth", "rough"])
def test_gmsh_meshes(gmsh_mesh, field):
    """Done-when of the step: t* leaves every cell proven valid, the witness's t (<= t* (1 + 1e-6)) inverts the
    witness cell (proven by check and by rational arithmetic), dense sampling agrees."""
    P, cells = gmsh_mesh
    if field == "smooth":
        D = 0.6 * np.stack([np.sin(3 * P[:, 1] + 1), np.sin(2.5 * P[:, 2]), np.cos(3.5 * P[:, 0])], 1)
    else:
        D = 0.3 * np.random.default_rng(7).standard_normal(P.shape)
    r = safe_step(P, cells, D)
    assert 0 < r.t < 1 and r.check_valid
    assert np.all(hs.check(P + r.t * D, cells).status == 1)
    fast = safe_step(P, cells, D, per_cell=False)  # the mesh's t* alone: the same t* and witness
    assert fast.t == r.t and fast.witness["cell"] == r.witness["cell"] and fast.witness["t"] == r.witness["t"]
    assert np.all(fast.cell_t >= r.t)
    w = r.witness
    assert w is not None and r.t < w["t"] <= r.t * (1 + 1e-6)
    after = hs.check(P + w["t"] * D, cells)
    assert after.status[w["cell"]] == 0
    assert w["exact_det"] <= 0
    # dense sampling: per cell, no loss sampled before the cell's proven fraction; for the mesh, the loss
    # sampled on a fine grid past t* lies close to it
    start = 0
    first = []
    for name, conn in cells:
        conn = np.asarray(conn)
        ts = np.linspace(0.0, 1.0, 65)
        f = dense_first_loss(P, D, name, conn, ts, sample_points(name, n=6))
        assert np.all(f >= r.cell_t[start:start + conn.shape[0]]), name
        first.append(f)
        start += conn.shape[0]
    first = np.concatenate(first)
    assert first.min() >= r.t
    # and sampling at the witness finds the loss there
    name, conn = next((n, np.asarray(c)) for n, c, s in _blocks(cells) if s <= w["cell"] < s + len(c))
    row = conn[w["cell"] - _offset(cells, name)][None]
    assert kernel.det_at(P + w["t"] * D, row, name, w["point"])[0] <= 0


def test_cli_step(tmp_path, capsys):
    """``hexsos step``: the one-line summary, the JSON's safe_step and witness, the exit codes, bad array names."""
    import json

    from hexsos_plugins.cli import main
    from hexsos_plugins.examples import structured_grid

    P, H = structured_grid(3)
    D = np.zeros_like(P)
    centre = int(np.argmin(np.linalg.norm(P - P.mean(axis=0), axis=1)))
    far = int(np.argmax(P @ np.ones(3)))
    D[centre] = [0.5, 0.5, 0.5]  # an interior node pushed through its neighbours
    m = hs.Mesh.from_arrays(P, H)
    path = str(tmp_path / "g.vtu")
    hs.write(m.to_meshio(point_data={"u": D, "v": np.zeros_like(P)}), path)
    assert main(["step", path, "--displacement", "u", "--json", "-o", str(tmp_path / "o.vtu")]) == 1
    d = json.loads(capsys.readouterr().out)
    expect = safe_step(P, H, D)
    assert d["safe_step"] == expect.t and 0 < d["safe_step"] < 1
    assert d["witness"]["cell"] == expect.witness["cell"] and d["witness"]["t"] > d["safe_step"]
    assert len(d["witness"]["point"]) == 3
    out = hs.read(str(tmp_path / "o.vtu"))
    arr = np.concatenate(out.source.cell_data["hexsos_safe_step"])
    assert arr.min() == d["safe_step"] and arr.max() == 1.0
    assert main(["step", path, "--displacement", "v"]) == 0
    assert "whole step is proven safe" in capsys.readouterr().out
    assert main(["step", path, "--displacement", "w"]) == 2
    assert "'w'" in capsys.readouterr().err
    assert far >= 0


def test_inversion_between_samples_that_halving_misses(tmp_path):
    """A twisting displacement of a Gmsh mixed mesh: every cell is proven valid at t = 1 (and 1/2), so checking
    the moved mesh accepts the whole step, yet a pyramid inverts on the way (t about 0.73 to 0.89) and comes
    back. The safe step stops before it, with a witness that rational arithmetic confirms."""
    pytest.importorskip("gmsh")
    from comparison.bench_step import edge_length, field
    from hexsos_plugins.examples import mixed_msh

    path = tmp_path / "m.msh"
    mixed_msh(path, order=1, size=0.34)
    m = hs.read(str(path))
    P, cells = m.points, [(t, np.asarray(c)) for t, c in m.cells]
    D = field("swirl", P, edge_length(P, cells), 1000 + len("mixed linear"))
    assert np.all(hs.check(P + D, cells).status == 1)  # plain halving stops here: t = 1
    assert np.all(hs.check(P + 0.5 * D, cells).status == 1)
    r = safe_step(P, cells, D, per_cell=False)
    assert 0.5 < r.t < 0.9 and r.check_valid
    w = r.witness
    assert w["cell_type"] == "pyramid" and w["exact_det"] <= 0 and w["t"] <= r.t * (1 + 1e-6)
    name, conn, s = next((n, c, s) for n, c, s in _blocks(cells) if n == w["cell_type"])
    row = conn[w["cell"] - s][None]
    assert hs.check(P + w["t"] * D, [(name, row)]).status[0] == 0
    # dense sampling at the witness's point: negative on the way, positive at both ends
    ts = np.linspace(w["t"], 0.85, 20)
    vals = [kernel.det_at(P + t * D, row, name, w["point"])[0] for t in ts[1:]]
    assert max(vals) < 0
    assert kernel.det_at(P + D, row, name, w["point"])[0] > 0 and kernel.det_at(P, row, name, w["point"])[0] > 0


def test_overflowing_step_is_not_called_safe():
    """A displacement so large that det J's coefficients overflow: no safe step is claimed, nothing raised."""
    X = reference_cell("hexahedron")
    D = np.zeros_like(X)
    D[6] = [1e300, -1e300, 1e300]
    r = safe_step(X, [("hexahedron", [list(range(8))])], D)
    assert r.t < 1.0
