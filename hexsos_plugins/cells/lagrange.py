"""Complete Lagrange cells of any order, generated: node positions in VTK's and Gmsh's orders, exact shape functions.

A complete Lagrange cell of order p has its nodes on the equispaced lattice of its reference element (the lattice
points ``m / p``; pyramids: see below). Two node orders are generated here, each from its library's rules:

**VTK** (``vtkLagrangeTetra``, ``vtkLagrangeHexahedron``, ``vtkLagrangeWedge``, VTK cell types 71, 72, 73): the
corners, then every edge's inner nodes from its first vertex to its second (hexahedron and wedge: in the direction
of increasing parametric coordinate), then every face's inner nodes, then the inner nodes of the cell.

* tetrahedron: edges 01, 12, 20, 03, 13, 23; faces (0, 1, 3), (2, 3, 1), (0, 3, 2), (0, 2, 1), each face's inner
  nodes a triangle of order p - 3 in the same recursive order (corners, edges 01, 12, 20, inner triangle);
  the inner nodes a tetrahedron of order p - 4 in this order;
* hexahedron: edges 01, 12, 32, 03, 45, 56, 76, 47, 04, 15, 26, 37; faces r = 0, r = 1, s = 0, s = 1, t = 0,
  t = 1, each in lexicographic order of its two parameters (the lower one fastest); inner nodes lexicographic
  (r fastest);
* wedge: edges 01, 12, 20, 34, 45, 53, 03, 14, 25; the triangles t = 0, t = 1 (inner nodes lexicographic, r
  fastest), the quadrilaterals on edges 01, 12, 20 (along the edge fastest, then t); inner nodes: the triangle's
  inner nodes lexicographic, then t.

**Gmsh** (``gmshGenerateMonomials*`` of Gmsh's ``pointsGenerators.cpp`` with the edge and face tables of
``MTetrahedron``, ``MHexahedron``, ``MPrism``, ``MPyramid``): corners, edges (the element's edge table, from
the first vertex to the second), faces (the face table; a face's inner nodes are a triangle of order p - 3 or a
quadrilateral of order p - 2 in Gmsh's recursive order, spanned from the face's first vertex along its second
and last vertices), then the inner nodes recursively: a tetrahedron of order p - 4, a hexahedron of order p - 2,
a pyramid of order p - 3, and for the prism the inner triangle of order p - 3 times the inner line of order
p - 2 (line nodes in Gmsh's order: both ends, then the inside).

Pyramids (Gmsh's types 118, 119, 120; VTK 9.7 has no Lagrange pyramid class) keep Gmsh's order, as hexsos does
for the 14-node pyramid. Gmsh's pyramid lattice point (i, j, k) (k = 0 the apex, k = p the base) is, in VTK's
collapsed-cube coordinates (:mod:`hexsos_plugins.cells.elements`), ``(i / k, j / k, 1 - k / p)`` (the apex:
``(0, 0, 1)``); the pyramid space of Bergot et al. of order p spans the shape functions.

Shape functions are built exactly and directly (no linear solve) for the tensor-product and simplex types:
the hexahedron's are products of 1-D Lagrange polynomials, the tetrahedron's Silvester's products
``prod_d prod_{m < a_d} (p lambda_d - m) / (m + 1)`` over the barycentric coordinates lambda, the wedge's the
triangle's times the line's. Pyramids solve the (small) interpolation problem in Bergot's space.
"""

from __future__ import annotations

from fractions import Fraction

__all__ = ["vtk_lattice", "gmsh_lattice", "reference_nodes", "lagrange_shapes", "pyramid_collapsed", "TYPES",
           "lattice_count"]

_F = Fraction

# --- Gmsh's recursive sub-orders (lattice points of order q, integer coordinates) -----------------------------------


def gmsh_line(q):
    """Gmsh's line of order q: both ends, then the inside."""
    return [0] if q == 0 else [0, q] + list(range(1, q))


