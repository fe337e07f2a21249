"""A mesh folded over itself by its node order (``Mesh.folded_cells``, ``meshrepair.orientation``): cells written
in the other handedness than their neighbours lie, once valid, on the same side of the faces they share with them.
The kernel's certificate, cell by cell, does not see it; the repair refuses such a mesh and names the cells, and
once they are flipped it untangles them out of the fold."""

import os

import numpy as np
import pytest

import hexsos_plugins as hs
from hexsos_plugins.errors import LeftHandedMeshError
from hexsos_plugins.examples import folded_column, structured_grid
from hexsos_plugins.io.mesh import Mesh

from folds import face_sides

FLIP = [0, 3, 2, 1, 4, 7, 6, 5]  # a hex's node order mirrored
KITTEN = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "hexalab", "kitten_with_bifur_3.mesh")


def test_a_fold_valid_cell_by_cell_is_named_refused_and_once_flipped_untangled():
    P, H = folded_column()
    assert (hs.check(P, H).status == 1).all()  # every hex valid by its own corners and coefficients
    a, b = face_sides(P, H, 0, 1)
    assert a * b > 0  # ... and the middle one on the lowest's side of their face: they overlap
    m = Mesh.from_arrays(P, H)
    assert np.flatnonzero(m.folded_cells()).tolist() == [1]
    assert np.flatnonzero(m.mirrored_cells()).tolist() == [1]
    with pytest.raises(LeftHandedMeshError, match=r"1 cell is written in the other handedness .*cells 1,? "):
        hs.repair(P, H, boundary="free")
    with pytest.raises(LeftHandedMeshError):
        hs.repair(P, H, method="paper")
    f = m.flipped(cells=m.mirrored_cells())
    assert not f.folded_cells().any()
    r0 = hs.check(f.points, f.hexes)
    assert r0.status[1] == 0 and (r0.status[[0, 2]] == 1).all()  # flipped, the fold is an invalid hex
    r = hs.repair(f.points, f.hexes, boundary="free", jobs=0)
    assert r.success and (hs.check(r.points, f.hexes).status == 1).all()
    for x, y in ((0, 1), (1, 2)):
        s, t = face_sides(r.points, f.hexes, x, y)
        assert s * t < 0  # each on its own side of the faces it shares: unfolded


def test_a_hex_written_mirrored_inside_a_grid_is_named_and_a_tangled_grid_is_not():
    P, H = structured_grid(3)
    H2 = H.copy()
    H2[13] = H2[13][FLIP]
    assert np.flatnonzero(Mesh.from_arrays(P, H2).folded_cells()).tolist() == [13]
    with pytest.raises(LeftHandedMeshError, match="cells 13"):
        hs.repair(P, H2)
    # a vertex pushed through its neighbours: inverted hexes, one handedness, nothing folded by the node order
    Q = P.copy()
    Q[(1 * 4 + 1) * 4 + 1, 2] -= 0.5
    assert (hs.check(Q, H).status == 0).any()
    assert not Mesh.from_arrays(Q, H).folded_cells().any()
    assert hs.repair(Q, H, jobs=0).success
    # two classes as large: both named (which is mirrored is the geometry's call), neither by the strict rule
    P2, H2 = structured_grid(2)
    H3 = H2.copy()
    H3[4:] = H3[4:][:, FLIP]
    m = Mesh.from_arrays(P2, H3)
    assert m.folded_cells().all() and not m.folded_cells(strict=True).any()


@pytest.mark.skipif(not os.path.exists(KITTEN), reason="the shared HexaLab mesh is absent")
def test_the_published_kitten_folds_over_itself_at_40_hexes(capsys):
    from hexsos_plugins.io import read

    m = read(KITTEN)
    folded = np.flatnonzero(m.folded_cells())
    assert folded.size == 40 and 23908 in folded
    assert np.array_equal(np.flatnonzero(m.mirrored_cells()), folded)
    assert (hs.check(m.points, m.hexes).status[folded] == 1).sum() >= 30  # most of them valid cell by cell
    with pytest.raises(LeftHandedMeshError, match="40 cells"):
        hs.repair(m.points, m.hexes)
    assert not m.flipped(cells=m.mirrored_cells()).folded_cells().any()
    # hexsos check names the same 40 (a hex negative at its centre: the mesh is read for folds), as repair does
    from hexsos_plugins import cli

    assert cli.main(["check", KITTEN, "--no-progress"]) == 2
    assert "40 of the 34880 hexahedron cells" in capsys.readouterr().err


