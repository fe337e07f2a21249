"""Built-in examples: single hexes with known minima, random hexes, and hex meshes generated with Gmsh.

Nothing here reads a file: every mesh is generated, so tests, benchmarks and ``hexsos demo`` need no data.
"""

from __future__ import annotations

import contextlib

import numpy as np

from .errors import DependencyError, InvalidInputError
from .cells.hexahedron import CORNERS
from .io.mesh import hexes_to_mesh  # noqa: F401 (re-exported: examples build meshes with it)

__all__ = [
    "gmsh_model",
    "cubed_ball",
    "unit_cube",
    "inside_invalid_hex",
    "twisted_hex",
    "folding_twist",
    "random_hexes",
    "hexes_to_mesh",
    "structured_grid",
    "folded_column",
    "gmsh_mesh",
    "demo_mesh",
]


#: The node across the hex from each node (parameter corner 1 - c).
OPPOSITE = np.array([int(np.flatnonzero((CORNERS == 1 - c).all(axis=1))[0]) for c in CORNERS])


def unit_cube() -> np.ndarray:
    """The unit cube, (8, 3) in VTK order: det J == 1 everywhere."""
    return CORNERS.astype(np.float64)


def inside_invalid_hex() -> np.ndarray:
    """A hex positive at all 8 corners and at its centre whose true minimum of det J is -0.199276 at
    (u, v, w) = (1, 0, 0.468061), on an edge. Corner-and-centre checks (VTK, pyvista) call it valid."""
    return np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0],
                     [2.28171276, 1.59767248, 2], [-0.59767248, 1.28171276, 2],
                     [-1.28171276, -0.59767248, 2], [0.59767248, -1.28171276, 2]], dtype=np.float64)


def twisted_hex(angle: float, *, shear: float = 0.0) -> np.ndarray:
    """The unit cube with its bottom four vertices rotated by ``angle`` (radians) about the vertical axis
    through the cube's centre (the paper's Figure 1) and its top face shifted by ``shear`` along +u.

    A twist of congruent faces stays valid up to a half turn (det J = det((1 - w) R + w I) > 0 below pi),
    and the shear does not change that: it moves x_w only, while x_u and x_v stay horizontal, so det J is
    unchanged. :func:`folding_twist` is a twist that does fold inside.
    """
    X = unit_cube()
    c, s = np.cos(angle), np.sin(angle)
    xy = X[:4, :2] - 0.5
    X[:4, :2] = 0.5 + xy @ np.array([[c, s], [-s, c]])
    X[4:, 0] += shear
    return X


def folding_twist(angle: float) -> np.ndarray:
    """A twisted hex that folds inside while its corners stay positive (the paper's Figure 1).

    :func:`twisted_hex` with its top face stretched to a 1.8 x 0.55 rectangle about the vertical axis and
    vertex 6 moved by (0.15, 0.1, 0.1) (so the minimizer is unique): the slices between the rotated square
    and the rectangle fold near w = 1/2 from about 145 degrees on, while all 8 corners keep det J >= 0.99.
    """
    X = twisted_hex(angle)
    X[4:, 0] = 0.5 + 1.8 * (X[4:, 0] - 0.5)
    X[4:, 1] = 0.5 + 0.55 * (X[4:, 1] - 0.5)
    X[6] += (0.15, 0.1, 0.1)
    return X


def random_hexes(m: int, *, sigma: float = 0.3, seed: int = 0) -> np.ndarray:
    """The paper's random family: the unit cube's vertices plus isotropic Gaussian noise, (m, 8, 3)."""
    rng = np.random.default_rng(seed)
    return unit_cube()[None] + sigma * rng.standard_normal((m, 8, 3))


