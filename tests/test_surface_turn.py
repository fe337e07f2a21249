"""The boundary surface does not fold: stage 1's term on the boundary quads, stage 2's hold on them, the projections'
and the report's count of boundary quads turned over."""

import os

import numpy as np
import pytest

import hexsos_plugins as hs
from comparison.stress import stress
from hexsos_plugins.meshrepair import optimize as op
from hexsos_plugins.meshrepair.boundary import boundary_model, quad_corners

CUBE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)


def _slab(n=4):
    """An n x n x 1 slab of unit hexes (VTK order): every vertex on the boundary."""
    idx = lambda i, j, k: (i * n + j) * 2 + k  # noqa: E731
    P = np.array([[i, j, k] for i in range(n) for j in range(n) for k in range(2)], dtype=float)
    H = np.array([[idx(i, j, 0), idx(i + 1, j, 0), idx(i + 1, j + 1, 0), idx(i, j + 1, 0),
                   idx(i, j, 1), idx(i + 1, j, 1), idx(i + 1, j + 1, 1), idx(i, j + 1, 1)]
                  for i in range(n - 1) for j in range(n - 1)], dtype=np.int64)
    return P, H


def test_the_surface_term_is_its_closed_form_on_the_cube_and_its_gradient_central_differences():
    H = np.arange(8, dtype=np.int64)[None]
    bm = boundary_model(CUBE, [("hexahedron", H)])
    assert bm.quads.shape == (6, 4) and np.allclose(np.abs(bm.quad_normal).sum(axis=1), 1.0)
    # the input normals point out of the cube
    centre = CUBE[bm.quads].mean(axis=1) - 0.5
    assert ((centre * bm.quad_normal).sum(axis=1) > 0).all()
    surface = (bm.quads, bm.quad_normal, bm.quad_s2)
    prob = op.Problem(CUBE, [("hexahedron", H)], [np.ones(1)], np.ones(8, dtype=bool), surface=surface)
    eps = 0.3
    g = np.zeros((8, 3))
    e, d = prob.surface_terms(prob.full(prob.x0())[prob.used], eps, g)
    chi1 = 0.5 * (1.0 + np.sqrt(1.0 + eps * eps))
    assert d == pytest.approx(1.0) and e == pytest.approx(24 * op.SURFACE_WEIGHT / chi1, rel=1e-12)
    assert np.abs(g).max() > 0  # the square's corner is not the minimum of S / chi alone
    # a moved slab, one top quad turned over: the gradient against central differences, at a large and a tiny eps
    P, Hs = _slab()
    bm = boundary_model(P, [("hexahedron", Hs)])
    rng = np.random.default_rng(0)
    V = P + 0.25 * rng.standard_normal(P.shape)
    V[[1, 3]] = V[[3, 1]]
    prob = op.Problem(V, [("hexahedron", Hs)], [np.ones(len(Hs))], np.ones(len(P), dtype=bool),
                      surface=(bm.quads, bm.quad_normal, bm.quad_s2))
    x = prob.x0()
    for eps in (0.5, 1e-3):
        def energy(z):
            return prob.surface_terms(prob.full(z)[prob.used], eps, np.zeros((prob.used.size, 3)))[0]

        gl = np.zeros((prob.used.size, 3))
        _, dmin = prob.surface_terms(prob.full(x)[prob.used], eps, gl)
        assert dmin < 0  # the swap turned quads over
        grad = gl[prob.local_free].ravel()
        for k in range(4):
            u = rng.standard_normal(x.shape)
            h = 1e-6
            fd = (energy(x + h * u) - energy(x - h * u)) / (2 * h)
            assert fd == pytest.approx(grad @ u, rel=1e-5)


