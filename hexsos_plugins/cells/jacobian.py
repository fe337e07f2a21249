"""det J of every cell type as a polynomial in Bernstein form: the tables the compiled kernel runs on.

For each type of :mod:`hexsos_plugins.cells.elements` the Jacobian determinant (pyramids: det J / (1 - t)^2) is a
polynomial on the reference element. The reference element is a product of *factors*: intervals
(``line``), triangles (``tri``) and tetrahedra (``tet``), each carrying the Bernstein basis of a degree:

=============== ================================ ===================== ==============
type            det J's factors (degree)         coefficients          as Gmsh counts
=============== ================================ ===================== ==============
tetra           tet (0)                          1                     tet 3p - 3
tetra10         tet (3)                          20
pyramid         line (2) x line (2) x line (0)   9 (independent of t)  pyramid 3p - 3
pyramid13, 14   line (5) x line (5) x line (3)   144
wedge           tri (1) x line (2)               9                     prism 3p - 1
wedge15, 18     tri (4) x line (5)               90
hexahedron      line (2)^3                       27                    hex 3p - 1
hexahedron20,27 line (5)^3                       216
tetra (order p) tet (3p - 3)                     84, 220, 455 (p=3-5)
hexahedron (p)  line (3p - 1)^3                  729, 1728, 3375
wedge (p)       tri (3p - 2) x line (3p - 1)     324, 792, 1575
pyramid (p)     line (3p-1)^2 x line (3p-3)      567, 1440, 2925
incomplete (p)  the complete type's of order p   (tetra16, ..., pyramid29: :mod:`.incomplete`)
=============== ================================ ===================== ==============

(orders 3-5: the complete Lagrange cells of :mod:`.lagrange`; their simplex factors of high degree are built by
closed formulas, :func:`factor_tables`, not by inverting a Vandermonde matrix.)

(exact degrees: e.g. for a linear wedge x_r, x_s are constant on the triangle and linear in t, x_t linear on
the triangle and constant in t.) Every value on the element is a convex combination of the coefficients, so
their minimum bounds det J from below, and the coefficients at the element's vertices are values;
subdividing (de Casteljau: lines in halves, triangles and tetrahedra into 4 and 8 by their edge midpoints)
gives the children's coefficients by fixed matrices with non-negative dyadic entries whose rows sum to 1 (the
compiled kernel bisects tetrahedra instead, along the lines of :func:`edge_lines`: the same kind of averages).

How the coefficients are computed (:func:`formulation`): the geometry is a Bernstein map too (its control
points are fixed dyadic combinations of the nodes; serendipity cells' maps lie in the complete space), so each
column of J is a Bernstein polynomial whose coefficients are scaled differences of neighbouring control points
(quadratic pyramids: the r and s columns divided by 1 - t, which rescales them by n / (n - k), see
:func:`_divide_one_minus_t`),
and det J = x_r . (x_s x x_t) follows by *products* of Bernstein polynomials, whose weights are positive and sum
to 1 per coefficient. No inverse transform, no amplification: the rounding of every coefficient is a small
multiple of u = 2^-53 times ``perm(A)``, the permanent of the largest |column coefficient| per component and
direction (about max |det J| for a reasonable cell, and scaling with det J under any scaling of the axes), plus
multiples of eta = 2^-1074 for underflow; :mod:`hexsos_plugins.kernel` states the bound. Everything here is
computed once, in exact rational arithmetic; the kernel rounds it to float64 and the exact fallback of
:mod:`hexsos_plugins.kernel.exact` uses it as it is.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from functools import lru_cache
from itertools import product
from math import comb, factorial, prod

import numpy as np

from .elements import ELEMENTS, exact_inverse
from .incomplete import TYPES as INCOMPLETE_TYPES
from .lagrange import TYPES as LAGRANGE_TYPES

__all__ = ["JacobianSpace", "space", "formulation", "factor_indices", "factor_tables", "product_table", "FACTOR_KINDS",
           "DIRECT_ABOVE", "TET_EDGES", "edge_lines", "bisect_exact"]

_F = Fraction
FACTOR_KINDS = ("line", "tri", "tet")
_DIM = {"line": 1, "tri": 2, "tet": 3}

# Factors of each type's det J polynomial: (kind, degree), and the pcoords slots each factor covers.
_FACTORS = {
    "tetra": (("tet", 0),),
    "tetra10": (("tet", 3),),
    "pyramid": (("line", 2), ("line", 2), ("line", 0)),
    "pyramid13": (("line", 5), ("line", 5), ("line", 3)),
    "pyramid14": (("line", 5), ("line", 5), ("line", 3)),
    "wedge": (("tri", 1), ("line", 2)),
    "wedge15": (("tri", 4), ("line", 5)),
    "wedge18": (("tri", 4), ("line", 5)),
    "hexahedron": (("line", 2), ("line", 2), ("line", 2)),
    "hexahedron20": (("line", 5), ("line", 5), ("line", 5)),
    "hexahedron27": (("line", 5), ("line", 5), ("line", 5)),
}


# The geometry of each type as a Bernstein polynomial map on the same factors (None: the linear pyramid, whose
# measure's columns are given directly by node differences, see _pyramid_columns; the quadratic pyramids are
# maps on the collapsed cube, their r and s columns divided by 1 - t, see _divide_one_minus_t).
_GEOMETRY = {
    "tetra": (("tet", 1),),
    "tetra10": (("tet", 2),),
    "pyramid": None,
    "pyramid13": (("line", 2), ("line", 2), ("line", 2)),
    "pyramid14": (("line", 2), ("line", 2), ("line", 2)),
    "wedge": (("tri", 1), ("line", 1)),
    "wedge15": (("tri", 2), ("line", 2)),
    "wedge18": (("tri", 2), ("line", 2)),
    "hexahedron": (("line", 1), ("line", 1), ("line", 1)),
    "hexahedron20": (("line", 2), ("line", 2), ("line", 2)),
    "hexahedron27": (("line", 2), ("line", 2), ("line", 2)),
}


def _lagrange_factors(domain, p):
    """det J's factors and the geometry's of a complete Lagrange cell of order p (pyramids: the measure)."""
    if domain == "tet":
        return (("tet", 3 * p - 3),), (("tet", p),)
    if domain == "cube":
        return (("line", 3 * p - 1),) * 3, (("line", p),) * 3
    if domain == "prism":
        return (("tri", 3 * p - 2), ("line", 3 * p - 1)), (("tri", p), ("line", p))
    return (("line", 3 * p - 1), ("line", 3 * p - 1), ("line", 3 * p - 3)), (("line", p),) * 3


for _name, _domain, _p, *_ in LAGRANGE_TYPES + INCOMPLETE_TYPES:  # (an incomplete cell's map is one of the
    _FACTORS[_name], _GEOMETRY[_name] = _lagrange_factors(_domain, _p)  # complete space: the same factors)


# --- one factor ------------------------------------------------------------------------------------------------
def factor_indices(kind, p):
    """Multi-indices of the factor's Bernstein basis (exponents of the barycentric coordinates 1..dim)."""
    d = _DIM[kind]
    return [a for a in product(range(p + 1), repeat=d) if sum(a) <= p] if kind != "line" else [(i,) for i in range(p + 1)]


