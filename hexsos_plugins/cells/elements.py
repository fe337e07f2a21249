"""The 3-D cell types hexsos knows: node orders, reference elements, shape functions, faces.

One registry, :data:`ELEMENTS`, keyed by meshio's cell type name. Every convention is VTK's
(``vtkCell.GetParametricCoords`` and ``vtkCell.InterpolateFunctions`` / ``InterpolateDerivs``), so a
ParaView user can reproduce every number:

============== ====== ====== ======= =========================================================
name           VTK id Gmsh   nodes   reference element (parametric coordinates r, s, t)
============== ====== ====== ======= =========================================================
tetra          10     4      4       unit simplex r, s, t >= 0, r + s + t <= 1
tetra10        24     11     10      unit simplex
pyramid        14     7      5       base [0, 1]^2 at t = 0, apex at t = 1 (see below)
pyramid13      27     19     13      the same (VTK's collapsed cube: every (r, s, 1) is the apex)
pyramid14      --     14     14      the same; VTK has no 14-node pyramid: Gmsh's node order, as meshio keeps it
wedge          13     6      6       unit triangle (r, s) times [0, 1] (t)
wedge15        26     18     15      unit triangle times [0, 1]
wedge18        32     13     18      unit triangle times [0, 1]
hexahedron     12     5      8       [0, 1]^3
hexahedron20   25     17     20      [0, 1]^3
hexahedron27   29     12     27      [0, 1]^3
tetra20 .. 56  71     29-31  20-56   unit simplex (complete Lagrange, orders 3-5: :mod:`.lagrange`)
hexahedron64.. 72     92-94  64-216  [0, 1]^3 (orders 3-5)
wedge40 .. 126 73     90,91,106 40-126 unit triangle times [0, 1] (orders 3-5)
pyramid30 ..91 --     118-120 30-91  the pyramid (orders 3-5, Bergot's space, Gmsh's node order)
tetra16, 22    --     137, 32 16, 22  Gmsh's incomplete cells of orders 3 and 4 (corner and edge nodes only, Gmsh's
hexahedron32,44--     99, 100 32, 44  node order, their spaces in :mod:`.incomplete`)
wedge24, 33    --     111,112 24, 33
pyramid21, 29  --     125,126 21, 29
============== ====== ====== ======= =========================================================

``voxel`` (VTK 11) is an axis-aligned hexahedron with its nodes in lexicographic order (x fastest); readers
turn it into a ``hexahedron`` with :data:`VOXEL_TO_VTK`.

Node order: VTK's, for every type VTK has (``ELEMENTS[name].nodes`` lists each node's parametric coordinates);
``pyramid14``, which VTK lacks, keeps Gmsh's (corners, the edges 01, 03, 04, 12, 14, 23, 24, 34, the base
centre), as meshio does.
A cell is *positively oriented* when det J > 0 with VTK's shape functions; for the wedge that is the
node order in which the triangle (0, 1, 2) turns counter-clockwise seen from the triangle (3, 4, 5), the
same as Gmsh's prism (measured with VTK 9: ``vtkMeshQuality`` volume and ``vtkCellValidator`` agree).
Gmsh's numbering differs from VTK's for the quadratic types: ``gmsh_to_vtk`` gives, for each VTK node,
the Gmsh node it is (``vtk_conn = gmsh_conn[:, gmsh_to_vtk]``).

Shape functions are polynomials with rational coefficients, computed exactly here from each type's
polynomial space and node positions (Lagrange interpolation), so exact arithmetic can use them too:

* tetra: P1; tetra10: P2; wedge: P1(r, s) x P1(t); wedge18: P2(r, s) x P2(t); wedge15: the serendipity
  space P2(r, s) x P1(t) + P1(r, s) t^2; hexahedron: Q1; hexahedron27: Q2; hexahedron20: the serendipity
  space (Q2 without the 7 monomials with two or three squared variables).
* pyramids: the pyramid space of Bergot et al. (as Gmsh), written in VTK's collapsed-cube coordinates
  (r, s, t) in [0, 1]^3, whose top face t = 1 is the apex: order p is spanned by r^i s^j (1 - t)^max(i, j) t^k,
  i, j <= p, k <= p - max(i, j) (the point of the true pyramid is (r (1 - t), s (1 - t), t), and these are
  its rational functions x^i y^j / (1 - t)^max(i, j) t^k). p = 1 is VTK's linear pyramid (N_0..3 =
  bilinear(r, s) (1 - t), N_4 = t); p = 2 is Gmsh's 14-node pyramid; the 13-node pyramid is the 14-node one
  whose base-centre node sits where the base's 8-node serendipity quadrilateral puts it (-1/4 of each base
  corner, 1/2 of each base mid-edge node): Gmsh's 13-node pyramid, measured equal with getBasisFunctions.
  VTK's vtkQuadraticPyramid (VTK 9.7) interpolates the same 13 nodes differently *inside* the cell (the same
  on every face; its functions hold r^2 s^2 t (1 - t), outside this space): hexsos follows Gmsh and the
  pyramid space there, and says so in the README.
  det J in these coordinates is (1 - t)^2 times the *measure* det J_pyr, the Jacobian determinant of the
  map with respect to the true pyramid's coordinates (x_r and x_s carry the factor 1 - t, exactly, since
  the top face maps to one point): VTK's det J is 0 at the apex of *every* pyramid and says nothing there.
  hexsos measures pyramids by ``det J / (1 - t)^2`` (the measure of Bergot et al. and Johnen et al., as
  Gmsh): the determinant of the Jacobian whose r and s columns are divided by (1 - t). For a linear pyramid
  it is independent of t and bilinear in (r, s) (the r^2 and s^2 terms cancel), so its minimum lies at a
  base corner; for the quadratic ones it is a polynomial of degree 5, 5, 3 in (r, s, t), searched over
  the whole cube.

det J is the determinant of ``d x / d (r, s, t)`` (columns the derivatives along r, s, t); the unit
reference cell (nodes at their parametric coordinates) has det J = 1 (pyramid: the measure 1 when the apex
is at (1/2, 1/2, 1)). Gmsh's reference cells differ: its ``minDetJac`` is our value times
:attr:`Element.gmsh_factor` (hexahedra [-1, 1]^3: 1/8; wedges: triangle as ours times [-1, 1]: 1/2;
tetrahedra: ours; pyramids: see the attribute).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from functools import cached_property
from itertools import product

import numpy as np

from .incomplete import TYPES as _INCOMPLETE_TYPES
from .incomplete import incomplete_nodes, space_exponents
from .lagrange import TYPES as _LAGRANGE_TYPES
from .lagrange import lagrange_shapes, reference_nodes

__all__ = ["Element", "ELEMENTS", "CELL_TYPES", "VOXEL_TO_VTK", "element", "cell_type_code", "world_points", "eval_exact", "HEX_FACES",
           "exact_inverse"]

#: VTK_VOXEL (cell type 11) orders its nodes with x fastest; ``voxel[:, VOXEL_TO_VTK]`` is a hexahedron.
VOXEL_TO_VTK = np.array([0, 1, 3, 2, 4, 5, 7, 6])

_F = Fraction


# --- polynomials in (r, s, t) with rational coefficients: {(i, j, k): Fraction} ------------------------------
def _mono(i, j, k, c=1):
    return {(i, j, k): _F(c)}


def _add(*ps):
    out = {}
    for p in ps:
        for e, c in p.items():
            out[e] = out.get(e, 0) + c
    return {e: c for e, c in out.items() if c != 0}


def _mul(p, q):
    out = {}
    for e1, c1 in p.items():
        for e2, c2 in q.items():
            e = (e1[0] + e2[0], e1[1] + e2[1], e1[2] + e2[2])
            out[e] = out.get(e, 0) + c1 * c2
    return {e: c for e, c in out.items() if c != 0}


def _scale(p, c):
    return {e: v * c for e, v in p.items() if v * c != 0}


def _diff(p, axis):
    out = {}
    for e, c in p.items():
        if e[axis]:
            f = list(e)
            f[axis] -= 1
            out[tuple(f)] = out.get(tuple(f), 0) + c * e[axis]
    return out


def eval_exact(p, x):
    return sum((c * x[0] ** e[0] * x[1] ** e[1] * x[2] ** e[2] for e, c in p.items()), _F(0))


def _div_one_minus_t(p):
    """p / (1 - t), exactly; raises if (1 - t) does not divide p."""
    # synthetic division in t: p = (1 - t) q  <=>  q_k = sum_{j <= k} p_j (coefficients of t^j, per (i, j))
    by = {}
    for (i, j, k), c in p.items():
        by.setdefault((i, j), {})[k] = c
    out = {}
    for (i, j), coeffs in by.items():
        deg = max(coeffs)
        acc = _F(0)
        for k in range(deg + 1):
            acc += coeffs.get(k, 0)
            if k < deg and acc != 0:
                out[(i, j, k)] = acc
        if acc != 0:
            raise ValueError("(1 - t) does not divide the polynomial")
    return out


def exact_inverse(M):
    """The inverse of a square matrix of Fractions, exact (Gauss-Jordan with row pivoting)."""
    n = len(M)
    A = [list(r) + [_F(int(i == j)) for j in range(n)] for i, r in enumerate(M)]
    for c in range(n):
        piv = next(r for r in range(c, n) if A[r][c] != 0)
        A[c], A[piv] = A[piv], A[c]
        inv = 1 / A[c][c]
        A[c] = [v * inv for v in A[c]]
        for r in range(n):
            if r != c and A[r][c] != 0:
                f = A[r][c]
                A[r] = [a - f * b for a, b in zip(A[r], A[c])]
    return [r[n:] for r in A]


# --- the element types ----------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Element:
    """A 3-D cell type: see the module docstring for the conventions.

    Attributes
    ----------
    name : meshio's cell type name
    vtk_type, gmsh_type : the type ids of VTK and Gmsh
    domain : ``"cube"``, ``"tet"``, ``"prism"`` or ``"pyramid"``
    order : geometric order (1 linear, 2 quadratic)
    nodes : (n, 3) parametric coordinates of the nodes (exact, as Fractions), VTK order
    corners : number of corner nodes (the first ones) whose det J values a corner check sees (pyramids: the 4 base
        corners; the measure has no single value at the apex)
    faces : corner-node faces, each ordered so that its right-hand normal points out of a positive cell
    gmsh_to_vtk : for each VTK node the Gmsh node it is (``vtk = gmsh[:, gmsh_to_vtk]``)
    gmsh_factor : Gmsh's ``minDetJac`` of a cell = our min det J times this (its reference cells differ)
    """

    name: str
    vtk_type: int
    gmsh_type: int
    domain: str
    order: int
    nodes: tuple
    corners: int
    faces: tuple
    basis: tuple = field(repr=False)  # polynomials spanning the space, or a function returning them
    gmsh_to_vtk: tuple = field(repr=False)
    gmsh_factor: float = 1.0
    lagrange: bool = False  # a complete Lagrange cell on its lattice: shape functions built directly (lagrange.py)

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @cached_property
    def shape_polynomials(self) -> tuple:
        """The shape functions N_0 .. N_{n-1} as exact polynomials ({(i, j, k): Fraction})."""
        n = self.n_nodes
        if self.lagrange:  # products of Lagrange polynomials on the lattice: no linear solve (lagrange.py)
            return lagrange_shapes(self.domain, self.order, self.nodes)
        basis = self.basis() if callable(self.basis) else self.basis  # (a callable: computed when first needed)
        V = [[eval_exact(b, x) for b in basis] for x in self.nodes]  # V[i][k] = basis_k(node_i)
        # N_i = sum_k C[k][i] basis_k with V C = I
        C = exact_inverse(V)
        return tuple(_add(*(_scale(basis[k], C[k][i]) for k in range(n))) for i in range(n))

    @cached_property
    def derivative_polynomials(self) -> tuple:
        """``D[d][i]``: d N_i / d x_d as exact polynomials, the *measure's* columns (for pyramids the r and s
        derivatives divided by (1 - t), see the module docstring)."""
        D = [[_diff(N, d) for N in self.shape_polynomials] for d in range(3)]
        if self.domain == "pyramid":
            D[0] = [_div_one_minus_t(p) for p in D[0]]
            D[1] = [_div_one_minus_t(p) for p in D[1]]
        return tuple(tuple(col) for col in D)

    @cached_property
    def _tables(self):
        """Float tables: exponents (K, 3) and coefficient matrices for N (n, K) and for the 3 derivatives."""
        exps = sorted({e for p in self.shape_polynomials for e in p}
                      | {e for col in self.derivative_polynomials for p in col for e in p})
        idx = {e: k for k, e in enumerate(exps)}
        N = np.zeros((self.n_nodes, len(exps)))
        D = np.zeros((3, self.n_nodes, len(exps)))
        for i, p in enumerate(self.shape_polynomials):
            for e, c in p.items():
                N[i, idx[e]] = float(c)
        for d in range(3):
            for i, p in enumerate(self.derivative_polynomials[d]):
                for e, c in p.items():
                    D[d, i, idx[e]] = float(c)
        return np.array(exps, dtype=np.int64), N, D

    @property
    def reference_nodes(self) -> np.ndarray:
        """(n, 3) float parametric coordinates of the nodes."""
        return np.array([[float(c) for c in x] for x in self.nodes])

    @property
    def centre(self) -> np.ndarray:
        """A point inside the reference element (its centroid; for pyramids the base's centre at t = 1/4)."""
        return {"cube": np.array([0.5, 0.5, 0.5]), "tet": np.array([0.25, 0.25, 0.25]),
                "prism": np.array([1 / 3, 1 / 3, 0.5]), "pyramid": np.array([0.5, 0.5, 0.25])}[self.domain]

    def _monomials(self, pc):
        exps = self._tables[0]
        pc = np.asarray(pc, dtype=np.float64).reshape(-1, 3)
        return np.prod(pc[:, None, :] ** exps[None, :, :], axis=2)  # (K, n_monomials)

    def shape_functions(self, pcoords) -> np.ndarray:
        """N_i at the points pcoords (K, 3): (K, n)."""
        return self._monomials(pcoords) @ self._tables[1].T

    def shape_derivatives(self, pcoords) -> np.ndarray:
        """The measure's derivative columns at pcoords (K, 3): (K, n, 3), ``[q, i, d] = d N_i / d x_d``
        (pyramids: r and s columns divided by (1 - t))."""
        m = self._monomials(pcoords)
        return np.einsum("km,dnm->knd", m, self._tables[2])

    def jacobian(self, X, pcoords) -> np.ndarray:
        """J (M, K, 3, 3) of cells X (M, n, 3) at pcoords (K, 3): ``J[m, q, a, d] = d x_a / d x_d`` (pyramids:
        the measure's columns)."""
        X = np.asarray(X, dtype=np.float64)
        if X.ndim == 2:
            X = X[None]
        dN = self.shape_derivatives(pcoords)
        return np.einsum("mna,knd->mkad", X, dN)

    def det(self, X, pcoords) -> np.ndarray:
        """det J (for pyramids det J / (1 - t)^2) of cells X (M, n, 3) at pcoords (K, 3): (M, K)."""
        return np.linalg.det(self.jacobian(X, pcoords))

    def det_exact(self, X, pcoords) -> Fraction:
        """det J (pyramids: the measure) of one cell X (n, 3) at one point, exactly (the float inputs taken as
        rationals)."""
        x = [_F(float(v)) for v in np.asarray(pcoords, dtype=np.float64).reshape(3)]
        Xf = [[_F(float(v)) for v in row] for row in np.asarray(X, dtype=np.float64).reshape(self.n_nodes, 3)]
        J = [[sum((Xf[i][a] * eval_exact(self.derivative_polynomials[d][i], x) for i in range(self.n_nodes)),
                  _F(0)) for d in range(3)] for a in range(3)]
        return (J[0][0] * (J[1][1] * J[2][2] - J[1][2] * J[2][1]) - J[0][1] * (J[1][0] * J[2][2] - J[1][2] * J[2][0])
                + J[0][2] * (J[1][0] * J[2][1] - J[1][1] * J[2][0]))


def _monomial_space(exps):
    return tuple(_mono(*e) for e in exps)


def _q(k):
    return [e for e in product(range(k + 1), repeat=3)]


def _p(k):
    return [e for e in product(range(k + 1), repeat=3) if sum(e) <= k]


def _tri(k):
    return [(i, j) for i in range(k + 1) for j in range(k + 1 - i)]


_H = _F(1, 2)
_HEX8 = ((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1))
_HEX20_EDGES = ((_H, 0, 0), (1, _H, 0), (_H, 1, 0), (0, _H, 0), (_H, 0, 1), (1, _H, 1), (_H, 1, 1), (0, _H, 1),
                (0, 0, _H), (1, 0, _H), (1, 1, _H), (0, 1, _H))
_HEX27_REST = ((0, _H, _H), (1, _H, _H), (_H, 0, _H), (_H, 1, _H), (_H, _H, 0), (_H, _H, 1), (_H, _H, _H))
_TET4 = ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1))
_TET10_EDGES = ((_H, 0, 0), (_H, _H, 0), (0, _H, 0), (0, 0, _H), (_H, 0, _H), (0, _H, _H))
_WEDGE6 = ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (0, 1, 1))
_WEDGE15_EDGES = ((_H, 0, 0), (_H, _H, 0), (0, _H, 0), (_H, 0, 1), (_H, _H, 1), (0, _H, 1), (0, 0, _H), (1, 0, _H),
                  (0, 1, _H))
