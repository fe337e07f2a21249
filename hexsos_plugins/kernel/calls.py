"""The kernel's entry points as Python functions: arrays in, arrays out, threaded (:mod:`.pool`), on the
implementation :mod:`.compiled` loaded, with the tables of :mod:`.cell_tables`.

Owns: :func:`run_cells`, :func:`coefficients`, :func:`evaluate`, :func:`polish`, :func:`scaled_jacobian`,
:func:`det_at`, :func:`finish`, and the argument lists of the compiled entry points
(:func:`entry_point_arguments`, from which the ahead-of-time build derives their signatures).
"""

from __future__ import annotations

import numpy as np

from ..cells.hexahedron import CORNER_INDEX, as_soa
from .compiled import impl
from .cell_tables import sj_id, sj_tables, tables
from .pool import LIGHT_CHUNK, spread

__all__ = ["run_cells", "coefficients", "det_bernstein", "evaluate", "polish", "scaled_jacobian", "det_at", "finish", "run_outputs",
           "run_args", "coefficient_args", "evaluate_args", "polish_args", "sj_args", "det_at_args", "finish_outputs",
           "finish_args", "entry_point_arguments"]


def run_outputs(m):
    """Empty output arrays of run_cells for m cells."""
    return {"lower": np.empty(m), "value": np.empty(m), "argmin": np.empty((m, 3)), "err": np.empty(m),
            "scale": np.empty(m), "corner": np.empty(m), "depth": np.empty(m, dtype=np.int64),
            "closed": np.empty(m, dtype=np.bool_), "flat": np.empty(m, dtype=np.bool_),
            "k": np.empty(m, dtype=np.int64), "boxes": np.empty(m, dtype=np.int64), "lowroot": np.empty(m),
            "size": np.empty(m)}


def run_args(points, conn, ids, t, out, start, stop, rtol=1e-9, flat_rtol=1e-12, max_depth=30, max_iter=2000,
              polish_iter=30, cap=256):
    """The arguments of the entry point run_chunk, in its order (also used to derive its compiled signature)."""
    return ((points, conn, ids, int(start), int(stop)) + t.formulation_args +
            (t.sizes, t.S, t.Snz, t.nchildren, t.cmaps, t.bptr, t.bidx, t.bvert, t.ctrl, t.vidx, t.cidx, t.Mptr,
             t.Midx, t.Mval, t.exps, t.G, t.h, t.fdim, t.fslot, t.fexp, t.fcoef, t.nctrl, t.nx, float(rtol), float(flat_rtol), int(max_depth),
             int(max_iter), int(polish_iter), int(cap), out["lower"], out["value"], out["argmin"], out["err"],
             out["scale"], out["corner"], out["depth"], out["closed"], out["flat"], out["k"], out["boxes"],
             out["lowroot"], out["size"]))


def run_cells(points, conn, ids, name, *, rtol=1e-9, flat_rtol=1e-12, max_depth=30, max_iter=2000, polish_iter=30,
              cap=256, out=None):
    """Run the kernel on the cells ``conn[ids]`` (rows of node indices into ``points``, VTK order).

    Returns a dict of arrays of length len(ids) in *scaled units* (a cell's det J values times 2^(-3 k), k in
    ``k``): ``lower`` (proven lower bound), ``value`` (det J at ``argmin``, up to ``err``), ``argmin`` (len, 3),
    ``err``, ``scale`` (max |b|), ``corner`` (smallest corner coefficient), ``size`` (size of det J's terms),
    ``depth``, ``closed``, ``flat``, ``boxes``, ``lowroot`` (the root bound min b - err). ``out``: such a dict of
    C-contiguous arrays (views into larger ones, say) to fill instead."""
    t = tables(name)
    ids = np.ascontiguousarray(ids, dtype=np.int64)
    points = np.ascontiguousarray(points, dtype=np.float64)
    conn = np.ascontiguousarray(conn, dtype=np.int64)
    m = int(ids.size)
    if out is None:
        out = run_outputs(m)
    spread(impl.run_chunk, m, lambda a, b: run_args(points, conn, ids, t, out, a, b, rtol, flat_rtol, max_depth,
                                                        max_iter, polish_iter, cap))
    return out


def coefficient_args(points, conn, ids, t, outs, start, stop):
    return (points, conn, ids, int(start), int(stop)) + t.formulation_args + (t.nctrl, t.nx) + tuple(outs)


def coefficients(points, conn, ids, name):
    """Bernstein coefficients (len(ids), nb) of the cells ``conn[ids]`` in scaled units, their error bounds,
    the scaling exponents k (world det J = scaled times 2^(3 k)) and the sizes of det J's terms."""
    t = tables(name)
    ids = np.ascontiguousarray(ids, dtype=np.int64)
    points = np.ascontiguousarray(points, dtype=np.float64)
    conn = np.ascontiguousarray(conn, dtype=np.int64)
    outs = (np.empty((ids.size, t.nb)), np.empty(ids.size), np.empty(ids.size, dtype=np.int64), np.empty(ids.size))
    spread(impl.coefficients_chunk, int(ids.size), lambda s, e: coefficient_args(points, conn, ids, t, outs, s, e))
    return outs


