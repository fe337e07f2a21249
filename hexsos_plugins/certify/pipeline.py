"""The validity pipeline: compiled kernel -> SOS where a hex's bracket stays open -> exact decisions.

``check(points, cells)`` returns, for every 3-D cell, the minimum of det J over its reference element
(pyramids: of det J / (1 - t)^2, see :mod:`hexsos_plugins.cells.elements`), where it occurs, a proven lower bound,
and a verdict that is a proof:

* ``1`` **valid**: a lower bound > 0 is proven: the kernel's Bernstein bound with its rounding and underflow
  terms subtracted (:mod:`hexsos_plugins.kernel`), an SOS certificate whose residual is bounded on the cube
  (:meth:`hexsos_plugins.kernel.sos.SOSSolver.certified_lower`, trilinear hexahedra), or exact rational arithmetic on
  the input coordinates (:mod:`hexsos_plugins.kernel.exact`) where the float bounds cannot decide.
* ``0`` **invalid**: a witness point (``argmin``) has det J <= 0: its computed value plus its rounding bound
  is <= 0, or its exact value is <= 0.
* ``-1`` **undecided**: neither could be proven. A *flat* cell (det J nowhere larger than ``flat_rtol`` times
  the size of its terms, a measure that scales with det J under any scaling of the axes) is undecided at once;
  so is the rare cell exact arithmetic cannot settle within its budget.

``min_det`` is det J at ``argmin``; ``min_det - lower_bound`` (``gap``) is at most ``rtol`` (default 1e-9)
times the cell's scale (its largest |Bernstein coefficient|) wherever the bracket closed.

Units. The kernel scales each cell by a power of two so that nothing overflows or underflows; values are
scaled back exactly where float64 can hold them. Where it cannot (det J beyond ~1e308, or below ~5e-324 in
magnitude), ``min_det`` is the nearest float of the same sign (at most the largest float, at least the
smallest subnormal), ``lower_bound`` the largest float below the proven bound (possibly 0.0 or -inf), and
``unrepresentable`` is set; verdicts are proven in the scaled units and are not affected.
"""

from __future__ import annotations

import threading
import time
from contextlib import nullcontext
from dataclasses import dataclass, field

import numpy as np

from ..cells.elements import CELL_TYPES, ELEMENTS, VOXEL_TO_VTK
from ..cells.topology import repeated_cells, repeated_words
from ..errors import InvalidInputError, NoHexahedraError
from ..kernel.calls import run_outputs
from ..kernel.pool import threads_for

__all__ = ["check", "CheckResult", "METHOD_NAMES", "STATUS_NAMES", "SOS_STATUS_NAMES", "validate_arrays",
           "validate_cells", "HEX_TYPES"]

#: Names of the codes in ``CheckResult.method``: what settled each cell.
METHOD_NAMES = ("bernstein", "subdivision", "sos", "exact", "flat")
_BERNSTEIN, _SUBDIVISION, _SOS, _EXACT, _FLAT = range(5)
#: Names of the verdict codes in ``CheckResult.status``.
STATUS_NAMES = {1: "valid", 0: "invalid", -1: "undecided"}
#: Names of the codes in ``CheckResult.sos_status`` (0: SOS did not run on that cell).
SOS_STATUS_NAMES = ("", "Solved", "AlmostSolved", "MaxIterations", "MaxTime", "NumericalError",
                    "InsufficientProgress", "PrimalInfeasible", "DualInfeasible", "AlmostPrimalInfeasible",
                    "AlmostDualInfeasible", "CallbackTerminated", "Unsolved", "other")
#: The hexahedral cell types (``CheckResult.to_dict()["hexes"]`` counts them).
HEX_TYPES = ("hexahedron", "hexahedron20", "hexahedron27")

#: From this many cells on, :func:`check` reads the cells written twice in a thread beside the kernel's work (where
#: the kernel runs on one thread or in other processes)
TWINS_BESIDE = 50_000

_SLICE = 65536  # cells per kernel call (progress between calls; the kernel itself works in chunks of 512)


def _sos_code(status: str) -> int:
    return SOS_STATUS_NAMES.index(status) if status in SOS_STATUS_NAMES else len(SOS_STATUS_NAMES) - 1


