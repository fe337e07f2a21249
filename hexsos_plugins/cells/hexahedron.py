"""The trilinear hexahedron: node order, parameter cube, and the polynomial det J.

Conventions (stated here once; every other module imports them)
----------------------------------------------------------------
Nodes are in **VTK order** (the same in meshio, Gmsh element type 5 and Medit)::

            7-----------6            node   (u, v, w)
           /|          /|              0    (0, 0, 0)
          / |         / |      w       1    (1, 0, 0)
         4-----------5  |      |  v    2    (1, 1, 0)
         |  3--------|--2      | /     3    (0, 1, 0)
         | /         | /       |/      4    (0, 0, 1)
         |/          |/        +--u    5    (1, 0, 1)
         0-----------1                 6    (1, 1, 1)
                                       7    (0, 1, 1)

Nodes 0-1-2-3 form the bottom quad, counter-clockwise seen from above (from +w); 4-5-6-7 lie above them.
The trilinear map is ``x(u, v, w) = sum_n X_n N_n(u, v, w)`` on the **parameter cube [0, 1]^3**, and
``det J = det [x_u, x_v, x_w]`` is measured in [0, 1]^3 units: the unit cube has det J == 1 everywhere.
(Gmsh's reference cube is [-1, 1]^3; its ``minDetJac`` equals our value / 8.)

det J is a polynomial of degree <= 2 in each of u, v, w and of total degree 4: 20 monomials (u^2 v^2,
u^2 w^2, v^2 w^2 and every monomial of total degree >= 5 vanish). We hold it in two bases:

* the tensor **Bernstein** basis of degree (2, 2, 2): 27 coefficients ``B[a, b, c]`` (flattened as
  ``9 a + 3 b + c``, with a, b, c the u, v, w indices). The corner coefficients are the values at the
  corners; every value on the cube is a convex combination of the coefficients. They come from the 27
  values on {0, 1/2, 1}^3, per axis ``b0 = f(0), b1 = 2 f(1/2) - (f(0) + f(1)) / 2, b2 = f(1)``.
* the **monomial** basis ``MONOMIALS`` (20 exponent triples), used by the SOS relaxations.

Arrays of many hexes are laid out structure-of-arrays: coordinates as ``(3, 8, M)`` and coefficients
as ``(27, M)``, so that each arithmetic step runs over M contiguous numbers.
"""

from __future__ import annotations

from fractions import Fraction
from itertools import product

import numpy as np

from ..errors import InvalidInputError
from .elements import VOXEL_TO_VTK

__all__ = [
    "CORNERS",
    "EDGES",
    "LEX_TO_VTK",
    "VOXEL_TO_VTK",
    "MONOMIALS",
    "UNIT_ROUND",
    "gather",
    "gather_t",
    "as_soa",
    "CORNER_INDEX",
    "bernstein_to_monomial",
    "det_at",
    "det_at_bernstein",
    "det_gradient_at",
    "det_hessian_at",
    "det_derivatives",
    "det_vertex_gradient",
    "map_points",
    "det_exact",
    "bernstein_exact",
]

#: Parameter corner (u, v, w) of each node in VTK order.
CORNERS = np.array(
    [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)], dtype=np.int64
)
#: The 12 edges (pairs of VTK nodes): the bottom quad's, the top quad's, then the vertical ones.
EDGES = np.array([(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)],
                 dtype=np.int64)
#: ``LEX_TO_VTK[4 i + 2 j + k]`` is the VTK node at corner (i, j, k), the paper's lexicographic order.
LEX_TO_VTK = np.array([int(np.flatnonzero((CORNERS == c).all(1))[0]) for c in product((0, 1), repeat=3)])
#: Exponents (i, j, k) of u^i v^j w^k of the 20 monomials of det J, graded then lexicographic.
MONOMIALS = tuple(
    m
    for m in sorted(product(range(3), repeat=3), key=lambda m: (sum(m), tuple(-e for e in m)))
    if sum(m) <= 4 and not (m[0] == 2 and m[1] == 2) and not (m[0] == 2 and m[2] == 2)
    and not (m[1] == 2 and m[2] == 2)
)
#: Unit roundoff of float64.
UNIT_ROUND = 2.0**-53