def structured_grid(nx: int, ny: int | None = None, nz: int | None = None, *, size=(1.0, 1.0, 1.0)):
    """An nx x ny x nz grid of axis-aligned hexes on a box of the given size: points (N, 3), hexes (M, 8)."""
    ny = nx if ny is None else ny
    nz = nx if nz is None else nz
    xs, ys, zs = (np.linspace(0.0, L, n + 1) for L, n in zip(size, (nx, ny, nz)))
    P = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)
    idx = np.arange(P.shape[0]).reshape(nx + 1, ny + 1, nz + 1)
    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    i, j, k = i.ravel(), j.ravel(), k.ravel()
    H = np.stack([idx[i + a, j + b, k + c] for a, b, c in CORNERS], axis=1)
    return P, H.astype(np.int64)


def folded_column():
    """Three unit hexes stacked along z, the middle one written in the mirrored node order (nodes 1 <-> 3, 5 <-> 7)
    and its top face pushed below its bottom (z 2 -> 0.5): points (16, 3), hexes (3, 8). Every hex is valid by its
    own node order, and the middle one lies inside the lowest: a mesh folded over itself, which no check of each
    cell on its own sees (:meth:`hexsos_plugins.io.mesh.Mesh.folded_cells` names hex 1)."""
    xy = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    P = np.concatenate([np.column_stack([xy, np.full(4, z)]) for z in (0.0, 1.0, 0.5, 3.0)])
    H = np.array([[0, 1, 2, 3, 4, 5, 6, 7], [4, 5, 6, 7, 8, 9, 10, 11], [8, 9, 10, 11, 12, 13, 14, 15]])
    H[1] = H[1][[0, 3, 2, 1, 4, 7, 6, 5]]
    return P, H


def cubed_ball(n: int = 2):
    """A cube's n^3 grid pushed radially onto the unit ball: points (N, 3), hexes (M, 8). Valid, but the hexes at
    the cube's corners have three faces on a smooth sphere, where no quad can be square (n = 2: min scaled
    Jacobian 0.67)."""
    P, H = structured_grid(n, n, n, size=(2.0, 2.0, 2.0))
    P = P - 1.0
    r2, ri = np.linalg.norm(P, axis=1), np.abs(P).max(axis=1)
    return np.where(r2[:, None] > 0, P * (ri / np.maximum(r2, 1e-300))[:, None], P), H


def _gmsh():
    try:
        import gmsh
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise DependencyError("generating example meshes needs Gmsh: pip install 'hexsos[gmsh]'") from exc
    return gmsh


@contextlib.contextmanager
def gmsh_model(name: str):
    """A Gmsh model of its own for the block (``with gmsh_model("m") as gmsh: ...``), removed after; Gmsh is
    initialized for the block (without the user's configuration, quiet) unless a session is open, then left as
    it was."""
    gmsh = _gmsh()
    own = not gmsh.isInitialized()
    if own:
        gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(name)
        try:
            yield gmsh
        finally:
            gmsh.model.remove()
    finally:
        if own:
            gmsh.finalize()


def gmsh_mesh(kind: str = "ring", n: int = 8):
    """A structured, all-valid hex mesh generated with Gmsh: points (N, 3), hexes (M, 8) in VTK order.

    Parameters
    ----------
    kind : {"ring", "box"}
        ``"ring"``: a quarter annulus (radii 1 and 2, quads recombined from a transfinite surface)
        revolved by 90 degrees about an axis beside it: curved hexes in every direction.
        ``"box"``: the unit box, transfinite.
    n : int
        Elements per edge (the ring has 2n x n x 2n hexes; the box n^3).
    """
    with gmsh_model(f"hexsos-{kind}") as gmsh:
        g = gmsh.model.geo
        if kind == "box":
            p = [g.addPoint(*c) for c in [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]]
            lines = [g.addLine(p[i], p[(i + 1) % 4]) for i in range(4)]
            loop = g.addCurveLoop(lines)
            surf = g.addPlaneSurface([loop])
            for c in lines:
                g.mesh.setTransfiniteCurve(c, n + 1)
            g.mesh.setTransfiniteSurface(surf)
            g.mesh.setRecombine(2, surf)
            g.extrude([(2, surf)], 0, 0, 1, numElements=[n], recombine=True)
        elif kind == "ring":
            c = g.addPoint(0, 0, 0)
            a1, a2 = g.addPoint(1, 0, 0), g.addPoint(2, 0, 0)
            b1, b2 = g.addPoint(0, 1, 0), g.addPoint(0, 2, 0)
            inner, outer = g.addCircleArc(a1, c, b1), g.addCircleArc(a2, c, b2)
            l1, l2 = g.addLine(a1, a2), g.addLine(b2, b1)
            loop = g.addCurveLoop([l1, outer, l2, -inner])
            surf = g.addPlaneSurface([loop])
            for curve, k in ((inner, 2 * n + 1), (outer, 2 * n + 1), (l1, n + 1), (l2, n + 1)):
                g.mesh.setTransfiniteCurve(curve, k)
            g.mesh.setTransfiniteSurface(surf)
            g.mesh.setRecombine(2, surf)
            # revolve about the axis through (3, 0, 0) parallel to y
            g.revolve([(2, surf)], 3, 0, 0, 0, 1, 0, np.pi / 2, numElements=[2 * n], recombine=True)
        else:
            raise InvalidInputError(f"kind: expected 'ring' or 'box', found {kind!r}")
        g.synchronize()
        gmsh.model.mesh.generate(3)
        return _hexes_from_gmsh(gmsh)


