"""The compiled kernel against exact rational arithmetic and VTK, for every cell type.

Every claim about a verdict is checked against an independent reference: exact Bernstein coefficients by
another road (tests/exact_reference.py), exact det J at points, and dense sampling on VTK's own shape
functions (tests/vtk_oracle.py).
"""

from fractions import Fraction

import numpy as np
import pytest

import exact_reference as ref
import vtk_oracle
from hexsos_plugins import check
from hexsos_plugins import kernel
from hexsos_plugins.generate import codegen
from hexsos_plugins.kernel import calls as kcalls
from hexsos_plugins.kernel import compiled as kcompiled
from hexsos_plugins.kernel import cell_tables as ktables
from hexsos_plugins.cells.elements import CELL_TYPES, ELEMENTS

TYPES = [n for n in CELL_TYPES if ELEMENTS[n].order <= 2]  # orders 3-5: tests/test_curved.py
QUADRATIC = {"tetra10", "wedge15", "wedge18", "hexahedron20", "hexahedron27", "pyramid13", "pyramid14"}


def _mirror(name):
    """The node permutation exchanging the parametric r and s (a reflection: every det J changes sign)."""
    el = ELEMENTS[name]
    nodes = [tuple(x) for x in el.nodes]
    return np.array([nodes.index((x[1], x[0], x[2])) for x in nodes])


def _reference(name):
    X = vtk_oracle.reference_nodes(name)
    return X


def _perturbed(name, m, sigma, seed):
    rng = np.random.default_rng(seed)
    X0 = _reference(name)
    return X0[None] + sigma * rng.standard_normal((m,) + X0.shape)


def _run(name, X):
    X = np.asarray(X, float)
    if X.ndim == 2:
        X = X[None]
    P = X.reshape(-1, 3)
    conn = np.arange(P.shape[0]).reshape(X.shape[0], -1)
    return check(P, [(name, conn)])


def _adversarial(name, seed):
    """Cells near the edge of validity and of float64: exact zeros (repeated nodes), ulp shifts, near-flat,
    needles, coordinates from subnormal to 1e300, large offsets."""
    rng = np.random.default_rng(seed)
    X0 = _reference(name)
    out = []
    # an exact zero: two corner nodes made equal (det J = 0 along the collapsed edge)
    Z = X0.copy()
    Z[1] = Z[0]
    out.append(Z)
    # one ulp either side of a cell whose det J vanishes at a corner: node 1 moved onto node 0's other edges' plane
    W = X0 + 0.05 * rng.standard_normal(X0.shape)
    W[1, 2] = W[0, 2]
    for step in (-1, 1):
        V = W.copy()
        V[1, 2] = np.nextafter(V[1, 2], step * np.inf)
        out.append(V)
    # near-flat (one direction squeezed after a rotation), needles, extreme magnitudes, offsets
    Q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    for eps in (1e-9, 1e-15):
        out.append((X0 * [1, 1, eps]) @ Q.T)
    for k in (300, 520, 540):
        out.append(X0 * [1.0, 2.0**-k, 2.0**-k])
    base = X0 + 0.1 * rng.standard_normal(X0.shape)
    for e in (-1070, -600, 600, 1000):
        out.append(np.ldexp(base, e))
    out.append(base * 5e-324 * 2**20)
    out.append(base + 1e15)
    out.append(base * 1e150 + 1e300)
    return out


def _exact_points(name, X, r, i, rng, k=6):
    """Rational points where the reference evaluates det J: the cell's vertices, the argmin, random points."""
    el = ELEMENTS[name]
    pts = [tuple(x) for x in el.nodes[: el.corners]]
    pts.append(tuple(Fraction(float(v)) for v in r.argmin[i]))
    for _ in range(k):
        x = rng.random(3)
        if el.domain == "tet":
            x = x / max(1.0, x.sum())
        elif el.domain == "prism":
            x[:2] = x[:2] / max(1.0, x[:2].sum())
        pts.append(tuple(Fraction(float(v)).limit_denominator(2**20) for v in x))
    if name == "pyramid":  # the linear pyramid's measure does not depend on t: its table has degree 0 there
        pts = [(p[0], p[1], Fraction(0)) for p in pts]
    return pts


@pytest.mark.parametrize("name", TYPES)
def test_coefficients_lie_within_their_rounding_bound(name):
    """|b - b_exact| <= err for every coefficient, b_exact from the independent reference, on adversarial cells."""
    cells = _adversarial(name, 1) + list(_perturbed(name, 3 if name in QUADRATIC else 6, 0.3, 2))
    for X in cells:
        X = np.asarray(X, float)
        P = X.reshape(-1, 3)
        conn = np.arange(P.shape[0])[None]
        b, err, k, _ = kernel.coefficients(P, conn, [0], name)
        assert np.isfinite(b).all() and np.isfinite(err).all()
        exact = ref.exact_coefficients(X, name)
        scale = Fraction(2) ** (-3 * int(k[0]))
        bound = Fraction(float(err[0]))
        worst = max(abs(Fraction(float(bj)) - e * scale) for bj, e in zip(b[0], exact))
        assert worst <= bound, (name, X.tolist(), float(worst), float(bound))