#: The tetrahedron's edges as pairs of its vertices (barycentric slots: 0 the origin, k the unit point e_k).
TET_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))


def edge_lines(p):
    """A tet factor of degree p seen along each edge (i, j) of :data:`TET_EDGES`: the coefficients whose other two
    barycentric exponents are fixed form a line, Bernstein coefficients of degree r = alpha_i + alpha_j in the
    pair (lambda_i, lambda_j). Returns (ptr (6, L + 1), idx (6, n), vert (4,)): line q of edge e is
    idx[e, ptr[e, q]:ptr[e, q + 1]], ordered by alpha_j = 0..r (the indices of :func:`factor_indices`); vert[k]
    the coefficient at vertex k (alpha = p e_k).

    Bisecting the edge at its midpoint m halves every line by de Casteljau at 1/2 (:func:`bisect_exact`):
    the child keeping vertex i (m in slot j) takes the left halves, the child keeping vertex j (m in slot i)
    the right halves; the other factors of the multinomial are the same for both."""
    idx = factor_indices("tet", p)
    where = {(p - sum(a),) + tuple(a): i for i, a in enumerate(idx)}
    ptr, order = [], []
    for i, j in TET_EDGES:
        k, l = (v for v in range(4) if v not in (i, j))
        row, prow = [], [0]
        for ak in range(p + 1):
            for al in range(p + 1 - ak):
                r = p - ak - al
                for aj in range(r + 1):
                    full = [0] * 4
                    full[i], full[j], full[k], full[l] = r - aj, aj, ak, al
                    row.append(where[tuple(full)])
                prow.append(len(row))
        ptr.append(prow)
        order.append(row)
    vert = [where[tuple(p * int(v == k) for v in range(4))] for k in range(4)]
    return (np.array(ptr, dtype=np.int64), np.array(order, dtype=np.int64), np.array(vert, dtype=np.int64))


