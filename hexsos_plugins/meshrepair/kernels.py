"""Compiled (numba) energy and gradient loops of :mod:`hexsos_plugins.meshrepair.optimize`.

Each loop runs over the cells of one block and, per cell, over its samples ``E_k = X^T G_k`` (3x3), and adds
its gradient straight into the vertex gradient ``g`` (N, 3). IEEE double precision, no fast-math. The
vectorized numpy expressions in :mod:`hexsos_plugins.meshrepair.optimize` compute the same numbers (tested).

numba compiles the loops at first use and caches them (``cache=True``). :func:`load` compiles or loads every loop
the repair calls, for the argument types of :data:`SIGNATURES`, before the repair's clocks start: the stages'
budgets in seconds then do not pay for a first compilation (measured: a first repair of the bunny spent 22 s of
its untangling's and its whole quality stage's 30 s compiling, and ended at 0.705 against 0.789 once cached).
"""

from __future__ import annotations

from functools import partial

import numpy as np
from numba import njit, types

from ..cells.hexahedron import EDGES
from ..cells.quality import SAMPLES


@njit(cache=True, inline="always")
def cofactor(J, C):
    """The cofactor matrix of the 3x3 J into C; returns det J (expanded along its first row)."""
    C[0, 0] = J[1, 1] * J[2, 2] - J[1, 2] * J[2, 1]
    C[0, 1] = J[1, 2] * J[2, 0] - J[1, 0] * J[2, 2]
    C[0, 2] = J[1, 0] * J[2, 1] - J[1, 1] * J[2, 0]
    C[1, 0] = J[0, 2] * J[2, 1] - J[0, 1] * J[2, 2]
    C[1, 1] = J[0, 0] * J[2, 2] - J[0, 2] * J[2, 0]
    C[1, 2] = J[0, 1] * J[2, 0] - J[0, 0] * J[2, 1]
    C[2, 0] = J[0, 1] * J[1, 2] - J[0, 2] * J[1, 1]
    C[2, 1] = J[0, 2] * J[1, 0] - J[0, 0] * J[1, 2]
    C[2, 2] = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
    return J[0, 0] * C[0, 0] + J[0, 1] * C[0, 1] + J[0, 2] * C[0, 2]


@njit(cache=True, inline="always")
def _chi(D, e2):
    """chi(D, eps) = (D + sqrt(eps^2 + D^2)) / 2 and d chi / dD, without the cancellation of D + r for D < 0
    (there chi = eps^2 / (2 (r - D)): with D = -0.9 and eps = 1e-9 the direct sum is exactly 0)."""
    r = np.sqrt(e2 + D * D)
    if D >= 0.0:
        chi = 0.5 * (D + r)
    else:
        chi = 0.5 * e2 / (r - D)
    return chi, chi / r


@njit(cache=True, inline="always")
def _gather(V, conn, m, X):
    """The nodes of cell m into X (n, 3)."""
    for i in range(conn.shape[1]):
        v = conn[m, i]
        X[i, 0] = V[v, 0]
        X[i, 1] = V[v, 1]
        X[i, 2] = V[v, 2]


@njit(cache=True, inline="always")
def _scatter(g, conn, m, gl):
    """Cell m's node gradients gl (n, 3) added into g, node by node."""
    for i in range(conn.shape[1]):
        v = conn[m, i]
        g[v, 0] += gl[i, 0]
        g[v, 1] += gl[i, 1]
        g[v, 2] += gl[i, 2]


@njit(cache=True, inline="always")
def _corner_term(J, C, D, F, e2, theta, inv, want_grad, dE):
    """Stage 1's term of one sample (J its Jacobian in units of the cell's size, C its cofactors, D = det J,
    F = |J|^2): returns it, and with ``want_grad`` puts its derivative by E = J s into dE."""
    chi, dchi = _chi(D, e2)
    c23 = chi ** (-2.0 / 3.0)
    if want_grad:
        coef = (-(2.0 / 3.0) * (1.0 - theta) * F * c23 / chi * dchi
                + theta * (2.0 * D / chi - (D * D + 1.0) * dchi / (chi * chi)))
        for a in range(3):
            for d in range(3):
                dE[a, d] = (2.0 * (1.0 - theta) * c23 * J[a, d] + coef * C[a, d]) * inv
    return (1.0 - theta) * F * c23 + theta * (D * D + 1.0) / chi


@njit(cache=True, nogil=True)
def untangle_corners(V, conn, G, s, eps, theta, g, want_grad):
    """Stage 1 over corner samples G (K, n, 3) (ideal-cell corners folded in): returns (energy, min D). Each cell's
    nodes are read once and its gradient summed over its samples before it goes into ``g`` (read and scattered per
    sample, the loop took 17 ms instead of 13 on 10,000 hexes of kitten_with_bifur_3)."""
    M = conn.shape[0]
    K = G.shape[0]
    n = conn.shape[1]
    X = np.empty((n, 3))
    gl = np.empty((n, 3))
    J = np.empty((3, 3))
    C = np.empty((3, 3))
    dE = np.empty((3, 3))
    total = 0.0
    dmin = np.inf
    e2 = eps * eps
    for m in range(M):
        _gather(V, conn, m, X)
        if want_grad:
            gl[:] = 0.0
        inv = 1.0 / s[m]
        for k in range(K):
            F = 0.0
            for a in range(3):
                for d in range(3):
                    acc = 0.0
                    for i in range(n):
                        acc += X[i, a] * G[k, i, d]
                    J[a, d] = acc * inv
                    F += J[a, d] * J[a, d]
            D = cofactor(J, C)
            if D < dmin:
                dmin = D
            total += _corner_term(J, C, D, F, e2, theta, inv, want_grad, dE)
            if want_grad:
                for i in range(n):
                    for d in range(3):
                        gi = G[k, i, d]
                        gl[i, 0] += dE[0, d] * gi
                        gl[i, 1] += dE[1, d] * gi
                        gl[i, 2] += dE[2, d] * gi
        if want_grad:
            _scatter(g, conn, m, gl)
    return total, dmin


