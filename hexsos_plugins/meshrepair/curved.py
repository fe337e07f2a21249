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
from functools import lru_cache

import numpy as np

from ..cells.elements import ELEMENTS
from ..cells.inputs import checked_block
from ..cells.jacobian import factor_indices, space
from ..errors import InvalidInputError, NoCellsError
from .boundary import NearestPoints
from .result import RepairResult

__all__ = ["repair_curved", "needs_curved", "curved_blocks", "coefficient_tables", "fast_coefficients", "kernel_coefficients", "curved_scaled_jacobian",
           "CurvedBoundary", "curved_boundary", "Problem", "cell_scales", "MOVABLE_DOMAINS", "node_cells", "cell_groups",
           "nodes_of"]

#: vertices of each reference element (the first nodes of every cell)
_VERTICES = {"tet": 4, "cube": 8, "prism": 6, "pyramid": 5}

#: The reference elements whose cells the curved repair moves (pyramids keep their nodes).
MOVABLE_DOMAINS = ("tet", "prism", "cube")


def needs_curved(hexes, cells) -> bool:
    """Whether a mesh goes to :func:`repair_curved`: it has no trilinear hexahedra (``hexes`` empty) but other
    3-D cells, or it has cells of order 2 or more."""
    n_hex = int(np.asarray(hexes).reshape(-1, 8).shape[0]) if np.asarray(hexes).size else 0
    cells = list(cells or [])
    if any(ELEMENTS[name].order > 1 for name, _ in cells if name in ELEMENTS):
        return True
    return n_hex == 0 and any(len(c) for _, c in cells)


def curved_blocks(hexes, cells) -> list:
    """The (type, conn) blocks of a mesh given as ``hexes`` (M, 8) and other ``cells`` (the arguments of
    :func:`hexsos_plugins.meshrepair.repair`): the hexahedra first when there are any."""
    H = np.asarray(hexes if hexes is not None else np.zeros((0, 8)), dtype=np.int64).reshape(-1, 8)
    out = [("hexahedron", H)] if H.shape[0] else []
    for k, item in enumerate(cells or []):
        try:
            name, conn = item
        except (TypeError, ValueError):
            raise InvalidInputError(f"cells[{k}]: expected a (cell type, connectivity) pair, found {item!r}") from None
        out.append((name, conn))
    return out


def _factor_collocation(kind, p):
    """A factor's Bernstein basis (as :func:`hexsos_plugins.cells.jacobian.factor_indices` orders it) at its
    control points alpha / p: A[q, i]."""
    from math import factorial, prod

    idx = factor_indices(kind, p)
    if p == 0:
        return np.ones((1, 1))
    A = np.empty((len(idx), len(idx)))
    for q, aq in enumerate(idx):
        x = np.array(aq, dtype=np.float64) / p
        lam = np.concatenate([[1.0 - x.sum()], x])
        for i, ai in enumerate(idx):
            e = (p - sum(ai),) + tuple(ai)
            A[q, i] = factorial(p) / prod(factorial(v) for v in e) * np.prod(lam ** np.array(e))
    return A


@lru_cache(maxsize=None)
def coefficient_tables(name: str):
    """(dN (nq, n, 3), Tf (3, m, m), sizes (3,)): the shape functions' derivatives at the control points of det
    J's Bernstein space (:func:`hexsos_plugins.cells.jacobian.space`), and per factor of the reference element the
    inverse of its Bernstein collocation matrix (padded; absent factors of size 1), whose Kronecker product takes
    det J's values at the control points to its Bernstein coefficients."""
    el = ELEMENTS[name]
    sp = space(name)
    X = np.asarray(sp.ctrl, dtype=np.float64)
    Ts = [np.linalg.inv(_factor_collocation(kind, p)) for kind, p in sp.factors]
    sizes = np.ones(3, dtype=np.int64)
    m = max(t.shape[0] for t in Ts)
    Tf = np.zeros((3, m, m))
    for f, t in enumerate(Ts):
        sizes[f] = t.shape[0]
        Tf[f, : t.shape[0], : t.shape[0]] = t
    for f in range(len(Ts), 3):
        Tf[f, 0, 0] = 1.0
    # the Kronecker product is the inverse of the whole collocation matrix (checked once per type)
    V = np.prod(X[:, None, :] ** sp.mono_exp[None, :, :], axis=2)
    A = V @ sp.M
    K = np.ones((1, 1))
    for t in Ts:
        K = np.kron(K, t)
    # (in doubles through monomials of degree up to 3p - 1 per variable: measured 1e-8 for wedge40, 4e-5 for
    # pyramid30, 7e-4 for hexahedron64; a space that is not the product is off by O(1))
    if not np.allclose(K @ A, np.eye(A.shape[0]), atol=1e-2):
        raise AssertionError(f"{name}: det J's Bernstein space is not the product of its factors' spaces")
    dN = np.ascontiguousarray(el.shape_derivatives(X))
    return dN, Tf, sizes


