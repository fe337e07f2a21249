"""VTK XML ``.vtu`` and ASCII legacy ``.vtk`` through VTK's own readers, where ``vtk`` is importable.

Measured (``python -m comparison.bench_read``): on a 2M-hex ``.vtu`` VTK's reader takes about 60% of meshio's time
at less than half its peak memory; on ASCII legacy files about half of meshio's time. (On *binary* legacy files
meshio is faster, so they are not read here.) ``vtk`` is imported inside :func:`read_vtk_api` only, never when
hexsos is imported: ParaView loads hexsos beside its own VTK.

What it returns is what meshio returns for the same file (tested), except for the node order of linear wedges,
which is the file's (VTK's) here and meshio's mirror there (see :mod:`hexsos_plugins.io.meshio_conventions`):

* points as float64 (N, 3); cell blocks per run of one cell type (:func:`.legacy_vtk.vtk_blocks`: pixels as
  quads, voxels as ``voxel``, 8-node cells typed 10 as hexahedra);
* point, cell and field data by name, shape (n,) for one component, (n, k) for k.

Any message VTK's readers log (they are captured, never printed), a cell type outside the fixed-size linear and
quadratic ones, VTK's Lagrange cells of orders 3-5 and polygons (polyhedra, strips, Lagrange cells of other
orders), or a non-numeric array makes it decline, and the next reader (meshio, then hexsos's tolerant legacy
reader) is tried. VTK's readers hand Lagrange hexahedra of old files over in the current node order: they are
taken as they come.
"""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from .common import ParseError
from ..meshio_conventions import shorten

__all__ = ["read_vtk_api", "vtk_available"]

_AVAILABLE = None


def vtk_available() -> bool:
    """Can VTK's readers be imported here? (Imports them once.)"""
    global _AVAILABLE
    if _AVAILABLE is None:
        try:
            import vtkmodules.vtkIOLegacy  # noqa: F401
            import vtkmodules.vtkIOXML  # noqa: F401
            from vtkmodules.util import numpy_support  # noqa: F401

            _AVAILABLE = True
        except Exception:
            _AVAILABLE = False
    return _AVAILABLE


def _array(vtk_array, what):
    from vtkmodules.util.numpy_support import vtk_to_numpy

    if vtk_array is None or not vtk_array.IsA("vtkDataArray"):
        raise ParseError(f"{what} is not a numeric array")
    arr = np.array(vtk_to_numpy(vtk_array))
    if arr.ndim == 2 and arr.shape[1] == 1:
        arr = arr[:, 0]
    return arr


def _arrays(data, what) -> dict:
    out = {}
    for i in range(data.GetNumberOfArrays()):
        abstract = data.GetAbstractArray(i)
        name = abstract.GetName() if abstract is not None else None
        if not name:
            raise ParseError(f"{what} array {i} has no name")
        out[name] = _array(data.GetArray(i), f"{what} array {name!r}")
    return out


def read_vtk_api(path, *, legacy: bool) -> meshio.Mesh:
    """Read ``path`` (``.vtu``, or ASCII legacy ``.vtk`` with ``legacy=True``) with VTK's reader."""
    if not vtk_available():
        raise ParseError("VTK's readers are not available (pip install vtk)")
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkOutputWindow, vtkStringOutputWindow

    from .legacy_vtk import check_data_lengths, vtk_blocks

    if legacy:
        from vtkmodules.vtkIOLegacy import vtkUnstructuredGridReader as Reader
    else:
        from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridReader as Reader
    previous = vtkOutputWindow.GetInstance()
    window = vtkStringOutputWindow()
    vtkOutputWindow.SetInstance(window)
    try:
        reader = Reader()
        reader.SetFileName(str(Path(path)))
        if legacy:
            reader.ReadAllScalarsOn()
            reader.ReadAllVectorsOn()
            reader.ReadAllTensorsOn()
            reader.ReadAllFieldsOn()
            reader.ReadAllNormalsOn()
            reader.ReadAllTCoordsOn()
            reader.ReadAllColorScalarsOn()
        reader.Update()
        said = window.GetOutput().strip()
        grid = reader.GetOutput()
        if said or reader.GetErrorCode() or grid is None:
            raise ParseError("VTK: " + shorten(said or "the reader failed", 200))
        if grid.GetNumberOfPoints() == 0 or grid.GetPoints() is None:
            raise ParseError("VTK read no points")
        points = np.array(vtk_to_numpy(grid.GetPoints().GetData()), dtype=np.float64)
        cell_array = grid.GetCells()
        offsets = np.array(vtk_to_numpy(cell_array.GetOffsetsArray()), dtype=np.int64)
        conn = vtk_to_numpy(cell_array.GetConnectivityArray())
        conn = conn.astype(np.int64, copy=False)
        types = np.array(vtk_to_numpy(grid.GetCellTypesArray() if not hasattr(grid, "GetCellTypes")
                                      else grid.GetCellTypes()), dtype=np.int64)
        point_data = _arrays(grid.GetPointData(), "point data")
        cell_data = _arrays(grid.GetCellData(), "cell data")
        field_data = _arrays(grid.GetFieldData(), "field data")
    finally:
        vtkOutputWindow.SetInstance(previous)
    if len(types) != len(offsets) - 1:
        raise ParseError(f"VTK returned {len(types)} cell types for {len(offsets) - 1} cells")
    check_data_lengths(point_data, len(points), cell_data, len(types))
    cells, cd = vtk_blocks(conn, offsets, types, cell_data)
    mesh = meshio.Mesh.__new__(meshio.Mesh)
    mesh.points, mesh.cells = points, cells
    mesh.point_data, mesh.cell_data, mesh.field_data = point_data, cd, field_data
    mesh.point_sets, mesh.cell_sets, mesh.gmsh_periodic, mesh.info = {}, {}, None, None
    return mesh
