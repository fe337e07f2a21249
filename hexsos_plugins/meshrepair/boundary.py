"""The boundary surface of a volume mesh, its feature edges and corners, and projection back onto it.

Used by the repair with ``boundary="slide"``: boundary vertices may move, but stay on the input's boundary
surface, vertices on feature edges stay on their feature curves, and feature corners stay where they are; with a
``tolerance`` > 0 each may also sit off its surface, curve or corner by up to that fraction of its boundary edge
length, and at most :data:`BAND_DIAGONAL` of the diagonal of the input's bounding box (a band: the repair's
quality is capped by the surface where it must stay exactly on it).

* Boundary faces: the faces (triangles, quads; corner nodes) of the 3-D cells that belong to one cell only,
  oriented outward for positively oriented cells (:attr:`hexsos_plugins.cells.elements.Element.faces`).
* Feature edges: boundary edges whose two boundary faces meet at an angle between their normals larger than
  ``feature_angle`` (degrees; default 45), and boundary edges not shared by exactly two boundary faces.
* Vertex kinds: *surface* (no feature edge), *curve* (exactly two feature edges), *corner* (one, or three or
  more: the ends and junctions of feature curves), pinned.

Projection uses libigl's exact point-to-simplex distance (an AABB tree built once per model and kept,
:class:`NearestPoints`) onto the input's boundary triangles (quads split along their 0-2 diagonal, as
:mod:`hexsos_plugins.meshrepair.fidelity` does) for surface vertices, and onto the input's feature segments for
curve vertices.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..cells.elements import ELEMENTS
from ..errors import DependencyError, InvalidInputError

__all__ = ["boundary_faces", "interior_vertices", "BoundaryModel", "NearestPoints", "boundary_model", "Slide",
           "quad_areas", "quad_corners", "size_floor", "TILT_DEGREES", "DEVIATION_SAMPLES",
           "LEASH_ROUNDS", "BAND_DIAGONAL"]

#: A boundary quad whose vector area is more than this many degrees from its input normal counts as tilted
#: (:meth:`BoundaryModel.tilted_quads`): the repair's report counts them beside the quads turned over
TILT_DEGREES = 60.0
#: Points along a boundary triangle's edge, less one, where :meth:`BoundaryModel.deviation` measures (15 a triangle)
DEVIATION_SAMPLES = 4
#: Times :meth:`BoundaryModel.closest` pulls a leashed vertex toward its input position and back onto the surface
LEASH_ROUNDS = 3


def _faces_of(cells):
    """All corner faces of the cells: (tris (T, 3), quads (Q, 4)) with the cell each comes from."""
    tris, quads = [], []
    for name, conn in cells:
        el = ELEMENTS.get(name)
        if el is None or conn.shape[0] == 0:
            continue
        for f in el.faces:
            (tris if len(f) == 3 else quads).append(conn[:, list(f)])
    T = np.concatenate(tris) if tris else np.zeros((0, 3), dtype=np.int64)
    Q = np.concatenate(quads) if quads else np.zeros((0, 4), dtype=np.int64)
    return T, Q


def _once(F):
    if F.shape[0] == 0:
        return F
    key = np.sort(F, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return F[counts[inv.ravel()] == 1]


def boundary_faces(cells):
    """The boundary faces of ``cells`` (list of (type, conn), VTK order): (tris (T, 3), quads (Q, 4))."""
    T, Q = _faces_of(cells)
    return _once(T), _once(Q)


def interior_vertices(cells, n_points):
    """(n_points,) bool: the vertices on no boundary face of ``cells`` (list of (type, conn), VTK order)."""
    inner = np.ones(int(n_points), dtype=bool)
    for F in boundary_faces(cells):
        inner[F.ravel()] = False
    return inner


def quad_areas(V, quads):
    """(Q, 3): twice the vector area of each quad (the cross product of its diagonals)."""
    return np.cross(V[quads[:, 2]] - V[quads[:, 0]], V[quads[:, 3]] - V[quads[:, 1]])


def quad_corners(V, quads, normal):
    """(Q, 4): ``n . (a x b)`` at each corner of the quads (a, b its edges to the next and the previous corner, n
    the quad's unit normal (Q, 3)); a corner <= 0 is turned over or degenerate against n."""
    X = V[quads]
    a = np.roll(X, -1, axis=1) - X
    b = np.roll(X, 1, axis=1) - X
    return (np.asarray(normal)[:, None, :] * np.cross(a, b)).sum(axis=2)


def _triangles(tris, quads):
    return np.concatenate([tris, quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]).astype(np.int64)


@dataclass
class Slide:
    """The boundary penalty of the optimizer: vertices ``idx`` pay ``w |Q (x - ref)|^2 / s2``."""

    idx: np.ndarray
    Q: np.ndarray
    ref: np.ndarray
    s2: np.ndarray
    frames: object = None  # optional callable(V, idx) -> (rows, Q): the normals where the vertices are now

    def follow(self, V):
        """References and normals moved to where the vertices are in V (after a projection onto the surface)."""
        self.ref = np.array(V[self.idx], dtype=np.float64)
        if self.frames is None or self.idx.size == 0:
            return
        rows, Q = self.frames(V, self.idx)
        pos = np.searchsorted(self.idx, rows)
        self.Q[pos] = Q


class NearestPoints:
    """libigl's exact nearest points on a fixed mesh of triangles or segments (V, F), through an AABB tree built at
    the first query and kept (``igl.AABB``; a tree per call, as ``igl.point_mesh_squared_distance`` builds, took
    2.7 ms of its 2.8 for 40 points on rockarm's 2,980 triangles; the kept one 0.05 ms, the same points to the
    bit). libigl's bindings before 2.6 have no ``AABB``: there a tree per call."""

    def __init__(self, V, F):
        self.V = np.ascontiguousarray(V, dtype=np.float64)
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        self.tree = None

    def __call__(self, P):
        """(squared distances (k,), element indices (k,), nearest points (k, 3)) of the points P (k, 3)."""
        igl = _igl()
        P = np.ascontiguousarray(P, dtype=np.float64)
        if not hasattr(igl, "AABB"):
            d2, I, C = igl.point_mesh_squared_distance(P, self.V, self.F)
        else:
            if self.tree is None:
                self.tree = igl.AABB()
                self.tree.init(self.V, self.F)
            d2, I, C = self.tree.squared_distance(self.V, self.F, P)
        return np.asarray(d2).ravel(), np.asarray(I, dtype=np.int64).ravel(), np.asarray(C)


@dataclass
class BoundaryModel:
    """The input's boundary: vertex kinds, normals / tangents, and the surface to project onto."""

    vertices: np.ndarray  # (B,) boundary vertex indices
    kind: np.ndarray  # (B,) 0 surface, 1 curve, 2 corner
    normal: np.ndarray  # (B, 3) unit normals (surface vertices)
    tangent: np.ndarray  # (B, 3) unit tangents (curve vertices)
    size: np.ndarray  # (B,) mean length of the boundary edges at the vertex
    surf_V: np.ndarray  # (n, 3) input coordinates
    surf_F: np.ndarray  # (T, 3) boundary triangles
    feat_E: np.ndarray  # (E, 2) feature segments
    feature_edges: int
    tolerance: np.ndarray | None = None  # (B,) the band: how far each may sit off its surface / curve / corner
    quads: np.ndarray | None = None  # (Q, 4) the boundary quads, each ordered as seen from outside ...
    quad_normal: np.ndarray | None = None  # (Q, 3) ... its unit outward normal in the input (:func:`boundary_model`)
    quad_s2: np.ndarray | None = None  # (Q,) the mean squared boundary edge length at its vertices
    leash: np.ndarray | None = None  # (B,) how far each may end from its input position (inf: any distance)
    diagonal: float = 0.0  # of the boundary vertices' bounding box in the input (a point no cell uses is no part of it)
    trees: dict = field(default_factory=dict, repr=False, compare=False)  # kind -> NearestPoints, built once

    def nearest(self, P, kind):
        """The exact nearest points of P (k, 3) on the input's boundary triangles (``kind`` 0) or feature segments
        (1): (squared distances (k,), element indices (k,), points (k, 3)) (:class:`NearestPoints`, kept)."""
        if kind not in self.trees:
            self.trees[kind] = NearestPoints(self.surf_V, self.surf_F if kind == 0 else self.feat_E)
        return self.trees[kind](P)

    @property
    def corners(self) -> np.ndarray:
        return self.vertices[self.kind == 2]

    def released(self, corners) -> "BoundaryModel":
        """This model with the feature corners ``corners`` (vertex indices) made surface vertices: they slide on
        the input surface (normal: their vertex normal) where they were pinned; the rest unchanged."""
        kind = self.kind.copy()
        kind[np.isin(self.vertices, corners) & (kind == 2)] = 0
        return replace(self, kind=kind)

    def turned_quads(self, V) -> np.ndarray:
        """(Q,) bool: the boundary quads whose vector area at V points against their input normal (turned over: the
        surface is folded there, with the cells on both sides valid or not). A quad with no input normal (neither it
        nor its vertices' faces had an area in the input: every point coincident) counts as not turned."""
        return self.quad_tilt(V) <= 0

    def tilted_quads(self, V, degrees: float = TILT_DEGREES) -> np.ndarray:
        """(Q,) bool: the boundary quads whose vector area at V is more than ``degrees`` from their input normal
        (turned over ones too): the surface's orientation lost there, though its vertices may lie on it."""
        return self.quad_tilt(V) < np.cos(np.radians(float(degrees)))

    def quad_tilt(self, V, rows=None) -> np.ndarray:
        """(Q,): the cosine of the angle between each boundary quad's vector area at V and its input normal (-1 to
        1; 0 where the quad has no area at V); 1 for a quad with no input normal (every point of the input
        coincident), which counts as neither turned nor tilted. ``rows``: those quads only, in that order."""
        if self.quads is None or self.quads.shape[0] == 0:
            return np.zeros(0)
        rows = slice(None) if rows is None else np.asarray(rows, dtype=np.int64)
        n = self.quad_normal[rows]
        a = quad_areas(V, self.quads[rows])
        size = np.sqrt((a * a).sum(axis=1))
        cos = np.where(size > 0, (a * n).sum(axis=1) / np.where(size > 0, size, 1.0), 0.0)
        return np.where((n != 0).any(axis=1), cos, 1.0)

    def surface(self):
        """The boundary quads, their input normals and squared sizes: an optimizer's ``surface`` (stage 1's term and
        stage 2's barrier keep them from turning over, :class:`hexsos_plugins.meshrepair.optimize.Problem`)."""
        return self.quads, self.quad_normal, self.quad_s2

    def slide(self, V, movable) -> Slide:
        """The penalty terms of the boundary vertices that may move (``movable`` (N,) bool), not corners."""
        keep = (self.kind < 2) & movable[self.vertices]
        idx = self.vertices[keep]
        n, t = self.normal[keep], self.tangent[keep]
        Q = np.where((self.kind[keep] == 0)[:, None, None], n[:, :, None] * n[:, None, :],
                     np.eye(3)[None] - t[:, :, None] * t[:, None, :])
        return Slide(idx=idx, Q=Q, ref=np.array(V[idx], dtype=np.float64), s2=_sized(self.size)[keep] ** 2,
                     frames=self.frames)

    def closest(self, V, idx=None) -> np.ndarray:
        """V with the (given, else all) surface and curve vertices moved to the nearest point of the input surface
        / curve, and corners to their input position; a leashed vertex (:meth:`leashed`) to the nearest such point
        within its leash of its input position."""
        W = np.array(V, dtype=np.float64, copy=True)
        sel = np.ones(self.vertices.size, dtype=bool) if idx is None else np.isin(self.vertices, idx)
        for kind, F in ((0, self.surf_F), (1, self.feat_E)):
            rows = self.vertices[(self.kind == kind) & sel]
            if rows.size == 0 or F.shape[0] == 0:
                continue
            W[rows] = self.nearest(W[rows], kind)[2]
            if self.leash is not None:
                W[rows] = self._held(W[rows], rows, kind)
        rows = self.vertices[(self.kind == 2) & sel]
        W[rows] = self.surf_V[rows]
        return W

    def _held(self, C, rows, kind, rounds: int = LEASH_ROUNDS):
        """C (k, 3), points of the surface (``kind`` 0) or curve (1) nearest to boundary vertices ``rows``, each
        brought within its leash of its input position: toward it along the line, then back onto the surface, a few
        times (on a curved surface one projection may leave it a little outside; its last point is inside)."""
        R = self.leash[np.searchsorted(self.vertices, rows)]
        C = np.array(C, dtype=np.float64, copy=True)
        for k in range(rounds + 1):
            A = self.surf_V[rows]
            d = C - A
            n = np.sqrt((d * d).sum(axis=1))
            far = n > R
            if not far.any():
                break
            pulled = A[far] + (R[far] / n[far])[:, None] * d[far]
            C[far] = pulled if k == rounds else self.nearest(pulled, kind)[2]
        return C

    def leashed(self, vertices, radius) -> "BoundaryModel":
        """This model with the boundary vertices ``vertices`` held within ``radius`` of their input positions in
        every projection (:meth:`closest`, :meth:`closest_point`; their band, :meth:`project`, on top); the rest
        unchanged."""
        leash = np.full(self.vertices.size, np.inf) if self.leash is None else self.leash.copy()
        leash[np.isin(self.vertices, vertices)] = float(radius)
        return replace(self, leash=leash)

    def closest_point(self, x, v) -> np.ndarray:
        """(3,): the nearest point to ``x`` (3,) of boundary vertex ``v``'s input surface or curve, as :meth:`closest`
        moves it there (a corner: its input position)."""
        at = int(np.searchsorted(self.vertices, v))
        if at >= self.vertices.size or self.vertices[at] != v:
            raise InvalidInputError(f"expected a boundary vertex, found vertex {int(v)}, which is on no boundary face")
        kind = int(self.kind[at])
        if kind == 2:
            return np.array(self.surf_V[v], dtype=np.float64)
        if (self.surf_F if kind == 0 else self.feat_E).shape[0] == 0:
            return np.array(x, dtype=np.float64)
        C = self.nearest(np.asarray(x, dtype=np.float64)[None], kind)[2]
        if self.leash is not None:
            C = self._held(C, np.array([v]), kind)
        return C[0]

    def deviation(self, V, samples: int = DEVIATION_SAMPLES) -> np.ndarray:
        """(T,): for each of the input's boundary triangles (``surf_F``), the largest distance between the input's
        boundary surface and the one at V (the same triangles) found at it: points spread on each triangle
        (``samples`` + 1 along an edge, the corners included), each at its exact distance to the other surface; a
        triangle's deviation is the largest of its own points' on either surface and of the input's points nearest
        to it at V (where a quad cuts across a crease of the input, the crease's points are far from the quad). The
        largest is the sampled Hausdorff distance of :func:`hexsos_plugins.meshrepair.fidelity.boundary_fidelity`
        (both directions), by place."""
        F = self.surf_F
        if F.shape[0] == 0:
            return np.zeros(0)
        n = int(samples)
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = (i + j) <= n
        a, b = i[keep] / n, j[keep] / n
        w = np.stack([1.0 - a - b, a, b], axis=1)  # (s, 3) barycentric weights
        owner = np.repeat(np.arange(F.shape[0]), w.shape[0])
        S0 = np.einsum("sk,tkd->tsd", w, self.surf_V[F]).reshape(-1, 3)
        S1 = np.einsum("sk,tkd->tsd", w, np.asarray(V, dtype=np.float64)[F]).reshape(-1, 3)
        back = np.sqrt(self.nearest(S1, 0)[0])  # V's surface to the input's
        d2, near, _ = NearestPoints(V, F)(S0)  # the input's surface to V's
        fwd = np.sqrt(d2)
        out = np.zeros(F.shape[0])
        np.maximum.at(out, owner, np.maximum(back, fwd))
        np.maximum.at(out, near, fwd)
        return out

    def frames(self, V, idx):
        """For the surface and curve vertices among ``idx``: (rows, Q (k, 3, 3)), the projector onto the normal of
        the input surface triangle nearest to each (curves: across the nearest feature segment), for a penalty
        that follows a vertex sliding away from where the input's vertex normal was taken."""
        rows_out, Q_out = [], []
        sel = np.isin(self.vertices, idx)
        for kind, F in ((0, self.surf_F), (1, self.feat_E)):
            rows = self.vertices[(self.kind == kind) & sel]
            if rows.size == 0 or F.shape[0] == 0:
                continue
            F = np.ascontiguousarray(F, dtype=np.int64)
            I = self.nearest(V[rows], kind)[1]
            A = self.surf_V[F[I, 0]]
            if kind == 0:
                u = np.cross(self.surf_V[F[I, 1]] - A, self.surf_V[F[I, 2]] - A)
            else:
                u = self.surf_V[F[I, 1]] - A
            n = np.linalg.norm(u, axis=1)
            ok = n > 0
            u = u / np.where(ok, n, 1.0)[:, None]
            outer = u[:, :, None] * u[:, None, :]
            Q = outer if kind == 0 else np.eye(3)[None] - outer
            rows_out.append(rows[ok])
            Q_out.append(Q[ok])
        if not rows_out:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 3, 3))
        return np.concatenate(rows_out), np.concatenate(Q_out)

    def band_width(self) -> np.ndarray:
        """(B,) how far each boundary vertex may sit off its surface, curve or corner (0: exactly on it)."""
        return np.zeros(self.vertices.size) if self.tolerance is None else self.tolerance

    def project(self, V, idx=None, band=True) -> np.ndarray:
        """V with the (given, else all) boundary vertices moved back into the band: onto the nearest point of the
        input surface / curve (corners: their input position) where the band is 0, else toward it until they are
        at most the band's width from it (``band=False``: onto it). Corners move only with a band (without one
        they are pinned)."""
        X = np.asarray(V, dtype=np.float64)
        C = self.closest(X, idx)
        width = np.zeros(X.shape[0])
        if band:
            width[self.vertices] = self.band_width()
        d = X - C
        n = np.sqrt((d * d).sum(axis=1))
        with np.errstate(divide="ignore", invalid="ignore"):
            keep = np.where(n > width, width / n, 1.0)
        return C + keep[:, None] * d

    def distance(self, V, idx=None) -> np.ndarray:
        """Distance of the boundary vertices (or ``idx``) to the input surface."""
        rows = self.vertices if idx is None else np.asarray(idx)
        if rows.size == 0:
            return np.zeros(0)
        return np.sqrt(self.nearest(V[rows], 0)[0])


