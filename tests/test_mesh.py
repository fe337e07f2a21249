"""HexMesh: construction and validation, orientation, flipping, write-back arrays, boundary faces.

Every mesh is generated here (structured grids, hand-made blocks). Each check has a case that must fail.
"""

from __future__ import annotations

import copy

import meshio
import numpy as np
import pytest

from hexsos_plugins.io import mesh as mesh_module
from hexsos_plugins.errors import InvalidInputError, NoCellsError, NoHexahedraError
from hexsos_plugins.cells.hexahedron import det_at
from hexsos_plugins.io.mesh import FLIP, INT_FILL, MIRROR, HexMesh


# ---------------------------------------------------------------------------------------------- fixtures
def grid(n, *, spacing=1.0, origin=(0.0, 0.0, 0.0)):
    """An n x n x n structured grid of unit hexes: points ((n+1)^3, 3), hexes (n^3, 8) in VTK order."""
    x = origin[0] + spacing * np.arange(n + 1, dtype=float)
    y = origin[1] + spacing * np.arange(n + 1, dtype=float)
    z = origin[2] + spacing * np.arange(n + 1, dtype=float)
    Z, Y, X = np.meshgrid(z, y, x, indexing="ij")
    points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)  # [k, j, i]
    c = idx[:-1, :-1, :-1]
    hexes = np.stack(
        [c, c + 1, c + (n + 1) + 1, c + (n + 1), c + (n + 1) ** 2, c + (n + 1) ** 2 + 1,
         c + (n + 1) ** 2 + (n + 1) + 1, c + (n + 1) ** 2 + (n + 1)], axis=-1
    ).reshape(-1, 8)
    return points, hexes


def centre_det(points, hexes):
    return det_at(points[hexes], np.array([0.5, 0.5, 0.5]))[0]


def voxel_block(data):
    """A meshio cell block of type 'voxel' (meshio's CellBlock constructor refuses that name)."""
    block = meshio.CellBlock("hexahedron", np.asarray(data))
    block.type = "voxel"
    return block


def mixed_source():
    """hexahedron block, tetra, quad, hexahedron block, hexahedron20 (higher order), wedge; with data."""
    pts, hexes = grid(2)
    n = len(pts)
    extra = np.array([[0, 0, 3.0], [1, 0, 3], [0, 1, 3], [0, 0, 4], [1, 0, 4], [0, 1, 4]])
    points = np.vstack([pts, extra])
    h20 = np.arange(20) % n  # connectivity content is irrelevant: the block is only carried along
    cells = [
        ("hexahedron", hexes[:3]),
        ("tetra", np.array([[n, n + 1, n + 2, n + 3]])),
        ("quad", hexes[:2, :4]),
        ("hexahedron", hexes[3:]),
        ("hexahedron20", h20[None, :]),
        ("wedge", np.array([[n, n + 1, n + 2, n + 3, n + 4, n + 5]])),
    ]
    cell_data = {
        "gmsh:physical": [np.full(len(c[1]), i + 1, dtype=np.int32) for i, c in enumerate(cells)],
        "material": [np.arange(len(c[1]), dtype=float) + 10 * i for i, c in enumerate(cells)],
    }
    point_data = {"temperature": np.arange(len(points), dtype=float)}
    return meshio.Mesh(points, cells, point_data=point_data, cell_data=cell_data,
                       field_data={"Inner": np.array([1, 3])})


def fingerprint(m: meshio.Mesh):
    return copy.deepcopy((m.points, [(b.type, np.array(b.data)) for b in m.cells],
                          {k: [np.array(a) for a in v] for k, v in m.cell_data.items()},
                          {k: np.array(v) for k, v in m.point_data.items()}, m.field_data))


def same(a, b):
    pa, ca, cda, pda, fa = a
    pb, cb, cdb, pdb, fb = b
    return (np.array_equal(pa, pb) and len(ca) == len(cb)
            and all(t1 == t2 and np.array_equal(d1, d2) for (t1, d1), (t2, d2) in zip(ca, cb))
            and cda.keys() == cdb.keys()
            and all(np.array_equal(x, y, equal_nan=True) for k in cda for x, y in zip(cda[k], cdb[k]))
            and pda.keys() == pdb.keys() and all(np.array_equal(pda[k], pdb[k]) for k in pda)
            and fa.keys() == fb.keys() and all(np.array_equal(fa[k], fb[k]) for k in fa))