def bisect_exact(c, p, edge):
    """The two children's coefficients of a tet factor of degree p (coefficients c, any numbers: Fractions give
    the exact ones) bisected at the midpoint of edge ``edge`` (an index into :data:`TET_EDGES`): (lo, hi), lo
    the child keeping vertex i, hi the one keeping vertex j (see :func:`edge_lines`).

    >>> from fractions import Fraction
    >>> _, _, vert = edge_lines(1)  # degree 1: the coefficients are the values at the vertices
    >>> c = [Fraction(0)] * 4
    >>> for k, v in enumerate((0, 3, 5, 7)):
    ...     c[vert[k]] = Fraction(v)
    >>> lo, hi = bisect_exact(c, 1, TET_EDGES.index((0, 1)))  # the midpoint of edge 0-1 takes the value 3/2
    >>> [str(lo[v]) for v in vert], [str(hi[v]) for v in vert]
    (['0', '3/2', '5', '7'], ['3/2', '3', '5', '7'])
    """
    ptr, idx, _ = edge_lines(p)
    lo, hi = list(c), list(c)
    for q in range(ptr.shape[1] - 1):
        line = [c[i] for i in idx[edge, ptr[edge, q]:ptr[edge, q + 1]]]
        r = len(line) - 1
        left, right = [line[0]], [line[r]]
        for level in range(1, r + 1):
            line = [(line[s] + line[s + 1]) / 2 for s in range(r - level + 1)]
            left.append(line[0])
            right.append(line[-1])
        for s in range(r + 1):
            lo[idx[edge, ptr[edge, q] + s]] = left[s]
            hi[idx[edge, ptr[edge, q] + s]] = right[r - s]
    return lo, hi


def _bary(kind, x):
    """Barycentric coordinates (lambda_0, lambda_1, ...) of a point x of the factor's reference element."""
    if kind == "line":
        return (1 - x[0], x[0])
    return (1 - sum(x),) + tuple(x)


def _basis_value(kind, p, alpha, x):
    """The Bernstein basis function alpha of degree p at x (exact)."""
    lam = _bary(kind, x)
    if kind == "line":
        i = alpha[0]
        return comb(p, i) * lam[0] ** (p - i) * lam[1] ** i
    a0 = p - sum(alpha)
    coef = _F(factorial(p), factorial(a0) * prod(factorial(a) for a in alpha))  # multinomial
    v = coef * lam[0] ** a0
    for a, l in zip(alpha, lam[1:]):
        v *= l ** a
    return v


def _ctrl_point(kind, p, alpha):
    """The control point of the basis function alpha (the point alpha / p; degree 0: the first vertex)."""
    if p == 0:
        return tuple(_F(0) for _ in alpha)
    return tuple(_F(a, p) for a in alpha)


def _vertices(kind):
    if kind == "line":
        return [(_F(0),), (_F(1),)]
    d = _DIM[kind]
    return [tuple(_F(0) for _ in range(d))] + [tuple(_F(int(i == j)) for i in range(d)) for j in range(d)]


def _children(kind, p):
    """Affine maps (A, o) of the children of the reference element (x -> o + A x), exact."""
    if p == 0:
        d = _DIM[kind]
        return [([[_F(int(i == j)) for j in range(d)] for i in range(d)], [_F(0)] * d)]
    h = _F(1, 2)
    if kind == "line":
        return [([[h]], [_F(0)]), ([[h]], [h])]
    V = _vertices(kind)
    d = _DIM[kind]

    def mid(a, b):
        return tuple((x + y) / 2 for x, y in zip(V[a], V[b]))

    if kind == "tri":
        m01, m12, m02 = mid(0, 1), mid(1, 2), mid(0, 2)
        simplices = [(V[0], m01, m02), (m01, V[1], m12), (m02, m12, V[2]), (m12, m02, m01)]
    else:
        m = {(a, b): mid(a, b) for a in range(4) for b in range(a + 1, 4)}
        simplices = [(V[0], m[0, 1], m[0, 2], m[0, 3]), (m[0, 1], V[1], m[1, 2], m[1, 3]),
                     (m[0, 2], m[1, 2], V[2], m[2, 3]), (m[0, 3], m[1, 3], m[2, 3], V[3])]
        # the octahedron of the edge midpoints, cut along its diagonal m02 - m13
        ring = [m[0, 1], m[0, 3], m[2, 3], m[1, 2]]
        for a, b in zip(ring, ring[1:] + ring[:1]):
            simplices.append((m[0, 2], m[1, 3], a, b))
    maps = []
    for s in simplices:
        o = list(s[0])
        A = [[s[j + 1][i] - s[0][i] for j in range(d)] for i in range(d)]
        maps.append((A, o))
    return maps