#: The band's width at most: this fraction of the diagonal of the input's bounding box, whatever the edge length (a
#: coarse or graded boundary's fraction of an edge is more: dinopet_graded's band of 0.35 of an edge left its
#: boundary 1.85% of the diagonal from the input's, capped 1.20%, at the same minimum, 0.770)
BAND_DIAGONAL = 0.012


def size_floor(sizes) -> float:
    """The least size the repair's energies divide by: a thousandth of the median of the finite positive values of
    ``sizes`` (an array, or a list of arrays), 1 when there is none. Cells of coincident vertices have size 0."""
    pos = np.concatenate([np.asarray(s, dtype=np.float64).ravel() for s in
                          (sizes if isinstance(sizes, (list, tuple)) else [sizes])] + [np.zeros(0)])
    pos = pos[np.isfinite(pos) & (pos > 0)]
    return 1e-3 * float(np.median(pos)) if pos.size else 1.0


def _sized(size):
    """Boundary edge lengths for the terms that divide by their square, each at least :func:`size_floor`. Where
    boundary vertices coincide, the size 0 (squared, 1e-300 underflows to 0) made the boundary penalty's weight
    infinite and stage 1's energy NaN (every point of a mesh on one line)."""
    return np.maximum(size, size_floor(size))


def _igl():
    try:
        import igl
    except ImportError as exc:
        raise DependencyError("boundary='slide' projects onto the input surface with libigl: pip install libigl "
                              "(or repair with boundary='fixed' / 'free')") from exc
    return igl


