"""The compiled kernel's source: numba functions only (math, numpy, numba, and the products generated from the
tables in :mod:`hexsos_plugins.kernel.generated`; nothing else of hexsos).

Compiled ahead of time into the extension ``hexsos_plugins.kernel.aot`` when the package is installed
(:mod:`hexsos_plugins.generate.extension`, numba's ``pycc``), or just in time with numba's cache where that extension
is absent or stale. :mod:`hexsos_plugins.kernel` documents what it computes and holds the Python interface.
No fastmath anywhere: every bound assumes IEEE-754 round-to-nearest per operation (a fused multiply-add only
removes a rounding; reassociation would break the bounds). The per-cell coefficient functions are inlined into
the chunk loops (``inline="always"``): a call with many array arguments costs a reference-count increment and
decrement per array, which measured 12% of a valid mesh's check.
"""

import math

import numpy as np
from numba import njit

from .generated import columns as _generated_columns
from .generated import has_columns as _has_generated_columns
from .generated import products as _generated_products
from .generated import products_only as _generated_products_only
from .generated import scaled_jacobian_loop as _generated_sj

U = 2.0**-53  # unit roundoff
ETA = 2.0**-1074  # smallest subnormal: bounds the error of any rounding in the subnormal range
_NO_EXTENT = -100000  # scaling exponent of a cell whose nodes all coincide
SIMPLEX_ITER = 4  # a tetrahedron's bisections per split of the budget max_iter (an 8-way split is 7 bisections)

# --- coefficients ----------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True, inline="always")
def _scaled_differences(points, conn, m, n, D):
    """D[i] = (X_i - X_0) * 2^-k for the nodes of cell m; returns k (the cell's extent * 2^-k is in [1, 2)),
    or _NO_EXTENT for a cell whose nodes all coincide (then D = 0)."""
    ext = 0.0
    for a in range(3):  # the coordinates gathered once, into D
        lo = points[conn[m, 0], a]
        hi = lo
        D[0, a] = lo
        for i in range(1, n):
            v = points[conn[m, i], a]
            D[i, a] = v
            if v < lo:
                lo = v
            if v > hi:
                hi = v
        half = 0.5 * hi - 0.5 * lo  # cannot overflow
        if half > ext:
            ext = half
    if ext == 0.0:
        for i in range(n):
            for a in range(3):
                D[i, a] = 0.0
        return _NO_EXTENT
    k = math.frexp(ext)[1]  # ext = f 2^k with f in [0.5, 1)
    # multiply by 2^-k: exact unless the product is subnormal (then within eta / 2). 2^-k is a float for
    # k >= -1023; for smaller k (subnormal coordinates) in two exact steps (|x| 2^-k stays below 2^55)
    if k >= -1023:
        f1 = math.ldexp(1.0, -k)
        f2 = 1.0
    else:
        f1 = math.ldexp(1.0, 600)
        f2 = math.ldexp(1.0, -k - 600)
    for a in range(3):
        s0 = D[0, a] * f1 * f2
        D[0, a] = 0.0
        for i in range(1, n):
            D[i, a] = D[i, a] * f1 * f2 - s0
    return k


#: The scaled Jacobian scales a cell whose longest vector is outside [SJ_LOW, SJ_HIGH] (2**-250, 2**250): inside, no
#: product of three of its components or of its edge lengths comes near the ends of the doubles
SJ_LOW = 2.0 ** -250
SJ_HIGH = 2.0 ** 250


@njit(cache=True, nogil=True, inline="always")
def _perm(A):
    """The permanent of a non-negative 3 x 3 matrix."""
    return (A[0, 0] * (A[1, 1] * A[2, 2] + A[1, 2] * A[2, 1]) + A[0, 1] * (A[1, 0] * A[2, 2] + A[1, 2] * A[2, 0])
            + A[0, 2] * (A[1, 0] * A[2, 1] + A[1, 1] * A[2, 0]))


@njit(cache=True, nogil=True, inline="always")
def _perm_growth(A, E):
    """An upper bound of perm(A + E) - perm(A) for A, E >= 0: sum over entries of E times the permanent of
    the complementary 2 x 2 minor of A + E (perm is multilinear in the rows and monotone)."""
    s = 0.0
    for r in range(3):
        r1, r2 = (r + 1) % 3, (r + 2) % 3
        for c in range(3):
            c1, c2 = (c + 1) % 3, (c + 2) % 3
            s += E[r, c] * ((A[r1, c1] + E[r1, c1]) * (A[r2, c2] + E[r2, c2])
                            + (A[r1, c2] + E[r1, c2]) * (A[r2, c1] + E[r2, c1]))
    return s


@njit(cache=True, nogil=True)
def _table_products(col, X, b, col_off, xp, xi, xj, xw, dp, di, dj, dw):
    """X = column 1 x column 2 and b = column 0 . X by loops over the product tables (sorted by output
    coefficient, xp / dp their row pointers)."""
    o1 = col_off[1]
    o2 = col_off[2]
    for g in range(X.shape[0]):
        s0 = s1 = s2 = 0.0
        for q in range(xp[g], xp[g + 1]):
            a = o1 + xi[q]
            bb = o2 + xj[q]
            w = xw[q]
            a0, a1, a2 = col[a, 0], col[a, 1], col[a, 2]
            b0, b1, b2 = col[bb, 0], col[bb, 1], col[bb, 2]
            s0 += w * (a1 * b2 - a2 * b1)
            s1 += w * (a2 * b0 - a0 * b2)
            s2 += w * (a0 * b1 - a1 * b0)
        X[g, 0], X[g, 1], X[g, 2] = s0, s1, s2
    # b = column 0 . X
    o0 = col_off[0]
    for i in range(b.shape[0]):
        s0 = 0.0
        for q in range(dp[i], dp[i + 1]):
            a = o0 + di[q]
            j = dj[q]
            t = col[a, 0] * X[j, 0]
            t += col[a, 1] * X[j, 1]
            t += col[a, 2] * X[j, 2]
            s0 += dw[q] * t
        b[i] = s0


@njit(cache=True, nogil=True)
def _table_columns(D, cptr, cidx_, cval, col_a, col_b, col_w, col_off, P, eP, col, A, E):
    """The columns' coefficients col, their largest magnitudes A and errors E per (component, direction) by
    loops over the tables: control points P = C D with their rounding bounds eP, then w (P_b - P_a)."""
    # control points and the bounds of their rounding (per component; relative terms only: every underflow
    # term is in the per-type constant c_abs). Where every control point is a node (linear cells) the
    # columns read the nodes themselves (no copy) and every control point's error is 0
    nctrl = P.shape[0]
    nodes_only = True
    for r in range(nctrl):
        if cptr[r + 1] - cptr[r] != 1 or cval[cptr[r]] != 1.0:
            nodes_only = False
            break
    if nodes_only:
        for r in range(nctrl):
            eP[r, 0] = eP[r, 1] = eP[r, 2] = 0.0
    for r in range(0 if nodes_only else nctrl):
        p0, p1 = cptr[r], cptr[r + 1]
        if p1 - p0 == 1 and cval[p0] == 1.0:  # a control point that is a node (linear cells, corners): exact
            i = cidx_[p0]
            P[r, 0], P[r, 1], P[r, 2] = D[i, 0], D[i, 1], D[i, 2]
            eP[r, 0] = eP[r, 1] = eP[r, 2] = 0.0
            continue
        s0 = s1 = s2 = 0.0
        t0 = t1 = t2 = 0.0
        for p in range(p0, p1):
            w = cval[p]
            i = cidx_[p]
            aw = abs(w)
            x0, x1, x2 = D[i, 0], D[i, 1], D[i, 2]
            s0 += w * x0
            s1 += w * x1
            s2 += w * x2
            t0 += aw * abs(x0)
            t1 += aw * abs(x1)
            t2 += aw * abs(x2)
        P[r, 0], P[r, 1], P[r, 2] = s0, s1, s2
        c = (p1 - p0 + 3.0) * U
        eP[r, 0], eP[r, 1], eP[r, 2] = c * t0, c * t1, c * t2
    # the columns from the control points
    src = D if nodes_only else P
    for d in range(3):
        a0 = a1 = a2 = 0.0
        e0 = e1 = e2 = 0.0
        for e in range(col_off[d], col_off[d + 1]):
            wa = col_w[e]
            ia = col_a[e]
            ib = col_b[e]
            ra = cidx_[ia] if nodes_only else ia  # the rows of src holding the control points
            rb = cidx_[ib] if nodes_only else ib
            v0 = wa * (src[rb, 0] - src[ra, 0])
            v1 = wa * (src[rb, 1] - src[ra, 1])
            v2 = wa * (src[rb, 2] - src[ra, 2])
            col[e, 0] = v0
            col[e, 1] = v1
            col[e, 2] = v2
            v0 = abs(v0)
            v1 = abs(v1)
            v2 = abs(v2)
            a0 = max(a0, v0)
            a1 = max(a1, v1)
            a2 = max(a2, v2)
            e0 = max(e0, U * v0 + wa * (eP[ia, 0] + eP[ib, 0]))
            e1 = max(e1, U * v1 + wa * (eP[ia, 1] + eP[ib, 1]))
            e2 = max(e2, U * v2 + wa * (eP[ia, 2] + eP[ib, 2]))
        A[0, d], A[1, d], A[2, d] = a0, a1, a2
        f = 1.0 + 4.0 * U
        E[0, d], E[1, d], E[2, d] = e0 * f, e1 * f, e2 * f


