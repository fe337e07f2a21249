"""The readers: every reader path gives the same mesh, in VTK node order, with nothing of the file lost; round
trips of Gmsh-made mixed and quadratic meshes through .msh (2.2, 4.1), .vtu and .vtk; the numpy MSH reader's
refusals; mirrored files reported, not fixed.

Every mesh is generated here by Gmsh or numpy; nothing is copied from elsewhere. Each check has a case that must
fail.
"""

from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path

import meshio
import numpy as np
import pytest

import hexsos_plugins.io as hio
from hexsos_plugins.cells.elements import ELEMENTS
from hexsos_plugins.errors import HexsosError, MeshFormatError
from hexsos_plugins.io.mesh import MIRROR, Mesh
from hexsos_plugins.io.readers import readers_for
from comparison.curved_mixed import build_mixed
from hexsos_plugins.io.readers.msh_binary import read_msh_binary

gmsh = pytest.importorskip("gmsh")
vtk = pytest.importorskip("vtk")




#: (order, incomplete) -> the 3-D cell types Gmsh makes for it, as meshio names them
KINDS = {
    "order1": (1, False, {"hexahedron", "wedge", "pyramid", "tetra"}),
    "order2": (2, False, {"hexahedron27", "wedge18", "pyramid14", "tetra10"}),
    "order2i": (2, True, {"hexahedron20", "wedge15", "pyramid13", "tetra10"}),
}


def write_gmsh_meshes(directory, kinds=KINDS):
    """Write each kind as Gmsh writes it: ``{kind}_41.msh`` (MSH 4.1 ASCII), ``{kind}_41b.msh`` (binary),
    ``{kind}_22b.msh`` (MSH 2.2 binary), ``{kind}_22.msh`` (2.2 ASCII), ``{kind}.vtk`` (Gmsh's legacy VTK).
    Returns ``{kind: {suffix: path}}``."""
    import gmsh

    out = {}
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        for kind in kinds:
            order, incomplete, _ = KINDS[kind]
            # the high-order nodes moved off their straight positions, so that a wrong node order changes the
            # geometry
            build_mixed(gmsh, order, incomplete=incomplete, bottom=True, curve=0.03)
            paths = {}
            for suffix, version, binary in (("41", 4.1, 0), ("41b", 4.1, 1), ("22b", 2.2, 1), ("22", 2.2, 0)):
                gmsh.option.setNumber("Mesh.MshFileVersion", version)
                gmsh.option.setNumber("Mesh.Binary", binary)
                paths[suffix] = os.path.join(directory, f"{kind}_{suffix}.msh")
                gmsh.write(paths[suffix])
            gmsh.option.setNumber("Mesh.Binary", 0)
            paths["vtk"] = os.path.join(directory, f"{kind}.vtk")
            gmsh.write(paths["vtk"])
            gmsh.model.remove()
            out[kind] = paths
    finally:
        gmsh.finalize()
    return out