def fast_coefficients(points, name, conn, ids=None) -> np.ndarray:
    """det J's Bernstein coefficients (len(ids), nb) of the cells ``conn[ids]`` in float64 (no error bound; the
    optimizer's view: :func:`hexsos_plugins.kernel.coefficients` has the proven ones)."""
    from .curvedkernels import coefficients

    dN, Tf, sizes = coefficient_tables(name)
    ids = np.arange(conn.shape[0], dtype=np.int64) if ids is None else np.ascontiguousarray(ids, dtype=np.int64)
    out = np.empty((ids.size, dN.shape[0]))
    if ids.size:
        coefficients(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(conn, dtype=np.int64),
                     ids, dN, Tf, sizes, out)
    return out


def kernel_coefficients(points, name, conn) -> np.ndarray:
    """The kernel's det J Bernstein coefficients (M, nb) of every cell ``conn``, in world units (fast; for the
    driver's bookkeeping)."""
    from ..kernel import coefficients

    conn = np.ascontiguousarray(conn, dtype=np.int64)
    b, _, k, _ = coefficients(np.ascontiguousarray(points, dtype=np.float64), conn, np.arange(conn.shape[0]), name)
    with np.errstate(over="ignore", under="ignore"):
        return np.ldexp(b, 3 * k[:, None])


def curved_scaled_jacobian(points, cells) -> np.ndarray:
    """Per cell of ``cells`` ((type, conn) list), min b / max b of det J's Bernstein coefficients as the kernel
    proves them (:func:`hexsos_plugins.kernel.coefficients`): a lower bound of min det J / max det J over the
    element when positive (1 for an affine cell); <= 0 when a coefficient is not positive."""
    from ..kernel import coefficients

    P = np.ascontiguousarray(points, dtype=np.float64)
    parts = []
    for name, conn in cells:
        conn = np.ascontiguousarray(conn, dtype=np.int64)
        if conn.shape[0] == 0:
            parts.append(np.zeros(0))
            continue
        b, err, _, _ = coefficients(P, conn, np.arange(conn.shape[0]), name)
        lo = (b.min(axis=1) - err)
        hi = b.max(axis=1) + err
        with np.errstate(divide="ignore", invalid="ignore"):
            parts.append(np.where(hi > 0, lo / np.where(hi > 0, hi, 1.0), -1.0))
    return np.concatenate(parts) if parts else np.zeros(0)


# ------------------------------------------------------------------------------------------------ boundary


def _face_geometry(name):
    """Per face of the type: (corner reference coords (k, 3), the nodes on the face, du, dv) with the face
    parametrized as xi(u, v) = xi_0 + u du + v dv (a triangle u, v >= 0, u + v <= 1; a quad [0, 1]^2)."""
    el = ELEMENTS[name]
    R = el.reference_nodes
    out = []
    for f in el.faces:
        C = R[list(f)]
        du = C[1] - C[0]
        dv = (C[2] - C[0]) if len(f) == 3 else (C[3] - C[0])
        n = np.cross(du, dv)
        on = np.flatnonzero(np.abs((R - C[0]) @ n) <= 1e-12 * np.linalg.norm(n))
        out.append((C, on, du, dv))
    return out


