"""The repair's last stage: raise the minimum scaled Jacobian vertex by vertex (target-driven local steps).

After the global stages (untangling, the barrier over a region), what caps the minimum is a handful of hexes, most
of them with several vertices on the surface. Here each vertex of the hexes below ``min + band`` moves in turn,
worst first, to raise the least scaled Jacobian sample of the hexes around it (the compiled steps of
:mod:`hexsos_plugins.meshrepair.kernels`): inside in any direction, on the surface in its input tangent plane, on a feature
curve along its tangent, feature corners and pinned vertices not at all; with a band
(:attr:`hexsos_plugins.meshrepair.boundary.BoundaryModel.tolerance`), boundary vertices move in any direction but
stay within the band's width of their surface, curve or corner. No accepted step lowers the mesh's minimum,
fails a hex's test of validity (its Bernstein coefficients of det J positive, or those of their split: see
:mod:`hexsos_plugins.meshrepair.optimize`) or takes a hex's shortest / longest edge below the lesser of
its own and :data:`RATIO_FLOOR`, so the stage ends where it started or higher, valid, with no edge collapsed.
Sweeps repeat until the minimum rises by less than ``min_gain`` in ``patience`` sweeps, or the deadline.
"""

from __future__ import annotations

import time

import numpy as np

from ..cells.hexahedron import EDGES
from ..cells.quality import SAMPLES, SHORT_EDGE_RATIO, hex_edge_ratio

__all__ = ["local_sweeps", "local_untangle", "straighten_quads", "vertex_freedoms", "band_limits", "BAND_BELOW",
           "RATIO_FLOOR"]

#: The band around the boundary (:attr:`hexsos_plugins.meshrepair.boundary.BoundaryModel.tolerance`) is for the
#: hexes the surface holds down: only vertices of hexes below this scaled Jacobian leave the surface (measured on a
#: graded solid whose hexes reach 0.994 on the surface: with the band everywhere, 0.995 for a boundary 0.68% of the
#: diagonal off instead of 0.08%). At 0.75 the published meshes piled up there: the hexes lifted to it met neighbours
#: whose surface vertices the band did not free (medians over three starts, the same day, 0.75 -> 0.85: the bunny
#: 0.798 -> 0.833, Dolphin_2 0.750 -> 0.767, cat_2 0.751 -> 0.753, the others within 0.001, the farthest boundary
#: vertex the same 1.16% of the diagonal at most)
BAND_BELOW = 0.85

#: No vertex step takes a hex's shortest edge over its longest below the lesser of its own and this
#: (:func:`hexsos_plugins.meshrepair.kernels.sweep`): the scaled Jacobian does not see an edge's length, and the
#: steps raised it by collapsing edges (after the last pass on cat_2, rockarm and dinopet_graded the least ratio was
#: 1e-5 to 1e-4). Measured there in single runs, before stage 2's edge term reached the boundary edges: 0.02 left
#: the minimum where it was (0.780, 0.733, 0.640) but drove edges down to the floor (61-88 hexes below 0.05); 0.1
#: cost it (0.655, 0.257, 0.549); 0.05: 0.746, 0.684, 0.632. It is the reports' short-edge threshold
#: (:data:`hexsos_plugins.cells.quality.SHORT_EDGE_RATIO`): the steps make no hex the report counts as short-edged.
RATIO_FLOOR = SHORT_EDGE_RATIO