@njit(cache=True, nogil=True)
def untangle_edges(V, conn, head, tail, s, eps, theta, g, want_grad):
    """:func:`untangle_corners` where every sample's G is an edge difference: column d of sample k is
    x[head[k, d]] - x[tail[k, d]] (G[k] has +1 at head, -1 at tail, 0 elsewhere: the hex corners of
    :mod:`hexsos_plugins.meshrepair.optimize`, the unit cube's corners folded in). The same numbers as
    :func:`untangle_corners` with that G, to the bit: its sums of two nonzero terms (products with +-1, exact) are
    this difference, rounded once, and each node's gradient takes the same terms in the same order; the zero terms it
    skips change no sum. The loop reads 4 nodes per sample, not 8: 1.5x the general loop's speed on the published
    meshes (``python -m comparison.bench_repair --corner-loops``)."""
    M = conn.shape[0]
    K = head.shape[0]
    n = conn.shape[1]
    X = np.empty((n, 3))
    gl = np.empty((n, 3))
    J = np.empty((3, 3))
    C = np.empty((3, 3))
    dE = np.empty((3, 3))
    total = 0.0
    dmin = np.inf
    e2 = eps * eps
    for m in range(M):
        _gather(V, conn, m, X)
        if want_grad:
            gl[:] = 0.0
        inv = 1.0 / s[m]
        for k in range(K):
            F = 0.0
            for a in range(3):
                for d in range(3):
                    J[a, d] = (X[head[k, d], a] - X[tail[k, d], a]) * inv
                    F += J[a, d] * J[a, d]
            D = cofactor(J, C)
            if D < dmin:
                dmin = D
            total += _corner_term(J, C, D, F, e2, theta, inv, want_grad, dE)
            if want_grad:
                # each node takes its terms of sample k in the order of d, as in :func:`untangle_corners`
                for d in range(3):
                    hd, tl = head[k, d], tail[k, d]
                    gl[hd, 0] += dE[0, d]
                    gl[hd, 1] += dE[1, d]
                    gl[hd, 2] += dE[2, d]
                    gl[tl, 0] -= dE[0, d]
                    gl[tl, 1] -= dE[1, d]
                    gl[tl, 2] -= dE[2, d]
        if want_grad:
            _scatter(g, conn, m, gl)
    return total, dmin


# VTK node at parameter corner (i, j, k)
_NODE = np.array([[[0, 4], [3, 7]], [[1, 5], [2, 6]]], dtype=np.int64)
_W = np.array([[1.0, 0.0], [0.5, 0.5], [0.0, 1.0]])  # linear interpolation weights at 0, 1/2, 1


@njit(cache=True)
def _hex_grid(V, conn, m, XU, XV, XW, f):
    """det J at {0, 1/2, 1}^3 of hex m (f[9 a + 3 b + c]); XU[b, c] = x_u at (v, w) = (b, c) / 2, etc."""
    eu = np.empty((2, 2, 3))
    ev = np.empty((2, 2, 3))
    ew = np.empty((2, 2, 3))
    _hex_grid_s(V, conn, m, XU, XV, XW, f, eu, ev, ew)


@njit(cache=True, inline="always")
def _hex_grid_s(V, conn, m, XU, XV, XW, f, eu, ev, ew):
    """:func:`_hex_grid` with its scratch arrays passed in."""
    for p in range(2):
        for q in range(2):
            for a in range(3):
                eu[p, q, a] = V[conn[m, _NODE[1, p, q]], a] - V[conn[m, _NODE[0, p, q]], a]
                ev[p, q, a] = V[conn[m, _NODE[p, 1, q]], a] - V[conn[m, _NODE[p, 0, q]], a]
                ew[p, q, a] = V[conn[m, _NODE[p, q, 1]], a] - V[conn[m, _NODE[p, q, 0]], a]
    for b in range(3):
        for c in range(3):
            for a in range(3):
                XU[b, c, a] = 0.0
                XV[b, c, a] = 0.0
                XW[b, c, a] = 0.0
                for p in range(2):
                    for q in range(2):
                        w = _W[b, p] * _W[c, q]
                        if w != 0.0:
                            XU[b, c, a] += w * eu[p, q, a]
                            XV[b, c, a] += w * ev[p, q, a]
                            XW[b, c, a] += w * ew[p, q, a]
    for a in range(3):
        for b in range(3):
            for c in range(3):
                u = XU[b, c]
                v = XV[a, c]
                w = XW[a, b]
                f[9 * a + 3 * b + c] = (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
                                        + u[2] * (v[0] * w[1] - v[1] * w[0]))


@njit(cache=True, inline="always")
def _axis_T(f, stride, off0, forward):
    # the per-axis Bernstein transform (0, 1/2, 1 values -> coefficients) or its transpose, in place
    x0 = f[off0]
    x1 = f[off0 + stride]
    x2 = f[off0 + 2 * stride]
    if forward:
        f[off0 + stride] = 2.0 * x1 - 0.5 * (x0 + x2)
    else:
        f[off0] = x0 - 0.5 * x1
        f[off0 + stride] = 2.0 * x1
        f[off0 + 2 * stride] = x2 - 0.5 * x1


@njit(cache=True)
def _to_bernstein(f, forward):
    for i in range(3):  # the three axes one after the other (each pass over the whole array)
        for j in range(3):
            _axis_T(f, 9, 3 * i + j, forward)  # along a
    for i in range(3):
        for j in range(3):
            _axis_T(f, 3, 9 * i + j, forward)  # along b
    for i in range(3):
        for j in range(3):
            _axis_T(f, 1, 9 * i + 3 * j, forward)  # along c


#: One subdivision of a quadratic Bernstein polynomial on [0, 1] at 1/2: (side, new, old), the coefficients on the
#: left half (side 0) and the right half (side 1) from the polynomial's own (de Casteljau)
_HALF = np.array([[[1.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.25, 0.5, 0.25]],
                  [[0.25, 0.5, 0.25], [0.0, 0.5, 0.5], [0.0, 0.0, 1.0]]])
#: The length of a hex's coefficient scratch with room for its split (:func:`_split`): the 27 coefficients, the
#: 216 of the split, and the two passes between (54, 108)
SPLIT_SCRATCH = 27 + 216 + 54 + 108