# ---------------------------------------------------------------------------------------------- from_arrays
def test_from_arrays_builds_one_hexahedron_block():
    pts, hexes = grid(2)
    hm = HexMesh.from_arrays(pts, hexes)
    assert hm.points.dtype == np.float64 and hm.points.shape == (27, 3)
    assert hm.hexes.dtype == np.int64 and np.array_equal(hm.hexes, hexes)
    assert [b.type for b in hm.source.cells] == ["hexahedron"]
    assert hm.hex_blocks == [(0, 0, 8)]
    assert hm.n_hexes == 8 and hm.n_points == 27
    assert "8 hexahedra" in repr(hm)
    # inputs are copied, not aliased
    pts[0, 0] = 99.0
    assert hm.points[0, 0] == 0.0


@pytest.mark.parametrize(
    "points, hexes, error, words",
    [
        (np.zeros((8, 2)), [list(range(8))], InvalidInputError, "(N, 3)"),
        ("nan", [list(range(8))], InvalidInputError, "point 3"),
        ("inf", [list(range(8))], InvalidInputError, "point 3"),
        (None, [list(range(7))], InvalidInputError, "(M, 8)"),
        (None, [[0, 1, 2, 3, 4, 5, 6, 8]], InvalidInputError, "point 8"),
        (None, [[0, 1, 2, 3, 4, 5, 6, -1]], InvalidInputError, "point -1"),
        (None, [[0, 1, 2, 3, 4, 5, 6, 7.5]], InvalidInputError, "integer"),
        (None, np.zeros((0, 8), dtype=int), NoHexahedraError, "at least one"),
    ],
)
def test_from_arrays_rejects_bad_input(points, hexes, error, words):
    cube, _ = grid(1)
    if points is None:
        points = cube
    elif isinstance(points, str):
        bad = cube.copy()
        bad[3, 1] = np.nan if points == "nan" else np.inf
        points = bad
    with pytest.raises(error) as info:
        HexMesh.from_arrays(points, hexes)
    assert words in str(info.value)


def test_index_error_names_the_hex_and_the_point():
    pts, hexes = grid(2)
    hexes = hexes.copy()
    hexes[5, 2] = 1000
    with pytest.raises(InvalidInputError, match=r"hexes\[5\].*point 1000.*27 points"):
        HexMesh.from_arrays(pts, hexes)
    HexMesh.from_arrays(pts, grid(2)[1])  # the unmodified grid passes


def test_unreferenced_points_are_accepted():
    pts, hexes = grid(1)
    pts = np.vstack([pts, [[5.0, 5.0, 5.0], [6.0, 6.0, 6.0]]])
    hm = HexMesh.from_arrays(pts, hexes)
    assert hm.n_points == 10
    assert not hm.boundary_vertices()[8:].any() and hm.boundary_vertices()[:8].all()


# ---------------------------------------------------------------------------------------------- from_meshio
def test_from_meshio_collects_hex_blocks_in_order_and_keeps_the_rest():
    src = mixed_source()
    before = fingerprint(src)
    hm = HexMesh.from_meshio(src, path="x.vtu")
    assert hm.hex_blocks == [(0, 0, 3), (3, 3, 8)]
    assert np.array_equal(hm.hexes, grid(2)[1])
    assert hm.source is src and same(fingerprint(src), before)
    assert hm.path == "x.vtu"
    assert not hm.voxel_rows.any()


@pytest.mark.parametrize(
    "cells, words",
    [
        ([("triangle", np.array([[0, 1, 2]] * 30)), ("line", np.array([[0, 1]] * 3))], ["30 triangle", "3 line"]),
        ([("quad", np.array([[0, 1, 2, 3]] * 4))], ["4 quad"]),
        ([("tetra84", np.zeros((2, 84), dtype=int))], ["2 tetra84", "not checked"]),  # order 6: beyond hexsos
        ([("hexahedron", np.zeros((0, 8), dtype=int)), ("triangle", np.array([[0, 1, 2]]))], ["1 triangle"]),
    ],
)
def test_from_meshio_without_checkable_cells(cells, words):
    pts, _ = grid(1)
    with pytest.raises(NoHexahedraError) as info:
        HexMesh.from_meshio(meshio.Mesh(pts, cells), path="t.vtk")
    assert isinstance(info.value, NoCellsError)
    for w in words:
        assert w in str(info.value)
    assert "t.vtk" in str(info.value)