@njit(cache=True, nogil=True, inline="always")
def _size_and_error(A, E, consts):
    """(err, size, degenerate) of a cell's coefficients from its columns' bounds A and errors E (see
    _cell_coefficients)."""
    size = _perm(A)
    # exactly degenerate: every term of det J has a factor that is exactly 0 (a cell in a plane, a line, ...);
    # a size that merely underflows is not that
    degenerate = not ((A[0, 0] > 0 and (A[1, 1] > 0 and A[2, 2] > 0 or A[1, 2] > 0 and A[2, 1] > 0))
                      or (A[0, 1] > 0 and (A[1, 0] > 0 and A[2, 2] > 0 or A[1, 2] > 0 and A[2, 0] > 0))
                      or (A[0, 2] > 0 and (A[1, 0] > 0 and A[2, 1] > 0 or A[1, 1] > 0 and A[2, 0] > 0)))
    if degenerate:
        size = 0.0
    # rounding: the inputs' errors (perm growth), the products' own roundings; underflow: c_abs (one subnormal
    # operation per cell: arithmetic on subnormal numbers is slow, so none is done before)
    c_rel, c_abs = consts[0], consts[1]
    growth = _perm_growth(A, E)
    err = (growth + c_rel * U * (size + growth)) * (1.0 + 1e-6)  # (the margin covers this formula's rounding)
    return err + c_abs * ETA, size, degenerate


@njit(cache=True, nogil=True, inline="always")
def _cell_start(points, conn, m, D, b):
    """The scaled node offsets D of cell m (_scaled_differences) and its exponent k; for a cell whose nodes all
    coincide (k = _NO_EXTENT) also its coefficients b, all 0."""
    k = _scaled_differences(points, conn, m, D.shape[0], D)
    if k == _NO_EXTENT:
        for i in range(b.shape[0]):
            b[i] = 0.0
    return k


@njit(cache=True, nogil=True, inline="always")
def _cell_coefficients(points, conn, m, cptr, cidx_, cval, col_a, col_b, col_w, col_off, xp, xi, xj, xw, dp, di, dj,
                       dw, consts, D, P, eP, col, X, b, A, E):
    """det J's Bernstein coefficients b of cell m, by Bernstein products of the Jacobian's columns.

    Steps: node offsets D (scaled by 2^-k), control points P = C D, column coefficients w (P_b - P_a), the
    cross product of columns 1 and 2 (product table x*), its dot product with column 0 (table d*). Returns
    (err, k, size, degenerate): err bounds |b - b_exact| (in the scaled units, det J times 2^-3k) for the cell
    as given; size = perm(A) with A the largest |column coefficient| per component and direction (det J's
    terms); degenerate: every term of det J is exactly 0 (the cell lies in a plane or less). The columns by
    loops over the tables, the products by generated code where the type has it (kernel/generated.py), else loops
    (sorted by output coefficient, xp / dp their row pointers); _generated_cell is the same for the types
    whose columns are generated too."""
    k = _cell_start(points, conn, m, D, b)
    if k == _NO_EXTENT:
        return 0.0, 0, 0.0, True
    _table_columns(D, cptr, cidx_, cval, col_a, col_b, col_w, col_off, P, eP, col, A, E)
    # X = column 1 x column 2 (each component a difference of two Bernstein products), then b = column 0 . X
    if not _generated_products_only(int(consts[6]), col, X, b):
        _table_products(col, X, b, col_off, xp, xi, xj, xw, dp, di, dj, dw)
    err, size, degenerate = _size_and_error(A, E, consts)
    return err, k, size, degenerate


@njit(cache=True, nogil=True, inline="always")
def _generated_cell(points, conn, m, consts, D, col, X, b, A, E):
    """_cell_coefficients for a type whose columns and products are generated (kernel/generated.py: the linear types;
    the same numbers as the table loops, bit for bit)."""
    k = _cell_start(points, conn, m, D, b)
    if k == _NO_EXTENT:
        return 0.0, 0, 0.0, True
    gid = int(consts[6])
    _generated_columns(gid, D, col, A, E)
    _generated_products(gid, col, X, b)
    err, size, degenerate = _size_and_error(A, E, consts)
    return err, k, size, degenerate


@njit(cache=True, nogil=True)
def _block_coefficients(points, conn, ids, start, stop, cptr, cidx_, cval, col_a, col_b, col_w, col_off, xp, xi,
                        xj, xw, dp, di, dj, dw, consts, D, P, eP, col, X, b, A, E, o_b, o_err, o_k, o_size, o_deg):
    """The coefficients of the cells ids[start:stop] into row t - start of the outputs. Two loops, one per
    path (_generated_cell, _cell_coefficients): a loop whose body holds both (even the table path as a call)
    ran the generated path a third slower (measured on hexahedra: 250 against 170 ns per cell)."""
    nb = b.shape[0]
    if _has_generated_columns(int(consts[6])):
        for t in range(start, stop):
            err, k, size, deg = _generated_cell(points, conn, ids[t], consts, D, col, X, b, A, E)
            j = t - start
            for i in range(nb):
                o_b[j, i] = b[i]
            o_err[j], o_k[j], o_size[j], o_deg[j] = err, k, size, deg
    else:
        for t in range(start, stop):
            err, k, size, deg = _cell_coefficients(points, conn, ids[t], cptr, cidx_, cval, col_a, col_b, col_w,
                                                   col_off, xp, xi, xj, xw, dp, di, dj, dw, consts, D, P, eP, col, X,
                                                   b, A, E)
            j = t - start
            for i in range(nb):
                o_b[j, i] = b[i]
            o_err[j], o_k[j], o_size[j], o_deg[j] = err, k, size, deg


# --- evaluation at a point from the coefficients ----------------------------------------------------------------


@njit(cache=True, nogil=True)
def _factor_weights(dim, x, fexp, fcoef, count, out):
    """Bernstein basis values of one factor at its coordinates x[:dim]: out[j] = coef_j prod_i lambda_i^a_ji
    with lambda = (1 - x_1 - ... - x_dim, x_1, ..., x_dim) (all >= 0)."""
    l0 = 1.0
    for j in range(dim):
        l0 -= x[j]
    if l0 < 0.0:
        l0 = 0.0
    for j in range(count):
        w = fcoef[j] * l0 ** fexp[j, 0]
        for i in range(dim):
            w *= x[i] ** fexp[j, i + 1]
        out[j] = w


@njit(cache=True, nogil=True)
def _eval_bernstein(b, x, fdim, fslot, fexp, fcoef, sizes, W, xs):
    """sum_j w_j(x) b_j with the explicit basis weights: the polynomial's value at x."""
    nf = sizes.shape[0]
    for k in range(nf):
        for j in range(fdim[k]):
            xs[j] = x[fslot[k] + j]
        _factor_weights(fdim[k], xs, fexp[k], fcoef[k], sizes[k], W[k])
    s = 0.0
    if nf == 1:
        for i in range(sizes[0]):
            s += W[0, i] * b[i]
    elif nf == 2:
        n1 = sizes[1]
        for i in range(sizes[0]):
            w0 = W[0, i]
            for j in range(n1):
                s += w0 * W[1, j] * b[i * n1 + j]
    else:
        n1, n2 = sizes[1], sizes[2]
        for i in range(sizes[0]):
            w0 = W[0, i]
            for j in range(n1):
                w01 = w0 * W[1, j]
                base = (i * n1 + j) * n2
                for k in range(n2):
                    s += w01 * W[2, k] * b[base + k]
    return s


# --- the branch-and-bound --------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _apply_factor(src, dst, M, nz, nk, pre, post):
    """dst = M applied along one factor axis of a row-major coefficient tensor of shape (pre, nk, post). Row r
    of M has nz[r, 0] nonzeros, in the columns nz[r, 1:] (ascending): only they are summed, in the dense
    product's order (the skipped terms are exact zeros: the same sums bit for bit)."""
    for i0 in range(pre):
        for j in range(post):
            base = i0 * nk * post + j
            for r in range(nk):
                s = 0.0
                for q in range(1, nz[r, 0] + 1):
                    c = nz[r, q]
                    s += M[r, c] * src[base + c * post]
                dst[base + r * post] = s