# ---------------------------------------------------------------------------------------------- helpers
def sample_points(el, n=6, seed=0):
    """Deterministic points inside a reference element (and its first corner)."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(0.05, 0.95, (n, 3))
    if el.domain == "tet":
        p = p / (p.sum(axis=1, keepdims=True) + rng.uniform(0.1, 1.0, (n, 1)))
    elif el.domain == "prism":
        flip = p[:, 0] + p[:, 1] > 1
        p[flip, :2] = 1 - p[flip, :2]
    elif el.domain == "pyramid":
        p[:, 2] *= 0.8
    return np.vstack([p, el.reference_nodes[:1]])


def dets_by_type(mesh: Mesh) -> dict:
    """{cell type: det J (cells, points) at sample_points, rows sorted}: comparable across block layouts."""
    out = {}
    for t, conn in mesh.cells:
        el = ELEMENTS[t]
        out.setdefault(t, []).append(el.det(mesh.points[conn], sample_points(el)))
    return {t: np.sort(np.concatenate(v), axis=0) for t, v in out.items()}


def quiet_read(fn, path):
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return fn(path)


def assert_same_mesh(a: meshio.Mesh, b: meshio.Mesh, what=""):
    """Same points, cell blocks (type, connectivity), cell/point/field data (values; NaN equal to NaN)."""
    assert np.array_equal(np.asarray(a.points, float), np.asarray(b.points, float)), what
    assert [(c.type, len(c.data)) for c in a.cells] == [(c.type, len(c.data)) for c in b.cells], what
    for ca, cb in zip(a.cells, b.cells):
        assert np.array_equal(ca.data, cb.data), f"{what}: {ca.type}"
    assert set(a.cell_data) == set(b.cell_data), what
    for k in a.cell_data:
        for x, y in zip(a.cell_data[k], b.cell_data[k]):
            assert np.array_equal(np.asarray(x, float).ravel(), np.asarray(y, float).ravel(), equal_nan=True), \
                f"{what}: cell data {k}"
    assert set(a.point_data) == set(b.point_data), what
    for k in a.point_data:
        x, y = np.asarray(a.point_data[k], float), np.asarray(b.point_data[k], float)
        assert np.array_equal(x.reshape(len(x), -1), y.reshape(len(y), -1), equal_nan=True), f"{what}: {k}"
    assert {k: np.ravel(v).tolist() for k, v in a.field_data.items()} == \
        {k: np.ravel(v).tolist() for k, v in b.field_data.items()}, what


@pytest.fixture(scope="module")
def gm(tmp_path_factory):
    return write_gmsh_meshes(str(tmp_path_factory.mktemp("gmsh")))


# ------------------------------------------------------------------------------------------- reader agreement
#: which readers must read each of Gmsh's MSH variants (meshio 5.3.5 fails on wedge15: KeyError)
EXPECTED = {"41b": {"numpy", "meshio", "gmsh"}, "22b": {"numpy", "meshio", "gmsh"}, "41": {"meshio", "gmsh"},
            "22": {"meshio", "gmsh"}}


def test_meshio_alone_cannot_read_msh41_with_wedge15(gm):
    """Why hexsos registers meshio's missing cell dimensions around its calls: plain meshio 5.3.5 raises
    KeyError('wedge15') on Gmsh's own order-2-incomplete MSH 4.1 file."""
    with pytest.raises(KeyError, match="wedge15"):
        quiet_read(meshio.read, gm["order2i"]["41"])
    assert hio.read(gm["order2i"]["41"]).reader == "meshio"  # with the dimensions registered, meshio reads it


@pytest.mark.parametrize("suffix", ["41b", "22b", "41", "22"])
@pytest.mark.parametrize("kind", list(KINDS))
def test_every_msh_reader_gives_the_same_mesh(gm, kind, suffix):
    path = Path(gm[kind][suffix])
    got, failed = {}, {}
    for who, fn in readers_for(path, "gmsh"):
        try:
            got[who] = quiet_read(fn, path)
        except Exception as exc:  # noqa: BLE001 - recorded and asserted below
            failed[who] = str(exc)
    assert EXPECTED[suffix] <= set(got), failed
    first = next(iter(got))
    for who in got:
        assert_same_mesh(got[first], got[who], f"{first} vs {who}")
    m = hio.read(path)
    assert m.reader == ("numpy" if suffix.endswith("b") else "meshio")
    assert set(m.counts_by_type()) | set(m.skipped) == KINDS[kind][2]
    assert {k: v.tolist() for k, v in m.source.field_data.items()} == {"Layers": [11, 3], "Cap": [12, 3],
                                                                        "Bottom": [21, 2]}


