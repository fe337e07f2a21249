"""Certified brackets ``lower <= min det J <= upper`` by Bernstein bounds and branch-and-bound.

On a box of the parameter cube every value of det J is a convex combination of the box's 27 Bernstein
coefficients, so the smallest coefficient is a lower bound, and the corner coefficients are values.
Halving a box (de Casteljau at 1/2 on each axis) gives its 8 children's coefficients; the bounds
converge quadratically in the box size. :func:`bracket` refines, for many hexes at once, only the boxes
that could still hold a value below the best one found minus the tolerance, so each hex ends with a
certified bracket of width <= ``rtol * max|B|`` (or stops at ``max_depth`` / ``max_boxes``, open).

Rounding. The coefficients of the root box carry a rigorous error bound ``err`` (see
:func:`hexsos_plugins.hexahedron.det_bernstein`). A child coefficient is a convex combination of its
parent's (weights in {1, 1/2, 1/4, ...}, exact in binary) summed in 27 terms, which adds at most
``27 u max|B|`` per level; we use ``err_d = err + 32 d u max|B|`` at depth d. Lower bounds subtract
``err_d``, so ``lower`` is rigorous for the exact polynomial of the float vertex coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .hexahedron import UNIT_ROUND, det_at_bernstein, det_derivatives

__all__ = ["Bracket", "bracket", "subdivision_matrix", "polish", "CORNER_COEFFS"]

#: Indices into the 27 coefficients of the 8 corner control points, in VTK node order.
CORNER_COEFFS = np.array([0, 18, 24, 6, 2, 20, 26, 8])
_CORNER_UVW = np.array(
    [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)], dtype=float
)
# Child c = 4 i + 2 j + k covers [i/2, (i+1)/2] x [j/2, ...] x [k/2, ...] of its parent.
_CHILD_OFFSET = np.array([((c >> 2) & 1, (c >> 1) & 1, c & 1) for c in range(8)], dtype=float)


def subdivision_matrix() -> np.ndarray:
    """The (27, 216) matrix T with ``children = coeffs @ T``: row-vector coefficients (K, 27) of K boxes
    to (K, 8 * 27), child c's coefficients at columns ``27 c .. 27 c + 26``. Entries are dyadic."""
    S = [np.array([[1, 0, 0], [0.5, 0.5, 0], [0.25, 0.5, 0.25]]),
         np.array([[0.25, 0.5, 0.25], [0, 0.5, 0.5], [0, 0, 1]])]
    T = np.empty((27, 216))
    for c in range(8):
        i, j, k = (c >> 2) & 1, (c >> 1) & 1, c & 1
        T[:, 27 * c : 27 * c + 27] = np.kron(np.kron(S[i], S[j]), S[k]).T
    return T


# Inside the branch-and-bound, each box's 27 coefficients are kept as a row with the 8 corner
# coefficients first (so the values at the corners are the contiguous slice [:, :8]).
_ROW = np.r_[CORNER_COEFFS, np.setdiff1d(np.arange(27), CORNER_COEFFS)]
_T = subdivision_matrix()[_ROW][:, (27 * np.arange(8)[:, None] + _ROW[None, :]).ravel()]
_TT = np.ascontiguousarray(_T.T)  # (216, 27): column-vector form
_LEVEL_ERR = 32.0 * UNIT_ROUND
_BB_CHUNK = 4096


@dataclass
class Bracket:
    """Per hex: ``lower <= min det J <= upper``, ``upper`` = det J at ``argmin`` (from the coefficients)."""

    lower: np.ndarray  # (M,) rigorous lower bound (rounding included)
    upper: np.ndarray  # (M,) value at argmin, from a corner coefficient (within err of exact)
    argmin: np.ndarray  # (M, 3)
    depth: np.ndarray  # (M,) int, subdivision depth reached (0: settled by the root coefficients)
    closed: np.ndarray  # (M,) bool, upper - lower <= tol
    tol: np.ndarray  # (M,) the absolute tolerance used
    boxes: int  # boxes examined in all


