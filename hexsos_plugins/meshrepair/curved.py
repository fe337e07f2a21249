"""Repair of meshes of any 3-D cells -- curved (quadratic and higher) and linear tetrahedra, wedges, hexahedra --
on the Bernstein coefficients of det J, certified by the kernel.

:func:`repair_curved` is what :func:`hexsos_plugins.meshrepair.repair` runs when a mesh has no trilinear hexahedra
or has cells of order 2 or more (Gmsh's ``setOrder`` curves the boundary elements and often inverts the cells
behind them). Every type of the registry (:data:`hexsos_plugins.cells.elements.ELEMENTS`) whose reference element
is a tetrahedron, prism or cube takes part, at any order the registry holds; pyramids keep their nodes and are
checked.

* **Skeleton** (:mod:`.skeleton`): where a cell's straight-sided cell (its corners) is folded, the linear mesh of
  the corners is untangled first and the high-order nodes of the cells with moved corners go back on the new
  corners with the input's curving (at most half of ``time_limit``).
* **Unknowns**: per group of cells to repair (cells not proven valid or with a coefficient <= 0, grouped by shared
  nodes), first the high-order nodes (edge, face, interior) of those cells, then of ``rings`` layers around
  them, then the corners too (at once for a group with a cell whose corners are folded); never the pinned nodes
  (boundary, below). Every cell touching a moving node is in the energy; a group is done when its own cells'
  coefficients are positive or the kernel proves them valid.
* **Energy**: per cell, det J's Bernstein coefficients ``b`` (det J sampled at the control points of its
  Bernstein space and converted, :func:`coefficient_tables`; the same space the kernel proves on) relative to
  the cell's mean det J in the input, ``r = b / s``; each coefficient pays ``f(r) = (1 + r^2) / chi(r, eps)``,
  ``chi = (r + sqrt(r^2 + eps^2)) / 2`` (:mod:`.curvedkernels`). With eps > 0 it is finite everywhere and
  untangles (Garanzha et al.'s regularization, eps shrinking with the most negative coefficient); with eps ->
  0 it is a barrier: positive coefficients, which prove det J > 0 over the whole element, stay positive, and
  each coefficient is drawn towards the mean, which raises the curved scaled Jacobian ``min b / max b`` (a
  lower bound of min det J / max det J over the element). Minimized by L-BFGS.
* **Quality**: rounds over the cells whose curved scaled Jacobian is below a threshold (``min_sj`` + 0.1, or
  0.5) and their rings, the lowest weighted most, while the minimum rises (or until ``min_sj``).
* **Boundary** (``boundary="slide"``, the default): the input's boundary faces are its curved faces (the cells'
  shape functions on each face). A node on a boundary face moves in its tangent plane (node normals from the
  curved faces), a node on a feature curve (boundary edges whose faces meet at more than ``feature_angle``)
  along the curve's tangent, feature corners stay; after each stage the moved boundary nodes go back onto the
  input's curved faces (sampled 4 x order times per edge) or feature curves, each as far as the cells stay
  positive. ``"fixed"`` pins every boundary node, ``"free"`` none.
* **Certificate**: :func:`hexsos_plugins.check` on every cell of the mesh; success only when every cell is
  proven valid. Otherwise the best mesh seen (fewest cells not proven valid: the input or the result) is
  returned with ``success=False``.
"""

from __future__ import annotations

import time

import numpy as np

from ..cells.elements import ELEMENTS
from ..cells.inputs import checked_block
from ..errors import InvalidInputError, NoCellsError
from .curvedcells import (MOVABLE_DOMAINS, VERTICES, CurvedBoundary, Problem, cell_groups, cell_scales,
                          coefficient_tables, curved_blocks, curved_boundary, curved_scaled_jacobian,
                          fast_coefficients, kernel_coefficients, needs_curved, node_cells, nodes_of)
from .result import RepairResult
from .orientation import refuse_mirrored
from ..cells.topology import refuse_collapsed
from .copies import originals, restore, written_twice

__all__ = ["repair_curved", "needs_curved", "curved_blocks", "coefficient_tables", "fast_coefficients",
           "kernel_coefficients", "curved_scaled_jacobian", "CurvedBoundary", "curved_boundary", "Problem",
           "cell_scales", "MOVABLE_DOMAINS", "node_cells", "cell_groups", "nodes_of"]


