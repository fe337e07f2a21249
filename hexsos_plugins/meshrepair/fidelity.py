"""Boundary fidelity of a repair: how far the boundary surface moved, and whether it self-intersects.

Computed with pymeshlab (optional dependency, extra ``fidelity``: ``pip install 'hexsos[fidelity]'``) on the
boundary quads of the hex mesh (faces that belong to one hex only), each split into two triangles along
the diagonal 0-2. The connectivity is the same before and after, so both surfaces have the same quads.

* Hausdorff distance, both directions (pymeshlab's ``get_hausdorff_distance``: points sampled on one
  surface -- its vertices, edges and faces -- to the closest point of the other), reported as the
  symmetric max (the larger of the two maxima) and the larger of the two means; also relative to the
  bounding-box diagonal of the boundary before repair.
* Self-intersecting boundary faces (``compute_selection_by_self_intersections_per_face``), counted as
  quads (a quad counts when either of its triangles is selected), before and after. MeshLab's test does not
  report adjacent triangles folded onto each other (measured: two triangles sharing an edge, folded
  almost flat onto each other, are not selected), so a fold along a boundary edge is not counted there.
"""

from __future__ import annotations

import numpy as np

from ..errors import DependencyError, InvalidInputError
from ..cells.elements import HEX_FACES

__all__ = ["boundary_fidelity", "boundary_quads", "surface_area", "FAR_FRACTION"]

#: A repaired boundary whose Hausdorff distance to the input's is more than this fraction of the input
#: boundary's bounding-box diagonal is far from it: ``hexsos repair`` says so in a warning
FAR_FRACTION = 0.02


def _pymeshlab():
    try:
        import pymeshlab
    except ImportError as exc:
        raise DependencyError("boundary fidelity needs pymeshlab: pip install 'hexsos[fidelity]'") from exc
    return pymeshlab


def boundary_quads(hexes) -> np.ndarray:
    """The quads (F, 4) that belong to exactly one hex, in the hex's local face order (outward when the
    hex is positively oriented)."""
    H = np.asarray(hexes, dtype=np.int64)
    faces = H[:, HEX_FACES].reshape(-1, 4)
    key = np.sort(faces, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inv.ravel()] == 1]


def surface_area(V, tri) -> float:
    """The area of the triangles ``tri`` (T, 3) at ``V``."""
    a = np.cross(V[tri[:, 1]] - V[tri[:, 0]], V[tri[:, 2]] - V[tri[:, 0]])
    return 0.5 * float(np.sqrt((a * a).sum(axis=1)).sum())


def _surface(points, quads, tris=None):
    """Vertices (only those on the boundary) and triangles: the quads split along the diagonal 0-2 (quad k
    gives triangles k and Q + k), then the boundary triangles."""
    tris = np.zeros((0, 3), dtype=np.int64) if tris is None else tris
    used, local = np.unique(np.concatenate([quads.ravel(), tris.ravel()]), return_inverse=True)
    local = local.ravel()
    q = local[:quads.size].reshape(-1, 4)
    t = local[quads.size:].reshape(-1, 3)
    out = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]], t])
    return np.ascontiguousarray(points[used], dtype=np.float64), np.ascontiguousarray(out, dtype=np.int32)


