"""How far can a mesh move and stay valid: the certified largest safe fraction of a displacement.

For nodes x and a displacement d, every cell of ``x + t d`` has det J (pyramids: the measure) a polynomial in
the reference coordinates and in t: each coefficient of its Bernstein form in the reference coordinates is a
trilinear form of the Jacobian's columns, which are linear in the nodes, so it is a **cubic in t**. This module
finds, per cell, the largest t* in [0, 1] such that det J > 0 is *proven* on the whole element for every t in
[0, t*], and for the mesh a witness (cell, point, t) just past the mesh's t* where det J <= 0 is proven.

How (no step rests on an unbounded rounding):

1. **Samples.** The kernel's rigorous coefficients (:func:`hexsos_plugins.kernel.coefficients`: Bernstein
   coefficients in the reference coordinates with a bound ``err`` on their rounding) of the geometries
   ``fl(x + t_j d)`` at t_j = 0, 1/4, 1/2, 1 (t_j d is exact; the sum rounds once, within u |y| + eta per
   coordinate). That rounding moves det J's coefficients by at most ``sum over the 6 terms of the determinant and
   the 3 factors of E A A`` (A: a bound on the columns' coefficients per component and direction, E on their
   change; the product weights are positive and sum to 1), from the column gains of the type's exact tables.
   Every sample is brought to the largest of the four scalings by a power of two (exact).
2. **Cubic in t.** The exact Bernstein coefficients in t on [0, 1] are a fixed rational 4 x 4 matrix times the four
   samples; its float image carries a bound (the samples' bounds through |L|, plus the rounding of the product).
3. **Search.** Intervals of t are dyadic (halving a cubic's Bernstein form: (a + b) / 2 rounds once); on each, a
   branch-and-bound in the reference coordinates (the kernel's child matrices, non-negative and exact, their rounding
   bounded by (n + 2) u times the weighted sum) proves det J > 0 when every box's smallest coefficient exceeds its
   bound, or proves det J <= 0 at a box vertex and the interval's right end (there coefficients are values). A
   depth-first sweep from t = 0 keeps the proven prefix [0, t*]: to a relative width ``rtol_cells`` for every cell,
   then to ``rtol`` for the cells that can still be the mesh's minimum.
4. **Witness.** At the right end of the limiting cell's last interval (or a few widths further, where the kernel's
   minimizer of ``fl(x + t d)`` gives the point), det J of the exact geometry ``x + t d`` (rationals: t is dyadic) is
   evaluated at the point in rational arithmetic: the witness is reported only when that value is <= 0.
5. **The mesh at t*.** The mesh a solver would build, ``fl(x + t* d)``, must be proven valid as given (the
   kernel's rigorous coefficients of it, and the same branch-and-bound in the reference coordinates where they
   do not settle); if rounding of the points leaves a cell near zero unproven, t* steps back to a smaller proven
   dyadic value until it is.

Every t returned is a dyadic rational (a float with a short mantissa), so x + t d is the same number everywhere.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from fractions import Fraction
from functools import lru_cache
from itertools import product
from math import factorial, prod

import numpy as np

from ..cells.jacobian import exact_inverse
from ..errors import InvalidInputError

__all__ = ["safe_step", "SafeStepResult", "exact_det_at", "T_SAMPLES"]

U = 2.0**-53
ETA = 2.0**-1074
_SLACK_REL = 1.0 + 2.0**-44  # covers the rounding of the few operations that compute a bound
_SLACK_ABS = 2.0**-1060  # covers underflow (eta / 2 per operation) of up to 2^13 operations
#: The fractions of the step at which the kernel's coefficients are sampled (t d exact: powers of two).
T_SAMPLES = (0.0, 0.25, 0.5, 1.0)
_MAX_DEPTH = 60  # t intervals no narrower than 2^-60
_MAX_INTERVALS = 1000  # t intervals examined per cell at most


def _up(x):
    """A bound computed from non-negative terms, rounded up past the rounding of its own few operations."""
    return x * _SLACK_REL + _SLACK_ABS


# --- exact tables --------------------------------------------------------------------------------------------------
def _bernstein3(t):
    t = Fraction(t)
    return [(1 - t) ** 3, 3 * t * (1 - t) ** 2, 3 * t * t * (1 - t), t ** 3]


@lru_cache(maxsize=1)
def _interpolation():
    """(L, |L| rounded up): the cubic's Bernstein coefficients on [0, 1] from its values at T_SAMPLES (exact
    rationals L rounded to float; the bound covers that rounding)."""
    V = [_bernstein3(t) for t in T_SAMPLES]
    Lq = exact_inverse(V)
    L = np.array([[float(v) for v in r] for r in Lq])
    Labs = np.array([[math.nextafter(abs(float(v)), math.inf) if v else 0.0 for v in r] for r in Lq])
    return L, Labs


@lru_cache(maxsize=None)
def _column_gains(name):
    """Per direction d, an upper bound g_d of sum_n |weight of node n| over the coefficients of column d (the
    columns are w (P_b - P_a), P = C X): |column coefficient, component c| <= g_d max_n |X_nc - m_c| for any m."""
    from ..cells.jacobian import formulation

    F = formulation(name)
    C = F["C"]
    n = len(C[0])
    g = []
    for _, entries in F["columns"]:
        best = max(abs(w) * sum(abs(C[b][i] - C[a][i]) for i in range(n)) for a, b, w in entries)
        g.append(math.nextafter(float(best), math.inf))
    return np.array(g)


class _Space:
    """The arrays of one type's Bernstein space that the search uses (from :func:`hexsos_plugins.cells.jacobian.space`)."""

    def __init__(self, name):
        from ..cells.jacobian import space

        sp = space(name)
        self.name = name
        self.sizes = [int(s) for s in sp.sizes]
        self.nb = int(sp.nb)
        self.vidx = np.asarray(sp.vertex_idx, dtype=np.int64)
        self.ctrl = np.asarray(sp.ctrl, dtype=np.float64)
        self.factors = sp.factors
        self.slots = sp.slots
        # per factor: its child matrices (exact dyadic floats) and the affine maps of the children
        self.children = []
        for f, n in enumerate(self.sizes):
            nc = int(sp.nchildren[f])
            mats = np.ascontiguousarray(sp.S[f, :nc, :n, :n])
            nnz = int(np.count_nonzero(mats, axis=2).max())
            self.children.append((mats, np.ascontiguousarray(sp.child_maps[f, :nc]), nnz))