def _apply(A, o, x):
    return tuple(o[i] + sum(A[i][j] * x[j] for j in range(len(x))) for i in range(len(o)))


#: Factors with more coefficients than this are built by :func:`factor_tables`' direct construction (no
#: inverse of a Vandermonde matrix: the inverse costs n^3 rational operations, minutes for a tetrahedron of degree 6).
DIRECT_ABOVE = 40


@lru_cache(maxsize=None)
def _factor(kind, p):
    return factor_tables(kind, p, direct=len(factor_indices(kind, p)) > DIRECT_ABOVE)


def _homogeneous(m, k):
    """Exponents of the monomials of degree k in m variables, in a fixed order, and their index."""
    E = [e for e in product(range(k + 1), repeat=m) if sum(e) == k]
    return E, {e: i for i, e in enumerate(E)}


def _multinomial(e):
    return factorial(sum(e)) // prod(factorial(a) for a in e)


def _full(kind, p, alpha):
    """The barycentric exponent (alpha_0, alpha_1, ...) of a factor's multi-index."""
    return (p - sum(alpha),) + tuple(alpha)


def _subdivision_direct(kind, p, A, o, idx):
    """The child matrix S (c_child = S c) of a factor of degree p for the child map x = o + A y, exactly, without
    any inverse: B_alpha composed with the map is a product of the parent's barycentric coordinates, each a
    linear form in the child's barycentric coordinates mu (weights W[j, i] = lambda_i of the child's vertex j, in
    {0, 1/2, 1}); the products are expanded in integers (2 W), and S[beta, alpha] = multinomial(alpha)
    [mu^beta] prod (2 lambda_i)^alpha_i / (multinomial(beta) 2^p)."""
    d = _DIM[kind]
    m = d + 1
    verts = [tuple(_F(0) for _ in range(d))] + [tuple(_F(int(i == j)) for i in range(d)) for j in range(d)]
    W2 = []
    for y in verts:
        x = _apply(A, o, y)
        lam = _bary(kind, x) if kind != "line" else (1 - x[0], x[0])
        row = [2 * v for v in lam]
        assert all(v.denominator == 1 for v in row), "child vertices off the half-lattice"
        W2.append([int(v) for v in row])
    W2 = np.array(W2, dtype=np.int64)  # (child vertex j, parent coordinate i)
    # P[k]: rows = parent exponents of degree k (order of _homogeneous), columns = mu monomials of degree k
    E0, _ = _homogeneous(m, 0)
    P = np.ones((1, 1), dtype=np.int64)
    rows = E0
    for k in range(p):
        Ek, ik = _homogeneous(m, k)
        Ek1, ik1 = _homogeneous(m, k + 1)
        shift = [np.array([ik1[tuple(e[a] + (a == j) for a in range(m))] for e in Ek]) for j in range(m)]
        parent, first = [], []
        for e in Ek1:
            i = next(a for a in range(m) if e[a])
            parent.append(ik[tuple(e[a] - (a == i) for a in range(m))])
            first.append(i)
        parent, first = np.array(parent), np.array(first)
        out = np.zeros((len(Ek1), len(Ek1)), dtype=np.int64)
        src = P[parent]
        for j in range(m):
            out[:, shift[j]] += W2[j, first][:, None] * src
        P, rows = out, Ek1
    ir = {e: i for i, e in enumerate(rows)}
    n = len(idx)
    full = [_full(kind, p, a) if kind != "line" else (p - a[0], a[0]) for a in idx]
    sel = np.array([ir[e] for e in full])
    Q = P[np.ix_(sel, sel)].T  # Q[beta, alpha]
    den = 2 ** p
    mult = [_multinomial(e) for e in full]
    S = [[_F(0)] * n for _ in range(n)]
    for b, a in zip(*np.nonzero(Q)):
        S[b][a] = _F(mult[a] * int(Q[b, a]), mult[b] * den)
    return S