def test_a_mesh_without_hexahedra_is_a_mesh():
    """Tetrahedra alone (or quadratic hexahedra alone) are checkable cells now: no error, no hexes."""
    pts, _ = grid(1)
    m = HexMesh.from_meshio(meshio.Mesh(pts, [("tetra", np.array([[0, 1, 3, 4]] * 3)),
                                              ("triangle", np.array([[0, 1, 2]]))]))
    assert m.n_hexes == 0 and m.hexes.shape == (0, 8) and m.n_cells == 3 and m.counts_by_type() == {"tetra": 3}
    assert m.cells[0][0] == "tetra" and m.cell_types.tolist() == [0, 0, 0]


def test_from_meshio_names_the_offending_cell_and_point():
    pts, hexes = grid(2)
    bad = hexes.copy()
    bad[1, 0] = 27
    m = meshio.Mesh(pts, [("tetra", np.array([[0, 1, 2, 3]])), ("hexahedron", bad)])
    with pytest.raises(InvalidInputError, match=r"cell 1 of block 1.*point 27"):
        HexMesh.from_meshio(m)
    nanpts = pts.copy()
    nanpts[13] = np.nan
    with pytest.raises(InvalidInputError, match="point 13"):
        HexMesh.from_meshio(meshio.Mesh(nanpts, [("hexahedron", hexes)]))
    with pytest.raises(InvalidInputError):
        HexMesh.from_meshio("not a mesh")


def test_voxels_are_converted_to_right_handed_hexes():
    pts, hexes = grid(2, spacing=0.5, origin=(1.0, 2.0, 3.0))
    from hexsos_plugins.cells.hexahedron import VOXEL_TO_VTK

    vox = hexes[:, VOXEL_TO_VTK]  # the same cells in VTK_VOXEL (lexicographic) node order
    m = meshio.Mesh(pts, [])
    m.cells = [voxel_block(vox[:5]), meshio.CellBlock("hexahedron", hexes[5:])]
    hm = HexMesh.from_meshio(m)
    assert np.array_equal(hm.hexes, hexes)
    assert (centre_det(hm.points, hm.hexes) > 0).all()
    assert hm.orientation() == "right-handed"
    assert hm.voxel_rows.tolist() == [True] * 5 + [False] * 3
    # negative case: voxel node order taken as a hexahedron is a twisted cell, not a positive one
    assert not (centre_det(pts, vox) > 0).any()
    # write-back: voxel blocks come out as hexahedron blocks in VTK order
    out = hm.to_meshio()
    assert [b.type for b in out.cells] == ["hexahedron", "hexahedron"]
    assert np.array_equal(out.cells[0].data, hexes[:5])
    assert m.cells[0].type == "voxel" and np.array_equal(m.cells[0].data, vox[:5])


# ---------------------------------------------------------------------------------------------- orientation
def test_orientation_right_left_mixed():
    pts, hexes = grid(3)
    assert HexMesh.from_arrays(pts, hexes).orientation() == "right-handed"
    mirrored = pts * np.array([-1.0, 1.0, 1.0])
    assert HexMesh.from_arrays(mirrored, hexes).orientation() == "left-handed"
    some = hexes.copy()
    some[4] = some[4, FLIP]
    assert HexMesh.from_arrays(pts, some).orientation() == "mixed"
    assert HexMesh.from_arrays(pts, hexes[:, FLIP]).orientation() == "left-handed"


def test_orientation_ignores_flat_hexes():
    pts, hexes = grid(1)
    flat = pts.copy()
    flat[:, 2] = 0.0  # det J == 0 everywhere
    both = np.vstack([pts, flat])
    hm = HexMesh.from_arrays(both, np.vstack([hexes[:, FLIP], hexes + 8]))
    assert hm.orientation() == "left-handed"  # the flat hex counts as neither
    assert HexMesh.from_arrays(flat, hexes).orientation() == "right-handed"


