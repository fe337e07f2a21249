"""Dense sampling of det J on VTK's own shape-function derivatives (InterpolateDerivs): an oracle for min det J.

Independent of hexsos's registry and kernel: VTK gives dN/dpcoords at the sample points, numpy's determinant
gives det J; pyramids use det J / (1 - t)^2, sampled below the apex. A grid over the reference element, then
rounds of zooming around the best points. Used by the comparison harness (experiment 8) and by the tests.

The quadratic pyramids are sampled on *Gmsh's* shape functions (getBasisFunctions "GradLagrange"): VTK has no
14-node pyramid, and its 13-node one interpolates differently inside the cell than the pyramid space hexsos
follows (Gmsh's; see hexsos_plugins.cells.elements). Gmsh's reference pyramid (u, v, w), base [-1, 1]^2, is reached
from VTK's collapsed cube by u = (2 r - 1)(1 - t), v = (2 s - 1)(1 - t), w = t; the measure's columns are
2 x_u, 2 x_v and x_u + x_v + x_w. They are sampled up to t = 1 - 1e-10: the measure of a quadratic pyramid has a
different limit along every direction into the apex.
"""

import contextlib
from functools import lru_cache

import numpy as np

CLASSES = {
    "tetra": "vtkTetra", "tetra10": "vtkQuadraticTetra", "pyramid": "vtkPyramid", "wedge": "vtkWedge",
    "wedge15": "vtkQuadraticWedge", "wedge18": "vtkBiQuadraticQuadraticWedge", "hexahedron": "vtkHexahedron",
    "hexahedron20": "vtkQuadraticHexahedron", "hexahedron27": "vtkTriQuadraticHexahedron",
}
DOMAIN = {"tetra": "tet", "tetra10": "tet", "pyramid": "pyramid", "wedge": "prism", "wedge15": "prism",
          "wedge18": "prism", "hexahedron": "cube", "hexahedron20": "cube", "hexahedron27": "cube",
          "pyramid13": "cube", "pyramid14": "cube"}
# Gmsh's quadratic pyramids: type id and, for each node in meshio's order, the Gmsh node it is (the 13-node one in
# VTK's order: Gmsh numbers the edges 01, 03, 04, 12, 14, 23, 24, 34, VTK 01, 12, 23, 30, 04, 14, 24, 34; meshio
# keeps the 14-node one, which VTK lacks, in Gmsh's order)
GMSH_PYRAMIDS = {"pyramid13": (19, [0, 1, 2, 3, 4, 5, 8, 10, 6, 7, 9, 11, 12]), "pyramid14": (14, list(range(14)))}
_TOP = 1.0 - 1e-10
#: How far a sampled value may lie off det J by the sampler's own rounding, relative to the cell's scale: Gmsh's
#: pyramid basis near the apex errs by about 1e-10 (measured against exact rational arithmetic); VTK's by ulps.
ROUNDING = {"pyramid13": 1e-9, "pyramid14": 1e-9}


@lru_cache(maxsize=None)
def _cell(name):
    import vtkmodules.vtkCommonDataModel as dm

    return getattr(dm, CLASSES[name])()


def _gmsh_session():
    """A Gmsh session for the block (an open one is used as it is)."""
    from hexsos_plugins.examples import gmsh_model

    return gmsh_model("vtk-sampling")


def _gmsh_reference(name):
    gtype, perm = GMSH_PYRAMIDS[name]
    with _gmsh_session() as gmsh:
        ref = np.asarray(gmsh.model.mesh.getElementProperties(gtype)[4]).reshape(-1, 3)[perm]
    u, v, w = ref.T
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(w < 1, (u / (1 - w) + 1) / 2, 0.0)
        s = np.where(w < 1, (v / (1 - w) + 1) / 2, 0.0)
    return np.c_[r, s, w]


def reference_nodes(name):
    if name in GMSH_PYRAMIDS:
        X = _gmsh_reference(name)
        X[4] = (0.5, 0.5, 1.0)
        for k in range(5, len(X)):  # the mid-edge nodes to the apex (t = 1/2), on the straight edges
            if X[k, 2] == 0.5:
                X[k, :2] = (X[k, :2] + 0.5) / 2
        return X
    c = _cell(name)
    n = c.GetNumberOfPoints()
    pc = c.GetParametricCoords()
    X = np.array([pc[i] for i in range(3 * n)]).reshape(n, 3)
    if name == "pyramid":
        X[4] = (0.5, 0.5, 1.0)
    return X