@pytest.mark.parametrize("kind", list(KINDS))
def test_msh_versions_and_gmsh_vtk_hold_the_same_cells(gm, kind):
    """MSH 4.1, 2.2 (ASCII and binary) and Gmsh's own .vtk of one model: the same det J at the same points for
    every cell type, except that Gmsh's VTK writer mirrors linear wedges (the next test)."""
    ref = dets_by_type(hio.read(gm[kind]["41b"]))
    for suffix in ("41", "22", "22b"):
        other = dets_by_type(hio.read(gm[kind][suffix]))
        assert other.keys() == ref.keys()
        for t in ref:  # ASCII files hold 16 significant digits
            assert np.allclose(other[t], ref[t], rtol=1e-12, atol=1e-14), (suffix, t)
    vtk_mesh = hio.read(gm[kind]["vtk"])
    got = dets_by_type(vtk_mesh)
    for t in ref:
        if t == "wedge":
            assert np.allclose(np.sort(-got[t], axis=0), ref[t], rtol=1e-12, atol=1e-12)
        elif t in got:
            assert np.allclose(got[t], ref[t], rtol=1e-12, atol=1e-12), t
    # Gmsh's cells are valid at these points, but for its quadratic pyramids, of which it folds a third here (3 of 9
    # in both orders; Gmsh's own det J agrees: test_node_orders)
    assert all(v > 0 for t, d in ref.items() for v in [d.min()] if t not in ("pyramid13", "pyramid14"))


def test_gmsh_vtk_files_with_linear_prisms_are_reported_mirrored(gm, monkeypatch):
    """Gmsh writes linear prisms to .vtk with nodes 1<->2 and 4<->5 swapped (as meshio does): VTK's own shape
    functions, vtkMeshQuality and vtkCellValidator call those cells inverted. hexsos reads the file's order and
    reports the wedges as left-handed (per type), on every reader path; it does not fix them unasked."""
    path = Path(gm["order1"]["vtk"])
    monkeypatch.setattr("hexsos_plugins.io.readers.VTK_MIN_BYTES", 0)
    m = hio.read(path)
    assert m.reader == "vtk"
    assert m.orientations() == {"tetra": "right-handed", "pyramid": "right-handed", "wedge": "left-handed",
                                "hexahedron": "right-handed"}
    assert m.orientation() == "mixed" and m.left_handed_types() == ["wedge"]
    readers = dict(readers_for(path, "vtk"))
    via = {who: quiet_read(fn, path) for who, fn in readers.items()}
    for who in via:
        assert_same_mesh(via["vtk"], via[who], who)
    # meshio alone mirrors them while reading: the opposite of the file, which is why hexsos undoes it
    theirs = quiet_read(meshio.read, path)
    wedge = [b.data for b in theirs.cells if b.type == "wedge"][0]
    ours = [c for t, c in m.cells if t == "wedge"][0]
    assert np.array_equal(wedge, ours[:, [0, 2, 1, 3, 5, 4]])
    # on request: flipping the left-handed type makes every cell right-handed
    fixed = m.flipped(m.left_handed_types())
    assert set(fixed.orientations().values()) == {"right-handed"}
    assert m.left_handed_types() == ["wedge"]  # the original is untouched
    # negative case: flipping everything mirrors the right-handed types instead
    assert set(m.flipped().orientations().values()) == {"left-handed", "right-handed"}