@pytest.mark.parametrize("name", TYPES)
def test_verdicts_are_proofs_on_adversarial_cells(name):
    """valid: the lower bound is <= exact det J at the vertices, the argmin and random points, all > 0;
    invalid: det J at the argmin is <= 0 exactly; min_det is det J at the argmin (to the bracket's width);
    never NaN."""
    rng = np.random.default_rng(3)
    cells = _adversarial(name, 4) + list(_perturbed(name, 4 if name in QUADRATIC else 12, 0.35, 5))
    decided = 0
    for X in cells:
        r = _run(name, X)
        assert np.isfinite(r.min_det).all() and not np.isnan(r.lower_bound).any()
        i = 0
        vals = [ref.exact_det(X, name, p) for p in _exact_points(name, X, r, i, rng)]
        low = Fraction(float(r.lower_bound[i])) if np.isfinite(r.lower_bound[i]) else None
        if low is not None:
            assert all(low <= v for v in vals), (name, X.tolist())
        if r.status[i] == 1:
            decided += 1
            assert r.lower_bound[i] >= 0 and all(v > 0 for v in vals)
        elif r.status[i] == 0:
            decided += 1
            at = ref.exact_det(X, name, [Fraction(float(v)) for v in r.argmin[i]])
            assert at <= 0, (name, X.tolist(), float(at))
        if r.status[i] != -1 and not r.unrepresentable[i]:
            at = ref.exact_det(X, name, [Fraction(float(v)) for v in r.argmin[i]])
            # within the bracket's width (1e-9 of the scale, or the rounding bound of a near-flat cell)
            tol = Fraction(1, 10**9) * Fraction(float(r.scale[i])) + Fraction(float(r.gap[i])) + Fraction(2) ** -1000
            assert abs(Fraction(float(r.min_det[i])) - at) <= tol
    assert decided >= len(cells) - 3  # only exactly flat cells may stay undecided


@pytest.mark.parametrize("name", TYPES)
def test_unit_mirrored_and_flat_cells(name):
    X = _reference(name)
    r = _run(name, np.stack([X, X[_mirror(name)], X * [1, 1, 0]]))
    assert r.status.tolist() == [1, 0, -1]
    assert r.min_det[:2].tolist() == [1.0, -1.0]
    assert r.lower_bound[0] <= 1.0 and r.lower_bound[0] > 1.0 - 1e-12
    assert r.method_names()[2] == "flat"
    assert r.cell_type_names().tolist() == [name] * 3


@pytest.mark.parametrize("name", [t for t in TYPES if t not in ("tetra", "pyramid")])
def test_valid_at_every_node_but_invalid_inside(name):
    """A cell with det J > 0 at all its nodes but < 0 inside: what node and corner checks miss. Candidates
    (seeded): one node pushed far, a little noise on all; the first that VTK sampling shows negative inside."""
    el = ELEMENTS[name]
    X0 = _reference(name)
    rng = np.random.default_rng(11)
    nodes = el.reference_nodes.copy()
    if el.domain == "pyramid":
        nodes = np.delete(nodes, 4, axis=0)  # the measure has no single value at the apex
    for trial in range(3000):
        if trial % 2:
            X = X0 + 0.04 * rng.standard_normal(X0.shape)
            X[rng.integers(X0.shape[0])] += rng.uniform(0.3, 1.2) * rng.standard_normal(3)
        else:
            X = X0 + 0.45 * rng.standard_normal(X0.shape)
        at_nodes = el.det(X, nodes)[0]
        if at_nodes.min() <= 0.05:
            continue
        d = vtk_oracle.det(name, X[None], vtk_oracle.grid(name, 9))[0].min()
        if d < -1e-3:
            break
    else:
        pytest.fail(f"no inside-only inversion found for {name}")
    r = _run(name, X)
    assert r.status[0] == 0 and r.corner_min_det[0] > 0 and r.invalid_inside_only[0]
    assert r.min_det[0] <= d + 1e-12


def test_linear_tetrahedra_and_pyramids_cannot_fold_inside():
    """The two types where inside-only inversion cannot exist: det J of a linear tet is constant, and the
    measure of a linear pyramid is bilinear in (r, s) (the r^2 and s^2 terms cancel: B_r and B_s share the base's
    twist vector), so its minimum is at a base corner."""
    X = _perturbed("tetra", 50, 0.4, 12)
    r = _run("tetra", X)
    d = vtk_oracle.det("tetra", X, vtk_oracle.grid("tetra", 5))
    assert np.allclose(d.min(axis=1), d.max(axis=1), rtol=1e-12, atol=1e-14)
    assert np.allclose(r.min_det, d[:, 0], rtol=1e-12, atol=1e-14)
    assert np.array_equal(r.status == 1, d[:, 0] > 0)
    X = _perturbed("pyramid", 200, 0.6, 13)
    r = _run("pyramid", X)
    d = vtk_oracle.det("pyramid", X, vtk_oracle.grid("pyramid", 9))
    corners = vtk_oracle.det("pyramid", X, np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float))
    assert np.allclose(d.min(axis=1), corners.min(axis=1), rtol=1e-9, atol=1e-12)
    assert np.allclose(r.min_det, corners.min(axis=1), rtol=1e-9, atol=1e-12)
    assert np.array_equal(r.status == 1, corners.min(axis=1) > 0) and not r.invalid_inside_only.any()
    assert (r.status == 0).any() and (r.status == 1).any()


