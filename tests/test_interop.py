"""What a user's own tools do with what hexsos writes and takes: meshio 5.3.5 and Gmsh open every .msh that
``convert`` and ``repair`` write (physical groups and result arrays kept); the formats that cannot hold an array
say so; meshio's own mesh objects are taken as they come.
"""

from __future__ import annotations

import os

import meshio
import numpy as np
import pytest

import hexsos_plugins as hs
from hexsos_plugins import cli

gmsh = pytest.importorskip("gmsh")

RESULTS = ("hexsos_min_det", "hexsos_lower_bound", "hexsos_argmin", "hexsos_status", "hexsos_corner_min_det")


@pytest.fixture(scope="module")
def gmsh_box(tmp_path_factory):
    """A Gmsh-written MSH 4.1 box of 4^3 hexes with two physical groups (the volume, two walls of quads) and one
    interior node pushed through its neighbours (some hexes invalid, for repair to fix)."""
    path = tmp_path_factory.mktemp("gmsh") / "box.msh"
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("box")
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [1], 7, "Body")
        gmsh.model.addPhysicalGroup(2, [1, 2], 8, "Walls")
        for _, c in gmsh.model.getEntities(1):
            gmsh.model.mesh.setTransfiniteCurve(c, 5)
        for _, s in gmsh.model.getEntities(2):
            gmsh.model.mesh.setTransfiniteSurface(s)
            gmsh.model.mesh.setRecombine(2, s)
        gmsh.model.mesh.setTransfiniteVolume(1)
        gmsh.model.mesh.generate(3)
        tags, xyz, _ = gmsh.model.mesh.getNodes(3, 1)  # interior nodes only
        xyz = xyz.reshape(-1, 3)
        k = int(np.argmin(np.abs(xyz - 0.5).sum(axis=1)))
        gmsh.model.mesh.setNode(int(tags[k]), (xyz[k] + [0.3, 0.0, 0.0]).tolist(), [])
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return path


