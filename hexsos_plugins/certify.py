"""The validity pipeline: Bernstein screen -> branch-and-bound -> SOS where needed -> proven verdicts.

``check(points, hexes)`` returns, for every hex, the minimum of det J over the parameter cube, where it
occurs, a proven lower bound, and a verdict that is a proof:

* ``1`` **valid**: a lower bound > 0 is proven. Lower bounds come from Bernstein coefficients with a
  rigorous bound on their floating-point rounding (see :func:`hexsos_plugins.hexahedron.det_bernstein`),
  from an SOS certificate whose residual is bounded on the cube (:meth:`SOSSolver.certified_lower`), or,
  for hexes whose bound lies inside the rounding error, from the Bernstein coefficients computed in exact
  rational arithmetic.
* ``0`` **invalid**: a witness point (``argmin``) has det J <= 0: its computed value plus its rounding
  bound is <= 0, or its exact rational value is <= 0.
* ``-1`` **undecided**: neither could be proven. A *flat* hex (det J is nowhere larger than
  ``flat_rtol`` times the product of its edge lengths: no sign of det J means anything for coordinates in
  float64) is always undecided, and fast.

``min_det`` is det J at ``argmin``; with ``method="auto"`` it is exact to ``rtol`` (default 1e-9) times the
hex's scale (its largest |Bernstein coefficient|): ``min_det - lower_bound <= rtol * scale`` is *proven*
for every hex whose bracket closed (``gap`` reports it; all hexes in the measurements of the README).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .bernstein import _CORNER_UVW, CORNER_COEFFS, bracket, polish
from .errors import InvalidInputError, NoHexahedraError
from .hexahedron import (
    UNIT_ROUND,
    bernstein_exact,
    bernstein_to_monomial,
    det_at,
    det_at_bernstein,
    det_bernstein,
    det_exact,
    gather_t,
)

__all__ = ["check", "CheckResult", "METHOD_NAMES", "STATUS_NAMES", "SOS_STATUS_NAMES", "validate_arrays"]

#: Names of the codes in ``CheckResult.method``: what settled each hex.
METHOD_NAMES = ("bernstein", "subdivision", "sos", "exact", "flat")
_BERNSTEIN, _SUBDIVISION, _SOS, _EXACT, _FLAT = range(5)
#: Names of the verdict codes in ``CheckResult.status``.
STATUS_NAMES = {1: "valid", 0: "invalid", -1: "undecided"}
#: Names of the codes in ``CheckResult.sos_status`` (0: SOS did not run on that hex).
SOS_STATUS_NAMES = ("", "Solved", "AlmostSolved", "MaxIterations", "MaxTime", "NumericalError",
                    "InsufficientProgress", "PrimalInfeasible", "DualInfeasible", "AlmostPrimalInfeasible",
                    "AlmostDualInfeasible", "CallbackTerminated", "Unsolved", "other")

_CHUNK = 32768  # measured: larger chunks amortize the branch-and-bound over more open hexes; past 32768 the
# coefficient arrays fall out of cache (8192 .. 131072 tried on random, ring and twisted-grid meshes)


def _sos_code(status: str) -> int:
    return SOS_STATUS_NAMES.index(status) if status in SOS_STATUS_NAMES else len(SOS_STATUS_NAMES) - 1


@dataclass
class CheckResult:
    """Per-hex results of :func:`check` (arrays of length M, the number of hexes), plus a summary.

    Attributes
    ----------
    min_det : (M,) float64, the minimum of det J over [0, 1]^3, equal to det J at ``argmin``
    lower_bound : (M,) float64, a proven lower bound of that minimum
    argmin : (M, 3) float64, where the minimum occurs, in parameter coordinates (u, v, w)
    status : (M,) int8, 1 valid, 0 invalid, -1 undecided
    corner_min_det : (M,) float64, the smallest det J at the 8 corners (what corner checks see)
    method : (M,) int8, index into :data:`METHOD_NAMES`: what settled the hex
    recovery_ratio : (M,) float64, lambda_2 / lambda_1 of the moment matrix where SOS ran, else NaN
    sos_status : (M,) int8, index into :data:`SOS_STATUS_NAMES` (0 where SOS did not run)
    scale : (M,) float64, the hex's scale, its largest |Bernstein coefficient| of det J
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
    seconds: float = 0.0
    method_requested: str = "auto"
    relaxation: str = "quad2"
    sos_solves: int = 0
    boxes: int = 0
    extra: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.status.shape[0])

    # --- derived arrays ----------------------------------------------------------------------------
    @property
    def gap(self) -> np.ndarray:
        """``min_det - lower_bound`` (>= 0): how far the minimum could be from exact."""
        return self.min_det - self.lower_bound

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
        """Invalid hexes that are valid at all 8 corners: the ones corner checks miss."""
        return (self.status == 0) & (self.corner_min_det > 0)

    @property
    def worst(self) -> int:
        """Index of the hex with the smallest min_det (-1 for an empty result)."""
        if len(self) == 0:
            return -1
        return int(np.nanargmin(self.min_det))

    def method_names(self) -> np.ndarray:
        return np.array(METHOD_NAMES, dtype=object)[self.method]

    def counts(self) -> dict:
        return {
            "hexes": len(self),
            "valid": int(self.valid.sum()),
            "invalid": int(self.invalid.sum()),
            "undecided": int(self.undecided.sum()),
            "invalid_inside_only": int(self.invalid_inside_only.sum()),
            "flat": int((self.method == _FLAT).sum()),
        }

    def to_dict(self) -> dict:
        """A JSON-ready summary (no per-hex arrays)."""
        w = self.worst
        d = self.counts()
        d.update({
            "min_det": float(self.min_det[w]) if w >= 0 else None,
            "worst_hex": w,
            "worst_argmin": [float(t) for t in self.argmin[w]] if w >= 0 else None,
            "max_gap_relative": float(np.max(self.gap / np.where(self.scale > 0, self.scale, 1.0))) if w >= 0 else None,
            "seconds": round(float(self.seconds), 6),
            "method": self.method_requested,
            "relaxation": self.relaxation,
            "settled_by": {name: int((self.method == i).sum()) for i, name in enumerate(METHOD_NAMES)},
            "sos_solves": int(self.sos_solves),
        })
        return d

    def cell_data(self) -> dict:
        """The result arrays under the names hexsos writes onto meshes."""
        return {
            "hexsos_min_det": self.min_det,
            "hexsos_lower_bound": self.lower_bound,
            "hexsos_argmin": self.argmin,
            "hexsos_status": self.status.astype(np.int8),
            "hexsos_corner_min_det": self.corner_min_det,
        }

    def summary(self) -> str:
        """A human-readable summary (several lines)."""
        c = self.counts()
        n = max(c["hexes"], 1)
        lines = [
            f"hexes      {c['hexes']}",
            f"valid      {c['valid']} ({100.0 * c['valid'] / n:.2f}%)",
            f"invalid    {c['invalid']} ({100.0 * c['invalid'] / n:.2f}%), of which {c['invalid_inside_only']} "
            "invalid inside only (valid at all 8 corners)",
            f"undecided  {c['undecided']}" + (f" ({c['flat']} flat)" if c["flat"] else ""),
        ]
        w = self.worst
        if w >= 0:
            u, v, t = self.argmin[w]
            lines.append(f"min det J  {self.min_det[w]:.9g} in hex {w} at (u, v, w) = ({u:.6f}, {v:.6f}, {t:.6f})")
        settled = ", ".join(f"{name} {k}" for name, k in self.to_dict()["settled_by"].items() if k)
        lines.append(f"settled by {settled}")
        lines.append(f"time       {self.seconds:.3f} s ({len(self) / max(self.seconds, 1e-9):,.0f} hexes/s)")
        return "\n".join(lines)

    def __repr__(self) -> str:
        c = self.counts()
        return (f"CheckResult(hexes={c['hexes']}, valid={c['valid']}, invalid={c['invalid']}, "
                f"undecided={c['undecided']}, invalid_inside_only={c['invalid_inside_only']})")

    _ARRAYS = (("min_det", np.float64, ()), ("lower_bound", np.float64, ()), ("argmin", np.float64, (3,)),
               ("status", np.int8, ()), ("corner_min_det", np.float64, ()), ("method", np.int8, ()),
               ("recovery_ratio", np.float64, ()), ("sos_status", np.int8, ()), ("scale", np.float64, ()))

    @classmethod
    def empty(cls, m: int, **kw) -> "CheckResult":
        """A result for m hexes to be filled block by block with :meth:`put`."""
        return cls(**{name: np.empty((m,) + shape, dtype=dt) for name, dt, shape in cls._ARRAYS}, **kw)

    def put(self, where: slice, part: "CheckResult") -> None:
        """Copy the arrays of ``part`` (the result of the hexes ``where``) into this result."""
        for name, _, _ in self._ARRAYS:
            getattr(self, name)[where] = getattr(part, name)
        self.sos_solves += part.sos_solves
        self.boxes += part.boxes

    @classmethod
    def concatenate(cls, parts) -> "CheckResult":
        """Join results of consecutive blocks of hexes."""
        first = parts[0]
        out = cls.empty(sum(len(p) for p in parts), method_requested=first.method_requested,
                        relaxation=first.relaxation)
        s = 0
        for p in parts:
            out.put(slice(s, s + len(p)), p)
            s += len(p)
        out.seconds = sum(p.seconds for p in parts)
        return out