@dataclass
class CheckResult:
    """Per-cell results of :func:`check` (arrays of length M, the number of cells), plus a summary.

    Attributes
    ----------
    min_det : (M,) float64, the minimum of det J over the reference element, equal to det J at ``argmin``
    lower_bound : (M,) float64, a proven lower bound of that minimum
    argmin : (M, 3) float64, where the minimum occurs, in VTK's parametric coordinates
    status : (M,) int8, 1 valid, 0 invalid, -1 undecided
    corner_min_det : (M,) float64, the smallest det J at the cell's corner nodes (what corner checks see)
    method : (M,) int8, index into :data:`METHOD_NAMES`: what settled the cell
    recovery_ratio : (M,) float64, lambda_2 / lambda_1 of the moment matrix where SOS ran, else NaN
    sos_status : (M,) int8, index into :data:`SOS_STATUS_NAMES` (0 where SOS did not run)
    scale : (M,) float64, the cell's scale, its largest |Bernstein coefficient| of det J
    cell_type : (M,) int8, index into :data:`hexsos_plugins.cells.elements.CELL_TYPES`
    unrepresentable : (M,) bool, min_det or lower_bound lies beyond float64's range in the input's units
    """

    min_det: np.ndarray
    lower_bound: np.ndarray
    argmin: np.ndarray
    status: np.ndarray
    corner_min_det: np.ndarray
    method: np.ndarray
    recovery_ratio: np.ndarray
    sos_status: np.ndarray
    scale: np.ndarray
    cell_type: np.ndarray = None
    unrepresentable: np.ndarray = None
    seconds: float = 0.0
    method_requested: str = "auto"
    relaxation: str = "quad2"
    sos_solves: int = 0
    boxes: int = 0
    extra: dict = field(default_factory=dict)
    #: Verdict's corner scaled Jacobian of every cell (NaN where a type has none), when the check was asked for it
    #: (``quality=True``) or :meth:`add_quality` ran; else None.
    scaled_jacobian: np.ndarray = None

    def __post_init__(self):
        m = int(self.status.shape[0])
        if self.cell_type is None:
            self.cell_type = np.full(m, CELL_TYPES.index("hexahedron"), dtype=np.int8)
        if self.unrepresentable is None:
            self.unrepresentable = np.zeros(m, dtype=bool)

    def __len__(self) -> int:
        return int(self.status.shape[0])

    # --- derived arrays ----------------------------------------------------------------------------
    @property
    def gap(self) -> np.ndarray:
        """``min_det - lower_bound`` (>= 0): how far the minimum could be from exact."""
        return self.min_det - self.lower_bound

    @property
    def relative_min_det(self) -> np.ndarray:
        """min det J over each cell divided by its scale (its largest |Bernstein coefficient|, about max |det J|):
        a size-free quality in [-1, 1], 1 for a parallelepiped; low where det J nearly vanishes inside a cell whose
        corners look fine."""
        return self.min_det / np.where(self.scale > 0, self.scale, 1.0)

    @property
    def valid(self) -> np.ndarray:
        return self.status == 1

    @property
    def invalid(self) -> np.ndarray:
        return self.status == 0

    @property
    def undecided(self) -> np.ndarray:
        return self.status == -1

    @property
    def invalid_inside_only(self) -> np.ndarray:
        """Invalid cells that are valid at all their corners: the ones corner checks miss."""
        return (self.status == 0) & (self.corner_min_det > 0)

    @property
    def repeated_cells(self) -> np.ndarray:
        """(M,) int: for each cell, the first earlier cell of its type on the same set of points, -1 where there
        is none (:func:`hexsos_plugins.cells.topology.repeated_cells`; ``extra["repeated_cells"]`` where any)."""
        twin = self.extra.get("repeated_cells")
        return np.full(len(self), -1, dtype=np.int64) if twin is None else twin

    @property
    def worst(self) -> int:
        """Index of the cell with the smallest min_det (-1 for an empty result)."""
        if len(self) == 0:
            return -1
        return int(np.nanargmin(self.min_det))

    def cell_type_names(self) -> np.ndarray:
        return np.array(CELL_TYPES, dtype=object)[self.cell_type]

    def method_names(self) -> np.ndarray:
        return np.array(METHOD_NAMES, dtype=object)[self.method]

    def counts(self) -> dict:
        hexes = int(np.isin(self.cell_type, [CELL_TYPES.index(t) for t in HEX_TYPES]).sum())
        return {
            "cells": len(self),
            "hexes": hexes,
            "valid": int(self.valid.sum()),
            "invalid": int(self.invalid.sum()),
            "undecided": int(self.undecided.sum()),
            "invalid_inside_only": int(self.invalid_inside_only.sum()),
            "flat": int((self.method == _FLAT).sum()),
        }

    def by_type(self) -> dict:
        """Per cell type present: cells, valid, invalid, invalid_inside_only, undecided, min_det, worst_cell."""
        out = {}
        for code in np.unique(self.cell_type):
            sel = np.flatnonzero(self.cell_type == code)
            w = int(sel[np.nanargmin(self.min_det[sel])])
            out[CELL_TYPES[int(code)]] = {
                "cells": int(sel.size),
                "valid": int((self.status[sel] == 1).sum()),
                "invalid": int((self.status[sel] == 0).sum()),
                "invalid_inside_only": int(self.invalid_inside_only[sel].sum()),
                "undecided": int((self.status[sel] == -1).sum()),
                "min_det": float(self.min_det[w]),
                "worst_cell": w,
            }
        return out

    def to_dict(self) -> dict:
        """A JSON-ready summary (no per-cell arrays)."""
        w = self.worst
        d = self.counts()
        rel = self.gap / np.where(self.scale > 0, self.scale, 1.0)
        d.update({
            "min_det": float(self.min_det[w]) if w >= 0 else None,
            "worst_hex": w,
            "worst_cell": w,
            "worst_argmin": [float(t) for t in self.argmin[w]] if w >= 0 else None,
            "max_gap_relative": float(np.nanmax(rel)) if w >= 0 else None,
            "seconds": round(float(self.seconds), 6),
            "method": self.method_requested,
            "relaxation": self.relaxation,
            "settled_by": {name: int((self.method == i).sum()) for i, name in enumerate(METHOD_NAMES)},
            "sos_solves": int(self.sos_solves),
            "unrepresentable": int(self.unrepresentable.sum()),
            "by_type": self.by_type(),
            "repeated_cells": int((self.repeated_cells >= 0).sum()),
        })
        q = self.quality()
        if q is not None:
            d["scaled_jacobian"] = q
        return d

    def add_quality(self, points, cells) -> "CheckResult":
        """Compute the corner scaled Jacobian (Verdict's, compiled: :func:`hexsos_plugins.kernel.scaled_jacobian`)
        of the same ``points`` and ``cells`` this result is about; returns self."""
        from ..kernel import scaled_jacobian

        sj = scaled_jacobian(points, cells)
        if sj.shape[0] != len(self):
            raise InvalidInputError(f"add_quality: expected the {len(self)} cells of this result, found {sj.shape[0]}")
        self.scaled_jacobian = sj
        return self

    def quality(self):
        """``{"min", "p1", "mean"}`` of the scaled Jacobian (None where no cell has one; JSON-ready), or None
        when it was not computed."""
        if self.scaled_jacobian is None:
            return None
        from ..cells.quality import summary

        return {k: (None if v is None or not np.isfinite(v) else float(v))
                for k, v in summary(self.scaled_jacobian).items()}

    def cell_data(self) -> dict:
        """The result arrays under the names hexsos writes onto meshes."""
        return {
            "hexsos_min_det": self.min_det,
            "hexsos_lower_bound": self.lower_bound,
            "hexsos_argmin": self.argmin,
            "hexsos_status": self.status.astype(np.int8),
            "hexsos_corner_min_det": self.corner_min_det,
            **({"hexsos_scaled_jacobian": self.scaled_jacobian} if self.scaled_jacobian is not None else {}),
        }

    def summary(self) -> str:
        """A human-readable summary (several lines)."""
        c = self.counts()
        n = max(c["cells"], 1)
        bt = self.by_type()
        what = "hexes" if set(bt) == {"hexahedron"} else "cells"
        lines = [
            f"{what:<10} {c['cells']}" + ("" if what == "hexes" else
                                         " (" + ", ".join(f"{v['cells']} {k}" for k, v in bt.items()) + ")"),
            f"valid      {c['valid']} ({100.0 * c['valid'] / n:.2f}%)",
            f"invalid    {c['invalid']} ({100.0 * c['invalid'] / n:.2f}%), of which {c['invalid_inside_only']} "
            "invalid inside only (valid at all corners)",
            f"undecided  {c['undecided']}" + (f" ({c['flat']} flat)" if c["flat"] else ""),
        ]
        if what == "cells":
            for k, v in bt.items():
                lines.append(f"  {k:<13} {v['cells']:>8} cells: {v['invalid']} invalid ({v['invalid_inside_only']} "
                             f"inside only), {v['undecided']} undecided, min det J {v['min_det']:.6g}")
        w = self.worst
        if w >= 0:
            u, v, t = self.argmin[w]
            name = "" if what == "hexes" else f" ({CELL_TYPES[int(self.cell_type[w])]})"
            lines.append(f"min det J  {self.min_det[w]:.9g} in {what[:-1] if what == 'cells' else 'hex'} {w}{name} at "
                         f"(u, v, w) = ({u:.6f}, {v:.6f}, {t:.6f})")
        settled = ", ".join(f"{name} {k}" for name, k in self.to_dict()["settled_by"].items() if k)
        lines.append(f"settled by {settled}")
        lines.append(f"time       {self.seconds:.3f} s ({len(self) / max(self.seconds, 1e-9):,.0f} {what}/s)")
        line = self.quality_line()
        if line:
            lines.append(line)
        said = repeated_words(self.repeated_cells)
        if said:
            lines.append(f"repeated   {said}: each copy is checked, but a solver would count the cell twice")
        return "\n".join(lines)

    def quality_line(self) -> str:
        """One line with the scaled Jacobian's minimum, 1st percentile and mean ("" when not computed)."""
        from ..cells.quality import sj_text

        q = self.quality()
        if not q or q.get("min") is None:
            return ""
        return (f"scaled J   min {sj_text(q['min'])}, 1st percentile {sj_text(q['p1'])}, mean {sj_text(q['mean'])} "
                "(corners, Verdict)")

    def __repr__(self) -> str:
        c = self.counts()
        return (f"CheckResult(cells={c['cells']}, valid={c['valid']}, invalid={c['invalid']}, "
                f"undecided={c['undecided']}, invalid_inside_only={c['invalid_inside_only']})")

    _ARRAYS = (("min_det", np.float64, ()), ("lower_bound", np.float64, ()), ("argmin", np.float64, (3,)),
               ("status", np.int8, ()), ("corner_min_det", np.float64, ()), ("method", np.int8, ()),
               ("recovery_ratio", np.float64, ()), ("sos_status", np.int8, ()), ("scale", np.float64, ()),
               ("cell_type", np.int8, ()), ("unrepresentable", np.bool_, ()))

    @classmethod
    def empty(cls, m: int, **kw) -> "CheckResult":
        """A result for m cells to be filled block by block with :meth:`put`."""
        return cls(**{name: np.empty((m,) + shape, dtype=dt) for name, dt, shape in cls._ARRAYS}, **kw)

    def put(self, where, part: "CheckResult") -> None:
        """Copy the arrays of ``part`` (the result of the cells ``where``) into this result."""
        for name, _, _ in self._ARRAYS:
            getattr(self, name)[where] = getattr(part, name)
        self.sos_solves += part.sos_solves
        self.boxes += part.boxes

    def take(self, idx) -> "CheckResult":
        """The result of the cells ``idx`` (an index array or mask)."""
        return CheckResult(**{name: getattr(self, name)[idx] for name, _, _ in self._ARRAYS},
                           method_requested=self.method_requested, relaxation=self.relaxation)

    @classmethod
    def concatenate(cls, parts) -> "CheckResult":
        """Join results of consecutive blocks of cells."""
        first = parts[0]
        out = cls.empty(sum(len(p) for p in parts), method_requested=first.method_requested,
                        relaxation=first.relaxation)
        s = 0
        for p in parts:
            out.put(slice(s, s + len(p)), p)
            s += len(p)
        out.seconds = sum(p.seconds for p in parts)
        return out