@pytest.mark.parametrize("name", TYPES)
def test_minimum_against_vtk_dense_sampling(name):
    """min det J within 1e-7 (relative to the scale) of VTK-based dense sampling, never above it; argmin
    where the minimizer is unique; never valid where sampling finds det J <= 0."""
    m = 8 if name in QUADRATIC else 24
    X = _perturbed(name, m, 0.25, 21)
    r = _run(name, X)
    d, p, unique = vtk_oracle.dense_min(name, X)
    scale = r.scale
    tol = vtk_oracle.ROUNDING.get(name, 0.0) * scale  # the sampler's own rounding (Gmsh's pyramids)
    assert np.all(r.min_det <= d + 1e-12 * scale)  # a minimum is never above a sampled value
    assert np.all(d - r.min_det <= 1e-7 * scale + 1e-3 * np.abs(d - r.min_det).clip(max=0)), (d - r.min_det) / scale
    assert not np.any((r.status == 1) & (d <= 0))
    assert np.all(r.lower_bound <= d + tol)
    close = unique & (np.abs(d - r.min_det) < 1e-9 * scale)
    dist = np.linalg.norm((r.argmin - p)[:, :2 if name == "pyramid" else 3], axis=1)
    assert np.all(dist[close] < 2e-3), dist[close]
    assert np.all(r.gap <= 1e-9 * scale * (1 + 1e-6) + 1e-300)  # every bracket closed to the tolerance


@pytest.mark.parametrize("name", TYPES)
def test_invariance_under_rigid_motions_and_scaling(name):
    X = _perturbed(name, 6 if name in QUADRATIC else 20, 0.3, 31)
    r = _run(name, X)
    rng = np.random.default_rng(32)
    Q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    if np.linalg.det(Q) < 0:
        Q[:, 0] *= -1
    moved = _run(name, X @ Q.T + [3.5, -1.25, 1e3])
    far = np.abs(r.min_det) > 1e-9 * r.scale
    assert np.array_equal(r.status[far], moved.status[far])
    assert np.allclose(r.min_det, moved.min_det, rtol=1e-9, atol=1e-9 * r.scale.max())
    for e in (-300, 300):  # powers of two: everything scales exactly (det J by 2^(3e), within float64's range)
        s = _run(name, np.ldexp(X, e))
        assert np.array_equal(s.status, r.status)
        assert np.array_equal(s.min_det, np.ldexp(r.min_det, 3 * e))
    axis = _run(name, X * [1e6, 1.0, 1e-6])  # per-axis scaling: det J scales by 1, the verdicts stay
    assert np.array_equal(axis.status, r.status) and not (axis.method_names() == "flat").any()


def test_every_finite_input_gives_an_honest_answer():
    """Issue cases at the edges of float64: the verdict matches exact arithmetic, no NaN, flags set where the
    value cannot be held in the input's units."""
    from hexsos_plugins.examples import unit_cube

    a = np.array([[0.0, 0.0, 0.0], [1.152921504606847e+18, 0.0, 0.0], [1.152921504606847e+18, 1.152921504606847e+18, 0.0],
                  [0.0, 4.5569512622227484e-305, 1.7088567233335307e-305], [0.0, 4.611686018427388e+18, 1.152921504606847e+18],
                  [1.152921504606847e+18, 4.611686018427388e+18, 1.152921504606847e+18],
                  [1.152921504606847e+18, 5.764607523034235e+18, 1.152921504606847e+18],
                  [0.0, 5.764607523034235e+18, 1.152921504606847e+18]])
    b = np.array([[0.0, 0.0, -0.25], [1.5, 0.5, -0.25], [1.0, 1.5, 0.0], [-0.25, 1.5, 0.25], [0.25, 0.25, 0.5],
                  [1.0, 5e-324, 0.75], [0.5, 0.75, 0.75], [-0.5, 0.75, 0.75]])
    c = unit_cube() * 2.0**60
    c[3] = (0.0, 5.696189077778436e-306, 0.0)
    cells = {"truly invalid": (a, 0), "truly valid, min 3e-324": (b, 1), "2^60 cube, tiny node": (c, 1)}
    for k in (515, 520, 530, 540):
        cells[f"needle 2^-{k}"] = (unit_cube() * [1, 2.0**-k, 2.0**-k], 1)
    cells["subnormal coordinates"] = (unit_cube() * 1e-310, 1)
    cells["spanning +-1.5e308"] = ((unit_cube() * 2 - 1) * 1.5e308, 1)
    for label, (X, want) in cells.items():
        r = _run("hexahedron", X)
        assert r.status[0] == want, label
        assert np.isfinite(r.min_det[0]) and not np.isnan(r.lower_bound[0]), label
        assert np.sign(r.min_det[0]) == (1 if want == 1 else np.sign(r.min_det[0])), label
        if want == 1:
            assert r.min_det[0] > 0 and r.lower_bound[0] >= 0, label
    # a cell whose minimum is below the float range is flagged; one within it is not
    assert _run("hexahedron", unit_cube() * 1e-310).unrepresentable[0]
    assert not _run("hexahedron", unit_cube() * 1e-100).unrepresentable[0]
    # invalid hexes far below 1: the lower bound is never above the minimum
    for s in (1e-200, 1e-300):
        X = unit_cube() * s
        X[6] = X[0] - 0.3 * s
        r = _run("hexahedron", X)
        assert r.status[0] == 0 and r.lower_bound[0] <= r.min_det[0] < 0