# Node index at corner (i, j, k) for i, j, k in {0, 1}.
_NODE = np.empty((2, 2, 2), dtype=np.int64)
for _n, (_i, _j, _k) in enumerate(CORNERS):
    _NODE[_i, _j, _k] = _n

# The 8 corner coefficients (index 9 a + 3 b + c with a = 2 u ...) in VTK node order.
CORNER_INDEX = np.array([18 * i + 6 * j + 2 * k for i, j, k in CORNERS])
# Rounding-error constant of ``det_at``: a value is a triple product of edge vectors interpolated in a few
# roundings, so it is within 15 u times the product of the largest edge L1 norms of exact (1024: a margin).
# (Not used by the proofs, which are the kernel's: no underflow term here.)
_ROUND_C = 1024.0


def gather(points, hexes) -> np.ndarray:
    """Vertex coordinates of every hex, structure-of-arrays.

    Parameters
    ----------
    points : array_like, shape (N, 3)
    hexes : array_like of int, shape (M, 8), VTK node order

    Returns
    -------
    X : ndarray, shape (3, 8, M), C-contiguous; ``X[c, n, m]`` is coordinate c of node n of hex m.
    """
    return gather_t(np.ascontiguousarray(np.asarray(points, dtype=np.float64).T), hexes)


def gather_t(points_t, hexes) -> np.ndarray:
    """:func:`gather` from points already transposed to a C-contiguous (3, N) array (reused across chunks)."""
    idx = np.ascontiguousarray(np.asarray(hexes, dtype=np.int64).T)  # (8, M)
    return np.take(points_t, idx, axis=1)


def as_soa(X, layout: str = "aos") -> np.ndarray:
    """Vertex coordinates as (3, 8, M). ``layout="aos"``: X is (M, 8, 3) or one hex (8, 3);
    ``layout="soa"``: X is already (3, 8, M) (as :func:`gather` returns)."""
    X = np.asarray(X, dtype=np.float64)
    if layout == "soa":
        if X.ndim != 3 or X.shape[:2] != (3, 8):
            raise InvalidInputError(f"expected structure-of-arrays coordinates of shape (3, 8, M), found {X.shape}")
        return np.ascontiguousarray(X)
    if layout != "aos":
        raise InvalidInputError(f"layout: expected 'aos' or 'soa', found {layout!r}")
    if X.shape == (8, 3):
        X = X[None]
    if X.ndim != 3 or X.shape[1:] != (8, 3):
        raise InvalidInputError(f"expected hex vertex coordinates of shape (M, 8, 3) or (8, 3), found {X.shape}")
    return np.ascontiguousarray(X.transpose(2, 1, 0))


def _edges(X):
    """Edge vectors along u, v, w: each a (3, 2, 2, M) array indexed by the other two corner bits."""
    eu = np.empty((3, 2, 2) + X.shape[2:])
    ev = np.empty_like(eu)
    ew = np.empty_like(eu)
    for a in (0, 1):
        for b in (0, 1):
            np.subtract(X[:, _NODE[1, a, b]], X[:, _NODE[0, a, b]], out=eu[:, a, b])  # (v, w) = (a, b)
            np.subtract(X[:, _NODE[a, 1, b]], X[:, _NODE[a, 0, b]], out=ev[:, a, b])  # (u, w) = (a, b)
            np.subtract(X[:, _NODE[a, b, 1]], X[:, _NODE[a, b, 0]], out=ew[:, a, b])  # (u, v) = (a, b)
    return eu, ev, ew