@pytest.mark.parametrize("kind", list(KINDS))
def test_round_trip_through_every_format_keeps_cells_orders_and_arrays(gm, kind, tmp_path):
    src = hio.read(gm[kind]["41b"])
    n, h = src.n_cells, src.n_hexes
    arrays = {"r": np.arange(n, dtype=float) / 7.0, "s": (np.arange(n) % 5).astype(np.int64),
              "v": np.arange(3 * n, dtype=float).reshape(n, 3)}
    if h:
        arrays["hexonly"] = np.linspace(1, 2, h)  # an array over the hexahedra only, as today's callers pass
    out = src.to_meshio(cell_data=arrays, point_data={"p": np.arange(src.n_points, dtype=float)})
    ref = dets_by_type(src)
    for ext in (".msh", ".vtu", ".vtk"):
        path = tmp_path / f"{kind}{ext}"
        notes = hio.write(out, path)
        back = hio.read(path)
        got = dets_by_type(back)
        # VTK has no 14-node pyramid: VTK files get 13-node ones (the base centre dropped, a note says so)
        as13 = ext != ".msh" and "pyramid14" in ref
        want_counts = {("pyramid13" if t == "pyramid14" and as13 else t): c for t, c in src.counts_by_type().items()}
        assert back.counts_by_type() == want_counts, ext
        for t in ref:
            if t == "pyramid14" and as13:
                assert got["pyramid13"].shape == ref[t].shape and any("pyramid14" in s for s in notes)
                continue
            assert np.array_equal(got[t], ref[t]), (ext, t)
        assert back.skipped == src.skipped == {}, ext
        cd = back.source.cell_data
        for name, values in arrays.items():
            rows = back.hex_blocks if name == "hexonly" else [(b, s, e) for b, _, s, e in back.cell_blocks]
            got_v = np.concatenate([np.asarray(cd[name][b]).reshape(e - s, -1) for b, s, e in rows])
            assert np.array_equal(got_v, values.reshape(len(values), -1)), (ext, name)
            checked = {b for b, _, _ in rows}
            for b, block in enumerate(back.source.cells):
                if b not in checked:
                    other = np.asarray(cd[name][b])
                    assert (np.isnan(other).all() if values.dtype.kind == "f" else (other == -2).all()), (ext, name)
        assert np.array_equal(np.ravel(back.source.point_data["p"]), np.arange(src.n_points, dtype=float))
        for tag in ("gmsh:physical", "gmsh:geometrical"):
            if ext == ".msh":
                a = np.concatenate([np.ravel(x) for x in cd[tag]])
                b_ = np.concatenate([np.ravel(x) for x in src.source.cell_data[tag]])
                assert np.array_equal(np.sort(a), np.sort(b_)), tag
        assert {k: np.ravel(v).tolist() for k, v in back.source.field_data.items()} == \
            {"Layers": [11, 3], "Cap": [12, 3], "Bottom": [21, 2]}, ext


VTK_CELLS = {"tetra": "vtkTetra", "tetra10": "vtkQuadraticTetra", "pyramid": "vtkPyramid", "wedge": "vtkWedge",
             "wedge15": "vtkQuadraticWedge", "wedge18": "vtkBiQuadraticQuadraticWedge",
             "hexahedron": "vtkHexahedron", "hexahedron20": "vtkQuadraticHexahedron",
             "hexahedron27": "vtkTriQuadraticHexahedron", "pyramid13": "vtkQuadraticPyramid"}


def vtk_det(cell, X, pc):
    """det J of a VTK cell with nodes X at pcoords pc from VTK's InterpolateDerivs."""
    n = len(X)
    out = []
    for p in pc:
        d = [0.0] * (3 * n)
        cell.InterpolateDerivs(list(map(float, p)), d)
        out.append(np.linalg.det(X.T @ np.array(d).reshape(3, n).T))
    return np.array(out)