@lru_cache(maxsize=None)
def _space(name):
    return _Space(name)


# --- coefficients in (reference coordinates, t) -------------------------------------------------------------------
def _rounding_bound(Y, conn, g, K):
    """Bound on how much det J's coefficients (scaled by 2^-3K) move between the geometry fl(x + t d) = Y and
    the exact x + t d, whose coordinates differ by at most u |Y| + eta (one rounding of a sum)."""
    cells = Y[conn]  # (m, n, 3)
    eps = np.abs(cells).max(axis=1) * U + 2.0 * ETA  # (m, 3) world units
    rng = cells.max(axis=1) - cells.min(axis=1)
    sh = -K[:, None]
    eps = _up(np.ldexp(eps, sh))
    rng = _up(np.ldexp(rng, sh))
    A = _up(g[None, None, :] * (rng + 2.0 * eps)[:, :, None])  # (m, component, direction): both geometries
    E = _up(g[None, None, :] * eps[:, :, None])
    tot = np.zeros(A.shape[0])
    for s in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        a0, a1, a2 = A[:, s[0], 0], A[:, s[1], 1], A[:, s[2], 2]
        e0, e1, e2 = E[:, s[0], 0], E[:, s[1], 1], E[:, s[2], 2]
        tot = tot + e0 * a1 * a2 + a0 * e1 * a2 + a0 * a1 * e2
    return _up(tot)