def _lattice(kind, k):
    """Lattice points (S, 2) of a triangle or a quad with k intervals per edge, and their triangles."""
    if kind == 3:
        idx = {}
        pts = []
        for j in range(k + 1):
            for i in range(k + 1 - j):
                idx[i, j] = len(pts)
                pts.append((i / k, j / k))
        tris = []
        for j in range(k):
            for i in range(k - j):
                tris.append((idx[i, j], idx[i + 1, j], idx[i, j + 1]))
                if i + j + 1 < k:
                    tris.append((idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]))
    else:
        pts = [(i / k, j / k) for j in range(k + 1) for i in range(k + 1)]
        tris = []
        for j in range(k):
            for i in range(k):
                a = j * (k + 1) + i
                tris += [(a, a + 1, a + k + 2), (a, a + k + 2, a + k + 1)]
    return np.array(pts), np.array(tris, dtype=np.int64)


class CurvedBoundary:
    """The input's curved boundary: which nodes lie on it and how they may move (``kind``: -1 inside, 0 on a
    surface, 1 on a feature curve, 2 a feature corner), their unit normals (kind 0) or tangents (kind 1), and the
    input's curved faces and feature curves sampled finely (``surf_V``, ``surf_F``; ``curve_V``, ``curve_E``)
    to project onto."""

    def __init__(self, kind, normal, tangent, surf_V, surf_F, curve_V, curve_E, feature_edges):
        self.kind, self.normal, self.tangent = kind, normal, tangent
        self.surf_V, self.surf_F, self.curve_V, self.curve_E = surf_V, surf_F, curve_V, curve_E
        self.feature_edges = feature_edges
        self.nearest = (NearestPoints(surf_V, surf_F), NearestPoints(curve_V, curve_E))  # trees built at first use

    @property
    def nodes(self):
        return np.flatnonzero(self.kind >= 0)

    def project(self, V, idx) -> np.ndarray:
        """V with the nodes ``idx`` of kinds 0 and 1 moved to the nearest point of the input's curved faces /
        feature curves (sampled)."""
        W = np.array(V, dtype=np.float64, copy=True)
        idx = np.asarray(idx, dtype=np.int64)
        for kind, SF in ((0, self.surf_F), (1, self.curve_E)):
            rows = idx[self.kind[idx] == kind]
            if rows.size == 0 or SF.shape[0] == 0:
                continue
            W[rows] = self.nearest[kind](W[rows])[2]
        return W

    def distance(self, V, idx=None) -> np.ndarray:
        """Distance of the boundary nodes (or ``idx``) to the input's curved faces (sampled)."""
        rows = self.nodes if idx is None else np.asarray(idx, dtype=np.int64)
        if rows.size == 0:
            return np.zeros(0)
        return np.sqrt(self.nearest[0](V[rows])[0])