@njit(cache=True, inline="always")
def _half(f, src, dst, blocks, stride):
    """One axis of :func:`_split`: each of ``blocks`` blocks of 27 coefficients at f[src:] (index 9 a + 3 b + c; the
    axis is u, v or w for ``stride`` 9, 3 or 1) into its two halves along that axis, block 2 q + side at f[dst:]."""
    for q in range(blocks):
        for side in range(2):
            for x in range(27):
                k = (x // stride) % 3
                base = src + 27 * q + x - k * stride
                acc = 0.0
                for k2 in range(3):
                    w = _HALF[side, k, k2]
                    if w != 0.0:
                        acc += w * f[base + k2 * stride]
                f[dst + 27 * (2 * q + side) + x] = acc


@njit(cache=True, inline="always")
def _half_T(f, src, dst, blocks, stride):
    """The transpose of :func:`_half` (f[src:] its output, f[dst:] its input, added to)."""
    for q in range(blocks):
        for side in range(2):
            for x in range(27):
                k = (x // stride) % 3
                base = dst + 27 * q + x - k * stride
                y = f[src + 27 * (2 * q + side) + x]
                for k2 in range(3):
                    w = _HALF[side, k, k2]
                    if w != 0.0:
                        f[base + k2 * stride] += w * y


@njit(cache=True, inline="always")
def _split(f):
    """One subdivision of the hex's 27 coefficients f[0:27] (index 9 a + 3 b + c) into the 216 of its 8 half-size
    cubes, f[27 + 27 q + 9 a + 3 b + c] for the cube q = 4 i + 2 j + k (the half i along u, j along v, k along w):
    convex combinations of the 27, so positive wherever they all are, and closer to det J. f[243:405] is scratch."""
    _half(f, 0, 243, 1, 9)  # along u: 2 blocks at 243
    _half(f, 243, 297, 2, 3)  # along v: 4 at 297
    _half(f, 297, 27, 4, 1)  # along w: 8 at 27


@njit(cache=True, inline="always")
def _split_T(f):
    """The transpose of :func:`_split`: f[0:27] = its transpose applied to f[27:243] (a gradient with respect to the
    216 coefficients -> with respect to the 27); f[243:405] is scratch."""
    for x in range(243, 405):
        f[x] = 0.0
    for x in range(27):
        f[x] = 0.0
    _half_T(f, 27, 297, 4, 1)
    _half_T(f, 297, 243, 2, 3)
    _half_T(f, 243, 0, 1, 9)


@njit(cache=True, inline="always")
def _positive(f):
    """Whether the hex whose 27 coefficients are f[0:27] (scratch up to :data:`SPLIT_SCRATCH`) passes the
    repair's test of validity: its 27 coefficients all positive, or else the 216 of their split (:func:`_split`)."""
    ok = True
    for p in range(27):
        if not (f[p] > 0.0):
            ok = False
            break
    if ok:
        return True
    _split(f)
    for q in range(27, 243):
        if not (f[q] > 0.0):
            return False
    return True


@njit(cache=True)
def hex_positive(V, conn):
    """Per hex (M,) bool: :func:`_positive` (the repair's test of validity beyond the corners)."""
    B = hex_bernstein(V, conn)
    out = np.empty(B.shape[0], dtype=np.bool_)
    f = np.empty(SPLIT_SCRATCH)
    for m in range(B.shape[0]):
        f[:27] = B[m]
        out[m] = _positive(f)
    return out


@njit(cache=True)
def hex_bernstein_split(V, conn):
    """The 216 Bernstein coefficients of det J of every hex on its 8 half-size cubes (:func:`_split`): (M, 216)."""
    B = hex_bernstein(V, conn)
    out = np.empty((B.shape[0], 216))
    f = np.empty(SPLIT_SCRATCH)
    for m in range(B.shape[0]):
        f[:27] = B[m]
        _split(f)
        out[m] = f[27:243]
    return out


@njit(cache=True)
def hex_bernstein(V, conn):
    """The 27 Bernstein coefficients of det J of every hex: (M, 27)."""
    M = conn.shape[0]
    out = np.empty((M, 27))
    XU = np.empty((3, 3, 3))
    XV = np.empty((3, 3, 3))
    XW = np.empty((3, 3, 3))
    f = np.empty(27)
    for m in range(M):
        _hex_grid(V, conn, m, XU, XV, XW, f)
        _to_bernstein(f, True)
        out[m] = f
    return out


@njit(cache=True)
def untangle_bernstein(V, conn, rows, GB, T, s, eps, theta_b, g, want_grad):
    """Stage 1's barrier on the 27 Bernstein coefficients of the hexes ``rows``: (energy, min b / s^3)."""
    XU = np.empty((3, 3, 3))
    XV = np.empty((3, 3, 3))
    XW = np.empty((3, 3, 3))
    GU = np.empty((3, 3, 3))
    GV = np.empty((3, 3, 3))
    GW = np.empty((3, 3, 3))
    eu = np.empty((2, 2, 3))
    ev = np.empty((2, 2, 3))
    ew = np.empty((2, 2, 3))
    gl = np.empty((8, 3))
    b = np.empty(27)
    db = np.empty(27)
    total = 0.0
    bmin = np.inf
    e2 = eps * eps
    for r in range(rows.shape[0]):  # the scratch arrays allocated once, not per hex (the same numbers)
        m = rows[r]
        _hex_grid_s(V, conn, m, XU, XV, XW, b, eu, ev, ew)
        _to_bernstein(b, True)
        s3 = s[m] ** 3
        for p in range(27):
            bh = b[p] / s3
            if bh < bmin:
                bmin = bh
            chi, dchi = _chi(bh, e2)
            total += theta_b * (bh * bh + 1.0) / chi
            db[p] = theta_b * (2.0 * bh / chi - (bh * bh + 1.0) * dchi / (chi * chi)) / s3
        if want_grad:
            _to_bernstein(db, False)
            gl[:] = 0.0
            _hex_grid_grad_local(gl, XU, XV, XW, db, GU, GV, GW)
            _scatter(g, conn, m, gl)
    return total, bmin


# --- stage 2 over the cells in parallel --------------------------------------------------------------------
# Each cell writes its energy, its minimum and its vertex gradient (n, 3) to its own rows; the sums and the scatter
# run after, in cell order, so the result does not depend on the number of threads. The logarithms of a cell's
# 9 gaps and of its 27 coefficients are taken of their products (one log per 1e+-150 of range): 36 logarithms
# per hex were most of the time of a loop with one log each.

_BIG = 1e150
_SMALL = 1e-150


@njit(cache=True, inline="always")
def _hex_grid_grad_local(gl, XU, XV, XW, df, GU, GV, GW):
    """The gradient of sum_q df[q] f_q (f the grid values of :func:`_hex_grid`) added into the cell's own (8, 3)
    rows gl (GU, GV, GW scratch (3, 3, 3))."""
    GU[:] = 0.0
    GV[:] = 0.0
    GW[:] = 0.0
    for a in range(3):
        for b in range(3):
            for c in range(3):
                d = df[9 * a + 3 * b + c]
                u = XU[b, c]
                v = XV[a, c]
                w = XW[a, b]
                GU[b, c, 0] += d * (v[1] * w[2] - v[2] * w[1])
                GU[b, c, 1] += d * (v[2] * w[0] - v[0] * w[2])
                GU[b, c, 2] += d * (v[0] * w[1] - v[1] * w[0])
                GV[a, c, 0] += d * (w[1] * u[2] - w[2] * u[1])
                GV[a, c, 1] += d * (w[2] * u[0] - w[0] * u[2])
                GV[a, c, 2] += d * (w[0] * u[1] - w[1] * u[0])
                GW[a, b, 0] += d * (u[1] * v[2] - u[2] * v[1])
                GW[a, b, 1] += d * (u[2] * v[0] - u[0] * v[2])
                GW[a, b, 2] += d * (u[0] * v[1] - u[1] * v[0])
    for p in range(2):
        for q in range(2):
            for a in range(3):
                su = 0.0
                sv = 0.0
                sw = 0.0
                for b in range(3):
                    for c in range(3):
                        w = _W[b, p] * _W[c, q]
                        if w != 0.0:
                            su += w * GU[b, c, a]
                            sv += w * GV[b, c, a]
                            sw += w * GW[b, c, a]
                gl[_NODE[1, p, q], a] += su
                gl[_NODE[0, p, q], a] -= su
                gl[_NODE[p, 1, q], a] += sv
                gl[_NODE[p, 0, q], a] -= sv
                gl[_NODE[p, q, 1], a] += sw
                gl[_NODE[p, q, 0], a] -= sw


#: Stage 2's loop on a region of this many cells and more runs in BARRIER_PARTS parts of consecutive cells on the
#: kernel's threads (``repair(..., jobs=)``; Python threads of :mod:`hexsos_plugins.kernel.pool`, the loop releases
#: the GIL); each cell writes its own rows, so the numbers are those of one thread. warrior_graded's rounds call it
#: 1,700 times on regions of 6,000-12,000 hexes (7.7-12 ms a call in one thread, 16 s of its 22 s of rounds). Not
#: numba's OpenMP loop: with the machine's 2 cores busy its workers cost 59 ms a call on 1,728 hexes against 3 ms in
#: one thread (rockarm's quality stage took 205 s instead of 15 s)
BARRIER_PARTS_MIN_CELLS = 4096
BARRIER_PARTS = 4


def barrier_cells(V, conn, G, factor, t, s, beta, hexes, want_grad, ecell, mcell, okc, gcell, split):
    """Stage 2's terms per cell: ecell (M,) energy, mcell (M,) min SJ, okc (M,) feasible,
    gcell (M, n, 3) the cell's vertex gradient (when ``want_grad``); ``split`` (M,) bool: the hexes whose barrier is
    on the 216 coefficients of their split (:func:`_split`, weight ``beta`` / 8) instead of their 27 (a coefficient
    near 0 is often the bound's slack, not det J's: kitten_with_bifur_3's rounds stopped beside a hex whose least
    coefficient was 6e-6 of its largest). Returns whether every cell is feasible; when
    not, the rows are incomplete (the work stops at the first infeasible cell of a part). On the kernel's threads
    in parts for :data:`BARRIER_PARTS_MIN_CELLS` cells and more."""
    from ..kernel.pool import run_all, threads

    M = conn.shape[0]
    stop = np.zeros(1, dtype=np.int64)  # set by the first infeasible cell: every part stops at its next cell
    if M < BARRIER_PARTS_MIN_CELLS or threads() <= 1:
        return _barrier_serial(V, conn, G, factor, t, s, beta, hexes, want_grad, ecell, mcell, okc, gcell, split,
                               stop)
    cuts = np.linspace(0, M, BARRIER_PARTS + 1).astype(np.int64)
    return all(run_all([partial(_barrier_serial, V, conn[lo:hi], G, factor, t, s[lo:hi], beta, hexes, want_grad,
                                ecell[lo:hi], mcell[lo:hi], okc[lo:hi], gcell[lo:hi], split[lo:hi], stop)
                        for lo, hi in zip(cuts[:-1], cuts[1:])]))


@njit(cache=True)
def _sample_nonzeros(G, n):
    """The samples' nonzero entries (a hex corner's column has 2 of 8, the centre's 8): nz[k, d] of them, vertex
    gi[k, d, j] with weight gv[k, d, j]."""
    K = G.shape[0]
    nz = np.zeros((K, 3), dtype=np.int64)
    gi = np.zeros((K, 3, n), dtype=np.int64)
    gv = np.zeros((K, 3, n))
    for k in range(K):
        for d in range(3):
            for i in range(n):
                if G[k, i, d] != 0.0:
                    gi[k, d, nz[k, d]] = i
                    gv[k, d, nz[k, d]] = G[k, i, d]
                    nz[k, d] += 1
    return nz, gi, gv


@njit(cache=True, nogil=True)
def _barrier_serial(V, conn, G, factor, t, s, beta, hexes, want_grad, ecell, mcell, okc, gcell, split, stop):
    nz, gi, gv = _sample_nonzeros(G, conn.shape[1])
    return _barrier_chunk(V, conn, nz, gi, gv, factor, t, s, beta, hexes, want_grad, ecell, mcell, okc, gcell, split,
                          stop)


@njit(cache=True)
def _barrier_chunk(V, conn, nz, gi, gv, factor, t, s, beta, hexes, want_grad, ecell, mcell, okc, gcell, split,
                   stop):
    """The cells of one part of :func:`barrier_cells` (its scratch arrays allocated once per part); stops at the
    first infeasible cell, its own (setting ``stop[0]``) or another part's (``stop[0]`` set)."""
    K = nz.shape[0]
    n = conn.shape[1]
    X = np.empty((n, 3))
    E = np.empty((3, 3))
    C = np.empty((3, 3))
    dE = np.empty((3, 3))
    gl = np.empty((n, 3))
    XU = np.empty((3, 3, 3))
    XV = np.empty((3, 3, 3))
    XW = np.empty((3, 3, 3))
    GU = np.empty((3, 3, 3))
    GV = np.empty((3, 3, 3))
    GW = np.empty((3, 3, 3))
    eu = np.empty((2, 2, 3))
    ev = np.empty((2, 2, 3))
    ew = np.empty((2, 2, 3))
    b = np.empty(SPLIT_SCRATCH)
    db = np.empty(SPLIT_SCRATCH)
    for m in range(conn.shape[0]):
        if stop[0] != 0:
            return False
        gl[:] = 0.0
        _gather(V, conn, m, X)
        total = 0.0
        smin = np.inf
        ok = True
        prod = 1.0
        for k in range(K):
            for d in range(3):
                a0 = 0.0
                a1 = 0.0
                a2 = 0.0
                for j in range(nz[k, d]):
                    i = gi[k, d, j]
                    w = gv[k, d, j]
                    a0 += X[i, 0] * w
                    a1 += X[i, 1] * w
                    a2 += X[i, 2] * w
                E[0, d] = a0
                E[1, d] = a1
                E[2, d] = a2
            c0 = E[0, 0] * E[0, 0] + E[1, 0] * E[1, 0] + E[2, 0] * E[2, 0]
            c1 = E[0, 1] * E[0, 1] + E[1, 1] * E[1, 1] + E[2, 1] * E[2, 1]
            c2 = E[0, 2] * E[0, 2] + E[1, 2] * E[1, 2] + E[2, 2] * E[2, 2]
            L = np.sqrt(c0) * np.sqrt(c1) * np.sqrt(c2)
            if not (L > 0.0):
                ok = False
                smin = -np.inf
                break
            D = cofactor(E, C)
            sj = factor * D / L
            if sj < smin:
                smin = sj
            gap = sj - t
            if not (gap > 0.0):
                ok = False
                break
            prod *= gap
            if prod < _SMALL or prod > _BIG:
                total -= np.log(prod)
                prod = 1.0
            if want_grad:
                w = -1.0 / gap
                for a in range(3):
                    dE[a, 0] = w * (factor / L * C[a, 0] - sj * E[a, 0] / c0)
                    dE[a, 1] = w * (factor / L * C[a, 1] - sj * E[a, 1] / c1)
                    dE[a, 2] = w * (factor / L * C[a, 2] - sj * E[a, 2] / c2)
                for d in range(3):
                    for j in range(nz[k, d]):
                        i = gi[k, d, j]
                        wv = gv[k, d, j]
                        gl[i, 0] += dE[0, d] * wv
                        gl[i, 1] += dE[1, d] * wv
                        gl[i, 2] += dE[2, d] * wv
        if ok:
            total -= np.log(prod)
        if ok and hexes:
            _hex_grid_s(V, conn, m, XU, XV, XW, b, eu, ev, ew)
            _to_bernstein(b, True)
            inv3 = 1.0 / (s[m] ** 3)
            prod = 1.0
            lsum = 0.0
            first, last, wb = 0, 27, beta
            if split[m]:
                _split(b)
                first, last, wb = 27, 243, beta / 8.0
            for p in range(first, last):
                if not (b[p] > 0.0):
                    ok = False
                    break
                prod *= b[p] * inv3
                if prod < _SMALL or prod > _BIG:
                    lsum += np.log(prod)
                    prod = 1.0
                db[p] = -wb / b[p]
            if ok:
                total -= wb * (lsum + np.log(prod))
                if want_grad:
                    if split[m]:
                        _split_T(db)
                    _to_bernstein(db, False)
                    _hex_grid_grad_local(gl, XU, XV, XW, db, GU, GV, GW)
        ecell[m] = total
        mcell[m] = smin
        okc[m] = ok
        if not ok:
            stop[0] = 1
            return False
        if want_grad:
            for i in range(n):
                for a in range(3):
                    gcell[m, i, a] = gl[i, a]
    return True


@njit(cache=True)
def hex_edge_term(V, conn, s, gamma, g):
    """Stage 2's edge term of hexes ``conn`` (M, 8) at V: ``gamma sum phi(r)`` over their edges shorter than the
    hex's size s (r = edge length / s, ``phi(r) = (r^-2 + r^2) / 2 - 1``, 0 from r = 1 on, continuously
    differentiable), its gradient added to g (N, 3). Returns the term (inf when an edge has length 0)."""
    total = 0.0
    for m in range(conn.shape[0]):
        inv2 = 1.0 / (s[m] * s[m])
        for q in range(12):
            a = conn[m, EDGES[q, 0]]
            b = conn[m, EDGES[q, 1]]
            d0 = V[a, 0] - V[b, 0]
            d1 = V[a, 1] - V[b, 1]
            d2 = V[a, 2] - V[b, 2]
            r2 = (d0 * d0 + d1 * d1 + d2 * d2) * inv2
            if not (r2 > 0.0):
                return np.inf
            if r2 >= 1.0:
                continue
            total += gamma * (0.5 * (1.0 / r2 + r2) - 1.0)
            w = gamma * (1.0 - 1.0 / (r2 * r2)) * inv2  # gamma phi'(r2) d(r2)/d(x_a) = gamma phi'(r2) 2 d / s^2
            g[a, 0] += w * d0
            g[a, 1] += w * d1
            g[a, 2] += w * d2
            g[b, 0] -= w * d0
            g[b, 1] -= w * d1
            g[b, 2] -= w * d2
    return total


@njit(cache=True)
def scatter_cells(g, conn, gcell):
    """g[conn[m, i]] += gcell[m, i] in cell order."""
    for m in range(conn.shape[0]):
        _scatter(g, conn, m, gcell[m])


# --- the vertex steps of :mod:`hexsos_plugins.meshrepair.localopt` ----------------------------------------------
# Each step moves one vertex to raise the least measure of the hexes around it (their least scaled Jacobian sample,
# or their least Bernstein coefficient of det J): the direction is the gradient of a soft minimum of those hexes'
# samples (weights exp(-(x - min) / tau)) restricted to the vertex's freedom (all of space inside, its input
# tangent plane on the surface, its feature's tangent on a feature curve); the step is halved until the soft
# minimum falls and no hex around goes below what the sweep allows. Serial, IEEE double precision, no fast-math.


@njit(cache=True, inline="always")
def _cell_eval(V, conn, m, G, factor, ref, tau, out, E, C, XU, XV, XW, b, eu, ev, ew):
    """Hex m: out[0] its least scaled Jacobian sample (-inf when it fails :func:`_positive`: a Bernstein coefficient
    of det J <= 0, also after one subdivision), out[1] the sum over its samples of exp(-(sj - ref) / tau). ``b``
    has room for the split (:data:`SPLIT_SCRATCH`)."""
    K = G.shape[0]
    smin = np.inf
    soft = 0.0
    for k in range(K):
        for a in range(3):
            for d in range(3):
                acc = 0.0
                for i in range(8):
                    gi = G[k, i, d]
                    if gi != 0.0:
                        acc += V[conn[m, i], a] * gi
                E[a, d] = acc
        c0 = E[0, 0] * E[0, 0] + E[1, 0] * E[1, 0] + E[2, 0] * E[2, 0]
        c1 = E[0, 1] * E[0, 1] + E[1, 1] * E[1, 1] + E[2, 1] * E[2, 1]
        c2 = E[0, 2] * E[0, 2] + E[1, 2] * E[1, 2] + E[2, 2] * E[2, 2]
        L = np.sqrt(c0) * np.sqrt(c1) * np.sqrt(c2)
        if not (L > 0.0):
            out[0] = -np.inf
            out[1] = np.inf
            return
        sj = factor * cofactor(E, C) / L
        if sj < smin:
            smin = sj
        soft += np.exp(-(sj - ref) / tau)
    _hex_grid_s(V, conn, m, XU, XV, XW, b, eu, ev, ew)
    _to_bernstein(b, True)
    if not _positive(b):
        out[0] = -np.inf
        out[1] = np.inf
        return
    out[0] = smin
    out[1] = soft


@njit(cache=True, inline="always")
def _edge_ratio2(V, conn, m):
    """Hex m's shortest edge over its longest, squared (0 when its longest has length 0)."""
    lo = np.inf
    hi = 0.0
    for q in range(12):
        a = conn[m, EDGES[q, 0]]
        b = conn[m, EDGES[q, 1]]
        d0 = V[a, 0] - V[b, 0]
        d1 = V[a, 1] - V[b, 1]
        d2 = V[a, 2] - V[b, 2]
        l2 = d0 * d0 + d1 * d1 + d2 * d2
        if l2 < lo:
            lo = l2
        if l2 > hi:
            hi = l2
    if not (hi > 0.0):
        return 0.0
    return lo / hi


@njit(cache=True)
def edge_ratios2(V, conn, out):
    """Each hex's shortest edge over its longest, squared, into ``out`` (M,)."""
    for m in range(conn.shape[0]):
        out[m] = _edge_ratio2(V, conn, m)


@njit(cache=True)
def edge_ratios_above(V, conn, floor2):
    """True when every hex m of ``conn`` has its shortest edge over its longest, squared, at least ``floor2[m]``."""
    for m in range(conn.shape[0]):
        if _edge_ratio2(V, conn, m) < floor2[m]:
            return False
    return True


@njit(cache=True)
def sweep(V, conn, G, factor, order, ptr, inc, loc, proj, step0, tau, max_steps, cell_sj, ref, A, width,
          ratio_floor):
    """One pass over the vertices ``order``: each moves by up to ``max_steps`` accepted steps (see the module
    docstring). ``ptr``/``inc``/``loc``: the hexes around each vertex (CSR) and the vertex's node index in each;
    ``proj`` (N, 3, 3) the projector onto each vertex's freedom; ``step0`` (N,) the first trial length (a fraction
    of the vertex's edge length); ``cell_sj`` (M,) the hexes' least samples, kept up to date. The band: a vertex
    with ``width[v]`` finite stays in {x : |A[v] (x - ref[v])| <= width[v]} (``A[v]`` an orthogonal projector:
    onto the normal of a surface vertex, across a curve's tangent, the identity at a corner): a trial position
    outside goes to the nearest point inside, and on the band's edge the part of a step leaving it goes. V is
    updated in place. ``ratio_floor``: no accepted step takes a hex's shortest edge over its longest below the
    lesser of its own and this (the scaled Jacobian does not see an edge's length: without it the steps collapsed
    edges to 1e-5 of their hex's longest). Returns the number of accepted steps."""
    K = G.shape[0]
    valence = 0
    for v in range(ptr.shape[0] - 1):
        if ptr[v + 1] - ptr[v] > valence:
            valence = ptr[v + 1] - ptr[v]
    floor2 = np.empty(valence)
    rf2 = ratio_floor * ratio_floor
    E = np.empty((3, 3))
    C = np.empty((3, 3))
    XU = np.empty((3, 3, 3))
    XV = np.empty((3, 3, 3))
    XW = np.empty((3, 3, 3))
    b = np.empty(SPLIT_SCRATCH)
    eu = np.empty((2, 2, 3))
    ev = np.empty((2, 2, 3))
    ew = np.empty((2, 2, 3))
    g = np.empty(3)
    x0 = np.empty(3)
    c = np.empty(3)
    ev2 = np.empty(2)
    r = np.empty(3)
    accepted = 0
    for oi in range(order.shape[0]):
        v = order[oi]
        lo, hi = ptr[v], ptr[v + 1]
        if hi == lo:
            continue
        for _ in range(max_steps):
            m0 = np.inf
            for j in range(lo, hi):
                if cell_sj[inc[j]] < m0:
                    m0 = cell_sj[inc[j]]
            if not (m0 > -np.inf):
                break
            # the soft minimum's gradient at v over every sample of the hexes around it
            g[0] = 0.0
            g[1] = 0.0
            g[2] = 0.0
            for j in range(lo, hi):
                m = inc[j]
                li = loc[j]
                for k in range(K):
                    for a in range(3):
                        for d in range(3):
                            acc = 0.0
                            for i in range(8):
                                gi = G[k, i, d]
                                if gi != 0.0:
                                    acc += V[conn[m, i], a] * gi
                            E[a, d] = acc
                    for d in range(3):
                        c[d] = E[0, d] * E[0, d] + E[1, d] * E[1, d] + E[2, d] * E[2, d]
                    L = np.sqrt(c[0]) * np.sqrt(c[1]) * np.sqrt(c[2])
                    D = cofactor(E, C)
                    sj = factor * D / L
                    w = np.exp(-(sj - m0) / tau)
                    if w < 1e-12:
                        continue
                    for a in range(3):
                        acc = 0.0
                        for d in range(3):
                            gi = G[k, li, d]
                            if gi != 0.0:
                                acc += (factor / L * C[a, d] - sj * E[a, d] / c[d]) * gi
                        g[a] += w * acc
            # restricted to the vertex's freedom
            d0 = proj[v, 0, 0] * g[0] + proj[v, 0, 1] * g[1] + proj[v, 0, 2] * g[2]
            d1 = proj[v, 1, 0] * g[0] + proj[v, 1, 1] * g[1] + proj[v, 1, 2] * g[2]
            d2 = proj[v, 2, 0] * g[0] + proj[v, 2, 1] * g[1] + proj[v, 2, 2] * g[2]
            banded = width[v] < np.inf
            if banded:
                for a in range(3):
                    r[a] = (A[v, a, 0] * (V[v, 0] - ref[v, 0]) + A[v, a, 1] * (V[v, 1] - ref[v, 1])
                            + A[v, a, 2] * (V[v, 2] - ref[v, 2]))
                rn = np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
                if rn > 0.0 and rn >= width[v] * (1.0 - 1e-9):
                    out = (d0 * r[0] + d1 * r[1] + d2 * r[2]) / rn
                    if out > 0.0:
                        d0 -= out * r[0] / rn
                        d1 -= out * r[1] / rn
                        d2 -= out * r[2] / rn
            nrm = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if not (nrm > 0.0):
                break
            x0[0] = V[v, 0]
            x0[1] = V[v, 1]
            x0[2] = V[v, 2]
            s0 = 0.0
            for j in range(lo, hi):
                _cell_eval(V, conn, inc[j], G, factor, m0, tau, ev2, E, C, XU, XV, XW, b, eu, ev, ew)
                s0 += ev2[1]
                floor2[j - lo] = min(_edge_ratio2(V, conn, inc[j]), rf2) if rf2 > 0.0 else -1.0
            h = step0[v] / nrm
            ok = False
            for _t in range(12):
                V[v, 0] = x0[0] + h * d0
                V[v, 1] = x0[1] + h * d1
                V[v, 2] = x0[2] + h * d2
                if banded:
                    for a in range(3):
                        r[a] = (A[v, a, 0] * (V[v, 0] - ref[v, 0]) + A[v, a, 1] * (V[v, 1] - ref[v, 1])
                                + A[v, a, 2] * (V[v, 2] - ref[v, 2]))
                    rn = np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
                    if rn > width[v]:
                        f = 1.0 - width[v] / rn
                        V[v, 0] -= f * r[0]
                        V[v, 1] -= f * r[1]
                        V[v, 2] -= f * r[2]
                m1 = np.inf
                s1 = 0.0
                for j in range(lo, hi):
                    _cell_eval(V, conn, inc[j], G, factor, m0, tau, ev2, E, C, XU, XV, XW, b, eu, ev, ew)
                    s1 += ev2[1]
                    if ev2[0] < m1:
                        m1 = ev2[0]
                    if not (m1 >= m0):
                        break
                    if rf2 > 0.0 and _edge_ratio2(V, conn, inc[j]) < floor2[j - lo]:
                        m1 = -np.inf
                        break
                if m1 >= m0 and s1 < s0:
                    ok = True
                    break
                h *= 0.5
            if not ok:
                V[v, 0] = x0[0]
                V[v, 1] = x0[1]
                V[v, 2] = x0[2]
                break
            for j in range(lo, hi):
                _cell_eval(V, conn, inc[j], G, factor, m0, tau, ev2, E, C, XU, XV, XW, b, eu, ev, ew)
                cell_sj[inc[j]] = ev2[0]
            accepted += 1
    return accepted


@njit(cache=True)
def cell_minima(V, conn, G, factor):
    """Least scaled Jacobian sample of every hex (-inf where it fails :func:`_positive`)."""
    M = conn.shape[0]
    out = np.empty(M)
    E = np.empty((3, 3))
    C = np.empty((3, 3))
    XU = np.empty((3, 3, 3))
    XV = np.empty((3, 3, 3))
    XW = np.empty((3, 3, 3))
    b = np.empty(SPLIT_SCRATCH)
    eu = np.empty((2, 2, 3))
    ev = np.empty((2, 2, 3))
    ew = np.empty((2, 2, 3))
    ev2 = np.empty(2)
    for m in range(M):
        _cell_eval(V, conn, m, G, factor, 0.0, 1.0, ev2, E, C, XU, XV, XW, b, eu, ev, ew)
        out[m] = ev2[0]
    return out


def hex_minima(V, H):
    """:func:`cell_minima` of hexes H with the hexahedron's samples of :data:`hexsos_plugins.cells.quality.SAMPLES`
    (the corners' scaled Jacobians, Verdict's)."""
    G, factor = SAMPLES["hexahedron"]
    return cell_minima(V, H, np.ascontiguousarray(G), float(factor))


@njit(cache=True, inline="always")
def _cell_eval_b(V, conn, m, inv3, ref, tau, out, XU, XV, XW, b, eu, ev, ew):
    """Hex m: out[0] its least Bernstein coefficient of det J in units of s^3, out[1] the sum over the 27 of
    exp(-(b - ref) / tau). XU, XV, XW, b are left holding the hex's grid (for the gradient)."""
    _hex_grid_s(V, conn, m, XU, XV, XW, b, eu, ev, ew)
    _to_bernstein(b, True)
    bmin = np.inf
    soft = 0.0
    for p in range(27):
        x = b[p] * inv3
        if x < bmin:
            bmin = x
        soft += np.exp(-(x - ref) / tau)
    out[0] = bmin
    out[1] = soft


@njit(cache=True)
def bernstein_minima(V, conn, inv3):
    """Least Bernstein coefficient of det J of every hex, in units of its s^3 (inv3 = 1 / s^3)."""
    M = conn.shape[0]
    out = np.empty(M)
    XU = np.empty((3, 3, 3))
    XV = np.empty((3, 3, 3))
    XW = np.empty((3, 3, 3))
    b = np.empty(27)
    eu = np.empty((2, 2, 3))
    ev = np.empty((2, 2, 3))
    ew = np.empty((2, 2, 3))
    ev2 = np.empty(2)
    for m in range(M):
        _cell_eval_b(V, conn, m, inv3[m], 0.0, 1.0, ev2, XU, XV, XW, b, eu, ev, ew)
        out[m] = ev2[0]
    return out


@njit(cache=True)
def sweep_bernstein(V, conn, inv3, order, ptr, inc, loc, proj, step0, tau, max_steps, cell_q, floor):
    """:func:`sweep` with the least Bernstein coefficient of det J (in units of s^3) as each hex's measure:
    moves that lower the soft minimum of the coefficients of the hexes around a vertex, lower no hex's least
    coefficient below min(its own, ``floor``) and so the least of them not at all: a hex whose coefficients are
    above ``floor`` > 0 keeps them positive (a fold inside untangled without making others)."""
    XU = np.empty((3, 3, 3))
    XV = np.empty((3, 3, 3))
    XW = np.empty((3, 3, 3))
    GU = np.empty((3, 3, 3))
    GV = np.empty((3, 3, 3))
    GW = np.empty((3, 3, 3))
    b = np.empty(27)
    db = np.empty(27)
    eu = np.empty((2, 2, 3))
    ev = np.empty((2, 2, 3))
    ew = np.empty((2, 2, 3))
    gl = np.empty((8, 3))
    g = np.empty(3)
    x0 = np.empty(3)
    ev2 = np.empty(2)
    accepted = 0
    for oi in range(order.shape[0]):
        v = order[oi]
        lo, hi = ptr[v], ptr[v + 1]
        if hi == lo:
            continue
        for _ in range(max_steps):
            m0 = np.inf
            for j in range(lo, hi):
                if cell_q[inc[j]] < m0:
                    m0 = cell_q[inc[j]]
            g[0] = 0.0
            g[1] = 0.0
            g[2] = 0.0
            s0 = 0.0
            for j in range(lo, hi):
                m = inc[j]
                _cell_eval_b(V, conn, m, inv3[m], m0, tau, ev2, XU, XV, XW, b, eu, ev, ew)
                s0 += ev2[1]
                for p in range(27):
                    db[p] = np.exp(-(b[p] * inv3[m] - m0) / tau) * inv3[m] / tau
                _to_bernstein(db, False)
                gl[:] = 0.0
                _hex_grid_grad_local(gl, XU, XV, XW, db, GU, GV, GW)
                g[0] += gl[loc[j], 0]
                g[1] += gl[loc[j], 1]
                g[2] += gl[loc[j], 2]
            d0 = proj[v, 0, 0] * g[0] + proj[v, 0, 1] * g[1] + proj[v, 0, 2] * g[2]
            d1 = proj[v, 1, 0] * g[0] + proj[v, 1, 1] * g[1] + proj[v, 1, 2] * g[2]
            d2 = proj[v, 2, 0] * g[0] + proj[v, 2, 1] * g[1] + proj[v, 2, 2] * g[2]
            nrm = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if not (nrm > 0.0) or not np.isfinite(nrm):
                break
            x0[0] = V[v, 0]
            x0[1] = V[v, 1]
            x0[2] = V[v, 2]
            h = step0[v] / nrm
            ok = False
            for _t in range(12):
                V[v, 0] = x0[0] + h * d0
                V[v, 1] = x0[1] + h * d1
                V[v, 2] = x0[2] + h * d2
                m1 = np.inf
                s1 = 0.0
                keep = True
                for j in range(lo, hi):
                    m = inc[j]
                    _cell_eval_b(V, conn, m, inv3[m], m0, tau, ev2, XU, XV, XW, b, eu, ev, ew)
                    s1 += ev2[1]
                    if ev2[0] < m1:
                        m1 = ev2[0]
                    # no hex around goes below min(its own, floor): one above the floor stays above it
                    if not (m1 >= m0) or not (ev2[0] >= min(cell_q[m], floor)):
                        keep = False
                        break
                if keep and s1 < s0:
                    ok = True
                    break
                h *= 0.5
            if not ok:
                V[v, 0] = x0[0]
                V[v, 1] = x0[1]
                V[v, 2] = x0[2]
                break
            for j in range(lo, hi):
                m = inc[j]
                _cell_eval_b(V, conn, m, inv3[m], m0, tau, ev2, XU, XV, XW, b, eu, ev, ew)
                cell_q[m] = ev2[0]
            accepted += 1
    return accepted


_F1, _F2, _F3 = types.float64[::1], types.float64[:, ::1], types.float64[:, :, ::1]
_I1, _I2 = types.int64[::1], types.int64[:, ::1]
_f8, _i8, _b1 = types.float64, types.int64, types.boolean

#: The argument types the repair calls each loop with (C-contiguous float64 / int64 arrays, writable: the driver
#: copies the caller's connectivity, so that a read-only one is not a second type); a call with other types still
#: works, compiled at that call (the parts of :func:`barrier_cells` and of stage 1's large blocks are slices of
#: these arrays: the same types).
SIGNATURES = {
    "untangle_corners": (_F2, _I2, _F3, _F1, _f8, _f8, _F2, _b1),
    "untangle_edges": (_F2, _I2, _I2, _I2, _F1, _f8, _f8, _F2, _b1),
    "untangle_bernstein": (_F2, _I2, _I1, types.float64[:, :, :], _F2, _F1, _f8, _f8, _F2, _b1),
    "_barrier_serial": (_F2, _I2, _F3, _f8, _f8, _F1, _f8, _b1, _b1, _F1, _F1, types.boolean[::1], _F3,
                        types.boolean[::1], _I1),
    "hex_bernstein": (_F2, _I2),
    "hex_positive": (_F2, _I2),
    "hex_edge_term": (_F2, _I2, _F1, _f8, _F2),
    "scatter_cells": (_F2, _I2, _F3),
    "edge_ratios2": (_F2, _I2, _F1),
    "edge_ratios_above": (_F2, _I2, _F1),
    "cell_minima": (_F2, _I2, _F3, _f8),
    "bernstein_minima": (_F2, _I2, _F1),
    "sweep": (_F2, _I2, _F3, _f8, _I1, _I1, _I1, _I1, _F3, _F1, _f8, _i8, _F1, _F2, _F3, _F1, _f8),
    "sweep_bernstein": (_F2, _I2, _F1, _I1, _I1, _I1, _I1, _F3, _F1, _f8, _i8, _F1, _f8),
}


def _dispatchers():
    return [(globals()[name], sig) for name, sig in SIGNATURES.items()]


def any_uncached(loops) -> bool:
    """Whether some of ``loops`` ((numba dispatcher, argument types) pairs) has nothing in numba's cache for its
    current source yet (only the cache's index is read: asking compiles nothing)."""
    from ..kernel.compiled import jit_cached

    return any(jit_cached(fn) is False for fn, _ in loops)


def compile_each(loops) -> None:
    """Compile, or load from numba's cache, each of ``loops`` ((dispatcher, argument types) pairs)."""
    for fn, sig in loops:
        fn.compile(sig)


def compiles_at_first_use() -> bool:
    """Whether some loop of :data:`SIGNATURES` has nothing in numba's cache for this source yet: :func:`load`
    (the first repair) compiles it (47 s for all of them on 2 cores, once)."""
    return any_uncached(_dispatchers())


def load() -> None:
    """Compile, or load from numba's cache, every loop of :data:`SIGNATURES` (a few milliseconds once cached)."""
    compile_each(_dispatchers())
