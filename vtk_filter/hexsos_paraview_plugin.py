"""hexsos as VTK filters and as a ParaView plugin (this one file is both).

Plain VTK (PyPI ``vtk`` >= 9.2; ParaView is not needed)::

    from vtk_filter import HexSOSCheckFilter
    f = HexSOSCheckFilter()
    f.SetInputDataObject(0, grid)          # a vtkUnstructuredGrid (or SetInputConnection)
    f.SetMethod("auto")                     # "auto" | "sos"
    f.Update()
    checked = f.GetOutputDataObject(0)      # the grid with the hexsos_* cell arrays
    folds = f.GetOutputDataObject(1)        # vtkPolyData: where each invalid hex folds
    f.GetResult()                           # the kernel's CheckResult (counts, summary())

ParaView (>= 5.10): load this file with Tools > Manage Plugins > Load New, or put the directory that holds
it on ``PV_PLUGIN_PATH``. The filters "HexSOS Check" and "HexSOS Repair" appear under Filters > Mesh Quality
(``paraview.simple.HexSOSCheck`` / ``HexSOSRepair`` in Python). ParaView loads *every* ``.py`` file of a
``PV_PLUGIN_PATH`` directory as a plugin: that is why the filters live in this file and why
``vtk_filter/__init__.py`` only defines lazy attributes (loading it registers nothing and runs no code).

How ParaView's Python finds the kernel and its dependencies (numpy, scipy, clarabel, meshio). ``hexsos paraview``
(:mod:`hexsos_plugins.cli.doors`) starts ParaView with this plugin loaded and hands it the ``sys.path`` of the
Python it runs in: nothing to set. Loaded any other way (by hand in the GUI, ``PV_PLUGIN_PATH``, ``LoadPlugin``
in a script) this file *appends* (never prepends: a virtual environment first on ``sys.path`` makes ParaView
load PyPI's ``vtkmodules`` and crash) to ``sys.path``, in this order, the directories that exist of

1. ``HEXSOS_PYTHONPATH`` (``os.pathsep``-separated), e.g. the site-packages of the Python where
   ``pip install hexsos`` ran;
2. the directory that holds the ``vtk_filter`` package this file belongs to, if it also holds
   ``hexsos_plugins`` (a repository checkout, or site-packages itself for a regular install);
3. ``$VIRTUAL_ENV/lib/pythonX.Y/site-packages`` when ParaView runs inside an activated virtual environment
   with ParaView's Python version X.Y;
4. the directories recorded by ``python -m vtk_filter.hexsos_paraview_plugin --record`` (run with the Python
   where hexsos is installed) in ``$XDG_CONFIG_HOME/hexsos/paraview-paths.txt`` (default ``~/.config``);
5. the environment in which a ``hexsos`` command last ran with ParaView's Python version X.Y: every ``hexsos``
   command records its environment (Python version, executable, ``sys.path``) in
   ``$XDG_CONFIG_HOME/hexsos/environments.json`` (see :func:`recorded_environments`).

ParaView's own numpy, scipy and VTK stay first. The compiled dependencies (clarabel) must be built for
ParaView's Python version: when the kernel cannot be imported, the error names the Python versions hexsos was
recorded for and ParaView's. ``python -m vtk_filter.hexsos_paraview_plugin`` (or ``hexsos paraview
--print-env``) prints the environment lines to use. The kernel is imported lazily, on the first execution, so
ParaView starts fast and a missing dependency is reported as a VTK error that names what to set.

Debian's ParaView 5.11 on Python 3.11 cannot load any Python plugin (its loader imports
``inspect.getargspec``, removed in Python 3.11) unless ``inspect.getargspec = inspect.getfullargspec`` ran
first: ``hexsos paraview`` does it; in ``pvpython`` scripts do it before ``LoadPlugin``; for the GUI started
by hand and ``PV_PLUGIN_PATH`` put ``vtk_filter/paraview_compat`` (its ``usercustomize.py`` does it) on
``PYTHONPATH``.
"""

from __future__ import annotations

import inspect
import os
import sys
import time

if not hasattr(inspect, "getargspec"):  # ParaView 5.11's decorators call it (Python >= 3.11 removed it)
    inspect.getargspec = inspect.getfullargspec

import numpy as np
from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray, vtk_to_numpy
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase
from vtkmodules.vtkCommonCore import (
    VTK_UNSIGNED_CHAR,
    vtkCommand,
    vtkDataArray,
    vtkObject,
    vtkOutputWindow,
    vtkPoints,
    vtkStringArray,
    vtkVersion,
)
from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkDataObject, vtkPolyData, vtkUnstructuredGrid

try:  # the decorators exist only inside ParaView; without it they do nothing
    from paraview.util.vtkAlgorithm import smdomain, smhint, smproperty, smproxy

    IN_PARAVIEW = True
except ImportError:
    IN_PARAVIEW = False

    class _NoDecorators:
        """Stands for ParaView's ``smproxy``/``smproperty``/``smdomain``/``smhint``: every decorator is a no-op."""

        def __getattr__(self, name):
            def factory(*args, **kwargs):
                return lambda obj: obj

            return factory

    smproxy = smproperty = smdomain = smhint = _NoDecorators()

__all__ = [
    "HexSOSCheckFilter",
    "HexSOSRepairFilter",
    "VTK_HEXAHEDRON",
    "VTK_VOXEL",
    "STATUS_NOT_A_HEX",
    "dependency_paths",
    "recorded_environments",
    "open_checked",
    "IN_PARAVIEW",
]

paraview_plugin_name = "HexSOS"
paraview_plugin_version = "0.1"

#: VTK cell types checked: hexahedra, and voxels (converted to hexahedron node order for the kernel).
VTK_HEXAHEDRON = 12
VTK_VOXEL = 11
#: ``hexsos_status`` of a cell that is not a hexahedron (the kernel's verdicts are 1, 0, -1).
STATUS_NOT_A_HEX = -2

_HERE = os.path.dirname(os.path.abspath(__file__))
_RECORD_NAME = os.path.join("hexsos", "paraview-paths.txt")
#: Written by every ``hexsos`` command (``hexsos_plugins.cli.doors.record_environment``), read here.
_ENVIRONMENTS_NAME = os.path.join("hexsos", "environments.json")


# ----------------------------------------------------------------------------------------------------
# Where ParaView's Python finds hexsos_plugins and its dependencies
# ----------------------------------------------------------------------------------------------------


def _config_file(name) -> str:
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return os.path.join(base, name)


def _record_file() -> str:
    return _config_file(_RECORD_NAME)


def _recorded_paths() -> list:
    try:
        with open(_record_file(), encoding="utf-8") as fh:
            return [line.strip() for line in fh if line.strip() and not line.lstrip().startswith("#")]
    except OSError:
        return []


def _minor(version) -> str:
    """'3.11' of '3.11.7' (or of '3.11')."""
    return ".".join(str(version).split(".")[:2])


def _this_python() -> str:
    return f"{sys.version_info[0]}.{sys.version_info[1]}"


def recorded_environments() -> list:
    """The environments ``hexsos`` commands ran in, most recent first, as recorded in
    ``$XDG_CONFIG_HOME/hexsos/environments.json`` (default ``~/.config``).

    Each is a dict with at least ``python`` (the version, e.g. ``"3.11.7"``), ``executable`` and ``paths``
    (the directories that Python imports hexsos and its dependencies from). A missing or unreadable file, or
    entries of another shape, count as nothing recorded.
    """
    import json

    try:
        with open(_config_file(_ENVIRONMENTS_NAME), encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError):
        return []
    entries = data.get("environments", []) if isinstance(data, dict) else []
    return [e for e in entries if isinstance(e, dict) and isinstance(e.get("python"), str)
            and isinstance(e.get("paths"), list) and all(isinstance(p, str) for p in e["paths"])]


def _recorded_environment():
    """The most recent recorded environment with this Python's major.minor version, or None."""
    for env in recorded_environments():
        if _minor(env["python"]) == _this_python():
            return env
    return None