def _incidence(H, N):
    """The cells (rows of ``H``: hexes, or boundary quads) at each of the N vertices, CSR: (ptr (N + 1,), the cells
    (inc), the vertex's corner in each (loc))."""
    k = H.shape[1]
    flat = H.ravel()
    order = np.argsort(flat, kind="stable")
    ptr = np.zeros(N + 1, dtype=np.int64)
    np.add.at(ptr, flat + 1, 1)
    ptr = np.cumsum(ptr)
    inc = (order // k).astype(np.int64)
    loc = (order % k).astype(np.int64)
    return ptr, inc, loc


def _edge_length(V, H, N):
    e = EDGES
    a, b = H[:, e[:, 0]].ravel(), H[:, e[:, 1]].ravel()
    ln = np.linalg.norm(V[a] - V[b], axis=1)
    s = np.bincount(a, ln, minlength=N) + np.bincount(b, ln, minlength=N)
    c = np.bincount(a, minlength=N) + np.bincount(b, minlength=N)
    return s / np.maximum(c, 1)


def vertex_freedoms(V, H, movable, boundary, step):
    """Each vertex's freedom for the vertex steps: (proj (N, 3, 3), ptr, inc, loc, step0 (N,)). ``proj`` the
    orthogonal projector onto the directions a vertex may move in (the identity inside, the input tangent plane on
    the surface, the tangent on a feature curve, 0 at corners and where not ``movable``); ``ptr``/``inc``/``loc``
    the hexes around each vertex (CSR) and its node index in each; ``step0`` ``step`` times the vertex's mean
    edge length."""
    N = V.shape[0]
    proj = np.zeros((N, 3, 3))
    proj[movable] = np.eye(3)
    if boundary is not None:
        bv = boundary.vertices
        on = movable[bv]
        n, t = boundary.normal, boundary.tangent
        Q = np.where((boundary.kind == 0)[:, None, None], np.eye(3)[None] - n[:, :, None] * n[:, None, :],
                     np.where((boundary.kind == 1)[:, None, None], t[:, :, None] * t[:, None, :], 0.0))
        proj[bv[on]] = Q[on]
    ptr, inc, loc = _incidence(H, N)
    return proj, ptr, inc, loc, step * _edge_length(V, H, N)


def band_limits(V, movable, boundary, proj, allowed):
    """The band of each boundary vertex (:attr:`hexsos_plugins.meshrepair.boundary.BoundaryModel.tolerance`) for
    :func:`hexsos_plugins.meshrepair.kernels.sweep`: (ref (N, 3), A (N, 3, 3), width (N,)), width inf where there is
    none. A movable boundary vertex with a band moves in any direction (``proj`` set to the identity), its component
    along A (the surface normal, across the curve, every direction at a corner) within ``width`` of ``ref``, its
    nearest point on the input surface, curve or corner. Only the vertices ``allowed`` (N,) bool get a band; the
    others keep their surface's tangent plane, their curve's tangent, or stay (corners)."""
    N = V.shape[0]
    ref = np.array(V, dtype=np.float64, copy=True)
    A = np.zeros((N, 3, 3))
    width = np.full(N, np.inf)
    if boundary is None:
        return ref, A, width
    w = boundary.band_width()
    bv = boundary.vertices
    on = movable[bv] & (w > 0) & allowed[bv]
    if not on.any():
        return ref, A, width
    n, t = boundary.normal, boundary.tangent
    Ab = np.where((boundary.kind == 0)[:, None, None], n[:, :, None] * n[:, None, :],
                  np.where((boundary.kind == 1)[:, None, None], np.eye(3)[None] - t[:, :, None] * t[:, None, :],
                           np.eye(3)[None]))
    idx = bv[on]
    A[idx] = Ab[on]
    width[idx] = w[on]
    proj[idx] = np.eye(3)
    ref[idx] = boundary.closest(V, idx)[idx]
    return ref, A, width


def _worst_first(H, q, verts, N):
    vmin = np.full(N, np.inf)
    np.minimum.at(vmin, H.ravel(), np.repeat(q, 8))
    return verts[np.argsort(vmin[verts], kind="stable")]


def straighten_quads(V, H, movable, boundary, *, degrees=None, rounds=20, tries=10, step=0.25):
    """Turn the boundary quads that face against their input normal back out, and stand those tilted more than
    ``degrees`` from it (default :data:`hexsos_plugins.meshrepair.boundary.TILT_DEGREES`) back toward it, by steps
    of their own movable vertices, none lowering the mesh's minimum scaled Jacobian.

    The quads are taken worst first (the least cosine of their vector area with their input normal,
    :meth:`BoundaryModel.quad_tilt <hexsos_plugins.meshrepair.boundary.BoundaryModel.quad_tilt>`). Each vertex of
    a quad (``movable`` (N,) bool) steps along the gradient of that cosine, ``step`` times its mean edge length at
    first, halved up to ``tries`` times; back into the band where the step left it
    (:meth:`BoundaryModel.band_width <hexsos_plugins.meshrepair.boundary.BoundaryModel.band_width>`: toward its
    nearest point of the input surface, curve or corner; a vertex without a band stays). A step is kept only when
    the quad's cosine grows, every hex around the vertex stays at or above the mesh's minimum sample and passes the
    test of validity (:func:`hexsos_plugins.meshrepair.kernels.cell_minima`), no hex's shortest / longest edge falls
    below the lesser of its own and :data:`RATIO_FLOOR`, and no other boundary quad around it falls below the lesser
    of its own cosine and the bound's. A quad's rounds over its vertices repeat while a step is kept and it is
    below the bound, ``rounds`` at most; they are undone unless the quad ends turned over no more (it was) or
    tilted no more (it was only tilted): else they would only have lowered hexes toward the minimum. Returns (V',
    info) with ``turned_before`` / ``_after``, ``tilted_before`` / ``_after`` (turned ones too) and ``steps`` (kept).
    """
    from . import kernels as lo
    from .boundary import TILT_DEGREES

    V = np.array(V, dtype=np.float64, copy=True)
    H = np.ascontiguousarray(H, dtype=np.int64)
    N = V.shape[0]
    degrees = TILT_DEGREES if degrees is None else float(degrees)
    bound = float(np.cos(np.radians(degrees)))
    info = {"turned_before": 0, "turned_after": 0, "tilted_before": 0, "tilted_after": 0, "steps": 0}
    if boundary.quads is None or boundary.quads.shape[0] == 0 or H.shape[0] == 0:
        return V, info
    quads, normal = boundary.quads, boundary.quad_normal
    info["turned_before"] = info["turned_after"] = int(boundary.turned_quads(V).sum())
    low = np.flatnonzero(boundary.tilted_quads(V, degrees))
    info["tilted_before"] = info["tilted_after"] = int(low.size)
    if low.size == 0:
        return V, info
    low = low[np.argsort(boundary.quad_tilt(V, low), kind="stable")]
    m = float(lo.hex_minima(V, H).min())
    floor = np.minimum(hex_edge_ratio(V, H), RATIO_FLOOR)
    ptr, inc, _ = _incidence(H, N)
    qptr, qinc, _ = _incidence(quads, N)
    width = np.zeros(N)
    width[boundary.vertices] = boundary.band_width()
    size = _edge_length(V, H, N)

    def cos(q):
        return float(boundary.quad_tilt(V, [q])[0])

    for q in low:
        start, steps, was = V.copy(), 0, cos(q)
        for _ in range(rounds):
            kept = 0
            for v in quads[q]:
                now = cos(q)
                if now >= bound:
                    break
                if not movable[v] or not width[v] > 0:
                    continue
                a = V[quads[q, 2]] - V[quads[q, 0]]
                b = V[quads[q, 3]] - V[quads[q, 1]]
                A = np.cross(a, b)
                An = float(np.sqrt(A @ A))
                # d cos / d A = (n - cos A / |A|) / |A|; A = a x b, a = p2 - p0, b = p3 - p1: u . a x b = a . (b x u)
                # = b . (u x a)
                u = (normal[q] - now * A / An) / An if An > 0 else normal[q]
                k = int(np.flatnonzero(quads[q] == v)[0])
                g = (-np.cross(b, u), -np.cross(u, a), np.cross(b, u), np.cross(u, a))[k]
                gn = float(np.sqrt(g @ g))
                if not gn > 0:
                    continue
                hx = inc[ptr[v]:ptr[v + 1]]
                Hx = np.ascontiguousarray(H[hx])
                around = qinc[qptr[v]:qptr[v + 1]]
                around = around[around != q]
                keep_at = np.minimum(boundary.quad_tilt(V, around), bound)
                x0 = V[v].copy()
                h = step * size[v] / gn
                for _t in range(tries):
                    x = x0 + h * g
                    C = boundary.closest_point(x, v)
                    d = x - C
                    dn = float(np.sqrt(d @ d))
                    V[v] = C + (width[v] / dn) * d if dn > width[v] else x
                    if (cos(q) > now
                            and float(lo.hex_minima(V, Hx).min()) >= m
                            and bool(np.all(hex_edge_ratio(V, Hx) >= floor[hx]))
                            and bool(np.all(boundary.quad_tilt(V, around) >= keep_at))):
                        kept += 1
                        break
                    V[v] = x0
                    h *= 0.5
            steps += kept
            if not kept or cos(q) >= bound:
                break
        end = cos(q)
        if (was <= 0 < end) or end >= bound:
            info["steps"] += steps
        else:  # neither turned out nor stood up: its steps are undone
            V = start
    info["turned_after"] = int(boundary.turned_quads(V).sum())
    info["tilted_after"] = int(boundary.tilted_quads(V, degrees).sum())
    return V, info


def local_untangle(V, H, sizes, movable, *, boundary=None, deadline=None, band=0.3, tau=0.05, step=0.1,
                   max_sweeps=100, patience=20, margin=1e-3):
    """Raise the least Bernstein coefficient of det J (in units of the hex's size s^3) vertex by vertex
    (:func:`hexsos_plugins.meshrepair.kernels.sweep_bernstein`), worst first, until every hex's is above ``margin``, it
    stalls, or the deadline. No accepted move takes a hex's least coefficient below min(its own, ``margin``): a
    hex whose coefficients are above the margin stays valid, so folds are removed without making others. Returns (V',
    info) with ``sweeps``, ``steps``, ``bad_before``, ``bad_after`` (hexes with a coefficient <= 0)."""
    from . import kernels as lo

    V = np.array(V, dtype=np.float64, copy=True)
    H = np.ascontiguousarray(H, dtype=np.int64)
    N = V.shape[0]
    with np.errstate(divide="ignore", over="ignore"):  # a cell beyond 1e+-102 of unit size: the largest double
        inv3 = np.minimum(1.0 / np.asarray(sizes, dtype=np.float64) ** 3, np.finfo(np.float64).max)
    proj, ptr, inc, loc, step0 = vertex_freedoms(V, H, movable, boundary, step)
    can = np.abs(proj).sum(axis=(1, 2)) > 0
    q = lo.bernstein_minima(V, H, inv3)
    info = {"sweeps": 0, "steps": 0, "bad_before": int((q <= 0).sum())}
    best, stall = float(q.min()), 0
    for _ in range(max_sweeps):
        if q.min() > margin:
            break
        low = q < min(float(q.min()) + band, margin)
        verts = np.unique(H[low].ravel())
        verts = verts[can[verts]]
        if verts.size == 0:
            break
        verts = _worst_first(H, q, verts, N)
        info["steps"] += int(lo.sweep_bernstein(V, H, inv3, verts, ptr, inc, loc, proj, step0, tau, 1, q,
                                                        margin))
        info["sweeps"] += 1
        m = float(q.min())
        if m > best + 1e-6:
            best, stall = m, 0
        else:
            stall += 1
            if stall >= patience:
                break
        if deadline is not None and time.perf_counter() > deadline:
            break
    info["bad_after"] = int((q <= 0).sum())
    return V, info


def local_sweeps(V, H, movable, *, boundary=None, deadline=None, band=0.1, tau=0.02, step=0.05, max_sweeps=200,
                 max_steps=1, patience=5, min_gain=1e-3, target=None, project=None, project_every=4,
                 band_below=BAND_BELOW, banded=None):
    """Raise the minimum scaled Jacobian of hexes H at V by moves of single vertices (module docstring).

    ``movable`` (N,) bool; ``boundary``: a :class:`hexsos_plugins.boundary.BoundaryModel` (surface vertices move
    in their tangent plane, curve vertices along their tangent, corners stay) or None (no constraint but
    ``movable``); ``target``: stop once the minimum reaches it; ``project(V, moved) -> V'``: called every
    ``project_every`` sweeps and at the end with the boundary vertices moved since the last call (it puts them
    back on the input surface; it must not lower the minimum); ``band_below``: only the vertices of hexes whose
    scaled Jacobian is below it at the start use the boundary's band (the others stay on the surface); ``banded``
    (N,) bool: of those, only these. Returns (V', info) with ``sweeps``, ``steps``, ``min_before``, ``min_after``."""
    from . import kernels as lo

    V = np.array(V, dtype=np.float64, copy=True)
    H = np.ascontiguousarray(H, dtype=np.int64)
    N = V.shape[0]
    G, factor = SAMPLES["hexahedron"]
    G = np.ascontiguousarray(G)
    proj, ptr, inc, loc, step0 = vertex_freedoms(V, H, movable, boundary, step)
    cell_sj = lo.cell_minima(V, H, G, float(factor))
    allowed = np.zeros(N, dtype=bool)
    allowed[H[cell_sj < band_below].ravel()] = True
    if banded is not None:
        allowed &= banded
    ref, A, width = band_limits(V, movable, boundary, proj, allowed)
    info = {"sweeps": 0, "steps": 0, "min_before": float(cell_sj.min()) if cell_sj.size else np.inf}
    can = np.abs(proj).sum(axis=(1, 2)) > 0
    best, stall = info["min_before"], 0
    V_last = V.copy()
    for _ in range(max_sweeps):
        m = float(cell_sj.min())
        if target is not None and m >= target:
            break
        # the hexes near the minimum, within ``band`` or half the way left to 1, whichever is less: near 1 every
        # hex is within 0.1 of it (a 32,000-hex graded solid at 0.989: 0.4 s a sweep over all of them for 0.006)
        low = cell_sj < m + min(band, 0.5 * (1.0 - m))
        verts = np.unique(H[low].ravel())
        verts = verts[can[verts]]
        if verts.size == 0:
            break
        verts = _worst_first(H, cell_sj, verts, N)  # by the least scaled Jacobian of the hexes around each
        info["steps"] += int(lo.sweep(V, H, G, float(factor), verts, ptr, inc, loc, proj, step0, tau, max_steps,
                                      cell_sj, ref, A, width, RATIO_FLOOR))
        info["sweeps"] += 1
        if project is not None and info["sweeps"] % project_every == 0:
            V = _project(project, V, V_last, boundary, H, G, factor, cell_sj, ref, width)
            V_last = V.copy()
        m_new = float(cell_sj.min())
        if target is not None and m_new >= target:
            break
        if m_new > best + min_gain:
            best, stall = m_new, 0
        else:
            stall += 1
            if stall >= patience:
                break
        if deadline is not None and time.perf_counter() > deadline:
            break
    if project is not None:
        V = _project(project, V, V_last, boundary, H, G, factor, cell_sj, ref, width)
    info["min_after"] = float(cell_sj.min()) if cell_sj.size else np.inf
    return V, info


def _project(project, V, V_last, boundary, H, G, factor, cell_sj, ref, width):
    """``project`` on the boundary vertices moved since ``V_last``; the band's references follow them."""
    from . import kernels as lo

    bv = boundary.vertices
    moved = bv[np.any(V[bv] != V_last[bv], axis=1)]
    if moved.size == 0:
        return V
    W = project(V, moved)
    cell_sj[:] = lo.cell_minima(W, H, G, float(factor))
    banded = moved[width[moved] < np.inf]
    if banded.size:
        ref[banded] = boundary.closest(W, banded)[banded]
    return W
