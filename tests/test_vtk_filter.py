"""The VTK filters (``vtk_filter``) in plain VTK pipelines: conversion of mixed grids, voxels, the fold points,
repair, options, errors, and a .vtu round trip. The math is the kernel's and is not tested again here: every
expected value comes from ``hexsos_plugins.check`` / ``repair`` called on the same hexes."""

import importlib.util
import os
import re

import numpy as np
import pytest

pytest.importorskip("vtkmodules.vtkCommonDataModel")

from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy  # noqa: E402
from vtkmodules.vtkCommonCore import (  # noqa: E402
    reference,
    vtkCommand,
    vtkOutputWindow,
    vtkPoints,
    vtkStringArray,
    vtkStringOutputWindow,
)
from vtkmodules.vtkCommonDataModel import vtkHexahedron, vtkUnstructuredGrid  # noqa: E402
from vtkmodules.vtkIOXML import (  # noqa: E402
    vtkXMLPolyDataReader,
    vtkXMLPolyDataWriter,
    vtkXMLUnstructuredGridReader,
    vtkXMLUnstructuredGridWriter,
)

import hexsos_plugins as hs  # noqa: E402
import vtk_filter  # noqa: E402
from hexsos_plugins.examples import inside_invalid_hex, structured_grid  # noqa: E402
from vtk_filter import HexSOSCheckFilter, HexSOSRepairFilter  # noqa: E402
from vtk_filter import hexsos_paraview_plugin as plugin  # noqa: E402

HEX, VOXEL, TETRA, QUAD, WEDGE, PYRAMID = 12, 11, 10, 9, 13, 14
NAMES = ("hexsos_min_det", "hexsos_lower_bound", "hexsos_argmin", "hexsos_status", "hexsos_corner_min_det")
# Voxel node j sits at corner (j & 1, j >> 1 & 1, j >> 2 & 1) (x fastest); the same corners in VTK hexahedron
# order (written out here, not taken from the kernel):
VTK_CORNERS = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
VOXEL_NODE_OF_HEX_NODE = [a + 2 * b + 4 * c for a, b, c in VTK_CORNERS]  # [0, 1, 3, 2, 4, 5, 7, 6]


# ------------------------------------------------------------------------------------------------------
# building grids
# ------------------------------------------------------------------------------------------------------


def make_grid(points, cells, *, point_arrays=None, cell_arrays=None, field_text=None):
    """A vtkUnstructuredGrid from points (N, 3) and cells [(vtk type, point ids), ...] in that order."""
    g = vtkUnstructuredGrid()
    pts = vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(points, dtype=np.float64), deep=1))
    g.SetPoints(pts)
    g.Allocate(len(cells))
    for t, ids in cells:
        g.InsertNextCell(int(t), len(ids), [int(i) for i in ids])
    for where, arrays in ((g.GetPointData(), point_arrays), (g.GetCellData(), cell_arrays)):
        for name, values in (arrays or {}).items():
            a = numpy_to_vtk(np.ascontiguousarray(values), deep=1)
            a.SetName(name)
            where.AddArray(a)
    if field_text is not None:
        s = vtkStringArray()
        s.SetName("note")
        s.InsertNextValue(field_text)
        g.GetFieldData().AddArray(s)
    return g


def voxel_block(offset=(10.0, 0.0, 0.0), push=0.8):
    """2 x 2 x 2 voxels (lexicographic connectivity, built from grid indices) with the centre vertex pushed
    by ``push`` along x: the voxels beside it fold. Returns points, voxel connectivity, the same cells as
    hexahedra (VTK order)."""
    n = 2
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)  # idx[i, j, k], i along x
    xs = np.linspace(0.0, 1.0, n + 1)
    P = np.stack(np.meshgrid(xs, xs, xs, indexing="ij"), axis=-1).reshape(-1, 3) + np.asarray(offset)
    P[idx[1, 1, 1], 0] += push
    vox, hexa = [], []
    for i in range(n):
        for j in range(n):
            for k in range(n):
                vox.append([idx[i + (v & 1), j + (v >> 1 & 1), k + (v >> 2 & 1)] for v in range(8)])
                hexa.append([idx[i + a, j + b, k + c] for a, b, c in VTK_CORNERS])
    return P, np.array(vox), np.array(hexa)


@pytest.fixture(scope="module")
def demo():
    pytest.importorskip("gmsh")
    from hexsos_plugins.examples import demo_mesh

    return demo_mesh()


