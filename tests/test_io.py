"""Reading and writing: tolerant readers, round trips through .vtu/.vtk/.msh/.mesh, Gmsh compatibility,
atomic writes, typed errors, inputs left untouched.

Every file is generated here (numpy grids, hand-written text). Each check has a case that must fail.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import io
import os
import re

import meshio
import numpy as np
import pytest

from hexsos_plugins import io as hio
from hexsos_plugins.errors import (
    InvalidInputError,
    MeshFormatError,
    MeshReadError,
    MeshWriteError,
    NoHexahedraError,
    UnsupportedFormatError,
)
from hexsos_plugins.cells.hexahedron import VOXEL_TO_VTK, det_at
from hexsos_plugins.io.mesh import INT_FILL, HexMesh


# ---------------------------------------------------------------------------------------------- fixtures
def grid(n, spacing=1.0):
    x = spacing * np.arange(n + 1, dtype=float)
    Z, Y, X = np.meshgrid(x, x, x, indexing="ij")
    points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    c = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)[:-1, :-1, :-1]
    s, t = n + 1, (n + 1) ** 2
    hexes = np.stack([c, c + 1, c + s + 1, c + s, c + t, c + t + 1, c + t + s + 1, c + t + s], -1).reshape(-1, 8)
    return points, hexes


#: The unit cube's corners in VTK node order: the hexahedron [0, 1, ..., 7] is right-handed.
CUBE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)


def mixed_mesh():
    """Hexes + tets + quads + wedges in five blocks, with point, cell and field data."""
    pts, hexes = grid(2)
    n = len(pts)
    extra = np.array([[0, 0, 3.0], [1, 0, 3], [0, 1, 3], [0, 0, 4], [1, 0, 4], [0, 1, 4]])
    points = np.vstack([pts, extra])
    cells = [
        ("hexahedron", hexes[:3]),
        ("tetra", np.array([[n, n + 1, n + 2, n + 3]])),
        ("quad", hexes[:2, :4]),
        ("hexahedron", hexes[3:]),
        ("wedge", np.array([[n, n + 1, n + 2, n + 3, n + 4, n + 5]])),
    ]
    cell_data = {
        "gmsh:physical": [np.full(len(c[1]), i + 1, dtype=np.int32) for i, c in enumerate(cells)],
        "gmsh:geometrical": [np.full(len(c[1]), i + 1, dtype=np.int32) for i, c in enumerate(cells)],
        "material": [np.arange(len(c[1]), dtype=float) + 10 * i + 0.25 for i, c in enumerate(cells)],
    }
    point_data = {"temperature": np.arange(len(points), dtype=float) / 7.0,
                  "velocity": np.arange(3 * len(points), dtype=float).reshape(-1, 3)}
    field_data = {"Inner": np.array([1, 3]), "Outer": np.array([2, 3])}
    return meshio.Mesh(points, cells, point_data=point_data, cell_data=cell_data, field_data=field_data)


def file_state(path):
    st = os.stat(path)
    return hashlib.sha256(open(path, "rb").read()).hexdigest(), st.st_mtime_ns, st.st_size


def meshio_fails(path):
    """True if plain meshio.read rejects the file (it may raise SystemExit)."""
    try:
        meshio.read(str(path))
    except (Exception, SystemExit):
        return True
    return False


def read_checked(path, **kw):
    """hio.read, asserting it leaves the file untouched and never raises SystemExit."""
    before = file_state(path)
    try:
        return hio.read(path, **kw)
    except SystemExit as exc:  # pragma: no cover - this is the failure being tested against
        pytest.fail(f"read raised SystemExit({exc})")
    finally:
        assert file_state(path) == before


def medit_text(*, same_line=False, quads_keyword="Quadrilaterals", tail=""):
    pts = "\n".join(f"{x:g} {y:g} {z:g} {i % 2}" for i, (x, y, z) in enumerate(CUBE))
    sep = " " if same_line else "\n"
    return (
        "MeshVersionFormatted 2\n# a comment line\nDimension 3\n\n"
        f"Vertices{sep}8\n{pts}\n\n"
        f"{quads_keyword}{sep}2\n1 2 3 4 7\n5 6 7 8 7\n\n"
        f"Tetrahedra{sep}1\n1 2 4 5 3\n\n"
        f"Hexahedra{sep}1\n1 2 3 4 5 6 7 8 42\n\n"
        f"End\n{tail}"
    )


def vtk_ascii(cell_type=12, order=None, tail="", version="3.0", n_cells_declared=None):
    order = list(range(8)) if order is None else order
    pts = "\n".join(f"{x:g} {y:g} {z:g}" for x, y, z in CUBE)
    return (
        f"# vtk DataFile Version {version}\nhand written\nASCII\nDATASET UNSTRUCTURED_GRID\n"
        f"POINTS 8 float\n{pts}\n"
        f"CELLS 2 14\n8 {' '.join(map(str, order))}\n4 0 1 3 4\n"
        f"CELL_TYPES 2\n{cell_type}\n10\n"
        "CELL_DATA 2\nSCALARS material int 1\nLOOKUP_TABLE default\n7 8\n"
        "POINT_DATA 8\nSCALARS temp double\nLOOKUP_TABLE default\n0 1 2 3 4 5 6 7\n"
        f"{tail}"
    )


def vtk_binary(cell_type=12, order=None, tail=b""):
    order = list(range(8)) if order is None else order
    be = lambda a, t: np.asarray(a, dtype=t).tobytes()  # noqa: E731 - big-endian packing
    return (
        b"# vtk DataFile Version 2.0\nhand written\nBINARY\nDATASET UNSTRUCTURED_GRID\n"
        b"POINTS 8 double\n" + be(CUBE, ">f8") + b"\n"
        b"CELLS 2 14\n" + be([8] + order + [4, 0, 1, 3, 4], ">i4") + b"\n"
        b"CELL_TYPES 2\n" + be([cell_type, 10], ">i4") + b"\n"
        b"CELL_DATA 2\nSCALARS material int 1\nLOOKUP_TABLE default\n" + be([7, 8], ">i4") + b"\n"
        + tail
    )


# ---------------------------------------------------------------------------------------------- tolerant readers
@pytest.mark.parametrize(
    "text",
    [
        pytest.param(medit_text(same_line=True), id="counts-on-keyword-line"),
        pytest.param(medit_text(quads_keyword="Quads"), id="Quads-keyword"),
        pytest.param(medit_text(tail="Generated by a tool, 2020\n1 2 3\n"), id="text-after-End"),
        pytest.param(medit_text(same_line=True, quads_keyword="Quads").replace("End\n", "") + "trailing words\n",
                     id="text-after-last-section"),
    ],
)
def test_medit_variants_meshio_rejects(tmp_path, text):
    path = tmp_path / "variant.mesh"
    path.write_text(text)
    assert meshio_fails(path)
    hm = read_checked(path)
    assert np.array_equal(hm.points, CUBE)
    assert hm.hexes.tolist() == [list(range(8))]
    s = hm.source
    assert [(b.type, len(b.data)) for b in s.cells] == [("quad", 2), ("tetra", 1), ("hexahedron", 1)]
    assert s.cells[0].data.tolist() == [[0, 1, 2, 3], [4, 5, 6, 7]]
    assert [a.tolist() for a in s.cell_data["medit:ref"]] == [[7, 7], [3], [42]]
    assert s.point_data["medit:ref"].tolist() == [0, 1] * 4
    assert hm.file_format == "medit"


def test_plain_medit_is_read_by_meshio_and_by_us_alike(tmp_path):
    path = tmp_path / "plain.mesh"
    path.write_text(medit_text())
    assert not meshio_fails(path)
    hm = read_checked(path)
    assert hm.hexes.tolist() == [list(range(8))]
    from hexsos_plugins.io.readers.medit import read_medit_text

    ours = read_medit_text(path.read_bytes(), path)
    theirs = meshio.read(str(path))
    assert np.array_equal(ours.points, theirs.points)
    assert all(a.type == b.type and np.array_equal(a.data, b.data) for a, b in zip(ours.cells, theirs.cells))


@pytest.mark.parametrize(
    "text, words",
    [
        (medit_text().replace("Vertices\n8", "Vertices\nabc"), ["vertex count after 'Vertices'", "'abc'", "line 6"]),
        (medit_text().replace("1 2 3 4 5 6 7 8 42", "1 2 3 x 5 6 7 8 42"), ["integer", "'x'", "Hexahedra"]),
        (medit_text().replace("Tetrahedra", "Bogus"), ["'Bogus'", "line"]),
        (medit_text().replace("Hexahedra\n1\n1 2 3 4 5 6 7 8 42\n\nEnd\n", "Hexahedra\n3\n1 2 3 4 5 6 7 8 42\n"),
         ["expected 27 numbers", "truncated"]),
        (medit_text().replace("Tetrahedra\n1\n", "Tetrahedra\n0\n"), ["the number '1'", "line 23", "count"]),
        (medit_text().replace("Hexahedra\n1\n1 2 3 4 5 6 7 8 42\n\nEnd\n", "Hexahedra\n1\n1 2 3 4 5 6 7 8 42\n"
                                                                        "1 2 3 4 5 6 7 8 43\n"),
         ["the number '1'", "count"]),
    ],
    ids=["bad-count", "bad-index", "unknown-keyword", "truncated", "count-too-small", "extra-entry"],
)
def test_medit_errors_say_what_and_where(tmp_path, text, words):
    path = tmp_path / "bad.mesh"
    path.write_text(text)
    with pytest.raises(MeshFormatError) as info:
        read_checked(path)
    msg = str(info.value)
    assert "bad.mesh" in msg and "Medit" in msg
    for w in words:
        assert w in msg


@pytest.mark.parametrize("binary", [False, True], ids=["ascii", "binary"])
def test_vtk_hexahedra_typed_as_tetra(tmp_path, binary):
    path = tmp_path / "typed10.vtk"
    if binary:
        path.write_bytes(vtk_binary(cell_type=10))
    else:
        path.write_text(vtk_ascii(cell_type=10))
    assert meshio_fails(path)
    hm = read_checked(path)
    assert np.array_equal(hm.points, CUBE)
    assert hm.hexes.tolist() == [list(range(8))]
    assert [(b.type, len(b.data)) for b in hm.source.cells] == [("hexahedron", 1), ("tetra", 1)]
    assert hm.source.cells[1].data.tolist() == [[0, 1, 3, 4]]
    assert [a.ravel().tolist() for a in hm.source.cell_data["material"]] == [[7], [8]]
    # negative case: the same file with a 6-node cell typed 12 is malformed, not silently accepted
    extra = tmp_path / "extra.vtk"
    extra.write_text(vtk_ascii(cell_type=10).replace("CELL_TYPES 2\n10\n10\n", "CELL_TYPES 1\n10\n10\n"))
    with pytest.raises(MeshFormatError, match="the number '10'"):
        read_checked(extra)
    bad = tmp_path / "bad12.vtk"
    bad.write_text(vtk_ascii(cell_type=12).replace("CELLS 2 14\n8 0 1 2 3 4 5 6 7", "CELLS 2 12\n6 0 1 2 3 4 5"))
    with pytest.raises(MeshFormatError, match="cell 0 has VTK cell type 12"):
        read_checked(bad)


@pytest.mark.parametrize("binary", [False, True], ids=["ascii", "binary"])
def test_vtk_voxels_come_out_right_handed(tmp_path, binary):
    order = np.arange(8)[VOXEL_TO_VTK].tolist()  # the cube's nodes in VTK_VOXEL order
    path = tmp_path / "voxel.vtk"
    if binary:
        path.write_bytes(vtk_binary(cell_type=11, order=order))
    else:
        path.write_text(vtk_ascii(cell_type=11, order=order))
    assert meshio_fails(path)
    hm = read_checked(path)
    assert hm.hexes.tolist() == [list(range(8))]
    assert hm.voxel_rows.tolist() == [True]
    assert hm.source.cells[0].type == "voxel"
    assert det_at(hm.points[hm.hexes], [0.5, 0.5, 0.5])[0][0] > 0
    assert hm.orientation() == "right-handed"
    # negative case: the voxel connectivity read as a hexahedron (type 12) is not positively oriented
    path12 = tmp_path / "voxel_as_hex.vtk"
    path12.write_text(vtk_ascii(cell_type=12, order=order))
    wrong = read_checked(path12)
    assert not det_at(wrong.points[wrong.hexes], [0.5, 0.5, 0.5])[0][0] > 0


def test_voxel_source_is_written_as_hexahedra(tmp_path):
    path = tmp_path / "voxel.vtk"
    path.write_text(vtk_ascii(cell_type=11, order=np.arange(8)[VOXEL_TO_VTK].tolist()))
    hm = read_checked(path)
    notes = hio.write(hm.source, tmp_path / "from_source.vtu")
    assert any("voxel" in n for n in notes)
    back = read_checked(tmp_path / "from_source.vtu")
    assert [b.type for b in back.source.cells] == ["hexahedron", "tetra"]
    assert back.hexes.tolist() == [list(range(8))] and back.orientation() == "right-handed"
    assert hm.source.cells[0].type == "voxel"  # the source itself is not converted
    assert hio.write(hm, tmp_path / "from_hexmesh.vtu") == []  # to_meshio already wrote hexahedra


def test_vtu_voxels_are_read_by_vtk_and_meshio_refuses_them(tmp_path, monkeypatch):
    monkeypatch.setattr("hexsos_plugins.io.readers.VTK_MIN_BYTES", 0)
    path = tmp_path / "voxel.vtu"
    with contextlib.redirect_stderr(io.StringIO()):
        meshio.write(str(path), meshio.Mesh(CUBE, [("hexahedron", [list(range(8))]), ("tetra", [[0, 1, 3, 4]])]),
                     binary=False)
    text = path.read_text()
    types = re.search(r'(Name="types"[^>]*>)\s*12\s', text)
    path.write_text(text[: types.end(1)] + "\n11\n" + text[types.end():])
    # VTK's reader keeps the voxel (the same nodes, now in voxel order: a twisted hexahedron as VTK order)
    hm = read_checked(path)
    assert hm.reader == "vtk" and [b.type for b in hm.source.cells] == ["voxel", "tetra"]
    assert hm.hexes.tolist() == [np.arange(8)[VOXEL_TO_VTK].tolist()] and hm.voxel_rows.tolist() == [True]
    # meshio alone would skip the voxel: that is an error, not a silent loss
    monkeypatch.setattr("hexsos_plugins.io.readers.vtk_api._AVAILABLE", False)
    with pytest.raises(MeshFormatError, match="type 11"):
        read_checked(path)
    # negative case: the unmodified file reads through meshio too
    path.write_text(text)
    assert read_checked(path).n_hexes == 1


@pytest.mark.parametrize("binary", [False, True], ids=["ascii", "binary"])
def test_vtk_text_after_the_data(tmp_path, binary):
    path = tmp_path / "tail.vtk"
    if binary:
        path.write_bytes(vtk_binary(tail=b"Converted by some tool\nmore text 1 2 3\n"))
    else:
        path.write_text(vtk_ascii(tail="Converted by some tool\nmore text 1 2 3\n"))
    assert meshio_fails(path)
    hm = read_checked(path)
    assert hm.hexes.tolist() == [list(range(8))] and np.array_equal(hm.points, CUBE)
    assert [a.ravel().tolist() for a in hm.source.cell_data["material"]] == [[7], [8]]
    if not binary:
        assert hm.source.point_data["temp"].ravel().tolist() == list(range(8))


def test_vtk_51_hexahedra_typed_as_tetra_are_not_silently_cut(tmp_path):
    pts = "\n".join(f"{x:g} {y:g} {z:g}" for x, y, z in CUBE)
    text = ("# vtk DataFile Version 5.1\nx\nASCII\nDATASET UNSTRUCTURED_GRID\n"
            f"POINTS 8 float\n{pts}\nCELLS 3 12\nOFFSETS vtktypeint64\n0 8 12\n"
            "CONNECTIVITY vtktypeint64\n0 1 2 3 4 5 6 7 0 1 3 4\nCELL_TYPES 2\n10\n10\n")
    path = tmp_path / "typed10_v51.vtk"
    path.write_text(text)
    with contextlib.redirect_stdout(io.StringIO()):
        theirs = meshio.read(str(path))
    assert [(b.type, b.data.tolist()) for b in theirs.cells] == [("tetra", [[4, 5, 6, 7], [0, 1, 3, 4]])]
    hm = read_checked(path)
    assert hm.hexes.tolist() == [list(range(8))]
    assert [(b.type, b.data.tolist()) for b in hm.source.cells] == [("hexahedron", [list(range(8))]),
                                                                    ("tetra", [[0, 1, 3, 4]])]
    # negative case: a genuine 5.1 tetra file stays as meshio read it
    tets = tmp_path / "tets_v51.vtk"
    tets.write_text(text.replace("CELLS 3 12\nOFFSETS vtktypeint64\n0 8 12", "CELLS 3 8\nOFFSETS vtktypeint64\n0 4 8")
                    .replace("0 1 2 3 4 5 6 7 0 1 3 4", "4 5 6 7 0 1 3 4"))
    hm = read_checked(tets)
    assert hm.n_hexes == 0 and hm.cells[0][0] == "tetra" and hm.cells[0][1].tolist() == [[4, 5, 6, 7], [0, 1, 3, 4]]


def test_vtk_51_written_by_meshio_is_read(tmp_path):
    pts, hexes = grid(2)
    path = tmp_path / "v51.vtk"
    meshio.write(str(path), meshio.Mesh(pts, [("hexahedron", hexes)]), binary=False)  # meshio's default: 5.1
    assert open(path).readline().strip().endswith("5.1")
    hm = read_checked(path)
    assert np.array_equal(hm.hexes, hexes)
    # our own reader handles the 5.1 layout (OFFSETS / CONNECTIVITY) too
    from hexsos_plugins.io.readers.legacy_vtk import read_legacy_vtk

    ours = read_legacy_vtk(path.read_bytes(), path)
    assert np.array_equal(ours.cells[0].data, hexes)


# ---------------------------------------------------------------------------------------------- round trips
def result_mesh():
    hm = HexMesh.from_meshio(mixed_mesh())
    M, N = hm.n_hexes, hm.n_points
    arrays = {
        "hexsos_min_det": np.linspace(0.5, 1.5, M),
        "hexsos_status": np.where(np.arange(M) % 3 == 0, 1, 0).astype(np.int64),
        "hexsos_argmin": np.arange(3 * M, dtype=float).reshape(M, 3) / 10.0,
    }
    disp = np.arange(3 * N, dtype=float).reshape(N, 3) / 100.0
    return hm, arrays, hm.to_meshio(cell_data=arrays, point_data={"hexsos_displacement": disp}), disp


@pytest.mark.parametrize("ext", [".vtu", ".vtk", ".msh", ".mesh"])
def test_round_trip_keeps_blocks_and_data(tmp_path, ext):
    hm, arrays, out, disp = result_mesh()
    src = hm.source
    path = tmp_path / f"result{ext}"
    notes = hio.write(out, path)
    assert isinstance(notes, list) and all(isinstance(n, str) for n in notes)
    back = read_checked(path)
    s = back.source
    assert [(b.type, len(b.data)) for b in s.cells] == [(b.type, len(b.data)) for b in src.cells]
    for b_out, b_back in zip(out.cells, s.cells):
        assert np.array_equal(b_out.data, b_back.data)
    assert np.array_equal(back.points, hm.points) and np.array_equal(back.hexes, hm.hexes)
    assert back.hex_blocks == hm.hex_blocks
    if ext == ".mesh":
        # documented: Medit keeps one integer reference per element (gmsh:physical here) and drops the rest
        assert [a.tolist() for a in s.cell_data["medit:ref"]] == [a.tolist() for a in src.cell_data["gmsh:physical"]]
        dropped = " ".join(notes)
        for name in ("hexsos_min_det", "hexsos_status", "hexsos_argmin", "material", "temperature", "Inner"):
            assert name in dropped
        return
    assert notes == []
    for name in ("temperature", "velocity"):
        assert np.array_equal(np.asarray(s.point_data[name]).reshape(src.point_data[name].shape),
                              src.point_data[name])
    assert np.array_equal(s.point_data["hexsos_displacement"], disp)
    for name in ("gmsh:physical", "gmsh:geometrical", "material"):
        for a, b in zip(s.cell_data[name], src.cell_data[name]):
            assert np.array_equal(np.ravel(a), b)
    assert {k: np.ravel(v).tolist() for k, v in s.field_data.items()} == {"Inner": [1, 3], "Outer": [2, 3]}
    for name, values in arrays.items():
        per_block = s.cell_data[name]
        on_hexes = np.concatenate([np.asarray(per_block[b]) for b, _, _ in back.hex_blocks])
        assert np.array_equal(on_hexes.reshape(values.shape), values)
        for b in (1, 2, 4):  # tetra, quad, wedge
            other = np.asarray(per_block[b])
            if values.dtype.kind == "f":
                assert np.isnan(other).all()
            else:
                assert (other == INT_FILL).all()


def test_msh_is_binary_41_and_meshio_alone_reads_its_cell_data(tmp_path):
    _, arrays, out, _ = result_mesh()
    path = tmp_path / "r.msh"
    hio.write(out, path)
    head = path.read_bytes()[:40]
    assert head.startswith(b"$MeshFormat\n4.1 1 8\n")
    with contextlib.redirect_stdout(io.StringIO()):
        m = meshio.read(str(path))  # meshio 5.3.5 alone: several blocks, $ElementData on each
    assert [len(b.data) for b in m.cells] == [len(b.data) for b in out.cells]
    for name in arrays:
        assert [len(a) for a in m.cell_data[name]] == [len(b.data) for b in out.cells]
    assert read_checked(path).n_hexes == 8


def test_vtk_is_legacy_42_ascii(tmp_path):
    _, _, out, _ = result_mesh()
    path = tmp_path / "r.vtk"
    hio.write(out, path)
    lines = path.read_text().splitlines()
    assert lines[0] == "# vtk DataFile Version 4.2" and lines[2] == "ASCII"


@pytest.mark.parametrize("ext", [".msh", ".vtk"])
def test_gmsh_opens_what_write_produces(tmp_path, ext):
    gmsh = pytest.importorskip("gmsh")
    hm, _, out, _ = result_mesh()
    path = tmp_path / f"for_gmsh{ext}"
    hio.write(out, path)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        tags, nodes = gmsh.model.mesh.getElementsByType(5)
        assert len(tags) == hm.n_hexes
        assert len(gmsh.model.mesh.getElementsByType(4)[0]) == 1  # the tetra
    finally:
        gmsh.finalize()


def test_gmsh_41_file_round_trip(tmp_path):
    """A file Gmsh itself writes (MSH 4.1, entities, physical groups) survives read -> write(.msh) -> Gmsh."""
    gmsh = pytest.importorskip("gmsh")
    src = tmp_path / "gmsh41.msh"
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("box")
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [1], 7, "Body")
        gmsh.model.addPhysicalGroup(2, [1, 2], 8, "Walls")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.5)
        gmsh.option.setNumber("Mesh.RecombineAll", 1)
        gmsh.option.setNumber("Mesh.Recombine3DAll", 1)
        gmsh.model.mesh.setTransfiniteAutomatic()
        gmsh.model.mesh.generate(3)
        n_hex = len(gmsh.model.mesh.getElementsByType(5)[0])
        gmsh.write(str(src))
    finally:
        gmsh.finalize()
    hm = read_checked(src)
    assert n_hex > 0 and hm.n_hexes == n_hex and hm.orientation() == "right-handed"
    assert {k: v.tolist() for k, v in hm.source.field_data.items()} == {"Body": [7, 3], "Walls": [8, 2]}
    out = tmp_path / "out.msh"
    notes = hio.write(hm.to_meshio(cell_data={"hexsos_min_det": np.ones(n_hex)}), out)
    assert notes == []  # the nodes' entities (gmsh:dim_tags) are kept too
    back = read_checked(out)
    assert np.array_equal(back.source.point_data["gmsh:dim_tags"], hm.source.point_data["gmsh:dim_tags"])
    assert np.array_equal(back.hexes, hm.hexes) and "hexsos_min_det" in back.source.cell_data
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(out))
        assert len(gmsh.model.mesh.getElementsByType(5)[0]) == n_hex
        assert sorted(gmsh.model.getPhysicalGroups()) == [(2, 8), (3, 7)]
    finally:
        gmsh.finalize()


def test_gmsh_cannot_open_binary_legacy_vtk(tmp_path):
    """Why .vtk is written ASCII: Gmsh 4.15 fails on binary legacy VTK (negative case for the test above)."""
    gmsh = pytest.importorskip("gmsh")
    pts, hexes = grid(1)
    path = tmp_path / "binary.vtk"
    meshio.write(str(path), meshio.Mesh(pts, [("hexahedron", hexes)]), file_format="vtk42", binary=True)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        with pytest.raises(Exception):
            gmsh.open(str(path))
    finally:
        gmsh.finalize()


def test_write_converts_what_formats_cannot_hold(tmp_path):
    pts, hexes = grid(1)
    m = meshio.Mesh(pts, [("hexahedron", hexes)], cell_data={"two": [np.ones((1, 2))], "flag": [np.array([True])],
                                                              "many": [np.arange(12.0).reshape(1, 12)],
                                                              "with space": [np.array([1.0])]})
    before = copy.deepcopy({k: [a.copy() for a in v] for k, v in m.cell_data.items()})
    notes = hio.write(m, tmp_path / "a.msh")
    text = " ".join(notes)
    assert "two" in text and "padded" in text and "many" in text and "flag" in text
    back = read_checked(tmp_path / "a.msh").source
    assert np.array_equal(back.cell_data["two"][0], [[1.0, 1.0, 0.0]])
    assert back.cell_data["many_11"][0].tolist() == [11.0]
    notes = hio.write(m, tmp_path / "a.vtk")
    assert any("with space" in n for n in notes)
    assert "with_space" in read_checked(tmp_path / "a.vtk").source.cell_data
    assert hio.write(m, tmp_path / "a.vtu") == ["boolean arrays written as int8: flag"]
    # the caller's mesh is untouched
    assert all(np.array_equal(m.cell_data[k][0], before[k][0]) for k in before)
    assert m.cell_data["two"][0].shape == (1, 2)


# ---------------------------------------------------------------------------------------------- atomic write
def test_failing_writer_leaves_nothing_behind(tmp_path, monkeypatch):
    _, _, out, _ = result_mesh()
    target = tmp_path / "out.vtu"

    def broken(filename, *args, **kwargs):
        with open(filename, "wb") as f:
            f.write(b"partial")
        raise RuntimeError("disk full")

    monkeypatch.setattr(meshio, "write", broken)
    with pytest.raises(MeshWriteError, match="disk full"):
        hio.write(out, target)
    assert os.listdir(tmp_path) == []
    # an existing target is left as it was
    target.write_bytes(b"old content")
    with pytest.raises(MeshWriteError):
        hio.write(out, target)
    assert os.listdir(tmp_path) == ["out.vtu"] and target.read_bytes() == b"old content"
    monkeypatch.undo()
    hio.write(out, target)  # negative case: the real writer replaces it
    assert os.listdir(tmp_path) == ["out.vtu"] and target.read_bytes() != b"old content"


def test_write_errors(tmp_path):
    _, _, out, _ = result_mesh()
    with pytest.raises(MeshWriteError, match=r"\.xyz.*\.vtu"):
        hio.write(out, tmp_path / "a.xyz")
    with pytest.raises(MeshWriteError, match="does not exist"):
        hio.write(out, tmp_path / "missing" / "a.vtu")
    with pytest.raises(MeshWriteError, match="directory"):
        hio.write(out, tmp_path)
    with pytest.raises(InvalidInputError):
        hio.write("not a mesh", tmp_path / "a.vtu")
    assert os.listdir(tmp_path) == []


def test_write_accepts_a_hexmesh_and_file_format(tmp_path):
    hm = HexMesh.from_arrays(*grid(2))
    assert hio.write(hm, tmp_path / "plain", file_format="vtu") == []
    assert read_checked(tmp_path / "plain", file_format="vtu").n_hexes == 8


# ---------------------------------------------------------------------------------------------- bad input
def _write(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return path


GARBAGE = bytes(range(256)) * 8


BAD_INPUTS = [
    ("empty.vtk", b"", MeshFormatError, ["empty"]),
    ("garbage.vtk", GARBAGE, MeshFormatError, ["legacy VTK", "vtk DataFile"]),
    ("garbage.mesh", GARBAGE, MeshFormatError, ["Medit"]),
    ("garbage.msh", GARBAGE, MeshFormatError, ["msh"]),
    ("garbage.vtu", GARBAGE, MeshFormatError, ["vtu"]),
    ("blank.mesh", b"\n\n   \n", MeshFormatError, ["Vertices"]),
    ("truncated.vtk", vtk_ascii()[: vtk_ascii().index("CELLS") + 20], MeshFormatError, ["truncated"]),
    ("truncated_bin.vtk", vtk_binary()[:150], MeshFormatError, ["truncated"]),
    ("shape.xyz", b"1 2 3", UnsupportedFormatError, [".vtk", ".msh", ".mesh"]),
    ("noext", b"1 2 3", UnsupportedFormatError, ["no extension"]),
    ("nan.vtk", vtk_ascii().replace("1 1 1", "nan 1 1"), InvalidInputError, ["point 6", "finite"]),
    ("range.vtk", vtk_ascii().replace("8 0 1 2 3 4 5 6 7", "8 0 1 2 3 4 5 6 99"), InvalidInputError,
     ["point 99", "8 points"]),
    ("wedge12.vtk", vtk_ascii().replace("CELLS 2 14\n8 0 1 2 3 4 5 6 7\n4 0 1 3 4",
                                         "CELLS 1 13\n12 0 1 2 3 4 5 6 7 0 1 2 3")
     .replace("CELL_TYPES 2\n12\n10", "CELL_TYPES 1\n31").replace("CELL_DATA 2\nSCALARS material int 1\n"
                                                                 "LOOKUP_TABLE default\n7 8\n", ""),
     NoHexahedraError, ["1 wedge12", "not checked"]),
    ("quads.vtk", vtk_ascii().replace("CELLS 2 14\n8 0 1 2 3 4 5 6 7\n4 0 1 3 4", "CELLS 2 10\n4 0 1 2 3\n4 4 5 6 7")
     .replace("CELL_TYPES 2\n12\n10", "CELL_TYPES 2\n9\n9"), NoHexahedraError, ["2 quad"]),
]


@pytest.mark.parametrize("name, content, error, words", BAD_INPUTS, ids=[c[0] for c in BAD_INPUTS])
def test_bad_input_raises_a_typed_error(tmp_path, name, content, error, words):
    path = _write(tmp_path, name, content)
    with pytest.raises(error) as info:
        read_checked(path)
    msg = str(info.value)
    assert name in msg
    for w in words:
        assert w in msg, msg


def test_bad_cases_differ_from_good_ones(tmp_path):
    """Negative control of the table above: the unmodified texts read fine, and so does a tetrahedra-only file."""
    tets = vtk_ascii().replace("CELLS 2 14\n8 0 1 2 3 4 5 6 7\n", "CELLS 2 10\n4 0 1 2 4\n").replace(
        "CELL_TYPES 2\n12", "CELL_TYPES 2\n10")
    m = read_checked(_write(tmp_path, "tets.vtk", tets))
    assert m.n_hexes == 0 and m.n_cells == 2 and m.counts_by_type() == {"tetra": 2}
    assert read_checked(_write(tmp_path, "good.vtk", vtk_ascii())).n_hexes == 1
    assert read_checked(_write(tmp_path, "good_bin.vtk", vtk_binary())).n_hexes == 1
    assert read_checked(_write(tmp_path, "good.mesh", medit_text())).n_hexes == 1


def test_missing_and_directory(tmp_path):
    with pytest.raises(MeshReadError, match="no such file") as info:
        hio.read(tmp_path / "nope.vtk")
    assert not isinstance(info.value, MeshFormatError)
    with pytest.raises(MeshReadError, match="directory"):
        hio.read(tmp_path)
    with pytest.raises(UnsupportedFormatError, match="file_format"):
        hio.read(_write(tmp_path, "x.vtk", vtk_ascii()), file_format="nonsense")


def test_read_does_not_print(tmp_path, capfd):
    path = _write(tmp_path, "typed10.vtk", vtk_ascii(cell_type=10))
    hio.read(path)
    with pytest.raises(MeshFormatError):
        hio.read(_write(tmp_path, "g.vtk", GARBAGE))
    captured = capfd.readouterr()
    assert captured.out == "" and captured.err == ""


def test_supported_extensions():
    exts = hio.supported_extensions()
    assert exts[:4] == [".vtu", ".vtk", ".msh", ".mesh"]
    assert ".xyz" not in exts
    assert ".msh" in hio.supported_extensions(write=True)
