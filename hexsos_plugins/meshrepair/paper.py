"""The paper's repair (``method="paper"``): Algorithm 1 (per-hex projection) and Algorithm 2 (averaging).

:func:`hexsos_plugins.repair` runs this with ``method="paper"``; its default is the untangle-and-optimize
repair of :mod:`hexsos_plugins.meshrepair`, which also uses this module as its last resort.

Algorithm 1, :func:`repair_hex` (``Pi`` in the paper)
    For a hex X that the kernel does not prove valid, alternate

    1. ``u* = argmin det J_X`` over [0, 1]^3 (the kernel's exact, polished minimizer; with
       ``method="sos"`` it comes from the moment relaxation), and
    2. the projection (R): ``X <- argmin ||Y - X||_F^2  s.t.  det J_Y(u*) >= margin``,

    until :func:`hexsos_plugins.check` proves the hex valid (status 1). (R) is solved by Newton / SQP:
    project X^k onto the constraint linearized at the current iterate (exactly: a closed form, or a
    dual system of <= 4 unknowns), relinearize, repeat; with the analytic gradient
    :func:`hexsos_plugins.cells.hexahedron.det_vertex_gradient`. It is judged by feasibility -- det J(u*) >=
    margin evaluated afterwards -- never by an optimizer's flag.

    The margin must be positive: with 0 the loop lands on det J(u*) = 0 and the kernel can never prove
    the hex valid. It is relative to the hex's size: ``margin * h^3`` with h the mean length of the hex's
    12 edges (det J is measured on the parameter cube [0, 1]^3, so it scales as a volume). Default
    :data:`DEFAULT_MARGIN` = 1e-3 (measured on 3525 invalid random sigma-0.3 hexes: 1e-4, 1e-3 and 1e-2 all
    repair 100%, median displacement 0.1127 / 0.1136 / 0.1222, so 1e-3 costs nothing over 1e-4 while
    1e-2 moves 8% more; on the meshes 1e-4 needs more outer iterations).

    Three measured departures from the paper's loop, each for hexes it does not repair:

    * (R) keeps the last :data:`MEMORY` (4) argmins of this call as constraints, not only the latest: with
      one point 0.2-0.35% of random sigma-0.3 hexes zig-zag between two minima for 50 steps, each
      projection undoing the other; with four, none (3525 of 3525 repaired, at most 11-29 steps).
    * A hex still not valid after a projection asks for 1.5x more margin at the next one (up to 0.3 h^3):
      a fold whose minimum slides along an edge is otherwise chased point by point for 50 steps.
    * Where det J has no gradient at u* (J of rank <= 1 there: a half-turn twist, a flat hex) the free
      vertices are moved by 1% of the hex's size in a fixed pseudo-random direction (at most 5 times).

Algorithm 2, :func:`repair_paper`
    Per outer iteration every hex the kernel does not prove valid (invalid or undecided) is repaired
    independently, ``Z_eta = Pi(H_eta V)``, valid hexes contribute their current vertices, and

        ``V_i <- (A_i + rho * sum_{eta ~ i} z_eta,i) / (1 + rho * deg_i)``

    with ``A = V`` (the current mesh, default) or ``A = V^0`` (the input, as the paper writes it;
    ``anchor="initial"``). Only hexes with a moved vertex are checked again. It stops when every hex is
    proven valid, or after ``max_iter`` iterations, and then returns the best mesh seen (fewest hexes not
    proven valid, then the largest min det J). The returned :class:`RepairResult` carries the final
    certificate: :func:`hexsos_plugins.check` with its defaults on the whole repaired mesh.

    * Anchor. With V^0 every vertex ever moved is pulled back a little at every iteration, so every hex
      around it is checked again (2x the kernel evaluations measured) and a hex repaired to barely valid
      slides back: with a fixed margin of 1e-4..1e-3 the bunny stalled at 9-30 invalid hexes for 100
      iterations, where the current V finished in 33-50. With the growing
      margin below both finish, in about the same iterations and displacement (within 1-6%), so the
      current V is the default for its cheaper re-checks and because untouched regions stay bit for bit.
    * The margin of a hex grows 2x with each outer iteration in which it is repaired again (up to 0.3
      h^3): the averaging moves a vertex by only ~1/deg of what Pi asked, and hexes that break each other
      in turn otherwise alternate for hundreds of iterations (measured: the demo mesh 200+ iterations
      without growth, 26 with it; a ring mesh 300+ against 31).
    * Once every hex is proven valid, moved hexes whose minimum is below ``margin * h^3`` get up to 10
      more iterations to reach it (without this the bunny ended with a hex at 8e-5 h^3).

Counting, as in the paper's Table 1: an *SOS step* is one evaluation of the kernel on one hex (one argmin
computation; with ``method="auto"`` most are settled by Bernstein bounds and need no SDP, the number of
actual SDP solves is ``stats["sdp_solves"]``); a *(R) step* is one projection of one hex.
"""

from __future__ import annotations

import time

import numpy as np