def boundary_fidelity(points_before, points_after, hexes, *, cells=None, samples_per_face: int = 10) -> dict:
    """Hausdorff distance between the boundary surfaces before and after, and their self-intersections.

    Parameters
    ----------
    points_before, points_after : array_like, shape (N, 3)
        The same mesh's coordinates before and after repair.
    hexes : array_like of int, shape (M, 8), VTK node order
    cells : list of (cell type, connectivity), optional, keyword-only
        The mesh's other 3-D cells (VTK order): their faces are part of the boundary surface (mixed meshes).
    samples_per_face : int, keyword-only
        Sample points per triangle for the Hausdorff distance (plus the vertices and edges). Default 10.

    Returns
    -------
    dict with ``hausdorff_max`` (symmetric: the larger of both directions' maxima), ``hausdorff_mean``
    (the larger of both directions' means), ``hausdorff_max_relative`` and ``hausdorff_mean_relative``
    (divided by ``bbox_diagonal``, of the boundary before), ``hausdorff_forward`` / ``hausdorff_backward``
    (max, mean, samples of each direction), ``self_intersecting_before`` / ``self_intersecting_after``
    (boundary quads with a self-intersecting triangle), ``boundary_quads``, ``boundary_vertices_moved``. Where
    the surface before or after has no area (every point of it on one line), the Hausdorff entries are None and
    ``hausdorff_note`` says why: pymeshlab cannot sample such a surface.

    Raises
    ------
    DependencyError
        pymeshlab is not installed.
    InvalidInputError
        the point arrays differ in shape or are not (N, 3).
    """
    A = np.asarray(points_before, dtype=np.float64)
    B = np.asarray(points_after, dtype=np.float64)
    if A.ndim != 2 or A.shape[1] != 3 or A.shape != B.shape:
        raise InvalidInputError(f"points_before and points_after: expected two arrays of the same shape (N, 3), "
                                f"found {A.shape} and {B.shape}")
    if cells:
        from .boundary import boundary_faces

        tris, quads = boundary_faces([("hexahedron", np.asarray(hexes, dtype=np.int64))] + list(cells))
    else:
        tris, quads = np.zeros((0, 3), dtype=np.int64), boundary_quads(hexes)
    top = max(int(quads.max()) if quads.size else -1, int(tris.max()) if tris.size else -1)
    if top >= A.shape[0]:
        raise InvalidInputError(f"hexes: node index {top} out of range ({A.shape[0]} points)")
    ml = _pymeshlab()
    if quads.shape[0] + tris.shape[0] == 0:
        zero = {"max": 0.0, "mean": 0.0, "samples": 0}
        return {"hausdorff_max": 0.0, "hausdorff_mean": 0.0, "hausdorff_max_relative": 0.0,
                "hausdorff_mean_relative": 0.0, "bbox_diagonal": 0.0, "hausdorff_forward": zero,
                "hausdorff_backward": zero, "self_intersecting_before": 0, "self_intersecting_after": 0,
                "boundary_quads": 0, "boundary_vertices_moved": 0}
    va, tri = _surface(A, quads, tris)
    vb, _ = _surface(B, quads, tris)
    diag = float(np.linalg.norm(va.max(axis=0) - va.min(axis=0)))
    ms = ml.MeshSet()
    ms.add_mesh(ml.Mesh(vertex_matrix=va, face_matrix=tri), "before")
    ms.add_mesh(ml.Mesh(vertex_matrix=vb, face_matrix=tri), "after")
    flat = [name for name, v in (("before", va), ("after", vb)) if not surface_area(v, tri) > 0]
    if flat:
        # pymeshlab cannot sample a surface of no area (its points coincident or on one line): measured, its
        # Hausdorff filter crashes the process (segmentation fault) sampling one and does not return targeting one
        fwd = bwd = None
    else:
        big = ml.PureValue(1e30)  # no cut-off: every sample counts (the default ignores distances > 5% of the bbox)
        n = int(samples_per_face) * tri.shape[0] + va.shape[0]
        kw = dict(samplevert=True, sampleedge=True, sampleface=True, samplenum=n, maxdist=big)
        fwd = ms.get_hausdorff_distance(sampledmesh=0, targetmesh=1, **kw)
        bwd = ms.get_hausdorff_distance(sampledmesh=1, targetmesh=0, **kw)
    nq = quads.shape[0]

    def self_intersecting(mesh_id):
        ms.set_current_mesh(mesh_id)
        ms.compute_selection_by_self_intersections_per_face()
        sel = ms.current_mesh().face_selection_array()
        return int((sel[:nq] | sel[nq:2 * nq]).sum() + sel[2 * nq:].sum())

    before, after = self_intersecting(0), self_intersecting(1)
    moved = int(np.any(va != vb, axis=1).sum())
    if fwd is None:
        return {"hausdorff_max": None, "hausdorff_mean": None, "hausdorff_max_relative": None,
                "hausdorff_mean_relative": None, "bbox_diagonal": diag, "hausdorff_forward": None,
                "hausdorff_backward": None,
                "hausdorff_note": f"not computed: the boundary surface {' and '.join(flat)} the repair has no area",
                "self_intersecting_before": before, "self_intersecting_after": after, "boundary_quads": quads.shape[0],
                "boundary_triangles": int(tris.shape[0]), "boundary_vertices_moved": moved}
    hmax = float(max(fwd["max"], bwd["max"]))
    hmean = float(max(fwd["mean"], bwd["mean"]))
    if moved == 0:  # identical surfaces: exactly 0 (pymeshlab computes in single precision)
        hmax = hmean = 0.0
    return {
        "hausdorff_max": hmax,
        "hausdorff_mean": hmean,
        "hausdorff_max_relative": hmax / diag if diag > 0 else 0.0,
        "hausdorff_mean_relative": hmean / diag if diag > 0 else 0.0,
        "bbox_diagonal": diag,
        "hausdorff_forward": {"max": float(fwd["max"]), "mean": float(fwd["mean"]), "samples": int(fwd["n_samples"])},
        "hausdorff_backward": {"max": float(bwd["max"]), "mean": float(bwd["mean"]), "samples": int(bwd["n_samples"])},
        "self_intersecting_before": before,
        "self_intersecting_after": after,
        "boundary_quads": nq,
        "boundary_triangles": int(tris.shape[0]),
        "boundary_vertices_moved": moved,
    }