def bernstein_to_monomial(B) -> np.ndarray:
    """Monomial coefficients (20, M) in the order of :data:`MONOMIALS` from Bernstein coefficients (27, M)."""
    C = np.array(B, dtype=np.float64).reshape((3, 3, 3) + np.shape(B)[1:])
    # per axis: c0 = b0, c1 = 2 (b1 - b0), c2 = b0 - 2 b1 + b2
    for ax in range(3):
        C = np.moveaxis(C, ax, 0)
        b0, b1, b2 = C[0].copy(), C[1].copy(), C[2].copy()
        C[0], C[1], C[2] = b0, 2.0 * (b1 - b0), b0 - 2.0 * b1 + b2
        C = np.moveaxis(C, 0, ax)
    return np.stack([C[i, j, k] for i, j, k in MONOMIALS])


def _bern1(t):
    """Quadratic Bernstein basis and its first two derivatives at t (any shape): three (3, ...) arrays."""
    t = np.asarray(t, dtype=np.float64)
    s = 1.0 - t
    b = np.stack([s * s, 2.0 * s * t, t * t])
    d = np.stack([-2.0 * s, 2.0 * (s - t), 2.0 * t])
    dd = np.stack([np.full_like(t, 2.0), np.full_like(t, -4.0), np.full_like(t, 2.0)])
    return b, d, dd


def _tensor_eval(B, uvw, du=0, dv=0, dw=0):
    B = np.asarray(B, dtype=np.float64)
    uvw = np.asarray(uvw, dtype=np.float64)
    bases = []
    for ax, order in enumerate((du, dv, dw)):
        bases.append(_bern1(uvw[..., ax])[order])
    C = B.reshape((3, 3, 3) + B.shape[1:])
    return np.einsum("abc...,a...,b...,c...->...", C, *bases)


def det_at_bernstein(B, uvw) -> np.ndarray:
    """det J from Bernstein coefficients B (27, M) at points uvw (M, 3) (or broadcastable): (M,)."""
    return _tensor_eval(B, uvw)