_WEDGE18_FACES = ((_H, 0, _H), (_H, _H, _H), (0, _H, _H))
_PYR5 = ((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1))
# VTK's mid-edge nodes: the base edges 01, 12, 23, 30, then the edges to the apex from 0, 1, 2, 3 (collapsed cube)
_PYR13_EDGES = ((_H, 0, 0), (1, _H, 0), (_H, 1, 0), (0, _H, 0), (0, 0, _H), (1, 0, _H), (1, 1, _H), (0, 1, _H))
_PYR14_CENTRE = ((_H, _H, 0),)

_HEX_FACES = ((0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (2, 3, 7, 6), (0, 4, 7, 3), (1, 2, 6, 5))
#: The six faces of a hexahedron (VTK node order), each ordered so that the right-hand-rule normal points out of a
#: positively oriented hex: the one face table of hexsos.
HEX_FACES = np.array(_HEX_FACES, dtype=np.int64)
_TET_FACES = ((0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3))
_WEDGE_FACES = ((0, 2, 1), (3, 4, 5), (0, 1, 4, 3), (1, 2, 5, 4), (2, 0, 3, 5))
_PYR_FACES = ((0, 3, 2, 1), (0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4))


def _nodes(*groups):
    return tuple(tuple(_F(c) for c in x) for g in groups for x in g)


def _serendipity_hex():
    return [e for e in _q(2) if sum(1 for a in e if a == 2) <= 1]


def _wedge_space(tri_deg, t_deg):
    return [(i, j, k) for i, j in _tri(tri_deg) for k in range(t_deg + 1)]


def _pyramid_basis(p):
    """Bergot's pyramid space of order p in collapsed-cube coordinates: r^i s^j (1 - t)^m t^k, m = max(i, j),
    k <= p - m."""
    omt = {(0, 0, 0): _F(1), (0, 0, 1): _F(-1)}  # 1 - t
    out = []
    for i in range(p + 1):
        for j in range(p + 1):
            m = max(i, j)
            f = _mono(i, j, 0)
            for _ in range(m):
                f = _mul(f, omt)
            out += [_mul(f, _mono(0, 0, k)) for k in range(p - m + 1)]
    return tuple(out)


def _pyramid13_basis():
    """The 13-node pyramid's shape functions: the 14-node pyramid's, its base-centre node (VTK order: node 13)
    eliminated by the base's serendipity quadrilateral (centre = -1/4 each base corner + 1/2 each base mid-edge)."""
    nodes = _nodes(_PYR5, _PYR13_EDGES, _PYR14_CENTRE)
    basis = _pyramid_basis(2)
    V = [[eval_exact(b, x) for b in basis] for x in nodes]
    C = exact_inverse(V)
    N14 = [_add(*(_scale(basis[k], C[k][i]) for k in range(14))) for i in range(14)]
    weight = [_F(-1, 4)] * 4 + [_F(0)] + [_F(1, 2)] * 4 + [_F(0)] * 4  # the centre's value from nodes 0..12
    return tuple(_add(N14[i], _scale(N14[13], weight[i])) for i in range(13))


_IDENTITY = {n: tuple(range(n)) for n in (4, 5, 6, 8)}
_HEX20_G2V = (0, 1, 2, 3, 4, 5, 6, 7, 8, 11, 13, 9, 16, 18, 19, 17, 10, 12, 14, 15)
_PYR13_G2V = (0, 1, 2, 3, 4, 5, 8, 10, 6, 7, 9, 11, 12)  # Gmsh's edges: 01, 03, 04, 12, 14, 23, 24, 34

ELEMENTS = {
    "tetra": Element("tetra", 10, 4, "tet", 1, _nodes(_TET4), 4, _TET_FACES, _monomial_space(_p(1)), _IDENTITY[4], 1.0),
    "tetra10": Element("tetra10", 24, 11, "tet", 2, _nodes(_TET4, _TET10_EDGES), 4, _TET_FACES,
                       _monomial_space(_p(2)), (0, 1, 2, 3, 4, 5, 6, 7, 9, 8), 1.0),
    "pyramid": Element("pyramid", 14, 7, "pyramid", 1, _nodes(_PYR5), 4, _PYR_FACES, _pyramid_basis(1), _IDENTITY[5],
                       0.25),
    "pyramid13": Element("pyramid13", 27, 19, "pyramid", 2, _nodes(_PYR5, _PYR13_EDGES), 4, _PYR_FACES,
                         _pyramid13_basis, _PYR13_G2V, 0.25),
    "pyramid14": Element("pyramid14", -1, 14, "pyramid", 2,
                         _nodes(_PYR5, [_PYR13_EDGES[k] for k in (0, 3, 4, 1, 5, 2, 6, 7)], _PYR14_CENTRE), 4,
                         _PYR_FACES, _pyramid_basis(2), tuple(range(14)), 0.25),
    "wedge": Element("wedge", 13, 6, "prism", 1, _nodes(_WEDGE6), 6, _WEDGE_FACES, _monomial_space(_wedge_space(1, 1)),
                     _IDENTITY[6], 0.5),
    "wedge15": Element("wedge15", 26, 18, "prism", 2, _nodes(_WEDGE6, _WEDGE15_EDGES), 6, _WEDGE_FACES,
                       _monomial_space(_wedge_space(2, 1) + [(i, j, 2) for i, j in _tri(1)]),
                       (0, 1, 2, 3, 4, 5, 6, 9, 7, 12, 14, 13, 8, 10, 11), 0.5),
    "wedge18": Element("wedge18", 32, 13, "prism", 2, _nodes(_WEDGE6, _WEDGE15_EDGES, _WEDGE18_FACES), 6, _WEDGE_FACES,
                       _monomial_space(_wedge_space(2, 2)),
                       (0, 1, 2, 3, 4, 5, 6, 9, 7, 12, 14, 13, 8, 10, 11, 15, 17, 16), 0.5),
    "hexahedron": Element("hexahedron", 12, 5, "cube", 1, _nodes(_HEX8), 8, _HEX_FACES, _monomial_space(_q(1)),
                          _IDENTITY[8], 0.125),
    "hexahedron20": Element("hexahedron20", 25, 17, "cube", 2, _nodes(_HEX8, _HEX20_EDGES), 8, _HEX_FACES,
                            _monomial_space(_serendipity_hex()), _HEX20_G2V, 0.125),
    "hexahedron27": Element("hexahedron27", 29, 12, "cube", 2, _nodes(_HEX8, _HEX20_EDGES, _HEX27_REST), 8, _HEX_FACES,
                            _monomial_space(_q(2)), _HEX20_G2V + (22, 23, 21, 24, 20, 25, 26), 0.125),
}

_CORNER_FACES = {"tet": _TET_FACES, "cube": _HEX_FACES, "prism": _WEDGE_FACES, "pyramid": _PYR_FACES}
_CORNERS = {"tet": 4, "cube": 8, "prism": 6, "pyramid": 4}


def _lagrange_element(name, domain, p, vtk_type, gmsh_type, factor):
    """A complete Lagrange cell of order p (:mod:`.lagrange`): VTK's node order (pyramids: Gmsh's)."""
    nodes = reference_nodes(domain, p, "vtk")
    if domain == "pyramid":
        g2v = tuple(range(len(nodes)))
        basis = lambda: _pyramid_basis(p)  # noqa: E731
    else:
        where = {x: i for i, x in enumerate(reference_nodes(domain, p, "gmsh"))}
        g2v = tuple(where[x] for x in nodes)
        basis = ()
    return Element(name, vtk_type, gmsh_type, domain, p, nodes, _CORNERS[domain], _CORNER_FACES[domain], basis, g2v,
                   factor, lagrange=domain != "pyramid")


for _row in _LAGRANGE_TYPES:
    ELEMENTS[_row[0]] = _lagrange_element(*_row)


def _incomplete_basis(domain, p):
    """The incomplete cell's space (:mod:`.incomplete`) as exact polynomials."""
    exps = space_exponents(domain, p)
    if domain != "pyramid":
        return _monomial_space(exps)
    omt = {(0, 0, 0): _F(1), (0, 0, 1): _F(-1)}  # 1 - t
    out = []
    for i, j, k in exps:
        f = _mono(i, j, k)
        for _ in range(max(i, j)):
            f = _mul(f, omt)
        out.append(f)
    return tuple(out)


def _incomplete_element(name, domain, p, gmsh_type, factor, _complete):
    """Gmsh's incomplete cell of order p (:mod:`.incomplete`): corners and edge nodes, Gmsh's node order (VTK has no
    such cell)."""
    nodes = incomplete_nodes(domain, p)
    return Element(name, -1, gmsh_type, domain, p, nodes, _CORNERS[domain], _CORNER_FACES[domain],
                   lambda: _incomplete_basis(domain, p), tuple(range(len(nodes))), factor)


for _row in _INCOMPLETE_TYPES:
    ELEMENTS[_row[0]] = _incomplete_element(*_row)

#: The cell types in a fixed order: ``CheckResult.cell_type`` holds indices into this tuple.
CELL_TYPES = tuple(ELEMENTS)


def element(name: str) -> Element:
    """The registry entry of a cell type name (``voxel`` is not one: convert it to a hexahedron first)."""
    try:
        return ELEMENTS[name]
    except KeyError:
        from ..errors import InvalidInputError

        raise InvalidInputError(f"cell type: expected one of {', '.join(CELL_TYPES)}, found {name!r}") from None


def cell_type_code(name: str) -> int:
    """The index of a cell type in :data:`CELL_TYPES`."""
    return CELL_TYPES.index(element(name).name)


def world_points(points, cells, pcoords) -> np.ndarray:
    """x(pcoords) of one parametric point per cell, by the cells' own shape functions: (M, 3).

    ``cells``: an (M, 8) array of hexahedra or (cell_type, conn) pairs, VTK node order; ``pcoords`` (M, 3) in
    the blocks' order (e.g. :attr:`hexsos_plugins.CheckResult.argmin`). A pyramid's point has t = 0 (its
    measure does not depend on t: see the module docstring): it lies on the base."""
    points = np.asarray(points, dtype=np.float64)
    pcoords = np.asarray(pcoords, dtype=np.float64).reshape(-1, 3)
    if not (isinstance(cells, (list, tuple)) and cells and isinstance(cells[0], (list, tuple))):
        cells = [("hexahedron", cells)]
    out, s = np.empty((len(pcoords), 3)), 0
    for name, conn in cells:
        conn = np.asarray(conn, dtype=np.int64)
        m = len(conn)
        N = element(name).shape_functions(pcoords[s : s + m])  # (m, n)
        out[s : s + m] = np.einsum("mn,mna->ma", N, points[conn])
        s += m
    return out