def test_flipped_fixes_a_left_handed_mesh_and_leaves_the_original_alone():
    src = mixed_source()
    src.points[:, 0] *= -1.0  # mirror: every hex left-handed
    hm = HexMesh.from_meshio(src)
    before_hexes = hm.hexes.copy()
    before_src = fingerprint(src)
    assert hm.orientation() == "left-handed"
    fixed = hm.flipped()
    assert fixed.orientation() == "right-handed"
    assert hm.orientation() == "left-handed"
    assert np.array_equal(hm.hexes, before_hexes) and same(fingerprint(src), before_src)
    assert np.array_equal(fixed.hexes, before_hexes[:, FLIP])
    # the copy's source has its hex blocks flipped, the other blocks as they were
    assert np.array_equal(fixed.source.cells[0].data, fixed.hexes[:3])
    assert np.array_equal(fixed.source.cells[3].data, fixed.hexes[3:])
    # every checked type is mirrored with its own permutation (hexahedron20 and wedge here), 2-D cells are not
    assert np.array_equal(fixed.source.cells[4].data, src.cells[4].data[:, MIRROR["hexahedron20"]])
    assert np.array_equal(fixed.source.cells[5].data, src.cells[5].data[:, [0, 2, 1, 3, 5, 4]])
    assert np.array_equal(fixed.source.cells[2].data, src.cells[2].data)
    assert fixed.source is not src
    assert np.array_equal(fixed.flipped().hexes, hm.hexes)


def test_flipped_keeps_voxel_blocks_in_voxel_order():
    pts, hexes = grid(1)
    from hexsos_plugins.cells.hexahedron import VOXEL_TO_VTK

    m = meshio.Mesh(pts * np.array([1.0, 1.0, -1.0]), [])
    m.cells = [voxel_block(hexes[:, VOXEL_TO_VTK])]
    hm = HexMesh.from_meshio(m)
    assert hm.orientation() == "left-handed"
    f = hm.flipped()
    assert f.orientation() == "right-handed"
    assert f.source.cells[0].type == "voxel"
    assert np.array_equal(f.source.cells[0].data[:, VOXEL_TO_VTK], f.hexes)


def test_with_points():
    src = mixed_source()
    hm = HexMesh.from_meshio(src)
    new = hm.points + 1.0
    moved = hm.with_points(new)
    assert np.array_equal(moved.points, new) and np.array_equal(moved.source.points, new)
    assert np.array_equal(moved.hexes, hm.hexes)
    assert np.array_equal(hm.points, src.points) and not np.array_equal(src.points, new)
    with pytest.raises(InvalidInputError, match="expected 33 points"):
        hm.with_points(new[:-1])
    bad = new.copy()
    bad[2, 2] = np.nan
    with pytest.raises(InvalidInputError, match="point 2"):
        hm.with_points(bad)


# ---------------------------------------------------------------------------------------------- to_meshio
def test_to_meshio_spreads_hex_arrays_and_fills_other_blocks():
    src = mixed_source()
    before = fingerprint(src)
    hm = HexMesh.from_meshio(src)
    M, N = hm.n_hexes, hm.n_points
    min_det = np.linspace(1.0, 2.0, M)
    status = np.arange(M, dtype=np.int64)
    argmin = np.arange(3 * M, dtype=float).reshape(M, 3)
    flags = np.arange(M) % 2 == 0
    disp = np.ones((N, 3))
    out = hm.to_meshio(cell_data={"hexsos_min_det": min_det, "hexsos_status": status, "hexsos_argmin": argmin,
                                  "flag": flags},
                       point_data={"hexsos_displacement": disp})
    assert out is not src
    assert [b.type for b in out.cells] == [b.type for b in src.cells]
    assert [len(b.data) for b in out.cells] == [3, 1, 2, 5, 1, 1]
    # source data kept
    assert set(out.cell_data) == {"gmsh:physical", "material", "hexsos_min_det", "hexsos_status",
                                  "hexsos_argmin", "flag"}
    for a, b in zip(out.cell_data["material"], src.cell_data["material"]):
        assert np.array_equal(a, b)
    assert np.array_equal(out.point_data["temperature"], src.point_data["temperature"])
    assert np.array_equal(out.field_data["Inner"], [1, 3])
    # new arrays: hex rows on hex blocks, NaN / -2 elsewhere
    md = out.cell_data["hexsos_min_det"]
    assert np.array_equal(md[0], min_det[:3]) and np.array_equal(md[3], min_det[3:])
    assert all(np.isnan(md[b]).all() for b in (1, 2, 4, 5))
    st = out.cell_data["hexsos_status"]
    assert np.array_equal(np.concatenate([st[0], st[3]]), status)
    assert all((st[b] == INT_FILL).all() and st[b].dtype.kind == "i" for b in (1, 2, 4, 5))
    am = out.cell_data["hexsos_argmin"]
    assert am[2].shape == (2, 3) and np.isnan(am[2]).all() and np.array_equal(am[3], argmin[3:])
    fl = out.cell_data["flag"]
    assert fl[0].dtype == np.int8 and fl[0].tolist() == [1, 0, 1] and fl[1].tolist() == [INT_FILL]
    assert np.array_equal(out.point_data["hexsos_displacement"], disp)
    # meshio accepts the result as consistent
    meshio.Mesh(out.points, out.cells, point_data=dict(out.point_data),
                cell_data={k: list(v) for k, v in out.cell_data.items()})
    # nothing of the source was touched, and the copies are independent
    assert same(fingerprint(src), before)
    out.cells[0].data[0, 0] = 999
    out.cell_data["material"][0][0] = -1.0
    assert same(fingerprint(src), before)