def boundary_model(points, cells, *, feature_angle: float = 45.0, suspect=None, tolerance: float = 0.0) -> BoundaryModel:
    """Analyse the boundary of ``cells`` (list of (type, conn)) at ``points`` (the input).

    ``tolerance``: the band (module docstring), a fraction of each boundary vertex's mean boundary edge length, at
    most :data:`BAND_DIAGONAL` of the diagonal of the boundary's bounding box.

    ``suspect`` (N,) bool, optional: vertices of inverted cells. A boundary face whose vertices are all suspect is
    folded or about to be: its normal says nothing about the surface, so it makes no feature edge and counts in a
    vertex's normal only when the vertex has no other face (measured on dinopet_graded: its inverted boundary hexes
    made 231 feature corners, pinned, and the repair moved the boundary 4.2% of the diagonal to untangle around
    them; without their folded faces' normals, 0.97%)."""
    P = np.asarray(points, dtype=np.float64)
    tris, quads = boundary_faces(cells)
    faces = [f for f in (tris, quads) if f.shape[0]]
    tri = _triangles(tris, quads)
    # face normals (quads: cross product of the diagonals), area-weighted vertex normals
    fn = []
    if tris.shape[0]:
        a, b, c = P[tris[:, 0]], P[tris[:, 1]], P[tris[:, 2]]
        fn.append(0.5 * np.cross(b - a, c - a))
    if quads.shape[0]:
        fn.append(0.5 * quad_areas(P, quads))
    fn = np.concatenate(fn) if fn else np.zeros((0, 3))
    allf = np.concatenate([np.pad(tris, ((0, 0), (0, 1)), constant_values=-1), quads]) if faces else np.zeros((0, 4), int)
    verts = np.unique(allf[allf >= 0])
    N = P.shape[0]
    bad_face = np.zeros(allf.shape[0], dtype=bool)
    if suspect is not None and allf.shape[0]:
        sus = np.asarray(suspect, dtype=bool)
        bad_face = np.where(allf >= 0, sus[np.maximum(allf, 0)], True).all(axis=1)

    def _normals(weight):
        out = np.zeros((N, 3))
        for k in range(4):
            col = allf[:, k]
            ok = col >= 0
            for a in range(3):
                out[:, a] += np.bincount(col[ok], weights=(fn[:, a] * weight)[ok], minlength=N)
        return out

    vn = _normals(~bad_face)
    if bad_face.any():
        only_bad = np.linalg.norm(vn, axis=1) == 0
        vn[only_bad] = _normals(np.ones(allf.shape[0], dtype=bool))[only_bad]
    # boundary edges and the faces on each side (faces numbered: triangles first, then quads)
    e_list, f_list = [], []
    for F, off in ((tris, 0), (quads, tris.shape[0])):
        k = F.shape[1]
        for j in range(k):
            e_list.append(np.sort(F[:, [j, (j + 1) % k]], axis=1))
            f_list.append(off + np.arange(F.shape[0]))
    E = np.concatenate(e_list) if e_list else np.zeros((0, 2), dtype=np.int64)
    Fi = np.concatenate(f_list) if f_list else np.zeros(0, dtype=np.int64)
    uniq, inv, counts = np.unique(E, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    order = np.argsort(inv, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)])
    unit = fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    feature = counts != 2
    two = np.flatnonzero(counts == 2)
    f1 = Fi[order[starts[two]]]
    f2 = Fi[order[starts[two] + 1]]
    cosang = (unit[f1] * unit[f2]).sum(axis=1)
    # a face of no area (collapsed cells) has no normal: its edges are not features for that reason alone (they
    # made every vertex of a collapsed layer a pinned corner)
    area = np.linalg.norm(fn, axis=1)
    flat = area <= 1e-12 * (float(np.median(area)) if area.size else 0.0)
    flat |= bad_face
    cosang = np.where(flat[f1] | flat[f2], 1.0, cosang)
    feature[two] = cosang < np.cos(np.radians(feature_angle))
    feat = uniq[feature]
    nfeat = np.bincount(feat.ravel(), minlength=N)
    kind = np.where(nfeat[verts] == 0, 0, np.where(nfeat[verts] == 2, 1, 2))
    # tangents of curve vertices: from the two feature edges
    tangent = np.zeros((verts.size, 3))
    curve = np.flatnonzero(kind == 1)
    if curve.size:
        pos = np.full(N, -1)
        pos[verts[curve]] = np.arange(curve.size)
        acc = np.zeros((curve.size, 3))
        cnt = np.zeros(curve.size, dtype=int)
        for a, b in feat:
            for u, v in ((a, b), (b, a)):
                i = pos[u]
                if i >= 0:
                    d = P[v] - P[u]
                    d /= max(np.linalg.norm(d), 1e-300)
                    acc[i] += d if cnt[i] == 0 else -d
                    cnt[i] += 1
        tangent[curve] = acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-300)
    normal = vn[verts] / np.maximum(np.linalg.norm(vn[verts], axis=1, keepdims=True), 1e-300)
    # local size: mean boundary edge length at each vertex
    el = np.linalg.norm(P[uniq[:, 0]] - P[uniq[:, 1]], axis=1)
    ssum = np.bincount(uniq.ravel(), weights=np.repeat(el, 2), minlength=N)
    scnt = np.bincount(uniq.ravel(), minlength=N)
    size = ssum[verts] / np.maximum(scnt[verts], 1)
    # the boundary quads' input normals: a quad's own (its vector area) unless it has no area or is folded itself
    # (a corner's normal against it); then the sum of its vertices' normals. Not whether its hex is inverted: a
    # stress test inverts every hex and leaves the surface as it was, and on a thin part (Dolphin_2's fins) the
    # vertex normals of both sides cancel
    qn = fn[tris.shape[0]:]
    qbad = area[tris.shape[0]:] <= 1e-12 * (float(np.median(area)) if area.size else 0.0)
    qbad |= quad_corners(P, quads, qn).min(axis=1) <= 0
    qn = np.where(qbad[:, None], vn[quads].sum(axis=1), qn)
    qn = qn / np.maximum(np.linalg.norm(qn, axis=1, keepdims=True), 1e-300)
    size2 = np.zeros(N)
    size2[verts] = _sized(size) ** 2
    diagonal = float(np.linalg.norm(np.ptp(P[verts], axis=0))) if verts.size else 0.0
    return BoundaryModel(vertices=verts, kind=kind, normal=normal, tangent=tangent, size=size,
                         surf_V=np.ascontiguousarray(P), surf_F=np.ascontiguousarray(tri),
                         feat_E=np.ascontiguousarray(feat), feature_edges=int(feat.shape[0]),
                         tolerance=np.minimum(float(tolerance) * size, BAND_DIAGONAL * diagonal),
                         quads=np.ascontiguousarray(quads, dtype=np.int64),
                         quad_normal=qn, quad_s2=size2[quads].mean(axis=1) if quads.shape[0] else np.zeros(0),
                         diagonal=diagonal)