def recursive_triangle(q):
    """A triangle of order q, recursively: corners, edges 01, 12, 20, the inner triangle of order q - 3 (VTK's and
    Gmsh's triangle order)."""
    if q < 0:
        return []
    if q == 0:
        return [(0, 0)]
    corners = [(0, 0), (q, 0), (0, q)]
    out = list(corners)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        (xa, ya), (xb, yb) = corners[a], corners[b]
        out += [(xa + (xb - xa) * i // q, ya + (yb - ya) * i // q) for i in range(1, q)]
    out += [(1 + x, 1 + y) for x, y in recursive_triangle(q - 3)]
    return out


def gmsh_quad(q):
    """Gmsh's quadrilateral of order q: corners, edges 01, 12, 23, 30, the inner quadrilateral of order q - 2."""
    if q < 0:
        return []
    if q == 0:
        return [(0, 0)]
    corners = [(0, 0), (q, 0), (q, q), (0, q)]
    out = list(corners)
    for a in range(4):
        (xa, ya), (xb, yb) = corners[a], corners[(a + 1) % 4]
        out += [(xa + (xb - xa) * i // q, ya + (yb - ya) * i // q) for i in range(1, q)]
    out += [(1 + x, 1 + y) for x, y in gmsh_quad(q - 2)]
    return out


def _edge_points(V, edges, p):
    out = []
    for a, b in edges:
        out += [tuple(V[a][d] + (V[b][d] - V[a][d]) * i // p for d in range(3)) for i in range(1, p)]
    return out


def _face_points(V, face, p, sub):
    """Inner nodes of a face spanned from its first vertex along its second and last ones: sub gives the 2-D
    lattice points (a, b) (already shifted inside), the point is V0 + a (V1 - V0) / p + b (Vlast - V0) / p."""
    v0, v1, v2 = V[face[0]], V[face[1]], V[face[-1]]
    return [tuple(v0[d] + ((v1[d] - v0[d]) * a + (v2[d] - v0[d]) * b) // p for d in range(3)) for a, b in sub]


def _tri_inner(p):
    return [(1 + a, 1 + b) for a, b in recursive_triangle(p - 3)]


def _quad_inner_gmsh(p):
    return [(1 + a, 1 + b) for a, b in gmsh_quad(p - 2)] if p >= 2 else []


# --- the tables ----------------------------------------------------------------------------------------------
_TET_V = lambda p: [(0, 0, 0), (p, 0, 0), (0, p, 0), (0, 0, p)]  # noqa: E731
_HEX_V = lambda p: [(0, 0, 0), (p, 0, 0), (p, p, 0), (0, p, 0), (0, 0, p), (p, 0, p), (p, p, p), (0, p, p)]  # noqa: E731
_PRI_V = lambda p: [(0, 0, 0), (p, 0, 0), (0, p, 0), (0, 0, p), (p, 0, p), (0, p, p)]  # noqa: E731
# Gmsh's pyramid in its monomial lattice (k = 0 the apex): base corners at k = p
_PYR_V = lambda p: [(0, 0, p), (p, 0, p), (p, p, p), (0, p, p), (0, 0, 0)]  # noqa: E731

GMSH_EDGES = {
    "tet": ((0, 1), (1, 2), (2, 0), (3, 0), (3, 2), (3, 1)),
    "cube": ((0, 1), (0, 3), (0, 4), (1, 2), (1, 5), (2, 3), (2, 6), (3, 7), (4, 5), (4, 7), (5, 6), (6, 7)),
    "prism": ((0, 1), (0, 2), (0, 3), (1, 2), (1, 4), (2, 5), (3, 4), (3, 5), (4, 5)),
    "pyramid": ((0, 1), (0, 3), (0, 4), (1, 2), (1, 4), (2, 3), (2, 4), (3, 4)),
}
GMSH_FACES = {
    "tet": ((0, 2, 1), (0, 1, 3), (0, 3, 2), (3, 1, 2)),
    "cube": ((0, 3, 2, 1), (0, 1, 5, 4), (0, 4, 7, 3), (1, 2, 6, 5), (2, 3, 7, 6), (4, 5, 6, 7)),
    "prism": ((0, 2, 1), (3, 4, 5), (0, 1, 4, 3), (0, 3, 5, 2), (1, 2, 5, 4)),
    "pyramid": ((0, 1, 4), (3, 0, 4), (1, 2, 4), (2, 3, 4), (0, 3, 2, 1)),
}
_VERTS = {"tet": _TET_V, "cube": _HEX_V, "prism": _PRI_V, "pyramid": _PYR_V}


def gmsh_lattice(domain, p):
    """Gmsh's nodes of the complete Lagrange cell of order p, as integer lattice points (tetrahedron, hexahedron,
    prism: p times our parametric coordinates; pyramid: Gmsh's monomial lattice (i, j, k), k = 0 the apex)."""
    if p == 0:
        return [(0, 0, 0)]
    V = _VERTS[domain](p)
    out = list(V) + _edge_points(V, GMSH_EDGES[domain], p)
    for face in GMSH_FACES[domain]:
        if len(face) == 4:
            out += _face_points(V, face, p, _quad_inner_gmsh(p))
        elif p >= 3:
            out += _face_points(V, face, p, _tri_inner(p))
    if domain == "tet" and p >= 4:
        out += [(1 + a, 1 + b, 1 + c) for a, b, c in gmsh_lattice("tet", p - 4)]
    elif domain == "cube" and p >= 2:
        out += [(1 + a, 1 + b, 1 + c) for a, b, c in gmsh_lattice("cube", p - 2)]
    elif domain == "prism" and p >= 3:
        out += [(1 + a, 1 + b, 1 + c) for a, b in recursive_triangle(p - 3) for c in gmsh_line(p - 2)]
    elif domain == "pyramid" and p >= 3:
        out += [(1 + a, 1 + b, 2 + c) for a, b, c in gmsh_lattice("pyramid", p - 3)]
    return out


_VTK_TET_EDGES = ((0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3))
_VTK_TET_FACES = ((0, 1, 3), (2, 3, 1), (0, 3, 2), (0, 2, 1))
_VTK_HEX_EDGES = ((0, 1), (1, 2), (3, 2), (0, 3), (4, 5), (5, 6), (7, 6), (4, 7), (0, 4), (1, 5), (2, 6), (3, 7))
_VTK_WEDGE_EDGES = ((0, 1), (1, 2), (2, 0), (3, 4), (4, 5), (5, 3), (0, 3), (1, 4), (2, 5))


def vtk_lattice(domain, p):
    """VTK's nodes of the Lagrange cell of order p (tetrahedron, hexahedron, wedge), as integer lattice points
    (p times the parametric coordinates)."""
    if p == 0:
        return [(0, 0, 0)]
    inner = range(1, p)
    if domain == "tet":
        V = _TET_V(p)
        out = list(V) + _edge_points(V, _VTK_TET_EDGES, p)
        if p >= 3:
            for face in _VTK_TET_FACES:
                out += _face_points(V, face, p, _tri_inner(p))
        if p >= 4:
            out += [(1 + a, 1 + b, 1 + c) for a, b, c in vtk_lattice("tet", p - 4)]
        return out
    if domain == "cube":
        V = _HEX_V(p)
        out = list(V) + _edge_points(V, _VTK_HEX_EDGES, p)
        out += [(0, a, b) for b in inner for a in inner] + [(p, a, b) for b in inner for a in inner]
        out += [(a, 0, b) for b in inner for a in inner] + [(a, p, b) for b in inner for a in inner]
        out += [(a, b, 0) for b in inner for a in inner] + [(a, b, p) for b in inner for a in inner]
        out += [(a, b, c) for c in inner for b in inner for a in inner]
        return out
    if domain == "prism":
        V = _PRI_V(p)
        out = list(V) + _edge_points(V, _VTK_WEDGE_EDGES, p)
        tri = [(a, b) for b in inner for a in inner if a + b < p]
        out += [(a, b, 0) for a, b in tri] + [(a, b, p) for a, b in tri]
        for a, b in ((0, 1), (1, 2), (2, 0)):  # the quadrilaterals: along the edge fastest, then t
            out += [tuple(V[a][d] + (V[b][d] - V[a][d]) * i // p if d < 2 else c for d in range(3))
                    for c in inner for i in inner]
        out += [(a, b, c) for c in inner for a, b in tri]
        return out
    raise ValueError(f"VTK has no Lagrange cell on a {domain}")


def pyramid_collapsed(i, j, k, p):
    """Gmsh's pyramid lattice point (i, j, k) of order p in VTK's collapsed-cube coordinates (exact)."""
    if k == 0:
        return (_F(0), _F(0), _F(1))
    return (_F(i, k), _F(j, k), 1 - _F(k, p))


def reference_nodes(domain, p, order="vtk"):
    """Parametric coordinates (Fractions) of the nodes in the given library's order."""
    if domain == "pyramid":
        return tuple(pyramid_collapsed(i, j, k, p) for i, j, k in gmsh_lattice("pyramid", p))
    pts = vtk_lattice(domain, p) if order == "vtk" else gmsh_lattice(domain, p)
    return tuple(tuple(_F(c, p) for c in x) for x in pts)


def lattice_count(domain, p):
    return {"tet": (p + 1) * (p + 2) * (p + 3) // 6, "cube": (p + 1) ** 3, "prism": (p + 1) ** 2 * (p + 2) // 2,
            "pyramid": (p + 1) * (p + 2) * (2 * p + 3) // 6}[domain]


# --- exact shape functions: polynomials {(i, j, k): Fraction} ------------------------------------------------------
def _pmul(a, b):
    out = {}
    for e1, c1 in a.items():
        for e2, c2 in b.items():
            e = (e1[0] + e2[0], e1[1] + e2[1], e1[2] + e2[2])
            out[e] = out.get(e, 0) + c1 * c2
    return {e: c for e, c in out.items() if c != 0}


def _falling(lin, a, p):
    """prod_{m < a} (p lin - m) / (m + 1) for a linear polynomial lin."""
    out = {(0, 0, 0): _F(1)}
    for m in range(a):
        f = {e: c * p / (m + 1) for e, c in lin.items()}
        f[(0, 0, 0)] = f.get((0, 0, 0), 0) - _F(m, m + 1)
        out = _pmul(out, {e: c for e, c in f.items() if c != 0})
    return out


def _lagrange_1d(i, p, axis):
    """The 1-D Lagrange polynomial of node i / p on the nodes m / p, in variable ``axis``."""
    out = {(0, 0, 0): _F(1)}
    e1 = tuple(int(d == axis) for d in range(3))
    for m in range(p + 1):
        if m != i:
            out = _pmul(out, {e1: _F(p, i - m), (0, 0, 0): _F(-m, i - m)})
    return out


def lagrange_shapes(domain, p, nodes):
    """The Lagrange shape functions of the complete space of order p on the lattice nodes (tetrahedron,
    hexahedron, wedge), in the order of ``nodes`` (Fractions, p times an integer lattice point each)."""
    r, s, t = {(1, 0, 0): _F(1)}, {(0, 1, 0): _F(1)}, {(0, 0, 1): _F(1)}
    out = []
    for x in nodes:
        a = [int(c * p) for c in x]
        if domain == "cube":
            f = _pmul(_pmul(_lagrange_1d(a[0], p, 0), _lagrange_1d(a[1], p, 1)), _lagrange_1d(a[2], p, 2))
        elif domain == "tet":
            l0 = {(0, 0, 0): _F(1), (1, 0, 0): _F(-1), (0, 1, 0): _F(-1), (0, 0, 1): _F(-1)}
            f = _falling(l0, p - sum(a), p)
            for lin, ai in zip((r, s, t), a):
                f = _pmul(f, _falling(lin, ai, p))
        elif domain == "prism":
            l0 = {(0, 0, 0): _F(1), (1, 0, 0): _F(-1), (0, 1, 0): _F(-1)}
            f = _pmul(_pmul(_falling(l0, p - a[0] - a[1], p), _falling(r, a[0], p)), _falling(s, a[1], p))
            f = _pmul(f, _lagrange_1d(a[2], p, 2))
        else:
            raise ValueError(domain)
        out.append(f)
    return tuple(out)


#: The generated types: (meshio-style name, domain, order, VTK type, Gmsh type, Gmsh's minDetJac factor).
TYPES = (
    ("tetra20", "tet", 3, 71, 29, 1.0), ("tetra35", "tet", 4, 71, 30, 1.0), ("tetra56", "tet", 5, 71, 31, 1.0),
    ("hexahedron64", "cube", 3, 72, 92, 0.125), ("hexahedron125", "cube", 4, 72, 93, 0.125),
    ("hexahedron216", "cube", 5, 72, 94, 0.125),
    ("wedge40", "prism", 3, 73, 90, 0.5), ("wedge75", "prism", 4, 73, 91, 0.5), ("wedge126", "prism", 5, 73, 106, 0.5),
    ("pyramid30", "pyramid", 3, -1, 118, 0.25), ("pyramid55", "pyramid", 4, -1, 119, 0.25),
    ("pyramid91", "pyramid", 5, -1, 120, 0.25),
)