def mixed_msh(path, *, order: int = 1, incomplete: bool = True, size: float = 0.34, damage: float = 0.0,
              seed: int = 0) -> dict:
    """Write a Gmsh-made mixed mesh to ``path`` (any format Gmsh writes, e.g. ``.msh``): unit boxes in a row,
    structured hexahedra beside tetrahedra (with the pyramids Gmsh puts where the hexahedra's quads meet
    them), and apart from them a box of prisms (extruded triangles).

    Parameters
    ----------
    order : {1, 2}, keyword-only
        Element order. With 2, ``incomplete`` picks Gmsh's serendipity elements (hexahedron20, wedge15; the
        pyramids are 13-node) or the complete ones (hexahedron27, wedge18, 14-node pyramids).
    size : float, keyword-only
        Target element size.
    damage : float, keyword-only
        Move this fraction of the interior nodes (seeded) by up to ``size`` in a random direction: inverted
        and inside-folded elements of every type.
    seed : int, keyword-only

    Returns
    -------
    dict : Gmsh element type name -> count.
    """
    with gmsh_model("hexsos-mixed") as gmsh:
        occ = gmsh.model.occ
        hexvol = occ.addBox(0, 0, 0, 1, 1, 1)
        tetvol = occ.addBox(1, 0, 0, 1, 1, 1)
        occ.fragment([(3, hexvol)], [(3, tetvol)])
        tri = occ.addRectangle(3, 0, 0, 1, 1)  # in the plane z = 0, meshed with triangles, extruded along z
        occ.extrude([(2, tri)], 0, 0, 1, numElements=[max(1, round(1 / size))], recombine=True)
        occ.synchronize()
        n = max(2, round(1 / size)) + 1
        for dim, tag in gmsh.model.getBoundary([(3, hexvol)], combined=False, recursive=True):
            if dim == 1:
                gmsh.model.mesh.setTransfiniteCurve(tag, n)
        for _, tag in gmsh.model.getBoundary([(3, hexvol)], combined=False):
            gmsh.model.mesh.setTransfiniteSurface(tag)
            gmsh.model.mesh.setRecombine(2, tag)
        gmsh.model.mesh.setTransfiniteVolume(hexvol)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size / 2)
        gmsh.model.mesh.generate(3)
        if order == 2:
            gmsh.option.setNumber("Mesh.SecondOrderIncomplete", int(incomplete))
            gmsh.model.mesh.setOrder(2)
        if damage > 0:
            tags, coords, _ = gmsh.model.mesh.getNodes(3, -1, includeBoundary=False)
            tags = np.asarray(tags)
            coords = np.asarray(coords).reshape(-1, 3)
            rng = np.random.default_rng(seed)
            pick = rng.random(tags.size) < damage
            d = rng.standard_normal((int(pick.sum()), 3))
            d *= (size * rng.random(d.shape[0]) / np.linalg.norm(d, axis=1))[:, None]
            for t, x in zip(tags[pick], coords[pick] + d):
                gmsh.model.mesh.setNode(int(t), x.tolist(), [])
        counts = {gmsh.model.mesh.getElementProperties(t)[0]: len(gmsh.model.mesh.getElementsByType(t)[0])
                  for t in gmsh.model.mesh.getElementTypes(3)}
        gmsh.write(str(path))
        return counts


