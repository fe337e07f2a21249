"""Exact rational decisions for the few cells whose sign float64 cannot settle.

The float kernel proves a verdict when a bound clears its rounding error. When it does not (det J within a
few units of rounding of 0 somewhere, or values below the float range after scaling), the cell is decided
here from its **input coordinates taken as rationals** (every float is a rational): the same formulation as
the kernel (:func:`hexsos_plugins.cells.jacobian.formulation`: control points, column differences, Bernstein
products) in :class:`fractions.Fraction` arithmetic gives det J's exact Bernstein coefficients, and an exact
best-first subdivision (the same child matrices, exact) looks for either

* a box whose coefficients are all > 0 for every box still open: **valid**, with the smallest of those
  coefficients as an exact lower bound, or
* a box vertex (a value of det J) <= 0: **invalid**, with that point and value.

It stops after a bounded number of boxes; a cell still open is left undecided (typically det J = 0 at a
point where it also has a zero gradient: a degenerate cell). Nothing is scaled or rounded on the way, so the
decision is about the cell exactly as given.
"""

from __future__ import annotations

import heapq
import math
from fractions import Fraction

import numpy as np

from ..cells.jacobian import formulation, space

__all__ = ["exact_coefficients", "decide", "round_down", "round_nearest", "beyond_float"]


def exact_coefficients(X, name: str) -> list:
    """det J's Bernstein coefficients (pyramids: the measure's) of one cell X (n, 3), exactly, as Fractions,
    in the order of :func:`hexsos_plugins.cells.jacobian.space`. X: floats, or rows of Fractions (taken as they are)."""
    F = formulation(name)
    if isinstance(X, list) and X and isinstance(X[0][0], Fraction):
        Xf = [list(row) for row in X]
    else:
        Xf = [[Fraction(float(v)) for v in row] for row in np.asarray(X, dtype=np.float64)]
    C = F["C"]
    P = [[sum((c * Xf[i][a] for i, c in enumerate(row) if c), Fraction(0)) for a in range(3)] for row in C]
    cols = [[[w * (P[b][a] - P[i][a]) for a in range(3)] for i, b, w in entries] for _, entries in F["columns"]]
    X1 = [[Fraction(0)] * 3 for _ in range(F["nx"])]
    c1, c2 = cols[1], cols[2]
    for g, i, j, w in F["cross"]:
        a, b = c1[i], c2[j]
        X1[g][0] += w * (a[1] * b[2] - a[2] * b[1])
        X1[g][1] += w * (a[2] * b[0] - a[0] * b[2])
        X1[g][2] += w * (a[0] * b[1] - a[1] * b[0])
    out = [Fraction(0)] * space(name).nb
    c0 = cols[0]
    for k, i, j, w in F["dot"]:
        a, x = c0[i], X1[j]
        out[k] += w * (a[0] * x[0] + a[1] * x[1] + a[2] * x[2])
    return out


def _children(coef, sp):
    """The children's exact coefficients of one box (the order of the kernel: row-major over factors)."""
    sizes = [int(z) for z in sp.sizes]
    nb = len(coef)
    tensors = [list(coef)]
    pre = 1
    for k, nk in enumerate(sizes):
        post = nb // (pre * nk)
        mats = sp.exact_S[k]
        if len(mats) > 1:
            new = []
            for t in tensors:
                for S in mats:
                    out = [Fraction(0)] * nb
                    for i0 in range(pre):
                        for j in range(post):
                            base = i0 * nk * post + j
                            src = [t[base + c * post] for c in range(nk)]
                            for r in range(nk):
                                out[base + r * post] = sum((S[r][c] * src[c] for c in range(nk) if S[r][c]), Fraction(0))
                    new.append(out)
            tensors = new
        pre *= nk
    return tensors


def decide(X, name: str, *, max_boxes: int = 400):
    """Decide one cell exactly.

    Returns ``(status, lower, witness, value, corner)``: status 1 (valid; ``lower`` a Fraction <= min det J,
    > 0), 0 (invalid; ``witness`` the parametric point (3,) of a vertex where det J = ``value`` <= 0) or -1
    (undecided within ``max_boxes`` boxes; ``lower`` the smallest bound found); ``corner`` the exact smallest
    det J at the cell's corner nodes."""
    sp = space(name)
    if name == "hexahedron":
        quick = _hex_corner_decision(X, sp)
        if quick is not None:
            return quick
    coef = exact_coefficients(X, name)
    corner = min(coef[int(j)] for j in sp.corner_idx)
    st, lower, witness, value = _decide(coef, sp, max_boxes)
    return st, lower, witness, value, corner


#: The trilinear hexahedron's corners (VTK order) and, per corner, the neighbours along r, s and t
_HEX_CORNERS = ((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1))
_HEX_ALONG = tuple(tuple(_HEX_CORNERS.index(tuple(c ^ (a == k) for k, c in enumerate(p))) for a in range(3))
                   for p in _HEX_CORNERS)