def dependency_paths() -> list:
    """The directories this plugin appends to ``sys.path`` inside ParaView, in order (see the module's doc)."""
    paths = [p for p in os.environ.get("HEXSOS_PYTHONPATH", "").split(os.pathsep) if p]
    root = os.path.dirname(_HERE)
    if os.path.isdir(os.path.join(root, "hexsos_plugins")):
        paths.append(root)
    venv = os.environ.get("VIRTUAL_ENV")
    if venv:
        paths.append(os.path.join(venv, "lib", f"python{sys.version_info[0]}.{sys.version_info[1]}", "site-packages"))
    paths += _recorded_paths()
    env = _recorded_environment()
    if env is not None:
        paths += env["paths"]
    seen, out = set(), []
    for p in paths:
        p = os.path.abspath(os.path.expanduser(p))
        if p not in seen and os.path.isdir(p):
            seen.add(p)
            out.append(p)
    return out


def version_note() -> str:
    """What the recorded environments say about Python versions, when none matches this Python ('' if one does)."""
    envs = recorded_environments()
    if not envs:
        return ("no hexsos command has recorded its environment yet (run any 'hexsos' command once, e.g. "
                "'hexsos demo', with the Python where hexsos is installed)")
    if _recorded_environment() is not None:
        return ""
    others = ", ".join(f"Python {e['python']} ({e.get('executable', '?')})" for e in envs[:3])
    return (f"hexsos was recorded for {others}, but ParaView runs Python {sys.version.split()[0]}: the compiled "
            f"dependencies (clarabel) load only in the Python version they were installed for; install hexsos "
            f"into a Python {_this_python()} environment and run 'hexsos' there once, or start ParaView with "
            f"'hexsos paraview'")


def _append_dependency_paths() -> list:
    added = []
    for p in dependency_paths():
        if p not in sys.path:
            sys.path.append(p)  # APPEND: ParaView's own vtkmodules and numpy must stay first
            added.append(p)
    return added


if IN_PARAVIEW:
    _append_dependency_paths()


class _KernelUnavailable(Exception):
    pass


def _kernel(*submodules):
    """The hexsos kernel package, imported on first use with ``submodules`` and the dependencies it may need
    (a missing one is reported now, with what to set, rather than in the middle of a check)."""
    import importlib

    try:
        import hexsos_plugins

        for name in ("scipy.optimize", "clarabel") + tuple(f"hexsos_plugins.{m}" for m in submodules):
            importlib.import_module(name)
    except ImportError as exc:
        note = version_note()
        raise _KernelUnavailable(
            f"cannot import the hexsos kernel in this Python {sys.version.split()[0]} ({sys.executable}): "
            f"{type(exc).__name__}: {exc}. " + (note + ". " if note else "")
            + "Start ParaView with 'hexsos paraview', or set HEXSOS_PYTHONPATH to the site-packages of the Python "
            f"where hexsos is installed (same Python version); searched: {dependency_paths() or 'nothing'}"
        ) from exc
    return hexsos_plugins


# ----------------------------------------------------------------------------------------------------
# VTK <-> arrays
# ----------------------------------------------------------------------------------------------------

_VTK_VERSION = (vtkVersion.GetVTKMajorVersion(), vtkVersion.GetVTKMinorVersion())


def _to_numpy(arr) -> np.ndarray:
    """A numpy view (or, for implicit/non-contiguous VTK arrays, a copy) of a vtkDataArray."""
    try:
        return vtk_to_numpy(arr)
    except Exception:  # implicit arrays (fixed-size cell storage, constant types) have no raw buffer
        copy = vtkDataArray.CreateDataArray(arr.GetDataType())
        copy.DeepCopy(arr)
        return vtk_to_numpy(copy).copy()


def _cell_types(grid) -> np.ndarray:
    """The VTK cell type of every cell, (C,) uint8."""
    if grid.GetNumberOfCells() == 0:
        return np.zeros(0, dtype=np.uint8)
    # VTK >= 9.6 returns the per-cell array from GetCellTypes() (GetCellTypesArray is deprecated); before,
    # GetCellTypes(vtkCellTypes) filled the distinct types and GetCellTypesArray() was the per-cell array.
    arr = grid.GetCellTypes() if _VTK_VERSION >= (9, 6) else grid.GetCellTypesArray()
    return np.asarray(_to_numpy(arr), dtype=np.uint8)


def _cells(grid):
    """Offsets (C+1,) and connectivity of the grid's cells (numpy, possibly views)."""
    cells = grid.GetCells()
    if cells is None or grid.GetNumberOfCells() == 0:
        return np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return _to_numpy(cells.GetOffsetsArray()), _to_numpy(cells.GetConnectivityArray())


def _points(grid) -> np.ndarray:
    pts = grid.GetPoints()
    if pts is None:
        return np.zeros((0, 3))
    return _to_numpy(pts.GetData()).reshape(-1, 3)


def _cell_type_summary(types) -> str:
    if types.size == 0:
        return "no cells"
    values, counts = np.unique(types, return_counts=True)
    return ", ".join(f"{int(c)} of type {int(v)}" for v, c in zip(values, counts))


def _checkable(grid, elements):
    """The grid's 3-D cells hexsos checks, grouped by type (in first-appearance order of the types).

    Returns
    -------
    blocks : list of (cell_type, conn (m, n) int64 VTK order, cell_ids (m,) int64); voxels as hexahedra
    types : (C,) uint8, every cell's VTK type
    """
    types = _cell_types(grid)
    # (VTK type, node count) -> registry name: VTK's Lagrange cells (71, 72, 73) have one type id for every order
    by_vtk = {}
    for name, el in elements.ELEMENTS.items():
        if el.vtk_type >= 0:
            by_vtk.setdefault(el.vtk_type, {})[el.n_nodes] = name
    by_vtk[VTK_VOXEL] = {8: "voxel"}
    present = [int(t) for t in dict.fromkeys(types.tolist()) if int(t) in by_vtk]
    if not present:
        return [], types
    offsets, conn = _cells(grid)
    offsets = np.asarray(offsets, dtype=np.int64)
    conn = np.asarray(conn, dtype=np.int64)
    blocks = []
    for vt in present:
        ids = np.flatnonzero(types == vt).astype(np.int64)
        sizes = offsets[ids + 1] - offsets[ids]
        for size in dict.fromkeys(sizes.tolist()):
            name = by_vtk[vt].get(int(size))
            if name is None:
                bad = int(ids[np.flatnonzero(sizes == size)[0]])
                want = " or ".join(str(k) for k in sorted(by_vtk[vt]))
                raise ValueError(f"cell {bad} is of VTK type {vt} with {int(size)} points: expected {want}")
            el = elements.ELEMENTS["hexahedron" if name == "voxel" else name]
            cell_ids = ids[sizes == size]
            H = conn[offsets[cell_ids][:, None] + np.arange(el.n_nodes)]
            if name == "voxel":
                H = H[:, elements.VOXEL_TO_VTK]
            blocks.append(("hexahedron" if name == "voxel" else name, H, cell_ids))
    return blocks, types


def _vtk_array(name, values):
    arr = numpy_to_vtk(np.ascontiguousarray(values), deep=1)
    arr.SetName(name)
    return arr


def _spread(values, cell_ids, n_cells, fill):
    """Per-hex values (M, ...) as per-cell values (C, ...), ``fill`` on cells that are not hexahedra."""
    values = np.asarray(values)
    out = np.full((n_cells,) + values.shape[1:], fill, dtype=values.dtype)
    out[cell_ids] = values
    return out


def _add_result_cell_arrays(out, result, cell_ids):
    """Write ``result.cell_data()`` onto ``out``'s
    cell data, cell ``cell_ids[m]`` getting checked cell m's values."""
    n = out.GetNumberOfCells()
    cd = out.GetCellData()
    arrays = dict(result.cell_data())  # with hexsos_scaled_jacobian where the check computed it
    for name, values in arrays.items():
        values = np.asarray(values)
        fill = STATUS_NOT_A_HEX if np.issubdtype(values.dtype, np.integer) else np.nan
        cd.AddArray(_vtk_array(name, _spread(values, cell_ids, n, fill)))