@pytest.fixture(scope="module")
def mixed(demo):
    """The demo mesh's hexes interleaved with tets, a quad, a wedge, a pyramid and a folded voxel block.

    Returns the grid and the oracle: the hexes in cell order (voxels reordered by the test's own table), the
    cell index of each, and ``hs.check`` on them.
    """
    P, H, info = demo
    Pv, V, Hv = voxel_block()
    n0 = P.shape[0]
    extra = np.array([[5.0, 5, 5], [6, 5, 5], [5, 6, 5], [5, 5, 6], [6, 6, 6], [6, 5, 6]])
    n1 = n0 + Pv.shape[0]
    points = np.concatenate([P, Pv, extra])
    cells, hex_nodes, hex_cells = [], [], []

    def add_hex(t, ids, vtk_order):
        hex_cells.append(len(cells))
        hex_nodes.append(vtk_order)
        cells.append((t, ids))

    cells.append((TETRA, H[0][[0, 1, 3, 4]]))  # shares points with hex 0
    for h in H[:300]:
        add_hex(HEX, h, h)
    cells.append((QUAD, H[5][[0, 3, 2, 1]]))  # a face of hex 5
    cells.append((WEDGE, n1 + np.arange(6)))
    for v, h in zip(V, Hv):
        add_hex(VOXEL, n0 + v, n0 + h)
    for h in H[300:]:
        add_hex(HEX, h, h)
    cells.append((PYRAMID, [n1, n1 + 1, n1 + 4, n1 + 2, n1 + 3]))
    cells.append((TETRA, n1 + np.arange(4)))
    n_cells = len(cells)
    grid = make_grid(points, cells,
                     point_arrays={"temperature": np.arange(points.shape[0], dtype=np.float64) * 0.5},
                     cell_arrays={"material": np.arange(n_cells, dtype=np.int32) % 7},
                     field_text="kept")
    hexes = np.array(hex_nodes, dtype=np.int64)
    hex_cells = np.array(hex_cells)
    expected = hs.check(points, hexes)
    inside_only_cell = hex_cells[info["inside_only_hex"] if info["inside_only_hex"] < 300 else info["inside_only_hex"] + 8]
    # the oracle of every cell: hs.check on the cells of each 3-D type (VTK order: the tets, the wedge and the
    # pyramid as given, voxels reordered by the test's own table), NaN / -2 on the quad
    names = {TETRA: "tetra", WEDGE: "wedge", PYRAMID: "pyramid"}
    by_cell = {k: np.full(len(cells), np.nan) for k in ("hexsos_min_det", "hexsos_lower_bound", "hexsos_corner_min_det")}
    by_cell["hexsos_status"] = np.full(len(cells), -2, dtype=np.int8)
    by_cell["hexsos_argmin"] = np.full((len(cells), 3), np.nan)
    for vt, name in names.items():
        ids = [i for i, (t, _) in enumerate(cells) if t == vt]
        r = hs.check(points, [(name, np.array([cells[i][1] for i in ids]))])
        for k, v in r.cell_data().items():
            by_cell[k][ids] = v
    for k, v in expected.cell_data().items():
        by_cell[k][hex_cells] = v
    return {"grid": grid, "points": points, "hexes": hexes, "hex_cells": hex_cells, "expected": expected,
            "types": np.array([t for t, _ in cells]), "inside_only_cell": int(inside_only_cell),
            "voxel_cells": hex_cells[300:308], "by_cell": by_cell,
            "checked": np.array([t != QUAD for t, _ in cells])}


def run_check(grid, **options):
    f = HexSOSCheckFilter()
    for k, v in options.items():
        getattr(f, "Set" + k)(v)
    f.SetInputDataObject(0, grid)
    f.Update()
    return f


def cell_array(data, name):
    return vtk_to_numpy(data.GetCellData().GetArray(name))


def fingerprint(grid):
    """Everything a filter could modify on its input: points, cells, types and every array, as bytes."""
    fp = {"points": vtk_to_numpy(grid.GetPoints().GetData()).tobytes(),
          "conn": vtk_to_numpy(grid.GetCells().GetConnectivityArray()).tobytes(),
          "offsets": vtk_to_numpy(grid.GetCells().GetOffsetsArray()).tobytes(),
          "types": [grid.GetCellType(i) for i in range(grid.GetNumberOfCells())]}
    for label, fd in (("point", grid.GetPointData()), ("cell", grid.GetCellData())):
        fp[label] = {fd.GetArrayName(i): vtk_to_numpy(fd.GetArray(i)).tobytes() for i in range(fd.GetNumberOfArrays())}
    fp["field"] = [grid.GetFieldData().GetAbstractArray(i).GetName() for i in range(grid.GetFieldData().GetNumberOfArrays())]
    return fp


class Messages:
    """Collects the ErrorEvent / WarningEvent messages of a VTK object (what vtkErrorMacro sends)."""

    def __init__(self, obj):
        from vtkmodules.util.misc import calldata_type
        from vtkmodules.util.vtkConstants import VTK_STRING

        self.errors, self.warnings = [], []

        @calldata_type(VTK_STRING)
        def on_error(o, e, text):
            self.errors.append(text)

        @calldata_type(VTK_STRING)
        def on_warning(o, e, text):
            self.warnings.append(text)

        obj.AddObserver(vtkCommand.ErrorEvent, on_error)
        obj.AddObserver(vtkCommand.WarningEvent, on_warning)
        self._keep = (on_error, on_warning)


# ------------------------------------------------------------------------------------------------------
# the package
# ------------------------------------------------------------------------------------------------------


def test_exports_resolve_and_paraview_is_optional():
    for name in vtk_filter.__all__:
        assert getattr(vtk_filter, name) is not None
    with pytest.raises(AttributeError):
        vtk_filter.NoSuchName  # noqa: B018
    assert issubclass(HexSOSCheckFilter, plugin.VTKPythonAlgorithmBase)  # classes, also under ParaView
    if importlib.util.find_spec("paraview") is None:
        assert plugin.IN_PARAVIEW is False  # PyPI vtk: the ParaView decorators are no-ops