def _time_coefficients(P, D, conn, name):
    """Per cell: det J's Bernstein coefficients in (reference coordinates, t on [0, 1]) (m, nb, 4), their error
    bounds (m, nb, 4), in units 2^(3 K) (K (m,) returned), from the kernel's samples at T_SAMPLES."""
    from ..kernel import coefficients

    m = conn.shape[0]
    ids = np.arange(m, dtype=np.int64)
    g = _column_gains(name)
    samples = []
    for t in T_SAMPLES:
        Y = P if t == 0.0 else P + t * D  # t D exact (a power of two); the sum rounds once
        b, err, k, _ = coefficients(Y, conn, ids, name)
        samples.append((Y, b, err, k))
    K = np.max([s[3] for s in samples], axis=0)
    nb = samples[0][1].shape[1]
    v = np.empty((m, nb, 4))
    e = np.empty((m, nb, 4))
    for j, (Y, b, err, k) in enumerate(samples):
        sh = 3 * (k - K)
        v[:, :, j] = np.ldexp(b, sh[:, None])
        ej = np.ldexp(err, sh) + ETA  # shifting down may underflow
        if T_SAMPLES[j] != 0.0:
            ej = ej + _rounding_bound(Y, conn, g, K)
        e[:, :, j] = _up(ej)[:, None]
    L, Labs = _interpolation()
    c = np.einsum("kj,mij->mik", L, v)
    va = np.abs(v)
    bound = np.einsum("kj,mij->mik", Labs, e) + 6.0 * U * np.einsum("kj,mij->mik", Labs, va)
    return c, _up(_up(bound)), K


def _halve_t(c, e):
    """The cubic's Bernstein coefficients (.., 4) on the two halves of its interval, with error bounds."""
    def mid(a, ea, b, eb):
        s = (a + b) * 0.5
        return s, _up((ea + eb) * 0.5 + U * np.abs(s) + ETA)

    c0, c1, c2, c3 = (c[..., i] for i in range(4))
    e0, e1, e2, e3 = (e[..., i] for i in range(4))
    a1, f1 = mid(c0, e0, c1, e1)
    m12, g12 = mid(c1, e1, c2, e2)
    b2, h2 = mid(c2, e2, c3, e3)
    a2, f2 = mid(a1, f1, m12, g12)
    b1, h1 = mid(m12, g12, b2, h2)
    a3, f3 = mid(a2, f2, b1, h1)
    left = np.stack([c0, a1, a2, a3], axis=-1), np.stack([e0, f1, f2, f3], axis=-1)
    right = np.stack([a3, b1, b2, c3], axis=-1), np.stack([f3, h1, h2, e3], axis=-1)
    return left, right


def _subdivide(c, e, A, o, sp):
    """Every box (B, nb, 4) split along every factor by the child matrices; the boxes' affine maps follow."""
    B = c.shape[0]
    shape = [B] + sp.sizes + [4]
    c, e, ca = c.reshape(shape), e.reshape(shape), np.abs(c).reshape(shape)
    for f, (Ms, maps, nnz) in enumerate(sp.children):
        nc = Ms.shape[0]
        if nc == 1:
            continue
        axis = 1 + f

        def apply(x):
            x = np.moveaxis(x, axis, 1)
            sh = x.shape
            y = np.matmul(Ms[:, None], x.reshape(sh[0], sh[1], -1)[None])  # (nc, B, n, rest)
            y = y.reshape((nc * sh[0],) + sh[1:])
            return np.moveaxis(y, 1, axis)

        c, ce, cabs = apply(c), apply(e), apply(ca)
        e = _up(ce + (nnz + 2) * U * cabs)
        ca = np.abs(c)
        o = (o[None] + np.einsum("bij,cj->cbi", A, maps[:, :, 3])).reshape(-1, 3)
        A = np.einsum("bij,cjk->cbik", A, maps[:, :, :3]).reshape(-1, 3, 3)
    n = c.shape[0]
    return c.reshape(n, -1, 4), e.reshape(n, -1, 4), A, o