def test_to_meshio_rejects_wrong_lengths():
    hm = HexMesh.from_meshio(mixed_source())
    with pytest.raises(InvalidInputError, match="M = 8"):
        hm.to_meshio(cell_data={"x": np.zeros(7)})
    with pytest.raises(InvalidInputError, match="N = 33"):
        hm.to_meshio(point_data={"x": np.zeros(32)})
    with pytest.raises(InvalidInputError, match="dtype"):
        hm.to_meshio(cell_data={"x": np.array(["a"] * 8)})


# ---------------------------------------------------------------------------------------------- boundary
def _outward(points, hexes, faces, hex_ids):
    """(face normal) . (face centroid - hex centroid) for each face; > 0 means outward."""
    p = points[faces]
    normal = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
    return np.einsum("ij,ij->i", normal, p.mean(axis=1) - points[hexes[hex_ids]].mean(axis=1))


@pytest.mark.parametrize("n", [1, 2, 4])
def test_boundary_faces_of_a_grid(n):
    pts, hexes = grid(n)
    hm = HexMesh.from_arrays(pts, hexes)
    faces, hex_ids = hm.boundary_faces(return_hex=True)
    assert faces.shape == (6 * n * n, 4) and faces.dtype == np.int64
    assert np.array_equal(hm.boundary_faces(), faces)
    assert (_outward(pts, hexes, faces, hex_ids) > 0).all()
    # every boundary face lies on the surface of the cube [0, n]^3
    on_surface = ((pts[faces] == 0) | (pts[faces] == n)).all(axis=1).any(axis=1)
    assert on_surface.all()
    assert len({tuple(sorted(f)) for f in faces.tolist()}) == len(faces)
    mask = hm.boundary_vertices()
    assert mask.sum() == (n + 1) ** 3 - max(n - 1, 0) ** 3
    # negative case: the reversed faces point inward
    assert (_outward(pts, hexes, faces[:, ::-1], hex_ids) < 0).all()


def test_boundary_faces_of_a_left_handed_mesh_point_outward():
    pts, hexes = grid(2)
    mirrored = pts * np.array([1.0, -1.0, 1.0])
    hm = HexMesh.from_arrays(mirrored, hexes)
    assert hm.orientation() == "left-handed"
    faces, ids = hm.boundary_faces(return_hex=True)
    assert len(faces) == 24 and (_outward(mirrored, hexes, faces, ids) > 0).all()


def test_boundary_excludes_shared_faces():
    pts, hexes = grid(2)
    hm = HexMesh.from_arrays(pts, hexes[:2])  # two hexes sharing one face
    faces = hm.boundary_faces()
    assert len(faces) == 10
    shared = {tuple(sorted(hexes[0, [1, 2, 6, 5]]))}
    assert not shared & {tuple(sorted(f)) for f in faces.tolist()}



# ---------------------------------------------------------------------------------------------- mixed meshes
@pytest.fixture(scope="module")
def gmsh_meshes(tmp_path_factory):
    pytest.importorskip("gmsh")
    from test_readers import write_gmsh_meshes

    return write_gmsh_meshes(str(tmp_path_factory.mktemp("mixed")), kinds=("order1", "order2"))