def test_hexsos_repair_names_the_fold_and_repairs_it_with_fix_orientation(tmp_path, capsys):
    """``hexsos repair`` reads a file folded by its node order as an error naming the cell (exit 2, one line, no
    traceback); with ``--fix-orientation`` it flips it and repairs (exit 0). ``hexsos check`` judges each cell as
    written (every one valid here) and reads every face for folds only with ``--folds``."""
    import meshio

    from hexsos_plugins import cli

    P, H = folded_column()
    src, out = tmp_path / "fold.vtu", tmp_path / "out.vtu"
    meshio.write(src, meshio.Mesh(P, [("hexahedron", H)]))
    assert cli.main(["repair", str(src), "-o", str(out), "--no-progress", "--no-fidelity"]) == 2
    err = capsys.readouterr().err
    assert "partly mirrored" in err and "(cells 1)" in err and "Traceback" not in err and not out.exists()
    assert cli.main(["repair", str(src), "-o", str(out), "--no-progress", "--no-fidelity", "--boundary", "free",
                     "--fix-orientation", "--json"]) == 0
    capsys.readouterr()
    m = meshio.read(out)
    H2 = m.cells_dict["hexahedron"]
    assert np.array_equal(H2[1], H[1][FLIP]) and not Mesh.from_arrays(m.points, H2).folded_cells().any()
    assert (hs.check(m.points, H2).status == 1).all()
    assert cli.main(["check", str(src), "--no-progress"]) == 0
    capsys.readouterr()
    # with --folds it reads them as the repair does: named (exit 2); flipped, the fold is an invalid hex (exit 1)
    assert cli.main(["check", str(src), "--no-progress", "--folds"]) == 2
    err = capsys.readouterr().err
    assert "partly mirrored" in err and "(cells 1)" in err and "--fix-orientation" in err
    assert cli.main(["check", str(src), "--no-progress", "--folds", "--fix-orientation", "--json"]) == 1
    import json

    d = json.loads(capsys.readouterr().out)
    assert d["invalid"] == 1 and d["orientation"].startswith("mirrored (1 hexahedron")
    # a right-handed, unfolded file passes the same reading
    P2, H3 = structured_grid(2)
    ok = tmp_path / "grid.vtu"
    meshio.write(ok, meshio.Mesh(P2, [("hexahedron", H3)]))
    assert cli.main(["check", str(ok), "--no-progress", "--folds"]) == 0


def test_hexsos_convert_reads_the_faces_for_folds_with_folds(tmp_path, capsys):
    """``hexsos convert --folds`` reads every shared face as ``check --folds`` does: the folded column is refused by
    name (exit 2, one line, nothing written); with ``--fix-orientation`` the flipped cell is written flipped and
    its status is invalid (0); without ``--folds`` each cell is converted as written (every one valid)."""
    import meshio

    from hexsos_plugins import cli

    P, H = folded_column()
    src, out = tmp_path / "fold.vtu", tmp_path / "out.vtk"
    meshio.write(src, meshio.Mesh(P, [("hexahedron", H)]))
    assert cli.main(["convert", str(src), str(out), "--no-progress"]) == 0
    capsys.readouterr()
    assert (meshio.read(out).cell_data_dict["hexsos_status"]["hexahedron"] == 1).all()
    out.unlink()
    assert cli.main(["convert", str(src), str(out), "--no-progress", "--folds"]) == 2
    err = capsys.readouterr().err
    assert "partly mirrored" in err and "(cells 1)" in err and "Traceback" not in err and not out.exists()
    assert cli.main(["convert", str(src), str(out), "--no-progress", "--folds", "--fix-orientation"]) == 0
    capsys.readouterr()
    m = meshio.read(out)
    assert np.array_equal(m.cells_dict["hexahedron"][1], H[1][FLIP])
    assert list(m.cell_data_dict["hexsos_status"]["hexahedron"]) == [1, 0, 1]  # 0: invalid


def test_where_the_signs_name_the_larger_class_the_smaller_is_not_named_too():
    """A column of three unit hexes, the lower two written mirrored (negative at their centres), the top one as it
    should be: the signs name the lower two; the fold rule, which would name the smaller class (the top one), stays
    out of that part, so that flipping what ``mirrored_cells`` names leaves one handedness and every hex valid."""
    xy = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    P = np.concatenate([np.column_stack([xy, np.full(4, z)]) for z in (0.0, 1.0, 2.0, 3.0)])
    H = np.array([[4 * k + i for i in range(8)] for k in range(3)])
    H[:2] = H[:2][:, FLIP]
    m = Mesh.from_arrays(P, H)
    assert np.flatnonzero(m.folded_cells()).tolist() == [2]  # the smaller class, by topology alone
    assert np.flatnonzero(m.mirrored_cells()).tolist() == [0, 1]
    f = m.flipped(cells=m.mirrored_cells())
    assert not f.folded_cells().any() and (hs.check(f.points, f.hexes).status == 1).all()