def repair_curved(points, cells, *, boundary: str = "slide", min_sj=None, max_iter=None, time_limit=None,
                  feature_angle: float = 45.0, rings: int = 2, pinned=None, progress=None, callback=None,
                  jobs: int = 1, scheduler=None) -> RepairResult:
    """Repair a mesh of any 3-D cells (module docstring): untangle, raise the curved scaled Jacobian, certify.

    Parameters
    ----------
    points : (N, 3)
    cells : list of (cell type, conn), VTK node order (as :func:`hexsos_plugins.check` takes them)
    boundary : "slide" (default), "fixed" or "free"
    min_sj : float in (0, 1), optional: target of the curved scaled Jacobian (min b / max b, proven by the
        kernel's coefficients); default None, as high as it goes
    max_iter : most L-BFGS iterations per optimization (default 300)
    time_limit : seconds for the optimization (the certificate always runs), counted, like ``stats["seconds"]``,
        from after the compiled loops are loaded (``stats["load_seconds"]``: compiled at the first curved repair)
    feature_angle, rings, pinned, progress, callback, jobs, scheduler : as :func:`hexsos_plugins.meshrepair.repair`

    Returns
    -------
    RepairResult: ``check`` is the kernel's certificate of every cell (blocks in the order of ``cells``),
    ``success`` only when every cell is proven valid (and ``min_sj`` reached is reported in ``stats``).
    """
    from ..certify import check
    from ..kernel import scaled_jacobian
    from ..cells.quality import sj_text, summary
    from .blas import single_thread
    from .skeleton import folded_cells, linear_blocks, place_high_order
    from .skeleton import untangle as skeleton_untangle
    from .curvedkernels import load

    t_load = time.perf_counter()
    load()  # the compiled loops, before the clock starts (compiled once, at first use)
    t0 = time.perf_counter()
    P0 = np.array(points, dtype=np.float64, copy=True)
    if P0.ndim != 2 or P0.shape[1] != 3 or not np.isfinite(P0).all():
        raise InvalidInputError(f"points: expected finite coordinates of shape (N, 3), found shape {P0.shape}")
    N = P0.shape[0]
    blocks = []
    for k, (name, conn) in enumerate(cells):
        # a private, writable copy: a read-only connectivity (as hexsos_plugins.read gives) would be a second
        # argument type of the compiled loops, compiled again
        blocks.append((name, checked_block(k, name, conn, N).copy()))
    if not any(c.shape[0] for _, c in blocks):
        raise NoCellsError("repair: expected 3-D cells, found none")
    refuse_collapsed(blocks)  # an edge of no length: never valid
    refuse_mirrored(P0, blocks)  # written mirrored throughout: a repair turns it inside out
    twin = written_twice(blocks)
    if twin is not None:  # cells written twice (Gmsh's MSH 2, an element in two physical groups): repaired once
        res = repair_curved(P0, originals(blocks, twin), boundary=boundary, min_sj=min_sj, max_iter=max_iter,
                            time_limit=time_limit, feature_angle=feature_angle, rings=rings, pinned=pinned,
                            progress=progress, callback=callback, jobs=jobs, scheduler=scheduler)
        return restore(res, twin, 0)
    if boundary not in ("slide", "fixed", "free"):
        raise InvalidInputError(f"boundary: expected slide, fixed or free, found {boundary!r}")
    maxiter = 300 if max_iter is None else int(max_iter)
    deadline = None if time_limit is None else t0 + float(time_limit)
    movable_blocks = [ELEMENTS[name].domain in MOVABLE_DOMAINS for name, _ in blocks]

    pin = np.zeros(N, dtype=bool)
    if pinned is not None:
        pm = np.asarray(pinned, dtype=bool)
        if pm.shape != (N,):
            raise InvalidInputError(f"pinned: expected a boolean array of shape ({N},), found {pm.shape}")
        pin |= pm
    for (name, conn), mv in zip(blocks, movable_blocks):
        if not mv:
            pin[conn.ravel()] = True
    used = np.zeros(N, dtype=bool)
    for _, conn in blocks:
        used[conn.ravel()] = True
    pin |= ~used
    bnd = None
    if boundary != "free":
        bnd = curved_boundary(P0, blocks, feature_angle=feature_angle)
        if boundary == "fixed":
            pin[bnd.kind >= 0] = True
        else:
            pin[bnd.kind == 2] = True
    slide = boundary == "slide"
    history = []

    def certify(V):
        return check(V, blocks, jobs=jobs, scheduler=scheduler)

    if progress is not None:
        progress(0, 1)
    ts = time.perf_counter()
    r0 = certify(P0)
    t_check0 = time.perf_counter() - ts
    bad0 = int((r0.status != 1).sum())
    csj0 = curved_scaled_jacobian(P0, blocks)
    sj0 = scaled_jacobian(P0, blocks)

    def entry(stage, V, nbad, seconds):
        e = {"iteration": len(history), "stage": stage, "invalid": int(nbad), "undecided": 0, "other_invalid": 0,
             "min_det": float("nan"), "min_sj": float(np.nanmin(scaled_jacobian(V, blocks))),
             "moved_vertices": int(np.any(V != P0, axis=1).sum()), "seconds": float(seconds)}
        history.append(e)
        if callback is not None and callback(e, V.copy()):
            raise _Stopped
        return e

    history.append({"iteration": 0, "stage": "input", "invalid": int((r0.status == 0).sum()),
                    "undecided": int((r0.status == -1).sum()), "other_invalid": 0,
                    "min_det": float(np.min(r0.min_det)), "min_sj": float(np.nanmin(sj0)) if sj0.size else np.nan,
                    "moved_vertices": 0, "seconds": t_check0})
    scale = cell_scales(P0, blocks)
    cells_at = node_cells(blocks, N)
    V = P0.copy()
    stage_s = {}
    its = {"untangle": 0, "quality": 0, "rounds": 0, "projection": 0}
    stopped = False

    def rvals(V):
        out = []
        for (name, conn), s, mv in zip(blocks, scale, movable_blocks):
            if not mv or conn.shape[0] == 0:
                out.append(np.full(conn.shape[0], np.inf))
                continue
            b = kernel_coefficients(V, name, conn)
            out.append(b.min(axis=1) / s)
        return out

    corner = np.zeros(N, dtype=bool)
    for name, conn in blocks:
        # the cell's vertices (``Element.corners`` counts a pyramid's 4 base corners only: the corner check's)
        corner[conn[:, :VERTICES[ELEMENTS[name].domain]].ravel()] = True
    high_order = used & ~corner & ~pin

    def region(core_masks, r, corners=True):
        masks = [m.copy() for m in core_masks]
        for _ in range(r):
            masks = cells_at(nodes_of(masks, blocks, N))
        free = nodes_of(masks, blocks, N) & ~pin
        if not corners:
            free &= ~corner
        sel = cells_at(free)  # every cell touching a free node is in the energy
        return free, [np.flatnonzero(s & mv) for s, mv in zip(sel, movable_blocks)]

    def back_to_surface(V, Vprev_ok, idx, rfun=None, of=None):
        """Boundary nodes idx onto the input's curved faces, each halved back while a cell (of the blocks ``of``,
        positivity by ``rfun``; the cells non-positive before too, or with ``rfun`` given only the others) goes
        non-positive."""
        of = blocks if of is None else of
        if bnd is None or idx.size == 0:
            return V
        W = bnd.project(V, idx)
        moved = idx[np.any(W[idx] != V[idx], axis=1)]
        if moved.size == 0:
            return V
        if rfun is None:
            rfun = rvals
            ok0 = [np.ones(c.shape[0], dtype=bool) for _, c in of]
        else:  # another group's folded cells do not hold a node back
            ok0 = [rr > 0 for rr in rfun(V)]
        for _ in range(12):
            r = rfun(W)
            badc = [(rr <= 0) & o for rr, o in zip(r, ok0)]
            sel = nodes_of(badc, of, N)
            culprits = moved[sel[moved]]
            if culprits.size == 0:
                break
            W[culprits] = 0.5 * (W[culprits] + V[culprits])
        else:
            r = rfun(W)
            sel = nodes_of([(rr <= 0) & o for rr, o in zip(r, ok0)], of, N)
            W[moved[sel[moved]]] = V[moved[sel[moved]]]
        its["projection"] += 1
        return W

    try:
        with single_thread():
            # stage 0: cells whose corners are folded (the straight-sided cell is inverted): untangle the linear
            # mesh of the corners, then the high-order nodes of the cells with moved corners back on the new
            # corners with the input's curving (:mod:`.skeleton`)
            ts = time.perf_counter()
            lin = linear_blocks(blocks)
            lscale = cell_scales(P0, lin)
            fold = folded_cells(V, lin, lscale)
            if any(f.any() for f in fold):
                Vs = skeleton_untangle(V, lin, lscale, fold, pin, bnd if slide else None, rings=1,
                                       deadline=None if deadline is None else ts + 0.5 * (deadline - ts),
                                       debug=_debug)
                moved = np.any(Vs != V, axis=1)
                if slide:
                    def lvals(W):
                        return [(kernel_coefficients(W, nm, cn).min(axis=1) / s_ if cn.shape[0] else np.zeros(0))
                                for (nm, cn), s_ in zip(lin, lscale)]
                    Vs = back_to_surface(Vs, V, np.flatnonzero(moved & (bnd.kind >= 0) & (bnd.kind < 2)), lvals, lin)
                V = place_high_order(Vs, P0, blocks, moved, bnd if slide else None, pin)
                its["skeleton_before"] = int(sum(f.sum() for f in fold))
                its["skeleton_after"] = int(sum(f.sum() for f in folded_cells(V, lin, lscale)))
                _debug(f"skeleton: {its['skeleton_before']} folded cells -> {its['skeleton_after']}, "
                       f"{int(moved.sum())} corners moved")
                entry("skeleton", V, sum(int((rr <= 1e-9).sum()) for rr in rvals(V)), time.perf_counter() - ts)
            stage_s["skeleton"] = time.perf_counter() - ts
            # stage 1: untangle every cell with a coefficient <= 0 (and those the kernel did not prove valid)
            ts = time.perf_counter()
            r = rvals(V)
            off = 0
            core = []
            for rr, (_, conn) in zip(r, blocks):
                m = rr <= 1e-9
                m |= r0.status[off: off + conn.shape[0]] != 1
                off += conn.shape[0]
                core.append(m)
            tries = 0
            # first the high-order nodes of the bad cells and their neighbours only (the corners keep the linear
            # mesh's shape), then wider, then the corners too
            plan = ([(False, 0), (False, rings)] if high_order.any() else []) + [(True, rings), (True, 2 * rings + 1)]
            while any(c.any() for c in core) and tries < len(plan):
                corners_too, ring = plan[tries]
                # one problem per group of bad cells sharing nodes: each stops when its own cells are positive; a
                # group with a cell folded at its corners (straight-sided cell inverted) moves its corners at once
                sj_now = np.split(scaled_jacobian(V, blocks), np.cumsum([c.shape[0] for _, c in blocks])[:-1])
                for comp in cell_groups(core, blocks, N):
                    folded = any((x[m] <= 0).any() for x, m in zip(sj_now, comp))
                    free, sel = region(comp, ring, corners=corners_too or folded)
                    if not free.any():
                        continue
                    prob = Problem(V, blocks, scale, sel, free, bnd if slide else None, core=comp)
                    _, rmin = prob.energy(np.zeros(prob.ndof), 1.0, grad=False)
                    best_r = rmin
                    stall = 0
                    for outer in range(20):
                        if rmin > 1e-9:
                            break
                        eps = np.sqrt(1e-12 + 0.04 * min(rmin, 0.0) ** 2)
                        Vn, rmin, nit = prob.minimize(eps, min(maxiter, 60), deadline, stop_positive=True)
                        its["untangle"] += max(nit, 0)
                        prob.V0 = Vn
                        _debug(f"untangle try {tries} outer {outer}: {free.sum()} free nodes, "
                               f"{sum(x.size for x in sel)} cells, eps {eps:.3g}, min r {rmin:.4g}, {nit} iterations")
                        if deadline is not None and time.perf_counter() > deadline:
                            break
                        # a coefficient may stay negative on a cell whose det J is positive: the kernel decides
                        if all((check(Vn, [(nm, cn[sl])]).status == 1).all()
                               for (nm, cn), sl in zip(blocks, sel) if sl.size):
                            break
                        # stalled (the most negative coefficient rises by less than 1% of itself twice): widen
                        stall = stall + 1 if rmin < best_r + 0.01 * abs(best_r) else 0
                        best_r = max(best_r, rmin)
                        if stall >= 2:
                            break
                    V = prob.V0
                    if slide:
                        V = back_to_surface(V, V, np.flatnonzero(free & (bnd.kind >= 0) & (bnd.kind < 2)))
                    if deadline is not None and time.perf_counter() > deadline:
                        break
                r = rvals(V)
                core = [rr <= 1e-9 for rr in r]
                entry("untangle", V, sum(int(c.sum()) for c in core), time.perf_counter() - ts)
                tries += 1
                if deadline is not None and time.perf_counter() > deadline:
                    break
            stage_s["untangle"] = time.perf_counter() - ts
            # stage 2: the curved scaled Jacobian of the worst cells and their rings
            ts = time.perf_counter()
            untangled = not any((rr <= 1e-9).any() for rr in rvals(V))
            if untangled:
                def csj(V):
                    out = []
                    for (name, conn), mv in zip(blocks, movable_blocks):
                        if not mv or conn.shape[0] == 0:
                            out.append(np.full(conn.shape[0], np.inf))
                            continue
                        b = kernel_coefficients(V, name, conn)
                        out.append(b.min(axis=1) / b.max(axis=1))
                    return out

                q = csj(V)
                m = min(float(x.min()) for x in q if x.size)
                for rnd in range(8):
                    if min_sj is not None and m >= min_sj:
                        break
                    if deadline is not None and time.perf_counter() > deadline:
                        break
                    tau = min(max(0.5, m + 0.2), 0.9) if min_sj is None else max(min_sj + 0.1, m + 0.1)
                    low = [x < tau for x in q]
                    if not any(lw.any() for lw in low):
                        break
                    free, sel = region(low, rings, corners=not high_order.any())
                    if not free.any():
                        break
                    prob = Problem(V, blocks, scale, sel, free, bnd if slide else None)
                    # the lowest cells weigh most
                    for b_, s_ in enumerate(sel):
                        qs = q[b_][s_]
                        prob.weight[b_] = np.where(qs < tau, (tau / np.maximum(qs, 1e-3)) ** 2, 1.0)
                    Vn, rmin_n, nit = prob.minimize(1e-12, min(maxiter, 100), deadline)
                    its["quality"] += max(nit, 0)
                    its["rounds"] += 1
                    if slide:
                        Vn = back_to_surface(Vn, V, np.flatnonzero(free & (bnd.kind >= 0) & (bnd.kind < 2)))
                    qn = csj(Vn)
                    mn = min(float(x.min()) for x in qn if x.size)
                    _debug(f"quality round {rnd}: {free.sum()} free nodes, tau {tau:.3g}, min {m:.4f} -> {mn:.4f}, "
                           f"min r {rmin_n:.3g}, {nit} iterations")
                    if rmin_n <= 1e-9 or mn < m or not all((rr > 1e-9).all() for rr in rvals(Vn)):
                        break
                    gain = mn - m
                    V, q, m = Vn, qn, mn
                    entry("quality", V, 0, time.perf_counter() - ts)
                    if gain < 1e-3 or (deadline is not None and time.perf_counter() > deadline):
                        break
            stage_s["quality"] = time.perf_counter() - ts
    except _Stopped:
        stopped = True
    # stage 3: the certificate
    ts = time.perf_counter()
    res = certify(V)
    nbad = int((res.status != 1).sum())
    if nbad > bad0:  # the input was better: it is the best mesh seen
        V, res, nbad = P0.copy(), r0, bad0
    stage_s["certify"] = time.perf_counter() - ts + t_check0
    ok = nbad == 0
    if progress is not None:
        progress(1, 1)
    csj1 = curved_scaled_jacobian(V, blocks)
    sj1 = scaled_jacobian(V, blocks)
    reached = None if min_sj is None else bool(csj1.size and csj1.min() >= min_sj)
    disp = V - P0
    norm = np.sqrt((disp * disp).sum(axis=1))
    movedv = norm > 0
    types = {}
    for name, conn in blocks:
        types[name] = types.get(name, 0) + int(conn.shape[0])
    if ok:
        message = (f"every cell proven valid; curved scaled Jacobian min {sj_text(csj1.min())} (was "
                   f"{sj_text(csj0.min())})")
        if reached is False:
            message += f"; the target min_sj {min_sj:g} was not reached"
    else:
        ids = np.flatnonzero(res.status != 1)
        why = []
        if stopped:
            why.append("stopped by the callback")
        elif deadline is not None and time.perf_counter() > deadline:
            why.append(f"time limit {time_limit:g} s reached")
        allpin = np.zeros(ids.size, dtype=bool)
        off = 0
        for name, conn in blocks:
            sel = (ids >= off) & (ids < off + conn.shape[0])
            allpin[sel] = pin[conn[ids[sel] - off]].all(axis=1)
            off += conn.shape[0]
        if allpin.any():
            why.append(f"{int(allpin.sum())} of them have every node pinned"
                       + (" (the boundary is fixed: try boundary='slide' or 'free')" if boundary == "fixed" else
                          " (feature corners or pyramids)"))
        message = (f"{ids.size} of {res.status.size} cells not proven valid (cells "
                   + ", ".join(str(int(i)) for i in ids[:8]) + (", ..." if ids.size > 8 else "") + ")"
                   + (" (" + "; ".join(why) + ")" if why else "") + "; the best mesh seen is returned")
    s0, s1 = summary(sj0), summary(sj1)
    stats = {
        "method": "curved", "boundary": boundary, "cells": int(sum(c.shape[0] for _, c in blocks)),
        "cell_types": types, "points": N, "hexes": int(sum(c.shape[0] for n, c in blocks if n == "hexahedron")),
        "invalid_before": int((r0.status == 0).sum()), "undecided_before": int((r0.status == -1).sum()),
        "invalid_after": int((res.status == 0).sum()), "undecided_after": int((res.status == -1).sum()),
        "min_det_before": float(np.min(r0.min_det)), "min_det_after": float(np.min(res.min_det)),
        "curved_sj_before": float(csj0.min()), "curved_sj_after": float(csj1.min()),
        "min_sj_before": s0["min"], "p1_sj_before": s0["p1"], "mean_sj_before": s0["mean"],
        "min_sj_after": s1["min"], "p1_sj_after": s1["p1"], "mean_sj_after": s1["mean"],
        "min_sj_target": min_sj, "min_sj_target_reached": reached,
        "untangle_iterations": its["untangle"], "quality_iterations": its["quality"],
        "quality_rounds": its["rounds"], "projections": its["projection"],
        "skeleton_folded_before": its.get("skeleton_before", 0), "skeleton_folded_after": its.get("skeleton_after", 0),
        "max_displacement": float(norm.max()) if N else 0.0,
        "mean_displacement": float(norm[movedv].mean()) if movedv.any() else 0.0,
        "moved_vertices": int(movedv.sum()), "pinned_vertices": int(pin.sum()),
        "boundary_vertices": int((bnd.kind >= 0).sum()) if bnd is not None else None,
        "feature_edges": bnd.feature_edges if bnd is not None else None,
        "stage_seconds": stage_s, "seconds": time.perf_counter() - t0, "load_seconds": t0 - t_load,
        "success": ok, "message": message, "other_cells": 0,
        "by_type": res.by_type() if hasattr(res, "by_type") else None,
    }
    if bnd is not None and slide:
        bn = bnd.nodes
        stats["boundary_max_distance"] = float(bnd.distance(V, bn).max()) if bn.size else 0.0
    history.append({"iteration": len(history), "stage": "certify", "invalid": int((res.status == 0).sum()),
                    "undecided": int((res.status == -1).sum()), "other_invalid": 0,
                    "min_det": float(np.min(res.min_det)), "min_sj": s1["min"],
                    "moved_vertices": int(movedv.sum()), "seconds": stage_s["certify"]})
    return RepairResult(points=V, success=ok, check=res, history=history, stats=stats, displacement=disp,
                        message=message, extra={"curved_scaled_jacobian": csj1})


class _Stopped(Exception):
    pass


def _debug(msg):
    import os
    import sys

    if os.environ.get("HEXSOS_CURVED_DEBUG"):
        sys.stderr.write(msg + "\n")