def test_package_init_loaded_as_a_paraview_plugin_runs_nothing():
    # ParaView loads every .py of a PV_PLUGIN_PATH directory, __init__.py included, as a stand-alone module
    path = os.path.join(os.path.dirname(vtk_filter.__file__), "__init__.py")
    spec = importlib.util.spec_from_file_location("__init__", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert not any(hasattr(v, "_pvsm_proxy_xml") for v in vars(module).values())
    assert sorted(module.__all__) == sorted(vtk_filter.__all__)


# ------------------------------------------------------------------------------------------------------
# check
# ------------------------------------------------------------------------------------------------------


def test_check_mixed_grid_arrays_equal_the_kernel_in_the_right_cells(mixed):
    """Every 3-D cell (hexahedra, voxels, tets, the wedge, the pyramid) gets the kernel's values of its own
    type in its own cell; the quad (2-D) NaN and -2."""
    grid, exp, by_cell = mixed["grid"], mixed["expected"], mixed["by_cell"]
    before = fingerprint(grid)
    f = run_check(grid)
    out = f.GetOutputDataObject(0)
    assert out.GetNumberOfCells() == grid.GetNumberOfCells() and out.GetNumberOfPoints() == grid.GetNumberOfPoints()
    assert [out.GetCellType(i) for i in range(out.GetNumberOfCells())] == mixed["types"].tolist()
    assert (~mixed["checked"]).sum() == 1  # the quad
    for name, values in by_cell.items():
        got = cell_array(out, name)
        assert got.dtype == np.asarray(values).dtype, name
        assert np.array_equal(got, values, equal_nan=True), name
    assert (cell_array(out, "hexsos_status")[mixed["types"] == TETRA] != -2).all()  # tets are checked now
    assert out.GetCellData().GetArray("hexsos_argmin").GetNumberOfComponents() == 3
    sj = cell_array(out, "hexsos_scaled_jacobian")
    assert np.isfinite(sj[mixed["checked"]]).all() and np.isnan(sj[~mixed["checked"]]).all()
    # the inside-only hex is found in its cell
    c = mixed["inside_only_cell"]
    assert cell_array(out, "hexsos_status")[c] == 0 and cell_array(out, "hexsos_corner_min_det")[c] > 0
    assert f.GetResult().counts()["cells"] == int(mixed["checked"].sum())
    assert exp.counts()["invalid"] >= 3 and exp.counts()["invalid_inside_only"] >= 1
    # every input array kept, unchanged; the input itself untouched
    assert np.array_equal(cell_array(out, "material"), cell_array(grid, "material"))
    assert np.array_equal(vtk_to_numpy(out.GetPointData().GetArray("temperature")),
                          vtk_to_numpy(grid.GetPointData().GetArray("temperature")))
    assert out.GetFieldData().GetAbstractArray("note").GetValue(0) == "kept"
    assert "invalid" in out.GetFieldData().GetAbstractArray("hexsos_summary").GetValue(0)
    assert fingerprint(grid) == before
    # the structure is shared, not copied
    assert (out.GetPoints().GetData().GetAddressAsString("vtkDataArray")
            == grid.GetPoints().GetData().GetAddressAsString("vtkDataArray"))


def test_fold_points_one_per_invalid_cell_at_x_of_argmin(mixed):
    from vtkmodules.vtkCommonDataModel import vtkGenericCell

    f = run_check(mixed["grid"])
    out, folds = f.GetOutputDataObject(0), f.GetOutputDataObject(1)
    assert folds.GetClassName() == "vtkPolyData"
    status = cell_array(out, "hexsos_status")
    invalid_cells = np.flatnonzero(status == 0)
    assert folds.GetNumberOfPoints() == invalid_cells.size > mixed["expected"].invalid.sum() - 1
    assert folds.GetNumberOfVerts() == invalid_cells.size
    pd = folds.GetPointData()
    cell_ids = vtk_to_numpy(pd.GetArray("hexsos_cell_id"))
    assert sorted(cell_ids.tolist()) == invalid_cells.tolist()
    assert np.array_equal(vtk_to_numpy(pd.GetArray("hexsos_min_det")), cell_array(out, "hexsos_min_det")[cell_ids])
    inside = vtk_to_numpy(pd.GetArray("hexsos_invalid_inside_only"))
    assert inside.tolist() == (cell_array(out, "hexsos_corner_min_det")[cell_ids] > 0).astype(int).tolist()
    assert inside[cell_ids.tolist().index(mixed["inside_only_cell"])] == 1
    # x(argmin) by VTK's own interpolation of each cell (its parametric coordinates, VTK node order; voxels are
    # checked as the equivalent hexahedra, so evaluated as those)
    X = vtk_to_numpy(folds.GetPoints().GetData())
    argmin = cell_array(out, "hexsos_argmin")
    points = mixed["points"]
    hex_of = dict(zip(mixed["hex_cells"].tolist(), range(len(mixed["hex_cells"]))))
    grid = mixed["grid"]
    for i, c in enumerate(cell_ids):
        if int(c) in hex_of:
            cell = vtkHexahedron()
            for k, node in enumerate(mixed["hexes"][hex_of[int(c)]]):
                cell.GetPointIds().SetId(k, k)
                cell.GetPoints().SetPoint(k, *points[node])
        else:
            cell = vtkGenericCell()
            grid.GetCell(int(c), cell)
        x, w = [0.0, 0.0, 0.0], [0.0] * cell.GetNumberOfPoints()
        cell.EvaluateLocation(reference(0), list(argmin[c]), x, w)
        assert np.allclose(X[i], x, rtol=0, atol=1e-12), (c, X[i], x)


def test_voxels_give_the_verdicts_of_the_equivalent_hexahedra():
    P, V, Hv = voxel_block(offset=(0, 0, 0))
    fv = run_check(make_grid(P, [(VOXEL, v) for v in V]))
    fh = run_check(make_grid(P, [(HEX, h) for h in Hv]))
    ov, oh = fv.GetOutputDataObject(0), fh.GetOutputDataObject(0)
    for name in NAMES:
        assert np.array_equal(cell_array(ov, name), cell_array(oh, name), equal_nan=True), name
    status = cell_array(ov, "hexsos_status")
    assert 0 < (status == 0).sum() < 8 and (status == 1).any()
    # the check keeps the cells as they are: voxels stay voxels
    assert {ov.GetCellType(i) for i in range(ov.GetNumberOfCells())} == {VOXEL}
    # undamaged voxels are all valid (wrongly ordered, they would fold)
    P2, V2, _ = voxel_block(push=0.0)
    assert (cell_array(run_check(make_grid(P2, [(VOXEL, v) for v in V2])).GetOutputDataObject(0),
                       "hexsos_status") == 1).all()
    assert VOXEL_NODE_OF_HEX_NODE == [0, 1, 3, 2, 4, 5, 7, 6]
    pts = vtk_to_numpy(fv.GetOutputDataObject(1).GetPoints().GetData())
    ptsh = vtk_to_numpy(fh.GetOutputDataObject(1).GetPoints().GetData())
    assert np.array_equal(pts, ptsh)


def test_options_change_results_and_modified_reexecutes():
    P, _, Hv = voxel_block(push=0.3)
    grid = make_grid(P, [(HEX, h) for h in Hv])
    f = run_check(grid)
    first = f.GetResult()
    assert first.method_requested == "auto" and not first.sos_status.any()
    f.Update()
    assert f.GetResult() is first  # nothing changed: not executed again
    mtime = f.GetMTime()
    f.SetMethod("auto")  # same value: not modified
    assert f.GetMTime() == mtime
    f.SetMethod("sos")
    assert f.GetMethod() == "sos" and f.GetMTime() > mtime
    f.Update()
    sos = f.GetResult()
    assert sos is not first and sos.method_requested == "sos" and sos.sos_status.any()
    assert np.array_equal(sos.status, first.status)  # verdicts are proofs either way
    f.SetRelaxation("paper")
    f.Update()
    assert f.GetResult().relaxation == "paper" and f.GetResult() is not sos
    again = f.GetResult()
    f.Modified()
    f.Update()
    assert f.GetResult() is not again
    with pytest.raises(ValueError, match="method"):
        f.SetMethod("fast")
    with pytest.raises(ValueError, match="relaxation"):
        f.SetRelaxation("order9")
    # an upstream change re-executes too
    grid.GetPoints().GetData().Modified()
    before = f.GetResult()
    f.Update()
    assert f.GetResult() is not before


def test_progress_is_reported():
    P, H = structured_grid(3)
    f = HexSOSCheckFilter()
    seen = []
    f.AddObserver(vtkCommand.ProgressEvent, lambda o, e: seen.append(o.GetProgress()))
    f.SetInputDataObject(0, make_grid(P, [(HEX, h) for h in H]))
    f.Update()
    assert seen and seen[-1] == 1.0 and seen == sorted(seen)


def _tets_only():
    return make_grid(np.eye(4)[:, :3], [(TETRA, [0, 1, 2, 3])])


def _quads_only():
    return make_grid(np.eye(4)[:, :3], [(QUAD, [0, 1, 2, 3])])


@pytest.mark.parametrize("make", [_quads_only, lambda: make_grid(np.zeros((0, 3)), [])], ids=["quads", "empty"])
@pytest.mark.parametrize("cls", [HexSOSCheckFilter, HexSOSRepairFilter])
def test_no_3d_cells_is_a_vtk_error_not_a_crash(make, cls):
    f = cls()
    msgs = Messages(f)
    f.SetInputDataObject(0, make())
    assert not f.Update()  # the request fails...
    assert len(msgs.errors) == 1 and "no 3-D cells" in msgs.errors[0]  # ...with one error event
    for port in range(f.GetNumberOfOutputPorts()):
        out = f.GetOutputDataObject(port)
        assert out.GetNumberOfCells() == 0 and out.GetNumberOfPoints() == 0
    assert f.GetResult() is None


def test_a_grid_of_tets_is_checked():
    f = run_check(_tets_only())
    out = f.GetOutputDataObject(0)
    assert cell_array(out, "hexsos_status").tolist() == [0]  # np.eye(4)[:, :3] is a mirrored unit tet
    assert cell_array(out, "hexsos_min_det").tolist() == [-1.0]


def test_errors_go_to_the_output_window_without_observers():
    previous = vtkOutputWindow.GetInstance()
    previous.Register(None)
    window = vtkStringOutputWindow()
    vtkOutputWindow.SetInstance(window)
    try:
        f = HexSOSCheckFilter()
        f.SetInputDataObject(0, _quads_only())
        f.Update()
        P, H = structured_grid(1)
        P[H[0][6]] = np.nan
        f.SetInputDataObject(0, make_grid(P, [(HEX, H[0])]))
        f.Update()
    finally:
        vtkOutputWindow.SetInstance(previous)
        previous.UnRegister(None)
    text = window.GetOutput()
    assert "ERROR" in text and "no 3-D cells" in text and "it has 1 of type 9" in text
    assert "finite" in text  # the kernel's InvalidInputError, reported the same way


# ------------------------------------------------------------------------------------------------------
# repair
# ------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def damaged():
    """A 3 x 3 x 3 grid with an interior vertex pushed through (4 folded hexes), the inside-only hex beside
    it, a folded voxel block, a tet on a grid corner and a quad on a grid face."""
    P, H = structured_grid(3)
    P[np.flatnonzero(np.all(np.isclose(P, 1 / 3), axis=1))[0], 0] += 0.4
    n0 = P.shape[0]
    X = inside_invalid_hex() * 0.25 + [3.0, 0.0, 0.0]
    Pv, V, _ = voxel_block(offset=(5.0, 0.0, 0.0), push=0.5)
    points = np.concatenate([P, X, Pv, [[-1.0, -1.0, -1.0]]])
    corner = int(np.flatnonzero(np.all(P == 0.0, axis=1))[0])
    cells = [(TETRA, [corner, corner + 1, corner + 4, points.shape[0] - 1])]
    cells += [(HEX, h) for h in H]
    cells.append((QUAD, H[0][[0, 1, 2, 3]]))
    cells.append((HEX, n0 + np.arange(8)))
    cells += [(VOXEL, n0 + 8 + v) for v in V]
    grid = make_grid(points, cells, point_arrays={"temperature": np.arange(points.shape[0], dtype=np.float64)},
                     cell_arrays={"material": np.arange(len(cells), dtype=np.int32)}, field_text="kept")
    return grid


def test_repair_filter_certifies_and_reports_the_displacement(damaged):
    before = fingerprint(damaged)
    f = HexSOSRepairFilter()
    msgs = Messages(f)
    seen = []
    f.AddObserver(vtkCommand.ProgressEvent, lambda o, e: seen.append((o.GetProgress(), o.GetProgressText())))
    f.SetInputDataObject(0, damaged)
    assert f.Update()
    r = f.GetResult()
    assert r.success and not msgs.errors and not msgs.warnings
    # ParaView's progress bar shows the algorithm's progress text: the stage under way, also once the bar (the
    # cells repaired) is full; the text is cleared at the end
    words = "untangling|smoothing|raising the quality|vertex steps|joint steps|standing quads back up"
    assert any(p == 1.0 and t and re.fullmatch(rf"hexsos repair: ({words})[a-z ,]*, \d+ s", t) for p, t in seen), seen
    assert seen[0] == (0.0, None) and f.GetProgressText() is None
    out = f.GetOutputDataObject(0)
    types_in = np.array([damaged.GetCellType(i) for i in range(damaged.GetNumberOfCells())])
    types_out = np.array([out.GetCellType(i) for i in range(out.GetNumberOfCells())])
    # voxels are written as hexahedra (their points moved), everything else keeps its type
    assert types_out.tolist() == np.where(types_in == VOXEL, HEX, types_in).tolist()
    status = cell_array(out, "hexsos_status")
    assert (status[(types_in == HEX) | (types_in == VOXEL)] == 1).all()
    assert status[types_in == TETRA].tolist() == [1]  # the tet is checked after the repair too
    assert status[types_in == QUAD].tolist() == [-2]  # a 2-D cell is not
    old = vtk_to_numpy(damaged.GetPoints().GetData()).astype(np.float64)
    new = vtk_to_numpy(out.GetPoints().GetData())
    assert new.dtype == np.float64 and np.array_equal(new, r.points)
    disp = vtk_to_numpy(out.GetPointData().GetArray("hexsos_displacement"))
    assert np.array_equal(disp, new - old) and np.abs(disp).max() > 0.01
    assert disp[-1].tolist() == [0.0, 0.0, 0.0]  # the tet's own point belongs to no hex
    # the output is proven valid by an independent check of its hexahedra, voxels now in hexahedron order
    hex_cells = np.flatnonzero(types_out == HEX)
    H = np.array([[out.GetCell(c).GetPointId(k) for k in range(8)] for c in hex_cells])
    recheck = hs.check(new, H)
    assert (recheck.status == 1).all()
    assert np.array_equal(cell_array(out, "hexsos_min_det")[hex_cells], recheck.min_det)
    # non-hex cells keep their connectivity; input arrays kept; the input untouched
    for c in np.flatnonzero((types_in != HEX) & (types_in != VOXEL)):
        ids_in = [damaged.GetCell(c).GetPointId(k) for k in range(damaged.GetCell(c).GetNumberOfPoints())]
        assert [out.GetCell(c).GetPointId(k) for k in range(len(ids_in))] == ids_in
    assert np.array_equal(cell_array(out, "material"), cell_array(damaged, "material"))
    assert out.GetPointData().GetArray("temperature") is not None
    assert out.GetFieldData().GetAbstractArray("note").GetValue(0) == "kept"
    assert vtk_to_numpy(out.GetFieldData().GetArray("hexsos_repair_success")).tolist() == [1]
    assert fingerprint(damaged) == before


def test_repair_options(damaged):
    f = HexSOSRepairFilter()
    assert (f.GetRepairMethod(), f.GetBoundary(), f.GetMinScaledJacobian(), f.GetFeatureAngle(), f.GetTimeLimit(),
            f.GetMaxIterations()) == ("optimize", "slide", 0.0, 45.0, 0.0, 0)
    assert (f.GetRho(), f.GetMargin(), f.GetPinBoundary(), f.GetPinNonHexPoints()) == (200.0, None, False, False)
    msgs = Messages(f)
    f.SetInputDataObject(0, damaged)
    # the default repair raises the quality: the field data says by how much, as an independent count finds
    assert f.Update() and not msgs.warnings
    r = f.GetResult()
    out = f.GetOutputDataObject(0)
    field = {k: vtk_to_numpy(out.GetFieldData().GetArray(f"hexsos_{k}"))[0]
             for k in ("min_sj_before", "min_sj_after", "p1_sj_after", "mean_sj_after")}
    types = np.array([out.GetCellType(i) for i in range(out.GetNumberOfCells())])
    new = vtk_to_numpy(out.GetPoints().GetData())
    H = np.array([[out.GetCell(c).GetPointId(k) for k in range(8)] for c in np.flatnonzero(types == HEX)])
    T = np.array([[out.GetCell(c).GetPointId(k) for k in range(4)] for c in np.flatnonzero(types == TETRA)])
    sj = hs.kernel.scaled_jacobian(new, [("hexahedron", H), ("tetra", T)])
    assert r.success and field["min_sj_after"] == pytest.approx(sj.min(), abs=1e-12)
    # (the free-standing hexes' corners are feature corners of the boundary: pinned, they bound the minimum)
    assert field["min_sj_after"] > 0 > field["min_sj_before"] and field["mean_sj_after"] >= field["p1_sj_after"]
    # a repair that cannot succeed: the free-standing inside-only hex has every vertex on the boundary
    f.SetBoundary("fixed")
    assert f.Update()
    assert len(msgs.warnings) == 1 and "not every" in msgs.warnings[0] and not f.GetResult().success
    out = f.GetOutputDataObject(0)
    assert (cell_array(out, "hexsos_status") == 0).sum() == f.GetResult().check.invalid.sum() > 0
    assert vtk_to_numpy(out.GetFieldData().GetArray("hexsos_repair_success")).tolist() == [0]
    mtime = f.GetMTime()
    f.SetBoundary("fixed")
    assert f.GetMTime() == mtime
    # the paper's repair and its own parameters
    f.SetRepairMethod("paper")
    f.SetBoundary("slide")  # the paper's method slides nothing: free
    f.SetMargin(0.01)
    f.SetRho(50.0)
    f.SetPinNonHexPoints(True)
    assert f.Update()
    r = f.GetResult()
    assert r.success and r.stats["margin"] == 0.01 and r.stats["rho"] == 50.0 and r.stats["method"] == "paper"
    disp = vtk_to_numpy(f.GetOutputDataObject(0).GetPointData().GetArray("hexsos_displacement"))
    tet, quad = damaged.GetCell(0), damaged.GetCell(28)
    for cell in (tet, quad):
        ids = [cell.GetPointId(k) for k in range(cell.GetNumberOfPoints())]
        assert not disp[ids].any()
    f.SetMargin(0.0)  # the kernel refuses it: a VTK error
    f.Update()
    assert msgs.errors and "margin" in msgs.errors[-1]
    with pytest.raises(ValueError, match="repair method"):
        f.SetRepairMethod("magic")


def test_repair_writes_voxels_as_hexahedra_beside_a_polyhedron():
    from vtkmodules.vtkCommonDataModel import vtkCellArray

    P, V, _ = voxel_block(push=0.5)
    n = P.shape[0]
    cube = np.array(VTK_CORNERS, dtype=np.float64) + [-3.0, 0.0, 0.0]
    grid = make_grid(np.concatenate([P, cube]), [(VOXEL, v) for v in V])
    faces = vtkCellArray()
    for f in ([0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]):
        faces.InsertNextCell(4, [n + i for i in f])
    try:
        grid.InsertNextCell(42, 8, [n + i for i in range(8)], faces)
    except TypeError:
        pytest.skip("this VTK takes polyhedron faces in another form")
    before = fingerprint(grid)
    f = HexSOSRepairFilter()
    f.SetInputDataObject(0, grid)
    assert f.Update() and f.GetResult().success
    out = f.GetOutputDataObject(0)
    assert [out.GetCellType(i) for i in range(9)] == [HEX] * 8 + [42]
    assert out.GetCell(8).GetNumberOfFaces() == 6
    assert (cell_array(out, "hexsos_status") == [1] * 8 + [-2]).all()
    assert fingerprint(grid) == before and grid.GetCellType(0) == VOXEL


def test_repair_flips_a_folded_cell_only_when_asked():
    """The middle hex of a column is written mirrored and lies inside the lowest (every cell valid by its own node
    order), beside a quad. Without FixOrientation the filter names it in a VTK error and outputs nothing; with it,
    the cell is flipped in the output (marked in hexsos_flipped), repaired and certified, and every shared face has
    its two hexes on opposite sides; the quad and the input are untouched."""
    from folds import face_sides
    from hexsos_plugins.examples import folded_column

    P, H = folded_column()
    grid = make_grid(np.concatenate([P, [[5.0, 0, 0], [6, 0, 0], [6, 1, 0]]]),
                     [(HEX, h) for h in H] + [(QUAD, [0, 16, 17, 18])])
    before = fingerprint(grid)
    f = HexSOSRepairFilter()
    msgs = Messages(f)
    assert f.GetFixOrientation() is False
    f.SetInputDataObject(0, grid)
    assert not f.Update()
    assert len(msgs.errors) == 1 and "(cells 1)" in msgs.errors[0] and "Fix Orientation" in msgs.errors[0]
    assert f.GetOutputDataObject(0).GetNumberOfCells() == 0
    f.SetFixOrientation(1)
    assert f.Update() and f.GetResult().success and len(msgs.errors) == 1
    out = f.GetOutputDataObject(0)
    conn = [[out.GetCell(c).GetPointId(k) for k in range(out.GetCell(c).GetNumberOfPoints())] for c in range(4)]
    assert conn[0] == H[0].tolist() and conn[2] == H[2].tolist() and conn[3] == [0, 16, 17, 18]
    assert conn[1] == H[1][[0, 3, 2, 1, 4, 7, 6, 5]].tolist()  # the mirror image: nodes 1 <-> 3, 5 <-> 7
    assert cell_array(out, "hexsos_flipped").tolist() == [0, 1, 0, 0]
    new = vtk_to_numpy(out.GetPoints().GetData())
    Hout = np.array(conn[:3])
    assert (hs.check(new, Hout).status == 1).all()
    for a, b in ((0, 1), (1, 2)):
        s, t = face_sides(new, Hout, a, b)
        assert s * t < 0  # unfolded
    assert fingerprint(grid) == before


def _checked(grid):
    """The check filter's output grid for ``grid`` and the VTK messages it sent (it must succeed)."""
    f = HexSOSCheckFilter()
    msgs = Messages(f)
    f.SetInputDataObject(0, grid)
    assert f.Update()
    return f.GetOutputDataObject(0), msgs


def test_check_marks_a_folded_cell_beside_its_verdicts():
    """The folded column (the middle hex written mirrored, lying inside the lowest) beside a quad: every hex valid by
    its own node order, so the check's status says valid; hexsos_mirrored marks the middle one, a VTK warning and
    the summary name it. The same column right-handed and unfolded (the middle hex stacked on the lowest): nothing
    marked, no warning. The input is untouched either way."""
    from hexsos_plugins.examples import folded_column

    P, H = folded_column()
    pts = np.concatenate([P, [[5.0, 0, 0], [6, 0, 0], [6, 1, 0]]])
    grid = make_grid(pts, [(HEX, h) for h in H] + [(QUAD, [0, 16, 17, 18])])
    before = fingerprint(grid)
    out, msgs = _checked(grid)
    assert cell_array(out, "hexsos_status").tolist() == [1, 1, 1, -2]
    assert cell_array(out, "hexsos_mirrored").tolist() == [0, 1, 0, 0]
    assert not msgs.errors and len(msgs.warnings) == 1
    assert "(cells 1) are written in the mirrored node order" in msgs.warnings[0]
    summary = out.GetFieldData().GetAbstractArray("hexsos_summary").GetValue(0)
    assert "mirrored node order" in summary and "Fix Orientation" in summary
    assert fingerprint(grid) == before

    # unfolded: the middle hex right-handed, its top face pushed up so it sits on the lowest
    Q = pts.copy()
    mid = H[1][[0, 3, 2, 1, 4, 7, 6, 5]]
    Q[mid[4:]] = Q[mid[:4]] + [0, 0, 1.0]
    top = H[2]
    Q[top[4:]] = Q[top[:4]] + [0, 0, 1.0]
    out, msgs = _checked(make_grid(Q, [(HEX, H[0]), (HEX, mid), (HEX, H[2]), (QUAD, [0, 16, 17, 18])]))
    assert cell_array(out, "hexsos_status").tolist() == [1, 1, 1, -2]
    assert cell_array(out, "hexsos_mirrored").tolist() == [0, 0, 0, 0]
    assert not msgs.warnings and not msgs.errors


def test_single_type_grids_with_implicit_arrays():
    """VTK >= 9.4 may store a single-type grid with implicit offsets and a constant types array."""
    from vtkmodules.vtkCommonDataModel import vtkCellArray

    P, V, Hv = voxel_block(push=0.5)
    cells = vtkCellArray()
    if not hasattr(cells, "UseFixedSizeDefaultStorage"):
        pytest.skip("this VTK has no fixed-size cell storage")
    cells.UseFixedSizeDefaultStorage(8)
    for v in V:
        cells.InsertNextCell(8, [int(i) for i in v])
    grid = make_grid(P, [])
    grid.SetCells(VOXEL, cells)
    expected = hs.check(P, Hv)
    out = run_check(grid).GetOutputDataObject(0)
    assert np.array_equal(cell_array(out, "hexsos_min_det"), expected.min_det)
    f = HexSOSRepairFilter()
    f.SetInputDataObject(0, grid)
    assert f.Update() and f.GetResult().success
    out = f.GetOutputDataObject(0)
    assert {out.GetCellType(i) for i in range(8)} == {HEX}
    assert {grid.GetCellType(i) for i in range(8)} == {VOXEL}


def test_a_hexahedron_without_8_points_is_an_error():
    P, H = structured_grid(1)
    f = HexSOSCheckFilter()
    msgs = Messages(f)
    f.SetInputDataObject(0, make_grid(P, [(HEX, H[0][:7])]))
    assert not f.Update()
    assert "7 points: expected 8" in msgs.errors[0]


# ------------------------------------------------------------------------------------------------------
# a real pipeline with files
# ------------------------------------------------------------------------------------------------------


def test_reader_filter_writer_round_trip_keeps_the_arrays(mixed, tmp_path):
    src, dst, folds_file = tmp_path / "in.vtu", tmp_path / "checked.vtu", tmp_path / "folds.vtp"
    w = vtkXMLUnstructuredGridWriter()
    w.SetFileName(str(src))
    w.SetInputData(mixed["grid"])
    assert w.Write() == 1
    reader = vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(src))
    f = HexSOSCheckFilter()
    f.SetInputConnection(reader.GetOutputPort())
    w1 = vtkXMLUnstructuredGridWriter()
    w1.SetFileName(str(dst))
    w1.SetInputConnection(f.GetOutputPort(0))
    w2 = vtkXMLPolyDataWriter()
    w2.SetFileName(str(folds_file))
    w2.SetInputConnection(f.GetOutputPort(1))
    assert w1.Write() == 1 and w2.Write() == 1

    back = vtkXMLUnstructuredGridReader()
    back.SetFileName(str(dst))
    back.Update()
    got = back.GetOutput()
    exp = mixed["expected"]
    for name, values in mixed["by_cell"].items():
        arr = cell_array(got, name)
        assert arr.dtype == np.asarray(values).dtype
        assert np.array_equal(arr, values, equal_nan=True), name
    assert np.array_equal(cell_array(got, "material"), cell_array(mixed["grid"], "material"))
    assert [got.GetCellType(i) for i in range(got.GetNumberOfCells())] == mixed["types"].tolist()
    fr = vtkXMLPolyDataReader()
    fr.SetFileName(str(folds_file))
    fr.Update()
    assert fr.GetOutput().GetNumberOfPoints() == int((mixed["by_cell"]["hexsos_status"] == 0).sum())
    assert fr.GetOutput().GetPointData().GetArray("hexsos_invalid_inside_only") is not None