def _gmsh_derivatives(name, pts):
    gtype, perm = GMSH_PYRAMIDS[name]
    pts = np.asarray(pts, float)
    r, s, t = pts.T
    uvw = np.c_[(2 * r - 1) * (1 - t), (2 * s - 1) * (1 - t), t]
    with _gmsh_session() as gmsh:
        _, g, _ = gmsh.model.mesh.getBasisFunctions(gtype, uvw.ravel().tolist(), "GradLagrange")
    g = np.asarray(g).reshape(len(pts), len(perm), 3)[:, perm]  # d N / d (u, v, w), VTK node order
    return np.stack([2 * g[..., 0], 2 * g[..., 1], g[..., 0] + g[..., 1] + g[..., 2]], axis=-1)


def derivatives(name, pts):
    """dN/dpcoords (K, n, 3) at pts (K, 3) from VTK (quadratic pyramids: the measure's columns, from Gmsh)."""
    if name in GMSH_PYRAMIDS:
        return _gmsh_derivatives(name, pts)
    c = _cell(name)
    n = c.GetNumberOfPoints()
    out = np.empty((len(pts), n, 3))
    d = [0.0] * (3 * n)
    for k, p in enumerate(np.asarray(pts, float)):
        c.InterpolateDerivs(p, d)
        out[k] = np.array(d).reshape(3, n).T
    return out


def det(name, X, pts):
    """det J (pyramids: / (1 - t)^2) of cells X (M, n, 3) at pts (K, 3): (M, K)."""
    dN = derivatives(name, pts)
    J = np.einsum("mna,knd->mkad", np.asarray(X, float), dN)
    d = np.linalg.det(J)
    if name == "pyramid":
        d = d / (1.0 - np.asarray(pts)[:, 2]) ** 2
    return d


def _inside(dom, P):
    P = np.asarray(P)
    ok = np.all((P >= 0) & (P <= 1), axis=1)
    if dom == "tet":
        ok &= P.sum(axis=1) <= 1
    elif dom == "prism":
        ok &= P[:, 0] + P[:, 1] <= 1
    elif dom == "pyramid":
        ok &= P[:, 2] <= 0.5
    return ok


def grid(name, n):
    g = np.linspace(0, 1, n)
    G = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    dom = DOMAIN[name]
    if dom == "pyramid":
        G[:, 2] *= 0.5
    if name in GMSH_PYRAMIDS:
        G[:, 2] = np.minimum(G[:, 2], _TOP)
    return G[_inside(dom, G + 0.0)]


def dense_min(name, X, *, n=13, zooms=8, starts=3, shrink=0.25):
    """Dense minimum per cell: values (M,), points (M, 3) and a uniqueness flag (M,) (every grid point within
    1e-3 of the value range of the minimum lies within 0.2 of the minimizer)."""
    # the quadratic pyramids' thousands of small evaluations share one Gmsh session
    with _gmsh_session() if name in GMSH_PYRAMIDS else contextlib.nullcontext():
        return _dense_min(name, X, n, zooms, starts, shrink)


def _dense_min(name, X, n, zooms, starts, shrink):
    X = np.asarray(X, float)
    M = X.shape[0]
    G = grid(name, n)
    vals = det(name, X, G)
    dom = DOMAIN[name]
    order = np.argsort(vals, axis=1)
    best_v = np.full(M, np.inf)
    best_p = np.zeros((M, 3))
    t = np.linspace(-1, 1, 5)
    T = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)
    for s in range(starts):
        p = G[order[:, s * 5]].copy()
        h = 1.0 / (n - 1)
        for _ in range(zooms):
            for m in range(M):
                cand = np.clip(p[m] + h * T, 0, 1)
                if name in GMSH_PYRAMIDS:
                    cand[:, 2] = np.minimum(cand[:, 2], _TOP)
                if dom == "pyramid":
                    cand[:, 2] = np.clip(cand[:, 2], 0, 0.5)
                cand = cand[_inside(dom, cand)]
                d = det(name, X[m : m + 1], cand)[0]
                p[m] = cand[np.argmin(d)]
            h *= shrink
        v = np.array([det(name, X[m : m + 1], p[m : m + 1])[0, 0] for m in range(M)])
        better = v < best_v
        best_v[better], best_p[better] = v[better], p[better]
    rng = vals.max(axis=1) - vals.min(axis=1)
    near = vals <= best_v[:, None] + 1e-3 * rng[:, None]
    dist = np.linalg.norm(G[None] - best_p[:, None], axis=2)
    if dom == "pyramid":
        dist = np.linalg.norm(G[None, :, :2] - best_p[:, None, :2], axis=2)
    unique = ~np.any(near & (dist > 0.2), axis=1)
    return best_v, best_p, unique