_PROVEN, _NEG, _UNKNOWN = 1, 0, -1


def _prove(c, e, sp, max_boxes, max_levels=24):
    """On one t interval (coefficients (nb, 4)): _PROVEN (det J > 0 on element x interval), (_NEG, point) (det J
    <= 0 proven at that point and the interval's right end), or _UNKNOWN within the budget."""
    cb, eb = c[None], e[None]
    A = np.eye(3)[None]
    o = np.zeros((1, 3))
    for _ in range(max_levels):
        hi_val = cb[:, sp.vidx, 3] + eb[:, sp.vidx, 3]
        neg = hi_val <= 0.0
        if neg.any():
            i, j = np.argwhere(neg)[0]
            x = A[i] @ sp.ctrl[sp.vidx[j]] + o[i]
            return _NEG, x
        low = (cb - eb).reshape(cb.shape[0], -1).min(axis=1)
        keep = ~(low > 0.0)  # NaN stays open
        if not keep.any():
            return _PROVEN, None
        if keep.sum() * _children_count(sp) > max_boxes:
            return _UNKNOWN, None
        cb, eb, A, o = _subdivide(cb[keep], eb[keep], A[keep], o[keep], sp)
    return _UNKNOWN, None


def _children_count(sp):
    return prod(m.shape[0] for m, _, _ in sp.children)


@dataclass
class _Sweep:
    """The depth-first sweep over dyadic t intervals of one cell: the proven prefix [0, lo], the intervals still
    to visit (level, index, coefficients, bounds), the first right end where det J <= 0 was proven (hi), the point."""

    stack: list
    lo: float = 0.0
    hi: float = math.inf
    point: np.ndarray | None = None
    hi_level: int = 0
    stuck: tuple | None = None  # the (level, index) interval where the sweep stopped
    stuck_item: tuple | None = None  # that interval with its coefficients (where a finer sweep resumes)
    intervals: int = 0  # intervals examined (a sweep stops at _MAX_INTERVALS)
    done: bool = False


def _start(c, e):
    return _Sweep(stack=[(0, 0, c, e)])


def _run(sw, sp, rtol, max_boxes, stop_at=math.inf):
    """Continue the sweep until the interval to examine is narrower than rtol times its left end (or the stack
    is empty: lo = 1), or the proven prefix reaches ``stop_at``."""
    if sw.stuck is not None:
        sw.stack.append(sw.stuck_item)
        sw.stuck = None
    while sw.stack:
        if sw.lo >= stop_at:
            return sw
        if sw.intervals >= _MAX_INTERVALS:  # the budget: lo stays what is proven
            return sw
        sw.intervals += 1
        m, k, c, e = sw.stack.pop()
        a = k * 2.0**-m
        # a wide interval gets a small budget of boxes: halving it in t is cheaper than a deep search in space
        # for an interval that is not provable at all (it reaches past the cell's loss)
        r, x = _prove(c, e, sp, min(max_boxes, 64 << min(m, 20)))
        if r == _PROVEN:
            sw.lo = (k + 1) * 2.0**-m
            continue
        if r == _NEG:
            right = (k + 1) * 2.0**-m
            if right <= sw.hi:
                sw.hi, sw.point, sw.hi_level = right, x, m
            sw.stack = []  # nothing right of a proven loss matters
        width = 2.0**-m
        if m >= _MAX_DEPTH or (a > 0 and width <= rtol * a) or (a == 0 and width <= 2.0**-_MAX_DEPTH):
            sw.stuck = (m, k)
            sw.stuck_item = (m, k, c, e)
            return sw
        (cl, el), (cr, er) = _halve_t(c, e)
        sw.stack.append((m + 1, 2 * k + 1, cr, er))
        sw.stack.append((m + 1, 2 * k, cl, el))
    sw.lo = 1.0 if sw.hi == math.inf else sw.lo
    sw.done = True
    return sw