def _add_other_cells(out, checked, cell_ids):
    """Status and min det J of the repair's other 3-D cells (``RepairResult.extra["other_cells"]``, one dict per
    block, blocks in ``cell_ids``' order) into the hex arrays :func:`_add_result_cell_arrays` wrote."""
    cd = out.GetCellData()
    for block, ids in zip(checked, cell_ids):
        for name, key in (("hexsos_status", "status"), ("hexsos_min_det", "min_det")):
            arr = cd.GetArray(name)
            for i, v in zip(ids.tolist(), np.asarray(block[key]).tolist()):
                arr.SetTuple1(i, v)


def _rewrite_cells(out, inp, types, rows):
    """Give ``out`` (a shallow copy of ``inp``) new cells: for each ``(cell_ids, conn)`` of ``rows`` those cells'
    points in that (VTK) order, voxels among them as hexahedra (type 12); every other cell as it was. New arrays
    throughout: the input's cells and types stay untouched."""
    offsets, conn = _cells(inp)
    offsets = np.array(offsets, dtype=np.int64)
    conn = np.array(conn, dtype=np.int64)
    new_types = np.array(types, dtype=np.uint8)
    for cell_ids, new in rows:
        conn[offsets[cell_ids][:, None] + np.arange(new.shape[1])] = new
        new_types[cell_ids[new_types[cell_ids] == VTK_VOXEL]] = VTK_HEXAHEDRON
    cells = vtkCellArray()
    cells.SetData(numpy_to_vtkIdTypeArray(offsets, deep=1), numpy_to_vtkIdTypeArray(conn, deep=1))
    cell_types = numpy_to_vtk(new_types, deep=1, array_type=VTK_UNSIGNED_CHAR)
    if hasattr(inp, "GetPolyhedronFaces") and inp.GetPolyhedronFaces() is not None:  # VTK >= 9.4
        out.SetPolyhedralCells(cell_types, cells, inp.GetPolyhedronFaceLocations(), inp.GetPolyhedronFaces())
    elif hasattr(inp, "GetFaces") and inp.GetFaces() is not None:  # VTK < 9.4
        out.SetCells(cell_types, cells, inp.GetFaceLocations(), inp.GetFaces())
    else:
        out.SetCells(cell_types, cells)


def _add_summary(data, name, text):
    arr = vtkStringArray()
    arr.SetName(name)
    arr.InsertNextValue(text)
    data.GetFieldData().AddArray(arr)


def _argmin_polydata(points, blocks, cell_ids, result, elements) -> vtkPolyData:
    """Vertices at x(argmin) of every invalid cell (where it folds), with its ids and values as point data."""
    bad = np.flatnonzero(result.status == 0)
    X = elements.world_points(points, [(t, c) for t, c, _ in blocks], result.argmin)[bad] if bad.size else \
        np.zeros((0, 3))
    poly = vtkPolyData()
    pts = vtkPoints()
    pts.SetDataTypeToDouble()
    pts.SetData(_vtk_array("Points", X.reshape(-1, 3)))
    poly.SetPoints(pts)
    verts = vtkCellArray()
    for i in range(bad.size):
        verts.InsertNextCell(1)
        verts.InsertCellPoint(i)
    poly.SetVerts(verts)
    pd = poly.GetPointData()
    pd.AddArray(_vtk_array("hexsos_cell_id", cell_ids[bad].astype(np.int64)))
    pd.AddArray(_vtk_array("hexsos_hex_id", bad.astype(np.int64)))
    pd.AddArray(_vtk_array("hexsos_min_det", result.min_det[bad]))
    pd.AddArray(_vtk_array("hexsos_argmin", result.argmin[bad].reshape(-1, 3)))
    pd.AddArray(_vtk_array("hexsos_corner_min_det", result.corner_min_det[bad]))
    pd.AddArray(_vtk_array("hexsos_invalid_inside_only", result.invalid_inside_only[bad].astype(np.int8)))
    pd.SetActiveScalars("hexsos_min_det")
    return poly


# ----------------------------------------------------------------------------------------------------
# The filters
# ----------------------------------------------------------------------------------------------------

_METHODS = ("auto", "sos")
_RELAXATIONS = ("quad2", "paper")
_REPAIR_METHODS = ("optimize", "paper")
_BOUNDARY_MODES = ("slide", "fixed", "free")


def _doc(text):
    """A <Documentation> element for a ParaView property (shown as its tooltip)."""
    from xml.sax.saxutils import escape

    return smdomain.xml(f"<Documentation>{escape(text)}</Documentation>")


def _string_list(*values):
    return smdomain.xml('<StringListDomain name="list">' + "".join(f'<String value="{v}"/>' for v in values)
                        + "</StringListDomain>")


class _HexSOSBase(VTKPythonAlgorithmBase):
    """Shared machinery: option storage with ``Modified()`` semantics, kernel access, error reporting."""

    def __init__(self, n_outputs):
        VTKPythonAlgorithmBase.__init__(self, nInputPorts=1, inputType="vtkUnstructuredGrid",
                                        nOutputPorts=n_outputs, outputType="vtkUnstructuredGrid")
        self._method = "auto"
        self._relaxation = "quad2"
        self._result = None
        self._last_message = None

    # --- options ---------------------------------------------------------------------------------
    def _set(self, attr, value):
        if getattr(self, attr) != value:
            setattr(self, attr, value)
            self.Modified()

    @staticmethod
    def _choice(name, value, choices):
        value = value.decode() if isinstance(value, bytes) else str(value)
        if value not in choices:
            raise ValueError(f"{name}: expected one of {list(choices)}, found {value!r}")
        return value

    def GetMethod(self) -> str:
        return self._method

    def GetRelaxation(self) -> str:
        return self._relaxation

    def GetResult(self):
        """The kernel's result of the last execution (``CheckResult`` / ``RepairResult``), None before or on error."""
        return self._result

    def GetLastMessage(self):
        """The error or warning text of the last execution (None if there was none)."""
        return self._last_message

    # --- messages (what vtkErrorMacro / vtkWarningMacro do) ----------------------------------------
    def _message(self, text, *, error):
        self._last_message = text
        event = vtkCommand.ErrorEvent if error else vtkCommand.WarningEvent
        if self.HasObserver(event):
            self.InvokeEvent(event, text)
        elif vtkObject.GetGlobalWarningDisplay():
            kind = "ERROR" if error else "Warning"
            full = f"{kind}: In {__file__}\n{type(self).__name__} ({hex(id(self))}): {text}\n\n"
            window = vtkOutputWindow.GetInstance()
            (window.DisplayErrorText if error else window.DisplayWarningText)(full)

    def _progress(self, done, total):
        self.UpdateProgress(min(1.0, done / total) if total else 1.0)

    def _prepare(self, grid, submodule):
        """The kernel and the grid's checkable cells (see :func:`_checkable`); raises what ``RequestData``
        reports."""
        kernel = _kernel("cells.elements", submodule)
        elements = sys.modules["hexsos_plugins.cells.elements"]
        blocks, types = _checkable(grid, elements)
        if not blocks:
            raise kernel.NoHexahedraError(
                f"the input has no 3-D cells hexsos checks (tetrahedra, pyramids, wedges, hexahedra, linear or "
                f"quadratic, and voxels): it has {_cell_type_summary(types)}")
        return kernel, elements, blocks, types

    def RequestData(self, request, inInfo, outInfo):
        self._result = None
        self._last_message = None
        inp = vtkUnstructuredGrid.GetData(inInfo[0], 0)
        outputs = [self.GetOutputData(outInfo, i) for i in range(self.GetNumberOfOutputPorts())]
        try:
            self._execute(inp, outputs)
        except Exception as exc:
            hexsos_error = getattr(sys.modules.get("hexsos_plugins"), "HexsosError", ())
            if not isinstance(exc, (_KernelUnavailable, ValueError) + ((hexsos_error,) if hexsos_error else ())):
                raise  # a bug: VTK prints the traceback
            for out in outputs:
                out.Initialize()
            self._message(f"hexsos: {exc}", error=True)
            return 0
        return 1


