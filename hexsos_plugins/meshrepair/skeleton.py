"""The straight-sided skeleton of a curved mesh: untangle its corners first, then put the high-order nodes back.

A curved cell whose *corners* are folded (its straight-sided cell, spanned by the corners, is inverted) is hard to
untangle on the curved cell's own det J: its edges and faces bend to compensate and the barrier on hundreds of
coefficients creeps. The classic robust path, used by :func:`hexsos_plugins.meshrepair.curved.repair_curved`:

1. the linear mesh of the corners (:func:`linear_blocks`: tetra, wedge, hexahedron) is untangled where its cells
   are not positive, per group of folded cells with ``rings`` layers around them (:func:`untangle`, Garanzha et
   al.'s regularized barrier on the linear cells' Bernstein coefficients with their eps rule: eps shrinks only as
   fast as the energy falls, so the fold opens before the barrier hardens), boundary corners sliding on the
   input's curved faces;
2. the high-order nodes of every cell with a moved corner go to their straight-sided positions on the new corners
   (:func:`straight_points`) plus the curving they had in the input (the input's node minus its straight-sided
   position), boundary nodes projected back onto the input's curved faces (:func:`place_high_order`);
3. the curved optimizer then works on the high-order nodes of the cells still not positive.

>>> import numpy as np
>>> from hexsos_plugins.cells.elements import ELEMENTS
>>> R = ELEMENTS["tetra10"].reference_nodes
>>> P = 2.0 * R + 1.0                     # an affine cell: its nodes are where the straight-sided cell has them
>>> S = straight_points(P, [("tetra10", np.arange(10)[None])])
>>> bool(np.allclose(S, P))
True
"""

from __future__ import annotations

import time
from functools import lru_cache

import numpy as np

from ..cells.elements import ELEMENTS

__all__ = ["LINEAR", "linear_blocks", "straight_matrix", "straight_points", "folded_cells", "untangle",
           "place_high_order"]

#: The linear type of each movable reference element.
LINEAR = {"tet": "tetra", "prism": "wedge", "cube": "hexahedron"}


def linear_blocks(blocks) -> list:
    """Per block the (linear type, corner connectivity) of its cells; blocks of other reference elements
    (pyramids) give an empty block."""
    out = []
    for name, conn in blocks:
        el = ELEMENTS[name]
        lin = LINEAR.get(el.domain)
        if lin is None:
            out.append(("tetra", np.zeros((0, 4), dtype=np.int64)))
        else:
            out.append((lin, np.ascontiguousarray(conn[:, : el.corners], dtype=np.int64)))
    return out


@lru_cache(maxsize=None)
def straight_matrix(name: str) -> np.ndarray:
    """(n, corners): the linear cell's shape functions at the type's reference nodes (node j of a straight-sided
    cell is ``M[j] @ corners``)."""
    el = ELEMENTS[name]
    return np.ascontiguousarray(ELEMENTS[LINEAR[el.domain]].shape_functions(el.reference_nodes))


def straight_points(P, blocks) -> np.ndarray:
    """P with every high-order node of the movable cells at its position on the straight-sided cell spanned by
    the corners (the same from every cell sharing it: cells meet on straight edges and faces)."""
    S = np.array(P, dtype=np.float64, copy=True)
    for name, conn in blocks:
        el = ELEMENTS[name]
        if el.domain not in LINEAR or el.order < 2 or conn.shape[0] == 0:
            continue
        M = straight_matrix(name)
        C = P[conn[:, : el.corners]]  # (m, c, 3)
        X = np.einsum("jc,mca->mja", M[el.corners:], C)
        S[conn[:, el.corners:].ravel()] = X.reshape(-1, 3)
    return S


def folded_cells(P, lin, scale) -> list:
    """Per linear block, the cells with a Bernstein coefficient of det J <= 0 (relative to ``scale``)."""
    from .curvedcells import kernel_coefficients

    out = []
    for (name, conn), s in zip(lin, scale):
        if conn.shape[0] == 0:
            out.append(np.zeros(0, dtype=bool))
            continue
        b = kernel_coefficients(P, name, conn)
        out.append(b.min(axis=1) / s <= 1e-9)
    return out


def _chi(d, eps):
    return 0.5 * (d + np.sqrt(d * d + eps * eps))


def untangle(V, lin, scale, core, pin, bnd, *, rings=2, deadline=None, outers=60, iters=100, quality_iters=60,
             eps0=1.0, schedule="aggressive", debug=None):
    """Untangle the linear cells marked in ``core`` (per block masks); returns the new points (a region is kept
    only when fewer of its cells are folded after it, or none).

    Unknowns: the corners of the marked cells and of ``rings`` layers around them, but the ``pin`` nodes (all
    marked cells in one problem, then those still folded in one problem with a ring more, then each group still
    folded alone);
    ``bnd`` (a :class:`hexsos_plugins.meshrepair.curved.CurvedBoundary`, or None for free) lets boundary corners
    slide in their tangent planes (projected back onto the input's curved faces by the caller). The energy is
    over every linear cell touching a free node; eps starts at ``eps0`` (large: the regularized energy is smooth and
    lets the fold open in big steps), then follows ``schedule``: "aggressive" (a fifth of the most negative
    coefficient) or "garanzha" (Garanzha et al.'s rule: shrinks with the energy's relative decrease); once every cell of the energy is positive ``quality_iters`` iterations of the barrier
    give the corners some room before the high-order nodes come back."""
    from .curvedcells import cell_groups, node_cells

    N = V.shape[0]
    cells_at = node_cells(lin, N)
    V = np.array(V, dtype=np.float64, copy=True)
    # every folded cell at once first, three outer steps (most groups open in two: they share them), the rest at
    # once with a ring more, then the groups still folded one by one
    V = _untangle_group(V, lin, scale, core, pin, bnd, cells_at, rings, deadline, min(outers, 3), iters,
                        quality_iters, eps0, schedule, debug)
    left = folded_cells(V, lin, scale)
    if any((c & l).any() for c, l in zip(core, left)):  # the rest at once again, with a ring more
        V = _untangle_group(V, lin, scale, [c & l for c, l in zip(core, left)], pin, bnd, cells_at, rings + 1,
                            deadline, min(outers, 3), iters, quality_iters, eps0, schedule, debug)
        left = folded_cells(V, lin, scale)
    for comp in cell_groups([c & l for c, l in zip(core, left)], lin, N):
        if deadline is not None and time.perf_counter() > deadline:
            break
        V = _untangle_group(V, lin, scale, comp, pin, bnd, cells_at, rings + 1, deadline, outers, iters,
                            quality_iters, eps0, schedule, debug)
    return V