def det_derivatives(B, uvw):
    """det J, its gradient and its Hessian with respect to (u, v, w), from B (27, M) at uvw (M, 3).

    Returns
    -------
    f : (M,)
    g : (M, 3)
    H : (M, 3, 3)
    """
    B = np.asarray(B, dtype=np.float64)
    uvw = np.asarray(uvw, dtype=np.float64)
    C = B.reshape((3, 3, 3) + B.shape[1:])
    bu, bv, bw = (_bern1(uvw[..., i]) for i in range(3))  # each (value, d, dd), (3, M)
    W = [np.einsum("abc...,c...->ab...", C, bw[k]) for k in range(3)]  # contract w: orders 0, 1, 2
    V = {(kw, kv): np.einsum("ab...,b...->a...", W[kw], bv[kv]) for kw, kv in
         ((0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (2, 0))}

    def U(kw, kv, ku):
        return np.einsum("a...,a...->...", V[kw, kv], bu[ku])

    f = U(0, 0, 0)
    g = np.stack([U(0, 0, 1), U(0, 1, 0), U(1, 0, 0)], axis=-1)
    H = np.empty(f.shape + (3, 3))
    H[..., 0, 0] = U(0, 0, 2)
    H[..., 1, 1] = U(0, 2, 0)
    H[..., 2, 2] = U(2, 0, 0)
    H[..., 0, 1] = H[..., 1, 0] = U(0, 1, 1)
    H[..., 0, 2] = H[..., 2, 0] = U(1, 0, 1)
    H[..., 1, 2] = H[..., 2, 1] = U(1, 1, 0)
    return f, g, H


def det_gradient_at(B, uvw) -> np.ndarray:
    """Gradient of det J with respect to (u, v, w) at uvw (M, 3): (M, 3)."""
    return det_derivatives(B, uvw)[1]


def det_hessian_at(B, uvw) -> np.ndarray:
    """Hessian of det J with respect to (u, v, w) at uvw (M, 3): (M, 3, 3)."""
    return det_derivatives(B, uvw)[2]


def _scale(eu, ev, ew):
    """Per hex, the product over directions of the largest edge L1 norm: bounds every |term| of det J."""
    su = np.abs(eu).sum(axis=0).reshape(4, -1).max(axis=0)
    sv = np.abs(ev).sum(axis=0).reshape(4, -1).max(axis=0)
    sw = np.abs(ew).sum(axis=0).reshape(4, -1).max(axis=0)
    return su * sv * sw


def _jacobian_at(X, uvw):
    """Columns x_u, x_v, x_w, each (3, M), of the Jacobian at uvw (M, 3), from X (3, 8, M)."""
    u, v, w = (np.asarray(uvw, dtype=np.float64)[..., i] for i in range(3))
    eu, ev, ew = _edges(X)
    lin = lambda e, s, t: (e[:, 0, 0] * (1 - s) + e[:, 1, 0] * s) * (1 - t) + (e[:, 0, 1] * (1 - s) + e[:, 1, 1] * s) * t
    return lin(eu, v, w), lin(ev, u, w), lin(ew, u, v), _scale(eu, ev, ew)


def det_at(X, uvw, *, layout="aos"):
    """det J at one point per hex, directly from the vertices, with a rigorous rounding bound.

    Parameters
    ----------
    X : array_like, shape (M, 8, 3) or (8, 3); with ``layout="soa"``, (3, 8, M)
    uvw : array_like, shape (M, 3) or (3,)

    Returns
    -------
    det : ndarray (M,)
    err : ndarray (M,), ``|det_computed - det_exact| <= err`` (for the point as given in float64).
    """
    X = as_soa(X, layout)
    xu, xv, xw, S = _jacobian_at(X, np.broadcast_to(np.asarray(uvw, dtype=np.float64), (X.shape[2], 3)))
    d = xu[0] * (xv[1] * xw[2] - xv[2] * xw[1]) + xu[1] * (xv[2] * xw[0] - xv[0] * xw[2]) + xu[2] * (
        xv[0] * xw[1] - xv[1] * xw[0]
    )
    return d, (_ROUND_C * UNIT_ROUND) * S


def map_points(X, uvw) -> np.ndarray:
    """World coordinates x(u, v, w) of one parameter point per hex (the trilinear map).

    Parameters
    ----------
    X : array_like, shape (M, 8, 3) or (8, 3)
    uvw : array_like, shape (M, 3) or (3,)

    Returns
    -------
    x : ndarray, shape (M, 3)
    """
    X = np.asarray(X, dtype=np.float64).reshape(-1, 8, 3)
    uvw = np.broadcast_to(np.asarray(uvw, dtype=np.float64), (X.shape[0], 3))
    N = np.ones((X.shape[0], 8))
    for n, c in enumerate(CORNERS):
        for ax in range(3):
            N[:, n] *= uvw[:, ax] if c[ax] else 1.0 - uvw[:, ax]
    return np.einsum("mn,mnc->mc", N, X)


def det_vertex_gradient(X, uvw, *, layout="aos") -> np.ndarray:
    """Gradient of det J at the parameter point uvw with respect to the 8 vertices.

    Parameters
    ----------
    X : array_like, shape (M, 8, 3) or (8, 3); with ``layout="soa"``, (3, 8, M)
    uvw : array_like, shape (M, 3) or (3,)

    Returns
    -------
    G : ndarray, shape (M, 8, 3); ``G[m, n]`` = d det J(uvw) / d X_n of hex m.
    """
    X = as_soa(X, layout)
    M = X.shape[2]
    uvw = np.broadcast_to(np.asarray(uvw, dtype=np.float64), (M, 3))
    xu, xv, xw, _ = _jacobian_at(X, uvw)
    cvw = np.cross(xv.T, xw.T)  # (M, 3)
    cwu = np.cross(xw.T, xu.T)
    cuv = np.cross(xu.T, xv.T)
    G = np.empty((M, 8, 3))
    for n, (i, j, k) in enumerate(CORNERS):
        # dN/du etc. of N = l_i(u) l_j(v) l_k(w), l_0(t) = 1 - t, l_1(t) = t
        lu = uvw[:, 0] if i else 1 - uvw[:, 0]
        lv = uvw[:, 1] if j else 1 - uvw[:, 1]
        lw = uvw[:, 2] if k else 1 - uvw[:, 2]
        su, sv, sw = (1.0 if i else -1.0), (1.0 if j else -1.0), (1.0 if k else -1.0)
        G[:, n] = (su * lv * lw)[:, None] * cvw + (sv * lu * lw)[:, None] * cwu + (sw * lu * lv)[:, None] * cuv
    return G


# --- exact rational arithmetic (for the few hexes whose sign is within the rounding bound) -----------


def _exact_jacobian(Xf, u, v, w):
    def lerp(a, b, t):
        return [a[c] + (b[c] - a[c]) * t for c in range(3)]

    def edge(n0, n1):
        return [Xf[n1][c] - Xf[n0][c] for c in range(3)]

    N = _NODE
    xu = lerp(lerp(edge(N[0, 0, 0], N[1, 0, 0]), edge(N[0, 1, 0], N[1, 1, 0]), v),
              lerp(edge(N[0, 0, 1], N[1, 0, 1]), edge(N[0, 1, 1], N[1, 1, 1]), v), w)
    xv = lerp(lerp(edge(N[0, 0, 0], N[0, 1, 0]), edge(N[1, 0, 0], N[1, 1, 0]), u),
              lerp(edge(N[0, 0, 1], N[0, 1, 1]), edge(N[1, 0, 1], N[1, 1, 1]), u), w)
    xw = lerp(lerp(edge(N[0, 0, 0], N[0, 0, 1]), edge(N[1, 0, 0], N[1, 0, 1]), u),
              lerp(edge(N[0, 1, 0], N[0, 1, 1]), edge(N[1, 1, 0], N[1, 1, 1]), u), v)
    return xu, xv, xw


def _exact_det(Xf, u, v, w) -> Fraction:
    a, b, c = _exact_jacobian(Xf, u, v, w)
    return (a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2])
            + a[2] * (b[0] * c[1] - b[1] * c[0]))