class HexSOSCheckFilter(_HexSOSBase):
    """Certified validity of every hexahedron of a vtkUnstructuredGrid (``hexsos_plugins.check``).

    Input: a vtkUnstructuredGrid. Cells of type VTK_HEXAHEDRON (12) are checked with their nodes in VTK
    order; VTK_VOXEL (11) cells are reordered to hexahedron order for the kernel (and stay voxels in the
    output: this filter never changes the input's structure). Every other cell (tets, wedges, pyramids,
    quads, quadratic hexes, polyhedra, ...) passes through untouched.

    Output port 0: the input grid (structure shallow-copied, every input array kept) with the kernel's cell
    arrays ``hexsos_min_det``, ``hexsos_lower_bound``, ``hexsos_argmin`` (3 components, u v w),
    ``hexsos_status`` (int8: 1 valid, 0 invalid, -1 undecided) and ``hexsos_corner_min_det``. Cells that are
    not hexahedra get NaN in the float arrays and -2 (:data:`STATUS_NOT_A_HEX`) in ``hexsos_status``. Each cell
    is judged as written; ``hexsos_mirrored`` (int8) marks 1 the cells written in the mirrored node order (a
    type all negative at its centres, or cells whose faces meet their neighbours' the wrong way round: they fold
    over them, whatever their own status; :func:`hexsos_plugins.io.handedness.mirrored_cells`), and a VTK
    warning names them. Field data ``hexsos_summary`` holds the kernel's summary text (and that warning's).

    Output port 1: a vtkPolyData with one vertex per invalid hex, at x(argmin) in world coordinates (where the
    hex folds), with point data ``hexsos_cell_id`` (cell index in the input grid), ``hexsos_hex_id`` (index
    among the hexahedra, in cell order), ``hexsos_min_det``, ``hexsos_argmin``, ``hexsos_corner_min_det`` and
    ``hexsos_invalid_inside_only`` (1: valid at all 8 corners, invalid inside: what corner checks miss).

    Options: ``SetMethod("auto" | "sos")`` and ``SetRelaxation("quad2" | "paper")``, passed to the kernel.

    Errors found while executing (a grid without hexahedra, a hexahedron without 8 points, non-finite
    coordinates, an option the kernel refuses, the kernel or a dependency missing from ParaView's Python) are
    reported the way ``vtkErrorMacro`` reports them: an ErrorEvent on this filter if someone observes it, else
    the VTK output window (ParaView's Output Messages). The request then fails (``RequestData`` returns 0, so
    ``Update()`` returns False and VTK adds its "returned failure for request" line) and the outputs are empty;
    nothing is raised to the caller. A setter given a value outside its choices raises ``ValueError`` at once.
    """

    def __init__(self):
        _HexSOSBase.__init__(self, 2)

    def FillOutputPortInformation(self, port, info):
        info.Set(vtkDataObject.DATA_TYPE_NAME(), "vtkUnstructuredGrid" if port == 0 else "vtkPolyData")
        return 1

    @smproperty.stringvector(name="Method", default_values="auto", number_of_elements=1)
    @_string_list(*_METHODS)
    @_doc("auto: Bernstein bounds and branch-and-bound, the SOS relaxation only where needed (fast, exact). "
          "sos: the SOS relaxation on every hex, as the paper (slow). Verdicts are proven either way.")
    def SetMethod(self, value):
        self._set("_method", self._choice("method", value, _METHODS))

    @smproperty.stringvector(name="Relaxation", default_values="quad2", number_of_elements=1)
    @_string_list(*_RELAXATIONS)
    @_doc("The SOS relaxation: quad2 (order 2 with quadratic box constraints, fast) or paper (the paper's).")
    def SetRelaxation(self, value):
        self._set("_relaxation", self._choice("relaxation", value, _RELAXATIONS))

    def _execute(self, inp, outputs):
        out, poly_out = outputs
        kernel, elements, blocks, _ = self._prepare(inp, "certify")
        P = _points(inp)
        cells = [(t, c) for t, c, _ in blocks]
        cell_ids = np.concatenate([ids for _, _, ids in blocks])
        self.UpdateProgress(0.0)
        result = kernel.check(P, cells, method=self._method, relaxation=self._relaxation, progress=self._progress,
                              jobs=0, quality=True)  # every core, as the command line; the scaled Jacobian too
        out.ShallowCopy(inp)
        _add_result_cell_arrays(out, result, cell_ids)
        mirrored, said = self._mirrored(P, cells)
        out.GetCellData().AddArray(_vtk_array("hexsos_mirrored", _spread(mirrored.astype(np.int8), cell_ids,
                                                                         out.GetNumberOfCells(), 0)))
        summary = result.summary()
        if said:
            said = (f"{said}. The cells are judged as written above; HexSOS Repair with Fix Orientation flips them "
                    "(hexsos_mirrored marks them)")
            summary += "\n" + said
        _add_summary(out, "hexsos_summary", summary)

        poly_out.ShallowCopy(_argmin_polydata(P, blocks, cell_ids, result, elements))
        self._result = result
        self.UpdateProgress(1.0)
        if said:
            self._message(f"hexsos: cells written in the mirrored node order: {said}", error=False)

    @staticmethod
    def _mirrored(P, cells):
        """The checked cells written in the mirrored node order (a bool mask in ``cells``' order) and the sentence
        naming them (:func:`hexsos_plugins.io.handedness.mirrored_cells`)."""
        from hexsos_plugins.io.handedness import mirrored_cells
        from hexsos_plugins.io.mesh import Mesh

        return mirrored_cells(Mesh.from_cells(P, cells), folded=True)  # every shared face read