def _to_world_reference(v, k3, *, down):
    """The conversion to world units with numpy's ldexp (what the check did before it was compiled)."""
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        w = np.ldexp(v, k3)
        back = np.ldexp(w, -k3)
    inexact = np.isfinite(w) & (back != v)
    over = ~np.isfinite(w) & np.isfinite(v)
    if down:
        lower = inexact & (back > v)
        w[lower] = np.nextafter(w[lower], -np.inf)
        w[over & (v > 0)] = np.finfo(np.float64).max
        w[over & (v < 0)] = -np.inf
        bad = over | (inexact & (np.abs(w) < 2.0**-1022))
    else:
        zero = (w == 0) & (v != 0)
        w[zero] = np.copysign(5e-324, v[zero])
        w[over] = np.copysign(np.finfo(np.float64).max, v[over])
        bad = over | zero
    return w, bad


def _world_by_finish(v, k, *, down):
    """kernel.finish's conversion of v as a lower bound (down) or as a value, the other one 0 (always exact, so
    the unrepresentable flags are v's alone)."""
    n = len(v)
    z = np.zeros(n)
    value, lower = (z.copy(), v.copy()) if down else (v.copy(), z.copy())
    _, _, bad = kernel.finish(value, lower, z.copy(), z.copy(), z.copy(), k, np.zeros(n, dtype=bool),
                              np.zeros(n, dtype=bool))
    return (lower if down else value), bad


def test_world_units_round_as_ldexp_and_in_the_right_direction():
    """The compiled conversion of the kernel's scaled values to world units (exponents 3k; products by powers
    of two within the normal range, ldexp beyond it) is bit-identical to numpy's ldexp with the same rounding rules on adversarial values: results in
    the subnormal range, overflowing, zeros, infinities, NaN, exponents far beyond the float range; a lower
    bound is never rounded up and a value keeps its sign."""
    rng = np.random.default_rng(11)
    n = 20000
    v = rng.standard_normal(n) * 2.0 ** rng.integers(-1074, 1000, n).astype(float)
    v[:9] = [0.0, -0.0, np.inf, -np.inf, 5e-324, -5e-324, 1.7e308, -2.2250738585072014e-308, np.nan]
    k = rng.integers(-400, 400, n)
    k[:9] = [-340, 340, 5, -5, 340, -340, 1000, -1000, 3]
    # exponents changing at every value, and in runs (the powers of two are formed once per run)
    for down, k in ((False, k), (True, k), (False, np.sort(k)), (True, np.sort(k))):
        want_w, want_bad = _to_world_reference(v.copy(), 3 * k, down=down)
        w, bad = _world_by_finish(v, k, down=down)
        assert np.array_equal(w.view(np.int64), want_w.view(np.int64)) and np.array_equal(bad, want_bad)
        fin = np.flatnonzero(np.isfinite(w) & np.isfinite(v) & (w != v))  # rounded or scaled
        rounded = [i for i in fin if Fraction(float(w[i])) != Fraction(float(v[i])) * Fraction(2) ** int(3 * k[i])]
        assert len(rounded) > 20
        for i in rounded:
            exact = Fraction(float(v[i])) * Fraction(2) ** int(3 * k[i])
            if down:  # a lower bound never rounds up
                assert Fraction(float(w[i])) < exact
            else:  # a value keeps its sign
                assert np.sign(w[i]) == np.sign(v[i]) != 0
    assert 0 < bad.sum() < n  # the adversarial values do reach the rounding branches


def test_finish_gives_the_verdict_rules_and_the_world_units_of_the_reference():
    """kernel.finish (the check's last compiled pass) gives the verdict rules (valid: lower > 0, invalid:
    value + err <= 0, flat: undecided; near: undecided, not flat, bracket closed or value within 64 err of 0)
    and the world units of the reference conversion, bit for bit, on adversarial values with NaN and exponents
    beyond the float range; lower bounds rounded down, the rest to nearest."""
    rng = np.random.default_rng(12)
    n = 6000
    value = rng.standard_normal(n) * 2.0 ** rng.integers(-1074, 1000, n).astype(float)
    lower = value - np.abs(rng.standard_normal(n)) * 2.0 ** rng.integers(-1074, 1000, n).astype(float)
    err = np.abs(value) * 2.0 ** rng.integers(-60, 2, n).astype(float)
    value[:6] = [np.nan, 0.0, -0.0, 1e-300, -1e-300, np.inf]
    lower[:6] = [np.nan, 0.0, -1.0, 1e-320, -np.inf, 1.0]
    corner, scale = rng.standard_normal(n), np.abs(rng.standard_normal(n)) + 1.0
    k = np.sort(rng.integers(-400, 400, n))
    flat, closed = rng.random(n) < 0.1, rng.random(n) < 0.5
    want_status = np.full(n, -1, dtype=np.int8)
    want_status[lower > 0] = 1
    want_status[value + err <= 0] = 0
    want_status[flat] = -1
    want_near = (want_status == -1) & ~flat & (closed | (np.abs(value) <= 64.0 * err))
    want = [_to_world_reference(a.copy(), 3 * k, down=d) for a, d in ((value, False), (lower, True), (corner, False),
                                                                     (scale, False))]
    got = [a.copy() for a in (value, lower, err, corner, scale)]
    status, near, bad = kernel.finish(*got, k, flat, closed)
    assert np.array_equal(status, want_status) and np.array_equal(near, want_near)
    assert {0, 1, -1} <= set(status.tolist()) and near.any()
    for a, (w, _) in zip((got[0], got[1], got[3], got[4]), want):
        assert np.array_equal(a.view(np.int64), w.view(np.int64))
    assert np.array_equal(got[2], err)  # err stays in scaled units
    assert np.array_equal(bad, want[0][1] | want[1][1]) and 0 < bad.sum() < n
    # negative case: the rules are not a constant: moving every lower bound above 0 changes the verdicts
    status2, _, _ = kernel.finish(np.full(n, 2.0), np.ones(n), err.copy(), corner.copy(), scale.copy(), k,
                                  np.zeros(n, dtype=bool), closed)
    assert (status2 == 1).all() and not np.array_equal(status2, status)