from ..certify import CheckResult, check, validate_arrays
from ..errors import InvalidInputError
from ..cells.hexahedron import det_at, det_vertex_gradient
from ..io.mesh import hexes_to_mesh
from .boundary import interior_vertices
from .options import DEFAULT_MARGIN, DEFAULT_RHO
from .result import RepairResult, readonly

__all__ = ["repair_paper", "repair_hex", "hex_edge_length", "boundary_vertex_mask", "MEMORY", "PARALLEL_MIN"]


#: The 12 edges of a hex in VTK order.
_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]])
#: The six faces of a hex in VTK order (outward for a positively oriented hex).

# (R) is solved to det J(u*) >= margin by aiming a little above it (Newton then crosses it in few steps).
_AIM = 1.25
_NEWTON_STEPS = 30
_HALVINGS = 6
# the farthest a vertex moves in one projection, in units of the hex's mean edge length
_REACH = 2.0
# A pinned repair that has not improved for this many outer iterations has stalled.
_PIN_PATIENCE = 15
# extra outer iterations, once every hex is proven valid, to lift moved hexes to the margin
_FINISH = 10
# where det J has no gradient at u*: at most _KICKS moves of the free vertices by _KICK x the hex's size
_KICKS = 5
_KICK = 0.01
# margin growth: x _GROWTH per outer iteration a hex is repaired again, x _STEP_GROWTH per projection of
# a hex still not valid in Algorithm 1, never above _MAX_MARGIN * h^3
_GROWTH = 2.0
_STEP_GROWTH = 1.5
_MAX_MARGIN = 0.3


def hex_edge_length(X) -> np.ndarray:
    """Mean length of the 12 edges of each hex: X (M, 8, 3) -> (M,)."""
    X = np.asarray(X, dtype=np.float64)
    e = X[:, _EDGES[:, 1]] - X[:, _EDGES[:, 0]]
    return np.sqrt((e * e).sum(axis=2)).mean(axis=1)


def boundary_vertex_mask(hexes, n_points: int) -> np.ndarray:
    """Boolean mask (N,): the points on a boundary quad (a hex face that belongs to one hex only)."""
    return ~interior_vertices([("hexahedron", np.asarray(hexes, dtype=np.int64).reshape(-1, 8))], n_points)


# ------------------------------------------------------------------------------------------------------
# Algorithm 1
# ------------------------------------------------------------------------------------------------------


def _check_hexes(X, check_kw) -> CheckResult:
    P, H = hexes_to_mesh(X)
    return check(P, H, **check_kw)


def _subsets(C):
    """Every non-empty subset of range(C) as a boolean mask (2^C - 1, C), smaller subsets first."""
    masks = np.array([[(k >> j) & 1 for j in range(C)] for k in range(1, 2 ** C)], dtype=bool)
    return masks[np.argsort(masks.sum(axis=1), kind="stable")]


_SUBSETS = {c: _subsets(c) for c in range(1, 5)}


def halfspace_projection(G, b, act):
    """Project 0 onto {y : G_j . y >= b_j for the active j}, for n problems at once (exactly).

    G : (n, C, D), b : (n, C), act : (n, C) bool. Returns y (n, D) = sum_j lam_j G_j with lam >= 0, and
    ok (n,) bool (False where no subset of the active constraints gave a feasible point: degenerate
    gradients). One active constraint has the closed form; more are solved by enumerating the active sets
    (C <= 4: at most 15 small dual systems).
    """
    n, C, D = G.shape
    y = np.zeros((n, D))
    ok = ((b <= 0) | ~act).all(axis=1)  # y = 0 satisfies them all
    found = ok.copy()
    nact = act.sum(axis=1)
    one = np.flatnonzero(~ok & (nact == 1))
    if one.size:
        j = act[one].argmax(axis=1)
        g = G[one, j]
        gg = np.einsum("nd,nd->n", g, g)
        good = gg > 0
        y[one[good]] = (b[one, j][good] / gg[good])[:, None] * g[good]
        found[one[good]] = True
    rows = np.flatnonzero(~ok & (nact > 1))
    if rows.size == 0:
        return y, found
    Gm, bm, am = G[rows], b[rows], act[rows]
    Q = np.einsum("ncd,ned->nce", Gm, Gm)
    tol = 1e-8 * np.abs(np.where(am, bm, 0.0)).max(axis=1, keepdims=True) + 1e-300
    best = np.full(rows.size, np.inf)
    ym = np.zeros((rows.size, D))
    for S in _SUBSETS[C]:
        idx = np.flatnonzero(S)
        use = np.flatnonzero(am[:, S].all(axis=1))
        if use.size == 0:
            continue
        QS = Q[use][:, idx][:, :, idx]
        ridge = 1e-13 * np.trace(QS, axis1=1, axis2=2)[:, None, None] * np.eye(idx.size)
        try:
            lam = np.linalg.solve(QS + ridge, bm[use][:, idx][..., None])[..., 0]
        except np.linalg.LinAlgError:
            continue
        Gl = np.einsum("nc,ncd->nd", lam, Gm[use][:, idx])
        vals = np.einsum("ncd,nd->nc", Gm[use], Gl)
        feas = (lam >= 0).all(axis=1) & ((vals >= bm[use] - tol[use]) | ~am[use]).all(axis=1)
        obj = np.einsum("nd,nd->n", Gl, Gl)
        better = feas & (obj < best[use])
        best[use[better]] = obj[better]
        ym[use[better]] = Gl[better]
    got = np.isfinite(best)
    y[rows[got]] = ym[got]
    found[rows[got]] = True
    return y, found