class HexSOSRepairFilter(_HexSOSBase):
    """Repair the hexahedra of a vtkUnstructuredGrid with a certificate (``hexsos_plugins.repair``).

    Input: as :class:`HexSOSCheckFilter`. Output: the grid with repaired point coordinates (float64, so the
    certificate survives: rounding to float32 could undo a margin), every input array kept, plus

    * point data ``hexsos_displacement`` (3 components): new minus old coordinates (zero on points no hex
      moved);
    * the kernel's cell arrays after repair (``hexsos_min_det``, ``hexsos_status``, ...; NaN / -2 on cells
      that are not hexahedra), the certificate of the repaired mesh;
    * field data ``hexsos_repair_success`` (1 / 0) and ``hexsos_summary`` (the repair's summary text).

    Voxels are written as hexahedra (type 12, nodes reordered): once their points move they are no longer
    axis-aligned boxes, which is what VTK_VOXEL means to VTK (its interpolation, contouring and rendering
    assume it). Cell order and count are unchanged, so cell arrays still line up. Non-hex cells keep their
    type and connectivity; points they share with hexahedra move with the hexahedra unless
    ``SetPinNonHexPoints(True)``.

    Options: ``SetRepairMethod`` (``"optimize"``, default: untangle, raise the minimum scaled Jacobian, certify;
    ``"paper"``: the paper's Algorithms 1 and 2), ``SetBoundary`` (``"slide"``, default: boundary points stay on
    the input's boundary surface and features; ``"fixed"``; ``"free"``), ``SetMinScaledJacobian`` (target; 0:
    as high as it goes), ``SetFeatureAngle`` (45 degrees), ``SetTimeLimit`` (seconds, 0: none),
    ``SetMaxIterations`` (0: the method's default), ``SetPinBoundary`` (same as boundary "fixed"),
    ``SetPinNonHexPoints`` (keep points of non-hex cells fixed); for ``"paper"`` also ``SetRho`` (200) and
    ``SetMargin`` (relative margin > 0; None: the kernel's default 1e-3); ``SetMethod`` and ``SetRelaxation``
    for the kernel. Field data also holds the quality before and after: ``hexsos_min_sj_before`` /
    ``_after``, ``hexsos_p1_sj_after``, ``hexsos_mean_sj_after`` (Verdict's corner scaled Jacobian),
    ``hexsos_edge_ratio_after`` (the least shortest / longest edge of a hex), and with a sliding boundary
    ``hexsos_boundary_max_distance`` (the farthest boundary point from the input's surface). Cells written in
    the mirrored node order (a whole type, or cells whose faces meet their neighbours' the wrong way round: they
    fold over them) are an error naming them, unless ``SetFixOrientation(1)``: then they are flipped first, in
    the output too, and marked 1 in the cell array ``hexsos_flipped``.
    A repair that does not prove every cell valid still outputs the best mesh found, with a VTK warning.
    Errors are reported as by :class:`HexSOSCheckFilter`. ``AbortExecuteOn()`` stops between iterations.
    """

    def __init__(self):
        _HexSOSBase.__init__(self, 1)
        self._rho = 200.0
        self._margin = None
        self._pin_boundary = False
        self._max_iterations = 0
        self._pin_non_hex = False
        self._repair_method = "optimize"
        self._boundary = "slide"
        self._min_sj = 0.0
        self._feature_angle = 45.0
        self._time_limit = 0.0
        self._fix_orientation = False
        self._t0 = time.perf_counter()  # the start of the last repair (the progress text's seconds)

    @smproperty.stringvector(name="RepairMethod", label="Repair Method", default_values="optimize",
                             number_of_elements=1)
    @_string_list(*_REPAIR_METHODS)
    @_doc("optimize: untangle, raise the minimum scaled Jacobian, certify every cell; paper: the paper's "
          "Algorithms 1 and 2.")
    def SetRepairMethod(self, value):
        self._set("_repair_method", self._choice("repair method", value, _REPAIR_METHODS))

    def GetRepairMethod(self) -> str:
        return self._repair_method

    @smproperty.stringvector(name="Boundary", default_values="slide", number_of_elements=1)
    @_string_list(*_BOUNDARY_MODES)
    @_doc("slide: boundary points stay on the input's boundary surface, feature edges and corners kept; fixed; "
          "free (the paper's method knows fixed and free).")
    def SetBoundary(self, value):
        self._set("_boundary", self._choice("boundary", value, _BOUNDARY_MODES))

    def GetBoundary(self) -> str:
        return self._boundary

    @smproperty.doublevector(name="MinScaledJacobian", label="Min Scaled Jacobian", default_values=0.0,
                             number_of_elements=1)
    @smdomain.doublerange(min=0.0, max=0.99)
    @_doc("Stop raising the quality once every cell reaches this corner scaled Jacobian; 0: as high as it goes.")
    def SetMinScaledJacobian(self, value):
        v = float(value)
        if not 0.0 <= v < 1.0:
            raise ValueError(f"min scaled Jacobian: expected a number in [0, 1), found {value!r}")
        self._set("_min_sj", v)

    def GetMinScaledJacobian(self) -> float:
        return self._min_sj

    @smproperty.doublevector(name="FeatureAngle", label="Feature Angle", default_values=45.0, number_of_elements=1)
    @smdomain.doublerange(min=0.0, max=180.0)
    @_doc("Boundary slide: edges whose faces' normals differ by more than this (degrees) are feature edges.")
    def SetFeatureAngle(self, value):
        self._set("_feature_angle", float(value))

    def GetFeatureAngle(self) -> float:
        return self._feature_angle

    @smproperty.doublevector(name="TimeLimit", label="Time Limit", default_values=0.0, number_of_elements=1)
    @smdomain.doublerange(min=0.0)
    @_doc("Seconds for untangling and quality (0: no limit); the certificate always runs.")
    def SetTimeLimit(self, value):
        self._set("_time_limit", float(value))

    def GetTimeLimit(self) -> float:
        return self._time_limit

    @smproperty.stringvector(name="Method", default_values="auto", number_of_elements=1)
    @_string_list(*_METHODS)
    @_doc("How the argmin of each hex not proven valid is found: auto (exact, fast) or sos (the paper's).")
    def SetMethod(self, value):
        self._set("_method", self._choice("method", value, _METHODS))

    @smproperty.stringvector(name="Relaxation", default_values="quad2", number_of_elements=1)
    @_string_list(*_RELAXATIONS)
    @_doc("The SOS relaxation: quad2 or paper.")
    def SetRelaxation(self, value):
        self._set("_relaxation", self._choice("relaxation", value, _RELAXATIONS))

    @smproperty.doublevector(name="Rho", default_values=200.0, number_of_elements=1)
    @smdomain.doublerange(min=0.0)
    @_doc("Weight of the repaired hexes against the original positions (the paper's rho). Larger: faster, "
          "farther from the input.")
    def SetRho(self, value):
        self._set("_rho", float(value))

    def GetRho(self) -> float:
        return self._rho

    @smproperty.doublevector(name="Margin", default_values=1e-3, number_of_elements=1)
    @smdomain.doublerange(min=0.0)
    @_doc("Relative margin > 0: each repaired hex is pushed to det J >= margin * h^3 at its worst point "
          "(h: mean edge length). The kernel's default is 1e-3.")
    def SetMargin(self, value):
        self._set("_margin", None if value is None else float(value))

    def GetMargin(self):
        return self._margin

    @smproperty.intvector(name="PinBoundary", label="Pin Boundary", default_values=0, number_of_elements=1)
    @smdomain.xml('<BooleanDomain name="bool"/>')
    @_doc("Keep the vertices on the boundary of the hex mesh fixed.")
    def SetPinBoundary(self, value):
        self._set("_pin_boundary", bool(value))

    def GetPinBoundary(self) -> bool:
        return self._pin_boundary

    @smproperty.intvector(name="MaxIterations", label="Max Iterations", default_values=0, number_of_elements=1)
    @smdomain.intrange(min=0, max=1000)
    @_doc("Most outer iterations of the repair (0: the method's default); the best mesh seen is returned if not "
          "every cell is valid.")
    def SetMaxIterations(self, value):
        self._set("_max_iterations", int(value))

    def GetMaxIterations(self) -> int:
        return self._max_iterations

    @smproperty.intvector(name="PinNonHexPoints", label="Pin Non-Hex Points", default_values=0,
                          number_of_elements=1)
    @smdomain.xml('<BooleanDomain name="bool"/>')
    @_doc("Keep fixed the points that belong to cells other than hexahedra (tets, wedges, quads, ...).")
    def SetPinNonHexPoints(self, value):
        self._set("_pin_non_hex", bool(value))

    def GetPinNonHexPoints(self) -> bool:
        return self._pin_non_hex

    @smproperty.intvector(name="FixOrientation", label="Fix Orientation", default_values=0, number_of_elements=1)
    @smdomain.xml('<BooleanDomain name="bool"/>')
    @_doc("Flip the cells written in the mirrored node order before the repair (a cell whose faces meet its "
          "neighbours' the wrong way round folds over them, whatever its points' places); off: the repair names "
          "them and stops. Flipped cells are marked in the cell array hexsos_flipped.")
    def SetFixOrientation(self, value):
        self._set("_fix_orientation", bool(value))

    def GetFixOrientation(self) -> bool:
        return self._fix_orientation

    def _right_handed(self, P, blocks):
        """``blocks`` with the cells written in the mirrored node order flipped when FixOrientation is on (else
        an error naming them), and the ids of the cells flipped."""
        from hexsos_plugins.io.handedness import right_handed
        from hexsos_plugins.io.mesh import Mesh

        mesh, _, flip = right_handed(Mesh.from_cells(P, [(t, c) for t, c, _ in blocks]), self._fix_orientation,
                                     folded=True, name="the input",
                                     hint="Turn on the repair filter's Fix Orientation (SetFixOrientation(1)) to "
                                          "flip them")
        if not flip.any():
            return blocks, np.zeros(0, dtype=np.int64)
        ids = np.concatenate([ids for _, _, ids in blocks])
        return [(t, c, i) for (t, c), (_, _, i) in zip(mesh.cells, blocks)], ids[flip]

    def _abort(self, entry, points):
        """The repair's callback: names the stage under way for ParaView's progress bar (the bar's fraction
        counts the cells repaired: full long before the quality stages end) and stops on the abort button."""
        from hexsos_plugins.meshrepair import step_words

        self.SetProgressText(f"hexsos repair: {step_words(entry)}, {time.perf_counter() - self._t0:.0f} s")
        return bool(self.GetAbortExecute())

    def _execute(self, inp, outputs):
        (out,) = outputs
        _, _, blocks, types = self._prepare(inp, "meshrepair")
        from hexsos_plugins import repair
        from hexsos_plugins.meshrepair import door_boundary

        P = _points(inp)
        blocks, flipped = self._right_handed(P, blocks)
        hex_blocks = [(c, ids) for t, c, ids in blocks if t == "hexahedron"]
        from hexsos_plugins.meshrepair.curved import needs_curved

        # curved cells, or no hexahedra but tetrahedra / wedges: repair() moves them on det J's coefficients
        curved = self._repair_method == "optimize" and needs_curved(
            np.concatenate([c for c, _ in hex_blocks]) if hex_blocks else np.zeros((0, 8), dtype=np.int64),
            [(t, c) for t, c, _ in blocks if t != "hexahedron"])
        if not hex_blocks and not curved:
            raise ValueError(f"the input has no hexahedra to repair: it has {_cell_type_summary(types)}")
        H = np.concatenate([c for c, _ in hex_blocks]) if hex_blocks else np.zeros((0, 8), dtype=np.int64)
        cell_ids = np.concatenate([ids for _, ids in hex_blocks]) if hex_blocks else np.zeros(0, dtype=np.int64)
        others = [(t, c) for t, c, _ in blocks if t != "hexahedron"]
        pinned = None
        if self._pin_non_hex:
            other = np.flatnonzero((types != VTK_HEXAHEDRON) & (types != VTK_VOXEL))
            if other.size:
                offsets, conn = _cells(inp)
                offsets = np.asarray(offsets, dtype=np.int64)
                pinned = np.zeros(P.shape[0], dtype=bool)
                starts, stops = offsets[other], offsets[other + 1]
                idx = np.concatenate([np.arange(a, b) for a, b in zip(starts, stops)])
                pinned[np.asarray(conn, dtype=np.int64)[idx]] = True
        self.UpdateProgress(0.0)
        boundary = door_boundary(self._boundary, self._repair_method, self._pin_boundary)
        self._t0 = time.perf_counter()
        try:
            result = repair(P, H, cells=others or None, method=self._repair_method, boundary=boundary,
                            min_sj=self._min_sj or None, feature_angle=self._feature_angle,
                            time_limit=self._time_limit or None, rho=self._rho, margin=self._margin,
                            max_iter=self._max_iterations or None, kernel_method=self._method,
                            relaxation=self._relaxation, progress=self._progress, callback=self._abort,
                            pinned=pinned, jobs=1 if self._repair_method == "paper" else 0)  # paper: processes
        finally:
            self.SetProgressText(None)  # the next run's bar shows the filter's own name again
        out.ShallowCopy(inp)
        rows = []  # the cells with new node orders: voxels as hexahedra, flipped cells mirrored
        for _, c, ids in blocks:
            m = np.isin(ids, flipped) | (types[ids] == VTK_VOXEL)
            if m.any():
                rows.append((ids[m], c[m]))
        if rows:
            _rewrite_cells(out, inp, types, rows)
        if flipped.size:
            mark = np.zeros(len(types), dtype=np.int8)
            mark[flipped] = 1
            out.GetCellData().AddArray(_vtk_array("hexsos_flipped", mark))
        pts = vtkPoints()
        pts.SetDataTypeToDouble()
        pts.SetData(_vtk_array("Points", np.asarray(result.points, dtype=np.float64)))
        out.SetPoints(pts)
        out.GetPointData().AddArray(_vtk_array("hexsos_displacement", result.displacement))
        if result.stats.get("method") == "curved":  # one certificate over the hexes, then the other blocks
            _add_result_cell_arrays(out, result.check, np.concatenate(
                [cell_ids] + [ids for t, _, ids in blocks if t != "hexahedron"]))
        else:
            _add_result_cell_arrays(out, result.check, cell_ids)
            _add_other_cells(out, result.extra.get("other_cells", []),
                             [ids for t, _, ids in blocks if t != "hexahedron"])
        flag = vtkDataArray.CreateDataArray(6)  # VTK_INT
        flag.SetName("hexsos_repair_success")
        flag.InsertNextTuple1(1 if result.success else 0)
        out.GetFieldData().AddArray(flag)
        for key in ("min_sj_before", "min_sj_after", "p1_sj_after", "mean_sj_after", "edge_ratio_after",
                    "boundary_max_distance"):
            v = result.stats.get(key)
            if isinstance(v, (int, float)):
                arr = vtkDataArray.CreateDataArray(11)  # VTK_DOUBLE
                arr.SetName(f"hexsos_{key}")
                arr.InsertNextTuple1(float(v))
                out.GetFieldData().AddArray(arr)
        _add_summary(out, "hexsos_summary", result.summary())
        self._result = result
        self.UpdateProgress(1.0)
        if not result.success:
            self._message(f"hexsos: not every hex proven valid after repair: {result.message}", error=False)