def test_flatness_scale_is_not_a_free_knob():
    """Flat means det J tiny against its own terms (a sheared slab), not a small cell nor a thin one: the top face
    moved in its plane with height 1e-6 is decided, with 1e-14 it is flat (undecided at once, no exact work);
    a thin box 1 x 1 x 1e-14, rotated, is as well conditioned as a cube."""
    from hexsos_plugins.examples import unit_cube

    Q, _ = np.linalg.qr(np.random.default_rng(5).standard_normal((3, 3)))

    def slab(h):
        X = unit_cube()
        X[4:] = X[:4] + [0.6, 0.3, h]
        return X @ Q.T

    r = _run("hexahedron", np.stack([slab(1e-6), slab(1e-14), (unit_cube() * [1, 1, 1e-14]) @ Q.T]))
    assert r.status.tolist() == [1, -1, 1]
    assert r.method_names().tolist()[1] == "flat"
    assert r.method_names().tolist()[2] != "flat"


def test_no_fastmath_in_anything_that_feeds_a_bound():
    from numba.core.registry import CPUDispatcher

    from hexsos_plugins.kernel import generated as _kernel_gen
    from hexsos_plugins.kernel import source as _kernel_src

    found = [f for m in (_kernel_src, _kernel_gen) for f in vars(m).values() if isinstance(f, CPUDispatcher)]
    assert len(found) > 15
    for f in found:
        assert not f.targetoptions.get("fastmath"), f.__name__


def test_compiled_extension_is_built_from_this_source_and_matches_the_jit():
    """The extension compiled at install is in use (no compilation at run time) and gives bit-identical results
    to numba's just-in-time compilation of the same source."""
    from hexsos_plugins.kernel import source as _kernel_src

    assert kernel.implementation() == "aot", "the compiled kernel extension was not built (pip install -e .)"
    from hexsos_plugins.kernel import aot as _kernel_aot

    for name in ("hexahedron", "wedge15", "pyramid", "pyramid13", "tetra10"):  # (tetra10: the bisection)
        X = _perturbed(name, 40, 0.3, 51)
        P = X.reshape(-1, 3)
        conn = np.arange(P.shape[0]).reshape(X.shape[0], -1)
        ids = np.arange(len(conn))
        t = kernel.tables(name)
        outs = []
        for impl in (_kernel_aot, _kernel_src):
            out = kcalls.run_outputs(len(ids))
            impl.run_chunk(*kcalls.run_args(P, conn, ids, t, out, 0, len(ids)))
            outs.append(out)
        for key in outs[0]:
            assert np.array_equal(outs[0][key], outs[1][key]), (name, key)


def test_saved_tables_are_the_computed_ones():
    """The tables written at build time (loaded at run time) equal the ones computed from the exact rationals."""
    saved = ktables.saved_tables("hexahedron27")
    assert saved is not None, "the tables file is missing or stale (pip install -e . writes it)"
    fresh = kernel.Tables("hexahedron27")
    for f in ktables.TABLE_FIELDS:
        assert np.array_equal(getattr(saved, f), getattr(fresh, f)), f


def test_threads_give_identical_results():
    X = _perturbed("hexahedron", 3000, 0.3, 41)
    P = X.reshape(-1, 3)
    H = np.arange(P.shape[0]).reshape(-1, 8)
    one, two = check(P, H, jobs=1), check(P, H, jobs=2)
    for name in ("min_det", "lower_bound", "argmin", "status", "method"):
        assert np.array_equal(getattr(one, name), getattr(two, name)), name


def _box_quadratic_min(Q, q, c):
    """The exact minimum of x^T Q x / 2 + q . x + c over [0, 1]^3 (any symmetric Q): every face, edge and vertex
    of the cube by its KKT point (each coordinate free, at 0 or at 1), an oracle independent of the kernel."""
    import itertools

    best = np.inf
    for fix in itertools.product((None, 0.0, 1.0), repeat=3):
        free = [a for a in range(3) if fix[a] is None]
        x = np.array([0.0 if f is None else f for f in fix])
        if free:
            Qf = Q[np.ix_(free, free)]
            rhs = -(q[free] + Q[np.ix_(free, [a for a in range(3) if a not in free])] @ x[[a for a in range(3) if a not in free]]
                    if len(free) < 3 else q[free])
            try:
                xf = np.linalg.solve(Qf, rhs)
            except np.linalg.LinAlgError:
                continue
            if np.any(xf < 0) or np.any(xf > 1):
                continue
            x[free] = xf
        best = min(best, 0.5 * x @ Q @ x + q @ x + c)
    return best