@njit(cache=True, nogil=True, inline="always")
def _children(coef, out, work, S, Snz, nchildren, sizes, fdim, tri):
    """All children's coefficients of one box into out[c], c row-major over the factors' child indices.

    A line factor of degree nk - 1 is halved by de Casteljau at 1/2 (each step averages two numbers: the same
    convex combinations as the factor's child matrices, in as many roundings as the degree), in place: box t's
    halves go to rows 2t and 2t + 1, boxes taken from the last down (each slab of lines is read whole into tri, nb
    numbers, before its halves are written, so row 0 may be its own lower half). Other factors apply their child
    matrices from a copy."""
    nb = coef.shape[0]
    count = 1
    for i in range(nb):
        out[0, i] = coef[i]
    pre = 1
    for k in range(sizes.shape[0]):
        nk = sizes[k]
        post = nb // (pre * nk)
        nck = nchildren[k]
        if nck > 1 and fdim[k] == 1 and nk == 3:  # degree 2 (hexahedra, pyramids, wedges): the steps written out
            for t in range(count - 1, -1, -1):
                lo = 2 * t
                hi = lo + 1
                for i0 in range(pre):
                    for j in range(post):
                        i_a = i0 * 3 * post + j
                        i_b = i_a + post
                        i_c = i_b + post
                        a = out[t, i_a]
                        b = out[t, i_b]
                        c = out[t, i_c]
                        m1 = 0.5 * (a + b)
                        m2 = 0.5 * (b + c)
                        mm = 0.5 * (m1 + m2)
                        out[lo, i_a] = a
                        out[lo, i_b] = m1
                        out[lo, i_c] = mm
                        out[hi, i_a] = mm
                        out[hi, i_b] = m2
                        out[hi, i_c] = c
            count *= 2
        elif nck > 1 and fdim[k] == 1:
            # the post lines of a slab side by side (innermost, contiguous), each line's steps in their order;
            # tri holds the slab (nk rows of post numbers)
            p = nk - 1
            for t in range(count - 1, -1, -1):
                lo = 2 * t
                hi = lo + 1
                for i0 in range(pre):
                    base = i0 * nk * post
                    for q in range(nk * post):
                        tri[q] = out[t, base + q]
                    for j in range(post):
                        out[lo, base + j] = tri[j]
                        out[hi, base + p * post + j] = tri[p * post + j]
                    for level in range(1, nk):
                        for r in range(nk - level):
                            for j in range(post):
                                tri[r * post + j] = 0.5 * (tri[r * post + j] + tri[(r + 1) * post + j])
                        for j in range(post):
                            out[lo, base + level * post + j] = tri[j]
                            out[hi, base + (p - level) * post + j] = tri[(nk - level - 1) * post + j]
            count *= 2
        elif nck > 1:
            for t in range(count):
                for i in range(nb):
                    work[t, i] = out[t, i]
            for t in range(count):
                for c in range(nck):
                    _apply_factor(work[t], out[t * nck + c], S[k, c], Snz[k, c], nk, pre, post)
            count *= nck
        pre *= nk
    return count


