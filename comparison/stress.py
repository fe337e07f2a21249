"""Generated repair test meshes: graded curved Gmsh solids, stress tests, a single fold, a hex + prism block.

Every mesh here is generated (Gmsh through its Python API, numpy), seeded; none is copied from anywhere.

* :func:`graded_solid` -- a curved solid with graded element sizes: a quarter annulus (radii 1 and 2) meshed
  with quads, the radial lines graded (Gmsh ``Progression``), revolved by 90 degrees about an axis beside it.
* :func:`stress` -- a fraction of the *interior* vertices moved by a random vector of length up to
  ``amp`` x the local edge length (uniform in a ball), as the published stress tests do (interior noise, the
  boundary surface kept).
* :func:`scatter_interior` -- every *interior* vertex at the centroid of the mesh, or anywhere in its bounding box
  (uniform): a start that keeps nothing of the interior but its connectivity (every hex inverted or of no size but
  those with seven boundary vertices), beyond the published stress tests.
* :func:`single_fold` -- a Gmsh box mesh in which one boundary hex has its boundary face moved to where the
  hex stays positive at all 8 corners but folds inside, and every other hex stays valid.
* :func:`hex_prism_block` -- an extruded square split into a quad half (hexahedra) and a
  triangle half (prisms) sharing nodes, interior nodes near the interface moved by up to ``amp`` (seeded).
* :func:`subdivided_solid` -- a CAD solid (OpenCASCADE through Gmsh) meshed with tetrahedra, each split into four
  hexes by Gmsh (``Mesh.SubdivisionAlgorithm`` 2): an unstructured all-hex mesh with singular edges everywhere,
  most boundary vertices on curved faces and feature curves.
* :func:`slide_boundary` -- a fraction of the *boundary* vertices slid along the boundary surface (each to the
  surface's nearest point to a point ``amp`` edge lengths away in a random direction): the boundary hexes fold
  where a meshing pipeline's projection onto the surface folds them, and the surface stays the same.
"""

from __future__ import annotations

import numpy as np

from gmsh_plugin.model import model_cells
from hexsos_plugins.examples import gmsh_model
from hexsos_plugins.meshrepair.boundary import interior_vertices

__all__ = ["graded_solid", "stress", "scatter_interior", "single_fold", "hex_prism_block",
           "subdivided_solid", "slide_boundary", "SOLIDS"]

#: The solids of :func:`subdivided_solid`
SOLIDS = ("sphere", "torus", "holed_box", "cone")


def graded_solid(n: int = 8, *, progression: float = 1.15):
    """Points and hexes of a graded curved solid with 2n x n x 2n hexes (see the module docstring)."""
    with gmsh_model("hexsos-graded") as gmsh:
        g = gmsh.model.geo
        c = g.addPoint(0, 0, 0)
        a1, a2 = g.addPoint(1, 0, 0), g.addPoint(2, 0, 0)
        b1, b2 = g.addPoint(0, 1, 0), g.addPoint(0, 2, 0)
        inner, outer = g.addCircleArc(a1, c, b1), g.addCircleArc(a2, c, b2)
        l1, l2 = g.addLine(a1, a2), g.addLine(b1, b2)
        loop = g.addCurveLoop([l1, outer, -l2, -inner])
        surf = g.addPlaneSurface([loop])
        g.mesh.setTransfiniteCurve(inner, 2 * n + 1)
        g.mesh.setTransfiniteCurve(outer, 2 * n + 1)
        g.mesh.setTransfiniteCurve(l1, n + 1, "Progression", progression)
        g.mesh.setTransfiniteCurve(l2, n + 1, "Progression", progression)
        g.mesh.setTransfiniteSurface(surf)
        g.mesh.setRecombine(2, surf)
        g.revolve([(2, surf)], 3, 0, 0, 0, 1, 0, np.pi / 2, numElements=[2 * n], recombine=True)
        g.synchronize()
        gmsh.model.mesh.generate(3)
        mc = model_cells()
        P, cells = mc.points, mc.cells
        return P, dict(cells)["hexahedron"]


