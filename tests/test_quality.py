"""The scaled Jacobian against vtkMeshQuality (Verdict), on random cells including inverted ones."""

import numpy as np
import pytest

from hexsos_plugins.errors import InvalidInputError
from hexsos_plugins.cells.quality import IDEAL, sample_scaled_jacobians, scaled_jacobian, sj_text, summary

vtk = pytest.importorskip("vtk")
from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy  # noqa: E402

VTK_TYPE = {"hexahedron": 12, "tetra": 10, "wedge": 13, "pyramid": 14}


def vtk_scaled_jacobian(name, X):
    M, n, _ = X.shape
    g = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(X.reshape(-1, 3)), deep=1))
    g.SetPoints(pts)
    for m in range(M):
        ids = vtk.vtkIdList()
        for k in range(n):
            ids.InsertNextId(m * n + k)
        g.InsertNextCell(VTK_TYPE[name], ids)
    q = vtk.vtkMeshQuality()
    q.SetInputData(g)
    q.SetHexQualityMeasureToScaledJacobian()
    q.SetTetQualityMeasureToScaledJacobian()
    q.SetWedgeQualityMeasureToScaledJacobian()
    q.SetPyramidQualityMeasureToScaledJacobian()
    q.Update()
    return vtk_to_numpy(q.GetOutput().GetCellData().GetArray("Quality")).astype(np.float64)


@pytest.mark.parametrize("name", ["hexahedron", "tetra", "wedge", "pyramid"])
def test_matches_vtk_mesh_quality_on_random_cells(name):
    rng = np.random.default_rng(7)
    ref = IDEAL[name]
    X = np.concatenate([ref + s * rng.standard_normal((700,) + ref.shape) for s in (0.1, 0.4, 1.0)])
    P = X.reshape(-1, 3)
    C = np.arange(P.shape[0]).reshape(-1, ref.shape[0])
    ours = scaled_jacobian(P, [(name, C)])
    theirs = vtk_scaled_jacobian(name, X)
    assert (ours < 0).sum() > 100  # inverted cells are part of the comparison
    if name == "pyramid":  # vtkMeshQuality clamps negative pyramids to 0; we keep the sign
        assert np.allclose(np.maximum(ours, 0.0), theirs, rtol=0, atol=1e-12)
        assert (theirs[ours < 0] == 0).all()
    else:
        assert np.allclose(ours, theirs, rtol=0, atol=1e-12)
    assert scaled_jacobian(ref, [(name, np.arange(ref.shape[0])[None])])[0] == pytest.approx(1.0, abs=1e-14)


def test_hex_takes_the_centre_sample_as_verdict_does():
    # corners alone would miss this: strongly distorted hexes where the centre's principal axes are the worst
    rng = np.random.default_rng(3)
    X = IDEAL["hexahedron"] + 1.0 * rng.standard_normal((3000, 8, 3))
    s = sample_scaled_jacobians(X, "hexahedron")
    corners, centre = s[:, :8].min(axis=1), s[:, 8]
    worse = centre < corners
    assert worse.sum() > 10
    v = vtk_scaled_jacobian("hexahedron", X[worse])
    assert np.allclose(v, centre[worse], atol=1e-12) and not np.allclose(v, corners[worse], atol=1e-3)


def test_hex_array_input_other_types_nan_and_summary():
    P = IDEAL["hexahedron"]
    assert scaled_jacobian(P, np.arange(8)[None]).tolist() == [1.0]
    Q = np.vstack([P, P + 2.0])
    mixed = scaled_jacobian(Q, [("hexahedron", np.arange(8)[None]), ("hexahedron20", np.zeros((2, 20), int))])
    assert mixed[0] == 1.0 and np.isnan(mixed[1:]).all() and mixed.shape == (3,)
    s = summary(np.array([0.5, np.nan, 0.1, 0.9]))
    assert s["min"] == 0.1 and s["mean"] == pytest.approx(0.5) and 0.1 < s["p1"] < 0.11
    assert np.isnan(summary([np.nan])["min"])
    with pytest.raises(InvalidInputError, match="out of range"):
        scaled_jacobian(P, np.array([[0, 1, 2, 3, 4, 5, 6, 8]]))
    with pytest.raises(InvalidInputError, match="expected"):
        scaled_jacobian(P, np.zeros((1, 7), int))


def test_sj_text_prints_a_small_scaled_jacobian_with_its_digits_not_as_zero():
    assert sj_text(0.86603) == "0.8660"
    assert sj_text(-0.5) == "-0.5000"
    assert sj_text(0.0) == "0.0000"
    assert sj_text(5e-5) == "0.0001"  # four decimals still say it is not 0
    assert sj_text(2e-6) == "2.00e-06"
    assert sj_text(-3.456e-9) == "-3.46e-09"
