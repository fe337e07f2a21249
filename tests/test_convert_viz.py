"""``hexsos convert`` round trips and the pictures (``--screenshot``, ``--histogram``)."""

import json

import meshio
import numpy as np
import pytest

import hexsos_plugins as hs
from hexsos_plugins import cli
from hexsos_plugins.examples import demo_mesh, structured_grid
from hexsos_plugins.io import read_meshio, write


@pytest.fixture(scope="module")
def demo():
    P, H, info = demo_mesh()
    return P, H, info, hs.check(P, H)


TETS = np.array([[0, 1, 2, 40], [3, 4, 5, 41]])


@pytest.fixture
def mixed_file(tmp_path, demo):
    P, H, _, _ = demo
    tets = TETS
    quads = H[:6, :4]
    mesh = meshio.Mesh(P, [("hexahedron", H), ("tetra", tets), ("quad", quads)],
                       point_data={"temperature": np.linspace(0, 1, len(P)), "velocity": np.ones((len(P), 3))},
                       cell_data={"gmsh:physical": [np.full(len(H), 1), np.full(2, 2), np.full(6, 3)]},
                       field_data={"solid": np.array([1, 3])})
    path = tmp_path / "mixed.vtu"
    write(mesh, path)  # meshio's own vtu writer would drop the field data
    assert "solid" in read_meshio(path).field_data
    return path


@pytest.mark.parametrize("ext", [".vtu", ".vtk", ".msh", ".mesh"])
def test_convert_round_trip_keeps_everything(mixed_file, tmp_path, ext, demo, capsys):
    P, H, _, ref = demo
    tets = hs.check(P, [("tetra", TETS)])  # 3-D cells of every type are checked; 2-D cells are not
    out = tmp_path / f"out{ext}"
    assert cli.main(["convert", str(mixed_file), str(out)]) == 0
    captured = capsys.readouterr()
    c = hs.check(P, [("hexahedron", H), ("tetra", TETS)]).counts()
    assert f"{len(H) + 2} cells, {c['invalid']} invalid" in captured.out and f"{c['undecided']} undecided" in captured.out
    m = read_meshio(out)
    types = [b.type for b in m.cells]
    assert {"hexahedron", "tetra", "quad"} <= set(types)
    assert [len(b.data) for b in m.cells if b.type == "hexahedron"] == [len(H)]
    hexblock = types.index("hexahedron")
    assert np.array_equal(m.cells[hexblock].data, H)  # the same connectivity
    assert np.allclose(m.points, P)
    if ext == ".mesh":
        # Medit holds one integer reference per element and nothing else: the warning names what is lost
        assert "hexsos_min_det" in captured.err and "warning" in captured.err
        return
    assert np.allclose(m.point_data["temperature"], np.linspace(0, 1, len(P)))
    assert m.point_data["velocity"].shape[1] == 3
    assert np.array_equal(m.cell_data["hexsos_status"][hexblock].astype(int), ref.status)
    assert np.allclose(m.cell_data["hexsos_min_det"][hexblock], ref.min_det)
    assert np.allclose(np.asarray(m.cell_data["hexsos_argmin"][hexblock]).reshape(-1, 3), ref.argmin)
    tet, quad = types.index("tetra"), types.index("quad")
    assert np.array_equal(np.asarray(m.cell_data["hexsos_status"][tet]).astype(int), tets.status)
    assert np.allclose(m.cell_data["hexsos_min_det"][tet], tets.min_det)
    assert np.all(np.isnan(m.cell_data["hexsos_min_det"][quad]))  # 2-D cells: NaN and -2
    assert np.all(np.asarray(m.cell_data["hexsos_status"][quad]) == -2)
    assert np.array_equal(np.asarray(m.cell_data["gmsh:physical"][tet]).astype(int), [2, 2])
    assert "solid" in m.field_data