def curved_boundary(points, cells, *, feature_angle: float = 45.0) -> CurvedBoundary:
    """The :class:`CurvedBoundary` of ``cells`` ((type, conn) list, VTK order) at ``points`` (the input)."""
    from .boundary import boundary_model

    P = np.asarray(points, dtype=np.float64)
    N = P.shape[0]
    # boundary faces: corner faces that belong to one cell only
    recs = []  # (block, face index, cell rows)
    keys = []
    for b, (name, conn) in enumerate(cells):
        if conn.shape[0] == 0:
            continue
        for fi, f in enumerate(ELEMENTS[name].faces):
            k = np.sort(conn[:, list(f)], axis=1)
            keys.append(np.pad(k, ((0, 0), (0, 4 - k.shape[1])), constant_values=-1))
            recs.append((b, fi, np.arange(conn.shape[0])))
    if not keys:
        raise NoCellsError("no 3-D cells to repair")
    K = np.concatenate(keys)
    _, inv, cnt = np.unique(K, axis=0, return_inverse=True, return_counts=True)
    once = cnt[inv.ravel()] == 1
    bm = boundary_model(P, cells, feature_angle=feature_angle)
    corner_kind = np.full(N, -1)
    corner_kind[bm.vertices] = bm.kind
    feat = {(int(min(a, b)), int(max(a, b))) for a, b in bm.feat_E}
    kind = np.full(N, -1)
    nacc = np.zeros((N, 3))
    tacc = np.zeros((N, 3))
    SV, SF, CV, CE = [], [], [], []
    nsv = ncv = 0
    off = 0
    for b, fi, rows in recs:
        sel = rows[once[off: off + rows.size]]
        off += rows.size
        if sel.size == 0:
            continue
        name, conn = cells[b]
        el = ELEMENTS[name]
        C, on, du, dv = _face_geometry(name)[fi]
        Xc = P[conn[sel]]  # (m, n, 3)
        R = el.reference_nodes
        # normals at the face's nodes: x_u x x_v of the curved face
        dN = el.shape_derivatives(R[on])  # (k, n, 3)
        J = np.einsum("mna,knd->mkad", Xc, dN)
        nrm = np.cross(J @ du, J @ dv)  # (m, k, 3)
        ids = conn[sel][:, on]
        for a in range(3):
            nacc[:, a] += np.bincount(ids.ravel(), weights=nrm[..., a].ravel(), minlength=N)
        kind[ids.ravel()] = np.maximum(kind[ids.ravel()], 0)
        # the face sampled
        kk = 4 * max(el.order, 1)
        uv, tri = _lattice(len(el.faces[fi]), kk)
        xi = C[0] + uv[:, :1] * du + uv[:, 1:] * dv
        Ns = el.shape_functions(xi)  # (S, n)
        S = np.einsum("sn,mna->msa", Ns, Xc).reshape(-1, 3)
        SV.append(S)
        SF.append((tri[None] + nsv + uv.shape[0] * np.arange(sel.size)[:, None, None]).reshape(-1, 3))
        nsv += S.shape[0]
        # feature edges of this face: sampled curves, and their nodes
        f = el.faces[fi]
        for j in range(len(f)):
            la, lb = f[j], f[(j + 1) % len(f)]
            ga, gb = conn[sel, la], conn[sel, lb]
            isf = np.array([(min(x, y), max(x, y)) in feat for x, y in zip(ga, gb)], dtype=bool)
            if not isf.any():
                continue
            ea, eb = R[la], R[lb]
            d = eb - ea
            ts = np.linspace(0.0, 1.0, kk + 1)
            Ne = el.shape_functions(ea + ts[:, None] * d)
            Xe = Xc[isf]
            CVp = np.einsum("sn,mna->msa", Ne, Xe).reshape(-1, 3)
            seg = np.stack([np.arange(kk), np.arange(1, kk + 1)], axis=1)
            CE.append((seg[None] + ncv + (kk + 1) * np.arange(Xe.shape[0])[:, None, None]).reshape(-1, 2))
            CV.append(CVp)
            ncv += CVp.shape[0]
            rel = R - ea
            ton = np.flatnonzero((np.linalg.norm(np.cross(rel, d), axis=1) <= 1e-12)
                                 & (rel @ d >= -1e-12) & (rel @ d <= d @ d + 1e-12))
            dNe = el.shape_derivatives(R[ton])
            Je = np.einsum("mna,knd->mkad", Xe, dNe)
            tv = Je @ d  # (m, k, 3)
            for kq, loc in enumerate(ton):
                g = conn[sel[isf], loc]
                t = tv[:, kq]
                for gi, ti in zip(g, t):
                    if kind[gi] < 1:
                        kind[gi] = 1
                    if tacc[gi] @ ti < 0:
                        ti = -ti
                    tacc[gi] += ti
    # corner vertices keep the boundary model's kinds (features meet at corners)
    cv = corner_kind >= 0
    kind[cv] = np.maximum(kind[cv], corner_kind[cv])
    normal = nacc / np.maximum(np.linalg.norm(nacc, axis=1, keepdims=True), 1e-300)
    tangent = tacc / np.maximum(np.linalg.norm(tacc, axis=1, keepdims=True), 1e-300)
    curve_V = np.ascontiguousarray(np.concatenate(CV)) if CV else np.zeros((0, 3))
    curve_E = np.ascontiguousarray(np.concatenate(CE)) if CE else np.zeros((0, 2), dtype=np.int64)
    return CurvedBoundary(kind, normal, tangent, np.ascontiguousarray(np.concatenate(SV)),
                          np.ascontiguousarray(np.concatenate(SF)), curve_V, curve_E, len(feat))


