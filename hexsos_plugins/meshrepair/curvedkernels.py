"""Compiled (numba) loops of :mod:`hexsos_plugins.meshrepair.curved`: the Bernstein coefficients of det J of
curved cells of any type, and the barrier on them with its gradient.

Per cell, det J is sampled at the ``nq`` control points of its Bernstein space (``dN`` (nq, n, 3): the shape
functions' derivatives there), and the coefficients are ``b = T d`` with ``T = T_1 x T_2 x T_3`` (Kronecker
product over the factors of the reference element, lines, triangles, tetrahedra: each ``T_f`` the inverse of its
factor's Bernstein collocation matrix, ``Tf`` (3, m, m) padded, ``sizes`` (3,) with 1 for absent factors;
:func:`hexsos_plugins.meshrepair.curved.coefficient_tables`). These numbers steer the optimizer only; validity is
decided by the kernel (:func:`hexsos_plugins.check`), never here. IEEE double precision, no fast-math.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types

from .kernels import any_uncached, cofactor, compile_each


@njit(cache=True)
def _kron_apply(Tf, sizes, x, y, w, transpose):
    """y = (T_1 x T_2 x T_3) x (or its transpose), x and y of length n1 n2 n3 (w: scratch of that length)."""
    n1, n2, n3 = sizes[0], sizes[1], sizes[2]
    # along axis 2
    for i in range(n1):
        for j in range(n2):
            base = (i * n2 + j) * n3
            for k in range(n3):
                acc = 0.0
                for l in range(n3):
                    acc += (Tf[2, l, k] if transpose else Tf[2, k, l]) * x[base + l]
                w[base + k] = acc
    # along axis 1
    for i in range(n1):
        for k in range(n3):
            for j in range(n2):
                acc = 0.0
                for l in range(n2):
                    acc += (Tf[1, l, j] if transpose else Tf[1, j, l]) * w[(i * n2 + l) * n3 + k]
                y[(i * n2 + j) * n3 + k] = acc
    # along axis 0
    for j in range(n2):
        for k in range(n3):
            for i in range(n1):
                acc = 0.0
                for l in range(n1):
                    acc += (Tf[0, l, i] if transpose else Tf[0, i, l]) * y[(l * n2 + j) * n3 + k]
                w[(i * n2 + j) * n3 + k] = acc
    for t in range(n1 * n2 * n3):
        y[t] = w[t]


@njit(cache=True)
def _dets(P, conn, c, dN, X, d, Cs):
    n = conn.shape[1]
    nq = dN.shape[0]
    for i in range(n):
        v = conn[c, i]
        X[i, 0] = P[v, 0]
        X[i, 1] = P[v, 1]
        X[i, 2] = P[v, 2]
    J = np.empty((3, 3))
    C = np.empty((3, 3))
    for q in range(nq):
        for a in range(3):
            for e in range(3):
                J[a, e] = 0.0
        for i in range(n):
            x0, x1, x2 = X[i, 0], X[i, 1], X[i, 2]
            for e in range(3):
                g = dN[q, i, e]
                J[0, e] += x0 * g
                J[1, e] += x1 * g
                J[2, e] += x2 * g
        d[q] = cofactor(J, C)
        for a in range(3):
            for e in range(3):
                Cs[q, a, e] = C[a, e]


@njit(cache=True)
def coefficients(P, conn, cells, dN, Tf, sizes, out):
    """out[k] = the Bernstein coefficients (nb,) of det J of cell ``cells[k]``."""
    nq = dN.shape[0]
    n = conn.shape[1]
    X = np.empty((n, 3))
    d = np.empty(nq)
    Cs = np.empty((nq, 3, 3))
    b = np.empty(nq)
    w = np.empty(nq)
    for k in range(cells.shape[0]):
        _dets(P, conn, cells[k], dN, X, d, Cs)
        _kron_apply(Tf, sizes, d, b, w, False)
        for i in range(nq):
            out[k, i] = b[i]


@njit(cache=True, inline="always")
def _chi(r, eps):
    # (r + sqrt(r^2 + eps^2)) / 2 without cancellation for r << 0, and its derivative
    s = np.sqrt(r * r + eps * eps)
    if r >= 0.0:
        return 0.5 * (r + s), 0.5 * (1.0 + r / s)
    ch = 0.5 * eps * eps / (s - r)
    return ch, ch / s


@njit(cache=True)
def barrier(P, conn, cells, dN, Tf, sizes, scale, weight, eps, gcell, want_grad, rcell):
    """sum over cells k of weight[k] / nb * sum_i f(b_ki / scale[k]), f(r) = (1 + r^2) / chi(r, eps), chi(r, eps)
    = (r + sqrt(r^2 + eps^2)) / 2 (Garanzha et al.'s regularization: finite everywhere, a barrier at r = 0 as eps
    -> 0, least at r = 1). With ``want_grad`` the gradient of each cell's term with respect to its nodes goes to
    gcell (K, n, 3); each cell's least r goes to rcell (K,). Returns (energy, min r)."""
    K = cells.shape[0]
    nq = dN.shape[0]
    n = conn.shape[1]
    X = np.empty((n, 3))
    d = np.empty(nq)
    Cs = np.empty((nq, 3, 3))
    b = np.empty(nq)
    w = np.empty(nq)
    fp = np.empty(nq)
    gq = np.empty(nq)
    E = 0.0
    rmin = np.inf
    for k in range(K):
        _dets(P, conn, cells[k], dN, X, d, Cs)
        _kron_apply(Tf, sizes, d, b, w, False)
        wk = weight[k] / nq
        s = scale[k]
        e = 0.0
        for i in range(nq):
            r = b[i] / s
            if r < rmin:
                rmin = r
            ch, dch = _chi(r, eps)
            num = 1.0 + r * r
            e += num / ch
            fp[i] = (2.0 * r * ch - num * dch) / (ch * ch) * wk / s
        E += wk * e
        rc = np.inf
        for i in range(nq):
            if b[i] / s < rc:
                rc = b[i] / s
        rcell[k] = rc
        if want_grad:
            _kron_apply(Tf, sizes, fp, gq, w, True)
            for i in range(n):
                for a in range(3):
                    gcell[k, i, a] = 0.0
            for q in range(nq):
                g = gq[q]
                for i in range(n):
                    acc0 = 0.0
                    acc1 = 0.0
                    acc2 = 0.0
                    for e3 in range(3):
                        v = dN[q, i, e3]
                        acc0 += Cs[q, 0, e3] * v
                        acc1 += Cs[q, 1, e3] * v
                        acc2 += Cs[q, 2, e3] * v
                    gcell[k, i, 0] += g * acc0
                    gcell[k, i, 1] += g * acc1
                    gcell[k, i, 2] += g * acc2
    return E, rmin


_F1, _F2, _F3 = types.float64[::1], types.float64[:, ::1], types.float64[:, :, ::1]
_I1, _I2 = types.int64[::1], types.int64[:, ::1]

#: The argument types the curved repair calls each loop with (C-contiguous float64 / int64 arrays, writable:
#: :func:`hexsos_plugins.meshrepair.curved.repair_curved` copies the caller's connectivity, so that a read-only one
#: is not a second type); the same for every cell type.
SIGNATURES = {
    "coefficients": (_F2, _I2, _I1, _F3, _F3, _I1, _F2),
    "barrier": (_F2, _I2, _I1, _F3, _F3, _I1, _F1, _F1, types.float64, _F3, types.boolean, _F1),
}


def _dispatchers():
    return [(globals()[name], sig) for name, sig in SIGNATURES.items()]


def compiles_at_first_use() -> bool:
    """Whether some loop of :data:`SIGNATURES` has nothing in numba's cache for this source yet: :func:`load`
    (the first curved repair) compiles it, once."""
    return any_uncached(_dispatchers())


def load() -> None:
    """Compile, or load from numba's cache, every loop of :data:`SIGNATURES`."""
    compile_each(_dispatchers())
