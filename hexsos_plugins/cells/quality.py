"""Verdict's scaled Jacobian per cell: the quality number hex-meshing papers, HexaLab and ParaView report.

The scaled Jacobian of a cell is the smallest normalized determinant of the edge vectors met at its corners:
1 for the ideal cell, 0 for a cell with a collapsed corner, negative where a corner is inverted. It is
computed at corners only (a hex can fold inside with every corner positive: that is what
:func:`hexsos_plugins.check` is for); it measures shape, not validity. Definitions, as ``vtkMeshQuality``
(Verdict) computes them with ``Set*QualityMeasureToScaledJacobian`` (tested against it on random cells,
inverted ones included):

* **hexahedron**: min over 9 samples of ``det[e1, e2, e3] / (|e1| |e2| |e3|)``: the 8 corners (the three
  edges leaving each corner, in right-handed order) and the centre (the three principal axes, each the sum
  of the four parallel edges).
* **tetra**: ``sqrt(2) det[x1 - x0, x2 - x0, x3 - x0] / max over corners of the product of its 3 edge
  lengths`` (1 for the regular tetrahedron).
* **wedge**: ``2 / sqrt(3)`` times the min over the 6 corners of the normalized corner determinant.
* **pyramid**: ``2`` times the min over the 4 base corners i of the tet scaled Jacobian / sqrt(2) of the tet
  (i, i + 1, i - 1, apex) (1 for the pyramid with all edges equal). vtkMeshQuality clamps negative pyramid
  values to 0; here the sign is kept (an inverted pyramid reads negative, as every other type does). Values
  above 1 (possible for pyramids only) are reflected to 2 - v, as Verdict does.
* any other cell type (quadratic cells, ...): NaN.

Cells are given in VTK node order (:mod:`hexsos_plugins.cells.elements`). Every corner determinant here is
linear in the vertex coordinates per column, ``E_k = X^T G_k`` with a constant (nodes, 3) matrix ``G_k``
per sample: :data:`SAMPLES` holds them, and the repair's optimizer uses the same tables.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError
from .hexahedron import EDGES

__all__ = ["scaled_jacobian", "summary", "sj_text", "sample_scaled_jacobians", "unit_edges", "det3", "SAMPLES",
           "LINEAR_TYPES", "IDEAL", "as_cell_list", "sample_edges", "hex_edge_ratio", "edge_ratio_summary",
           "SHORT_EDGE_RATIO"]

#: A hex whose shortest edge is below this fraction of its longest is counted in the reports (an aspect ratio
#: above 20): the scaled Jacobian does not see an edge's length, and a hex with an edge collapsed toward 0 can
#: score near 1 at every corner.
SHORT_EDGE_RATIO = 0.05

#: The cell types with a scaled Jacobian (linear 3-D cells).
LINEAR_TYPES = ("hexahedron", "tetra", "wedge", "pyramid")

_S3 = np.sqrt(3.0)
#: The ideal cell of each type with edge length 1, VTK node order (positively oriented).
IDEAL = {
    "hexahedron": np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)],
                           dtype=np.float64),
    "tetra": np.array([(0, 0, 0), (1, 0, 0), (0.5, _S3 / 2, 0), (0.5, _S3 / 6, np.sqrt(2.0 / 3.0))]),
    "wedge": np.array([(0, 0, 0), (1, 0, 0), (0.5, _S3 / 2, 0), (0, 0, 1), (1, 0, 1), (0.5, _S3 / 2, 1)]),
    "pyramid": np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0.5, 0.5, np.sqrt(0.5))]),
}

# corner samples: (corner node, its three neighbours); the column order is fixed below so that the ideal cell
# has a positive determinant
_CORNERS = {
    "hexahedron": [(0, (1, 3, 4)), (1, (2, 0, 5)), (2, (3, 1, 6)), (3, (0, 2, 7)),
                   (4, (7, 5, 0)), (5, (4, 6, 1)), (6, (5, 7, 2)), (7, (6, 4, 3))],
    "tetra": [(0, (1, 2, 3)), (1, (2, 0, 3)), (2, (0, 1, 3)), (3, (0, 2, 1))],
    "wedge": [(0, (1, 2, 3)), (1, (2, 0, 4)), (2, (0, 1, 5)), (3, (5, 4, 0)), (4, (3, 5, 1)), (5, (4, 3, 2))],
}
# pyramid: the corners of the 4 tets (i, i + 1, i - 1, apex), each tet's 4 corners
_PYR = []
for _i in range(4):
    _t = (_i, (_i + 1) % 4, (_i + 3) % 4, 4)
    for _c in range(4):
        _PYR.append((_t[_c], tuple(_t[j] for j in range(4) if j != _c)))
_CORNERS["pyramid"] = _PYR
#: Scale of each type's normalized corner determinant (1 for the ideal cell).
_FACTOR = {"hexahedron": 1.0, "tetra": np.sqrt(2.0), "wedge": 2.0 / _S3, "pyramid": 2.0}


def _build_samples():
    out = {}
    for name, corners in _CORNERS.items():
        n = IDEAL[name].shape[0]
        G = []
        for c, nb in corners:
            g = np.zeros((n, 3))
            for j, k in enumerate(nb):
                g[k, j] += 1.0
                g[c, j] -= 1.0
            if np.linalg.det(IDEAL[name].T @ g) < 0:  # right-handed on the ideal cell
                g = g[:, [1, 0, 2]]
            G.append(g)
        if name == "hexahedron":  # the centre: principal axes, each the mean of the four parallel edges
            g = np.zeros((8, 3))
            for axis, (plus, minus) in enumerate((([1, 2, 5, 6], [0, 3, 4, 7]), ([2, 3, 6, 7], [0, 1, 4, 5]),
                                                  ([4, 5, 6, 7], [0, 1, 2, 3]))):
                g[plus, axis] = 0.25
                g[minus, axis] = -0.25
            G.append(g)
        G = np.array(G)
        out[name] = (G, _FACTOR[name])
    return out


#: ``SAMPLES[name] = (G, factor)``: G (K, nodes, 3), the sample matrices (``E_k = X^T G_k``, columns the edge
#: vectors of sample k), and the factor that makes the ideal cell's scaled Jacobian 1.
SAMPLES = _build_samples()


def sample_edges(X, name) -> np.ndarray:
    """Edge matrices of every sample of cells X (M, n, 3) of type ``name``: (M, K, 3, 3), columns the edges."""
    G = SAMPLES[name][0]
    return np.einsum("mna,knd->mkad", X, G, optimize=True)


def unit_edges(E) -> np.ndarray:
    """Edge matrices E (M, K, 3, 3) (or any (M, ...) array of each cell's vectors), each cell's times the power of
    two that takes its largest |entry| into [0.5, 1): exact, so a scaled Jacobian from them is the same bit for bit,
    but a cell far from unit size (1e-140, 1e140) no longer underflows or overflows its edge products. Cells with no
    finite positive entry as they are.

    >>> E = np.eye(3)[None, None] * 2.0**-470  # 3.3e-142: its product of three edge lengths underflows to 0
    >>> U = unit_edges(E)
    >>> float(np.prod(np.linalg.norm(E, axis=2))), float(det3(U)[0, 0] / np.prod(np.linalg.norm(U, axis=2)))
    (0.0, 1.0)
    """
    E = np.asarray(E, dtype=np.float64)
    if E.shape[0] == 0:
        return E
    ext = np.abs(E).reshape(E.shape[0], -1).max(axis=1)
    ok = (ext > 0) & np.isfinite(ext)
    k = np.where(ok, np.frexp(np.where(ok, ext, 1.0))[1], 0)
    return np.ldexp(E, -k.reshape((-1,) + (1,) * (E.ndim - 1)))


def det3(E) -> np.ndarray:
    """Determinants of 3 x 3 matrices E (..., 3, 3) by the triple product of their columns, as the compiled kernel
    forms them (``numpy.linalg.det`` goes through logarithms: 0.125 (1 + 2**-52) for half the identity).

    >>> float(det3(0.5 * np.eye(3))), float(det3(np.array([[2.0, 0, 0], [0, 0, 3], [0, 1, 0]])))
    (0.125, -6.0)
    """
    a, b, c = E[..., :, 0], E[..., :, 1], E[..., :, 2]
    return (a[..., 0] * (b[..., 1] * c[..., 2] - b[..., 2] * c[..., 1])
            - b[..., 0] * (a[..., 1] * c[..., 2] - a[..., 2] * c[..., 1])
            + c[..., 0] * (a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]))


def sample_scaled_jacobians(X, name) -> np.ndarray:
    """Normalized corner determinants (M, K): ``factor * det E_k / (|e1| |e2| |e3|)`` per sample.

    For hexahedra and wedges the cell's scaled Jacobian is their minimum; for tetrahedra and pyramids it is
    per tet ``factor * det / max over the tet's corners of the edge-length product`` (equal to the minimum
    over its corners while det > 0): see :func:`scaled_jacobian`.
    """
    X = np.asarray(X, dtype=np.float64)
    E = unit_edges(sample_edges(X, name))
    det = det3(E)
    lengths = np.sqrt((E * E).sum(axis=2)).prod(axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = SAMPLES[name][1] * det / lengths
    return np.where(lengths > np.finfo(np.float64).tiny, v, 0.0)


def _cell_values(X, name) -> np.ndarray:
    if name in ("hexahedron", "wedge"):
        return sample_scaled_jacobians(X, name).min(axis=1)
    # tetra (one tet) and pyramid (four): det / the largest corner product of each tet
    E = unit_edges(sample_edges(np.asarray(X, dtype=np.float64), name))
    M = E.shape[0]
    det = det3(E).reshape(M, -1, 4)[:, :, 0]
    big = np.sqrt((E * E).sum(axis=2)).prod(axis=2).reshape(M, -1, 4).max(axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(big > np.finfo(np.float64).tiny, SAMPLES[name][1] * det / big, 0.0).min(axis=1)
    if name == "pyramid":  # Verdict reflects values above 1 (possible for pyramids only): 2 - v
        v = np.where(v > 1.0, 2.0 - v, v)
    return v


def as_cell_list(cells) -> list:
    """``cells`` as a list of (type name, (M, n) int array): an (M, 8) array is a list of one hexahedron block;
    meshio's cells and meshes as :func:`hexsos_plugins.cells.inputs.cell_pairs` takes them."""
    from .inputs import cell_pairs

    pairs, _ = cell_pairs(cells)
    cells = pairs if pairs is not None else cells
    if isinstance(cells, (list, tuple)) and (len(cells) == 0 or isinstance(cells[0], (list, tuple))):
        out = []
        for item in cells:
            if len(item) != 2:
                raise InvalidInputError(f"cells: expected (cell type, connectivity) pairs, found {item!r}")
            name, conn = item
            conn = np.asarray(conn)
            if conn.ndim != 2 or conn.dtype.kind not in "iu":
                raise InvalidInputError(f"cells: expected an integer (M, n) connectivity for {name!r}, "
                                        f"found shape {conn.shape} and dtype {conn.dtype}")
            out.append((str(name), conn.astype(np.int64, copy=False)))
        return out
    arr = np.asarray(cells)
    if arr.ndim != 2 or arr.shape[1] != 8 or arr.dtype.kind not in "iu":
        raise InvalidInputError(f"cells: expected an (M, 8) integer hex array or a list of (type, connectivity), "
                                f"found an array of shape {arr.shape} and dtype {arr.dtype}")
    return [("hexahedron", arr.astype(np.int64, copy=False))]