@njit(cache=True, nogil=True)
def _compose(parent, child, out):
    """out = parent o child for affine maps stored as 3 x 4 matrices [A | o] (x -> A x + o)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = parent[i, 0] * child[0, j] + parent[i, 1] * child[1, j] + parent[i, 2] * child[2, j]
        out[i, 3] = parent[i, 3] + parent[i, 0] * child[0, 3] + parent[i, 1] * child[1, 3] + parent[i, 2] * child[2, 3]


@njit(cache=True, nogil=True)
def _line_weights(p, t, out):
    """Bernstein basis of degree p at t in [0, 1] into out[:p + 1] (non-negative)."""
    s = 1.0 - t
    if p == 2:  # the loop below, written out (1.0 * x and 2.0 * x are exact: the same numbers)
        out[0] = s * s
        out[1] = 2.0 * (t * s)
        out[2] = t * t
        return
    if p == 1:
        out[0] = s
        out[1] = t
        return
    for i in range(p + 1):
        w = 1.0
        for _ in range(i):
            w *= t
        for _ in range(p - i):
            w *= s
        c = 1.0
        for j in range(1, i + 1):
            c = c * (p - i + j) / j
        out[i] = c * w


@njit(cache=True, nogil=True)
def _min_quadratic(g_lo, g_hi, lam, dl, dh):
    """min over d in [dl, dh] (dl <= 0 <= dh) of min(g_lo d, g_hi d) + lam d^2 / 2 (g_lo <= g_hi)."""
    m = 0.0
    for side in range(2):
        g = g_lo if side == 0 else g_hi  # d >= 0 takes g_lo, d <= 0 takes g_hi
        end = dh if side == 0 else dl
        v = g * end + 0.5 * lam * end * end
        if v < m:
            m = v
        if lam > 0.0:
            d = -g / lam
            if (side == 0 and 0.0 < d < dh) or (side == 1 and dl < d < 0.0):
                v = g * d + 0.5 * lam * d * d
                if v < m:
                    m = v
    return m


@njit(cache=True, nogil=True)
def taylor_bound(c, e, t, sizes, W, Wd, F3, F33, I3):
    """A rigorous lower bound of a polynomial over a box from its tensor Bernstein coefficients c (line
    factors; sizes = degrees + 1, up to 3 axes), each within e of exact, by its second-order expansion at the
    local point t (in [0, 1]^3): f(x) = f(t) + g . d + d^T H(xi) d / 2 with d = x - t and xi in the box, where
    f(t) and g = grad f(t) are enclosed by evaluating the (derivative) coefficients with non-negative weights,
    and every entry of H over the box by the extremes of its Bernstein coefficients (second differences);
    d^T H d >= sum_a (H_aa,lo - sum_b!=a max|H_ab|) d_a^2, so the bound is f(t) plus three one-dimensional
    minimizations. Near a minimizer (g ~ 0, H positive) it is within the rounding of f's minimum on a box
    where plain Bernstein bounds still need many halvings. Scratch: F3 (4, 3), F33 (4, 3, 3), I3 (2, 3) int."""
    n0, n1, n2 = sizes[0], sizes[1] if sizes.shape[0] > 1 else 1, sizes[2] if sizes.shape[0] > 2 else 1
    p = (n0 - 1, n1 - 1, n2 - 1)
    cmax = 0.0
    for i in range(c.shape[0]):
        if abs(c[i]) > cmax:
            cmax = abs(c[i])
    # value at t
    for a in range(3):
        _line_weights(p[a], t[a], W[a])
    v = 0.0
    for i in range(n0):
        for j in range(n1):
            for k in range(n2):
                v += W[0, i] * W[1, j] * W[2, k] * c[(i * n1 + j) * n2 + k]
    total = abs(v)
    v_lo = v - e * (1.0 + 64.0 * U) - 4.0 * (c.shape[0] + 12.0) * U * cmax
    # gradient at t: derivative coefficients p_a (c[.. i+1 ..] - c[.. i ..]) evaluated with degree p_a - 1 weights
    g = F3[0]
    eg = F3[1]
    for a in range(3):
        g[a] = 0.0
        eg[a] = 0.0
    for a in range(3):
        if p[a] == 0:
            continue
        _line_weights(p[a] - 1, t[a], Wd)
        s = 0.0
        dmax = 0.0
        step = n1 * n2 if a == 0 else (n2 if a == 1 else 1)
        for i in range(n0 - 1 if a == 0 else n0):  # every coefficient with a successor along a, in order
            for j in range(n1 - 1 if a == 1 else n1):
                for k in range(n2 - 1 if a == 2 else n2):
                    base = (i * n1 + j) * n2 + k
                    dlt = p[a] * (c[base + step] - c[base])
                    if abs(dlt) > dmax:
                        dmax = abs(dlt)
                    if a == 0:
                        w = Wd[i] * W[1, j] * W[2, k]
                    elif a == 1:
                        w = W[0, i] * Wd[j] * W[2, k]
                    else:
                        w = W[0, i] * W[1, j] * Wd[k]
                    s += w * dlt
        g[a] = s
        eg[a] = 2.0 * p[a] * e + 4.0 * (c.shape[0] + 12.0) * U * dmax
        total += abs(s)
    # Hessian enclosures over the box: every entry in [Hl, Hh], from the extremes of its Bernstein coefficients
    # (second differences), widened by their rounding
    Hl = F33[0]
    Hh = F33[1]
    for a in range(3):
        for b2 in range(3):
            Hl[a, b2] = 0.0
            Hh[a, b2] = 0.0
    for a in range(3):
        for b2 in range(a, 3):
            if (a == b2 and p[a] < 2) or (a != b2 and (p[a] == 0 or p[b2] == 0)):
                continue
            sa = n1 * n2 if a == 0 else (n2 if a == 1 else 1)
            sb = n1 * n2 if b2 == 0 else (n2 if b2 == 1 else 1)
            fac = p[a] * (p[a] - 1) if a == b2 else p[a] * p[b2]
            lo = np.inf
            hi = -np.inf
            amax = 0.0
            # every coefficient whose second difference along (a, b2) exists, in order
            e0 = (2 if a == 0 else 0) if a == b2 else (1 if a == 0 or b2 == 0 else 0)
            e1 = (2 if a == 1 else 0) if a == b2 else (1 if a == 1 or b2 == 1 else 0)
            e2 = (2 if a == 2 else 0) if a == b2 else (1 if a == 2 or b2 == 2 else 0)
            for i in range(n0 - e0):
                for j in range(n1 - e1):
                    for k in range(n2 - e2):
                        base = (i * n1 + j) * n2 + k
                        if a == b2:
                            h = fac * ((c[base + 2 * sa] - c[base + sa]) - (c[base + sa] - c[base]))
                        else:
                            h = fac * ((c[base + sa + sb] - c[base + sa]) - (c[base + sb] - c[base]))
                        if h < lo:
                            lo = h
                        if h > hi:
                            hi = h
                        if abs(h) > amax:
                            amax = abs(h)
            # inputs within e; the differences round relative to first differences, each at most 2 cmax
            eh = 4.0 * fac * e + 16.0 * fac * U * cmax + 8.0 * U * amax
            Hl[a, b2] = Hl[b2, a] = lo - eh
            Hh[a, b2] = Hh[b2, a] = hi + eh
    # axes where t is on a face and the gradient points into the element ("active"): their cross terms are
    # folded into their linear term (H_ab d_a d_b >= -max|H_ab| R_b |d_a|, R_b the farthest d_b); the free axes
    # keep theirs: d^T H d >= d^T Hm d - |d|^T Hr |d| >= d^T (Hm - diag(rho)) d (Hm, Hr: midpoints and radii,
    # rho the radii's row sums), and beta I below that matrix when a shifted Cholesky succeeds (verified: the
    # shift covers the factorization's rounding)
    active = I3[0]
    for a in range(3):
        active[a] = 0
        if p[a] > 0 and ((t[a] == 0.0 and g[a] - eg[a] > 0.0) or (t[a] == 1.0 and g[a] + eg[a] < 0.0)):
            active[a] = 1
    lin = F3[2]
    for a in range(3):
        lin[a] = 0.0
    for a in range(3):
        for b2 in range(3):
            if b2 != a and active[a] == 1 and p[b2] > 0 and not (active[b2] == 1 and b2 < a):
                lin[a] += max(abs(Hl[a, b2]), abs(Hh[a, b2])) * max(t[b2], 1.0 - t[b2])
    free = I3[1]
    nfree = 0
    for a in range(3):
        if p[a] > 0 and active[a] == 0:
            free[nfree] = a
            nfree += 1
    B = F33[2]
    bsum = 0.0
    for i in range(nfree):
        a = free[i]
        rho = 0.0
        for j in range(nfree):
            rho += 0.5 * (Hh[a, free[j]] - Hl[a, free[j]])
        for j in range(nfree):
            B[i, j] = 0.5 * (Hh[a, free[j]] + Hl[a, free[j]])
            bsum += abs(B[i, j])
        B[i, i] -= rho * (1.0 + 4.0 * U)
    beta = -np.inf
    if nfree > 0:
        dmin = np.inf
        for i in range(nfree):
            dmin = min(dmin, B[i, i])
        shift = 32.0 * U * bsum + 1e-300
        for trial in range(6):  # the largest of dmin/2, dmin/8, ..., 0 that a verified Cholesky accepts
            cand = dmin * 0.5 ** (2 * trial + 1) if trial < 5 else 0.0
            if cand < 0.0:
                break
            ok = True
            L = F33[3]
            for i in range(nfree):
                for j in range(i + 1):
                    sacc = B[i, j] - (cand + shift if i == j else 0.0)
                    for k in range(j):
                        sacc -= L[i, k] * L[j, k]
                    if i == j:
                        if sacc <= 0.0:
                            ok = False
                            break
                        L[i, i] = math.sqrt(sacc)
                    else:
                        L[i, j] = sacc / L[j, j]
                if not ok:
                    break
            if ok:
                beta = cand
                break
        if beta == -np.inf:  # not positive definite: Gershgorin on the interval matrix
            beta = np.inf
            for i in range(nfree):
                a = free[i]
                r = Hl[a, a]
                for j in range(nfree):
                    if j != i:
                        r -= max(abs(Hl[a, free[j]]), abs(Hh[a, free[j]]))
                beta = min(beta, r)
    bound = v_lo
    for a in range(3):
        if p[a] == 0:
            continue
        if active[a] == 1 and t[a] == 0.0:
            m = _min_quadratic(g[a] - eg[a] - lin[a], g[a] + eg[a] + lin[a], Hl[a, a], 0.0, 1.0)
        elif active[a] == 1:
            m = _min_quadratic(g[a] - eg[a] - lin[a], g[a] + eg[a] + lin[a], Hl[a, a], -1.0, 0.0)
        else:
            m = _min_quadratic(g[a] - eg[a], g[a] + eg[a], beta, -t[a], 1.0 - t[a])
        bound += m
        total += abs(m)
    return bound - 16.0 * U * total


@njit(cache=True, nogil=True)
def _refine(b, err, level_err, tol, upper, argmin, max_depth, max_iter, S, Snz, nchildren, sizes, fdim, cmaps, ctrl,
            vidx, bc, bmap, blow, bdepth, kids, work, pmap, cmap, tri, taylor, TW, TWd, tloc, TF3, TF33, TI3):
    """Best-first branch-and-bound of one cell from its root coefficients b.

    Returns (lower, upper, depth, closed, boxes); ``argmin`` (3,) receives the box vertex where ``upper`` (the
    smallest vertex coefficient seen: a value, up to rounding) was found. Boxes whose bound is at least
    ``upper - tol`` are pruned (the bound of a pruned box stays >= the final upper - tol: upper only falls);
    the lower bound is the smallest bound of the pruned, dropped and live boxes."""
    nb = b.shape[0]
    cap = blow.shape[0]
    for i in range(nb):
        bc[0, i] = b[i]
    for i in range(3):
        for j in range(4):
            bmap[0, i, j] = 1.0 if i == j else 0.0
    lo0 = np.inf
    for i in range(nb):
        if b[i] < lo0:
            lo0 = b[i]
    blow[0] = lo0 - err
    bdepth[0] = 0
    live = 1
    pruned = np.inf
    dropped = np.inf
    maxd = 0
    boxes = 0
    it = 0
    while live > 0:
        bi = 0
        for i in range(1, live):
            if blow[i] < blow[bi]:
                bi = i
        if blow[bi] >= upper - tol:
            break
        if bdepth[bi] >= max_depth or it >= max_iter:
            break
        if taylor and bdepth[bi] > 0:  # at the root it almost never prunes (7 of 13,524 random hexes)
            # a second-order bound around the best point (the box maps of line factors are axis-aligned) may
            # prune the box at once instead of many halvings
            # (expanded at the box's point nearest to the best point: there the gradient is small too)
            for a in range(3):
                ha = bmap[bi, a, a]
                ta = (argmin[a] - bmap[bi, a, 3]) / ha if ha > 0.0 else 0.0
                tloc[a] = min(max(ta, 0.0), 1.0)
            tb = taylor_bound(bc[bi], err + bdepth[bi] * level_err, tloc, sizes, TW, TWd, TF3, TF33, TI3)
            if tb >= upper - tol:
                if tb < pruned:
                    pruned = tb
                live -= 1
                if bi != live:
                    for i in range(nb):
                        bc[bi, i] = bc[live, i]
                    for i in range(3):
                        for j in range(4):
                            bmap[bi, i, j] = bmap[live, i, j]
                    blow[bi] = blow[live]
                    bdepth[bi] = bdepth[live]
                continue
        it += 1
        d = bdepth[bi] + 1
        if d > maxd:
            maxd = d
        for i in range(3):
            for j in range(4):
                pmap[i, j] = bmap[bi, i, j]
        count = _children(bc[bi], kids, work, S, Snz, nchildren, sizes, fdim, tri)
        live -= 1  # the parent's slot gets the last live box
        if bi != live:
            for i in range(nb):
                bc[bi, i] = bc[live, i]
            for i in range(3):
                for j in range(4):
                    bmap[bi, i, j] = bmap[live, i, j]
            blow[bi] = blow[live]
            bdepth[bi] = bdepth[live]
        e_d = err + d * level_err
        for c in range(count):
            boxes += 1
            cl = np.inf
            for i in range(nb):
                if kids[c, i] < cl:
                    cl = kids[c, i]
            cl -= e_d
            vmin = np.inf
            vbest = 0
            for j in range(vidx.shape[0]):
                v = kids[c, vidx[j]]
                if v < vmin:
                    vmin = v
                    vbest = vidx[j]
            keep = cl < upper - tol or vmin < upper
            if not keep:
                if cl < pruned:
                    pruned = cl
                continue
            _compose(pmap, cmaps[c], cmap)
            if vmin < upper:
                upper = vmin
                for a in range(3):
                    argmin[a] = cmap[a, 3] + cmap[a, 0] * ctrl[vbest, 0] + cmap[a, 1] * ctrl[vbest, 1] + \
                        cmap[a, 2] * ctrl[vbest, 2]
            if cl >= upper - tol:
                if cl < pruned:
                    pruned = cl
                continue
            if live >= cap:
                if cl < dropped:
                    dropped = cl
                continue
            for i in range(nb):
                bc[live, i] = kids[c, i]
            for i in range(3):
                for j in range(4):
                    bmap[live, i, j] = cmap[i, j]
            blow[live] = cl
            bdepth[live] = d
            live += 1
    lower = min(pruned, dropped)
    for i in range(live):
        if blow[i] < lower:
            lower = blow[i]
    if lower > upper:
        lower = upper
    return lower, upper, maxd, upper - lower <= tol, boxes


@njit(cache=True, nogil=True, inline="always")
def bisect_tet(coef, lo, hi, e, bptr, bidx, tri):
    """The two children of a tetrahedral box (one tet factor) bisected at the midpoint of its edge e: every line
    of coefficients along the edge (bidx[e, bptr[e, q]:bptr[e, q + 1]], ordered by the exponent of the edge's
    second vertex) halved by de Casteljau at 1/2 (each step averages two numbers: r roundings for a line of
    degree r, no growth), the left halves into lo (the child keeping the edge's first vertex), the right halves
    into hi; returns the smallest coefficient of each child. O(n p) operations for n coefficients of degree p,
    against O(n^2) for a dense child matrix; lines of degree <= 2 (most of them) written out, the same steps."""
    ix = bidx[e]
    pt = bptr[e]
    mlo = np.inf
    mhi = np.inf
    for q in range(pt.shape[0] - 1):
        p0 = pt[q]
        r = pt[q + 1] - p0 - 1
        if r == 0:
            i0 = ix[p0]
            a = coef[i0]
            lo[i0] = a
            hi[i0] = a
            if a < mlo:
                mlo = a
            if a < mhi:
                mhi = a
        elif r == 1:
            i0 = ix[p0]
            i1 = ix[p0 + 1]
            a = coef[i0]
            c = coef[i1]
            m = 0.5 * (a + c)
            lo[i0] = a
            lo[i1] = m
            hi[i0] = m
            hi[i1] = c
            if a < mlo:
                mlo = a
            if m < mlo:
                mlo = m
            if m < mhi:
                mhi = m
            if c < mhi:
                mhi = c
        elif r == 2:
            i0 = ix[p0]
            i1 = ix[p0 + 1]
            i2 = ix[p0 + 2]
            a = coef[i0]
            bb = coef[i1]
            c = coef[i2]
            m1 = 0.5 * (a + bb)
            m2 = 0.5 * (bb + c)
            mm = 0.5 * (m1 + m2)
            lo[i0] = a
            lo[i1] = m1
            lo[i2] = mm
            hi[i0] = mm
            hi[i1] = m2
            hi[i2] = c
            if a < mlo:
                mlo = a
            if m1 < mlo:
                mlo = m1
            if mm < mlo:
                mlo = mm
            if mm < mhi:
                mhi = mm
            if m2 < mhi:
                mhi = m2
            if c < mhi:
                mhi = c
        else:
            for s in range(r + 1):
                tri[s] = coef[ix[p0 + s]]
            v = tri[0]
            lo[ix[p0]] = v
            if v < mlo:
                mlo = v
            v = tri[r]
            hi[ix[p0 + r]] = v
            if v < mhi:
                mhi = v
            for level in range(1, r + 1):
                for s in range(r - level + 1):
                    tri[s] = 0.5 * (tri[s] + tri[s + 1])
                v = tri[0]
                lo[ix[p0 + level]] = v
                if v < mlo:
                    mlo = v
                v = tri[r - level]
                hi[ix[p0 + r - level]] = v
                if v < mhi:
                    mhi = v
    return mlo, mhi


@njit(cache=True, nogil=True)
def _refine_simplex(b, err, level_err, tol, upper, argmin, max_depth, max_iter, bptr, bidx, bvert, bc, bv, blow,
                    bdepth, kids, pv, tri):
    """Best-first branch-and-bound of a cell whose det J is one tet factor (the tetrahedra), by bisection: the
    chosen box (smallest bound) is cut in two at the midpoint of its longest edge (in reference coordinates)
    by :func:`bisect_tet`. The same rules as :func:`_refine` otherwise: a box's bound is its smallest coefficient
    minus err + depth level_err, the midpoint's coefficient is a value (the vertices of a box are values: its
    children's other vertices are their parent's); boxes whose bound is at least ``upper - tol`` are pruned.
    bv (cap, 4, 3) holds each box's vertices (slot k: barycentric vertex k).

    Rounding: a level rounds each coefficient at most p times (degree p), each time by at most U M + eta / 2
    (M the largest |coefficient| then; averaging does not grow earlier errors), so by p (U M + eta / 2). Every
    coefficient is within err + depth level_err of a convex combination of the exact root coefficients, so M <=
    scale + err + depth level_err; and a cell is refined only while err < 2 scale / 3 (else tol >= 4 err closes
    its root bracket: max b - min b <= 2 scale <= 3 err), so M < 1.7 scale and p (U M + eta / 2) is below
    level_err = 2 (n + 2) U scale + 16 n eta (n > p coefficients), the 8-way split's bound."""
    nb = b.shape[0]
    cap = blow.shape[0]
    for i in range(nb):
        bc[0, i] = b[i]
    for k in range(4):
        for a in range(3):
            bv[0, k, a] = 1.0 if a == k - 1 else 0.0
    lo0 = np.inf
    for i in range(nb):
        if b[i] < lo0:
            lo0 = b[i]
    blow[0] = lo0 - err
    bdepth[0] = 0
    live = 1
    pruned = np.inf
    dropped = np.inf
    maxd = 0
    boxes = 0
    it = 0
    while live > 0:
        bi = 0
        for i in range(1, live):
            if blow[i] < blow[bi]:
                bi = i
        if blow[bi] >= upper - tol:
            break
        if bdepth[bi] >= max_depth or it >= max_iter:
            break
        it += 1
        d = bdepth[bi] + 1
        if d > maxd:
            maxd = d
        # the longest edge (the first of equals)
        e = 0
        best = -1.0
        for q in range(6):
            i0 = 0 if q < 3 else (1 if q < 5 else 2)
            j0 = q + 1 if q < 3 else (q - 1 if q < 5 else 3)
            ln = 0.0
            for a in range(3):
                dl = bv[bi, j0, a] - bv[bi, i0, a]
                ln += dl * dl
            if ln > best:
                best = ln
                e = q
        ei = 0 if e < 3 else (1 if e < 5 else 2)
        ej = e + 1 if e < 3 else (e - 1 if e < 5 else 3)
        mlo, mhi = bisect_tet(bc[bi], kids[0], kids[1], e, bptr, bidx, tri)
        for k in range(4):
            for a in range(3):
                pv[k, a] = bv[bi, k, a]
        live -= 1  # the parent's slot gets the last live box
        if bi != live:
            for i in range(nb):
                bc[bi, i] = bc[live, i]
            for k in range(4):
                for a in range(3):
                    bv[bi, k, a] = bv[live, k, a]
            blow[bi] = blow[live]
            bdepth[bi] = bdepth[live]
        # the midpoint: its coefficient (the same number in both children) is a value there
        vm = kids[0, bvert[ej]]
        if vm < upper:
            upper = vm
            for a in range(3):
                argmin[a] = 0.5 * (pv[ei, a] + pv[ej, a])
        e_d = err + d * level_err
        for c in range(2):
            boxes += 1
            cl = (mlo if c == 0 else mhi) - e_d
            if cl >= upper - tol:
                if cl < pruned:
                    pruned = cl
                continue
            if live >= cap:
                if cl < dropped:
                    dropped = cl
                continue
            for i in range(nb):
                bc[live, i] = kids[c, i]
            for k in range(4):
                for a in range(3):
                    bv[live, k, a] = pv[k, a]
            moved = ej if c == 0 else ei  # the slot the midpoint takes
            for a in range(3):
                bv[live, moved, a] = 0.5 * (pv[ei, a] + pv[ej, a])
            blow[live] = cl
            bdepth[live] = d
            live += 1
    lower = min(pruned, dropped)
    for i in range(live):
        if blow[i] < lower:
            lower = blow[i]
    if lower > upper:
        lower = upper
    return lower, upper, maxd, upper - lower <= tol, boxes