def _monomial_direct(kind, p, idx, mono):
    """Bernstein -> monomial matrix (mono k, basis i): B_alpha = multinomial(alpha_0, alpha) (1 - sum x)^alpha_0
    x^alpha, expanded by the multinomial theorem."""
    where = {mm: k for k, mm in enumerate(mono)}
    M = [[_F(0)] * len(idx) for _ in mono]
    for i, a in enumerate(idx):
        a0 = p - sum(a)
        c = _multinomial((a0,) + tuple(a))
        for g in product(range(a0 + 1), repeat=len(a)):
            if sum(g) > a0:
                continue
            coef = c * _multinomial((a0 - sum(g),) + g) * (-1) ** sum(g)
            M[where[tuple(x + y for x, y in zip(a, g))]][i] += coef
    return M


def factor_tables(kind, p, direct=False):
    """Exact tables of one factor: indices, sample points, T (values -> coefficients; None for a direct build
    with more than DIRECT_ABOVE coefficients), children (matrices and maps), control points, vertex indices,
    Bernstein -> monomial matrix and the monomial exponents. ``direct``: the child matrices and the monomial
    matrix by closed formulas (the same rationals; tests compare both builds)."""
    idx = factor_indices(kind, p)
    n = len(idx)
    pts = [_ctrl_point(kind, p, a) for a in idx]  # sample at the control points (equispaced)
    mono = idx if kind != "line" else [(i,) for i in range(p + 1)]
    verts = [i for i, a in enumerate(idx) if (p == 0 and i == 0) or (p > 0 and (
        sum(a) == 0 or (kind == "line" and a[0] == p) or (kind != "line" and max(a) == p)))]
    if direct and p > 0:
        T = None
        if n <= 60:  # the geometry's factors (degree <= 5) need T
            T = exact_inverse([[_basis_value(kind, p, a, x) for a in idx] for x in pts])
        kids = [(_subdivision_direct(kind, p, A, o, idx), A, o) for A, o in _children(kind, p)]
        return {"idx": idx, "pts": pts, "T": T, "children": kids, "verts": verts, "mono": mono,
                "M": _monomial_direct(kind, p, idx, mono)}
    return _factor_by_inverse(kind, p)


def _factor_by_inverse(kind, p):
    """factor_tables by inverting the Vandermonde matrix of the Bernstein basis at the control points."""
    idx = factor_indices(kind, p)
    n = len(idx)
    pts = [_ctrl_point(kind, p, a) for a in idx]  # sample at the control points (equispaced)
    V = [[_basis_value(kind, p, a, x) for a in idx] for x in pts]
    T = exact_inverse(V)
    kids = []
    for A, o in _children(kind, p):
        Q = [[_basis_value(kind, p, a, _apply(A, o, x)) for a in idx] for x in pts]
        S = [[sum(T[i][k] * Q[k][j] for k in range(n)) for j in range(n)] for i in range(n)]
        kids.append((S, A, o))
    verts = [i for i, a in enumerate(idx) if (p == 0 and i == 0) or (p > 0 and (
        sum(a) == 0 or (kind == "line" and a[0] == p) or (kind != "line" and max(a) == p)))]
    # monomials x^m of the factor (same multi-index set, as exponents of the cartesian coordinates)
    mono = idx if kind != "line" else [(i,) for i in range(p + 1)]
    # Bernstein basis alpha expanded in monomials: sample-free, by solving on the sample points
    W = [[prod(x[j] ** m[j] for j in range(len(m))) for m in mono] for x in pts]
    Winv = exact_inverse(W)  # monomial coefficients of a polynomial from its values at pts
    Bmono = [[sum(Winv[k][q] * V[q][i] for q in range(n)) for i in range(n)] for k in range(n)]  # (mono k, basis i)
    return {"idx": idx, "pts": pts, "T": T, "children": kids, "verts": verts, "mono": mono, "M": Bmono}


def _kron(mats):
    out = [[_F(1)]]
    for M in mats:
        out = [[a * b for a in ra for b in rb] for ra in out for rb in M]
    return out


# --- Bernstein products and the Jacobian's columns ----------------------------------------------------------
def _coef(kind, p, alpha):
    """The (multi)nomial coefficient of the Bernstein basis function alpha of degree p."""
    if kind == "line":
        return comb(p, alpha[0])
    a0 = p - sum(alpha)
    return factorial(p) // (factorial(a0) * prod(factorial(a) for a in alpha))


def _combos(factors):
    """The coefficient multi-indices of a factor structure, row-major (factor 0 slowest)."""
    return list(product(*[factor_indices(k, p) for k, p in factors]))


def _flat(factors):
    return {c: i for i, c in enumerate(_combos(factors))}