def stress(P, H, *, frac: float = 0.8, amp: float = 1.0, seed: int = 0):
    """A copy of P with ``frac`` of the interior vertices moved by up to ``amp`` x the local edge length."""
    from hexsos_plugins.meshrepair.paper import hex_edge_length

    P = np.array(P, dtype=np.float64, copy=True)
    rng = np.random.default_rng(seed)
    inner = np.flatnonzero(interior_vertices([("hexahedron", H)], len(P)))
    pick = rng.choice(inner, size=int(round(frac * inner.size)), replace=False)
    # local edge length: mean over the hexes around each vertex
    h = hex_edge_length(P[H])
    s = np.bincount(H.ravel(), weights=np.repeat(h, 8), minlength=len(P)) / np.maximum(
        np.bincount(H.ravel(), minlength=len(P)), 1)
    d = rng.standard_normal((pick.size, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = amp * s[pick] * rng.random(pick.size) ** (1.0 / 3.0)
    P[pick] += r[:, None] * d
    return P


def scatter_interior(P, H, *, where: str = "box", seed: int = 0):
    """A copy of P with every interior vertex at the centroid of P (``where="centroid"``) or at a uniform random
    point of P's bounding box (``"box"``)."""
    P = np.array(P, dtype=np.float64, copy=True)
    inner = interior_vertices([("hexahedron", H)], len(P))
    if where == "centroid":
        P[inner] = P.mean(axis=0)
    elif where == "box":
        lo, hi = P.min(axis=0), P.max(axis=0)
        P[inner] = lo + np.random.default_rng(seed).random((int(inner.sum()), 3)) * (hi - lo)
    else:
        raise ValueError(f"where: expected 'centroid' or 'box', found {where!r}")
    return P


def single_fold(n: int = 5, *, seed: int = 0):
    """A Gmsh box mesh (n^3 hexes) with one boundary hex valid at its 8 corners but folded inside.

    Returns points, hexes and the index of the folded hex.
    """
    from hexsos_plugins import check
    from hexsos_plugins.examples import gmsh_mesh
    from hexsos_plugins.meshrepair.fidelity import boundary_quads

    P, H = gmsh_mesh("box", n)
    P = P.copy()
    quads = boundary_quads(H)
    top = quads[np.isclose(P[quads][:, :, 2], 1.0).all(axis=1)]
    f = top[np.argmin(np.linalg.norm(P[top].mean(axis=1)[:, :2] - 0.5, axis=1))]
    near = np.flatnonzero(np.isin(H, f).any(axis=1))
    m = int(near[np.argmax(np.isin(H[near], f).sum(axis=1))])
    rng = np.random.default_rng(seed)
    h = 1.0 / n
    K = 4000
    for _ in range(20):
        d = rng.uniform(-0.9, 0.9, (K, 4, 3)) * h
        Q = np.repeat(P[None], K, axis=0)
        Q[:, f] += d
        X = Q[:, H[near]]  # (K, len(near), 8, 3)
        r = check(X.reshape(-1, 3), np.arange(X.shape[0] * X.shape[1] * 8).reshape(-1, 8))
        st = r.status.reshape(K, -1)
        io = r.invalid_inside_only.reshape(K, -1)
        j = int(np.flatnonzero(near == m)[0])
        ok = io[:, j] & (np.delete(st, j, axis=1) == 1).all(axis=1)
        if ok.any():
            k = int(np.flatnonzero(ok)[0])
            P[f] += d[k]
            return P, H, m
    raise RuntimeError("single_fold: no corner-valid fold found")


def hex_prism_block(n: int = 6, *, amp: float = 0.2, seed: int = 0, layers: int = 5):
    """Issue 14's mesh: points and [("hexahedron", H), ("wedge", W)] (VTK order), interface nodes moved."""
    with gmsh_model("hexsos-mix") as gmsh:
        g = gmsh.model.geo
        p = [g.addPoint(x, y, 0) for x, y in ((0, 0), (1, 0), (2, 0), (2, 1), (1, 1), (0, 1))]
        lines = [g.addLine(p[i], p[(i + 1) % 6]) for i in range(6)]
        mid = g.addLine(p[1], p[4])
        left = g.addPlaneSurface([g.addCurveLoop([lines[0], mid, lines[4], lines[5]])])
        right = g.addPlaneSurface([g.addCurveLoop([lines[1], lines[2], lines[3], -mid])])
        for c in lines + [mid]:
            g.mesh.setTransfiniteCurve(c, n + 1)
        g.mesh.setTransfiniteSurface(left)
        g.mesh.setRecombine(2, left)
        g.extrude([(2, left), (2, right)], 0, 0, 1, numElements=[layers], recombine=True)
        g.synchronize()
        gmsh.model.mesh.generate(3)
        mc = model_cells()
        P, cells = mc.points, mc.cells
    cells = dict(cells)
    H, W = cells["hexahedron"], cells["wedge"]
    rng = np.random.default_rng(seed)
    inner = np.flatnonzero(interior_vertices([("hexahedron", H), ("wedge", W)], len(P))
                           & (np.abs(P[:, 0] - 1.0) < 0.35))
    d = rng.uniform(-1, 1, (inner.size, 3))
    P = P.copy()
    P[inner] += amp * d
    return P, [("hexahedron", H), ("wedge", W)]


def subdivided_solid(shape: str = "sphere", size: float = 0.25):
    """Points and hexes of a solid of :data:`SOLIDS` meshed with tetrahedra of edge length up to ``size`` and each
    split into four hexes by Gmsh (see the module docstring): a sphere of radius 1, a torus (radii 1 and 0.4), a
    2 x 1 x 1 box with a cylindrical hole of radius 0.3 through it, a cone (radii 1 and 0.2, height 1.5)."""
    from hexsos_plugins.errors import InvalidInputError

    if shape not in SOLIDS:
        raise InvalidInputError(f"shape: expected one of {', '.join(SOLIDS)}, found {shape!r}")
    with gmsh_model(f"hexsos-{shape}") as gmsh:
        o = gmsh.model.occ
        if shape == "sphere":
            o.addSphere(0, 0, 0, 1)
        elif shape == "torus":
            o.addTorus(0, 0, 0, 1, 0.4)
        elif shape == "holed_box":
            box = o.addBox(0, 0, 0, 2, 1, 1)
            hole = o.addCylinder(1, 0.5, -0.1, 0, 0, 1.2, 0.3)
            o.cut([(3, box)], [(3, hole)])
        else:
            o.addCone(0, 0, 0, 0, 0, 1.5, 1, 0.2)
        o.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", float(size))
        gmsh.option.setNumber("Mesh.SubdivisionAlgorithm", 2)
        gmsh.model.mesh.generate(3)
        mc = model_cells()
    H = dict(mc.cells)["hexahedron"]
    used, H = np.unique(H, return_inverse=True)  # the points of the hexes only (Gmsh keeps the geometry's nodes)
    return np.ascontiguousarray(mc.points[used]), H.reshape(-1, 8)


def slide_boundary(P, H, *, frac: float = 0.1, amp: float = 0.8, seed: int = 0):
    """A copy of P with ``frac`` of the boundary vertices slid along the boundary surface by about ``amp`` x the
    mean boundary edge length (see the module docstring; libigl's point-mesh distance)."""
    import igl

    from hexsos_plugins.meshrepair.fidelity import boundary_quads

    P = np.array(P, dtype=np.float64, copy=True)
    q = boundary_quads(H)
    tris = np.ascontiguousarray(np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]), dtype=np.int64)
    b = np.unique(q)
    h = float(np.linalg.norm(P[q[:, 1]] - P[q[:, 0]], axis=1).mean())
    rng = np.random.default_rng(seed)
    pick = rng.choice(b, size=max(1, int(round(frac * b.size))), replace=False)
    d = rng.standard_normal((pick.size, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    _, _, C = igl.point_mesh_squared_distance(P[pick] + amp * h * d, P, tris)
    P[pick] = C
    return P