def test_boundary_of_a_mixed_mesh_is_the_box_surface(gmsh_meshes):
    """Hexahedra, prisms, pyramids and tetrahedra: the faces of exactly one cell (triangles and quads) are the
    surface of the box [0, 2] x [0, 1] x [0, 1.3]: outward, area 11.8; no interior face among them."""
    from hexsos_plugins.io import read

    m = read(gmsh_meshes["order1"]["41b"])
    b = m.boundary(return_cell=True)
    assert len(b["triangle"]) and len(b["quad"])
    P = m.points
    area = 0.0
    cells_centroid = {}
    for _, t, s, e in m.cell_blocks:
        conn = [c for (bb, tt, ss, ee), (_, c) in zip(m.cell_blocks, m.cells) if ss == s][0]
        cells_centroid.update(zip(range(s, e), P[conn].mean(axis=1)))
    for kind in ("triangle", "quad"):
        f = P[b[kind]]
        n = np.cross(f[:, 1] - f[:, 0], f[:, 2] - f[:, 0]) if kind == "triangle" else \
            np.cross(f[:, 2] - f[:, 0], f[:, 3] - f[:, 1])
        area += 0.5 * np.linalg.norm(n, axis=1).sum()
        owner = np.array([cells_centroid[c] for c in b[f"{kind}_cell"]])
        assert (np.einsum("ij,ij->i", n, f.mean(axis=1) - owner) > 0).all()
        on = np.isclose(f, 0) | np.isclose(f, [2.0, 1.0, 1.3])
        assert on.all(axis=1).any(axis=1).all()  # every face lies in a face of the box
    assert np.isclose(area, 2 * (2 * 1 + 2 * 1.3 + 1 * 1.3))
    mask = m.boundary_vertices()
    on_box = (np.isclose(P, 0) | np.isclose(P, [2.0, 1.0, 1.3])).any(axis=1)
    assert np.array_equal(mask, on_box)
    # hexahedra's own boundary quads: only those on the box, none shared with a prism or pyramid
    faces, ids = m.boundary_faces(return_hex=True)
    assert len(faces) and (np.isclose(P[faces], 0) | np.isclose(P[faces], [2.0, 1.0, 1.3])).all(axis=1).any(axis=1).all()
    # negative case: the hexahedra alone have more boundary quads (their faces against prisms and pyramids)
    alone = HexMesh.from_arrays(P, m.hexes).boundary_faces()
    assert len(alone) > len(faces)


def test_boundary_vertices_of_quadratic_cells_include_edge_and_face_nodes(gmsh_meshes):
    from hexsos_plugins.io import read

    m = read(gmsh_meshes["order2"]["41b"])
    mask = m.boundary_vertices()
    bottom = np.unique(np.concatenate([b.data.ravel() for b in m.source.cells if b.type in ("triangle6", "quad9")]))
    assert mask[bottom].all()  # every node of the bottom faces, mid-edge and mid-face nodes included
    centres = np.concatenate([c[:, 26] for t, c in m.cells if t == "hexahedron27"])
    assert not mask[centres].any()  # negative case: the hexahedra's centre nodes are inside


def test_orientation_and_flip_per_type():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1]], float)
    m = HexMesh.from_cells(pts, [("tetra", [[0, 1, 2, 3]]), ("wedge", [[0, 2, 1, 3, 5, 4]])])
    assert m.orientations() == {"tetra": "right-handed", "wedge": "left-handed"}
    assert m.orientation() == "mixed" and m.left_handed_types() == ["wedge"]
    fixed = m.flipped(m.left_handed_types())
    assert fixed.orientation() == "right-handed"
    assert np.array_equal(fixed.cells[0][1], m.cells[0][1])  # the tetra is left alone
    with pytest.raises(InvalidInputError, match="cell_types"):
        m.flipped(["nonsense"])
    # arrays over all cells go onto the checked blocks
    out = m.to_meshio(cell_data={"x": np.array([1.0, 2.0])})
    assert [a.tolist() for a in out.cell_data["x"]] == [[1.0], [2.0]]
    with pytest.raises(InvalidInputError, match="M = 2"):
        m.to_meshio(cell_data={"x": np.zeros(3)})


