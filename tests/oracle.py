"""An independent oracle for min det J: dense sampling with zooming, written without the kernel's code.

det J is computed from the shape-function derivatives and numpy's determinant, a different path from
the kernel's triple products and Bernstein coefficients.
"""

import numpy as np

CORNERS = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)], float)


def det_j(X, p):
    """det J of hexes X (M, 8, 3) at points p (M, K, 3) -> (M, K)."""
    u, v, w = p[..., 0], p[..., 1], p[..., 2]  # (M, K)
    J = [[0.0] * 3 for _ in range(3)]  # J[c][d] = d x_c / d u_d
    for n, (a, b, c) in enumerate(CORNERS):
        lu, lv, lw = (u if a else 1 - u), (v if b else 1 - v), (w if c else 1 - w)
        dN = ((2 * a - 1) * lv * lw, (2 * b - 1) * lu * lw, (2 * c - 1) * lu * lv)
        for comp in range(3):
            x = X[:, n, comp][:, None]
            for d in range(3):
                J[comp][d] = J[comp][d] + x * dN[d]
    return (J[0][0] * (J[1][1] * J[2][2] - J[1][2] * J[2][1]) - J[0][1] * (J[1][0] * J[2][2] - J[1][2] * J[2][0])
            + J[0][2] * (J[1][0] * J[2][1] - J[1][1] * J[2][0]))


def dense_min(X, *, grid=21, zooms=8, starts=4, shrink=0.2):
    """Dense minimum of det J over [0, 1]^3 for hexes X (M, 8, 3).

    A grid**3 sample, then from the ``starts`` best distinct grid points, ``zooms`` rounds of a 9**3
    sample on a box around the current best, shrinking by ``shrink`` each round.

    Returns
    -------
    value : (M,), point : (M, 3), unique : (M,) bool, True where every grid point within 1e-3 * scale of the
    minimum lies within 0.15 of the minimizer (an isolated minimizer, so comparing argmins makes sense).
    """
    X = np.asarray(X, float).reshape(-1, 8, 3)
    M = X.shape[0]
    g = np.linspace(0, 1, grid)
    G = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    vals = np.concatenate([det_j(X[i : i + 16], np.broadcast_to(G, (min(16, M - i),) + G.shape)) for i in range(0, M, 16)])
    order = np.argsort(vals, axis=1)
    best_v = np.full(M, np.inf)
    best_p = np.zeros((M, 3))
    h0 = 1.0 / (grid - 1)
    t = np.linspace(-1, 1, 9)
    T = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)
    for s in range(starts):
        # the s-th best grid point that is not next to a better one already taken
        p = G[order[:, s * 3]].copy()
        h = h0
        for _ in range(zooms):
            P = np.clip(p[:, None, :] + h * T[None], 0, 1)
            d = det_j(X, P)
            k = d.argmin(axis=1)
            p = P[np.arange(M), k]
            h *= shrink
        v = det_j(X, p[:, None, :])[:, 0]
        better = v < best_v
        best_v[better], best_p[better] = v[better], p[better]
    scale = np.abs(vals).max(axis=1)
    near = vals <= best_v[:, None] + 1e-3 * scale[:, None]
    dist = np.linalg.norm(G[None] - best_p[:, None], axis=2)
    unique = ~np.any(near & (dist > 0.15), axis=1)
    return best_v, best_p, unique