# --- exact evaluation ---------------------------------------------------------------------------------------------
def _basis_exact(kind, p, x):
    """The factor's Bernstein basis values at x (rationals), in the order of its indices."""
    if kind == "line":
        s = x[0]
        return [Fraction(math.comb(p, i)) * (1 - s) ** (p - i) * s ** i for i in range(p + 1)]
    d = 2 if kind == "tri" else 3
    lam = [1 - sum(x)] + list(x)
    out = []
    for a in product(range(p + 1), repeat=d):
        if sum(a) > p:
            continue
        a0 = p - sum(a)
        coef = Fraction(factorial(p), factorial(a0) * prod(factorial(v) for v in a))
        v = coef * lam[0] ** a0
        for ai, li in zip(a, lam[1:]):
            v *= li ** ai
        out.append(v)
    return out


def exact_det_at(X, name, x) -> Fraction:
    """det J (pyramids: the measure) of one cell with rational (or float) nodes X (n, 3) at the reference point x,
    exactly: the exact Bernstein coefficients (:func:`hexsos_plugins.kernel.exact.exact_coefficients`) at x."""
    from ..kernel.exact import exact_coefficients
    from ..cells.jacobian import space

    sp = space(name)
    coef = exact_coefficients([[Fraction(v) for v in row] for row in X], name)
    xq = [Fraction(float(v)) for v in x]
    vals = [_basis_exact(kind, p, [xq[s] for s in slots]) for (kind, p), slots in zip(sp.factors, sp.slots)]
    total = Fraction(0)
    for combo, cf in zip(product(*[range(len(v)) for v in vals]), coef):
        if cf:
            total += cf * prod(vals[f][i] for f, i in enumerate(combo))
    return total


def _exact_cell(P, D, conn_row, t):
    tq = Fraction(t)
    return [[Fraction(float(P[n, a])) + tq * Fraction(float(D[n, a])) for a in range(3)] for n in conn_row]


# --- result --------------------------------------------------------------------------------------------------------
@dataclass
class SafeStepResult:
    """The certified largest safe fraction of a displacement.

    ``t``: the mesh's t* (1.0 when the whole step is proven safe): det J > 0 is proven on every cell for every
    t in [0, t]. ``cell_t`` (M,): per cell, a proven safe fraction (1.0, or within ``rtol_cells`` relative of the
    cell's true one; the cells that set the mesh's t*, within ``rtol``). ``cell_hi`` (M,): per cell, a t where its
    det J <= 0 was proven (inf where none was sought or found). ``witness``: ``{"cell", "cell_type", "point",
    "t", "det", "exact_det"}`` (cell: its index in the blocks' order; point: reference coordinates, as
    :attr:`hexsos_plugins.CheckResult.argmin`) with
    det J of the exact ``x + t d`` at the reference point, <= 0 by rational arithmetic (det: that value rounded
    to a float, world units), or None (the whole step is safe, or no loss was proven). ``check_valid``: whether
    every cell of fl(x + t d), the points as a float array, is proven valid as given (True unless t = 0)."""

    t: float
    cell_t: np.ndarray
    cell_hi: np.ndarray
    witness: dict | None
    check_valid: bool
    seconds: float = 0.0
    stats: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)  # what a door adds (e.g. the Gmsh element tags)

    @property
    def safe(self) -> bool:
        """Whether the whole step (t = 1) is proven safe."""
        return self.t == 1.0

    def to_dict(self) -> dict:
        w = None
        if self.witness is not None:
            w = {"cell": int(self.witness["cell"]), "point": [float(v) for v in self.witness["point"]],
                 "t": float(self.witness["t"]), "det": float(self.witness["det"])}
        return {"safe_step": float(self.t), "witness": w, "whole_step_safe": self.safe,
                "check_valid_at_safe_step": bool(self.check_valid), "cells": int(self.cell_t.size),
                "cells_limited": int(np.count_nonzero(self.cell_t < 1.0)) if self.stats.get("per_cell", True) else None,
                "seconds": float(self.seconds)}