def bracket(B, err, *, rtol: float = 1e-9, max_depth: int = 30, max_boxes: int = 64, stats=None) -> Bracket:
    """Certified bracket of min det J over [0, 1]^3 for each hex, by vectorized branch-and-bound.

    Parameters
    ----------
    B : array_like, shape (27, M)
        Bernstein coefficients (see :func:`hexsos_plugins.hexahedron.det_bernstein`).
    err : array_like, shape (M,)
        Rigorous bound on the rounding error of ``B``.
    rtol : float, keyword-only
        Target bracket width relative to ``max|B|`` (the hex's scale). Default 1e-9.
    max_depth : int, keyword-only
        Deepest subdivision level (box side ``2**-max_depth``). Default 30.
    max_boxes : int, keyword-only
        Most boxes kept per hex and level; the rest are folded into the lower bound. Default 64.
    stats : dict, optional
        The summaries :func:`~hexsos_plugins.hexahedron.det_bernstein` fills in (saves recomputing them).

    Returns
    -------
    Bracket
    """
    B = np.asarray(B, dtype=np.float64)
    err = np.asarray(err, dtype=np.float64)
    M = B.shape[1]
    if stats is None:
        corners = B[CORNER_COEFFS]  # (8, M)
        k = corners.argmin(axis=0)
        stats = {"max_abs": np.abs(B).max(axis=0), "min": B.min(axis=0), "corner_arg": k,
                 "corner_min": corners[k, np.arange(M)]}
    scale = stats["max_abs"]
    tol = np.maximum(rtol * scale, 4.0 * err)
    upper = stats["corner_min"].copy()
    argmin = _CORNER_UVW[stats["corner_arg"]]
    lower = stats["min"] - err
    depth = np.zeros(M, dtype=np.int64)
    open_ = np.flatnonzero(lower < upper - tol)
    boxes = 0
    for s in range(0, open_.size, _BB_CHUNK):
        ids = open_[s : s + _BB_CHUNK]
        lo_, up_, am_, dp_, nb = _refine(B[:, ids], err[ids], scale[ids], tol[ids], upper[ids], argmin[ids],
                                         max_depth, max_boxes)
        lower[ids], upper[ids], argmin[ids], depth[ids] = lo_, up_, am_, dp_
        boxes += nb
    lower = np.minimum(lower, upper)  # a lower bound never exceeds a value (only rounding could say so)
    closed = upper - lower <= tol
    return Bracket(lower=lower, upper=upper, argmin=argmin, depth=depth, closed=closed, tol=tol, boxes=boxes)


def _refine(B, err, scale, tol, upper, argmin, max_depth, max_boxes):
    """Branch-and-bound on a chunk of m hexes; returns (lower, upper, argmin, depth, boxes).

    Boxes are columns of a (27, K) array (structure-of-arrays, corners in rows 0..7), sorted by hex.
    """
    m = B.shape[1]
    lower = np.full(m, np.inf)
    depth = np.zeros(m, dtype=np.int64)
    level_err = _LEVEL_ERR * scale
    hid = np.arange(m)
    C = np.ascontiguousarray(B[_ROW])  # (27, K)
    org = np.zeros((m, 3))
    h = 1.0
    boxes = 0
    for d in range(1, max_depth + 1):
        h *= 0.5
        K = hid.size
        Ck = (_TT @ C).reshape(8, 27, K)  # [child, coefficient, parent]
        boxes += 8 * K
        cmin = Ck[:, :8].min(axis=1)  # (8, K) best corner value of each child
        lo = np.minimum(cmin, Ck[:, 8:].min(axis=1))
        lo -= err[hid] + d * level_err[hid]

        starts = np.flatnonzero(np.concatenate(([True], hid[1:] != hid[:-1])))
        uh = hid[starts]
        depth[uh] = d
        pbest = cmin.min(axis=0)  # (K,) per parent
        seg = np.minimum.reduceat(pbest, starts)
        better = seg < upper[uh]
        if better.any():
            seg_of = np.repeat(np.arange(starts.size), np.diff(np.append(starts, K)))
            hit = np.flatnonzero(better[seg_of] & (pbest == seg[seg_of]))
            first = hit[np.unique(seg_of[hit], return_index=True)[1]]  # one parent per improved hex
            c = cmin[:, first].argmin(axis=0)
            corner = Ck[c, :8, first].argmin(axis=1)
            upper[hid[first]] = seg[seg_of[first]]
            argmin[hid[first]] = org[first] + h * (_CHILD_OFFSET[c] + _CORNER_UVW[corner])

        # prune children that cannot hold a value below upper - tol; their bounds go into lower
        keep = lo < (upper - tol)[hid]
        dropped = np.where(keep, np.inf, lo).min(axis=0)
        np.minimum.at(lower, uh, np.minimum.reduceat(dropped, starts))
        k, c = np.nonzero(keep.T)  # sorted by parent, hence by hex
        if k.size == 0:
            hid = k
            break
        hid = hid[k]
        lo = lo[c, k]
        C = np.ascontiguousarray(Ck[c, :, k].T)
        org = org[k] + h * _CHILD_OFFSET[c]

        # cap the boxes per hex: keep the max_boxes with the lowest bounds (a boolean mask keeps the order)
        starts = np.flatnonzero(np.concatenate(([True], hid[1:] != hid[:-1])))
        counts = np.diff(np.append(starts, hid.size))
        if counts.max() > max_boxes:
            order = np.lexsort((lo, hid))
            rank = np.arange(hid.size) - np.repeat(starts, counts)
            keep = np.zeros(hid.size, dtype=bool)
            keep[order[rank < max_boxes]] = True
            np.minimum.at(lower, hid[~keep], lo[~keep])
            hid, C, org, lo = hid[keep], C[:, keep], org[keep], lo[keep]
    if hid.size:  # depth exhausted: the live boxes' bounds go into the lower bound
        np.minimum.at(lower, hid, lo)
    return lower, upper, argmin, depth, boxes


