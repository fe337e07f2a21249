"""The curved cells of a repair: det J's Bernstein coefficients, the curved boundary, and the energy's problem.

What :func:`hexsos_plugins.meshrepair.curved.repair_curved` and its straight-sided skeleton
(:mod:`hexsos_plugins.meshrepair.skeleton`) both stand on: which meshes take the curved path (:func:`needs_curved`,
:func:`curved_blocks`), the coefficient tables and their fast and kernel evaluations, the curved scaled Jacobian,
the input's curved boundary (:class:`CurvedBoundary`), the barrier problem on a group of nodes (:class:`Problem`)
and the cell groups it is posed on. The energy and the method are described in :mod:`.curved`.
"""

from __future__ import annotations

import time
from functools import lru_cache

import numpy as np

from ..cells.elements import ELEMENTS
from ..cells.jacobian import factor_indices, space
from ..errors import InvalidInputError, NoCellsError
from .boundary import NearestPoints

__all__ = ["needs_curved", "curved_blocks", "coefficient_tables", "fast_coefficients", "kernel_coefficients",
           "curved_scaled_jacobian", "CurvedBoundary", "curved_boundary", "Problem", "cell_scales", "VERTICES",
           "MOVABLE_DOMAINS", "node_cells", "cell_groups", "nodes_of"]

#: vertices of each reference element (the first nodes of every cell)
VERTICES = {"tet": 4, "cube": 8, "prism": 6, "pyramid": 5}

#: The reference elements whose cells the curved repair moves (pyramids keep their nodes).
MOVABLE_DOMAINS = ("tet", "prism", "cube")


def needs_curved(hexes, cells) -> bool:
    """Whether a mesh goes to :func:`repair_curved`: it has no trilinear hexahedra (``hexes`` empty) but other
    3-D cells, or it has cells of order 2 or more. ``hexes`` not of shape (M, 8): :class:`InvalidInputError`."""
    H = np.asarray(hexes if hexes is not None else np.zeros((0, 8)))
    if H.size and (H.ndim != 2 or H.shape[1] != 8):
        raise InvalidInputError(f"hexes: expected shape (M, 8), found {H.shape}")
    n_hex = int(H.shape[0]) if H.size else 0
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
