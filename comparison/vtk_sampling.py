"""Dense sampling of det J on VTK's own shape-function derivatives (InterpolateDerivs): an oracle for min det J.

Independent of hexsos's registry and kernel: VTK gives dN/dpcoords at the sample points, numpy's determinant
gives det J; pyramids use det J / (1 - t)^2, sampled below the apex. A grid over the reference element, then
rounds of zooming around the best points. Used by the comparison harness (experiment 8) and by the tests.
"""

from functools import lru_cache

import numpy as np

CLASSES = {
    "tetra": "vtkTetra", "tetra10": "vtkQuadraticTetra", "pyramid": "vtkPyramid", "wedge": "vtkWedge",
    "wedge15": "vtkQuadraticWedge", "wedge18": "vtkBiQuadraticQuadraticWedge", "hexahedron": "vtkHexahedron",
    "hexahedron20": "vtkQuadraticHexahedron", "hexahedron27": "vtkTriQuadraticHexahedron",
}
DOMAIN = {"tetra": "tet", "tetra10": "tet", "pyramid": "pyramid", "wedge": "prism", "wedge15": "prism",
          "wedge18": "prism", "hexahedron": "cube", "hexahedron20": "cube", "hexahedron27": "cube"}


@lru_cache(maxsize=None)
def _cell(name):
    import vtkmodules.vtkCommonDataModel as dm

    return getattr(dm, CLASSES[name])()


def reference_nodes(name):
    c = _cell(name)
    n = c.GetNumberOfPoints()
    pc = c.GetParametricCoords()
    X = np.array([pc[i] for i in range(3 * n)]).reshape(n, 3)
    if name == "pyramid":
        X[4] = (0.5, 0.5, 1.0)
    return X


def derivatives(name, pts):
    """dN/dpcoords (K, n, 3) at pts (K, 3) from VTK."""
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
    return G[_inside(dom, G + 0.0)]


def dense_min(name, X, *, n=13, zooms=8, starts=3, shrink=0.25):
    """Dense minimum per cell: values (M,), points (M, 3) and a uniqueness flag (M,) (every grid point within
    1e-3 of the value range of the minimum lies within 0.2 of the minimizer)."""
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