def test_stage_2_holds_the_quads_positive_at_a_rounds_start():
    P, H = _slab()
    bm = boundary_model(P, [("hexahedron", H)])
    rng = np.random.default_rng(1)
    V = P + 0.05 * rng.standard_normal(P.shape)
    prob = op.Problem(V, [("hexahedron", H)], [np.ones(len(H))], np.ones(len(P), dtype=bool), surface=bm.surface())
    x = prob.x0()
    e0, g0 = prob.barrier_energy(x, 0.0)
    prob.hold_surface(V)
    assert prob.surface["held"].size == len(bm.quads)  # every corner positive
    e1, g1 = prob.barrier_energy(x, 0.0)
    assert np.isfinite(e1) and e1 != e0
    for _ in range(3):  # the barrier's gradient against central differences
        u = rng.standard_normal(x.shape)
        h = 1e-6
        fd = ((prob.barrier_energy(x + h * u, 0.0, grad=False)[0] - prob.barrier_energy(x - h * u, 0.0, grad=False)[0])
              / (2 * h))
        assert fd == pytest.approx(g1 @ u, rel=1e-5)
    # a held quad turned over (a vertex moved across its diagonal, every hex still valid): infeasible; the same move
    # without the quad held is not
    idx = lambda i, j: (i * 4 + j) * 2 + 1  # noqa: E731  (the top layer)
    quad = np.array([[idx(1, 1), idx(1, 0), idx(3, 1), idx(2, 3)]], dtype=np.int64)
    n = np.array([[0.0, 0.0, 1.0]])
    free = np.ones(len(P), dtype=bool)
    held = op.Problem(P, [("hexahedron", H)], [np.ones(len(H))], free, surface=(quad, n, np.ones(1)))
    held.hold_surface(P)
    assert held.surface["held"].tolist() == [0]
    moved = held.x0()
    moved.reshape(-1, 3)[idx(1, 1), 0] += 0.5
    assert held.barrier_energy(moved, 0.0, grad=False)[0] == np.inf
    plain = op.Problem(P, [("hexahedron", H)], [np.ones(len(H))], free)
    assert np.isfinite(plain.barrier_energy(moved, 0.0, grad=False)[0])


def test_projections_turn_no_quad_over():
    """A top vertex of the slab moved half an edge along x, every hex still valid, across the diagonal of a quad
    (its vertices at (1, 1), (1, 0), (3, 1), (2, 3) on the top, positive against its normal): projected with the
    quad as the problem's surface it stops short, the quad kept; without, it goes all the way and turns it over."""
    P, H = _slab()
    idx = lambda i, j: (i * 4 + j) * 2 + 1  # noqa: E731  (the top layer)
    quad = np.array([[idx(1, 1), idx(1, 0), idx(3, 1), idx(2, 3)]], dtype=np.int64)
    n = np.array([[0.0, 0.0, 1.0]])
    v = idx(1, 1)
    target = P.copy()
    target[v, 0] += 0.5
    assert quad_corners(P, quad, n).min() > 0 > quad_corners(target, quad, n).min()
    free = np.ones(len(P), dtype=bool)
    held = op.Problem(P, [("hexahedron", H)], [np.ones(len(H))], free, surface=(quad, n, np.ones(1)))
    W = op.project_valid(held, P, target, np.array([v]))
    assert quad_corners(W, quad, n).min() > 0 and P[v, 0] < W[v, 0] < target[v, 0]
    plain = op.Problem(P, [("hexahedron", H)], [np.ones(len(H))], free)
    W2 = op.project_valid(plain, P, target, np.array([v]))
    assert np.array_equal(W2, target) and quad_corners(W2, quad, n).min() < 0


def test_turned_quads_counts_a_folded_surface_and_not_a_moved_one():
    P, H = _slab()
    bm = boundary_model(P, [("hexahedron", H)])
    assert bm.turned_quads(P).sum() == 0
    V = P.copy()
    V[:, 2] += 0.3 * V[:, 0]  # sheared: every quad keeps its side
    assert bm.turned_quads(V).sum() == 0
    top = [v for v in range(len(P)) if P[v, 2] == 1 and P[v, 0] == 1]
    V = P.copy()
    V[top, 0] = 2.6  # the top's column x = 1 pushed past x = 2: the quads between turn over
    turned = bm.turned_quads(V)
    assert turned.sum() >= 3
    assert (bm.quad_normal[turned][:, 2] == 1.0).all()  # top quads, faced up in the input
    # a quad folded in the input takes its vertices' normals: its own vector area says nothing
    W = P.copy()
    W[top[1], 0] = 2.6
    bmw = boundary_model(W, [("hexahedron", H)])
    folded = ~np.isclose(np.abs(bmw.quad_normal).max(axis=1), 1.0)
    assert folded.any() and (bmw.quad_normal[folded][:, 2] > 0.5).all()
    # an input of no area (every point coincident) gives its quads no normal: none counts as turned, whatever follows
    bm0 = boundary_model(np.zeros_like(P), [("hexahedron", H)])
    assert (bm0.quad_normal == 0).all()
    assert bm0.turned_quads(np.zeros_like(P)).sum() == 0 and bm0.turned_quads(V).sum() == 0


