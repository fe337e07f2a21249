"""An exact rational reference for det J's Bernstein coefficients, independent of the kernel's formulation.

The kernel computes coefficients by Bernstein products of the Jacobian's columns; this reference takes the
other road: det J at the equispaced grid of each factor (exactly, from the registry's exact shape functions,
themselves checked against VTK in test_elements), then the exact inverse of the Bernstein collocation matrix,
factor by factor. Degrees are restated here, not imported from the kernel's tables.
"""

from fractions import Fraction
from itertools import product
from math import factorial, prod

import numpy as np

from hexsos_plugins.cells.elements import ELEMENTS, eval_exact

# (kind, degree) of det J's factors, restated (see the module docstring of hexsos_plugins.cells.jacobian)
DEGREES = {
    "tetra": (("tet", 0),),
    "tetra10": (("tet", 3),),
    "pyramid": (("line", 2), ("line", 2), ("line", 0)),
    "pyramid13": (("line", 5), ("line", 5), ("line", 3)),
    "pyramid14": (("line", 5), ("line", 5), ("line", 3)),
    "wedge": (("tri", 1), ("line", 2)),
    "wedge15": (("tri", 4), ("line", 5)),
    "wedge18": (("tri", 4), ("line", 5)),
    "hexahedron": (("line", 2),) * 3,
    "hexahedron20": (("line", 5),) * 3,
    "hexahedron27": (("line", 5),) * 3,
    # order 3: det J of a tetrahedron has degree 3 (3 - 1) = 6, of a wedge 3 p - 2 = 7 on the triangle, 3 p - 1 = 8
    # along t
    "tetra20": (("tet", 6),),
    "wedge40": (("tri", 7), ("line", 8)),
}
_DIM = {"line": 1, "tri": 2, "tet": 3}


def _multi(kind, p):
    d = _DIM[kind]
    return [a for a in product(range(p + 1), repeat=d) if sum(a) <= p]


def _basis(kind, p, a, x):
    lam = [1 - sum(x)] + list(x)
    a0 = p - sum(a)
    c = Fraction(factorial(p), factorial(a0) * prod(factorial(v) for v in a))
    return c * lam[0] ** a0 * prod(l ** v for l, v in zip(lam[1:], a))


def _points(kind, p):
    return [tuple(Fraction(v, p) if p else Fraction(0) for v in a) for a in _multi(kind, p)]


def _inverse(M):
    n = len(M)
    A = [list(r) + [Fraction(int(i == j)) for j in range(n)] for i, r in enumerate(M)]
    for c in range(n):
        piv = next(r for r in range(c, n) if A[r][c] != 0)
        A[c], A[piv] = A[piv], A[c]
        inv = 1 / A[c][c]
        A[c] = [v * inv for v in A[c]]
        for r in range(n):
            if r != c and A[r][c]:
                f = A[r][c]
                A[r] = [x - f * y for x, y in zip(A[r], A[c])]
    return [r[n:] for r in A]


_CACHE = {}


def _tables(name):
    if name not in _CACHE:
        facs = DEGREES[name]
        pts = [_points(k, p) for k, p in facs]
        Tk = [_inverse([[_basis(k, p, a, x) for a in _multi(k, p)] for x in pp]) for (k, p), pp in zip(facs, pts)]
        grid = [sum((list(x) for x in combo), []) for combo in product(*pts)]
        el = ELEMENTS[name]
        D = [[[eval_exact(el.derivative_polynomials[d][i], g) for d in range(3)] for i in range(el.n_nodes)]
             for g in grid]
        _CACHE[name] = (Tk, D, [len(pp) for pp in pts])
    return _CACHE[name]


def exact_det(X, name, x):
    """det J (pyramids: the measure) of cell X (n, 3) at a rational point x, exactly."""
    el = ELEMENTS[name]
    Xf = [[Fraction(float(v)) for v in r] for r in np.asarray(X, float)]
    xf = [Fraction(v) for v in x]
    J = [[sum((Xf[i][a] * eval_exact(el.derivative_polynomials[d][i], xf) for i in range(el.n_nodes)), Fraction(0))
          for d in range(3)] for a in range(3)]
    return (J[0][0] * (J[1][1] * J[2][2] - J[1][2] * J[2][1]) - J[0][1] * (J[1][0] * J[2][2] - J[1][2] * J[2][0])
            + J[0][2] * (J[1][0] * J[2][1] - J[1][1] * J[2][0]))


def exact_coefficients(X, name):
    """det J's Bernstein coefficients of cell X, exactly, row-major over the factors."""
    Tk, D, sizes = _tables(name)
    Xf = [[Fraction(float(v)) for v in r] for r in np.asarray(X, float)]
    vals = []
    for Dq in D:
        J = [[sum((Xf[i][a] * Dq[i][d] for i in range(len(Xf))), Fraction(0)) for d in range(3)] for a in range(3)]
        vals.append(J[0][0] * (J[1][1] * J[2][2] - J[1][2] * J[2][1]) - J[0][1] * (J[1][0] * J[2][2] - J[1][2] * J[2][0])
                    + J[0][2] * (J[1][0] * J[2][1] - J[1][1] * J[2][0]))
    t = vals
    nb = len(t)
    pre = 1
    for T, n in zip(Tk, sizes):
        post = nb // (pre * n)
        out = [Fraction(0)] * nb
        for i0 in range(pre):
            for j in range(post):
                base = i0 * n * post + j
                src = [t[base + c * post] for c in range(n)]
                for r in range(n):
                    out[base + r * post] = sum((T[r][c] * src[c] for c in range(n)), Fraction(0))
        t = out
        pre *= n
    return t

