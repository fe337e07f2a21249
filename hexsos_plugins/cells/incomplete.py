"""Gmsh's incomplete cells of orders 3 to 5: nodes on the corners and edges only, and their polynomial spaces.

With ``Mesh.SecondOrderIncomplete = 1``, Gmsh 4.15's ``setOrder(p)`` (p = 3, 4, 5) makes cells whose nodes are the
corners and the edges' inner nodes of the complete Lagrange cell of the same order (no face or inner nodes), in
Gmsh's order (the first ``corners + edges (p - 1)`` nodes of :func:`.lagrange.gmsh_lattice`; measured with
``getElementProperties``):

================================= ============ ============ ====================================================
names (p = 3, 4, 5)               Gmsh         nodes        space (monomials r^i s^j t^k of hexsos' parametric
                                                            coordinates, or as stated)
================================= ============ ============ ====================================================
tetra16, tetra22, tetra28         137, 32, 33  6p - 2       1, r^i, s^i, t^i (i <= p), and the products of two
                                                            coordinates of degree p (r^a s^b, r^a t^b, s^a t^b,
                                                            a, b >= 1, a + b = p): at p = 3, P_3 without rs, rt,
                                                            st, rst
hexahedron32, 44, 56              99-101       12p - 4      r^i s^j t^k, i, j, k <= p, at most one exponent >= 2
                                                            (Gmsh's serendipity hexahedron; above p = 3 not the
                                                            classical serendipity space: no face bubbles)
wedge24, wedge33, wedge42         111-113      9p - 3       t^k, r t^k, s t^k (k <= p); r^i, s^i, r^i t, s^i t
                                                            (2 <= i <= p); r^a s^b and r^a s^b t (a, b >= 1,
                                                            a + b = p)
pyramid21, pyramid29, pyramid37   125-127      8p - 3       in VTK's collapsed cube: r^i s^j (1 - t)^max(i, j) t^k
                                                            with i, j <= 1 and k <= p - max(i, j), or one of
                                                            i, j in 2..p, the other <= 1, and k = 0
================================= ============ ============ ====================================================

Measured with Gmsh 4.15's ``getBasisFunctions``: the tetrahedra's and hexahedra's shape functions span exactly these
spaces (``tests/test_incomplete.py`` asks Gmsh). Each space contains the complete space of order 1 and lies in the
complete space of order p (tetrahedra: P_p; hexahedra: Q_p; wedges: P_p(r, s) x P_p(t); pyramids: Bergot's space of
order p), so a straight cell is affine and the incomplete cell's map is a map of the complete cell of the same order:
its det J has the complete cell's Bernstein factors, and the complete cell whose nodes are this map at the complete
lattice is the same cell (how a .vtu holds it, :data:`COMPLETE`). At p = 2 the same rules give tetra10, hexahedron20,
wedge15 and pyramid13.

Gmsh 4.15 cannot evaluate its prisms of order >= 3 at all ("FaceClosureFull not implemented for prisms of order
3"): the wedges' space is the one Gmsh's source generates for them (``gmshGenerateMonomialsPrismSerendipity``; at
p = 2 it is wedge15's space, and its trace on each face is the space of the incomplete triangle or quadrilateral
Gmsh puts there). Gmsh's incomplete pyramids are made and written by Gmsh, but its ``getBasisFunctions`` returns
the same values at every point (a vertex included, where an interpolating basis is 1 at that vertex's function
and 0 elsewhere): Gmsh has no working interpolation for them (nor can it open a file holding one: "Could not
create element"); neither can it take back its incomplete hexahedra of orders 4 and 5 (adding one through its API
crashes it). hexsos defines the pyramids' space as
above: at p = 2 this rule gives exactly the 13-node pyramid's space (Bergot's order-2 space without its base-centre
bubble r^2 s^2 (1 - t)^2, which is Gmsh's 13-node pyramid), its trace on the base is the quadrilateral serendipity
space and it has 8p - 3 functions, one per node (unisolvent: the registry's exact solve would fail otherwise).

>>> [row[0] for row in TYPES][:8]
['tetra16', 'tetra22', 'hexahedron32', 'hexahedron44', 'wedge24', 'wedge33', 'pyramid21', 'pyramid29']
>>> [len(space_exponents(d, 5)) for d in ("tet", "cube", "prism", "pyramid")]
[28, 56, 42, 37]
>>> len(space_exponents("tet", 3)), len(space_exponents("cube", 4)), len(space_exponents("pyramid", 3))
(16, 44, 21)
"""