def _untangle_group(V, lin, scale, comp, pin, bnd, cells_at, rings, deadline, outers, iters, quality_iters, eps0,
                    schedule, debug):
    from .curvedcells import Problem, nodes_of, fast_coefficients

    N = V.shape[0]
    masks = [c.copy() for c in comp]
    for _ in range(rings):
        masks = cells_at(nodes_of(masks, lin, N))
    free = nodes_of(masks, lin, N) & ~pin
    if not free.any():
        return V
    sel = [np.flatnonzero(s) for s in cells_at(free)]

    def rcells(P):
        return [fast_coefficients(P, name, conn, sl).min(axis=1) / s[sl] if sl.size else np.zeros(0)
                for (name, conn), s, sl in zip(lin, scale, sel)]

    # the group's cells and the cells positive now must end positive; another group's folded cells in the
    # ring are that group's to untangle
    watch = [c[sl] | (r > 1e-9) for c, sl, r in zip(comp, sel, rcells(V))]
    full = []
    for c, sl, w in zip(comp, sel, watch):
        m = np.zeros(c.shape[0], dtype=bool)
        m[sl[w]] = True
        full.append(m)
    prob = Problem(V, lin, scale, sel, free, bnd, core=full)  # an outer step stops once those are positive

    def rall(P):
        return min((float(r[w].min()) for r, w in zip(rcells(P), watch) if w.any()), default=np.inf)

    def nbad(P):
        return sum(int((r <= 1e-9).sum()) for r in rcells(P))

    n0 = nbad(prob.V0)

    d = rall(prob.V0)
    eps = max(0.2 * abs(min(d, 0.0)), eps0)
    E_prev = prob.energy(np.zeros(prob.ndof), eps, grad=False)[0]
    best, since = d, 0
    for outer in range(outers):
        Vn, _, nit = prob.minimize(eps, iters, deadline, stop_positive=True)
        prob.V0 = Vn
        d = rall(Vn)
        if debug is not None:
            debug(f"skeleton: {int(sum(c.sum() for c in comp))} folded cells, {int(free.sum())} free corners, "
                  f"outer {outer}: eps {eps:.3g}, min r {d:.4g}, {nit} iterations")
        if d > 1e-9 or (deadline is not None and time.perf_counter() > deadline):
            break
        # no progress in 6 outer steps (the most negative coefficient rose by less than 1% of itself): give up
        since = 0 if d > best + 0.01 * abs(best) else since + 1
        best = max(best, d)
        if since >= 6 or eps < 1e-5:  # or the barrier is hard and the cell still folded: a structural zero
            break
        if schedule == "garanzha":
            E = prob.energy(np.zeros(prob.ndof), eps, grad=False)[0]
            sigma = max(1.0 - E / E_prev, 0.1)
            mu = (1.0 - sigma) * _chi(d, eps)
            eps = 2.0 * np.sqrt(mu * (mu - d)) if d < mu else 1e-9
            E_prev = prob.energy(np.zeros(prob.ndof), eps, grad=False)[0]
        else:
            eps = np.sqrt(1e-12 + 0.04 * min(d, 0.0) ** 2)
    if d > 1e-9 and quality_iters:
        Vq, _, _ = prob.minimize(1e-9, quality_iters, deadline)
        if rall(Vq) > d:
            prob.V0 = Vq
    if d > 1e-9 or nbad(prob.V0) < n0:  # never worse: fewer cells of the region folded, or none
        V = prob.V0
    return V


def place_high_order(V, P0, blocks, moved, bnd=None, pin=None) -> np.ndarray:
    """V with the high-order nodes of every cell touching a ``moved`` node at their straight-sided positions on
    V's corners plus the curving they had in ``P0`` (``P0`` minus its straight-sided positions); with ``bnd``,
    boundary nodes (kinds 0 and 1) among them projected onto the input's curved faces / feature curves. Nodes
    marked in ``pin`` stay."""
    W = np.array(V, dtype=np.float64, copy=True)
    S1 = straight_points(V, blocks)
    S0 = straight_points(P0, blocks)
    ho = np.zeros(V.shape[0], dtype=bool)
    for name, conn in blocks:
        el = ELEMENTS[name]
        if el.domain not in LINEAR or el.order < 2 or conn.shape[0] == 0:
            continue
        touch = moved[conn[:, : el.corners]].any(axis=1)
        ho[conn[touch, el.corners:].ravel()] = True
    if pin is not None:
        ho &= ~pin
    idx = np.flatnonzero(ho)
    W[idx] = S1[idx] + (P0[idx] - S0[idx])
    if bnd is not None and idx.size:
        b = idx[(bnd.kind[idx] >= 0) & (bnd.kind[idx] < 2)]
        if b.size:
            W = bnd.project(W, b)
    return W