def _as_displacement(displacement, n_points):
    D = np.asarray(displacement, dtype=np.float64)
    if D.shape != (n_points, 3):
        raise InvalidInputError(f"displacement: expected an array of shape ({n_points}, 3) (one vector per point), "
                                f"found shape {D.shape}")
    if not np.all(np.isfinite(D)):
        raise InvalidInputError("displacement: expected finite values, found NaN or infinity")
    return D


def safe_step(points, cells, displacement, *, rtol: float = 2.0**-24, rtol_cells: float = 2.0**-10,
              max_boxes: int = 4096, jobs: int = 1, verify: bool = True, per_cell: bool = True) -> SafeStepResult:
    """The certified largest fraction t* in [0, 1] of the displacement that keeps every cell valid.

    Parameters
    ----------
    points : array_like (N, 3)
    cells : the forms :func:`hexsos_plugins.check` takes (an (M, 8) hex array, (type, conn) pairs, a dict)
    displacement : array_like (N, 3), one vector per point: the step moves the points to ``points + t *
        displacement``.
    rtol : float, keyword-only
        Relative width to which the mesh's t* is resolved (default 2^-24, about 6e-8).
    rtol_cells : float, keyword-only
        Relative width for the other cells' fractions (default 2^-10).
    max_boxes : int, keyword-only
        Most boxes in the reference coordinates per t interval.
    jobs : int, keyword-only
        Threads of the compiled kernel (0: one per core).
    verify : bool, keyword-only
        Prove every cell of fl(x + t* d) valid as given (and step back until it is).
    per_cell : bool, keyword-only
        Resolve every cell's own safe fraction (default). False: only the mesh's t* and its witness; each cell
        is then swept no further than needed to show it is not the minimum (``cell_t`` holds proven lower
        bounds, not resolved ones): much faster when many cells limit the step.

    Returns
    -------
    SafeStepResult

    Examples
    --------
    >>> import numpy as np
    >>> from hexsos_plugins.certify.safe_step import safe_step
    >>> cube = np.array([[0,0,0],[1,0,0],[1,1,0],[0,1,0],[0,0,1],[1,0,1],[1,1,1],[0,1,1]], float)
    >>> d = np.zeros_like(cube); d[6] = [-3.0, -3.0, -3.0]  # node 6 pushed through the cell
    >>> r = safe_step(cube, [range(8)], d)
    >>> 0 < r.t < 1, r.witness["t"] > r.t
    (True, True)
    """
    from .pipeline import validate_cells
    from ..kernel import cores, set_threads

    t0 = time.perf_counter()
    if not isinstance(jobs, (int, np.integer)) or jobs < 0:
        raise InvalidInputError(f"jobs: expected a number >= 0 (0: one per core), found {jobs!r}")
    if not (0 < rtol < 1 and 0 < rtol_cells < 1):
        raise InvalidInputError(f"rtol, rtol_cells: expected numbers in (0, 1), found {rtol!r}, {rtol_cells!r}")
    P, blocks = validate_cells(points, cells)
    D = _as_displacement(displacement, P.shape[0])
    old = set_threads(cores() if jobs == 0 else jobs)
    try:
        return _safe_step(P, D, blocks, rtol, rtol_cells, max_boxes, verify, t0, per_cell)
    finally:
        set_threads(old)


def _estimate(c, vidx, n=65):
    """A first guess (no proof) of where each cell loses validity: the first of n values of t where det J at a
    vertex of the element (its vertex coefficients' cubic in t) is negative; 1 where none is."""
    ts = np.linspace(0.0, 1.0, n)
    B = np.stack([(1 - ts) ** 3, 3 * ts * (1 - ts) ** 2, 3 * ts ** 2 * (1 - ts), ts ** 3], axis=1)  # (n, 4)
    vals = (c[:, vidx, :] @ B.T).min(axis=1)  # (m, n)
    neg = vals < 0
    return np.where(neg.any(axis=1), ts[np.argmax(neg, axis=1)], 1.0)