from __future__ import annotations

from fractions import Fraction

from .lagrange import GMSH_EDGES, gmsh_lattice, pyramid_collapsed

__all__ = ["TYPES", "COMPLETE", "incomplete_nodes", "space_exponents", "corner_count"]

#: The incomplete types: (name, domain, order, Gmsh type, Gmsh's minDetJac factor, the complete type of that order).
TYPES = (
    ("tetra16", "tet", 3, 137, 1.0, "tetra20"), ("tetra22", "tet", 4, 32, 1.0, "tetra35"),
    ("hexahedron32", "cube", 3, 99, 0.125, "hexahedron64"), ("hexahedron44", "cube", 4, 100, 0.125, "hexahedron125"),
    ("wedge24", "prism", 3, 111, 0.5, "wedge40"), ("wedge33", "prism", 4, 112, 0.5, "wedge75"),
    ("pyramid21", "pyramid", 3, 125, 0.25, "pyramid30"), ("pyramid29", "pyramid", 4, 126, 0.25, "pyramid55"),
    ("tetra28", "tet", 5, 33, 1.0, "tetra56"), ("hexahedron56", "cube", 5, 101, 0.125, "hexahedron216"),
    ("wedge42", "prism", 5, 113, 0.5, "wedge126"), ("pyramid37", "pyramid", 5, 127, 0.25, "pyramid91"),
)
#: Each incomplete type's complete Lagrange type of the same order and geometry.
COMPLETE = {row[0]: row[5] for row in TYPES}

_CORNERS = {"tet": 4, "cube": 8, "prism": 6, "pyramid": 5}


def corner_count(domain: str) -> int:
    """The number of vertices of the reference element (the pyramid's apex included)."""
    return _CORNERS[domain]


def incomplete_nodes(domain: str, p: int) -> tuple:
    """The nodes of the incomplete cell of order p in Gmsh's order, as exact parametric coordinates (VTK's
    coordinates: the pyramid's in the collapsed cube): the corners and edges of Gmsh's complete lattice.

    >>> [tuple(str(c) for c in x) for x in incomplete_nodes("tet", 3)[4:6]]  # edge 0-1, from vertex 0
    [('1/3', '0', '0'), ('2/3', '0', '0')]
    """
    k = _CORNERS[domain] + len(GMSH_EDGES[domain]) * (p - 1)
    pts = gmsh_lattice(domain, p)[:k]
    if domain == "pyramid":
        return tuple(pyramid_collapsed(i, j, kk, p) for i, j, kk in pts)
    return tuple(tuple(Fraction(c, p) for c in x) for x in pts)


def space_exponents(domain: str, p: int) -> list:
    """The space of the incomplete cell of order p (see the module docstring): monomial exponents (i, j, k)
    for the tetrahedron, hexahedron and wedge; for the pyramid (i, j, k) stands for r^i s^j (1 - t)^max(i, j) t^k."""
    if domain == "tet":
        out = [(0, 0, 0)] + [tuple(i * (d == e) for e in range(3)) for d in range(3) for i in range(1, p + 1)]
        for d, e in ((0, 1), (0, 2), (1, 2)):
            for a in range(1, p):
                x = [0, 0, 0]
                x[d], x[e] = a, p - a
                out.append(tuple(x))
        return out
    if domain == "cube":
        rng = range(p + 1)
        return [(i, j, k) for k in rng for j in rng for i in rng if sum(v >= 2 for v in (i, j, k)) <= 1]
    if domain == "prism":
        out = [(a, b, k) for a, b in ((0, 0), (1, 0), (0, 1)) for k in range(p + 1)]
        out += [(a, b, k) for i in range(2, p + 1) for a, b in ((i, 0), (0, i)) for k in (0, 1)]
        out += [(a, p - a, k) for a in range(1, p) for k in (0, 1)]
        return out
    if domain == "pyramid":
        out = [(i, j, k) for i in (0, 1) for j in (0, 1) for k in range(p - max(i, j) + 1)]
        out += [(a, b, 0) for i in range(2, p + 1) for a, b in ((i, 0), (i, 1), (0, i), (1, i))]
        return out
    raise ValueError(f"no incomplete cell on a {domain}")