# ------------------------------------------------------------------------------------------------ energy


class Problem:
    """The energy over the cells ``sel`` (per block ids) with the nodes ``free`` as unknowns, each in its own
    basis (3 columns inside, the tangent plane on a surface, the tangent on a curve)."""

    def __init__(self, V, blocks, scale, sel, free, bnd, core=None):
        import scipy.sparse as sps


        self.V0 = np.array(V, dtype=np.float64)
        self.blocks, self.scale = blocks, scale
        self.sel = [np.ascontiguousarray(s, dtype=np.int64) for s in sel]
        # ``core`` (per block, cell masks): the cells whose least coefficient is the one reported (positions in sel)
        self.core = None if core is None else [np.flatnonzero(m[s_]) for m, s_ in zip(core, self.sel)]
        self.weight = [np.ones(s.size) for s in self.sel]
        self.free = np.flatnonzero(free)
        F = self.free.size
        rows, cols, vals = [], [], []
        col = 0
        kinds = bnd.kind[self.free] if bnd is not None else np.full(F, -1)
        for j, v in enumerate(self.free):
            kd = kinds[j]
            if kd == 0:
                n = bnd.normal[v]
                a = np.eye(3)[np.argmin(np.abs(n))]
                t1 = np.cross(n, a)
                t1 /= np.linalg.norm(t1)
                basis = [t1, np.cross(n, t1)]
            elif kd == 1:
                basis = [bnd.tangent[v]]
            else:
                basis = list(np.eye(3))
            for e in basis:
                for a in range(3):
                    if e[a] != 0.0:
                        rows.append(3 * j + a)
                        cols.append(col)
                        vals.append(e[a])
                col += 1
        self.ndof = col
        self.B = sps.csr_matrix((vals, (rows, cols)), shape=(3 * F, col))
        self.BT = self.B.T.tocsr()
        self.N = self.V0.shape[0]

    def points(self, y):
        P = self.V0.copy()
        P[self.free] += (self.B @ y).reshape(-1, 3)
        return P

    def energy(self, y, eps, grad=True):
        from .curvedkernels import barrier

        P = self.points(y)
        E = 0.0
        rmin = np.inf
        g = np.zeros((self.N, 3))
        for kb, ((name, conn), s, sel, w) in enumerate(zip(self.blocks, self.scale, self.sel, self.weight)):
            if sel.size == 0:
                continue
            dN, Tf, sizes = coefficient_tables(name)
            gc = np.empty((sel.size, conn.shape[1], 3)) if grad else np.empty((1, 1, 3))
            rc = np.empty(sel.size)
            e, rm = barrier(P, conn, sel, dN, Tf, sizes, np.ascontiguousarray(s[sel]), w, float(eps), gc, grad, rc)
            E += e
            if self.core is not None:  # the cells to untangle: the others may keep a negative coefficient
                rm = float(rc[self.core[kb]].min()) if self.core[kb].size else np.inf
            rmin = min(rmin, rm)
            if grad:
                idx = conn[sel].ravel()
                for a in range(3):
                    g[:, a] += np.bincount(idx, weights=gc[..., a].ravel(), minlength=self.N)
        if not grad:
            return E, rmin
        return E, self.BT @ g[self.free].ravel(), rmin

    def rmin(self, P):
        m = np.inf
        for k, ((name, conn), s, sel) in enumerate(zip(self.blocks, self.scale, self.sel)):
            if self.core is not None:
                sel = sel[self.core[k]]
            if sel.size:
                b = fast_coefficients(P, name, conn, sel)
                m = min(m, float((b.min(axis=1) / s[sel]).min()))
        return m

    def minimize(self, eps, maxiter, deadline=None, stop_positive=False):
        """L-BFGS from the current points; returns (points, min r, iterations: energy evaluations when stopped
        early). ``stop_positive``: stop at the
        first point where every coefficient is positive (untangling)."""
        from scipy.optimize import minimize

        calls = [0]

        def fun(y):
            calls[0] += 1
            if deadline is not None and time.perf_counter() > deadline:
                raise _Deadline(y)
            E, g, rm = self.energy(y, eps)
            if stop_positive and rm > 1e-9 and np.any(y != 0):
                raise _Deadline(y)
            return E, g

        y0 = np.zeros(self.ndof)
        try:
            res = minimize(fun, y0, jac=True, method="L-BFGS-B",
                           options={"maxiter": int(maxiter), "gtol": 1e-10, "ftol": 1e-12, "maxcor": 20})
            y, nit = res.x, int(res.nit)
        except _Deadline as d:
            y, nit = d.y, calls[0]
        P = self.points(y)
        return P, self.rmin(P), nit