# ----------------------------------------------------------------------------------------------------
# ParaView registration (no-ops without ParaView). The class decorators are applied as calls and their
# results dropped: ParaView's class decorators return a wrapper *function*, and the filters stay classes.
# ----------------------------------------------------------------------------------------------------


def _register(cls, name, label, help_text, output_ports):
    wrapped = smdomain.datatype(dataTypes=["vtkUnstructuredGrid"], composite_data_supported=False)(cls)
    wrapped = smproperty.input(name="Input", port_index=0)(wrapped)
    ports = "".join(f'<OutputPort name="{n}" index="{i}"/>' for i, n in enumerate(output_ports))
    wrapped = smproperty.xml(ports + f"<Documentation short_help=\"{help_text}\">{help_text}</Documentation>")(wrapped)
    wrapped = smhint.xml('<ShowInMenu category="Mesh Quality"/>')(wrapped)
    smproxy.filter(name=name, label=label, support_reload=False)(wrapped)


_register(HexSOSCheckFilter, "HexSOSCheck", "HexSOS Check",
          "Certified validity of every hexahedron: exact min det J, where it occurs, a proven verdict.",
          ["Checked Mesh", "Fold Points"])
_register(HexSOSRepairFilter, "HexSOSRepair", "HexSOS Repair",
          "Move the vertices as little as possible until every hexahedron is proven valid.",
          ["Repaired Mesh"])


# ----------------------------------------------------------------------------------------------------
# Inside ParaView: open meshes with "HexSOS Check" applied (what ``hexsos paraview`` shows)
# ----------------------------------------------------------------------------------------------------

#: How ``open_checked`` colours ``hexsos_status``: value, label, RGB.
STATUS_COLOURS = (
    (1, "valid", (0.75, 0.80, 0.90)),
    (0, "invalid", (0.90, 0.05, 0.05)),
    (-1, "undecided", (1.00, 0.60, 0.00)),
    (STATUS_NOT_A_HEX, "not checked", (0.50, 0.50, 0.50)),
)
#: The colour of the fold points (x(argmin) of every invalid hex).
FOLD_COLOUR = (0.0, 0.0, 0.0)
#: The colour of the cells written in the mirrored node order (``hexsos_mirrored``: they fold over their
#: neighbours, whatever their status), as the Gmsh panel draws them.
MIRRORED_COLOUR = (0.0, 0.35, 1.0)


def _status_counts(grid) -> dict:
    arr = grid.GetCellData().GetArray("hexsos_status") if grid is not None else None
    if arr is None:
        return {}
    values, counts = np.unique(_to_numpy(arr), return_counts=True)
    return {int(v): int(c) for v, c in zip(values, counts)}