# --- polish ------------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _mono_derivs(c, exps, x, g, H, pw):
    """Value, gradient g (3,) and Hessian H (3, 3) of sum_m c_m x^m (pw: (3, 1 + the largest exponent) scratch)."""
    for a in range(3):
        pw[a, 0] = 1.0
        for k in range(1, pw.shape[1]):
            pw[a, k] = pw[a, k - 1] * x[a]
    f = 0.0
    g0 = g1 = g2 = 0.0
    h00 = h11 = h22 = h01 = h02 = h12 = 0.0
    for m in range(c.shape[0]):
        cm = c[m]
        if cm == 0.0:
            continue
        e0, e1, e2 = exps[m, 0], exps[m, 1], exps[m, 2]
        p0, p1, p2 = pw[0, e0], pw[1, e1], pw[2, e2]
        d0 = e0 * pw[0, e0 - 1] if e0 > 0 else 0.0
        d1 = e1 * pw[1, e1 - 1] if e1 > 0 else 0.0
        d2 = e2 * pw[2, e2 - 1] if e2 > 0 else 0.0
        f += cm * p0 * p1 * p2
        g0 += cm * d0 * p1 * p2
        g1 += cm * p0 * d1 * p2
        g2 += cm * p0 * p1 * d2
        if e0 > 1:
            h00 += cm * e0 * (e0 - 1) * pw[0, e0 - 2] * p1 * p2
        if e1 > 1:
            h11 += cm * p0 * e1 * (e1 - 1) * pw[1, e1 - 2] * p2
        if e2 > 1:
            h22 += cm * p0 * p1 * e2 * (e2 - 1) * pw[2, e2 - 2]
        h01 += cm * d0 * d1 * p2
        h02 += cm * d0 * p1 * d2
        h12 += cm * p0 * d1 * d2
    g[0], g[1], g[2] = g0, g1, g2
    H[0, 0], H[1, 1], H[2, 2] = h00, h11, h22
    H[0, 1] = H[1, 0] = h01
    H[0, 2] = H[2, 0] = h02
    H[1, 2] = H[2, 1] = h12
    return f