# ------------------------------------------------------------------------------------------------------
# how ParaView finds the dependencies
# ------------------------------------------------------------------------------------------------------


def test_dependency_paths_order_and_record(tmp_path, monkeypatch, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    monkeypatch.setenv("HEXSOS_PYTHONPATH", os.pathsep.join([str(a), str(tmp_path / "missing"), str(b)]))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.delenv("VIRTUAL_ENV", raising=False)
    paths = plugin.dependency_paths()
    root = os.path.dirname(os.path.dirname(os.path.abspath(plugin.__file__)))
    assert paths[:2] == [str(a), str(b)]  # the environment variable first, missing directories dropped
    if os.path.isdir(os.path.join(root, "hexsos_plugins")):
        assert paths[2] == root
    assert plugin.main(["--record"]) == 0
    recorded = (tmp_path / "config" / "hexsos" / "paraview-paths.txt").read_text().splitlines()
    assert recorded[0].startswith("#") and len(recorded) > 1
    assert set(recorded[1:]) <= set(plugin.dependency_paths())
    capsys.readouterr()
    assert plugin.main([]) == 0
    text = capsys.readouterr().out
    assert "PV_PLUGIN_PATH=" in text and "HEXSOS_PYTHONPATH=" in text and "paraview_compat" in text


def test_safe_step_filter_in_plain_vtk():
    """HexSOSSafeStepFilter on a grid of hexes and a tet with a 2-component displacement: each checked cell gets
    its safe fraction (the kernel's), the tet too; the witness vertex lies in the moved grid; a missing array is
    a VTK error with empty outputs."""
    from vtk_filter import HexSOSSafeStepFilter

    P, H = structured_grid(3)
    P = np.concatenate([P, [[5, 0, 0], [6, 0, 0], [5, 1, 0], [5, 0, 1]]])
    centre = int(np.argmin(np.linalg.norm(P[:-4] - 0.5, axis=1)))
    D2 = np.zeros((len(P), 2))
    D2[centre] = [0.9, 0.9]  # pushed across its neighbours in the plane
    cells = [(HEX, h) for h in H] + [(QUAD, [0, 1, 2, 3])] + [(TETRA, [len(P) - 4 + i for i in range(4)])]
    grid = make_grid(P, cells, point_arrays={"u": D2})
    f = HexSOSSafeStepFilter()
    f.SetDisplacement("u")
    f.SetInputDataObject(0, grid)
    assert f.Update()
    D = np.column_stack([D2, np.zeros(len(P))])
    expected = hs.safe_step(P, [("hexahedron", H), ("tetra", [[len(P) - 4 + i for i in range(4)]])], D)
    got = vtk_to_numpy(f.GetOutputDataObject(0).GetCellData().GetArray("hexsos_safe_step"))
    assert 0 < expected.t < 1
    assert np.array_equal(got[: len(H)], expected.cell_t[: len(H)]) and np.isnan(got[len(H)])
    assert got[-1] == 1.0
    w = f.GetOutputDataObject(1)
    assert w.GetNumberOfPoints() == 1
    assert vtk_to_numpy(w.GetPointData().GetArray("hexsos_cell_id"))[0] == expected.witness["cell"]
    f.SetDisplacement("nope")
    assert not f.Update()
    assert "'nope'" in f.GetLastMessage() and f.GetOutputDataObject(0).GetNumberOfCells() == 0


def test_a_cell_written_twice_is_named_in_the_summary_and_both_copies_checked():
    """A hex written again (as a Gmsh MSH 2 file of a volume in two physical groups has every cell twice): both
    copies are checked and valid, and the summary names the copy; without it the summary says nothing of copies."""
    P, H = structured_grid(2)
    out = run_check(make_grid(P, [(HEX, h) for h in H] + [(HEX, H[3][[1, 2, 3, 0, 5, 6, 7, 4]])])).GetOutputDataObject(0)
    assert cell_array(out, "hexsos_status").tolist() == [1] * 9
    summary = out.GetFieldData().GetAbstractArray("hexsos_summary").GetValue(0)
    assert "1 cell names the same points as an earlier cell (cells 8; cell 8 names those of cell 3)" in summary
    plain = run_check(make_grid(P, [(HEX, h) for h in H])).GetOutputDataObject(0)
    assert "repeated" not in plain.GetFieldData().GetAbstractArray("hexsos_summary").GetValue(0)