def validate_arrays(points, hexes):
    """Check and convert ``points`` (N, 3) and ``hexes`` (M, 8); raise typed errors that say what is wrong."""
    try:
        P = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"points: expected an array of numbers of shape (N, 3), could not convert: {exc}") from exc
    if P.ndim != 2 or P.shape[1] != 3:
        raise InvalidInputError(f"points: expected shape (N, 3), found {P.shape}")
    H = np.asarray(hexes)
    if H.ndim != 2 or H.shape[1] != 8:
        if H.size == 0:
            raise NoHexahedraError("no hexahedra given: expected hexes of shape (M, 8) with M >= 1, found an empty array")
        raise InvalidInputError(f"hexes: expected shape (M, 8), found {H.shape}")
    if H.shape[0] == 0:
        raise NoHexahedraError("no hexahedra given: expected hexes of shape (M, 8) with M >= 1, found M = 0")
    if not np.issubdtype(H.dtype, np.integer):
        if np.issubdtype(H.dtype, np.floating) and np.all(np.isfinite(H)) and np.all(H == np.round(H)):
            H = H.astype(np.int64)
        else:
            raise InvalidInputError(f"hexes: expected integer node indices, found dtype {H.dtype}")
    H = H.astype(np.int64, copy=False)
    bad = (H < 0) | (H >= P.shape[0])
    if bad.any():
        m = int(np.flatnonzero(bad.any(axis=1))[0])
        raise InvalidInputError(f"hexes: node index out of range in hex {m}: {H[m].tolist()} (there are {P.shape[0]} points)")
    fin = np.isfinite(P).all(axis=1)
    if not fin.all():  # unreferenced points may be anything; referenced ones must be finite
        ok = fin[H]
        if not ok.all():
            m = int(np.flatnonzero(~ok.all(axis=1))[0])
            i = int(H[m][~ok[m]][0])
            raise InvalidInputError(f"points: expected finite coordinates, found {P[i].tolist()} at point {i} (hex {m})")
    return P, H