def _gmsh_open(path):
    """What Gmsh sees in ``path``: hexes, physical groups with names, and the data views with their names."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        groups = {(d, t): gmsh.model.getPhysicalName(d, t) for d, t in gmsh.model.getPhysicalGroups()}
        in_groups = {(d, t): sum(len(gmsh.model.mesh.getElements(d, e)[1][0]) if gmsh.model.mesh.getElements(d, e)[1]
                                 else 0 for e in gmsh.model.getEntitiesForPhysicalGroup(d, t)) for d, t in groups}
        views = sorted(gmsh.option.getString(f"View[{gmsh.view.getIndex(v)}].Name") for v in gmsh.view.getTags())
        return {"hexes": len(gmsh.model.mesh.getElementsByType(5)[0]), "groups": groups, "sizes": in_groups,
                "views": views}
    finally:
        gmsh.finalize()


def _meshio_sees(path, n_hex):
    m = meshio.read(str(path))  # meshio 5.3.5's own reader, no hexsos code in between
    types = [b.type for b in m.cells]
    assert "hexahedron" in types and "quad" in types
    hexes = [i for i, t in enumerate(types) if t == "hexahedron"]
    assert sum(len(m.cells[i].data) for i in hexes) == n_hex
    for name in RESULTS:
        assert [len(a) for a in m.cell_data[name]] == [len(b.data) for b in m.cells], name
    phys = {t: set(np.concatenate([m.cell_data["gmsh:physical"][i] for i, b in enumerate(m.cells) if b.type == t]))
            for t in set(types)}
    assert phys == {"hexahedron": {7}, "quad": {8}}
    assert {k: np.asarray(v).tolist() for k, v in m.field_data.items()} == {"Body": [7, 3], "Walls": [8, 2]}
    return m


def test_convert_writes_msh_that_meshio_and_gmsh_open_with_groups_and_results(gmsh_box, tmp_path, capsys):
    src = hs.read(str(gmsh_box))
    ref = hs.check(src.points, src.hexes)
    assert ref.counts()["invalid"] > 0
    out = tmp_path / "converted.msh"
    assert cli.main(["convert", str(gmsh_box), str(out)]) == 0
    m = _meshio_sees(out, len(src.hexes))
    on_hexes = np.concatenate([m.cell_data["hexsos_status"][i] for i, b in enumerate(m.cells)
                               if b.type == "hexahedron"])
    assert np.array_equal(on_hexes.astype(int), ref.status)
    seen = _gmsh_open(out)
    assert seen["hexes"] == len(src.hexes)
    assert seen["groups"] == {(3, 7): "Body", (2, 8): "Walls"}
    assert seen["sizes"] == {(3, 7): 64, (2, 8): 32}
    assert set(RESULTS) <= set(seen["views"])
    assert "warning" not in capsys.readouterr().err  # nothing dropped


def test_repair_writes_msh_that_meshio_and_gmsh_open_with_groups_and_results(gmsh_box, tmp_path, capsys):
    src = hs.read(str(gmsh_box))
    out = tmp_path / "repaired.msh"
    assert cli.main(["repair", str(gmsh_box), "-o", str(out), "--no-fidelity"]) == 0
    m = _meshio_sees(out, len(src.hexes))
    assert m.point_data["hexsos_displacement"].shape == (len(src.points), 3)
    fixed = hs.read(str(out))
    assert hs.check(fixed.points, fixed.hexes).counts()["valid"] == len(src.hexes)
    seen = _gmsh_open(out)
    assert seen["groups"] == {(3, 7): "Body", (2, 8): "Walls"} and seen["sizes"] == {(3, 7): 64, (2, 8): 32}
    assert set(RESULTS) | {"hexsos_displacement"} <= set(seen["views"])


def test_msh_keeps_cells_without_a_group_and_cells_split_within_a_block(tmp_path):
    """Elements of one block in two physical groups, and a block with no group beside one with a group: every
    tag comes back per element, in the cells' order, from meshio and from hexsos; the warning says where the
    ungrouped cells went."""
    from hexsos_plugins.examples import structured_grid

    P, H = structured_grid(2)
    quads = np.array([[0, 1, 4, 3], [1, 2, 5, 4]])
    phys = np.array([1, 1, 2, 2, 1, 1, 2, 2])
    mesh = meshio.Mesh(P, [("quad", quads), ("hexahedron", H)],
                       cell_data={"gmsh:physical": [np.zeros(2, int), phys], "x": [np.array([5.0, 6.0]),
                                                                                  np.arange(8.0)]})
    path = tmp_path / "split.msh"
    notes = hs.write(mesh, path)
    assert len(notes) == 1 and "physical group 0" in notes[0]
    for m in (meshio.read(str(path)), hs.read(str(path)).source):
        got_phys = np.concatenate([np.ravel(a) for a in m.cell_data["gmsh:physical"]])
        got_x = np.concatenate([np.ravel(a) for a in m.cell_data["x"]])
        assert got_phys.tolist() == [0, 0] + phys.tolist() and got_x.tolist() == [5, 6] + list(range(8))
        hexes = np.concatenate([b.data for b in m.cells if b.type == "hexahedron"])
        assert np.array_equal(hexes, H)


# ---------------------------------------------------------------------------------------------- item 3
@pytest.fixture(scope="module")
def result_vtu(tmp_path_factory, gmsh_box):
    path = tmp_path_factory.mktemp("vtu") / "m.vtu"
    assert cli.main(["convert", str(gmsh_box), str(path)]) == 0
    return path


def test_convert_to_exodus_keeps_the_result_arrays_as_element_variables(result_vtu, tmp_path, capsys):
    pytest.importorskip("netCDF4")
    capsys.readouterr()
    src = meshio.read(str(result_vtu))
    out = tmp_path / "o.exo"
    assert cli.main(["convert", str(result_vtu), str(out)]) == 0
    err = capsys.readouterr().err
    assert "hexsos_argmin -> hexsos_argminX .. hexsos_argminZ" in err
    back = meshio.read(str(out))
    assert [len(b.data) for b in back.cells] == [len(b.data) for b in src.cells]
    for name in RESULTS + ("hexsos_scaled_jacobian", "gmsh:physical"):
        want = src.cell_data[name]
        got = [np.column_stack([back.cell_data[name + c][b] for c in "XYZ"]) for b in range(len(want))] \
            if name == "hexsos_argmin" else back.cell_data[name]
        for a, b in zip(want, got):
            assert np.array_equal(np.asarray(a, dtype=float).reshape(np.shape(b)), b, equal_nan=True), name
    vtk = pytest.importorskip("vtk")
    reader = vtk.vtkExodusIIReader()
    reader.SetFileName(str(out))
    reader.UpdateInformation()
    names = {reader.GetElementResultArrayName(i) for i in range(reader.GetNumberOfElementResultArrays())}
    assert set(RESULTS) <= names  # VTK joins hexsos_argminX/Y/Z back into hexsos_argmin


@pytest.mark.parametrize("ext", [".inp", ".bdf"])
def test_formats_without_arrays_name_what_they_drop(result_vtu, tmp_path, capsys, ext):
    capsys.readouterr()
    out = tmp_path / f"o{ext}"
    assert cli.main(["convert", str(result_vtu), str(out)]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "does not hold cell data" in line]
    assert len(lines) == 1 and all(name in lines[0] for name in RESULTS), err
    notes = hs.write(meshio.read(str(result_vtu)), tmp_path / f"again{ext}")
    assert any("hexsos_min_det" in n for n in notes)
    # a mesh with nothing to drop gives no warning (the warning is about the data, not the format)
    bare = meshio.Mesh(np.eye(4)[:, :3] * 1.0, [("tetra", np.array([[0, 1, 2, 3]]))])
    assert hs.write(bare, tmp_path / f"bare{ext}") == []


# ---------------------------------------------------------------------------------------------- item 4
def test_the_formats_extra_is_in_all_and_brings_what_meshio_needs():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    from hexsos_plugins.io.meshio_conventions import FORMAT_PACKAGES

    with open(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "pyproject.toml"), "rb") as f:
        extras = tomllib.load(f)["project"]["optional-dependencies"]
    assert "formats" in extras["all"][0].split("[")[1]
    assert {r.split(">")[0] for r in extras["formats"]} == set(FORMAT_PACKAGES) == {"netCDF4", "h5py"}


@pytest.mark.parametrize("ext, package", [(".exo", "netCDF4"), (".xdmf", "h5py"), (".med", "h5py")])
def test_exodus_xdmf_and_med_read_and_a_missing_package_is_named(result_vtu, tmp_path, ext, package, monkeypatch,
                                                                capsys):
    pytest.importorskip(package)
    src = hs.read(str(result_vtu))
    path = tmp_path / f"m{ext}"
    hs.write(src.source, path)
    back = hs.read(str(path))
    assert np.array_equal(back.points, src.points) and len(back.hexes) == len(src.hexes)
    assert cli.main(["check", str(path)]) == 1  # some hexes invalid: read and checked
    capsys.readouterr()

    import builtins
    real_import = builtins.__import__

    def without(name, *args, **kwargs):  # the package is not installed
        if name.split(".")[0] == package:
            raise ModuleNotFoundError(f"No module named '{package}'", name=package)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", without)
    from hexsos_plugins.errors import DependencyError

    with pytest.raises(DependencyError, match=f"pip install {package}.*hexsos\\[formats\\]"):
        hs.read(str(path))
    with pytest.raises(DependencyError, match=f"needs the Python package {package}"):
        hs.write(src.source, tmp_path / f"again{ext}")
    assert not (tmp_path / f"again{ext}").exists()
    assert cli.main(["check", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"pip install {package}" in err[0], err


# ---------------------------------------------------------------------------------------------- item 5
def test_check_takes_meshio_cells_and_meshes(gmsh_box):
    m = meshio.read(str(gmsh_box))  # quad blocks (the walls) and a hexahedron block, in meshio's CellBlocks
    assert {b.type for b in m.cells} == {"quad", "hexahedron"}
    H = np.concatenate([b.data for b in m.cells if b.type == "hexahedron"])
    ref = hs.check(m.points, H)
    assert ref.counts()["invalid"] > 0
    for got in (hs.check(m.points, m.cells), hs.check(m), hs.check(m.points, m), hs.check(hs.read(str(gmsh_box)))):
        assert np.array_equal(got.status, ref.status) and np.array_equal(got.min_det, ref.min_det)
    assert hs.check(m).extra["not_checked"] == {"quad": 32}
    assert "not_checked" not in ref.extra
    # two hexahedron blocks, as meshio gives a file with two volumes
    two = [meshio.CellBlock("hexahedron", H[:20]), meshio.CellBlock("hexahedron", H[20:])]
    assert np.array_equal(hs.check(m.points, two).status, ref.status)
    sj = hs.scaled_jacobian(m.points, m.cells)
    assert np.array_equal(sj, hs.scaled_jacobian(m.points, H))
    # only 2-D cells: a typed error that says what was found
    with pytest.raises(hs.NoHexahedraError, match="32 quad"):
        hs.check(m.points, [b for b in m.cells if b.type == "quad"])
    with pytest.raises(hs.InvalidInputError, match="found None"):
        hs.check(m.points)


# ---------------------------------------------------------------------------------------------- item 6
def _medit_text_vertices(text):
    """The 'Vertices' coordinates of a Medit file as Python parses each number of the text (float64)."""
    words = text.split()
    i = next(k for k, w in enumerate(words) if w.lower() == "vertices")
    n = int(words[i + 1])
    return np.array([[float(x) for x in words[i + 2 + 4 * r: i + 5 + 4 * r]] for r in range(n)])


MEDIT_V1 = """MeshVersionFormatted 1
Dimension 3
Vertices
8
0 0 0 1
1.0000000000000002 0 0 1
1 0.309011 0 1
0 1 0.1234567890123456789 1
0 0 1 1
1 0 1 1
1 1 1.0000001 1
3.141592653589793 1 1 1
Hexahedra
1
1 2 3 4 5 6 7 8 1
End
"""


def test_medit_files_are_read_at_float64_whatever_the_version_line(tmp_path):
    from hexsos_plugins.io import readers_for

    path = tmp_path / "v1.mesh"
    path.write_text(MEDIT_V1)
    want = _medit_text_vertices(MEDIT_V1)
    assert meshio.read(str(path)).points.dtype == np.float32  # what meshio alone does with version 1
    got = hs.read(str(path))
    assert got.points.dtype == np.float64 and np.array_equal(got.points, want)  # digit for digit
    # every reader hexsos may use for the file gives the text's numbers, meshio's included
    for who, reader in readers_for(path, "medit"):
        assert np.array_equal(np.asarray(reader(path).points), want), who
    # convert writes the file's numbers, not their single-precision neighbours
    out = tmp_path / "o.vtu"
    assert cli.main(["convert", str(path), str(out)]) == 0
    assert np.array_equal(meshio.read(str(out)).points, want)


@pytest.mark.parametrize("name", ["cat_2.mesh", "Dolphin_2.mesh"])
def test_published_medit_files_are_read_digit_for_digit(name):
    from conftest import published

    path = published(os.path.join("hexalab", name))
    with open(path) as fh:
        text = fh.read()
    assert np.array_equal(hs.read(path).points, _medit_text_vertices(text))