def test_second_order_bound_is_below_the_exact_minimum_and_tight_near_it():
    """The kernel's Taylor bound on a box (Bernstein coefficients of a quadratic) is never above the quadratic's
    exact minimum there, convex or not, minimizer inside or on the boundary; at the minimizer of a convex one
    it is within rounding of the minimum."""
    from hexsos_plugins.kernel import source as src

    rng = np.random.default_rng(61)
    sp = kernel.tables("hexahedron")
    mono = sp.exps  # the 27 monomial exponents; M maps Bernstein to monomial coefficients
    Minv = np.linalg.inv(sp.M)
    W, Wd = np.zeros((3, 3)), np.zeros(3)
    F3, F33, I3 = np.zeros((4, 3)), np.zeros((4, 3, 3)), np.zeros((2, 3), dtype=np.int64)
    tight = 0
    for trial in range(300):
        A = rng.standard_normal((3, 3))
        Q = A @ A.T if trial % 2 else A + A.T  # convex or indefinite
        x0 = rng.uniform(-0.3, 1.3, 3)
        q = -Q @ x0
        c = rng.standard_normal()
        mono_c = np.zeros(len(mono))
        for m, e in enumerate(mono):
            e = tuple(e)
            if e == (0, 0, 0):
                mono_c[m] = c
            elif sum(e) == 1:
                mono_c[m] = q[int(np.argmax(e))]
            elif sum(e) == 2 and max(e) == 2:
                a = int(np.argmax(e))
                mono_c[m] = 0.5 * Q[a, a]
            elif sum(e) == 2:
                a, b = np.flatnonzero(e)
                mono_c[m] = Q[a, b]
        bern = Minv @ mono_c
        exact = _box_quadratic_min(Q, q, c)
        for t in (np.clip(x0, 0, 1), rng.random(3), np.array([0.0, 1.0, 0.5])):
            bound = src.taylor_bound(bern, 1e-15, np.ascontiguousarray(t), sp.sizes, W, Wd, F3, F33, I3)
            assert bound <= exact + 1e-12 * (1 + abs(exact)), (trial, t, bound, exact)
        if trial % 2 and np.all((x0 > 0) & (x0 < 1)):
            bound = src.taylor_bound(bern, 0.0, np.ascontiguousarray(x0), sp.sizes, W, Wd, F3, F33, I3)
            assert bound >= exact - 1e-9 * (1 + abs(exact))
            tight += 1
    assert tight > 10


def test_compiled_scaled_jacobian_is_verdicts_as_quality_computes_it():
    """The compiled scaled Jacobian (what hexsos check reports) equals quality.scaled_jacobian, itself tested
    against vtkMeshQuality, on random cells of every linear type, inverted ones included; quadratic cells get
    their corners' value (Verdict's convention)."""
    from hexsos_plugins.cells import quality

    rng = np.random.default_rng(71)
    for name, X0 in quality.IDEAL.items():
        X = X0[None] + 0.35 * rng.standard_normal((500,) + X0.shape)
        P = X.reshape(-1, 3)
        C = np.arange(len(P)).reshape(len(X), -1)
        a, b = quality.scaled_jacobian(P, [(name, C)]), kernel.scaled_jacobian(P, [(name, C)])
        assert (a < 0).any() and (a > 0.5).any()
        assert np.allclose(a, b, rtol=0, atol=1e-13), name
    for name, linear in (("hexahedron27", "hexahedron"), ("hexahedron20", "hexahedron"), ("wedge15", "wedge"),
                         ("wedge18", "wedge"), ("tetra10", "tetra")):
        X = _perturbed(name, 40, 0.4, 72)
        n = X.shape[1]
        C = np.arange(X.shape[0] * n).reshape(-1, n)
        got = kernel.scaled_jacobian(X.reshape(-1, 3), [(name, C)])
        k = ELEMENTS[linear].n_nodes
        want = quality.scaled_jacobian(X[:, :k].reshape(-1, 3), [(linear, np.arange(X.shape[0] * k).reshape(-1, k))])
        assert np.isfinite(got).all() and np.allclose(got, want, rtol=0, atol=1e-13), name
        assert (got < 0.9).any()  # perturbed corners: not the ideal value everywhere


def test_generated_scaled_jacobian_is_current_and_bit_identical_to_the_table_loop(monkeypatch):
    """Each linear type's scaled Jacobian runs straight-line generated code (_kernel_gen) that gives the table
    loop's numbers bit for bit, on random, inverted, ideal and degenerate cells; a sample table the generated code
    was not made from is not used (its fingerprint differs), and would give other numbers."""
    from hexsos_plugins.cells import quality

    rng = np.random.default_rng(74)
    for name, X0 in quality.IDEAL.items():
        X = X0[None] + 0.4 * rng.standard_normal((400,) + X0.shape)
        X[0] = X0
        X[1] = 0.0  # every node at one point: every edge product 0
        X[2, 1:] = X[2, 0] + 1e-170  # edge products below the smallest normal number
        X[3] = X0 * np.array([1.0, 1.0, -1.0])  # inverted
        P = X.reshape(-1, 3)
        C = np.arange(len(P)).reshape(len(X), -1)
        ids = np.arange(len(C))
        assert ktables.sj_id(name) == ktables.SJ_GENERATED.index(name) + 1
        gen, loop = np.empty(len(C)), np.empty(len(C))
        kcompiled.impl.scaled_jacobian_chunk(*kcalls.sj_args(P, C, ids, name, gen, 0, len(C)))
        kcompiled.impl.scaled_jacobian_chunk(*kcalls.sj_args(P, C, ids, name, loop, 0, len(C), generated=False))
        assert np.array_equal(gen, loop), name
        assert gen[1] == 0.0 and gen[2] == 0.0 and gen[3] < 0 < gen[0] and (gen < 0).any() and (gen > 0.5).any()
    # negative case: swap two samples' first columns: the loop computes other numbers, the fingerprint moves
    real = ktables.sj_tables

    def swapped(name):
        vptr, vnode, vw, samp, ssign, factor = real(name)
        samp = samp.copy()
        samp[[0, 1], 0] = samp[[1, 0], 0]
        return vptr, vnode, vw, samp, ssign, factor

    X = quality.IDEAL["hexahedron"][None] + 0.3 * rng.standard_normal((50, 8, 3))
    P, C = X.reshape(-1, 3), np.arange(400).reshape(50, 8)
    before = kernel.scaled_jacobian(P, C)
    monkeypatch.setattr(ktables, "sj_tables", swapped)
    monkeypatch.setattr(kcalls, "sj_tables", swapped)
    assert ktables.sj_id("hexahedron") == 0
    other = np.empty(50)
    kcompiled.impl.scaled_jacobian_chunk(*kcalls.sj_args(P, C, np.arange(50), "hexahedron", other, 0, 50))
    assert not np.array_equal(before, other)


