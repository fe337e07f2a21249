"""Whether two cells that share a face lie on opposite sides of it (unfolded) or on the same side (folded over each
other): an independent measure for the fold tests, by their centroids and the plane of the shared face."""

import numpy as np


def face_sides(P, H, a, b):
    """The signed distances of cells ``a``'s and ``b``'s centroids (rows of ``H`` into points ``P``) from the plane
    of the face they share (its nodes' least-squares plane); opposite signs: each on its own side."""
    P = np.asarray(P, dtype=np.float64)
    shared = [v for v in H[a] if v in H[b]]
    c = P[shared].mean(axis=0)
    n = np.linalg.svd(P[shared] - c)[2][2]
    return float((P[H[a]].mean(axis=0) - c) @ n), float((P[H[b]].mean(axis=0) - c) @ n)