class _Deadline(Exception):
    def __init__(self, y):
        super().__init__("deadline")
        self.y = np.array(y)


# ------------------------------------------------------------------------------------------------ driver


def cell_scales(P, blocks):
    """Per block, each cell's mean det J (= the mean of its Bernstein coefficients), at least a quarter of its
    largest coefficient (inverted cells) and never 0."""
    out = []
    for name, conn in blocks:
        if conn.shape[0] == 0:
            out.append(np.zeros(0))
            continue
        b = kernel_coefficients(P, name, conn)
        s = np.maximum(b.mean(axis=1), 0.25 * np.abs(b).max(axis=1))
        out.append(np.where(s > 0, s, 1.0))
    return out


def node_cells(blocks, N):
    """For dilation: per block, the cells touching a node mask."""
    def cells_at(mask):
        return [mask[conn].any(axis=1) if conn.shape[0] else np.zeros(0, bool) for _, conn in blocks]
    return cells_at


def cell_groups(masks, blocks, N):
    """The marked cells split into groups that share nodes (per group: per block masks)."""
    import scipy.sparse as sps
    from scipy.sparse.csgraph import connected_components

    ids, rows = [], []
    for m, (_, conn) in zip(masks, blocks):
        sel = np.flatnonzero(m)
        ids.append(sel)
        rows.append(conn[sel])
    n_cells = sum(i.size for i in ids)
    if n_cells == 0:
        return []
    starts = np.cumsum([0] + [i.size for i in ids])
    ci = np.concatenate([np.repeat(np.arange(starts[b], starts[b + 1]), r.shape[1]) for b, r in enumerate(rows)])
    ni = np.concatenate([r.ravel() for r in rows])
    G = sps.csr_matrix((np.ones(ci.size), (ci, n_cells + ni)), shape=(n_cells + N, n_cells + N))
    _, lab = connected_components(G, directed=False)
    lab = lab[:n_cells]
    out = []
    for c in np.unique(lab):
        comp = []
        for b, m in enumerate(masks):
            mm = np.zeros(m.shape, dtype=bool)
            mm[ids[b][lab[starts[b]: starts[b + 1]] == c]] = True
            comp.append(mm)
        out.append(comp)
    return out


def nodes_of(masks, blocks, N):
    """The nodes (mask (N,)) of the cells marked in ``masks`` (per block)."""
    v = np.zeros(N, dtype=bool)
    for m, (_, conn) in zip(masks, blocks):
        if conn.shape[0]:
            v[conn[m].ravel()] = True
    return v


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
    from ..cells.quality import summary
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
        corner[conn[:, :_VERTICES[ELEMENTS[name].domain]].ravel()] = True
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
        message = (f"every cell proven valid; curved scaled Jacobian min {csj1.min():.4f} (was {csj0.min():.4f})")
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