def _hexes_from_gmsh(gmsh):
    """Points and hexes (VTK order) of the current Gmsh model (Gmsh's hexahedron order is VTK's)."""
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    order = np.argsort(node_tags)
    tags = np.asarray(node_tags)[order]
    P = np.asarray(coords).reshape(-1, 3)[order]
    _, enodes = gmsh.model.mesh.getElementsByType(5)
    H = np.searchsorted(tags, np.asarray(enodes).reshape(-1, 8))
    used = np.unique(H)
    remap = np.full(P.shape[0], -1)
    remap[used] = np.arange(used.size)
    return P[used].copy(), remap[H].astype(np.int64)


def demo_mesh(n: int = 6, *, seed: int = 0):
    """The mesh of ``hexsos demo``: a Gmsh ring mesh with deterministic damage.

    * Two interior vertices are pushed through the hex across from them: corner inversions.
    * The boundary face of one boundary hex is distorted (its 4 vertices moved) to where that hex stays
      clearly positive at all 8 corners but folds inside: the damage corner checks (VTK, HexaLab) miss.
      The displacement is the best of a seeded random search (scored by min(corner min, -true min)).

    Returns
    -------
    points : (N, 3), hexes : (M, 8), info : dict naming the moved vertices and the inside-only hex
    """
    from .certify import check

    from .io.mesh import HexMesh

    P, H = gmsh_mesh("ring", n)
    P = P.copy()
    faces, owner = HexMesh.from_arrays(P, H).boundary_faces(return_hex=True)
    on_boundary = np.zeros(P.shape[0], dtype=bool)
    on_boundary[faces.ravel()] = True
    interior = np.flatnonzero(~on_boundary)
    h = float(np.median(np.linalg.norm(P[H[:, 1]] - P[H[:, 0]], axis=1)))
    info = {"corner_inverted_vertices": [], "inside_only_hex": None, "inside_only_vertices": []}

    # 1. an inside-only inversion on a boundary hex near the middle of the mesh
    centre = P.mean(axis=0)
    f = int(np.argmin(np.linalg.norm(P[faces].mean(axis=1) - centre, axis=1)))
    m, face = int(owner[f]), faces[f]
    local = np.array([int(np.flatnonzero(H[m] == v)[0]) for v in face])
    rng = np.random.default_rng(seed)
    trials = np.repeat(P[H[m]][None], 20000, axis=0)
    trials[:, local] += 0.7 * h * rng.standard_normal((trials.shape[0], 4, 3))
    r = check(*hexes_to_mesh(trials))
    score = np.where(r.invalid_inside_only, np.minimum(r.corner_min_det, -r.min_det) / r.scale, -np.inf)
    best = int(np.argmax(score))
    if not np.isfinite(score[best]):  # pragma: no cover - the search is deterministic
        raise RuntimeError("demo_mesh: no inside-only inversion found")
    P[face] = trials[best, local]
    info["inside_only_hex"] = m
    info["inside_only_vertices"] = [int(v) for v in face]

    # 2. corner inversions away from it: push two interior vertices through the hex across from them
    near = set(int(v) for v in H[np.any(np.isin(H, face), axis=1)].ravel())
    pool = [int(v) for v in interior if int(v) not in near]
    for v in (pool[len(pool) // 5], pool[(4 * len(pool)) // 5]):
        mm = int(np.flatnonzero((H == v).any(axis=1))[0])
        k = int(np.flatnonzero(H[mm] == v)[0])
        P[v] = P[v] + 1.2 * (P[H[mm][OPPOSITE[k]]] - P[v])
        info["corner_inverted_vertices"].append(v)
    return P, H, info