# --- input validation ----------------------------------------------------------------------------------------------
def _points(points) -> np.ndarray:
    try:
        P = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"points: expected an array of numbers of shape (N, 3), could not convert: {exc}") from exc
    if P.ndim != 2 or P.shape[1] != 3:
        raise InvalidInputError(f"points: expected shape (N, 3), found {P.shape}")
    return np.ascontiguousarray(P)


def _indices(conn, what, n_nodes, n_points) -> np.ndarray:
    H = np.asarray(conn)
    if H.ndim != 2 or H.shape[1] != n_nodes:
        if H.size == 0:
            raise NoHexahedraError(f"no cells given: expected {what} of shape (M, {n_nodes}) with M >= 1, found an "
                                   "empty array")
        raise InvalidInputError(f"{what}: expected shape (M, {n_nodes}), found {H.shape}")
    if H.shape[0] == 0:
        raise NoHexahedraError(f"no cells given: expected {what} of shape (M, {n_nodes}) with M >= 1, found M = 0")
    if not np.issubdtype(H.dtype, np.integer):
        if np.issubdtype(H.dtype, np.floating) and np.all(np.isfinite(H)) and np.all(H == np.round(H)):
            H = H.astype(np.int64)
        else:
            raise InvalidInputError(f"{what}: expected integer node indices, found dtype {H.dtype}")
    H = np.ascontiguousarray(H, dtype=np.int64)
    if int(H.min()) < 0 or int(H.max()) >= n_points:  # two reductions; the cell is found only when one is bad
        bad = (H < 0) | (H >= n_points)
        m = int(np.flatnonzero(bad.any(axis=1))[0])
        raise InvalidInputError(f"{what}: node index out of range in cell {m}: {H[m].tolist()} (there are {n_points} "
                                "points)")
    return H