def _hex_corner_decision(X, sp):
    """:func:`decide`'s answer for a trilinear hex with two nodes at the same point where a corner decides it,
    without the 27 coefficients: det J at a corner is its Bernstein coefficient there, the determinant of its three
    edges (each signed from the lower coordinate to the higher), exactly. A hex with coincident nodes often has a
    corner with det J exactly 0 (an edge of no length), which float64 cannot settle: a stress start with every
    interior vertex of the 34,880-hex kitten_with_bifur_3 at one point sends 5,171 such hexes here, and its check took
    5.0 s with the 27 coefficients, 0.9 s with this (the same results). None where no node coincides with another
    or every corner is positive (the full decision follows)."""
    A = np.asarray(X, dtype=np.float64)
    if A.shape != (8, 3) or np.unique(A, axis=0).shape[0] == 8:
        return None
    # every float is an integer over a power of two: on a common denominator D the corners' determinants are
    # integer arithmetic, exact, over D^3
    ratios = [[float(v).as_integer_ratio() for v in row] for row in A]
    D = max(d for row in ratios for _, d in row)
    Xf = [[n * (D // d) for n, d in row] for row in ratios]
    values = {}
    for c, p in enumerate(_HEX_CORNERS):
        cols = []
        for a in range(3):
            n = _HEX_ALONG[c][a]
            lo, hi = (c, n) if p[a] == 0 else (n, c)
            cols.append([Xf[hi][k] - Xf[lo][k] for k in range(3)])
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = cols  # d x / d r, d x / d s, d x / d t
        values[p] = Fraction(a0 * (b1 * c2 - b2 * c1) - b0 * (a1 * c2 - a2 * c1) + c0 * (a1 * b2 - a2 * b1), D ** 3)
    ctrl = sp.ctrl
    vidx = [int(v) for v in sp.vertex_idx]
    # the coefficient of index j sits at the corner ctrl[j]; the same vertex as _decide picks (the first least)
    at = {j: values[tuple(int(round(x)) for x in ctrl[j])] for j in vidx}
    j = min(vidx, key=lambda v: at[v])
    if at[j] > 0:
        return None
    corner = min(values[tuple(int(round(x)) for x in ctrl[int(k)])] for k in sp.corner_idx)
    return 0, None, np.array(ctrl[j], dtype=np.float64), at[j], corner


def _decide(coef, sp, max_boxes):
    maps = np.asarray(sp.child_maps)
    vidx = [int(v) for v in sp.vertex_idx]
    ctrl = sp.ctrl

    def vertex_check(c, A, o):
        j = min(vidx, key=lambda v: c[v])
        if c[j] <= 0:
            return j, A @ ctrl[j] + o
        return None

    A0, o0 = np.eye(3), np.zeros(3)
    hit = vertex_check(coef, A0, o0)
    if hit is not None:
        return 0, None, hit[1], coef[hit[0]]
    low = min(coef)
    if low > 0:
        return 1, low, None, None
    # exact best-first subdivision; boxes ordered by their smallest coefficient
    counter = 0
    heap = [(low, counter, coef, A0, o0)]
    settled_low = None  # smallest positive bound of the boxes proven positive
    nchild = [int(c) for c in sp.nchildren]
    combos = list(np.ndindex(*nchild))
    boxes = 0
    while heap:
        low, _, c, A, o = heapq.heappop(heap)
        if low > 0:  # every remaining box is positive too
            settled_low = low if settled_low is None else min(settled_low, low)
            for item in heap:
                settled_low = min(settled_low, item[0])
            return 1, settled_low, None, None
        if boxes >= max_boxes:
            return -1, low, None, None
        for combo, child in zip(combos, _children(c, sp)):
            boxes += 1
            Ac, oc = A.copy(), o.copy()
            for f, ci in enumerate(combo):
                Mk = maps[f, ci]
                oc = oc + Ac @ Mk[:, 3]
                Ac = Ac @ Mk[:, :3]
            hit = vertex_check(child, Ac, oc)
            if hit is not None:
                return 0, None, hit[1], child[hit[0]]
            cl = min(child)
            if cl > 0:
                settled_low = cl if settled_low is None else min(settled_low, cl)
                continue
            counter += 1
            heapq.heappush(heap, (cl, counter, child, Ac, oc))
    return 1, settled_low, None, None  # every box was proven positive


def round_down(q) -> float:
    """The largest float <= the rational q (0.0 or a subnormal for tiny positive q; -max for q below it)."""
    try:
        f = float(q)
    except OverflowError:
        return -1.7976931348623157e308 if q < 0 else 1.7976931348623157e308
    if f > q:
        f = math.nextafter(f, -math.inf)
    return f


def round_nearest(q) -> float:
    """The float nearest to q with the sign of q (a nonzero q that underflows becomes the smallest
    subnormal of its sign; one that overflows the largest float of its sign)."""
    try:
        f = float(q)
    except OverflowError:  # q is a Fraction or an int: its sign by comparison (math.copysign would convert it)
        return -1.7976931348623157e308 if q < 0 else 1.7976931348623157e308
    if f == 0.0 and q != 0:
        return -5e-324 if q < 0 else 5e-324
    return f


def beyond_float(q) -> bool:
    """Does the rational q lie beyond float64's range (|q| > the largest float)?"""
    return abs(q) > _MAX_FLOAT


_MAX_FLOAT = Fraction(1.7976931348623157e308)