@pytest.mark.parametrize("ext", [".vtu", ".vtk"])
@pytest.mark.parametrize("kind", list(KINDS))
def test_what_hexsos_writes_vtk_reads_with_the_same_det(gm, kind, ext, tmp_path):
    """Files written by hexsos, read by VTK itself: VTK's InterpolateDerivs gives our det J on every cell (the
    pyramid: VTK's det J is ours times (1 - t)^2), and vtkMeshQuality's volume is positive."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    src = hio.read(gm[kind]["41b"])
    path = tmp_path / f"w{ext}"
    hio.write(src, path)
    reader = vtk.vtkXMLUnstructuredGridReader() if ext == ".vtu" else vtk.vtkUnstructuredGridReader()
    reader.SetFileName(str(path))
    reader.Update()
    grid = reader.GetOutput()
    P = vtk_to_numpy(grid.GetPoints().GetData()).astype(float)
    checked = 0
    by_type = {}
    for t, conn in src.cells:
        by_type.setdefault(t, []).append(conn)
    for t, conns in by_type.items():
        if t in ("pyramid13", "pyramid14"):  # VTK interpolates them otherwise inside (test_node_orders measures it)
            continue
        el = ELEMENTS[t]
        ids = [i for i in range(grid.GetNumberOfCells()) if grid.GetCellType(i) == el.vtk_type]
        conn = np.concatenate(conns)
        assert len(ids) == len(conn), t
        pc = sample_points(el)
        for i in ids[:: max(1, len(ids) // 4)]:
            cell = grid.GetCell(i)
            vc = np.array([cell.GetPointId(j) for j in range(cell.GetNumberOfPoints())])
            X = P[vc]
            ours = el.det(X, pc)[0]
            theirs = vtk_det(getattr(vtk, VTK_CELLS[t])(), X, pc)
            if t == "pyramid":
                theirs = theirs / (1 - pc[:, 2]) ** 2
            assert np.allclose(ours, theirs, rtol=1e-10, atol=1e-12), t
            assert ours.min() > 0, t
            checked += 1
    assert checked > 0
    q = vtk.vtkMeshQuality()
    q.SetInputData(grid)
    for s in ("Tet", "Wedge", "Hex", "Pyramid"):
        getattr(q, f"Set{s}QualityMeasureToVolume")()
    q.Update()
    vol = vtk_to_numpy(q.GetOutput().GetCellData().GetArray("Quality"))
    types = vtk_to_numpy(grid.GetCellTypes())
    linear = np.isin(types, [10, 12, 13, 14])
    if linear.any():
        assert (vol[linear] > 0).all()


def test_written_msh_wedge18_is_in_gmsh_order(gm, tmp_path):
    """meshio's MSH writer has no wedge18 permutation: hexsos permutes before writing, so Gmsh sees the same
    geometry (its element nodes, taken through gmsh_to_vtk, are our cells)."""
    src = hio.read(gm["order2"]["41b"])
    path = tmp_path / "w18.msh"
    hio.write(src, path)
    el = ELEMENTS["wedge18"]
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        _, nodes = gmsh.model.mesh.getElementsByType(el.gmsh_type)
        theirs = (np.asarray(nodes, dtype=np.int64).reshape(-1, 18) - 1)[:, list(el.gmsh_to_vtk)]
    finally:
        gmsh.finalize()
    ours = np.concatenate([c for t, c in src.cells if t == "wedge18"])
    assert np.array_equal(theirs, ours)
    # negative case: the file as meshio alone would write it (no permutation) is not what Gmsh should see
    assert not np.array_equal(ours[:, np.argsort(el.gmsh_to_vtk)], ours)


# ------------------------------------------------------------------------------------------- mirrored files
def test_a_mirrored_file_is_reported_not_fixed(tmp_path):
    """A .vtu whose tetrahedra and wedges are all mirrored: read as they are, reported per type, fixed only by
    flipped(); the file itself is never touched."""
    P = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 0]], float)
    tet = np.array([[0, 1, 2, 3]])
    wedge = np.array([[0, 1, 2, 3, 4, 5]])
    good = Mesh.from_cells(P, [("tetra", tet), ("wedge", wedge)])
    assert good.orientation() == "right-handed"
    bad = good.flipped()
    path = tmp_path / "mirrored.vtu"
    hio.write(bad, path)
    before = path.read_bytes()
    m = hio.read(path)
    assert m.orientations() == {"tetra": "left-handed", "wedge": "left-handed"} and m.orientation() == "left-handed"
    assert np.array_equal(m.cells[0][1], tet[:, MIRROR["tetra"]])
    assert np.array_equal(m.cells[1][1], wedge[:, MIRROR["wedge"]])
    assert m.flipped().orientation() == "right-handed"
    assert path.read_bytes() == before
    # negative case: the right-handed mesh written and read back stays right-handed
    hio.write(good, tmp_path / "good.vtu")
    assert hio.read(tmp_path / "good.vtu").orientation() == "right-handed"


# ------------------------------------------------------------------------------------------- numpy MSH reader
def test_numpy_msh_reader_refuses_truncated_files_and_declines_others(gm, tmp_path):
    raw = Path(gm["order1"]["41b"]).read_bytes()
    cut = tmp_path / "cut.msh"
    cut.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(Exception) as info:
        read_msh_binary(cut)
    assert "truncated" in str(info.value) or "expected" in str(info.value)
    with pytest.raises(MeshFormatError):
        hio.read(cut)
    with pytest.raises(Exception, match="declines"):
        read_msh_binary(Path(gm["order1"]["41"]))  # ASCII: meshio's and Gmsh's
    # negative case: the whole file reads, and agrees with Gmsh's reader
    from hexsos_plugins.io.readers.gmsh_api import read_gmsh_api

    assert_same_mesh(read_msh_binary(Path(gm["order1"]["41b"])), read_gmsh_api(Path(gm["order1"]["41b"])))


@pytest.mark.parametrize("suffix", ["41b", "22b"])
def test_numpy_msh_reader_keeps_nothing_of_the_mapped_file(gm, tmp_path, monkeypatch, suffix):
    """The reader maps the file instead of copying it, and closes the mapping before it returns: a mesh read
    does not change when its file is overwritten afterwards, nor when it is deleted. A reader that kept a view
    of the mapping is read again from a copy (the fallback is exercised by a parse that leaks one)."""
    import shutil

    from hexsos_plugins.io.readers import msh_binary

    path = tmp_path / f"m_{suffix}.msh"
    shutil.copy(gm["order2"][suffix], path)
    m = read_msh_binary(path)
    keep = {"points": m.points.copy(), **{f"cells{i}": b.data.copy() for i, b in enumerate(m.cells)},
            **{f"{k}{i}": np.array(v, copy=True) for k, vs in m.cell_data.items() for i, v in enumerate(vs)}}
    raw = path.read_bytes()
    path.write_bytes(raw.replace(b"\x00", b"\x07"))  # the same length, other numbers everywhere
    now = {"points": m.points, **{f"cells{i}": b.data for i, b in enumerate(m.cells)},
           **{f"{k}{i}": np.asarray(v) for k, vs in m.cell_data.items() for i, v in enumerate(vs)}}
    assert keep.keys() == now.keys() and all(np.array_equal(keep[k], now[k]) for k in keep)
    path.unlink()
    assert np.array_equal(m.points, keep["points"])
    # negative case: a parse that returns a view of the mapping is caught, and the mesh is read from a copy
    path.write_bytes(raw)
    real = msh_binary.parse
    leaked = []

    def leaky(buf):
        mesh = real(buf)
        if not isinstance(buf, bytes):
            mesh.points = np.frombuffer(buf, dtype=np.uint8, count=8)  # a view of the mapping
            leaked.append(True)
        return mesh

    monkeypatch.setattr(msh_binary, "parse", leaky)
    again = read_msh_binary(path)
    assert leaked and np.array_equal(again.points, keep["points"])


def test_gmsh_reader_is_not_tried_on_a_binary_file_the_numpy_reader_found_broken(gm, tmp_path, monkeypatch):
    import hexsos_plugins.io.readers as readers

    calls = []
    real = readers.read_gmsh_api
    monkeypatch.setattr(readers, "read_gmsh_api", lambda q: calls.append(q) or real(q))
    raw = Path(gm["order1"]["41b"]).read_bytes()
    cut = tmp_path / "cut.msh"
    cut.write_bytes(raw[: len(raw) // 2])  # counts beyond the end of the file: broken, Gmsh's reader not asked
    with pytest.raises(MeshFormatError, match="truncated"):
        hio.read(cut)
    assert calls == []
    # negative cases: a file the numpy reader only declines (ASCII) still reaches Gmsh's reader when meshio fails,
    # and so does a binary file that is whole
    raw = Path(gm["order1"]["41"]).read_bytes()
    cut.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(HexsosError):
        hio.read(cut)
    assert calls == [cut]
    monkeypatch.setattr(readers, "via_meshio", lambda q, f: (_ for _ in ()).throw(readers.ParseError("no")))
    monkeypatch.setattr(readers, "read_msh_binary", lambda q: (_ for _ in ()).throw(readers.ParseError(
        "the numpy MSH reader declines this file: test")))
    m = hio.read(gm["order1"]["41b"])
    assert m.reader == "gmsh" and len(calls) == 2


def test_gmsh_reader_leaves_no_session_and_declines_a_running_one(gm):
    from hexsos_plugins.io.readers.gmsh_api import read_gmsh_api

    read_gmsh_api(Path(gm["order1"]["41"]))
    assert not gmsh.isInitialized()
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.model.add("mine")
        with pytest.raises(Exception, match="session of its own"):
            read_gmsh_api(Path(gm["order1"]["41"]))
        assert gmsh.model.getCurrent() == "mine"
    finally:
        gmsh.finalize()


def test_vtk_and_meshio_read_vtu_alike(gm, tmp_path, monkeypatch):
    monkeypatch.setattr("hexsos_plugins.io.readers.VTK_MIN_BYTES", 0)
    src = hio.read(gm["order2i"]["41b"])
    path = tmp_path / "a.vtu"
    hio.write(src.to_meshio(cell_data={"r": np.arange(src.n_cells, dtype=float)}), path)
    via = {who: quiet_read(fn, path) for who, fn in readers_for(path, "vtu")}
    assert set(via) == {"vtk", "meshio"}
    assert_same_mesh(via["vtk"], via["meshio"])
    assert hio.read(path).reader == "vtk"
    monkeypatch.setattr("hexsos_plugins.io.readers.vtk_api._AVAILABLE", False)
    assert hio.read(path).reader == "meshio"


def test_vtk_reader_only_where_it_pays(tmp_path, monkeypatch):
    """VTK's readers are imported only for large files (or when VTK is loaded already): a small .vtu in a process
    without VTK is read by meshio, and VTK is not imported."""
    import subprocess
    import sys

    P = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    path = tmp_path / "small.vtu"
    hio.write(Mesh.from_cells(P, [("tetra", [[0, 1, 2, 3]])]), path)
    code = ("import sys, hexsos_plugins.io as hio; m = hio.read(sys.argv[1]); "
            "print(m.reader, 'vtkmodules.vtkIOXML' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["meshio", "False"]
    monkeypatch.setattr("hexsos_plugins.io.readers.VTK_MIN_BYTES", 0)
    assert hio.read(path).reader == "vtk"  # negative case: above the threshold VTK reads it


def test_legacy_vtk_lagrange_cells_round_trip_and_vtk_sees_the_same_cells(tmp_path):
    """Orders 3 and 4 through legacy .vtk: hexsos writes version 4.2 with the Lagrange hexahedron in VTK's old node
    order, which VTK's legacy reader converts (it did not: VTK's det J of a written hexahedron125 differed from
    hexsos' by 0.04); hexsos reads 4.2 files (old order) and VTK's own 5.1 files (current order) back to the same
    cells, by its own reader and by VTK's."""
    import hexsos_plugins as hs
    from comparison import lagrange_oracle as LO
    from comparison.curved_mixed import write_mixed
    from hexsos_plugins.io.readers.legacy_vtk import read_legacy_vtk
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOLegacy import vtkUnstructuredGridReader, vtkUnstructuredGridWriter

    def dets(mesh, names):
        out = {}
        for t, c in mesh.cells:
            if t in names:
                d = ELEMENTS[t].det(mesh.points[c], LO.domain_points(t, 6, seed=2))
                out[t] = np.concatenate([out[t], d]) if t in out else d
        return {t: np.sort(d.ravel()) for t, d in out.items()}

    for order in (3, 4):
        src = write_mixed(tmp_path / f"m{order}.msh", order, noise=0.02)
        m = hs.read(src)
        names = {t for t, _ in m.cells if ELEMENTS[t].lagrange}
        assert any(ELEMENTS[t].domain == "cube" for t in names) and len(names) == 3
        ref = dets(m, names)
        legacy = tmp_path / f"m{order}.vtk"
        hs.write(m, legacy)
        assert legacy.read_bytes().startswith(b"# vtk DataFile Version 4.2")
        # VTK's legacy reader: the hexahedra hexsos checked
        r = vtkUnstructuredGridReader()
        r.SetFileName(str(legacy))
        r.Update()
        g = r.GetOutput()
        types = np.array([g.GetCellType(i) for i in range(g.GetNumberOfCells())])
        P = vtk_to_numpy(g.GetPoints().GetData())
        hexname = next(t for t in names if ELEMENTS[t].domain == "cube")
        ids = np.flatnonzero(types == 72)
        conn = np.array([[g.GetCell(int(i)).GetPointId(k) for k in range(ELEMENTS[hexname].n_nodes)] for i in ids])
        pc = LO.domain_points(hexname, 40, seed=3)
        blk = next(c for t, c in m.cells if t == hexname)
        ours = ELEMENTS[hexname].det(m.points[blk], pc)
        assert np.allclose(LO.vtk_det(hexname, P[conn], pc), ours, rtol=1e-8, atol=1e-8)
        # back through hexsos' own reader (4.2: old order converted) and through VTK's writer's 5.1 file
        v51 = tmp_path / f"m{order}_51.vtk"
        w = vtkUnstructuredGridWriter()
        w.SetInputData(g)
        w.SetFileName(str(v51))
        w.Write()
        assert v51.read_bytes().startswith(b"# vtk DataFile Version 5.1")
        for path in (legacy, v51):
            back = read_legacy_vtk(path.read_bytes(), path)
            got = dets(Mesh.from_meshio(back), names)
            for t in names:
                assert np.allclose(got[t], ref[t], rtol=1e-9, atol=1e-9), (path.name, t)
            assert {b.type for b in back.cells} >= names
        # the old-order conversion is needed: without it the 4.2 file's hexahedra are other cells
        raw = legacy.read_bytes().replace(b"Version 4.2", b"Version 5.1", 1)
        wrong = read_legacy_vtk(raw, legacy)
        wb = next(b.data for b in wrong.cells if b.type == hexname)
        assert not np.allclose(ELEMENTS[hexname].det(wrong.points[wb], pc), ours, rtol=1e-6, atol=1e-6)


def test_gmsh_incomplete_elements_above_order_five_are_named_in_the_error(tmp_path):
    """Gmsh makes incomplete elements at order 6 (Mesh.SecondOrderIncomplete): hexsos has no exact element for them
    (it reads those of orders 3-5, tests/test_incomplete.py); the error names Gmsh's element type (meshio's said only
    'np.int32(52)') and what hexsos reads, on one line."""
    import subprocess
    import sys

    path = tmp_path / "incomplete6.msh"
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("inc")
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.6)
        gmsh.option.setNumber("Mesh.SecondOrderIncomplete", 1)
        gmsh.model.mesh.generate(3)
        gmsh.model.mesh.setOrder(6)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    p = subprocess.run([sys.executable, "-m", "hexsos_plugins", "check", str(path)], capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 2 and "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1
    assert "Gmsh element type" in p.stderr and "incomplete" in p.stderr and "np.int32" not in p.stderr