def _violation(X, uvw, act, floor):
    """min over the active points of det J(u_j) - floor, per hex: X (n, 8, 3), uvw (n, C, 3), act (n, C)."""
    n, C = act.shape
    d = det_at(np.repeat(X, C, axis=0), uvw.reshape(-1, 3))[0].reshape(n, C)
    return np.where(act, d - floor[:, None], np.inf).min(axis=1)


def project(Xk, uvw, act, target, floor, free, reach):
    """Solve (R) for K hexes at once: min ||X - Xk||_F^2 s.t. det J_X(u_j) >= floor for the points u_j.

    ``uvw`` (K, C, 3) holds up to C points per hex (``act`` (K, C) says which are in use): the latest argmin
    and the ones before it in this call of Algorithm 1 (see :func:`_pi`). Newton / SQP: X_{j+1} is the exact
    projection of Xk onto the constraints linearized at X_j (aiming at ``target``), until every constraint
    holds with ``floor`` -- evaluated, not taken from a solver's flag. Pinned vertices (``free`` False) get a
    zero gradient, so they never move.

    No vertex moves farther than ``reach`` (K,) from Xk in one projection (a longer step is shortened:
    the constraints are then met over several steps, and a hopeless pinned hex cannot run away).

    Returns X (K, 8, 3), feasible (K,) bool, stuck (K,) bool (the free vertices cannot raise det J at the
    points: vanishing or contradictory linearized constraints).
    """
    K, C = act.shape
    X = Xk.copy()
    feasible = np.zeros(K, dtype=bool)
    stuck = np.zeros(K, dtype=bool)
    best = Xk.copy()
    best_v = np.full(K, -np.inf)
    fr = free[:, None, :, None]
    todo = np.arange(K)
    for _ in range(_NEWTON_STEPS):
        n = todo.size
        Xt = np.repeat(X[todo], C, axis=0)
        u = uvw[todo].reshape(-1, 3)
        d = det_at(Xt, u)[0].reshape(n, C)
        a = act[todo]
        # worst violation relative to the floor: the figure of merit of an infeasible iterate
        viol = np.where(a, d - floor[todo][:, None], np.inf).min(axis=1)
        better = viol > best_v[todo]
        best[todo[better]] = X[todo[better]]
        best_v[todo[better]] = viol[better]
        ok = viol >= 0
        feasible[todo[ok]] = True
        todo, d, a, Xt, u = todo[~ok], d[~ok], a[~ok], Xt.reshape(n, C, 8, 3)[~ok].reshape(-1, 8, 3), \
            u.reshape(n, C, 3)[~ok].reshape(-1, 3)
        if todo.size == 0:
            break
        n = todo.size
        g = det_vertex_gradient(Xt, u).reshape(n, C, 8, 3) * fr[todo]
        gg = np.einsum("ncij,ncij->nc", g, g)
        g = np.where(a[:, :, None, None], g, 0.0)
        lin = d + np.einsum("ncij,nij->nc", g, Xk[todo] - X[todo])  # each constraint linearized at Xk
        b = target[todo][:, None] - lin
        dead = a & (gg <= 1e-28 * np.maximum(np.abs(d), 1e-300) ** (4.0 / 3.0)) & (b > 0)
        y, found = halfspace_projection(g.reshape(n, C, 24), b, a & ~dead)
        bad = ~found | dead.any(axis=1)
        stuck[todo[bad]] = True
        todo, y, v0 = todo[~bad], y[~bad], viol[~ok][~bad]
        if todo.size == 0:
            break
        # the full step, halved while it makes the worst constraint worse (a simple globalization)
        target_x = Xk[todo] + y.reshape(-1, 8, 3)
        far = np.sqrt(((target_x - Xk[todo]) ** 2).sum(axis=2)).max(axis=1)
        shrink = np.where(far > reach[todo], reach[todo] / np.where(far > 0, far, 1.0), 1.0)
        step = Xk[todo] + shrink[:, None, None] * (target_x - Xk[todo]) - X[todo]
        finite = np.isfinite(step).all(axis=(1, 2))
        step[~finite] = 0.0
        t = np.ones(todo.size)
        for _ in range(_HALVINGS):
            Y = X[todo] + t[:, None, None] * step
            vy = _violation(Y, uvw[todo], act[todo], floor[todo])
            worse = vy < v0
            if not worse.any():
                break
            t[worse] *= 0.5
        X[todo] = X[todo] + t[:, None, None] * step
    # hexes whose Newton did not reach the floor keep the best iterate seen
    X[~feasible] = best[~feasible]
    return X, feasible, stuck & ~feasible


#: Points u* that Algorithm 1 keeps as constraints of (R) (the latest argmin and the ones before it).
MEMORY = 4