def test_the_compiled_kernel_releases_the_gil():
    """The kernel's threads run in parallel only if its compiled calls release the GIL: while one runs, another
    Python thread keeps counting (with the GIL held it would stand still for the whole call)."""
    import threading

    from hexsos_plugins.examples import structured_grid

    P, H = structured_grid(60)  # 216,000 hexes: a call of a good fraction of a second
    ids = np.arange(len(H))
    t = kernel.tables("hexahedron")
    out = kcalls.run_outputs(len(ids))
    kcompiled.impl.run_chunk(*kcalls.run_args(P, H, ids, t, out, 0, 10))
    done, count = threading.Event(), [0]

    def spin():
        while not done.is_set():
            count[0] += 1

    th = threading.Thread(target=spin)
    th.start()
    try:
        while count[0] == 0:
            pass
        c0 = count[0]
        kcompiled.impl.run_chunk(*kcalls.run_args(P, H, ids, t, out, 0, len(ids)))
        c1 = count[0]
    finally:
        done.set()
        th.join()
    assert c1 - c0 > 10_000, c1 - c0


@pytest.mark.parametrize("name", ["tetra10", "wedge15", "wedge18", "hexahedron27"])
def test_argmin_lies_in_the_reference_element_exactly(name):
    """The polish moves along faces of the element: its point must stay inside in exact arithmetic (a point a
    rounding beyond r + s + t = 1 is not in the element, and det J there proves nothing)."""
    el = ELEMENTS[name]
    X = _perturbed(name, 150, 0.3, 5)
    r = _run(name, X)
    assert (r.method_names() == "subdivision").sum() > 10  # many cells polished
    for a in r.argmin:
        f = [Fraction(float(v)) for v in a]
        assert all(0 <= v <= 1 for v in f), (name, a)
        if el.domain == "tet":
            assert sum(f) <= 1, (name, a)
        elif el.domain == "prism":
            assert f[0] + f[1] <= 1, (name, a)


@pytest.mark.parametrize("name", TYPES)
def test_compiled_det_at_one_point_matches_the_registry(name):
    """kernel.det_at (the orientation pass) gives the registry's det J at the point for every type; a mirrored
    node order gives its negative (the sign a left-handed file shows)."""
    el = ELEMENTS[name]
    X = _perturbed(name, 30, 0.05, 61)
    P = X.reshape(-1, 3)
    conn = np.arange(P.shape[0]).reshape(X.shape[0], -1)
    pc = el.centre
    got = kernel.det_at(P, conn, name, pc)
    want = el.det(X, pc[None])[:, 0]
    assert np.allclose(got, want, rtol=1e-12, atol=1e-14 * np.abs(want).max())
    assert (got > 0).all()
    mirrored = kernel.det_at(P, conn[:, _mirror(name)], name, pc)
    assert np.allclose(mirrored, -want, rtol=1e-12, atol=1e-14 * np.abs(want).max())


def test_generated_products_are_current_and_bit_identical_to_the_table_loops():
    """_kernel_gen.py is what the current tables generate (an edit of the registry or the formulation without
    regenerating fails here, and the kernel then falls back to the loops), each generated type uses it, and its
    coefficients and error bounds equal the table loops' bit for bit, adversarial cells included."""
    from pathlib import Path

    from hexsos_plugins.kernel import generated as _kernel_gen

    assert Path(_kernel_gen.__file__).read_text() == codegen.generated_source()
    for name in TYPES:
        assert kernel.tables(name).consts[6] == (ktables.GENERATED.index(name) + 1 if name in ktables.GENERATED else 0)
    for name in ktables.GENERATED:
        X = np.array([_reference(name)] + _adversarial(name, 71) + list(_perturbed(name, 300, 0.4, 72)))
        P = X.reshape(-1, 3)
        conn = np.arange(P.shape[0]).reshape(X.shape[0], -1)
        ids = np.arange(len(conn))
        outs = []
        for t in (kernel.Tables(name), kernel.Tables(name, generated=False)):
            o = (np.empty((len(ids), t.nb)), np.empty(len(ids)), np.empty(len(ids), dtype=np.int64), np.empty(len(ids)))
            kcompiled.impl.coefficients_chunk(*kcalls.coefficient_args(P, conn, ids, t, o, 0, len(ids)))
            outs.append(o)
        assert outs[0][0].shape[1] > 0 and kernel.Tables(name).consts[6] > 0
        for a, b in zip(*outs):
            assert np.array_equal(a, b, equal_nan=True), name
    # negative case: a table with a weight changed is not what the generated code computes, and its fingerprint
    # no longer matches the generated code's, so the kernel would not use it
    t = kernel.Tables("hexahedron", generated=False)
    assert ktables.generated_id(t) == ktables.GENERATED.index("hexahedron") + 1
    t.dw = t.dw.copy()
    t.dw[0] *= 1.5
    assert ktables.generated_id(t) == 0
    # so is a table whose columns read other nodes (the generated columns are fingerprinted too)
    t2 = kernel.Tables("hexahedron", generated=False)
    t2.col_b = t2.col_b.copy()
    t2.col_b[[0, 1]] = t2.col_b[[1, 0]]
    assert ktables.generated_id(t2) == 0
    X = _perturbed("hexahedron", 20, 0.3, 73)
    P = X.reshape(-1, 3)
    conn = np.arange(P.shape[0]).reshape(20, -1)
    o1 = kernel.coefficients(P, conn, np.arange(20), "hexahedron")[0]
    o2 = (np.empty((20, t.nb)), np.empty(20), np.empty(20, dtype=np.int64), np.empty(20))
    kcompiled.impl.coefficients_chunk(*kcalls.coefficient_args(P, conn, np.arange(20), t, o2, 0, 20))
    assert not np.array_equal(o1, o2[0])