def test_convert_json_and_input_untouched(mixed_file, tmp_path, capsys):
    before = mixed_file.read_bytes()
    assert cli.main(["convert", str(mixed_file), str(tmp_path / "o.vtk"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["output"].endswith("o.vtk") and d["invalid_inside_only"] >= 1
    assert mixed_file.read_bytes() == before


def test_convert_says_cells_written_twice_and_keeps_them(tmp_path, capsys):
    """A cell written again on the same points (Gmsh's MSH 2 writes an element once per physical group) is named in
    ``convert``'s one line and kept in its output; a mesh without one says nothing of it."""
    P, H = structured_grid(2)
    for extra, said in ((H[[3]][:, [1, 2, 3, 0, 5, 6, 7, 4]], ", 1 written twice"), (np.zeros((0, 8), int), None)):
        src, out = tmp_path / f"in{len(extra)}.vtu", tmp_path / f"out{len(extra)}.vtu"
        write(meshio.Mesh(P, [("hexahedron", np.vstack([H, extra]))]), src)
        assert cli.main(["convert", str(src), str(out)]) == 0
        line = capsys.readouterr().out
        assert ("written twice" in line) == (said is not None) and (said is None or said in line), line
        assert len(read_meshio(out).cells[0].data) == len(H) + len(extra)


def test_convert_unknown_output_extension(mixed_file, tmp_path, capsys):
    assert cli.main(["convert", str(mixed_file), str(tmp_path / "o.xyz")]) == 2
    assert "hexsos: error:" in capsys.readouterr().err
    assert not (tmp_path / "o.xyz").exists()


def _image(path):
    import matplotlib.image as mpimg

    with open(path, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    return mpimg.imread(path)[..., :3]


def _share(img, rgb, tol=0.12):
    return float(np.mean(np.all(np.abs(img - np.array(rgb)) < tol, axis=-1)))


def test_screenshot_shows_invalid_and_inside_only_hexes(demo, tmp_path):
    from hexsos_plugins import viz

    P, H, _, r = demo
    img = _image(viz.screenshot(P, H, r, tmp_path / "bad.png"))
    assert img.shape[0] > 500 and img.std() > 0.05  # rendered, not blank
    magenta = _share(img, (1.0, 0.0, 1.0), 0.25)
    red = np.mean((img[..., 0] > 0.55) & (img[..., 1] < 0.35) & (img[..., 2] < 0.35))
    assert magenta > 0 and red > 0
    # a valid mesh: no red, no magenta
    Pg, Hg = structured_grid(4)
    good = hs.check(Pg, Hg)
    img = _image(viz.screenshot(Pg, Hg, good, tmp_path / "good.png"))
    assert _share(img, (1.0, 0.0, 1.0), 0.25) == 0
    assert np.mean((img[..., 0] > 0.55) & (img[..., 1] < 0.35) & (img[..., 2] < 0.35)) == 0


def test_histogram_marks_invalid_bins(demo, tmp_path):
    from hexsos_plugins import viz

    _, _, _, r = demo
    img = _image(viz.histogram(r, tmp_path / "h.png"))
    red = np.mean((img[..., 0] > 0.7) & (img[..., 1] < 0.3) & (img[..., 2] < 0.3))
    assert red > 0
    Pg, Hg = structured_grid(3)
    img = _image(viz.histogram(hs.check(Pg, Hg), tmp_path / "g.png"))
    assert np.mean((img[..., 0] > 0.7) & (img[..., 1] < 0.3) & (img[..., 2] < 0.3)) == 0


def test_check_writes_both_pictures(demo, tmp_path, capsys):
    P, H, _, _ = demo
    src = tmp_path / "m.vtu"
    meshio.write(src, meshio.Mesh(P, [("hexahedron", H)]))
    assert cli.main(["check", str(src), "--screenshot", str(tmp_path / "s.png"), "--histogram",
                     str(tmp_path / "h.png")]) == 1
    out = capsys.readouterr().out
    assert "wrote" in out and (tmp_path / "s.png").stat().st_size > 10000 and (tmp_path / "h.png").exists()


def _slab(nx, ny, nz):
    """A flat plate of nx * ny * nz unit hexes (VTK order)."""
    x, y, z = np.arange(nx + 1.0), np.arange(ny + 1.0), np.arange(nz + 1.0)
    Z, Y, X = np.meshgrid(z, y, x, indexing="ij")
    P = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    c = np.arange(P.shape[0]).reshape(nz + 1, ny + 1, nx + 1)[:-1, :-1, :-1]
    s, t = nx + 1, (nx + 1) * (ny + 1)
    H = np.stack([c, c + 1, c + s + 1, c + s, c + t, c + t + 1, c + t + s + 1, c + t + s], -1).reshape(-1, 8)
    return P, H


def _bad_colour(img):
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r > 100) & (r > 2 * g) & (r > 2 * b)


def test_a_screenshot_of_a_big_mesh_shows_its_one_bad_hex(tmp_path):
    """20,000 hexes, one vertex pushed through a neighbour: the few invalid hexes are a few pixels at the mesh's
    scale; the picture frames them and zooms on them in an inset."""
    pytest.importorskip("pyvista")
    from PIL import Image

    from hexsos_plugins import viz

    P, H = _slab(100, 100, 2)
    k = np.flatnonzero(np.all(P == [30, 60, 1], axis=1))[0]
    P[k, 2] += 1.6  # through the top layer
    r = hs.check(P, H)
    assert 1 <= r.counts()["invalid"] <= 8
    out = viz.screenshot(P, H, r, tmp_path / "big.png")
    img = np.asarray(Image.open(out).convert("RGB")).astype(int)
    h, w = img.shape[:2]
    bad = _bad_colour(img)
    bad[: int(0.2 * h), : int(0.32 * w)] = False  # the legend (its red text and swatch)
    inset = bad[:, int(0.75 * w):]
    assert inset.sum() > 800, inset.sum()  # the zoomed bad hexes
    assert bad[:, : int(0.72 * w)].sum() > 600, bad[:, : int(0.72 * w)].sum()  # the frame in the main view
    # a mesh with every cell valid has neither frames nor insets
    P2, H2 = _slab(100, 100, 2)
    r2 = hs.check(P2, H2)
    img2 = np.asarray(Image.open(viz.screenshot(P2, H2, r2, tmp_path / "valid.png")).convert("RGB")).astype(int)
    assert _bad_colour(img2).sum() == 0


def test_bad_cells_are_grouped_in_clusters():
    from hexsos_plugins import viz

    P, H = _slab(40, 10, 1)
    for x in (5, 30):  # two separate folds, far apart
        k = np.flatnonzero(np.all(P == [x, 5, 1], axis=1))[0]
        P[k, 2] -= 1.6
    r = hs.check(P, H)
    clusters = viz.bad_clusters(P, [("hexahedron", H)], r, 1.0)
    assert len(clusters) == 2 and sum(len(c) for c in clusters) == r.counts()["invalid"]
    assert all(np.all(r.status[c] != 1) for c in clusters)