def _show_cells_between(simple, source, view, label, array, low, high):
    """Show the cells of ``source`` whose cell array ``array`` lies in [low, high] (a Threshold named ``label``) in
    ``view``; returns the display."""
    cut = simple.Threshold(Input=source)
    simple.RenameSource(label, cut)
    cut.Scalars = ["CELLS", array]
    cut.LowerThreshold = low
    cut.UpperThreshold = high
    if "ThresholdMethod" in cut.ListProperties():  # ParaView >= 5.10
        cut.ThresholdMethod = "Between"
    return simple.Show(cut, view)


def _paint(shown, association, rgb):
    """Display ``shown`` in one solid colour ``rgb`` instead of by an array of its ``association`` ("CELLS",
    "POINTS"); returns it."""
    shown.ColorArrayName = [association, ""]
    shown.AmbientColor = list(rgb)
    shown.DiffuseColor = list(rgb)
    return shown


def _mirrored_count(grid) -> int:
    arr = grid.GetCellData().GetArray("hexsos_mirrored") if grid is not None else None
    return 0 if arr is None else int(np.count_nonzero(_to_numpy(arr)))


def _say_in_colour(simple, view, words, rgb):
    """``words`` in the upper left corner of ``view``, in colour ``rgb``: what a colour drawn apart from the
    status legend means."""
    text = simple.Text(Text=words)
    simple.RenameSource("hexsos: key", text)
    shown = simple.Show(text, view)
    shown.WindowLocation = "Upper Left Corner"
    shown.Color = list(rgb)
    shown.FontSize = 16
    shown.Bold = 1
    return shown


def _colour_by_status(simple, displays, view, counts):
    """One categorical colour map for ``hexsos_status`` on ``displays``; the legend lists the statuses present,
    with their number of cells."""
    lut = simple.GetColorTransferFunction("hexsos_status")
    lut.InterpretValuesAsCategories = 1
    present = [(v, label, rgb) for v, label, rgb in STATUS_COLOURS if counts.get(v)]
    lut.Annotations = [str(x) for v, label, _ in present for x in (v, f"{label} ({counts[v]})")]
    lut.IndexedColors = [c for _, _, rgb in present for c in rgb]
    for d in displays:
        simple.ColorBy(d, ("CELLS", "hexsos_status"))
        d.LookupTable = lut
    if displays:
        displays[0].SetScalarBarVisibility(view, True)
        bar = simple.GetScalarBar(lut, view)
        bar.Title = "hexsos_status"
        bar.ComponentTitle = ""
    return lut


def open_checked(paths, *, names=None, view=None, screenshot=None, size=(1280, 800)) -> dict:
    """Open each mesh file of ``paths`` in ParaView with "HexSOS Check" applied, and show the result.

    Runs inside ParaView (GUI or ``pvpython``; this plugin loaded). Each mesh is shown translucent and coloured
    by ``hexsos_status`` (:data:`STATUS_COLOURS`; the legend lists the statuses present, with their counts),
    its cells not proven valid opaque-ish on top (a Threshold), those written in the mirrored node order
    (``hexsos_mirrored``) solid blue (:data:`MIRRORED_COLOUR`), and the fold points (output port 1: x(argmin) of
    every invalid hex) as black spheres; the camera looks at everything obliquely. With
    ``screenshot`` the view is saved there as a PNG of ``size`` pixels (without the orientation axes).

    Returns a dict: ``meshes`` (per file: ``file``, ``cells``, ``valid``, ``invalid``, ``undecided``,
    ``not_checked``, ``invalid_inside_only``, ``fold_points``, ``mirrored``; or ``file`` and ``error`` when ParaView cannot
    read it or the check fails, with the filter's own message: the other files are still shown),
    ``screenshot``, ``plugin`` (this file) and ``kernel`` (the ``hexsos_plugins`` package ParaView's Python
    imported).
    """
    from paraview import simple

    names = list(names) if names is not None else [os.path.basename(p) for p in paths]
    view = view or simple.GetActiveViewOrCreate("RenderView")
    report = {"meshes": [], "screenshot": None, "plugin": os.path.abspath(__file__), "kernel": None}
    displays, total, last = [], {}, None
    for path, name in zip(paths, names):
        reader = simple.OpenDataFile(path)
        if reader is None:
            report["meshes"].append({"file": name, "error": f"{name}: ParaView has no reader for this file"})
            continue
        simple.RenameSource(name, reader)
        check = simple.HexSOSCheck(Input=reader)
        check.UpdatePipeline()
        algorithm = check.GetClientSideObject()  # this module's HexSOSCheckFilter (built-in session)
        result = algorithm.GetResult()
        if result is None:  # the filter said why (its message is in ParaView's Output Messages too)
            why = (algorithm.GetLastMessage() or "no result").replace("hexsos: ", "", 1)
            report["meshes"].append({"file": name, "error": f"{name}: HexSOS Check failed: {why}"})
            continue
        grid = algorithm.GetOutputDataObject(0)
        counts = _status_counts(grid)
        for v, c in counts.items():
            total[v] = total.get(v, 0) + c
        folds = algorithm.GetOutputDataObject(1)
        report["meshes"].append({
            "file": name, "cells": int(grid.GetNumberOfCells()), "valid": counts.get(1, 0),
            "invalid": counts.get(0, 0), "undecided": counts.get(-1, 0),
            "not_checked": counts.get(STATUS_NOT_A_HEX, 0),
            "invalid_inside_only": int(np.count_nonzero(getattr(result, "invalid_inside_only", ()))),
            "fold_points": int(folds.GetNumberOfPoints()),
            "mirrored": _mirrored_count(grid),
        })

        shown = simple.Show(check, view)
        shown.Opacity = 0.3
        displays.append(shown)
        if counts.get(0, 0) + counts.get(-1, 0):  # the cells not proven valid, on top
            bad_shown = _show_cells_between(simple, check, view, f"{name}: not proven valid", "hexsos_status", -1, 0)
            bad_shown.Opacity = 0.6
            displays.append(bad_shown)
        if report["meshes"][-1]["mirrored"]:  # the cells written mirrored, solid blue on top
            _paint(_show_cells_between(simple, check, view, f"{name}: written mirrored", "hexsos_mirrored", 1, 1),
                   "CELLS", MIRRORED_COLOUR)
        fold_shown = _paint(simple.Show(simple.OutputPort(check, 1), view), "POINTS", FOLD_COLOUR)
        fold_shown.SetRepresentationType("Points")
        fold_shown.RenderPointsAsSpheres = 1
        fold_shown.PointSize = 14
        last = check
    mirrored = sum(m.get("mirrored", 0) for m in report["meshes"])
    if mirrored:  # the status legend's colours are the statuses'; the blue of the mirrored cells is said here
        _say_in_colour(simple, view, f"blue: {mirrored} cell{'s' if mirrored != 1 else ''} written in the mirrored "
                       "node order", MIRRORED_COLOUR)
    if displays:
        _colour_by_status(simple, displays, view, total)
        view.ResetCamera()
        camera = view.GetActiveCamera()
        camera.Elevation(35)
        camera.Azimuth(20)
        view.ResetCamera()
        simple.SetActiveSource(last)
    kernel = sys.modules.get("hexsos_plugins")
    report["kernel"] = getattr(kernel, "__file__", None)
    simple.Render(view)
    if screenshot:  # the mesh and its legend; ParaView's orientation axes (a red X) stay in the window only
        axes = view.OrientationAxesVisibility
        view.OrientationAxesVisibility = 0
        simple.SaveScreenshot(screenshot, view, ImageResolution=list(size))
        view.OrientationAxesVisibility = axes
        report["screenshot"] = screenshot
    return report


# ----------------------------------------------------------------------------------------------------
# python -m vtk_filter.hexsos_paraview_plugin [--record]: how to point ParaView at this installation
# ----------------------------------------------------------------------------------------------------