def test_mirrored_cells_are_found_by_the_faces_they_share_not_by_their_sign():
    pts, hexes = grid(4)
    assert not HexMesh.from_arrays(pts, hexes).mirrored_cells().any()
    # a block of 32 hexes written mirrored, glued to a right-handed one: exactly those, and flipping them mends
    half = pts[hexes[:, 0], 0] < 2
    some = hexes.copy()
    some[half] = some[half][:, FLIP]
    m = HexMesh.from_arrays(pts, some)
    assert m.orientation() == "mixed" and np.array_equal(m.mirrored_cells(), half)
    fixed = m.flipped(cells=m.mirrored_cells())
    assert np.array_equal(fixed.hexes, hexes) and np.array_equal(m.hexes, some)
    assert fixed.orientation() == "right-handed" and not fixed.mirrored_cells().any()
    # one cell written the wrong way round
    one = hexes.copy()
    one[21] = one[21, FLIP]
    assert np.flatnonzero(HexMesh.from_arrays(pts, one).mirrored_cells()).tolist() == [21]
    # a slab of cells inverted by their nodes' positions (12 negative at the centre) is not mirrored
    tangled = pts.copy()
    inner = (pts[:, 2] == 2) & (pts[:, :2] > 0).all(axis=1) & (pts[:, :2] < 4).all(axis=1)
    tangled[inner, 2] = -0.5
    t = HexMesh.from_arrays(tangled, hexes)
    assert (t.centre_det() < 0).sum() == 12 and not t.mirrored_cells().any()
    # nor is an inverted hex that shares no face, in a block with positive ones (it could be either)
    alone = np.vstack([pts[hexes[0]], tangled[hexes][t.centre_det() < 0][0]])
    assert not HexMesh.from_arrays(alone, np.arange(16).reshape(2, 8)).mirrored_cells().any()
    # a block negative throughout, glued to nothing, is: the second of two blocks
    far = pts + [10.0, 0.0, 0.0]
    two = HexMesh.from_cells(np.vstack([pts, far]), [("hexahedron", hexes), ("hexahedron", hexes[:, FLIP] + len(pts))])
    assert np.flatnonzero(two.mirrored_cells()).tolist() == list(range(64, 128))
    # other types by their own faces: a tet mirrored beside a right-handed one (they share face 1-2-3)
    tp = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    assert not HexMesh.from_cells(tp, [("tetra", tets)]).mirrored_cells().any()
    bad = tets.copy()
    bad[1] = bad[1][MIRROR["tetra"]]
    assert HexMesh.from_cells(tp, [("tetra", bad)]).mirrored_cells().tolist() == [False, True]
    with pytest.raises(InvalidInputError, match="bool array of shape"):
        m.flipped(cells=np.ones(3, dtype=bool))


def test_boundary_faces_of_a_jumbled_mixed_mesh_match_a_count_of_every_face():
    """Mesh.boundary (faces of exactly one cell, from the faces' node tuples sorted and grouped) against a plain count
    of every face's node set: tetrahedra (triangles) and hexahedra (quads) in random order, some cells written twice
    (a copy counts once: Gmsh's MSH 2 writes an element once per physical group; before, the copies' faces were
    read as shared and left holes in the boundary), point numbers spread over a million (the grouping packs two
    numbers in one)."""
    from collections import Counter

    from hexsos_plugins.cells.elements import ELEMENTS
    from hexsos_plugins.examples import structured_grid

    rng = np.random.default_rng(3)
    P, H = structured_grid(3)
    H = H[rng.permutation(len(H))]
    H = np.concatenate([H, H[:4][:, [1, 2, 3, 0, 5, 6, 7, 4]]])  # four hexes twice, turned: their faces count once
    T = np.array([[0, 1, 4, 16], [1, 5, 4, 17], [0, 1, 4, 16]])  # the first tet twice
    spread = np.sort(rng.choice(10**6, size=len(P), replace=False))
    Q = np.zeros((spread[-1] + 1, 3))
    Q[spread] = P
    cells = [("hexahedron", spread[H]), ("tetra", spread[T])]
    got = mesh_module.Mesh.from_cells(Q, cells).boundary()
    for t, conn in cells:
        k = 4 if t == "hexahedron" else 3
        distinct = list({frozenset(c): c for c in conn[::-1]}.values())  # each cell once
        count = Counter(frozenset(c[list(f)]) for c in distinct for f in ELEMENTS[t].faces if len(f) == k)
        other = Counter()
        for t2, conn2 in cells:
            if t2 != t:
                other.update(frozenset(c[list(f)]) for c in conn2 for f in ELEMENTS[t2].faces if len(f) == k)
        want = sorted(sorted(s) for s, n in (count + other).items() if n == 1)
        assert sorted(sorted(f) for f in got["quad" if k == 4 else "triangle"].tolist()) == want