def _safe_step(P, D, blocks, rtol, rtol_cells, max_boxes, verify, t0, per_cell=True):
    total = sum(b.shape[0] for _, b in blocks)
    cell_t = np.ones(total)
    cell_hi = np.full(total, np.inf)
    sweeps = {}  # global cell index -> (sweep, space, block conn row, type)
    pending = []  # (first guess, global index, coefficients, bounds, space, conn row, type)
    # the mesh as given: a cell not proven valid at t = 0 has no safe step (and is not swept)
    from .pipeline import check

    at_start = check(P, blocks)
    start_bad = np.asarray(at_start.status) != 1
    start = 0
    root_proven = 0
    for name, conn in blocks:
        m = conn.shape[0]
        if m == 0:
            continue
        c, e, _ = _time_coefficients(P, D, conn, name)
        low = (c - e).reshape(m, -1).min(axis=1)
        ok = low > 0.0
        root_proven += int(ok.sum())
        sp = _space(name)
        finite = np.isfinite(c).reshape(m, -1).all(axis=1) & np.isfinite(e).reshape(m, -1).all(axis=1)
        # no coefficient at t = 0 clears its bound (e.g. a cell that grows by hundreds of orders of magnitude over
        # the step, its start then lost below the scaling): no subdivision can prove anything near t = 0
        hopeless = ~((c[:, :, 0] - e[:, :, 0]).max(axis=1) > 0.0)
        skip = start_bad[start:start + m] | ~finite | hopeless  # no safe step proven (cell_t = 0)
        cell_t[start:start + m][skip] = 0.0
        bad = np.flatnonzero(~ok & ~skip)
        est = _estimate(c[bad], sp.vidx) if bad.size else []
        for i, g in zip(bad, est):
            pending.append((float(g), start + int(i), c[i], e[i], sp, conn[i], name))
        start += m
    pending.sort(key=lambda p: (p[0], p[1]))
    refined = set()
    if per_cell:
        for _, g, c, e, sp, row, name in pending:
            sw = _run(_start(c, e), sp, rtol_cells, max_boxes)
            sweeps[g] = (sw, sp, row, name)
            cell_t[g], cell_hi[g] = sw.lo, sw.hi
        # refine the cells that can still hold the mesh's minimum
        while True:
            T_hi = cell_hi.min() if total else np.inf
            todo = [g for g, (sw, *_r) in sweeps.items() if g not in refined and not sw.done and cell_t[g] < T_hi]
            if not todo:
                break
            for g in todo:
                sw, sp, _, _ = sweeps[g]
                _run(sw, sp, rtol, max_boxes)
                cell_t[g], cell_hi[g] = sw.lo, sw.hi
                refined.add(g)
    else:
        # the mesh's minimum only: cells in the order of their first guess, each swept (to rtol) no further than
        # the smallest t where a loss is proven so far
        T_hi = math.inf
        for _, g, c, e, sp, row, name in pending:
            sw = _run(_start(c, e), sp, rtol, max_boxes, stop_at=T_hi)
            sweeps[g] = (sw, sp, row, name)
            cell_t[g], cell_hi[g] = sw.lo, sw.hi
            T_hi = min(T_hi, sw.hi)
            refined.add(g)
    T = float(cell_t.min()) if total else 1.0
    witness = None
    if start_bad.any():  # invalid as given: the check's witness, at t = 0
        witness = _start_witness(P, blocks, at_start)
    elif T < 1.0:
        witness = _find_witness(P, D, sweeps, cell_t, T)
    check_valid = True
    steps_back = 0
    if verify and T > 0.0:
        while T > 0.0:
            if _valid_as_given(P + T * D, blocks, max_boxes):
                break
            steps_back += 1  # every t below a proven t is proven too: step back to a shorter dyadic t
            T = float(np.ldexp(np.floor(np.ldexp(T * (1.0 - 2.0 ** (steps_back - 24)), 40)), -40))
        check_valid = T > 0.0
    elif T == 0.0:
        check_valid = False
    stats = {"cells": total, "root_proven": root_proven, "searched": len(sweeps), "refined": len(refined),
             "per_cell": bool(per_cell),
             "steps_back": steps_back}
    return SafeStepResult(t=T, cell_t=cell_t, cell_hi=cell_hi, witness=witness, check_valid=check_valid,
                          seconds=time.perf_counter() - t0, stats=stats)