def _finite(P, H, what):
    if np.isfinite(P).all():  # the usual case, in one flat pass
        return
    fin = np.isfinite(P).all(axis=1)
    if not fin.all():  # unreferenced points may be anything; referenced ones must be finite
        ok = fin[H]
        if not ok.all():
            m = int(np.flatnonzero(~ok.all(axis=1))[0])
            i = int(H[m][~ok[m]][0])
            raise InvalidInputError(f"points: expected finite coordinates, found {P[i].tolist()} at point {i} "
                                    f"({what} {m})")


def validate_arrays(points, hexes):
    """Check and convert ``points`` (N, 3) and ``hexes`` (M, 8); raise typed errors that say what is wrong."""
    P = _points(points)
    H = _indices(hexes, "hexes", 8, P.shape[0])
    _finite(P, H, "hex")
    return P, H


def validate_cells(points, cells):
    """Check and convert ``points`` and ``cells`` for :func:`check`.

    ``cells`` is an (M, 8) integer array (trilinear hexahedra), a sequence of ``(cell_type, conn)`` pairs or a
    mapping ``{cell_type: conn}``; ``cell_type`` a name of :data:`hexsos_plugins.cells.elements.CELL_TYPES` (or
    ``"voxel"``, converted to a hexahedron), ``conn`` (M_t, n_t) in VTK node order.
    meshio's ``CellBlock`` lists, a ``meshio.Mesh`` and a hexsos ``Mesh`` are taken too
    (:func:`hexsos_plugins.cells.inputs.cell_pairs`: blocks that are not 3-D left out).
    Returns ``(points (N, 3), [(cell_type, conn (M_t, n_t) int64), ...])``."""
    from ..cells.inputs import cell_pairs

    P = _points(points)
    pairs, not_checked = cell_pairs(cells)
    if pairs is not None:
        if not pairs:
            found = ", ".join(f"{n} {t}" for t, n in not_checked.items()) or "no cell blocks"
            raise NoHexahedraError(f"no 3-D cells given: expected at least one block of 3-D cells, found {found}")
        cells = pairs
    if isinstance(cells, dict):
        pairs = list(cells.items())
    elif isinstance(cells, (list, tuple)) and cells and isinstance(cells[0], (list, tuple)) and len(cells[0]) == 2 \
            and isinstance(cells[0][0], str):
        pairs = list(cells)
    else:
        return P, [("hexahedron", validate_arrays(P, cells)[1])]
    blocks = []
    for name, conn in pairs:
        if not isinstance(name, str):
            raise InvalidInputError(f"cells: expected (cell_type, connectivity) pairs, found a {type(name).__name__} "
                                    "as cell type")
        key = "hexahedron" if name == "voxel" else name
        if key not in ELEMENTS:
            raise InvalidInputError(f"cells: cell type {name!r} is not one hexsos checks; expected one of "
                                    f"{', '.join(CELL_TYPES)} (or voxel)")
        H = _indices(conn, f"{name} cells", ELEMENTS[key].n_nodes, P.shape[0])
        if name == "voxel":
            H = np.ascontiguousarray(H[:, VOXEL_TO_VTK])
        _finite(P, H, name)
        blocks.append((key, H))
    if not blocks:
        raise NoHexahedraError("no cells given: expected at least one block of 3-D cells, found none")
    return P, blocks