def _pi(X0, free, margin, max_steps, check_kw, first=None, memory=MEMORY, size=None, strict=None):
    """Algorithm 1 on K hexes (K, 8, 3). ``first``: (status, min_det, argmin) of X0 from a check already
    made (the outer iteration's), which saves one kernel evaluation per hex.

    ``strict`` (K,) bool: hexes that must also reach det J >= margin * h^3 at their minimum, valid or not.
    (R) keeps as constraints the last ``memory`` argmins found in this call (the paper: only the latest).
    With one point the loop can zig-zag between two minima, each projection undoing the other (seen on
    0.35% of random sigma-0.3 hexes, unrepaired after 50 steps); with the points remembered it cannot.
    """
    X = np.array(X0, dtype=np.float64, copy=True)
    K = X.shape[0]
    if first is None:
        r = _check_hexes(X, check_kw)
        first, sos_steps, sdp = (r.status, r.min_det, r.argmin), np.ones(K, dtype=np.int64), int(r.sos_solves)
    else:
        sos_steps, sdp = np.zeros(K, dtype=np.int64), 0
    r_steps = np.zeros(K, dtype=np.int64)
    status, min_det, argmin = (np.array(a, copy=True) for a in first)
    h = hex_edge_length(X0) if size is None else np.asarray(size, dtype=np.float64)
    h3 = h**3
    reach = _REACH * h
    floor = np.broadcast_to(np.asarray(margin, dtype=np.float64) * h3, (K,)).copy()
    cap = np.maximum(floor, _MAX_MARGIN * h3)
    C = max(1, min(int(memory), 4))
    pts = np.zeros((K, C, 3))
    act = np.zeros((K, C), dtype=bool)
    stuck = np.zeros(K, dtype=bool)
    kicks = np.zeros(K, dtype=np.int64)
    infeasible = 0
    # ``strict`` hexes must also reach their (first) floor, even when proven valid already
    base = floor.copy()
    strict = np.zeros(K, dtype=bool) if strict is None else np.asarray(strict, dtype=bool)

    def unfinished(idx):
        return (status[idx] != 1) | (strict[idx] & (min_det[idx] < base[idx]))

    active = np.flatnonzero(unfinished(np.arange(K)))
    for _ in range(max_steps):
        if active.size == 0:
            break
        # remember the new argmin: shift the older points back (the oldest drops out)
        pts[active, 1:] = pts[active, :-1]
        act[active, 1:] = act[active, :-1]
        pts[active, 0] = argmin[active]
        act[active, 0] = True
        same = (np.abs(pts[active, 1:] - pts[active, :1]).max(axis=2) < 1e-7) & act[active, 1:]
        act[active, 1:] &= ~same  # a point seen again is kept once
        if r_steps.max() > 0:  # a hex still not valid after a projection: ask for more (see _STEP_GROWTH)
            again = active[r_steps[active] > 0]
            floor[again] = np.minimum(floor[again] * _STEP_GROWTH, cap[again])
        Xn, feas, st = project(X[active], pts[active], act[active], _AIM * floor[active], floor[active],
                                free[active], reach[active])
        retry = np.flatnonzero(~feas & (act[active].sum(axis=1) > 1))
        if retry.size:  # the remembered points could not all be met: the latest alone, as the paper
            one = np.zeros((retry.size, C), dtype=bool)
            one[:, 0] = True
            a = active[retry]
            Xr, fr, sr = project(X[a], pts[a], one, _AIM * floor[a], floor[a], free[a], reach[a])
            Xn[retry], feas[retry], st[retry] = Xr, fr, sr
            act[a, 1:] = False
        r_steps[active] += 1
        infeasible += int((~feas).sum())
        moved = np.any(Xn != X[active], axis=(1, 2))
        # det J has a zero gradient at u* (J of rank <= 1 there, e.g. a half-turn twist): no first-order
        # move exists. Kick the free vertices by 1% of the hex's size in a fixed pseudo-random direction,
        # at most _KICKS times per hex, and go on from there.
        kick = np.flatnonzero(st & ~moved & (kicks[active] < _KICKS) & free[active].any(axis=1))
        if kick.size:
            a = active[kick]
            rng = np.random.default_rng(int(kicks[a].sum()) + 17 * a.size)
            dirs = rng.standard_normal((a.size, 8, 3)) * free[a][:, :, None]
            dirs /= np.linalg.norm(dirs.reshape(a.size, -1), axis=1)[:, None, None]
            Xn[kick] = X[a] + (_KICK * h[a])[:, None, None] * dirs
            kicks[a] += 1
            moved[kick] = True
        X[active] = Xn
        stuck[active[st & ~moved]] = True
        redo = active[moved]
        if redo.size:
            rr = _check_hexes(X[redo], check_kw)
            sos_steps[redo] += 1
            sdp += int(rr.sos_solves)
            status[redo], min_det[redo], argmin[redo] = rr.status, rr.min_det, rr.argmin
        active = active[moved]
        active = active[unfinished(active)]
    info = {
        "valid": status == 1,
        "status": status,
        "min_det": min_det,
        "argmin": argmin,
        "margin": floor,
        "steps": r_steps,
        "sos_steps": sos_steps,
        "stuck": stuck & (status != 1),
        "projection_steps": int(r_steps.sum()),
        "sos_steps_total": int(sos_steps.sum()),
        "sdp_solves": sdp,
        "infeasible_projections": infeasible,
    }
    return X, info