def _fractions(X8):
    X8 = np.asarray(X8, dtype=np.float64).reshape(8, 3)
    return [[Fraction(float(x)) for x in row] for row in X8]


def det_exact(X8, uvw) -> Fraction:
    """det J of one hex X8 (8, 3) at the float point uvw, exactly (rational arithmetic on the float inputs)."""
    u, v, w = (Fraction(float(t)) for t in uvw)
    return _exact_det(_fractions(X8), u, v, w)


def bernstein_exact(X8) -> list:
    """The 27 Bernstein coefficients of det J of one hex X8 (8, 3), exactly, as Fractions (order of B)."""
    Xf = _fractions(X8)
    h = Fraction(1, 2)
    F = [[[_exact_det(Xf, a * h, b * h, c * h) for c in range(3)] for b in range(3)] for a in range(3)]

    def tr(f0, f1, f2):
        return f0, 2 * f1 - (f0 + f2) / 2, f2

    for a in range(3):
        for b in range(3):
            F[a][b] = list(tr(*F[a][b]))
    for a in range(3):
        for c in range(3):
            col = tr(F[a][0][c], F[a][1][c], F[a][2][c])
            for b in range(3):
                F[a][b][c] = col[b]
    for b in range(3):
        for c in range(3):
            col = tr(F[0][b][c], F[1][b][c], F[2][b][c])
            for a in range(3):
                F[a][b][c] = col[a]
    return [F[a][b][c] for a in range(3) for b in range(3) for c in range(3)]