# --- the pipeline ----------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Options:
    """The options of one check, sent with every block of cells to wherever it runs."""

    method: str
    relaxation: str
    rtol: float
    flat_rtol: float
    max_depth: int
    max_boxes: int
    sos_tol: float
    sos_max_iter: int
    exact_boxes: int


_SOLVERS = {}  # one SOSSolver per process, setting and SOS thread, reused across blocks


def _solver(opts: _Options, thread: int = 0):
    key = (opts.relaxation, opts.sos_tol, opts.sos_max_iter, thread)
    if key not in _SOLVERS:
        from ..kernel.sos import SOSSolver

        _SOLVERS[key] = SOSSolver(relaxation=opts.relaxation, tol=opts.sos_tol, max_iter=opts.sos_max_iter)
    return _SOLVERS[key]


#: Hexes per SOS thread below which the relaxation runs in the calling thread: a thread pays once it has some
#: 20 ms of solves (quad2 takes about 1.5 ms per hex, the paper's relaxation 25 ms).
_SOS_MIN_PER_THREAD = {"quad2": 16, "paper": 1}


#: The second pass over brackets still open: the memory for live boxes per thread (the first pass keeps 256
#: boxes), at most _WIDE_CAP boxes, and the box budget as a multiple of ``max_boxes``.
_WIDE_BYTES = 64 * 2**20
_WIDE_CAP = 262144
_WIDE_BOXES = 64