def _check_margin(margin):
    if margin is None:
        return DEFAULT_MARGIN
    try:
        m = float(margin)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"margin: expected a positive number, found {margin!r}") from exc
    if not np.isfinite(m) or m <= 0:
        raise InvalidInputError(
            f"margin: expected a positive number (with 0 the projection lands on det J = 0 and no hex can be "
            f"proven valid), found {margin!r}")
    return m


def _check_kw(method, relaxation, rtol=1e-9):
    return {"method": method, "relaxation": relaxation, "rtol": rtol}


#: Fewest hexes per worker before Algorithm 1 is spread over an executor's workers (below, shipping the
#: hexes costs more than repairing them here).
PARALLEL_MIN = 64
_PER_HEX = ("valid", "status", "min_det", "argmin", "margin", "steps", "sos_steps", "stuck")
_SUMMED = ("projection_steps", "sos_steps_total", "sdp_solves", "infeasible_projections")


def _pi_task(task):
    """Algorithm 1 on one block of hexes (run wherever the executor puts it)."""
    X, free, margin, max_steps, check_kw, first, size, strict = task
    return _pi(X, free, margin, max_steps, check_kw, first=first, size=size, strict=strict)


def _pi_parallel(ex, X, free, margin, max_steps, check_kw, *, first, size, strict):
    """:func:`_pi` on the executor's workers in blocks of hexes (each task carries only its hexes)."""
    K = X.shape[0]
    if ex.workers == 1 or K < PARALLEL_MIN * ex.workers:
        return _pi(X, free, margin, max_steps, check_kw, first=first, size=size, strict=strict)
    blocks = np.array_split(np.arange(K), min(4 * ex.workers, K // PARALLEL_MIN))
    tasks = [(X[b], free[b], margin[b], max_steps, check_kw, tuple(a[b] for a in first), size[b], strict[b])
             for b in blocks]
    parts = ex.map(_pi_task, tasks)
    Z = np.concatenate([z for z, _ in parts])
    info = {k: np.concatenate([i[k] for _, i in parts]) for k in _PER_HEX}
    info.update({k: sum(i[k] for _, i in parts) for k in _SUMMED})
    return Z, info


def repair_hex(X, *, margin=None, max_steps: int = 50, pinned=None, method: str = "auto",
               relaxation: str = "quad2"):
    """Algorithm 1 of the paper on one hex or many at once (independently).

    Parameters
    ----------
    X : array_like, shape (8, 3) or (M, 8, 3)
        Vertex coordinates, VTK node order (see :mod:`hexsos_plugins.cells.hexahedron`).
    margin : float, optional, keyword-only
        Relative margin c > 0: each projection (R) asks ``det J(u*) >= c * h^3`` with h the hex's mean edge
        length. Default :data:`DEFAULT_MARGIN` (1e-3).
    max_steps : int, keyword-only
        Most projections per hex. Default 50.
    pinned : array_like of bool, shape (8,) or (M, 8), optional, keyword-only
        Vertices that must not move.
    method, relaxation : keyword-only
        Passed to :func:`hexsos_plugins.check` (``method="sos"``: u* from the moment relaxation, as the paper).

    Returns
    -------
    X_new : ndarray, same shape as X
        A new array. Hexes the kernel proves valid at the start are returned bit for bit.
    info : dict
        ``valid`` (M,) bool (proven by the kernel at the end), ``status``, ``min_det``, ``argmin`` (of X_new),
        ``steps`` (M,) projections per hex, ``sos_steps`` (M,) kernel evaluations per hex, ``margin`` (M,)
        the absolute margin used, ``stuck`` (M,) hexes the projection could not move (e.g. pinned),
        and totals ``projection_steps``, ``sos_steps_total``, ``sdp_solves``, ``infeasible_projections``.

    Examples
    --------
    >>> from hexsos_plugins.examples import inside_invalid_hex
    >>> Y, info = repair_hex(inside_invalid_hex())
    >>> bool(info["valid"][0]), Y.shape
    (True, (8, 3))
    """
    A = np.asarray(X, dtype=np.float64)
    single = A.shape == (8, 3)
    if single:
        A = A[None]
    if A.ndim != 3 or A.shape[1:] != (8, 3):
        raise InvalidInputError(f"X: expected shape (8, 3) or (M, 8, 3), found {A.shape}")
    if A.shape[0] == 0:
        raise InvalidInputError("X: expected at least one hex, found shape (0, 8, 3)")
    if not np.isfinite(A).all():
        raise InvalidInputError("X: expected finite coordinates, found NaN or inf")
    c = _check_margin(margin)
    if int(max_steps) < 0:
        raise InvalidInputError(f"max_steps: expected an integer >= 0, found {max_steps!r}")
    if pinned is None:
        free = np.ones(A.shape[:2], dtype=bool)
    else:
        pm = np.asarray(pinned, dtype=bool)
        try:
            free = ~np.broadcast_to(pm, A.shape[:2])
        except ValueError as exc:
            raise InvalidInputError(f"pinned: expected shape (8,) or ({A.shape[0]}, 8), found {pm.shape}") from exc
    Y, info = _pi(A, free, c, int(max_steps), _check_kw(method, relaxation))
    return (Y[0] if single else Y), info


# ------------------------------------------------------------------------------------------------------
# Algorithm 2
# ------------------------------------------------------------------------------------------------------


def repair_paper(points, hexes, *, rho: float = DEFAULT_RHO, margin=None, pin_boundary: bool = False,
           max_iter: int = 100, method: str = "auto", relaxation: str = "quad2", progress=None,
           callback=None, anchor: str = "current", max_steps: int = 50, pinned=None, jobs: int = 1,
           scheduler=None) -> RepairResult:
    """Repair a hex mesh: move its vertices as little as possible until every hex is proven valid.

    Parameters
    ----------
    points : array_like, shape (N, 3)
    hexes : array_like of int, shape (M, 8), VTK node order
    rho : float, keyword-only
        Weight of the repaired hexes against the anchor in the vertex update. Default 200 (the paper's).
    margin : float, optional, keyword-only
        Relative margin c > 0 of Algorithm 1: det J(u*) >= c * h^3, h the hex's mean edge length.
        Default :data:`DEFAULT_MARGIN` (1e-3).
    pin_boundary : bool, keyword-only
        Keep the boundary vertices (on quads that belong to one hex only) fixed in both steps (Figure 13).
    max_iter : int, keyword-only
        Most outer iterations. Default 100. When reached, the best mesh seen is returned, success False.
    method, relaxation : keyword-only
        Passed to :func:`hexsos_plugins.check` in the iterations. ``method="sos"`` runs the moment relaxation
        on every hex checked, as the paper (much slower). The final certificate uses ``check``'s defaults.
    progress : callable(done, total), optional
        After each outer iteration: ``done`` hexes repaired so far out of ``total`` not proven valid at first.
    callback : callable(entry, points), optional
        After each outer iteration with its history entry and the current coordinates (do not modify them);
        returning True stops the repair.
    anchor : {"current", "initial"}, keyword-only
        A in the vertex update: the current V (default; see the module docstring) or the input V^0 (the
        paper's formula).
    max_steps : int, keyword-only
        Most projections per hex in each call of Algorithm 1. Default 50.
    pinned : array_like of bool (N,), optional, keyword-only
        Further vertices to keep fixed (besides the boundary with ``pin_boundary``).
    jobs, scheduler : keyword-only
        Run the per-hex repair steps (Algorithm 1) and the checks on ``jobs`` processes or a Dask cluster
        (a ``dask.distributed.Client`` or a scheduler address), as :func:`hexsos_plugins.check` does. Each
        task carries only its hexes' coordinates; iterations with few hexes to repair stay in this process.

    Returns
    -------
    RepairResult
        ``stats`` holds ``hexes``, ``invalid_before``, ``undecided_before``, ``invalid_after``,
        ``undecided_after``, ``outer_iterations``, ``sos_steps``, ``projection_steps``, ``sdp_solves``,
        ``seconds``, ``max_displacement``, ``mean_displacement`` (over moved vertices), ``moved_vertices``,
        ``monotone_invalid``, ``pinned_vertices``, ``margin``, ``rho``, ``anchor``, ``message``.

    Raises
    ------
    InvalidInputError
        bad arrays or parameters (non-positive rho or margin, ...).
    NoHexahedraError
        no hexes.

    Examples
    --------
    >>> from hexsos_plugins.examples import inside_invalid_hex
    >>> from hexsos_plugins.io.mesh import hexes_to_mesh
    >>> P, H = hexes_to_mesh(inside_invalid_hex())
    >>> r = repair_paper(P, H)
    >>> r.success, r.stats["invalid_before"], r.stats["invalid_after"]
    (True, 1, 0)
    """
    from ..certify.parallel import executor

    with executor(jobs, scheduler) as ex:
        return _repair(points, hexes, rho=rho, margin=margin, pin_boundary=pin_boundary, max_iter=max_iter,
                       method=method, relaxation=relaxation, progress=progress, callback=callback, anchor=anchor,
                       max_steps=max_steps, pinned=pinned, ex=ex)


def _repair(points, hexes, *, rho, margin, pin_boundary, max_iter, method, relaxation, progress, callback, anchor,
            max_steps, pinned, ex) -> RepairResult:
    t0 = time.perf_counter()
    P0, H = validate_arrays(points, hexes)
    P0 = np.array(P0, dtype=np.float64, copy=True)  # never alias the caller's array
    N, M = P0.shape[0], H.shape[0]
    try:
        rho = float(rho)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"rho: expected a positive number, found {rho!r}") from exc
    if not np.isfinite(rho) or rho <= 0:
        raise InvalidInputError(f"rho: expected a positive number, found {rho!r}")
    c = _check_margin(margin)
    if int(max_iter) != max_iter or max_iter < 0:
        raise InvalidInputError(f"max_iter: expected an integer >= 0, found {max_iter!r}")
    max_iter = int(max_iter)
    if anchor not in ("initial", "current"):
        raise InvalidInputError(f"anchor: expected 'initial' or 'current', found {anchor!r}")
    ckw = _check_kw(method, relaxation)

    pin = np.zeros(N, dtype=bool)
    if pin_boundary:
        pin |= boundary_vertex_mask(H, N)
    if pinned is not None:
        pm = np.asarray(pinned, dtype=bool)
        if pm.shape != (N,):
            raise InvalidInputError(f"pinned: expected a boolean array of shape ({N},), found {pm.shape}")
        pin |= pm
    deg = np.bincount(H.ravel(), minlength=N).astype(np.float64)
    size0 = hex_edge_length(P0[H])  # each hex's size, from the input: margins and reach never drift
    free_h = ~pin[H]  # (M, 8)

    V = P0.copy()
    r0 = check(V, H, executor=ex, **ckw)
    status, min_det, argmin = r0.status.copy(), r0.min_det.copy(), r0.argmin.copy()
    sos_steps, r_steps, sdp = M, 0, int(r0.sos_solves)
    bad0 = int((status != 1).sum())
    history = [_entry(0, status, min_det, M, 0, 0, time.perf_counter() - t0)]
    h3 = size0**3
    best = (_score(status, min_det, np.zeros(M, dtype=bool), h3, c), V.copy(), 0)
    message = ""
    stopped = None
    no_gain = 0
    impossible = np.zeros(M, dtype=bool)
    # outer iterations each hex has been repaired, kept when it becomes valid: a hex that breaks again starts
    # where it was (measured 20-30% fewer iterations than starting over)
    stubborn = np.zeros(M, dtype=np.int64)
    finishing = 0
    done_shown = 0
    if progress is not None:
        progress(0, bad0)

    it = 0
    while True:
        # hexes the repair has moved must end with their minimum at least margin * h^3 (when they can):
        # without this the last averaging leaves some barely valid (measured on the bunny: min det J
        # 8e-5 h^3). At most _FINISH extra iterations once every hex is proven valid.
        touched = np.any(V != P0, axis=1)[H].any(axis=1)
        weak = touched & (status == 1) & (min_det < c * size0**3)
        if not (status != 1).any():
            if not weak.any() or finishing >= _FINISH:
                message = f"every hex proven valid after {it} outer iteration{'s' * (it != 1)}"
                break
            finishing += 1
        bad = np.flatnonzero((status != 1) | weak)
        if it >= max_iter:
            stopped = "max_iter"
            break
        # hexes whose every vertex is pinned cannot change
        impossible = (status != 1) & ~free_h.any(axis=1)
        work = bad[~impossible[bad]]
        if work.size == 0:
            stopped = "pinned"
            break
        it += 1
        ti = time.perf_counter()
        X = V[H[work]]
        mw = np.minimum(c * _GROWTH ** np.minimum(stubborn[work], 60), max(c, _MAX_MARGIN))
        Z, info = _pi_parallel(ex, X, free_h[work], mw, max_steps, ckw,
                               first=(status[work], min_det[work], argmin[work]), size=size0[work], strict=weak[work])
        stubborn[work] += 1
        sos_steps += info["sos_steps_total"]
        r_steps += info["projection_steps"]
        sdp += info["sdp_solves"]
        # vertex update: V_i <- (A_i + rho sum_eta z_eta,i) / (1 + rho deg_i), written as an increment so
        # that vertices nothing acts on stay bit for bit
        num = np.zeros((N, 3))
        np.add.at(num, H[work].ravel(), (Z - X).reshape(-1, 3))
        num *= rho
        if anchor == "initial":
            num += P0 - V
        delta = num / (1.0 + rho * deg)[:, None]
        delta[pin] = 0.0
        moved = np.any(delta != 0.0, axis=1)
        Vn = V.copy()
        Vn[moved] += delta[moved]
        moved = np.any(Vn != V, axis=1)
        V = Vn
        recheck = np.flatnonzero(moved[H].any(axis=1))
        if recheck.size:
            rr = check(V, H[recheck], executor=ex, **ckw)
            status[recheck], min_det[recheck], argmin[recheck] = rr.status, rr.min_det, rr.argmin
            sos_steps += int(recheck.size)
            sdp += int(rr.sos_solves)
        entry = _entry(it, status, min_det, int(recheck.size) + info["sos_steps_total"], info["projection_steps"],
                       int(moved.sum()), time.perf_counter() - ti)
        history.append(entry)
        score = _score(status, min_det, np.any(V != P0, axis=1)[H].any(axis=1), h3, c)
        gain = score[0] > best[0][0] or (score[0] == best[0][0] and
                                         score[1] > best[0][1] + 1e-6 * abs(best[0][1]))
        no_gain = 0 if gain else no_gain + 1
        if score > best[0]:
            best = (score, V.copy(), it)
        # the callback (a checkpoint's record) sees the step before the progress report says it happened
        stop = callback is not None and callback(entry, readonly(V))
        if progress is not None:
            done_shown = max(done_shown, bad0 - int((status != 1).sum()))
            progress(min(done_shown, bad0), bad0)
        if stop:
            stopped = "callback"
            break
        if not moved.any():
            stopped = "no_move"
            break
        if pin.any() and no_gain >= _PIN_PATIENCE:
            stopped = "pinned_stall"
            break

    # the best mesh seen, then the certificate on all of it with check's defaults
    if best[2] != it:
        V = best[1]
    final = check(V, H, relaxation=relaxation, executor=ex)
    success = bool((final.status == 1).all())
    fbad = final.status != 1
    if not success:
        message = _failure_message(stopped, final, fbad, impossible, pin, H, it, max_iter, best[2])
    elif not message:
        message = f"every hex proven valid after {it} outer iteration{'s' * (it != 1)}"
    if progress is not None:
        progress(bad0, bad0)

    disp = V - P0
    norm = np.sqrt((disp * disp).sum(axis=1))
    movedv = norm > 0
    inv_counts = [h["invalid"] + h["undecided"] for h in history]
    stats = {
        "hexes": M,
        "points": N,
        "invalid_before": int((r0.status == 0).sum()),
        "undecided_before": int((r0.status == -1).sum()),
        "invalid_after": int((final.status == 0).sum()),
        "undecided_after": int((final.status == -1).sum()),
        "outer_iterations": it,
        "best_iteration": int(best[2]) if not success else it,
        "sos_steps": int(sos_steps),
        "projection_steps": int(r_steps),
        "sdp_solves": int(sdp),
        "seconds": time.perf_counter() - t0,
        "max_displacement": float(norm.max()) if N else 0.0,
        "mean_displacement": float(norm[movedv].mean()) if movedv.any() else 0.0,
        "moved_vertices": int(movedv.sum()),
        "monotone_invalid": bool(all(b <= a for a, b in zip(inv_counts, inv_counts[1:]))),
        "min_det_before": float(r0.min_det.min()),
        "min_det_after": float(final.min_det.min()),
        "pinned_vertices": int(pin.sum()),
        "margin": c,
        "rho": rho,
        "anchor": anchor,
        "method": "paper",
        "kernel_method": method,
        "success": success,
        "message": message,
    }
    return RepairResult(points=V, success=success, check=final, history=history, stats=stats,
                        displacement=disp, message=message)


def _score(status, min_det, touched, h3, c):
    """Larger is better. While hexes are not proven valid: (- their number, smallest min det J); once every
    hex is: (0, - moved hexes below the margin, smallest min det J / h^3 of the moved hexes)."""
    bad = int((status != 1).sum())
    if bad:
        return (-bad, float(np.min(min_det)), 0.0)
    # a hex of no size in the input (its corners at one point) has no margin to keep: any valid one is above it
    rel = np.divide(min_det[touched], h3[touched], out=np.full(int(touched.sum()), np.inf), where=h3[touched] > 0)
    return (0, -int((rel < c).sum()), float(rel.min()) if rel.size else np.inf)


def _entry(it, status, min_det, sos, proj, moved, seconds):
    return {"iteration": it, "invalid": int((status == 0).sum()), "undecided": int((status == -1).sum()),
            "min_det": float(np.min(min_det)), "sos_steps": int(sos), "projection_steps": int(proj),
            "moved_vertices": int(moved), "seconds": float(seconds)}


def _failure_message(stopped, final, fbad, impossible, pin, H, it, max_iter, best_it):
    n = int(fbad.sum())
    what = f"{n} hex{'es' * (n != 1)} not proven valid"
    ids = np.flatnonzero(fbad)
    shown = ", ".join(str(int(i)) for i in ids[:8]) + (", ..." if ids.size > 8 else "")
    touch_pin = fbad & pin[H].any(axis=1)
    if stopped == "pinned" or (impossible & fbad).any():
        k = int((impossible & fbad).sum())
        return (f"{what} (hexes {shown}); {k} of them have all 8 vertices pinned (pinned boundary), so they "
                f"cannot be repaired: repair without pin_boundary / --pin-boundary")
    if stopped == "pinned_stall" or (pin.any() and touch_pin.any()):
        return (f"{what} (hexes {shown}) after {it} outer iterations: the repair stalled with the boundary pinned "
                f"({int(touch_pin.sum())} of them have pinned vertices that leave too little freedom); repair "
                f"without pin_boundary / --pin-boundary. The best mesh seen (iteration {best_it}) is returned")
    if stopped == "callback":
        return f"{what}: stopped by the callback after {it} outer iterations; best mesh (iteration {best_it}) returned"
    if stopped == "no_move":
        return (f"{what} (hexes {shown}): the projection could not move any vertex after {it} outer iterations; "
                f"best mesh (iteration {best_it}) returned")
    return (f"{what} (hexes {shown}) after max_iter = {max_iter} outer iterations; the best mesh seen "
            f"(iteration {best_it}) is returned. Try a larger max_iter or margin")