@njit(cache=True, nogil=True)
def _mono_value(c, exps, x, pw):
    for a in range(3):
        pw[a, 0] = 1.0
        for k in range(1, pw.shape[1]):
            pw[a, k] = pw[a, k - 1] * x[a]
    f = 0.0
    for m in range(c.shape[0]):
        if c[m] != 0.0:
            f += c[m] * pw[0, exps[m, 0]] * pw[1, exps[m, 1]] * pw[2, exps[m, 2]]
    return f


@njit(cache=True, nogil=True)
def _two_sum(a, b):
    """s = fl(a + b) and the exact error e: a + b = s + e exactly (Knuth; needs IEEE semantics, no fastmath)."""
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


@njit(cache=True, nogil=True)
def _inside(G, h, x):
    """x lies in {G x <= h} exactly (the faces' rows hold 0 and +-1; sums of coordinates are tested with their
    exact rounding errors, so a point on a simplex face is accepted and one a rounding beyond it is not)."""
    for i in range(G.shape[0]):
        s = 0.0
        e = 0.0
        for a in range(3):
            if G[i, a] != 0.0:
                s, ea = _two_sum(s, G[i, a] * x[a])
                e += ea
        if s > h[i] or (s == h[i] and e > 0.0):
            return False
    return True


@njit(cache=True, nogil=True)
def _free_basis(G, act, Q, Z, v):
    """Z (nz, 3): an orthonormal basis of the directions along every active face (rows of G where act)."""
    nq = 0
    for i in range(G.shape[0]):
        if not act[i] or nq == 3:
            continue
        for a in range(3):
            v[a] = G[i, a]
        for j in range(nq):
            p = v[0] * Q[j, 0] + v[1] * Q[j, 1] + v[2] * Q[j, 2]
            for a in range(3):
                v[a] -= p * Q[j, a]
        nv = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        if nv > 1e-12:
            for a in range(3):
                Q[nq, a] = v[a] / nv
            nq += 1
    nz = 0
    for e in range(3):
        for a in range(3):
            v[a] = 1.0 if a == e else 0.0
        for j in range(nq):
            p = v[0] * Q[j, 0] + v[1] * Q[j, 1] + v[2] * Q[j, 2]
            for a in range(3):
                v[a] -= p * Q[j, a]
        for j in range(nz):
            p = v[0] * Z[j, 0] + v[1] * Z[j, 1] + v[2] * Z[j, 2]
            for a in range(3):
                v[a] -= p * Z[j, a]
        nv = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        if nv > 1e-8 and nz < 3 - nq:
            for a in range(3):
                Z[nz, a] = v[a] / nv
            nz += 1
    return nz


@njit(cache=True, nogil=True)
def _reduced_step(Z, nz, g, H, gr, Hr, Lc, y, step):
    """The Newton step on span(Z) where the reduced Hessian is positive definite, else steepest descent;
    returns (is_newton, |reduced gradient|^2)."""
    gnorm = 0.0
    for i in range(nz):
        gr[i] = Z[i, 0] * g[0] + Z[i, 1] * g[1] + Z[i, 2] * g[2]
        gnorm += gr[i] * gr[i]
        for j in range(nz):
            s = 0.0
            for a in range(3):
                s += Z[i, a] * (H[a, 0] * Z[j, 0] + H[a, 1] * Z[j, 1] + H[a, 2] * Z[j, 2])
            Hr[i, j] = s
    ok = True
    for i in range(nz):  # Cholesky of the reduced Hessian
        for j in range(i + 1):
            s = Hr[i, j]
            for k in range(j):
                s -= Lc[i, k] * Lc[j, k]
            if i == j:
                if s <= 1e-14 * (abs(Hr[i, i]) + 1e-300):
                    ok = False
                    break
                Lc[i, i] = math.sqrt(s)
            else:
                Lc[i, j] = s / Lc[j, j]
        if not ok:
            break
    if ok:
        for i in range(nz):
            s = -gr[i]
            for k in range(i):
                s -= Lc[i, k] * y[k]
            y[i] = s / Lc[i, i]
        for i in range(nz - 1, -1, -1):
            s = y[i]
            for k in range(i + 1, nz):
                s -= Lc[k, i] * y[k]
            y[i] = s / Lc[i, i]
    else:
        for i in range(nz):
            y[i] = -gr[i]
    for a in range(3):
        s = 0.0
        for i in range(nz):
            s += Z[i, a] * y[i]
        step[a] = s
    return ok, gnorm


@njit(cache=True, nogil=True)
def _polish(b, x0, Mptr, Midx, Mval, exps, G, h, iterations, out, c, pw, Q, Z, Hr, Lc, v, g, H, gr, y, step, xt):
    """Projected Newton descent on the polynomial with Bernstein coefficients b from x0 (in the element).

    Each iteration takes as active the faces the point is on where the descent direction leaves, a basis Z
    of the directions along them, a Newton step on Z (steepest descent where the reduced Hessian is not
    positive definite); a face the step would cross at once joins the active set and the step is recomputed;
    then the longest feasible step is halved until the value falls. It stops when no step lowers the value,
    when a Newton step's predicted decrease is within the rounding of a value (at a minimum: no shorter step
    could show one), or when a step no longer moves the point. out receives the best point (x0 if nothing
    lowers the value); the value there (monomial form, for ranking only) is returned. (Mptr, Midx, Mval): the
    nonzeros of the Bernstein-to-monomial matrix by row."""
    nb = b.shape[0]
    for i in range(nb):
        s = 0.0
        for q in range(Mptr[i], Mptr[i + 1]):
            s += Mval[q] * b[Midx[q]]
        c[i] = s
    for a in range(3):
        out[a] = x0[a]
    f = _mono_derivs(c, exps, out, g, H, pw)
    csum = 0.0
    for i in range(nb):
        csum += abs(c[i])
    noise = 16.0 * U * csum  # the rounding of a value: a smaller decrease cannot show
    ng = G.shape[0]
    act = np.zeros(ng, dtype=np.bool_)
    for _ in range(iterations):
        for i in range(ng):
            on = G[i, 0] * out[0] + G[i, 1] * out[1] + G[i, 2] * out[2] >= h[i] - 1e-13
            act[i] = on and -(G[i, 0] * g[0] + G[i, 1] * g[1] + G[i, 2] * g[2]) > 0.0
        nz = 0
        ok = False
        gnorm = 0.0
        tmax = 0.0
        for _a in range(ng + 1):
            nz = _free_basis(G, act, Q, Z, v)
            if nz == 0:
                break
            ok, gnorm = _reduced_step(Z, nz, g, H, gr, Hr, Lc, y, step)
            if gnorm == 0.0:
                nz = 0
                break
            tmax = 1.0 if ok else 1.0 / math.sqrt(gnorm)
            block = -1
            for i in range(ng):  # ratio test on the faces the step moves towards
                gs = G[i, 0] * step[0] + G[i, 1] * step[1] + G[i, 2] * step[2]
                if gs > 0.0:
                    slack = h[i] - (G[i, 0] * out[0] + G[i, 1] * out[1] + G[i, 2] * out[2])
                    if slack < 1e-13:
                        slack = 0.0
                        if not act[i]:
                            block = i
                    if slack / gs < tmax:
                        tmax = slack / gs
            if tmax > 0.0 or block < 0:
                break
            act[block] = True  # the step crosses a face the point is on: move along it instead
        if nz == 0 or tmax <= 0.0:
            break
        improved = False
        t = tmax
        # a Newton step predicts the decrease -g.step / 2 of the quadratic model; where that is within the
        # rounding of a value (at the minimum), no shorter step can show a decrease either: stop
        small = ok and -0.5 * (g[0] * step[0] + g[1] * step[1] + g[2] * step[2]) * t <= noise
        for _h in range(30):
            moved = False
            for a in range(3):
                xt[a] = out[a] + t * step[a]
                if xt[a] != out[a]:
                    moved = True
            if not moved:  # the step is below the points' spacing: shorter ones stay put as well
                break
            for i in range(ng):  # clip onto the coordinate faces the step reached (exactly representable)
                if abs(G[i, 0]) + abs(G[i, 1]) + abs(G[i, 2]) == 1.0:
                    for a in range(3):
                        if G[i, a] != 0.0:
                            lim = h[i] / G[i, a]
                            if (G[i, a] > 0.0 and xt[a] > lim) or (G[i, a] < 0.0 and xt[a] < lim):
                                xt[a] = lim
            if _inside(G, h, xt):
                if _mono_value(c, exps, xt, pw) < f:
                    improved = True
                    break
                if small:
                    break
            t *= 0.5
        if not improved:
            break
        for a in range(3):
            out[a] = xt[a]
        f = _mono_derivs(c, exps, out, g, H, pw)
    return f