def test_boundary_terms_stay_finite_where_boundary_vertices_coincide():
    """Boundary vertices at one point have boundary edges of length 0: the penalty's weight divided by their
    square (1e-300 squared underflows to 0) was infinite, and stage 1's energy NaN. Their sizes are now floored
    at a thousandth of the median of the others, and the others' sizes are left exactly as they were."""
    P, H = _slab()
    bm = boundary_model(P, [("hexahedron", H)])
    free = np.ones(len(P), dtype=bool)
    assert np.array_equal(bm.slide(P, free).s2, bm.size[bm.kind < 2] ** 2)  # nothing floored on a regular slab
    W = P.copy()
    W[[1, 2, 8]] = W[0]  # the corner vertex 0 and its three neighbours at one point: its edges have no length
    bmw = boundary_model(W, [("hexahedron", H)])
    assert (bmw.size == 0).any() and (bmw.quad_s2 > 0).all()
    sl = bmw.slide(W, free)
    assert np.isfinite(sl.s2).all() and (sl.s2 > 0).all()
    assert sl.s2.min() == pytest.approx((1e-3 * np.median(bmw.size[bmw.size > 0])) ** 2)
    prob = op.Problem(W + 0.01, [("hexahedron", H)], [np.ones(len(H))], free, slide=sl, surface=bmw.surface())
    e, g = prob.untangle_energy(prob.x0(), 1e-3, None)
    assert np.isfinite(e) and np.isfinite(g).all()


def test_tilted_quads_counts_quads_standing_up_from_their_input_normal_and_not_those_sheared_a_little():
    """A top quad of the slab tilted by raising one of its edges: its vector area turns by atan(rise) from the input
    normal (+z); past 60 degrees it counts as tilted, not yet as turned; below 60 it does not count."""
    P, H = _slab(3)
    bm = boundary_model(P, [("hexahedron", H)])
    assert np.allclose(bm.quad_tilt(P), 1.0) and bm.tilted_quads(P).sum() == 0
    top = np.flatnonzero(np.all(P[bm.quads][:, :, 2] == 1, axis=1))
    corner = top[np.argmin(P[bm.quads[top]].sum(axis=(1, 2)))]  # the top quad at x, y in [0, 1]
    edge = [v for v in bm.quads[corner] if P[v, 0] == 1 and P[v, 2] == 1]  # its edge x = 1, shared with others
    for rise, tilted in ((1.0, False), (1.5, False), (2.0, True), (5.0, True)):  # 45, 56.3, 63.4, 78.7 degrees
        V = P.copy()
        V[edge, 2] += rise
        cos = bm.quad_tilt(V)[corner]
        assert cos == pytest.approx(1.0 / np.hypot(1.0, rise), rel=1e-12)
        assert bm.tilted_quads(V)[corner] == tilted and not bm.turned_quads(V)[corner]
        assert bm.tilted_quads(V, degrees=80.0).sum() == 0
    V = P.copy()
    V[edge, 0] = -1.0  # pushed past the quad's other edge: turned over, and so tilted too
    assert bm.turned_quads(V)[corner] and bm.tilted_quads(V)[corner] and bm.quad_tilt(V)[corner] == -1.0


def test_published_kitten_stress_test_certified_with_its_surface_unfolded():
    """kitten_with_bifur_3 with every interior vertex moved by up to 3 edge lengths: before stage 1's surface term,
    its untangling slid boundary vertices until 93 of its boundary quads turned over in its first second, and one
    start (the same moved by 1e-12 of the diagonal) ended its 60 s with 15 hexes inverted; the others were certified
    with 133-169 quads turned over (the hexes valid, their surface folded through itself)."""
    from conftest import published

    path = published(os.path.join("hexalab", "kitten_with_bifur_3.mesh"))
    mesh = hs.read(path)
    mesh = mesh.flipped(cells=mesh.mirrored_cells())  # as `hexsos repair --fix-orientation` (it folds over itself)
    P = stress(mesh.points, mesh.hexes, frac=1.0, amp=3.0, seed=1)
    r = hs.repair(P, mesh.hexes)
    assert r.stats["invalid_before"] > 34000
    assert r.success and r.stats["invalid_after"] == 0 and r.stats["turned_quads_before"] == 0
    assert r.stats["turned_quads_after"] == 0
    assert r.stats["min_sj_after"] > 0.3
    assert "boundary quads turned over" in r.summary()