def _check_block(P, conn, name, opts: _Options, progress=None, offset=0, total=None) -> CheckResult:
    """Check the cells conn (M, n) of one type; the whole pipeline, in this process."""
    from .. import kernel

    t0 = time.perf_counter()
    M = conn.shape[0]
    # what the rest needs, for every cell; the rest of the kernel's outputs in scratch reused slice by slice
    keep = ("lower", "value", "argmin", "err", "scale", "corner", "closed", "flat", "k")
    if opts.method == "sos":
        keep += ("lowroot",)
    full = {k: v for k, v in run_outputs(M).items() if k in keep}
    scratch = {k: v for k, v in run_outputs(min(M, _SLICE)).items() if k not in keep}
    method = np.empty(M, dtype=np.int8)
    boxes = 0
    for s in range(0, M, _SLICE):
        e = min(s + _SLICE, M)
        out = {k: v[s:e] for k, v in full.items()}
        out.update({k: v[: e - s] for k, v in scratch.items()})
        kernel.run_cells(P, conn, np.arange(s, e), name, rtol=opts.rtol, flat_rtol=opts.flat_rtol,
                         max_depth=opts.max_depth, max_iter=opts.max_boxes, out=out)
        method[s:e] = np.where(out["depth"] > 0, _SUBDIVISION, _BERNSTEIN)
        boxes += int(out["boxes"].sum())
        if progress is not None:
            progress(offset + e, total if total is not None else M)
    # brackets left open because the live boxes outgrew the kernel's working set (minima along an edge or a
    # face, where many boxes stay within the tolerance): once more with a wide working set and a larger budget
    wide = np.flatnonzero(~full["closed"] & ~full["flat"])
    if wide.size:
        cap = min(_WIDE_CAP, _WIDE_BYTES // (8 * (kernel.tables(name).nb + 14)))
        again = kernel.run_cells(P, conn, wide, name, rtol=opts.rtol, flat_rtol=opts.flat_rtol,
                                 max_depth=opts.max_depth, max_iter=_WIDE_BOXES * opts.max_boxes, cap=cap)
        for k in keep:
            full[k][wide] = again[k]
        method[wide] = np.where(again["depth"] > 0, _SUBDIVISION, _BERNSTEIN)
        boxes += int(again["boxes"].sum())
    r = full
    lower, value, argmin, err = r["lower"], r["value"], r["argmin"], r["err"]
    scale, flat = r["scale"], r["flat"]
    ratio = np.full(M, np.nan)
    sos_status = np.zeros(M, dtype=np.int8)
    sos_solves = 0

    if name == "hexahedron" and opts.method == "sos":
        idx = np.flatnonzero(~flat)
        lower[:] = r["lowroot"]
        sos_solves, boxes = _sos_everything(P, conn, idx, opts, lower, value, argmin, err, scale, ratio, sos_status,
                                            method, r, boxes)
    elif name == "hexahedron":
        open_ = wide[~r["closed"][wide] & ~flat[wide]]  # the others were closed or flat before the wide pass
        if open_.size:
            sos_solves = _run_sos(P, conn, open_, opts, lower, value, argmin, err, ratio, sos_status)
            method[open_] = _SOS

    # the verdicts, and world units in place (the scaled values are not needed after this), in one compiled
    # pass. ``near``: signs float64 could not settle (the bracket closed around 0, or the witness within its
    # rounding bound of 0): exact rational arithmetic on the input coordinates. Cells left open by the search
    # limits are not sent (they stay undecided: raise max_boxes / max_depth)
    status, near, unrep = kernel.finish(value, lower, err, r["corner"], scale, r["k"], flat, r["closed"])
    min_det, low_w, corner, scale_w = value, lower, r["corner"], scale
    method[flat] = _FLAT
    near = np.flatnonzero(near)
    if near.size:
        from ..kernel.exact import beyond_float, decide, round_down, round_nearest

        el = ELEMENTS[name]
        for i in near:
            X = P[conn[i]]
            st, lo_q, witness, value_q, corner_q = decide(X, name, max_boxes=opts.exact_boxes)
            if st == -1:
                continue
            status[i] = st
            method[i] = _EXACT
            corner[i] = round_nearest(corner_q)
            if st == 0:
                argmin[i] = witness
            else:
                value_q = el.det_exact(X, argmin[i])  # the value at the point, exactly (> 0: the cell is valid)
                lo_q = min(lo_q, value_q)
            min_det[i] = round_nearest(value_q)
            low_w[i] = round_down(lo_q) if st == 1 else min(low_w[i], round_down(value_q))
            unrep[i] = bool(float(min_det[i]) != value_q and abs(min_det[i]) < 2.0**-1022) or (
                st == 1 and low_w[i] <= 0.0) or beyond_float(value_q) or (st == 1 and beyond_float(lo_q))
    return CheckResult(min_det=min_det, lower_bound=low_w, argmin=argmin, status=status, corner_min_det=corner,
                       method=method, recovery_ratio=ratio, sos_status=sos_status, scale=scale_w,
                       cell_type=np.full(M, CELL_TYPES.index(name), dtype=np.int8), unrepresentable=unrep,
                       seconds=time.perf_counter() - t0, method_requested=opts.method, relaxation=opts.relaxation,
                       sos_solves=sos_solves, boxes=boxes)


def _monomials(b):
    from ..cells.hexahedron import bernstein_to_monomial

    return bernstein_to_monomial(np.ascontiguousarray(b.T))


def _run_sos(P, conn, idx, opts, lower, value, argmin, err, ratio, sos_status) -> int:
    """The relaxation on the hexes idx (scaled units): certified lower bounds, and polished moment points
    where they beat the current argmin."""
    from .. import kernel

    b, berr, _, _ = kernel.coefficients(P, conn, idx, "hexahedron")
    ok = np.isfinite(b).all(axis=1)  # never hand non-finite data to the solver
    idx, b, berr = idx[ok], b[ok], berr[ok]
    if idx.size == 0:
        return 0
    C = _monomials(b)
    coeff_err = 128.0 * berr
    found = [None] * idx.size  # per hex: the moments' argmin where Solved

    scales = np.abs(b).max(axis=1)

    def solve(part, thread):
        # Clarabel releases the GIL: one solver per thread, disjoint hexes; the certificates of a thread's hexes
        # at once (a few numpy calls for all of them, not a dozen per hex holding the GIL)
        solver = _solver(opts, thread)
        part = np.asarray(part, dtype=np.int64)
        res = solver.solve_many(C[:, part], scales[part], coeff_err[part])
        for j, st, ok, rr, lo, am in zip(part.tolist(), res.status, res.solved.tolist(), res.recovery_ratio,
                                         res.lower, res.argmin):
            i = idx[j]
            sos_status[i] = _sos_code(st)
            if ok:
                ratio[i] = rr
                lower[i] = max(lower[i], lo)
                found[j] = am

    n_threads = max(1, min(kernel.threads(), idx.size // _SOS_MIN_PER_THREAD.get(opts.relaxation, 16)))
    if n_threads == 1:
        solve(range(idx.size), 0)
    else:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=n_threads, thread_name_prefix="hexsos-sos") as pool:
            for f in [pool.submit(solve, range(t, idx.size, n_threads), t) for t in range(n_threads)]:
                f.result()
    starts = [(j, a) for j, a in enumerate(found) if a is not None]
    if starts:
        jj = np.array([j for j, _ in starts])
        x, f = kernel.polish(b[jj], np.array([a for _, a in starts]), "hexahedron")
        cur = kernel.evaluate(b[jj], argmin[idx[jj]], "hexahedron")
        better = f < cur
        t = kernel.tables("hexahedron")
        sc = np.abs(b[jj]).max(axis=1)
        ii = idx[jj[better]]
        argmin[ii] = x[better]
        value[ii] = f[better]
        err[ii] = berr[jj[better]] + t.consts[4] * kernel.U * sc[better] + t.consts[5] * kernel.ETA
    lower[idx] = np.minimum(lower[idx], value[idx] + err[idx])
    return int(idx.size)


def _sos_everything(P, conn, idx, opts, lower, value, argmin, err, scale, ratio, sos_status, method, r, boxes):
    """``method="sos"``: the relaxation on every hex, as the paper; the kernel's branch-and-bound only where SOS
    gave no usable minimum (any status but Solved), no verdict, or a bound that disagrees with its point."""
    from .. import kernel

    t = kernel.tables("hexahedron")
    # start from the best corner, not the kernel's minimum: the minimum is SOS's to find
    b, berr, _, _ = kernel.coefficients(P, conn, idx, "hexahedron")
    vert = t.vidx[np.argmin(b[:, t.vidx], axis=1)]
    argmin[idx] = t.ctrl[vert]
    value[idx] = b[np.arange(idx.size), vert]
    err[idx] = berr
    solves = _run_sos(P, conn, idx, opts, lower, value, argmin, err, ratio, sos_status)
    method[idx] = _SOS
    todo = idx[(sos_status[idx] != 1) | (value[idx] - lower[idx] > 1e-6 * scale[idx]) | (lower[idx] <= 0) &
               (value[idx] + err[idx] > 0)]
    if todo.size:
        rr = kernel.run_cells(P, conn, todo, "hexahedron", rtol=opts.rtol, flat_rtol=opts.flat_rtol,
                              max_depth=opts.max_depth, max_iter=opts.max_boxes)
        boxes += int(rr["boxes"].sum())
        better = rr["value"] < value[todo]
        argmin[todo[better]] = rr["argmin"][better]
        value[todo[better]] = rr["value"][better]
        err[todo[better]] = rr["err"][better]
        lower[todo] = np.minimum(np.maximum(lower[todo], rr["lower"]), value[todo] + err[todo])
        method[todo] = _SUBDIVISION
    return solves, boxes


def _check_task(task):
    """One block on a worker (process or Dask): its own points and connectivity, the options."""
    P, conn, name, opts = task
    return _check_block(P, conn, name, opts)


def _local(P, conn):
    """The points a block of cells uses, and the connectivity renumbered into them."""
    used, inv = np.unique(conn, return_inverse=True)
    return np.ascontiguousarray(P[used]), inv.reshape(conn.shape).astype(np.int64)


def check(points, cells=None, *, method: str = "auto", relaxation: str = "quad2", rtol: float = 1e-9,
          flat_rtol: float = 1e-12, max_depth: int = 30, max_boxes: int = 2000, sos_tol: float = 1e-8,
          sos_max_iter: int = 100, exact_boxes: int = 400, progress=None, jobs: int = 1, processes: int = 1,
          scheduler=None, block_size: int | None = None, executor=None, quality: bool = False) -> CheckResult:
    """Certified validity of every cell: exact min det J, where it occurs, and a proven verdict.

    Parameters
    ----------
    points : array_like, shape (N, 3); or a meshio.Mesh or hexsos Mesh, given alone (``check(mesh)``)
    cells : array_like of int, shape (M, 8); or a sequence of (cell_type, conn) pairs; or {cell_type: conn};
        or meshio's cells (``meshio.read(f).cells``, a list of ``CellBlock``) or a ``meshio.Mesh``
        Trilinear hexahedra (M, 8), or blocks of any type of :data:`hexsos_plugins.cells.elements.CELL_TYPES` (and
        ``"voxel"``); node order VTK's (see :mod:`hexsos_plugins.cells.elements`). Results follow the blocks' order.
        Of meshio's blocks, those that are not 3-D (a Gmsh mesh's boundary quadrilaterals, ...) are left out,
        as :func:`hexsos_plugins.read` leaves them out of a file, and counted in ``result.extra["not_checked"]``.
    method : {"auto", "sos"}, keyword-only
        ``"auto"`` (default): the compiled kernel (Bernstein bounds and branch-and-bound) on every cell, the
        SOS relaxation on trilinear hexahedra whose bracket stays open. ``"sos"``: the relaxation on every
        trilinear hexahedron, as the paper (argmin from the moments, polished); other types use ``"auto"``.
    relaxation : {"quad2", "paper"}, keyword-only
        The SOS relaxation (see :data:`hexsos_plugins.kernel.sos.RELAXATIONS`). Default ``"quad2"``.
    rtol : float, keyword-only
        Bracket width sought, relative to each cell's scale. Default 1e-9.
    flat_rtol : float, keyword-only
        A cell whose det J is nowhere larger than ``flat_rtol`` times the size of its terms is flat:
        undecided at once. Default 1e-12.
    max_depth, max_boxes : int, keyword-only
        Limits of the branch-and-bound per cell (subdivision depth, boxes split). Defaults 30 and 2000. (Curved
        tetrahedra are bisected, not split in 8: there a bisection counts a third of a level and a quarter of
        a split.)
    sos_tol, sos_max_iter : keyword-only
        Clarabel's tolerances (default 1e-8) and iteration cap (default 100). Only the status ``Solved`` is used.
    exact_boxes : int, keyword-only
        Most boxes the exact rational subdivision examines for a cell float64 cannot decide. Default 400.
    progress : callable(done, total), optional
        Called as cells are done.
    jobs : int, keyword-only
        Threads in the compiled kernel (0: one per core). Default 1.
    processes : int, keyword-only
        Worker processes (each running the kernel; 0: one per core). Default 1: none.
    scheduler : dask.distributed.Client or str, optional
        Run on a Dask cluster (a client, or a scheduler address such as ``"tcp://host:8786"``).
    block_size : int, optional
        Cells per task on processes or Dask (default: about four tasks per worker, at most 65536 cells).
    executor : optional
        An open executor of :func:`hexsos_plugins.certify.parallel.executor` to use instead of ``processes`` and
        ``scheduler`` (callers that check many times, like the repair, reuse one pool or cluster connection).
    quality : bool, keyword-only
        Also compute Verdict's corner scaled Jacobian of every cell (``result.scaled_jacobian``; its minimum,
        1st percentile and mean in :meth:`CheckResult.summary`, ``to_dict()["scaled_jacobian"]`` and the cell
        array ``hexsos_scaled_jacobian``), as every door reports it. Default False.

    Returns
    -------
    CheckResult

    Examples
    --------
    >>> import numpy as np
    >>> from hexsos_plugins import check
    >>> cube = np.array([[0,0,0],[1,0,0],[1,1,0],[0,1,0],[0,0,1],[1,0,1],[1,1,1],[0,1,1]], float)
    >>> r = check(cube, [range(8)])
    >>> int(r.status[0]), float(r.min_det[0])
    (1, 1.0)
    >>> tet = np.array([[0,0,0],[1,0,0],[0,1,0],[0,0,1]], float)
    >>> r = check(tet, [("tetra", [[0, 1, 2, 3]]), ("tetra", [[0, 2, 1, 3]])])
    >>> r.status.tolist(), r.min_det.tolist()
    ([1, 0], [1.0, -1.0])
    """
    if method not in ("auto", "sos"):
        raise InvalidInputError(f"method: expected 'auto' or 'sos', found {method!r}")
    from ..kernel.sos import RELAXATIONS  # light import; the solver is built only when needed

    if relaxation not in RELAXATIONS:
        raise InvalidInputError(f"relaxation: expected one of {sorted(RELAXATIONS)}, found {relaxation!r}")
    for name, v in (("jobs", jobs), ("processes", processes)):
        if not isinstance(v, (int, np.integer)) or v < 0:
            raise InvalidInputError(f"{name}: expected a number >= 0 (0: one per core), found {v!r}")
    from ..cells.inputs import cell_pairs, mesh_points_and_cells

    points, cells = mesh_points_and_cells(points, cells)
    if cells is None:
        raise InvalidInputError("cells: expected hexahedra (M, 8), (cell_type, conn) pairs or meshio's cells, "
                                "found None")
    not_checked = cell_pairs(cells)[1]
    P, blocks = validate_cells(points, cells)
    t0 = time.perf_counter()
    # the cells written twice: on a large mesh read beside the kernel's work where the kernel leaves a core to it
    # (one thread here, or the work in other processes), else at once: a thread's start costs more than the reading
    # of a small mesh, and beside the kernel's threads on every core it slowed them more than it took
    twins = {}

    def read_twins():
        try:
            twins["cells"] = repeated_cells(blocks)
        except BaseException as exc:  # raised where the check waits for it
            twins["error"] = exc

    side = None
    spare = jobs == 1 or processes != 1 or scheduler is not None or executor is not None
    if spare and sum(conn.shape[0] for _, conn in blocks) >= TWINS_BESIDE:
        side = threading.Thread(target=read_twins, name="hexsos-repeated-cells", daemon=True)
        side.start()
    else:
        read_twins()
    opts = _Options(method, relaxation, float(rtol), float(flat_rtol), int(max_depth), int(max_boxes), float(sos_tol),
                    int(sos_max_iter), int(exact_boxes))
    total = sum(b.shape[0] for _, b in blocks)
    from .parallel import executor as make_executor

    ctx = nullcontext(executor) if executor is not None else make_executor(processes, scheduler)
    with ctx as ex, threads_for(jobs):
        start = 0
        if ex.workers == 1 and len(blocks) == 1:  # one block in this process: its result is the result
            name, conn = blocks[0]
            result = _check_block(P, conn, name, opts, progress, 0, total)
            result.method_requested, result.relaxation = method, relaxation
        elif ex.workers == 1:
            result = CheckResult.empty(total, method_requested=method, relaxation=relaxation)
            for name, conn in blocks:
                part = _check_block(P, conn, name, opts, progress, start, total)
                result.put(slice(start, start + len(part)), part)
                start += len(part)
        else:
            result = CheckResult.empty(total, method_requested=method, relaxation=relaxation)
            tasks, where = [], []
            for name, conn in blocks:
                m = conn.shape[0]
                size = block_size or max(4096, min(65536, -(-m // (4 * ex.workers))))
                for s in range(0, m, size):
                    where.append(slice(start + s, start + min(s + size, m)))
                    tasks.append((name, conn[s : s + size]))
                start += m

            def gen():
                for name, c in tasks:
                    Pl, cl = _local(P, c)
                    yield Pl, cl, name, opts

            done = 0
            for k, part in ex.imap(_check_task, gen()):
                result.put(where[k], part)
                done += len(part)
                if progress is not None:
                    progress(done, total)
    if side is not None:
        side.join()
    if "error" in twins:
        raise twins["error"]
    if (twins["cells"] >= 0).any():
        result.extra["repeated_cells"] = twins["cells"]
    result.seconds = time.perf_counter() - t0
    if quality:
        with threads_for(jobs):
            result.add_quality(P, [(name, conn) for name, conn in blocks])
    if not_checked:
        result.extra["not_checked"] = dict(not_checked)
    return result