# --- the driver ----------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def run_chunk(points, conn, ids, start, stop, cptr, cidx_, cval, col_a, col_b, col_w, col_off, xp, xi, xj, xw, dp,
               di, dj, dw, consts, sizes, S, Snz, nchildren, cmaps, bptr, bidx, bvert, ctrl, vidx, cidx, Mptr, Midx,
               Mval, exps, G, h,
               fdim, fslot, fexp, fcoef, nctrl, nx, rtol, flat_rtol, max_depth, max_iter, polish_iter, cap,
               o_lower, o_value, o_argmin, o_err, o_scale, o_corner, o_depth, o_closed, o_flat, o_k, o_boxes,
               o_lowroot, o_size):
    """The kernel on the cells ids[start:stop] (outputs at the same positions), with scratch of its own."""
    n = conn.shape[1]
    nb = ctrl.shape[0]
    nf = sizes.shape[0]
    maxn = S.shape[2]
    nchild = cmaps.shape[0]
    ncol = col_a.shape[0]
    D = np.empty((n, 3))
    Pc = np.empty((nctrl, 3))
    eP = np.empty((nctrl, 3))
    col = np.empty((ncol, 3))
    X = np.empty((nx, 3))
    b = np.empty(nb)
    A = np.empty((3, 3))
    E = np.empty((3, 3))
    bc = np.empty((cap, nb))
    bmap = np.empty((cap, 3, 4))
    blow = np.empty(cap)
    bdepth = np.empty(cap, dtype=np.int64)
    kids = np.empty((nchild, nb))
    work = np.empty((nchild, nb))
    pmap = np.empty((3, 4))
    cmap = np.empty((3, 4))
    W = np.empty((nf, maxn))
    xs = np.empty(3)
    argmin = np.empty(3)
    x = np.empty(3)
    pc = np.empty(nb)
    pw = np.empty((3, max(8, exps.max() + 1)))  # powers up to the largest exponent
    Q = np.empty((3, 3))
    Z = np.empty((3, 3))
    Hr = np.empty((3, 3))
    Lc = np.zeros((3, 3))
    v3 = np.empty(3)
    g3 = np.empty(3)
    H3 = np.empty((3, 3))
    gr = np.empty(3)
    y3 = np.empty(3)
    st3 = np.empty(3)
    xt = np.empty(3)
    tri = np.empty(nb)  # the subdivision's scratch: a slab of a line factor's coefficients
    TW = np.zeros((3, maxn))
    TWd = np.zeros(maxn)
    tloc = np.zeros(3)
    TF3 = np.zeros((4, 3))
    TF33 = np.zeros((4, 3, 3))
    TI3 = np.zeros((2, 3), dtype=np.int64)
    # one tet factor of positive degree (the tetrahedra): bisection (_refine_simplex), its boxes' vertices in bv
    simplex = nf == 1 and fdim[0] == 3 and nb > 1
    bv = np.empty((cap if simplex else 1, 4, 3))
    pv = np.empty((4, 3))
    line_only = True  # the second-order bound is implemented for products of lines (hexahedra, pyramids)
    for k in range(nf):
        if fdim[k] != 1:
            line_only = False
    blk = 64  # the coefficients of this many cells at a time, in their own loop (see _block_coefficients)
    Bb = np.empty((blk, nb))
    Berr = np.empty(blk)
    Bk = np.empty(blk, dtype=np.int64)
    Bsize = np.empty(blk)
    Bdeg = np.empty(blk, dtype=np.bool_)
    for t in range(start, stop):
        j = (t - start) % blk
        if j == 0:
            _block_coefficients(points, conn, ids, t, min(t + blk, stop), cptr, cidx_, cval, col_a, col_b, col_w,
                                col_off, xp, xi, xj, xw, dp, di, dj, dw, consts, D, Pc, eP, col, X, b, A, E, Bb, Berr,
                                Bk, Bsize, Bdeg)
        for i in range(nb):
            b[i] = Bb[j, i]
        err, k, size, degenerate = Berr[j], Bk[j], Bsize[j], Bdeg[j]
        scale = 0.0
        lo = np.inf
        for i in range(nb):
            ab = abs(b[i])
            if ab > scale:
                scale = ab
            if b[i] < lo:
                lo = b[i]
        corner = np.inf
        for j in range(cidx.shape[0]):
            if b[cidx[j]] < corner:
                corner = b[cidx[j]]
        upper = np.inf
        best_v = 0
        for j in range(vidx.shape[0]):
            if b[vidx[j]] < upper:
                upper = b[vidx[j]]
                best_v = vidx[j]
        for a in range(3):
            argmin[a] = ctrl[best_v, a]
        o_scale[t] = scale
        o_corner[t] = corner
        o_k[t] = k
        o_size[t] = size
        o_lowroot[t] = lo - err
        # flat: det J nowhere larger than flat_rtol times the size of its terms; where those terms are near the
        # subnormal range float64 cannot tell (that is not flatness: exact arithmetic decides such cells)
        flat = degenerate or (size > 2.0**-900 and scale <= flat_rtol * size)
        o_flat[t] = flat
        tol = rtol * scale
        if 4.0 * err > tol:
            tol = 4.0 * err
        lower = lo - err
        depth = 0
        closed = lower >= upper - tol
        boxes = 0
        value = upper
        verr = err
        if flat:
            closed = False
        elif not closed:
            # polish first, from the best vertex: a near-optimal value from the start prunes boxes at once
            verr = err + consts[4] * U * scale + consts[5] * ETA
            _polish(b, argmin, Mptr, Midx, Mval, exps, G, h, polish_iter, x, pc, pw, Q, Z, Hr, Lc, v3, g3, H3, gr, y3,
                    st3, xt)
            v_new = _eval_bernstein(b, x, fdim, fslot, fexp, fcoef, sizes, W, xs)
            if v_new < value:
                value = v_new
                for a in range(3):
                    argmin[a] = x[a]
            level_err = consts[2] * U * scale + consts[3] * ETA
            for a in range(3):
                x[a] = argmin[a]
            if simplex:  # three bisections per level of the 8-way split: the same depth and budget in volume
                lower, upper, depth, closed, boxes = _refine_simplex(b, err, level_err, tol, value, x, 3 * max_depth,
                                                                     SIMPLEX_ITER * max_iter, bptr, bidx, bvert, bc,
                                                                     bv, blow, bdepth, kids, pv, tri)
            else:
                lower, upper, depth, closed, boxes = _refine(b, err, level_err, tol, value, x, max_depth, max_iter, S,
                                                             Snz, nchildren, sizes, fdim, cmaps, ctrl, vidx, bc, bmap,
                                                             blow, bdepth, kids, work, pmap, cmap, tri, line_only, TW,
                                                             TWd, tloc, TF3, TF33, TI3)
            if depth == 0:
                depth = 1  # the point may have left the root's vertices: evaluated, not a coefficient
            # the search found a lower vertex than the polished point: polish from there (a box vertex is exact
            # to 53 bits of depth; beyond, a rounded midpoint might leave the element: then it is not used)
            if upper < value and _inside(G, h, x):
                _polish(b, x, Mptr, Midx, Mval, exps, G, h, polish_iter, st3, pc, pw, Q, Z, Hr, Lc, v3, g3, H3, gr, y3,
                        xs, xt)
                v1 = _eval_bernstein(b, x, fdim, fslot, fexp, fcoef, sizes, W, xs)
                v2 = _eval_bernstein(b, st3, fdim, fslot, fexp, fcoef, sizes, W, xs)
                if v2 < v1:
                    for a in range(3):
                        x[a] = st3[a]
                    v1 = v2
                if v1 < value:
                    value = v1
                    for a in range(3):
                        argmin[a] = x[a]
        if lower > value + verr:
            lower = value + verr  # a lower bound never exceeds a value (only rounding could say so)
        o_lower[t] = lower
        o_value[t] = value
        o_err[t] = verr
        for a in range(3):
            o_argmin[t, a] = argmin[a]
        o_depth[t] = depth
        o_closed[t] = closed
        o_boxes[t] = boxes


@njit(cache=True, nogil=True)
def coefficients_chunk(points, conn, ids, start, stop, cptr, cidx_, cval, col_a, col_b, col_w, col_off, xp, xi, xj,
                        xw, dp, di, dj, dw, consts, nctrl, nx, o_b, o_err, o_k, o_size):
    n = conn.shape[1]
    nb = o_b.shape[1]
    ncol = col_a.shape[0]
    D = np.empty((n, 3))
    Pc = np.empty((nctrl, 3))
    eP = np.empty((nctrl, 3))
    col = np.empty((ncol, 3))
    X = np.empty((nx, 3))
    b = np.empty(nb)
    A = np.empty((3, 3))
    E = np.empty((3, 3))
    deg = np.empty(stop - start, dtype=np.bool_)
    _block_coefficients(points, conn, ids, start, stop, cptr, cidx_, cval, col_a, col_b, col_w, col_off, xp, xi, xj,
                        xw, dp, di, dj, dw, consts, D, Pc, eP, col, X, b, A, E, o_b[start:stop], o_err[start:stop],
                        o_k[start:stop], o_size[start:stop], deg)


@njit(cache=True, nogil=True)
def evaluate(b, X, fdim, fslot, fexp, fcoef, sizes, maxn, out):
    W = np.empty((sizes.shape[0], maxn))
    xs = np.empty(3)
    for m in range(b.shape[0]):
        out[m] = _eval_bernstein(b[m], X[m], fdim, fslot, fexp, fcoef, sizes, W, xs)


