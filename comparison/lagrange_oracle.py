"""Independent samplers of det J for the Lagrange cells of orders 3-5: VTK's own Lagrange cells
(``vtkLagrangeTetra``, ``vtkLagrangeHexahedron``, ``vtkLagrangeWedge``: ``InterpolateDerivs``) and Gmsh's
``getJacobians``, on cells given in hexsos' node order (VTK's; pyramids Gmsh's).

VTK 9.7 has no Lagrange pyramid class: pyramids are sampled by Gmsh only. Gmsh 4.15 cannot evaluate prisms of
order 3 and above ("FaceClosureFull not implemented for prisms of order 3"): prisms are sampled by VTK only.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["VTK_CLASSES", "vtk_cell", "vtk_derivatives", "vtk_det", "gmsh_det", "gmsh_can_evaluate", "reference_cell",
           "domain_points", "valid_at_nodes_invalid_inside"]

VTK_CLASSES = {"tet": "vtkLagrangeTetra", "cube": "vtkLagrangeHexahedron", "prism": "vtkLagrangeWedge"}


def vtk_cell(name):
    """A VTK Lagrange cell of the type's order with nodes 0..n-1 (its points to be set by the caller)."""
    import vtkmodules.vtkCommonDataModel as dm

    from hexsos_plugins.cells.elements import ELEMENTS

    el = ELEMENTS[name]
    c = getattr(dm, VTK_CLASSES[el.domain])()
    n = el.n_nodes
    c.GetPointIds().SetNumberOfIds(n)
    c.GetPoints().SetNumberOfPoints(n)
    for i in range(n):
        c.GetPointIds().SetId(i, i)
        c.GetPoints().SetPoint(i, 0.0, 0.0, 0.0)
    c.Initialize()
    if hasattr(c, "SetUniformOrderFromNumPoints"):
        c.SetUniformOrderFromNumPoints(n)
    return c


def vtk_parametric_coords(name):
    c = vtk_cell(name)
    n = c.GetNumberOfPoints()
    pc = c.GetParametricCoords()
    return np.array([pc[i] for i in range(3 * n)]).reshape(n, 3)


@lru_cache(maxsize=64)
def _derivs(name, key):
    pts = np.frombuffer(key).reshape(-1, 3)
    c = vtk_cell(name)
    n = c.GetNumberOfPoints()
    out = np.empty((len(pts), n, 3))
    d = [0.0] * (3 * n)
    node_major = c.GetClassName() == "vtkLagrangeHexahedron"
    for k, p in enumerate(pts):
        c.InterpolateDerivs(list(map(float, p)), d)
        # VTK 9.7: vtkLagrangeHexahedron gives the derivatives node by node (n, 3); vtkLagrangeTetra and
        # vtkLagrangeWedge direction by direction (3, n), as the linear cells do (measured: the other reading
        # disagrees with the shape functions' own finite differences by O(1))
        out[k] = np.array(d).reshape(n, 3) if node_major else np.array(d).reshape(3, n).T
    return out


def vtk_derivatives(name, pts):
    """VTK's shape-function derivatives (K, n, 3) at parametric points pts (K, 3)."""
    return _derivs(name, np.ascontiguousarray(pts, dtype=np.float64).tobytes())


def vtk_det(name, X, pts):
    """det J of cells X (M, n, 3) (hexsos' node order = VTK's) at pts (K, 3) by VTK's shape functions: (M, K)."""
    dN = vtk_derivatives(name, pts)
    return np.linalg.det(np.einsum("mna,knd->mkad", np.asarray(X, float).reshape(-1, dN.shape[1], 3), dN))