def polish(B, uvw, *, iterations: int = 20):
    """Improve minimizers of det J on [0, 1]^3 by bounded local optimization (never makes them worse).

    Each iteration takes the better of two moves, when it lowers det J: a projected Newton step on the
    coordinates not held at a bound by the gradient, and the best exact move along one axis (det J is
    a quadratic in each of u, v, w, so that move is exact). Points stop when neither move helps.

    Parameters
    ----------
    B : array_like, shape (27, M)
    uvw : array_like, shape (M, 3), starting points in [0, 1]^3
    iterations : int, keyword-only, the most iterations. Default 20.

    Returns
    -------
    uvw : ndarray (M, 3)
    value : ndarray (M,), det J at uvw (from B)
    """
    B = np.asarray(B, dtype=np.float64)
    x = np.clip(np.array(uvw, dtype=np.float64), 0.0, 1.0).reshape(-1, 3)
    f = det_at_bernstein(B, x)
    live = np.arange(x.shape[0])
    eye = np.eye(3)
    for _ in range(iterations):
        if live.size == 0:
            break
        Bl, xl = B[:, live], x[live]
        fl, g, H = det_derivatives(Bl, xl)
        n = live.size
        # best exact single-axis move: f(x + t e_i) = f + g_i t + H_ii t^2 / 2, t in [-x_i, 1 - x_i]
        lo, hi = -xl, 1.0 - xl
        Hd = np.einsum("mii->mi", H)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_in = np.where(Hd > 0, np.clip(-g / Hd, lo, hi), lo)
        cand = np.stack([lo, hi, t_in], axis=-1)  # (n, 3 axes, 3 candidates)
        dec = g[:, :, None] * cand + 0.5 * Hd[:, :, None] * cand**2
        j = dec.reshape(n, 9).argmin(axis=1)
        ax, which = j // 3, j % 3
        xc = xl.copy()
        xc[np.arange(n), ax] = np.clip(xl[np.arange(n), ax] + cand[np.arange(n), ax, which], 0.0, 1.0)
        # projected Newton on the free coordinates
        active = ((xl <= 0.0) & (g > 0)) | ((xl >= 1.0) & (g < 0))
        free = ~active
        Hf = np.where(free[:, :, None] & free[:, None, :], H, 0.0) + active[:, :, None] * eye
        gf = np.where(free, g, 0.0)
        ev = np.linalg.eigvalsh(Hf)
        pd = ev[:, 0] > 1e-12 * np.maximum(np.abs(ev[:, -1]), 1e-300)
        step = np.zeros_like(xl)
        if pd.any():
            step[pd] = -np.linalg.solve(Hf[pd], gf[pd][:, :, None])[:, :, 0]
        xn = np.clip(xl + step, 0.0, 1.0)
        fc = det_at_bernstein(Bl, xc)
        fn = det_at_bernstein(Bl, xn)
        use_n = fn < fc
        xb = np.where(use_n[:, None], xn, xc)
        fb = np.where(use_n, fn, fc)
        improved = fb < fl
        x[live[improved]] = xb[improved]
        f[live[improved]] = fb[improved]
        live = live[improved]
    return x, f