def scaled_jacobian(points, cells) -> np.ndarray:
    """Verdict's scaled Jacobian of every cell (see the module docstring).

    Parameters
    ----------
    points : array_like, shape (N, 3)
    cells : array_like of int, shape (M, 8) (hexahedra, VTK order), or a list of (cell type, connectivity)
        pairs (meshio names, VTK node order), e.g. ``[("hexahedron", H), ("wedge", W)]``.

    Returns
    -------
    ndarray, shape (C,): one value per cell, blocks in the order given; NaN for cell types without one.

    Examples
    --------
    >>> import numpy as np
    >>> from hexsos_plugins.cells.quality import IDEAL
    >>> float(scaled_jacobian(IDEAL["hexahedron"], np.arange(8)[None])[0])
    1.0
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InvalidInputError(f"points: expected shape (N, 3), found {P.shape}")
    out = []
    for name, conn in as_cell_list(cells):
        if conn.size and (conn.min() < 0 or conn.max() >= P.shape[0]):
            raise InvalidInputError(f"cells ({name}): node index out of range 0..{P.shape[0] - 1}")
        if name in SAMPLES and conn.shape[1] == IDEAL[name].shape[0]:
            out.append(_cell_values(P[conn], name) if conn.shape[0] else np.zeros(0))
        else:
            out.append(np.full(conn.shape[0], np.nan))
    return np.concatenate(out) if out else np.zeros(0)


def hex_edge_ratio(points, hexes) -> np.ndarray:
    """The shortest edge of every hex over its longest, (M,) in [0, 1] (0 where every edge has length 0)."""
    P = np.asarray(points, dtype=np.float64)
    H = np.asarray(hexes, dtype=np.int64).reshape(-1, 8)
    ln = np.linalg.norm(unit_edges(P[H[:, EDGES[:, 0]]] - P[H[:, EDGES[:, 1]]]), axis=2)
    hi = ln.max(axis=1) if len(H) else np.zeros(0)
    return np.divide(ln.min(axis=1) if len(H) else hi, hi, out=np.zeros_like(hi), where=hi > 0)


def edge_ratio_summary(points, hexes) -> tuple:
    """(least shortest / longest edge of a hex, hexes below :data:`SHORT_EDGE_RATIO`); (1.0, 0) without hexes."""
    r = hex_edge_ratio(points, hexes)
    return (float(r.min()) if r.size else 1.0, int((r < SHORT_EDGE_RATIO).sum()))


def sj_text(x) -> str:
    """A scaled Jacobian as the reports print it: four decimals, but three significant digits where four decimals
    would print a value that is not 0 as 0.0000 (a flat mesh's cells certified at 1e-6 read "certified, min 0.0000",
    as if one were degenerate)."""
    x = float(x)
    return f"{x:.2e}" if x != 0 and abs(x) < 5e-5 else f"{x:.4f}"


def summary(sj) -> dict:
    """``{"min", "p1", "mean"}`` of scaled Jacobians (NaN entries ignored; NaN when there are none).

    ``p1`` is the 1st percentile (numpy's linear interpolation).
    """
    a = np.asarray(sj, dtype=np.float64)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"min": float("nan"), "p1": float("nan"), "mean": float("nan")}
    return {"min": float(a.min()), "p1": float(np.percentile(a, 1.0)), "mean": float(a.mean())}