def evaluate_args(b, X, t, out):
    return (b, X, t.fdim, t.fslot, t.fexp, t.fcoef, t.sizes, int(t.S.shape[2]), out)


def polish_args(b, X0, t, iterations, out, vals):
    return (b, X0, t.Mptr, t.Midx, t.Mval, t.exps, t.G, t.h, int(iterations), t.fdim, t.fslot, t.fexp, t.fcoef,
            t.sizes, int(t.S.shape[2]), out, vals)


def evaluate(b, X, name):
    """The polynomials with coefficients b (m, nb) at the points X (m, 3) (explicit Bernstein weights)."""
    t = tables(name)
    out = np.empty(np.shape(b)[0])
    impl.evaluate(*evaluate_args(np.ascontiguousarray(b, dtype=np.float64), np.ascontiguousarray(X, dtype=np.float64),
                                   t, out))
    return out


def polish(b, X0, name, *, iterations=30):
    """Local descent of the polynomials b (m, nb) from the points X0 (m, 3) inside the reference element;
    returns the points (never worse than X0) and the values there."""
    t = tables(name)
    b = np.ascontiguousarray(b, dtype=np.float64)
    X0 = np.ascontiguousarray(X0, dtype=np.float64)
    out = np.empty_like(X0)
    vals = np.empty(b.shape[0])
    impl.polish_many(*polish_args(b, X0, t, iterations, out, vals))
    return out, vals



def sj_args(points, conn, ids, name, out, start, stop, generated=True):
    vptr, vnode, vw, samp, ssign, factor = sj_tables(name)
    return (points, conn, ids, int(start), int(stop), vptr, vnode, vw, samp, ssign, factor,
            name in ("tetra", "pyramid"), name == "pyramid", sj_id(name) if generated else 0, out)


def scaled_jacobian(points, cells) -> np.ndarray:
    """Verdict's scaled Jacobian of every cell, compiled (the definitions and sample tables of
    :mod:`hexsos_plugins.cells.quality`, which computes the same numbers with numpy). ``cells``: an (M, 8) hex array or
    (cell_type, conn) pairs. Quadratic cells get the value of their corner nodes' linear cell (their first
    nodes in VTK order), as Verdict computes hexahedron, wedge and tetrahedron metrics for any node count."""
    from ..cells.elements import ELEMENTS
    from ..cells.quality import SAMPLES, as_cell_list

    points = np.ascontiguousarray(points, dtype=np.float64)
    parts = []
    for name, conn in as_cell_list(cells):
        conn = np.asarray(conn, dtype=np.int64)
        if name not in SAMPLES and name in ELEMENTS:
            linear = {"tet": "tetra", "prism": "wedge", "cube": "hexahedron", "pyramid": "pyramid"}[ELEMENTS[name].domain]
            if conn.ndim == 2 and conn.shape[1] > ELEMENTS[linear].n_nodes:
                name, conn = linear, conn[:, :ELEMENTS[linear].n_nodes]
        conn = np.ascontiguousarray(conn, dtype=np.int64)
        out = np.full(conn.shape[0], np.nan)
        if name in SAMPLES and conn.shape[0] and conn.shape[1] == SAMPLES[name][0].shape[1]:
            ids = np.arange(conn.shape[0])
            spread(impl.scaled_jacobian_chunk, conn.shape[0], lambda a, b: sj_args(points, conn, ids, name, out, a, b))
        parts.append(out)
    return np.concatenate(parts) if parts else np.zeros(0)


def det_at_args(points, conn, ids, dN, out, start, stop):
    return (points, conn, ids, int(start), int(stop), dN, out)


def det_at(points, conn, name, pcoords) -> np.ndarray:
    """det J (pyramids: the measure) of every cell ``conn`` (VTK order) of type ``name`` at one reference point,
    compiled, threaded as the kernel is. A sign test (no rounding bound): the orientation of node orders."""
    from ..cells.elements import element

    el = element(name)
    dN = np.ascontiguousarray(el.shape_derivatives(np.asarray(pcoords, dtype=np.float64).reshape(1, 3))[0])
    points = np.ascontiguousarray(points, dtype=np.float64)
    conn = np.ascontiguousarray(conn, dtype=np.int64)
    out = np.empty(conn.shape[0])
    ids = np.arange(conn.shape[0], dtype=np.int64)
    spread(impl.det_at_chunk, conn.shape[0], lambda a, b: det_at_args(points, conn, ids, dN, out, a, b))
    return out


def finish_outputs(m):
    return np.empty(m, dtype=np.int8), np.empty(m, dtype=np.bool_), np.empty(m, dtype=np.bool_)