def product_table(fa, fb):
    """Entries (out, ia, ib, w) with ``(sum_a a_i B_i) (sum_b b_j B_j) = sum_k c_k B_k``,
    ``c_k = sum w a_ia b_ib`` over the entries with out = k: the weights (exact, > 0) of the product of two
    Bernstein polynomials on the same factors, of degrees fa and fb; for every k they sum to 1."""
    fc = tuple((k, pa + pb) for (k, pa), (_, pb) in zip(fa, fb))
    ia_of, ib_of, ic_of = _flat(fa), _flat(fb), _flat(fc)
    out = []
    for ca in _combos(fa):
        for cb in _combos(fb):
            w = _F(1)
            cc = []
            for (k, pa), (_, pb), a, b in zip(fa, fb, ca, cb):
                g = tuple(x + y for x, y in zip(a, b))
                w *= _F(_coef(k, pa, a) * _coef(k, pb, b), _coef(k, pa + pb, g))
                cc.append(g)
            out.append((ic_of[tuple(cc)], ia_of[ca], ib_of[cb], w))
    out.sort()
    return out


def _geometry_control(name, gfactors):
    """(nctrl, n) exact matrix C with control points P = C X of the type's geometry as a Bernstein map on
    gfactors (serendipity types: their map is a polynomial of the complete space, so this is exact)."""
    el = ELEMENTS[name]
    tabs = [_factor(k, p) for k, p in gfactors]
    pts = []
    for combo in product(*[range(len(t["idx"])) for t in tabs]):
        x = []
        for t, j in zip(tabs, combo):
            x += list(t["pts"][j])
        pts.append(tuple(x))
    T = _kron([t["T"] for t in tabs])
    n = el.n_nodes
    where = {x: q for q, x in enumerate(pts)}
    if len(pts) == n and all(tuple(x) in where for x in el.nodes):
        # a Lagrange cell whose nodes are the sample points: N_i(pt_q) = [q is node i], C = T's columns
        q_of = [where[tuple(x)] for x in el.nodes]
        return [[T[a][q_of[i]] for i in range(n)] for a in range(len(pts))]
    N = [_eval_all(el.shape_polynomials, x) for x in pts]  # values of the map at the points
    return [[sum((T[a][q] * N[q][i] for q in range(len(pts)) if N[q][i]), _F(0)) for i in range(n)]
            for a in range(len(pts))]


def _eval_all(polys, x):
    """The values of many exact polynomials at one point (each power computed once)."""
    pw = [[_F(1)] for _ in range(3)]
    top = max(max(e[d] for p in polys for e in p) for d in range(3))
    for d in range(3):
        for _ in range(top):
            pw[d].append(pw[d][-1] * x[d])
    return [sum((c * pw[0][e[0]] * pw[1][e[1]] * pw[2][e[2]] for e, c in p.items()), _F(0)) for p in polys]


def _geometry_columns(gfactors, slots):
    """Per pcoords direction d: the column's factors and, per coefficient, (a, b, w): the coefficient is
    w (P_b - P_a) (derivative of a Bernstein map: scaled differences of neighbouring control points)."""
    gidx = _flat(gfactors)
    cols = []
    for d in range(3):
        f = next(i for i, sl in enumerate(slots) if d in sl)
        j = slots[f].index(d)
        kind, p = gfactors[f]
        cf = tuple((k, q - 1) if i == f else (k, q) for i, (k, q) in enumerate(gfactors))
        entries = []
        for combo in _combos(cf):
            beta = combo[f]
            if kind == "line":
                a_f, b_f = beta, (beta[0] + 1,)
            else:
                a_f = beta
                b_f = tuple(v + (1 if i == j else 0) for i, v in enumerate(beta))
            ca = combo[:f] + (a_f,) + combo[f + 1 :]
            cb = combo[:f] + (b_f,) + combo[f + 1 :]
            entries.append((gidx[ca], gidx[cb], p))
        cols.append((cf, entries))
    return cols


def _pyramid_columns():
    """The pyramid's measure det[x_r / (1 - t), x_s / (1 - t), x_t] with x = (1 - t) B(r, s) + t X_4: columns
    B_r (linear in s), B_s (linear in r) and X_4 - B (bilinear), as node differences (control points = nodes)."""
    L, Z = "line", "line"
    col_r = (((L, 0), (L, 1), (Z, 0)), [(0, 1, 1), (3, 2, 1)])  # s = 0: X1 - X0; s = 1: X2 - X3
    col_s = (((L, 1), (L, 0), (Z, 0)), [(0, 3, 1), (1, 2, 1)])  # r = 0: X3 - X0; r = 1: X2 - X1
    col_t = (((L, 1), (L, 1), (Z, 0)), [(0, 4, 1), (3, 4, 1), (1, 4, 1), (2, 4, 1)])  # (r, s) = 00, 01, 10, 11
    return [col_r, col_s, col_t]