def _installation_paths() -> list:
    """site-packages of this Python and the directory holding hexsos_plugins (for an editable install)."""
    import site
    import sysconfig

    paths = []
    try:
        import hexsos_plugins

        paths.append(os.path.dirname(os.path.dirname(os.path.abspath(hexsos_plugins.__file__))))
    except ImportError:
        pass
    paths += [sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]]
    try:
        paths += site.getsitepackages()
    except AttributeError:  # pragma: no cover - old virtualenv
        pass
    seen, out = set(), []
    for p in paths:
        if p not in seen and os.path.isdir(p):
            seen.add(p)
            out.append(p)
    return out


def main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m vtk_filter.hexsos_paraview_plugin",
        description="Print how to load the hexsos ParaView plugin with this Python's packages, or record them.")
    parser.add_argument("--record", action="store_true",
                        help=f"write this Python's package directories to {_record_file()} (read by the plugin)")
    args = parser.parse_args(argv)
    paths = _installation_paths()
    version = f"{sys.version_info[0]}.{sys.version_info[1]}"
    if args.record:
        target = _record_file()
        os.makedirs(os.path.dirname(target), exist_ok=True)
        with open(target, "w", encoding="utf-8") as fh:
            fh.write(f"# written by {sys.executable} (Python {version}); one directory per line, appended to "
                     f"ParaView's sys.path by the hexsos plugin\n")
            fh.write("".join(p + "\n" for p in paths))
        print(f"recorded {len(paths)} directories in {target}")
        return 0
    print("# simplest: 'hexsos paraview [MESH ...]' starts ParaView with all of this done; by hand:")
    print(f"# hexsos ParaView plugin, packages of {sys.executable} (Python {version});")
    print(f"# ParaView's Python must be {version} too (compiled dependencies such as clarabel)")
    print(f"export PV_PLUGIN_PATH={_HERE}")
    print(f"export HEXSOS_PYTHONPATH={os.pathsep.join(paths)}")
    print("# Debian's ParaView 5.11 with Python >= 3.11 only:")
    print(f"export PYTHONPATH={os.path.join(_HERE, 'paraview_compat')}${{PYTHONPATH:+:$PYTHONPATH}}")
    return 0


# ----------------------------------------------------------------------------------------------------
# The certified largest safe step of a displacement field
# ----------------------------------------------------------------------------------------------------


class HexSOSSafeStepFilter(_HexSOSBase):
    """The certified largest fraction of a displacement that keeps every cell valid (``hexsos_plugins.safe_step``, :mod:`hexsos_plugins.certify.safe_step`).

    Input: a vtkUnstructuredGrid with a point-data vector array (``SetDisplacement(name)``, default
    ``"displacement"``; 2 components are taken with z = 0). The step moves the points to ``x + t * d``.

    Output port 0: the input grid (structure shallow-copied, arrays kept) with the cell array
    ``hexsos_safe_step``: each checked cell's proven safe fraction (1 where the whole step is safe; NaN on
    cells hexsos does not check), and field data ``hexsos_safe_step`` (the mesh's t*) and ``hexsos_summary``.

    Output port 1: a vtkPolyData with the witness: one vertex where validity is proven lost just past t*, at its
    position in the moved mesh ``x + t_w d``, with point data ``hexsos_cell_id`` (cell index in the input grid),
    ``hexsos_witness_t`` (t_w), ``hexsos_witness_pcoords`` (reference coordinates) and ``hexsos_witness_det``
    (det J there, <= 0 by rational arithmetic); empty when the whole step is safe.

    Errors (no such array, a grid without checkable cells, ...) are reported as :class:`HexSOSCheckFilter`'s.
    """

    def __init__(self):
        _HexSOSBase.__init__(self, 2)
        self._displacement = "displacement"

    def FillOutputPortInformation(self, port, info):
        info.Set(vtkDataObject.DATA_TYPE_NAME(), "vtkUnstructuredGrid" if port == 0 else "vtkPolyData")
        return 1

    @smproperty.stringvector(name="Displacement", default_values="displacement", number_of_elements=1)
    @_doc("The point-data vector array to step along (e.g. a solver's displacement): points move to x + t d.")
    def SetDisplacement(self, value):
        self._set("_displacement", value.decode() if isinstance(value, bytes) else str(value))

    def GetDisplacement(self) -> str:
        return self._displacement

    def _execute(self, inp, outputs):
        out, poly_out = outputs
        kernel, elements, blocks, _ = self._prepare(inp, "certify.safe_step")
        arr = inp.GetPointData().GetArray(self._displacement)
        if arr is None:
            pd = inp.GetPointData()
            have = [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]
            raise ValueError(f"expected a point-data array named {self._displacement!r} (the displacement), "
                             f"found: {', '.join(map(str, have)) or 'none'}")
        D = np.asarray(_to_numpy(arr), dtype=np.float64)
        if D.ndim != 2 or D.shape[1] not in (2, 3):
            raise ValueError(f"{self._displacement}: expected a vector array (2 or 3 components), found shape "
                             f"{D.shape}")
        if D.shape[1] == 2:
            D = np.column_stack([D, np.zeros(len(D))])
        P = _points(inp)
        cells = [(t, c) for t, c, _ in blocks]
        cell_ids = np.concatenate([ids for _, _, ids in blocks])
        self.UpdateProgress(0.0)
        step = sys.modules["hexsos_plugins.certify.safe_step"]
        result = step.safe_step(P, cells, D, jobs=0)
        out.ShallowCopy(inp)
        out.GetCellData().AddArray(_vtk_array("hexsos_safe_step", _spread(result.cell_t, cell_ids,
                                                                           out.GetNumberOfCells(), np.nan)))
        t_arr = _vtk_array("hexsos_safe_step", np.array([result.t]))
        out.GetFieldData().AddArray(t_arr)
        w = result.witness
        text = (f"safe step t* = {result.t:.9g}" if result.t < 1 else "the whole step is proven safe (t* = 1)")
        if w is not None:
            text += f"; cell {int(cell_ids[w['cell']])} proven invalid at t = {w['t']:.9g}"
        _add_summary(out, "hexsos_summary", text)
        poly = vtkPolyData()
        pts = vtkPoints()
        pts.SetDataTypeToDouble()
        verts = vtkCellArray()
        if w is not None:
            s = 0
            for name, conn, _ in blocks:
                if s <= w["cell"] < s + len(conn):
                    row = conn[w["cell"] - s][None]
                    X = elements.world_points(P + w["t"] * D, [(name, row)], np.asarray(w["point"])[None])
                    break
                s += len(conn)
            pts.SetData(_vtk_array("Points", X.reshape(-1, 3)))
            verts.InsertNextCell(1)
            verts.InsertCellPoint(0)
        else:
            pts.SetData(_vtk_array("Points", np.zeros((0, 3))))
        poly.SetPoints(pts)
        poly.SetVerts(verts)
        pd = poly.GetPointData()
        n = 1 if w is not None else 0
        pd.AddArray(_vtk_array("hexsos_cell_id", np.array([int(cell_ids[w["cell"]])] if n else [], dtype=np.int64)))
        pd.AddArray(_vtk_array("hexsos_witness_t", np.array([w["t"]] if n else [], dtype=np.float64)))
        pd.AddArray(_vtk_array("hexsos_witness_pcoords", np.asarray([w["point"]] if n else np.zeros((0, 3)),
                                                                    dtype=np.float64).reshape(-1, 3)))
        pd.AddArray(_vtk_array("hexsos_witness_det", np.array([w["det"]] if n else [], dtype=np.float64)))
        poly_out.ShallowCopy(poly)
        self._result = result
        self.UpdateProgress(1.0)


_register(HexSOSSafeStepFilter, "HexSOSSafeStep", "HexSOS Safe Step",
          "The certified largest fraction of a displacement that keeps every cell valid, and where it is lost.",
          ["Mesh", "Witness"])



if __name__ == "__main__":
    sys.exit(main())