def test_polish_reaches_the_minimum_to_rounding_and_stops_there():
    """The local descent (what makes the branch-and-bound's upper bound tight from the start) reaches the
    minimum of cells whose root bound cannot close (minima along edges and faces) to the rounding of det J from
    the best vertex, stopping once a Newton step's predicted decrease is within rounding; never below a proven
    lower bound. The start alone is far from it on most (the assertion can fail), and restarting from the
    polished points moves nothing."""
    from hexsos_plugins.examples import hexes_to_mesh, random_hexes

    P, H = hexes_to_mesh(random_hexes(3000, sigma=0.3, seed=12))
    r = kernel.run_cells(P, H, np.arange(len(H)), "hexahedron")
    sub = np.flatnonzero(r["depth"] > 0)
    assert sub.size > 200
    b, _, _, _ = kernel.coefficients(P, H, sub, "hexahedron")
    t = kernel.tables("hexahedron")
    start = t.ctrl[t.vidx[np.argmin(b[:, t.vidx], axis=1)]]
    x, f = kernel.polish(b, start, "hexahedron")
    sc = r["scale"][sub]
    assert np.all(f >= r["lower"][sub] - 1e-15 * sc)
    assert (np.abs(f - r["value"][sub]) <= 1e-13 * sc).mean() > 0.9
    f0 = kernel.evaluate(b, start, "hexahedron")
    assert (np.abs(f0 - r["value"][sub]) <= 1e-13 * sc).mean() < 0.5
    x2, f2 = kernel.polish(b, x, "hexahedron")
    assert np.all(f2 <= f) and np.all(np.abs(f2 - f) <= 1e-14 * sc)


def test_the_scaled_jacobian_of_a_cell_far_from_unit_size_is_its_value_at_unit_size_bit_for_bit():
    """A power of two times every coordinate leaves a scaled Jacobian unchanged: the compiled values (generated
    and table loop) and quality.py's at 2**-1000 ... 2**1000 are those at unit size bit for bit, on random and
    inverted cells of every linear type, and the edge ratio too. At 2**-470 the product of three edge lengths
    underflows to 0 (every cell read 0 before); at 2**470 it overflows to inf."""
    from hexsos_plugins.cells import quality

    rng = np.random.default_rng(75)
    for name, X0 in quality.IDEAL.items():
        X = X0[None] + 0.35 * rng.standard_normal((300,) + X0.shape)
        P = X.reshape(-1, 3)
        C = np.arange(len(P)).reshape(len(X), -1)
        ids = np.arange(len(C))
        unit = kernel.scaled_jacobian(P, [(name, C)])
        ours = quality.scaled_jacobian(P, [(name, C)])
        assert (unit < 0).any() and (unit > 0.5).any() and np.allclose(unit, ours, rtol=0, atol=1e-13)
        for e in (-1000, -470, 470, 1000):
            Q = np.ldexp(P, e)
            edges = np.linalg.norm(Q[C[:, 1]] - Q[C[:, 0]], axis=1)
            if abs(e) == 470:  # the case: a product of three edge lengths is not a double there
                with np.errstate(over="ignore", under="ignore"):
                    assert (edges ** 3 == (0.0 if e < 0 else np.inf)).all()
            assert np.array_equal(kernel.scaled_jacobian(Q, [(name, C)]), unit), (name, e)
            assert np.array_equal(quality.scaled_jacobian(Q, [(name, C)]), ours), (name, e)
            loop = np.empty(len(C))
            kcompiled.impl.scaled_jacobian_chunk(*kcalls.sj_args(Q, C, ids, name, loop, 0, len(C), generated=False))
            assert np.array_equal(loop, unit), (name, e)
    P, C = np.ldexp(quality.IDEAL["hexahedron"], -1000), np.arange(8)[None]
    assert quality.hex_edge_ratio(P, C).tolist() == [1.0]
    X = quality.IDEAL["hexahedron"] + 0.2 * rng.standard_normal((8, 3))
    assert quality.hex_edge_ratio(np.ldexp(X, 700), C)[0] == quality.hex_edge_ratio(X, C)[0] < 1.0