def _divide_one_minus_t(column, C):
    """A column x_d (d = r, s) of a map on the collapsed cube, divided by (1 - t): a Bernstein polynomial of
    degree n in t vanishing at t = 1 (its coefficients there are differences of the apex's control points,
    equal exactly) divided by (1 - t) has degree n - 1 and coefficients b_k n / (n - k) (B^n_k / (1 - t) =
    n / (n - k) B^{n-1}_k). Exact: the dropped entries are checked to be differences of equal rows of C."""
    factors, entries = column
    (kind, n) = factors[2]
    assert kind == "line" and n >= 1
    combos = _combos(factors)
    out_index = _flat(factors[:2] + ((kind, n - 1),))
    out = []
    for (a, b, w), combo in zip(entries, combos):
        k = combo[2][0]
        if k == n:
            assert C[a] == C[b], "the top face of a pyramid is not one point"
            continue
        out.append((a, b, w * _F(n, n - k), out_index[combo[:2] + ((k,),)]))
    out.sort(key=lambda e: e[3])
    return (factors[:2] + ((kind, n - 1),), [(a, b, w) for a, b, w, _ in out])


@lru_cache(maxsize=None)
def formulation(name: str) -> dict:
    """How the kernel computes det J's Bernstein coefficients for a type, exactly (rationals):

    ``C`` (nctrl, n): control points of the geometry from the nodes (the pyramid: the nodes themselves);
    ``columns``: per direction d, the column's factors and its coefficients as (a, b, w): w (P_b - P_a);
    ``cross``: product table of column 1 by column 2 (into the space of x_s x x_t);
    ``dot``: product table of column 0 by that space (into det J's space, the order of :func:`space`)."""
    el = ELEMENTS[name]
    g = _GEOMETRY[name]
    slots, s = [], 0
    for k, _ in _FACTORS[name]:
        slots.append(tuple(range(s, s + _DIM[k])))
        s += _DIM[k]
    if g is None:
        C = [[_F(int(i == j)) for j in range(el.n_nodes)] for i in range(el.n_nodes)]
        cols = _pyramid_columns()
    else:
        C = _geometry_control(name, g)
        cols = _geometry_columns(g, tuple(slots))
        if el.domain == "pyramid":  # the measure's columns: x_r / (1 - t), x_s / (1 - t), x_t
            cols = [_divide_one_minus_t(cols[0], C), _divide_one_minus_t(cols[1], C), cols[2]]
    cross = product_table(cols[1][0], cols[2][0])
    fx = tuple((k, a + b) for (k, a), (_, b) in zip(cols[1][0], cols[2][0]))
    dot = product_table(cols[0][0], fx)
    fdet = tuple((k, a + b) for (k, a), (_, b) in zip(cols[0][0], fx))
    assert tuple(p for _, p in fdet) == tuple(p for _, p in _FACTORS[name]), (name, fdet)
    return {"C": C, "columns": cols, "cross": cross, "dot": dot, "nx": len(_combos(fx))}


# --- one cell type -------------------------------------------------------------------------------------------
@dataclass(eq=False)
class JacobianSpace:
    """The Bernstein tables of one cell type's det J (see the module docstring). Arrays are float64 unless
    noted; ``exact_*`` are the rational originals."""

    name: str
    factors: tuple  # ((kind, degree), ...)
    slots: tuple  # per factor, the pcoords indices it covers
    sizes: np.ndarray  # (nf,) coefficients per factor
    nb: int  # coefficients in all
    n_nodes: int
    S: np.ndarray  # (nf, maxc, maxn, maxn) per-factor child matrices
    exact_S: list  # per factor, per child, lists of Fractions
    nchildren: np.ndarray  # (nf,)
    child_maps: np.ndarray  # (nf, maxc, 3, 4) each child's affine map on the full pcoords ([A | o])
    ctrl: np.ndarray  # (nb, 3) control points
    vertex_idx: np.ndarray  # (nv,) coefficients at the reference element's vertices (values)
    corner_idx: np.ndarray  # (nc,) coefficients at the element's corner nodes, in node order
    mono_exp: np.ndarray  # (nb, 3) monomial exponents
    M: np.ndarray  # (nb, nb) Bernstein -> monomial coefficients
    G: np.ndarray  # (ng, 3) the reference element is {x : G x <= h}
    h: np.ndarray  # (ng,)