def gmsh_can_evaluate(name) -> bool:
    """Whether Gmsh 4.15 evaluates the type given its nodes (not prisms of order >= 3; of its incomplete cells, not
    the pyramids, whose basis it does not interpolate, nor the hexahedra of orders 4 and 5, which it cannot take
    back: see hexsos_plugins.cells.incomplete and tests/test_incomplete.py)."""
    from hexsos_plugins.cells.elements import ELEMENTS
    from hexsos_plugins.cells.incomplete import COMPLETE

    el = ELEMENTS[name]
    if name in COMPLETE and (el.domain == "pyramid" or (el.domain == "cube" and el.order >= 4)):
        return False
    return not (el.domain == "prism" and el.order >= 3)


def gmsh_det(name, X, pts):
    """Gmsh's det J (``getJacobians``) of cells X (M, n, 3) at pts (K, 3) (VTK's parametric coordinates), in our
    units: (M, K)."""
    from comparison.against_gmsh import gmsh_cells, gmsh_local
    from hexsos_plugins.cells.elements import ELEMENTS

    el = ELEMENTS[name]
    X = np.asarray(X, float)
    M, n = X.shape[:2]
    conn = np.arange(M * n).reshape(M, n)
    with gmsh_cells(X.reshape(-1, 3), [(name, conn)], "lagrange-det") as (gmsh, tags, factors):
        _, dets, _ = gmsh.model.mesh.getJacobians(el.gmsh_type, gmsh_local(el, pts).ravel().tolist(), tag=1)
    return np.asarray(dets).reshape(M, len(pts)) / el.gmsh_factor


def reference_cell(name):
    """The type's straight-sided reference cell in world coordinates, det J = 1 everywhere (pyramids: the right
    pyramid with apex (1/2, 1/2, 1), the measure 1)."""
    from hexsos_plugins.cells.elements import ELEMENTS

    el = ELEMENTS[name]
    X = el.reference_nodes.copy()
    if el.domain == "pyramid":
        X[:, 0] = X[:, 0] * (1 - X[:, 2]) + X[:, 2] / 2
        X[:, 1] = X[:, 1] * (1 - X[:, 2]) + X[:, 2] / 2
    return X


def domain_points(name, n, seed=0, top=0.999):
    """n random parametric points of the type's reference element (pyramids: t below ``top``)."""
    from hexsos_plugins.cells.elements import ELEMENTS

    dom = ELEMENTS[name].domain
    rng = np.random.default_rng(seed)
    p = rng.random((4 * n, 3))
    if dom == "tet":
        p = p[p.sum(axis=1) <= 1]
    elif dom == "prism":
        p = p[p[:, 0] + p[:, 1] <= 1]
    elif dom == "pyramid":
        p[:, 2] *= top
    return p[:n]


def valid_at_nodes_invalid_inside(name):
    """A cell whose det J is > 0 at every node but < 0 somewhere inside (on a dense sample), or None: the first of
    a seeded sequence of perturbed reference cells (growing noise on every node, then a little on the edge and
    inner nodes only, which the 44-node hexahedron and the 33-node wedge need) that is so."""
    from hexsos_plugins.cells.elements import ELEMENTS

    el = ELEMENTS[name]
    nodes = el.reference_nodes  # (the pyramid's apex: the measure at (0, 0, 1))
    pts = domain_points(name, 1500, seed=1)
    rng = np.random.default_rng(17)
    X0 = reference_cell(name)

    def first(X):
        ok = (el.det(X, nodes).min(axis=1) > 1e-3) & (el.det(X, pts).min(axis=1) < -1e-3)
        return X[int(np.argmax(ok))] if ok.any() else None

    for sigma in (0.05, 0.08, 0.1, 0.12, 0.15, 0.2, 0.3):
        X = first(X0[None] + sigma / el.order * rng.standard_normal((200,) + X0.shape))
        if X is not None:
            return X
    for sigma in (0.015, 0.02, 0.025, 0.03, 0.04):
        X = np.repeat(X0[None], 2000, axis=0)
        X[:, el.corners:] += sigma * rng.standard_normal((2000, el.n_nodes - el.corners, 3))
        X = first(X)
        if X is not None:
            return X
    return None