def _valid_as_given(Y, blocks, max_boxes):
    """Whether every cell of the mesh Y, as given (floats), is proven valid: the kernel's rigorous coefficients,
    then the branch-and-bound of the search on the cells whose smallest coefficient does not clear its bound
    (a budget of ``max_boxes`` boxes a cell; :func:`hexsos_plugins.check` would bring its full machinery, whose
    search can take long on a cell whose minimum is this close to 0)."""
    from ..kernel import coefficients

    for name, conn in blocks:
        m = conn.shape[0]
        if m == 0:
            continue
        b, err, _, _ = coefficients(Y, conn, np.arange(m, dtype=np.int64), name)
        low = b.min(axis=1) - err
        if not np.all(np.isfinite(b)):
            return False
        sp = _space(name)
        for i in np.flatnonzero(~(low > 0.0)):
            c = np.repeat(b[i][:, None], 4, axis=1)  # constant in t
            e = np.full_like(c, _up(err[i]))
            if _prove(c, e, sp, max_boxes)[0] != _PROVEN:
                return False
    return True


def _start_witness(P, blocks, result):
    """A cell proven invalid as given (t = 0) and its point, confirmed in rational arithmetic; None if the mesh
    is only undecided there."""
    start = 0
    for name, conn in blocks:
        for i in np.flatnonzero(np.asarray(result.status[start:start + len(conn)]) == 0):
            x = np.asarray(result.argmin[start + i], dtype=np.float64)
            val = exact_det_at(_exact_cell(P, np.zeros_like(P), conn[i], 0.0), name, x)
            if val <= 0:
                return {"cell": int(start + i), "cell_type": name, "point": x, "t": 0.0, "det": float(val),
                        "exact_det": val}
        start += len(conn)
    return None


def _find_witness(P, D, sweeps, cell_t, T):
    """A point and a t > T where det J of the exact x + t d is <= 0 (rational arithmetic), in a cell whose safe
    fraction is T; None if none is proven."""
    from ..kernel import run_cells

    for g in np.flatnonzero(cell_t == T):
        if int(g) not in sweeps:  # not swept (its coefficients are not finite numbers): no witness from it
            continue
        sw, sp, row, name = sweeps[int(g)]
        candidates = []
        if sw.point is not None:
            candidates.append((sw.hi, sw.point))
        width = 2.0**-(sw.stuck[0] if sw.stuck else sw.hi_level)
        for i in range(12):
            t = sw.lo + width * 2.0**i
            if t > 1.0 or t > sw.hi:
                break
            Y = P[row] + t * D[row]
            out = run_cells(Y, np.arange(len(row), dtype=np.int64)[None], np.zeros(1, dtype=np.int64), name)
            candidates.append((t, out["argmin"][0].copy()))
        candidates.sort(key=lambda tc: tc[0])
        for t, x in candidates:
            val = exact_det_at(_exact_cell(P, D, row, t), name, x)
            if val <= 0:
                return {"cell": int(g), "cell_type": name, "point": np.asarray(x, dtype=np.float64), "t": float(t),
                        "det": float(val), "exact_det": val}
    return None