def finish_args(value, lower, err, corner, scale, k, flat, closed, status, near, bad, start, stop):
    return (value, lower, err, corner, scale, k, flat, closed, int(start), int(stop), status, near, bad)


def finish(value, lower, err, corner, scale, k, flat, closed):
    """The verdicts of cells from run_cells' outputs (scaled units), and their numbers in world units, in place
    (times 2^(3 k): exact where representable, else value, corner and scale to the nearest float of the same
    sign, lower to the largest float below; see source.finish_chunk): returns status
    (1 valid: lower > 0; 0 invalid: value + err <= 0; -1 otherwise and where flat), near (undecided, not flat,
    and the bracket closed or the value within 64 err of 0: for the exact decision) and unrepresentable (value
    or lower). One compiled pass, threaded as the kernel is."""
    arrays = [np.ascontiguousarray(a, dtype=np.float64) for a in (value, lower, err, corner, scale)]
    if any(a is not b for a, b in zip(arrays, (value, lower, err, corner, scale))):
        raise TypeError("finish: expected contiguous float64 arrays (it writes them in place)")
    k = np.ascontiguousarray(k, dtype=np.int64)
    flat = np.ascontiguousarray(flat, dtype=np.bool_)
    closed = np.ascontiguousarray(closed, dtype=np.bool_)
    outs = finish_outputs(value.shape[0])
    spread(impl.finish_chunk, value.shape[0], lambda a, b: finish_args(*arrays, k, flat, closed, *outs, a, b),
            min_chunk=LIGHT_CHUNK)
    return outs


def entry_point_arguments() -> dict:
    """Example arguments of every entry point of the compiled source (a trilinear hexahedron), by name: the
    ahead-of-time build derives the exported signatures from them."""
    t = tables("hexahedron")
    P = np.ascontiguousarray(np.eye(8, 3))
    conn = np.arange(8, dtype=np.int64)[None]
    ids = np.zeros(1, dtype=np.int64)
    b = np.zeros((1, t.nb))
    X = np.zeros((1, 3))
    coeff_outs = (np.empty((1, t.nb)), np.empty(1), np.empty(1, dtype=np.int64), np.empty(1))
    return {
        "run_chunk": run_args(P, conn, ids, t, run_outputs(1), 0, 1),
        "coefficients_chunk": coefficient_args(P, conn, ids, t, coeff_outs, 0, 1),
        "evaluate": evaluate_args(b, X, t, np.empty(1)),
        "polish_many": polish_args(b, X, t, 30, np.empty((1, 3)), np.empty(1)),
        "scaled_jacobian_chunk": sj_args(P, conn, ids, "hexahedron", np.empty(1), 0, 1),
        "det_at_chunk": det_at_args(P, conn, ids, np.zeros((8, 3)), np.empty(1), 0, 1),
        "finish_chunk": finish_args(*(np.zeros(1) for _ in range(5)), np.zeros(1, dtype=np.int64),
                                     np.zeros(1, dtype=np.bool_), np.zeros(1, dtype=np.bool_),
                                     *finish_outputs(1), 0, 1),
    }


def det_bernstein(X, *, layout="aos", stats=None):
    """Tensor Bernstein coefficients of det J, with a rigorous bound on their rounding error.

    A convenience over :func:`coefficients` for trilinear hexahedra, in the units of X.

    Parameters
    ----------
    X : array_like, shape (M, 8, 3) or (8, 3); with ``layout="soa"``, (3, 8, M) (see :func:`hexsos_plugins.cells.hexahedron.gather`)
    stats : dict, optional
        Filled with per-hex summaries: ``max_abs`` (the scale, max |B|), ``min`` (min B), ``corner_min`` and
        ``corner_arg`` (the smallest of the 8 corner coefficients and its node, VTK order).

    Returns
    -------
    B : ndarray, shape (27, M); ``B[9 a + 3 b + c]`` belongs to the control point (a, b, c) / 2.
    err : ndarray, shape (M,); ``|B_computed - B_exact| <= err`` for every coefficient (values that overflow
        float64 in the units of X are inf).
    """
    Xs = as_soa(X, layout)
    M = Xs.shape[2]
    P = np.ascontiguousarray(Xs.transpose(2, 1, 0).reshape(-1, 3))
    conn = np.arange(8 * M, dtype=np.int64).reshape(M, 8)
    b, err, k, _ = coefficients(P, conn, np.arange(M), "hexahedron")
    with np.errstate(over="ignore", under="ignore"):
        B = np.ldexp(b, 3 * k[:, None]).T.copy()
        err = np.ldexp(err, 3 * k)
    if stats is not None:
        corners = B[CORNER_INDEX]
        arg = corners.argmin(axis=0)
        stats.update(max_abs=np.abs(B).max(axis=0), min=B.min(axis=0), corner_arg=arg,
                     corner_min=corners[arg, np.arange(M)])
    return B, err