def _domain(elem_domain, factors):
    if elem_domain == "cube" or (elem_domain == "pyramid" and factors[2][1] > 0):  # quadratic pyramids: the cube
        G = [[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]]
        h = [0, 1, 0, 1, 0, 1]
    elif elem_domain == "tet":
        G = [[-1, 0, 0], [0, -1, 0], [0, 0, -1], [1, 1, 1]]
        h = [0, 0, 0, 1]
    elif elem_domain == "prism":
        G = [[-1, 0, 0], [0, -1, 0], [1, 1, 0], [0, 0, -1], [0, 0, 1]]
        h = [0, 0, 1, 0, 1]
    else:  # linear pyramid: the measure does not depend on t; it is searched on the base square (t = 0)
        G = [[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]]
        h = [0, 1, 0, 1, 0, 0]
    return np.array(G, dtype=np.float64), np.array(h, dtype=np.float64)


@lru_cache(maxsize=None)
def space(name: str) -> JacobianSpace:
    """The :class:`JacobianSpace` of a cell type (computed once per process)."""
    el = ELEMENTS[name]
    factors = _FACTORS[name]
    tabs = [_factor(k, p) for k, p in factors]
    slots, s = [], 0
    for k, _ in factors:
        slots.append(tuple(range(s, s + _DIM[k])))
        s += _DIM[k]
    sizes = np.array([len(t["idx"]) for t in tabs], dtype=np.int64)
    nb = int(np.prod(sizes))
    ctrl, mono = [], []
    for combo in product(*[range(len(t["idx"])) for t in tabs]):
        c, m = [], []
        for t, j in zip(tabs, combo):
            c += list(t["pts"][j])
            m += list(t["mono"][j])
        ctrl.append(tuple(c))
        mono.append(tuple(m))
    nf = len(factors)
    maxn = int(sizes.max())
    maxc = max(len(t["children"]) for t in tabs)
    S = np.zeros((nf, maxc, maxn, maxn))
    maps = np.zeros((nf, maxc, 3, 4))
    nchildren = np.array([len(t["children"]) for t in tabs], dtype=np.int64)
    for f, t in enumerate(tabs):
        n = len(t["idx"])
        for c, (Sm, A, o) in enumerate(t["children"]):
            S[f, c, :n, :n] = [[float(v) for v in r] for r in Sm]
            full = np.zeros((3, 4))
            full[:, :3] = np.eye(3)
            for a, ia in enumerate(slots[f]):
                for b, ib in enumerate(slots[f]):
                    full[ia, ib] = float(A[a][b])
                full[ia, 3] = float(o[a])
            maps[f, c] = full
    # vertex coefficients (product of the factors' vertices) and the element's corners among them
    strides = [int(np.prod(sizes[f + 1 :])) for f in range(nf)]
    vertex_idx = sorted(sum(j * st for j, st in zip(combo, strides))
                        for combo in product(*[t["verts"] for t in tabs]))
    ctrl_arr = np.array([[float(v) for v in c] for c in ctrl])
    corner_idx = []
    flat_slots = [i for f, (_, p) in enumerate(factors) if p == 0 for i in slots[f]]
    for x in el.nodes[: el.corners]:
        xx = np.array([float(v) for v in x])
        xx[flat_slots] = 0.0  # degree 0 along these coordinates (pyramids: t; linear tets: all)
        k = int(np.flatnonzero(np.all(ctrl_arr == xx, axis=1))[0])
        corner_idx.append(k)
    M = np.ones((1, 1))
    for t in tabs:  # for the polish only (floats suffice)
        M = np.kron(M, np.array([[float(v) for v in r] for r in t["M"]]))
    G, h = _domain(el.domain, factors)
    return JacobianSpace(
        name=name, factors=factors, slots=tuple(slots), sizes=sizes, nb=nb, n_nodes=el.n_nodes, S=S,
        exact_S=[[Sm for Sm, _, _ in t["children"]] for t in tabs], nchildren=nchildren, child_maps=maps,
        ctrl=ctrl_arr, vertex_idx=np.array(vertex_idx, dtype=np.int64), corner_idx=np.array(corner_idx, dtype=np.int64),
        mono_exp=np.array(mono, dtype=np.int64), M=M, G=G, h=h)