def test_straighten_quads_turns_a_quad_back_out_and_stands_a_tilted_one_up_without_lowering_the_minimum(monkeypatch):
    """A top quad of a 3 x 3 slab whose input normal leans toward -x, -y (set by hand): leaning by 101 degrees the
    quad is turned over, by 78 only tilted; raising its corner at the slab's centre (shared by four hexes) turns it
    back. With a hex elsewhere at 0.5 the step costs nothing below the minimum and is kept; with every hex a unit
    cube (the minimum 1) any step lowers it, and nothing moves; nor does a pinned vertex. (A band of 0.8 of an edge,
    its cap by the diagonal lifted: the step leaves the surface by more than 1.2% of this small slab's diagonal.)"""
    from hexsos_plugins.cells.quality import scaled_jacobian
    from hexsos_plugins.meshrepair import boundary
    from hexsos_plugins.meshrepair.localopt import straighten_quads

    monkeypatch.setattr(boundary, "BAND_DIAGONAL", 1.0)

    P, H = _slab(4)
    low = P.copy()
    far = int(np.flatnonzero((P == [3, 3, 1]).all(axis=1))[0])
    low[far] += [0.6, 0.6, 0.0]  # one corner hex far from the quad, sheared: the mesh's minimum
    mine = float(scaled_jacobian(low, H).min())
    assert 0.3 < mine < 0.9
    movable = np.ones(len(P), dtype=bool)
    for lean, turned in ((-0.2, True), (0.3, False)):
        bm = boundary_model(P, [("hexahedron", H)], tolerance=0.8)
        q = int(np.flatnonzero(np.all(P[bm.quads][:, :, 2] == 1, axis=1)
                               & np.all(P[bm.quads][:, :, :2].max(axis=1) == 1, axis=1))[0])  # top, x, y in [0, 1]
        bm.quad_normal[q] = np.array([-1.0, -1.0, lean]) / np.sqrt(2.0 + lean * lean)
        assert np.flatnonzero(bm.tilted_quads(low)).tolist() == [q] and bm.turned_quads(low)[q] == turned
        V, info = straighten_quads(low, H, movable, bm)
        assert (info["turned_before"], info["turned_after"]) == (int(turned), 0)
        assert (info["tilted_before"], info["tilted_after"]) == (1, 0) and info["steps"] > 0
        assert not bm.tilted_quads(V).any() and not bm.turned_quads(V).any()
        moved = np.flatnonzero((V != low).any(axis=1))
        assert set(moved) <= set(bm.quads[q]) and len(moved) >= 1
        assert float(scaled_jacobian(V, H).min()) >= mine - 1e-12
        assert (hs.check(V, H).status == 1).all()
        # the minimum at 1: the quad stays and nothing moves
        V1, info1 = straighten_quads(P, H, movable, bm)
        assert info1["tilted_after"] == 1 and info1["steps"] == 0 and np.array_equal(V1, P)
        # its vertices pinned: the same
        still = movable.copy()
        still[bm.quads[q]] = False
        V2, info2 = straighten_quads(low, H, still, bm)
        assert info2["tilted_after"] == 1 and np.array_equal(V2, low)


def test_closest_point_of_one_vertex_is_closest_of_every_kind_and_quad_tilt_of_some_rows_is_theirs():
    """``BoundaryModel.closest_point`` (one vertex at a trial position) gives what ``closest`` gives for it: on a
    cube (3^3 hexes, 45 degree features) a face vertex, an edge vertex and a corner, each moved off; an interior
    vertex is refused. ``quad_tilt(V, rows)`` is ``quad_tilt(V)[rows]``."""
    from hexsos_plugins.errors import InvalidInputError
    from hexsos_plugins.examples import structured_grid

    P, H = structured_grid(3)
    bm = boundary_model(P, [("hexahedron", H)])
    V = P + 0.07 * np.random.default_rng(3).uniform(-1, 1, P.shape)
    kind = dict(zip(bm.vertices.tolist(), bm.kind.tolist()))
    picks = [next(v for v, k in kind.items() if k == want) for want in (0, 1, 2)]
    full = bm.closest(V, picks)
    for v in picks:
        assert np.array_equal(bm.closest_point(V[v], v), full[v])
        assert not np.array_equal(full[v], V[v])
    inside = int(np.setdiff1d(np.arange(len(P)), bm.vertices)[0])
    with pytest.raises(InvalidInputError, match="boundary vertex"):
        bm.closest_point(V[inside], inside)
    rows = [5, 0, 17]
    assert np.array_equal(bm.quad_tilt(V, rows), bm.quad_tilt(V)[rows])