def check(points, hexes, *, method: str = "auto", relaxation: str = "quad2", rtol: float = 1e-9,
          flat_rtol: float = 1e-12, max_depth: int = 30, max_boxes: int = 64, sos_tol: float = 1e-8,
          sos_max_iter: int = 100, progress=None, chunk_size: int = _CHUNK, jobs: int = 1, scheduler=None,
          block_size: int | None = None, executor=None) -> CheckResult:
    """Certified validity of every hex: exact min det J, where it occurs, and a proven verdict.

    Parameters
    ----------
    points : array_like, shape (N, 3)
    hexes : array_like of int, shape (M, 8), VTK node order (see :mod:`hexsos_plugins.hexahedron`)
    method : {"auto", "sos"}, keyword-only
        ``"auto"`` (default) screens every hex with Bernstein bounds, refines by branch-and-bound, and
        runs the SOS relaxation only where the bracket stays open. ``"sos"`` runs the SOS relaxation on
        every hex, as the paper does (argmin from the moments, polished); verdicts still need a proof.
    relaxation : {"quad2", "paper"}, keyword-only
        The SOS relaxation (see :data:`hexsos_plugins.sos.RELAXATIONS`). Default ``"quad2"``.
    rtol : float, keyword-only
        Bracket width sought, relative to each hex's scale. Default 1e-9.
    flat_rtol : float, keyword-only
        A hex whose det J is nowhere larger than ``flat_rtol`` times the product of its largest edge
        lengths is flat: undecided. Default 1e-12.
    max_depth, max_boxes : int, keyword-only
        Limits of the branch-and-bound (subdivision depth, boxes per hex). Defaults 30 and 64.
    sos_tol : float, keyword-only
        Clarabel's tolerances. Default 1e-8.
    sos_max_iter : int, keyword-only
        Clarabel's iteration cap. Default 100. A solve that ends in any status but ``Solved`` gives no
        bound and no argmin: the hex is then decided by the other proofs or stays undecided.
    progress : callable(done, total), optional
        Called after each chunk of hexes (and each SOS solve batch) with the hexes done so far.
    chunk_size : int, keyword-only
        Hexes processed at once (bounds memory and keeps the arrays in cache). Default 32768.
    jobs : int, keyword-only
        Worker processes (0: one per core). Default 1: in this process.
    scheduler : dask.distributed.Client or str, optional
        Run on a Dask cluster (a client, or a scheduler address such as ``"tcp://host:8786"``).
    block_size : int, optional
        Hexes per task with ``jobs > 1`` or a scheduler (default: about four tasks per worker, at most
        65536 hexes each). Each task carries only its hexes' vertex coordinates.
    executor : optional
        An open executor of :func:`hexsos_plugins.parallel.executor` to use instead of ``jobs`` and
        ``scheduler`` (callers that check many times, like the repair, reuse one pool or cluster connection).

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
    """
    if method not in ("auto", "sos"):
        raise InvalidInputError(f"method: expected 'auto' or 'sos', found {method!r}")
    from .sos import RELAXATIONS  # light import; the solver is built only when needed

    if relaxation not in RELAXATIONS:
        raise InvalidInputError(f"relaxation: expected one of {sorted(RELAXATIONS)}, found {relaxation!r}")
    P, H = validate_arrays(points, hexes)
    t0 = time.perf_counter()
    M = H.shape[0]
    opts = _Options(method, relaxation, rtol, flat_rtol, max_depth, max_boxes, sos_tol, sos_max_iter,
                    max(1, int(chunk_size)))
    PT = np.ascontiguousarray(P.T)
    from contextlib import nullcontext

    from .parallel import executor as make_executor

    result = CheckResult.empty(M, method_requested=method, relaxation=relaxation)
    with (nullcontext(executor) if executor is not None else make_executor(jobs, scheduler)) as ex:
        # in this process: chunk by chunk; elsewhere: blocks of about four per worker, each carrying only
        # its hexes' vertex coordinates (gathered lazily, a bounded number in flight)
        size = opts.chunk if ex.workers == 1 else (block_size or max(opts.chunk, min(65536, -(-M // (4 * ex.workers)))))
        starts = range(0, M, size)
        blocks = (gather_t(PT, H[s : s + size]) for s in starts)
        done = 0
        for k, part in ex.imap(_check_block, blocks, opts):
            result.put(slice(starts[k], starts[k] + len(part)), part)
            done += len(part)
            if progress is not None:
                progress(done, M)
    result.seconds = time.perf_counter() - t0
    return result


@dataclass(frozen=True)
class _Options:
    """The options of one check, sent with every block of hexes to wherever it runs."""

    method: str
    relaxation: str
    rtol: float
    flat_rtol: float
    max_depth: int
    max_boxes: int
    sos_tol: float
    sos_max_iter: int
    chunk: int


_SOLVERS = {}  # one SOSSolver per process and setting, reused across blocks


def _solver(opts: _Options):
    key = (opts.relaxation, opts.sos_tol, opts.sos_max_iter)
    if key not in _SOLVERS:
        from .sos import SOSSolver

        _SOLVERS[key] = SOSSolver(relaxation=opts.relaxation, tol=opts.sos_tol, max_iter=opts.sos_max_iter)
    return _SOLVERS[key]


def _check_block(X, opts: _Options) -> CheckResult:
    """Check the hexes of a block of vertex coordinates X (3, 8, m), in cache-sized chunks."""
    m = X.shape[2]
    parts = [_check_chunk(X[:, :, s : s + opts.chunk], opts) for s in range(0, m, opts.chunk)]
    return CheckResult.concatenate(parts) if len(parts) > 1 else parts[0]


def _check_chunk(X, ctx: _Options) -> CheckResult:
    # Scale each hex by a power of two (exact) so that its extent is about 1: det J can then neither
    # overflow nor underflow whatever the units (coordinates near 1e+-300 included), and every value is
    # scaled back exactly (ldexp) at the end.
    extent = (X.max(axis=1) - X.min(axis=1)).max(axis=0)
    _, e = np.frexp(extent)
    X = X * np.ldexp(1.0, -e)[None, None, :]  # times a power of two: exact
    stats = {}
    B, err = det_bernstein(X, layout="soa", stats=stats)
    m = X.shape[2]
    scale = stats["max_abs"]
    edge_scale = err / (1024.0 * UNIT_ROUND)  # product of the largest edge L1 norms per direction
    flat = scale <= ctx.flat_rtol * edge_scale
    corner_min = stats["corner_min"]
    at_root_corner = np.ones(m, dtype=bool)  # argmin is still the root's best corner (its value: corner_min)
    method = np.full(m, _BERNSTEIN, dtype=np.int8)
    ratio = np.full(m, np.nan)
    sos_status = np.zeros(m, dtype=np.int8)
    sos_solves = 0

    if ctx.method == "auto":
        br = bracket(B, err, rtol=ctx.rtol, max_depth=ctx.max_depth, max_boxes=ctx.max_boxes, stats=stats)
        lower, argmin, boxes = br.lower, br.argmin, br.boxes
        method[br.depth > 0] = _SUBDIVISION
        at_root_corner[br.depth > 0] = False
        refine = np.flatnonzero(br.depth > 0)
        if refine.size:
            x, _ = polish(B[:, refine], argmin[refine])
            argmin[refine] = x
        open_ = np.flatnonzero(~br.closed & ~flat)
        if open_.size:
            sos_solves = _run_sos(ctx, B, err, open_, argmin, lower, ratio, sos_status)
            method[open_] = _SOS
            at_root_corner[open_] = False
    else:  # "sos": the relaxation on every hex, then proofs
        lower = np.full(m, -np.inf)
        argmin = np.zeros((m, 3))
        argmin[:] = _CORNER_UVW[stats["corner_arg"]]
        idx = np.flatnonzero(~flat)
        sos_solves = _run_sos(ctx, B, err, idx, argmin, lower, ratio, sos_status)
        method[:] = _SOS
        at_root_corner[idx] = False
        lower = np.maximum(lower, stats["min"] - err)  # the root Bernstein bound holds too
        boxes = 0

    # det J at argmin: where argmin is the root's best corner, its corner coefficient is that value (the same
    # triple product of edge vectors as det_at computes there); elsewhere evaluate it from the vertices
    perr = err.copy()
    min_det = corner_min.copy()
    inside = np.flatnonzero(~at_root_corner)
    if inside.size:
        min_det[inside], perr[inside] = det_at(X[:, :, inside], argmin[inside], layout="soa")
    # a lower bound never exceeds a value: where rounding would say so, the value is the bound
    lower = np.minimum(lower, min_det + perr)
    status = np.full(m, -1, dtype=np.int8)
    status[lower > 0] = 1
    status[min_det + perr <= 0] = 0

    if ctx.method == "sos":
        # where SOS gave no usable minimum (any status but Solved), no verdict, or a certified bound that
        # disagrees with the polished value (several minimizers, inexact relaxation), the branch-and-bound
        # finds the minimum and the proof
        todo = np.flatnonzero(~flat & ((status == -1) | (sos_status != 1) | (min_det - lower > 1e-6 * scale)))
        if todo.size:
            br = bracket(B[:, todo], err[todo], rtol=ctx.rtol, max_depth=ctx.max_depth, max_boxes=ctx.max_boxes)
            boxes += br.boxes
            better = br.upper < min_det[todo]
            if better.any():
                x, _ = polish(B[:, todo[better]], br.argmin[better])
                argmin[todo[better]] = x
            lower[todo] = np.maximum(lower[todo], br.lower)
            min_det[todo], perr[todo] = det_at(X[:, :, todo], argmin[todo], layout="soa")
            lower[todo] = np.minimum(lower[todo], min_det[todo] + perr[todo])
            status[todo[lower[todo] > 0]] = 1
            status[todo[min_det[todo] + perr[todo] <= 0]] = 0
            method[todo] = _SUBDIVISION

    # signs within the rounding bound (the witness's value, or the smallest root coefficient, closer to 0 than
    # its error bound): decide in exact rational arithmetic
    near = np.flatnonzero((status == -1) & ~flat & ((min_det - perr <= 0) | (np.abs(stats["min"]) <= err)))
    for i in near:
        s = _exact_decision(X[:, :, i].T, argmin[i])
        if s is not None:
            status[i], lo, witness, value = s
            method[i] = _EXACT
            if lo is not None:
                lower[i] = max(lower[i], lo)
            if witness is not None:
                argmin[i] = witness
            if value is not None:  # the witness's exact det J (<= 0), rounded down
                min_det[i] = value
                lower[i] = min(lower[i], value)
    status[flat] = -1
    method[flat] = _FLAT
    e3 = 3 * e
    with np.errstate(over="ignore"):  # a value beyond float range is reported as +-inf
        min_det, lower, corner_min, scale = (np.ldexp(a, e3) for a in (min_det, lower, corner_min, scale))
    return CheckResult(min_det=min_det, lower_bound=lower, argmin=argmin, status=status, corner_min_det=corner_min,
                       method=method, recovery_ratio=ratio, sos_status=sos_status, scale=scale,
                       method_requested=ctx.method, relaxation=ctx.relaxation, sos_solves=sos_solves, boxes=boxes)


def _run_sos(ctx, B, err, idx, argmin, lower, ratio, sos_status) -> int:
    """Solve the relaxation on the hexes idx; update argmin (polished), lower (certified) in place."""
    solver = _solver(ctx)
    C = bernstein_to_monomial(B[:, idx])
    coeff_err = 128.0 * err[idx]
    starts = []
    for j, i in enumerate(idx):
        sol = solver.solve(C[:, j], scale=float(np.abs(B[:, i]).max()) or 1.0)
        sos_status[i] = _sos_code(sol.status)
        if sol.solved:
            ratio[i] = sol.recovery_ratio
            lower[i] = max(lower[i], solver.certified_lower(sol, C[:, j], coeff_err[j]))
            starts.append((i, sol.argmin))
    if starts:
        ii = np.array([i for i, _ in starts])
        x0 = np.array([a for _, a in starts])
        x, f = polish(B[:, ii], x0)
        # keep whichever point is lower: the polished moment point or the one we had
        cur = det_at_bernstein(B[:, ii], argmin[ii])
        better = f < cur
        argmin[ii[better]] = x[better]
    return len(idx)


def _exact_decision(X8, uvw):
    """Verdict in exact rational arithmetic for one hex whose sign lies inside the rounding bound.

    Returns ``(status, lower bound or None, new witness uvw or None, witness value or None)``, or None when
    exact arithmetic cannot decide either. Values are floats rounded down from the exact rationals.
    """
    exact = det_exact(X8, uvw)
    if exact <= 0:
        return 0, None, None, _round_down(exact)
    coeffs = bernstein_exact(X8)
    corners = [coeffs[int(k)] for k in CORNER_COEFFS]
    k = min(range(8), key=corners.__getitem__)
    if corners[k] <= 0:
        return 0, None, _CORNER_UVW[k].copy(), _round_down(corners[k])
    low = min(coeffs)
    if low > 0:  # proven exactly; the float bound is rounded down (0.0 only if it underflows)
        return 1, _round_down(low), None, None
    return None


def _round_down(q) -> float:
    """The largest float <= the rational q."""
    f = float(q)
    return math.nextafter(f, -math.inf) if f > q else f