@njit(cache=True, nogil=True)
def polish_many(b, X0, Mptr, Midx, Mval, exps, G, h, iterations, fdim, fslot, fexp, fcoef, sizes, maxn, out, vals):
    nb = b.shape[1]
    pc = np.empty(nb)
    pw = np.empty((3, max(8, exps.max() + 1)))  # powers up to the largest exponent
    Q = np.empty((3, 3))
    Z = np.empty((3, 3))
    Hr = np.empty((3, 3))
    Lc = np.zeros((3, 3))
    v3 = np.empty(3)
    g3 = np.empty(3)
    H3 = np.empty((3, 3))
    gr = np.empty(3)
    y3 = np.empty(3)
    st3 = np.empty(3)
    xt = np.empty(3)
    x = np.empty(3)
    W = np.empty((sizes.shape[0], maxn))
    xs = np.empty(3)
    for m in range(b.shape[0]):
        _polish(b[m], X0[m], Mptr, Midx, Mval, exps, G, h, iterations, x, pc, pw, Q, Z, Hr, Lc, v3, g3, H3, gr, y3, st3,
                xt)
        v_new = _eval_bernstein(b[m], x, fdim, fslot, fexp, fcoef, sizes, W, xs)
        v_old = _eval_bernstein(b[m], X0[m], fdim, fslot, fexp, fcoef, sizes, W, xs)
        if v_new < v_old:
            for a in range(3):
                out[m, a] = x[a]
            vals[m] = v_new
        else:
            for a in range(3):
                out[m, a] = X0[m, a]
            vals[m] = v_old


@njit(cache=True, nogil=True)
def scaled_jacobian_chunk(points, conn, ids, start, stop, vptr, vnode, vw, samp, ssign, factor, grouped, reflect,
                          sid, out):
    """Verdict's scaled Jacobian of the cells ids[start:stop] (see :mod:`hexsos_plugins.cells.quality`) from the sample
    matrices' distinct columns (up to sign): vector v is sum_q vw[q] x_vnode[q] over q in vptr[v]:vptr[v + 1]
    (in node order, as the matrix product), and sample k has the columns ssign[k, d] * vector samp[k, d]; a
    column shared by several samples (a hexahedron's edge) is formed and measured once. ``grouped``: samples
    come in fours, the corners of a tet, whose value is det / the largest of their edge products (tetra,
    pyramid); else each sample is det / its own edge product (hexahedron, wedge). ``reflect``: values above 1
    become 2 - v (pyramids, as Verdict). The minimum over samples goes to out[t]. ``sid``: the type's generated
    code (kernel/generated.py, the same operations straight-line, about 4x faster), 0 for these loops."""
    if _generated_sj(sid, points, conn, ids, start, stop, out):
        return
    K = samp.shape[0]
    nv = vptr.shape[0] - 1
    tiny = 2.2250738585072014e-308
    Vx = np.empty((nv, 3))
    Ln = np.empty(nv)
    for t in range(start, stop):
        m = ids[t]
        for v in range(nv):
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            for q in range(vptr[v], vptr[v + 1]):
                w = vw[q]
                node = conn[m, vnode[q]]
                s0 += w * points[node, 0]
                s1 += w * points[node, 1]
                s2 += w * points[node, 2]
            Vx[v, 0] = s0
            Vx[v, 1] = s1
            Vx[v, 2] = s2
            Ln[v] = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        # a cell far from unit size (its longest vector outside [SJ_LOW, SJ_HIGH]: 1e-140, 1e140): the vectors
        # times the power of two that takes their largest component into [0.5, 1), exact, so the value is the one
        # at unit size bit for bit, where the edge products would underflow (at 1e-140 every cell read 0) or
        # overflow. Inside, as they are (the same numbers: the scaling is exact)
        lmax = 0.0
        for v in range(nv):
            if Ln[v] > lmax:
                lmax = Ln[v]
        if not (SJ_LOW <= lmax <= SJ_HIGH):
            ext = 0.0
            for v in range(nv):
                for a in range(3):
                    x = abs(Vx[v, a])
                    if x > ext:
                        ext = x
            if 0.0 < ext < np.inf:
                e2 = math.frexp(ext)[1]  # int32, not the samples' index k below (one variable, one type: pycc)
                f1 = math.ldexp(1.0, -e2 // 2)  # 2**-e2 in two factors, each a double for every e2
                f2 = math.ldexp(1.0, -e2 - (-e2 // 2))
                for v in range(nv):
                    for a in range(3):
                        Vx[v, a] = Vx[v, a] * f1 * f2
                    Ln[v] = math.sqrt(Vx[v, 0] * Vx[v, 0] + Vx[v, 1] * Vx[v, 1] + Vx[v, 2] * Vx[v, 2])
        best = np.inf
        gdet = 0.0
        gbig = 0.0
        for k in range(K):
            a = samp[k, 0]
            b = samp[k, 1]
            c = samp[k, 2]
            # det[s_a V_a, s_b V_b, s_c V_c] = s_a s_b s_c det[V_a, V_b, V_c]: a sign flip is exact
            det = (Vx[a, 0] * (Vx[b, 1] * Vx[c, 2] - Vx[b, 2] * Vx[c, 1])
                   - Vx[b, 0] * (Vx[a, 1] * Vx[c, 2] - Vx[a, 2] * Vx[c, 1])
                   + Vx[c, 0] * (Vx[a, 1] * Vx[b, 2] - Vx[a, 2] * Vx[b, 1])) * ssign[k]
            lengths = Ln[a] * Ln[b] * Ln[c]
            if grouped:
                if k % 4 == 0:
                    gdet = det
                    gbig = lengths
                elif lengths > gbig:
                    gbig = lengths
                if k % 4 == 3:
                    val = factor * gdet / gbig if gbig > tiny else 0.0
                    if val < best:
                        best = val
            else:
                val = factor * det / lengths if lengths > tiny else 0.0
                if val < best:
                    best = val
        if reflect and best > 1.0:
            best = 2.0 - best
        out[t] = best


@njit(cache=True, nogil=True)
def det_at_chunk(points, conn, ids, start, stop, dN, out):
    """det J of the cells ids[start:stop] at one reference point, from dN (n, 3), the shape-function derivatives
    there (the measure's columns for pyramids): J[a, d] = sum_i dN[i, d] x_i[a]. No rounding bound: a sign test
    (the orientation of a file's node order), never a certificate."""
    E = np.empty((3, 3))
    for t in range(start, stop):
        m = ids[t]
        for a in range(3):
            for d in range(3):
                E[a, d] = 0.0
        for i in range(conn.shape[1]):  # zero weights skipped
            node = conn[m, i]
            for d in range(3):
                w = dN[i, d]
                if w != 0.0:
                    for a in range(3):
                        E[a, d] += w * points[node, a]
        out[t] = (E[0, 0] * (E[1, 1] * E[2, 2] - E[1, 2] * E[2, 1]) - E[0, 1] * (E[1, 0] * E[2, 2] - E[1, 2] * E[2, 0])
                  + E[0, 2] * (E[1, 0] * E[2, 1] - E[1, 1] * E[2, 0]))


@njit(cache=True, nogil=True, inline="always")
def _world_value(x, k, up, dn, fast, down):
    """x 2^k, exact where representable, else the nearest float of the same sign (``down`` false: a value) or
    the largest float below (``down``: a lower bound), and whether it is unrepresentable (overflow; a value that
    underflows to 0; a lower bound below the normal range that had to be rounded); up, dn = 2^k, 2^-k when
    ``fast`` (|k| <= 1022)."""
    if fast:  # a product by a power of two is one correctly rounded operation, as ldexp
        w = x * up
        back = w * dn
    else:
        w = math.ldexp(x, k)
        back = math.ldexp(w, -k)
    b = False
    if math.isfinite(w):
        if back != x:  # inexact: w rounded (in the subnormal range)
            if down:
                if back > x:
                    w = np.nextafter(w, -np.inf)
                b = abs(w) < 2.2250738585072014e-308
            elif w == 0.0:
                w = math.copysign(5e-324, x)
                b = True
    elif math.isfinite(x):  # overflow
        if down:
            w = 1.7976931348623157e308 if x > 0.0 else -np.inf
        else:
            w = math.copysign(1.7976931348623157e308, x)
        b = True
    return w, b


@njit(cache=True, nogil=True)
def finish_chunk(value, lower, err, corner, scale, kexp, flat, closed, start, stop, status, near, bad):
    """The verdicts of cells start:stop from their brackets (scaled units), then their numbers in world units,
    in place: status 1 where lower > 0, 0 where value + err <= 0, -1 otherwise and where flat; near where
    undecided but not flat with the bracket closed or the value within 64 err of 0 (for the exact decision);
    value, corner and scale to the nearest float (_world_value), lower rounded down, bad where value or lower is
    not representable."""
    last = -(1 << 40)
    up = 1.0
    dn = 1.0
    fast = False
    for i in range(start, stop):
        x = value[i]
        st = -1
        if lower[i] > 0.0:
            st = 1
        if x + err[i] <= 0.0:
            st = 0
        if flat[i]:
            st = -1
        status[i] = st
        near[i] = st == -1 and not flat[i] and (closed[i] or abs(x) <= 64.0 * err[i])
        k = 3 * kexp[i]
        if k != last:  # neighbouring cells share their exponent: the powers of two once per run of them
            last = k
            fast = -1022 <= k <= 1022
            if fast:
                up = math.ldexp(1.0, k)
                dn = math.ldexp(1.0, -k)
        value[i], b1 = _world_value(x, k, up, dn, fast, False)
        lower[i], b2 = _world_value(lower[i], k, up, dn, fast, True)
        corner[i], _ = _world_value(corner[i], k, up, dn, fast, False)
        scale[i], _ = _world_value(scale[i], k, up, dn, fast, False)
        bad[i] = b1 or b2

