"""The kernel's tables: each cell type's formulation (:mod:`hexsos_plugins.cells.jacobian`) in the compiled
kernel's array layout, rounded from exact rationals once, saved at build time (``tables.npz``) and checked
against a fingerprint of their sources when loaded; and which types' straight-line code in
:mod:`hexsos_plugins.kernel.generated` matches the current tables (the generator itself is
:mod:`hexsos_plugins.generate.codegen`, run at build time only).

Owns: :class:`Tables`, :func:`tables`, the fingerprints. Imports the cells wing only.
"""

from __future__ import annotations

import hashlib
import os
from functools import lru_cache
from math import factorial, prod
from pathlib import Path

import numpy as np

from ..cells.jacobian import edge_lines, factor_indices, formulation, space

__all__ = ["Tables", "tables", "write_tables", "tables_fingerprint", "saved_tables", "sj_tables", "generated_id",
           "sj_id", "code_fingerprint", "sj_fingerprint", "nodes_only", "generated_fingerprints", "GENERATED",
           "SJ_GENERATED", "GENERATED_FILE", "TABLE_FIELDS", "TABLE_SCALARS", "TABLE_FILE", "TINY"]

_HERE = Path(__file__).parent
#: The files the tables and the generated code depend on (their fingerprint).
TABLE_SOURCES = (_HERE.parent / "cells" / "elements.py", _HERE.parent / "cells" / "jacobian.py",
                 _HERE.parent / "cells" / "lagrange.py", _HERE.parent / "cells" / "incomplete.py", Path(__file__),
                 _HERE / "generated.py")

_DIMS = {"line": 1, "tri": 2, "tet": 3}


class Tables:
    """One cell type's tables (:func:`hexsos_plugins.cells.jacobian.formulation` and :func:`~hexsos_plugins.cells.jacobian.space`)
    in the kernel's array layout (floats rounded from the exact rationals)."""

    def __init__(self, name, generated=True):
        sp = space(name)
        F = formulation(name)
        self.name = name
        self.nb = sp.nb
        self.n_nodes = sp.n_nodes
        C = F["C"]
        ptr, idx, val = [0], [], []
        for row in C:
            for i, v in enumerate(row):
                if v != 0:
                    idx.append(i)
                    val.append(float(v))  # dyadic rationals with small numerators: exact
            ptr.append(len(idx))
        self.cptr = np.array(ptr, dtype=np.int64)
        self.cidx_ = np.array(idx, dtype=np.int64)
        self.cval = np.array(val, dtype=np.float64)
        self.nctrl = len(C)
        ca, cb, cw, off = [], [], [], [0]
        for _, entries in F["columns"]:
            for a, b, w in entries:
                ca.append(a)
                cb.append(b)
                cw.append(float(w))
            off.append(len(ca))
        self.col_a = np.array(ca, dtype=np.int64)
        self.col_b = np.array(cb, dtype=np.int64)
        self.col_w = np.array(cw, dtype=np.float64)
        self.col_off = np.array(off, dtype=np.int64)
        self.nx = int(F["nx"])
        # the product tables, sorted by output coefficient, with row pointers (xp, dp)
        xo, self.xi, self.xj, self.xw = (np.array([e[i] for e in F["cross"]], dtype=dt)
                                         for i, dt in enumerate((np.int64, np.int64, np.int64, np.float64)))
        do, self.di, self.dj, self.dw = (np.array([e[i] for e in F["dot"]], dtype=dt)
                                         for i, dt in enumerate((np.int64, np.int64, np.int64, np.float64)))
        self.xp = np.concatenate([[0], np.cumsum(np.bincount(xo, minlength=self.nx))]).astype(np.int64)
        self.dp = np.concatenate([[0], np.cumsum(np.bincount(do, minlength=sp.nb))]).astype(np.int64)
        # rounding constants (see the module docstring of jacobian): terms per product coefficient
        kx = int(np.bincount(xo).max())
        kd = int(np.bincount(do).max())
        sizes = [int(z) for z in sp.sizes]
        degs = [p for _, p in sp.factors]
        c_rel = 2.0 * (kx + kd + 16.0)
        # Underflow. Every rounding in the subnormal range errs by at most eta / 2 (additions are exact there).
        # After scaling, |D| <= 2, so |P| <= 2 cmax (cmax: the largest row sum of |C|), |column coefficient| <=
        # acap = 2 wmax (4 cmax); the absolute errors: P within (nnzmax + 1) eta of its value from D (scaling
        # and products), a column coefficient within 2 wmax of that; they grow det J's coefficients by at most
        # 9 e (acap + e)^2 (the permanent's growth, e that bound); the cross products add kx 4 eta / 2 per X
        # coefficient, |X| <= 2 acap^2, and the dot products kd (3 acap kx 4 eta / 2 + 4 eta / 2). Four times that.
        Cabs = np.zeros(self.nctrl)
        np.add.at(Cabs, np.repeat(np.arange(self.nctrl), np.diff(self.cptr)), np.abs(self.cval))
        cmax = float(Cabs.max())
        nnzmax = float(np.diff(self.cptr).max())
        wmax = float(np.abs(self.col_w).max())
        acap = 2.0 * wmax * 4.0 * cmax
        e_col = 2.0 * wmax * (nnzmax + 1.0)
        c_abs = 4.0 * (9.0 * e_col * (acap + 1.0) ** 2 + kx * 2.0 * 3.0 * acap + kd * (3.0 * acap * kx * 2.0 + 2.0)
                       + 100.0)
        level_rel = 2.0 * float(sum(z + 2 for z in sizes))
        level_abs = 16.0 * float(sum(sizes))
        eval_rel = 2.0 * (sp.nb + 4.0 * sum(p + 4 for p in degs))
        eval_abs = 8.0 * sp.nb
        # consts[6]: the number of this type's generated products in generated.py (0: the table loops), only if
        # that file was generated from these very tables
        gid = generated_id(self) if generated else 0
        self.consts = np.array([c_rel, c_abs, level_rel, level_abs, eval_rel, eval_abs, float(gid)])
        self.sizes = sp.sizes.astype(np.int64)
        self.S = np.ascontiguousarray(sp.S)
        # the child matrices' nonzero columns by row (25-37% of a simplex factor's entries): Snz[k, c, r, 0] of
        # them, in Snz[k, c, r, 1:] ascending (the subdivision sums only these: the same numbers)
        self.Snz = _nonzero_columns(self.S)
        self.nchildren = sp.nchildren.astype(np.int64)
        self.cmaps = np.ascontiguousarray(_composed_child_maps(sp))
        # one tet factor (the tetrahedra): its lines along each edge, for the kernel's bisection (empty otherwise)
        if len(sp.factors) == 1 and sp.factors[0][0] == "tet" and sp.factors[0][1] > 0:
            self.bptr, self.bidx, self.bvert = edge_lines(sp.factors[0][1])
        else:
            self.bptr, self.bidx, self.bvert = (np.zeros((6, 1), dtype=np.int64), np.zeros((6, 0), dtype=np.int64),
                                                np.zeros(4, dtype=np.int64))
        self.ctrl = np.ascontiguousarray(sp.ctrl)
        self.vidx = sp.vertex_idx.astype(np.int64)
        self.cidx = sp.corner_idx.astype(np.int64)
        self.M = np.ascontiguousarray(sp.M)
        # M's nonzeros by row (columns ascending), for the polish's conversion to monomials: 18-44% of the
        # entries; the skipped terms are exact zeros, so the sums are the dense loop's bit for bit
        nz = self.M != 0.0
        self.Mptr = np.concatenate([[0], np.cumsum(nz.sum(axis=1))]).astype(np.int64)
        self.Midx = np.ascontiguousarray(np.nonzero(nz)[1], dtype=np.int64)
        self.Mval = np.ascontiguousarray(self.M[nz])
        self.exps = sp.mono_exp.astype(np.int64)
        self.G = np.ascontiguousarray(sp.G)
        self.h = np.ascontiguousarray(sp.h)
        self.fdim = np.array([_DIMS[k] for k, _ in sp.factors], dtype=np.int64)
        self.fslot = np.array([s[0] for s in sp.slots], dtype=np.int64)
        maxn = int(sp.sizes.max())
        self.fexp = np.zeros((len(sp.factors), maxn, 4), dtype=np.int64)
        self.fcoef = np.zeros((len(sp.factors), maxn))
        for fi, (kind, p) in enumerate(sp.factors):
            for j, alpha in enumerate(factor_indices(kind, p)):
                a = (p - sum(alpha),) + tuple(alpha)
                self.fexp[fi, j, : len(a)] = a
                self.fcoef[fi, j] = factorial(p) / prod(factorial(v) for v in a)

    @property
    def formulation_args(self):
        return (self.cptr, self.cidx_, self.cval, self.col_a, self.col_b, self.col_w, self.col_off, self.xp, self.xi,
                self.xj, self.xw, self.dp, self.di, self.dj, self.dw, self.consts)


# --- the products unrolled from the tables ---------------------------------------------------------------------------
#: The types whose cross and dot products are generated as straight-line code (small tables; the others loop).
GENERATED = ("tetra", "tetra10", "pyramid", "wedge", "hexahedron")
#: The types whose scaled Jacobian is generated as straight-line code (quality.SAMPLES' types).
SJ_GENERATED = ("tetra", "pyramid", "wedge", "hexahedron")
GENERATED_FILE = _HERE / "generated.py"
TINY = 2.2250738585072014e-308  # the smallest normal double: edge products below it give 0 (Verdict)


def code_fingerprint(t) -> str:
    """SHA-256 of what a type's generated code is computed from: its control points, columns and product tables."""
    h = hashlib.sha256()
    for a in (t.cptr, t.cidx_, t.cval, t.col_a, t.col_b, t.col_w, t.col_off, t.xp, t.xi, t.xj, t.xw, t.dp, t.di,
              t.dj, t.dw):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(f"{t.nx} {t.nb}".encode())
    return h.hexdigest()


def nodes_only(t) -> bool:
    """Whether every control point of the type is exactly one node with weight 1 (the linear types)."""
    return bool(np.all(np.diff(t.cptr) == 1) and np.all(t.cval[t.cptr[:-1]] == 1.0))


@lru_cache(maxsize=1)
def generated_fingerprints() -> dict:
    """{type: fingerprint of the tables its code in generated.py was generated from}, from the file's header."""
    try:
        lines = GENERATED_FILE.read_text().splitlines()
    except OSError:
        return {}
    out = {}
    for line in lines:
        for head, key in (("# code of ", ""), ("# scaled Jacobian of ", "sj:")):
            if line.startswith(head):
                name, fp = line[len(head):].split(": ")
                out[key + name] = fp
    return out


def sj_fingerprint(name) -> str:
    """SHA-256 of what a type's generated scaled Jacobian is computed from: sj_tables and the type's rule."""
    h = hashlib.sha256()
    vptr, vnode, vw, samp, ssign, factor = sj_tables(name)
    for a in (vptr, vnode, vw, samp, ssign):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(f"{factor!r} {name in ('tetra', 'pyramid')} {name == 'pyramid'}".encode())
    return h.hexdigest()


def sj_id(name) -> int:
    """1 + the type's index in SJ_GENERATED if generated.py holds its scaled Jacobian for the current samples,
    else 0 (the table loop)."""
    if name not in SJ_GENERATED or generated_fingerprints().get("sj:" + name) != sj_fingerprint(name):
        return 0
    return SJ_GENERATED.index(name) + 1


def generated_id(t) -> int:
    """1 + the type's index in GENERATED if generated.py holds its products for these very tables, else 0."""
    if t.name not in GENERATED or generated_fingerprints().get(t.name) != code_fingerprint(t):
        return 0
    return GENERATED.index(t.name) + 1



def _nonzero_columns(S) -> np.ndarray:
    """For matrices S (..., n, n): per row the count of nonzero entries, then their columns, ascending."""
    out = np.zeros(S.shape[:-1] + (S.shape[-1] + 1,), dtype=np.int64)
    for ix in np.ndindex(*S.shape[:-1]):
        cols = np.flatnonzero(S[ix] != 0.0)
        out[ix + (0,)] = cols.size
        out[ix][1:1 + cols.size] = cols
    return out


def _composed_child_maps(sp) -> np.ndarray:
    """(children, 3, 4): the map of each child of a box (row-major over the factors' child indices)."""
    out = []
    for combo in np.ndindex(*[int(c) for c in sp.nchildren]):
        A = np.eye(3)
        o = np.zeros(3)
        for f, c in enumerate(combo):  # the factors act on disjoint coordinates: the order does not matter
            Mk = sp.child_maps[f, c]
            o = o + A @ Mk[:, 3]
            A = A @ Mk[:, :3]
        out.append(np.hstack([A, o[:, None]]))
    return np.array(out)


_TABLES = {}
TABLE_FILE = _HERE / "tables.npz"
TABLE_FIELDS = ("cptr", "cidx_", "cval", "col_a", "col_b", "col_w", "col_off", "xp", "xi", "xj", "xw", "dp", "di",
                "dj", "dw", "consts", "sizes", "S", "Snz", "nchildren", "cmaps", "bptr", "bidx", "bvert", "ctrl", "vidx",
                "cidx", "M", "Mptr", "Midx", "Mval", "exps", "G", "h", "fdim", "fslot", "fexp", "fcoef")
TABLE_SCALARS = ("nb", "n_nodes", "nctrl", "nx")


def tables_fingerprint() -> str:
    """SHA-256 of the sources the tables come from (the registry, the formulation, this module)."""
    h = hashlib.sha256()
    for path in TABLE_SOURCES:
        h.update(path.read_bytes())
    return h.hexdigest()


def write_tables(path=TABLE_FILE) -> str:
    """Compute every type's tables (exact rational arithmetic, rounded) and save them for fast loading."""
    from ..cells.elements import CELL_TYPES

    data = {"fingerprint": np.array(tables_fingerprint())}
    for name in CELL_TYPES:
        t = Tables(name)
        for f in TABLE_FIELDS:
            data[f"{name}/{f}"] = getattr(t, f)
        for f in TABLE_SCALARS:
            data[f"{name}/{f}"] = np.array(getattr(t, f))
    tmp = Path(path).with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **data)  # (the high orders' child matrices are mostly zeros)
    os.replace(tmp, path)
    return str(path)


_SAVED = None


def saved_tables(name):
    """The tables of a type from the file written at build time, if it exists and matches the sources (only
    that type's arrays are read)."""
    global _SAVED
    if _SAVED is None:
        _SAVED = False
        try:
            z = np.load(TABLE_FILE)
            if str(z["fingerprint"]) == tables_fingerprint():
                _SAVED = z
        except (OSError, KeyError, ValueError):
            pass
    if not _SAVED or f"{name}/nb" not in _SAVED.files:
        return None
    t = Tables.__new__(Tables)
    t.name = name
    for f in TABLE_FIELDS:
        setattr(t, f, np.ascontiguousarray(_SAVED[f"{name}/{f}"]))
    for f in TABLE_SCALARS:
        setattr(t, f, int(_SAVED[f"{name}/{f}"]))
    return t


def tables(name: str) -> Tables:
    """The kernel's tables of a cell type: from the file written at build time, else computed (once per process)."""
    if name not in _TABLES:
        _TABLES[name] = saved_tables(name) or Tables(name)
    return _TABLES[name]



@lru_cache(maxsize=None)
def sj_tables(name):
    """The scaled Jacobian's sample matrices G (K, n, 3) of :data:`quality.SAMPLES` as distinct columns up to
    sign: (vptr, vnode, vw) the columns' nonzero weights in node order, samp (K, 3) each sample's columns,
    ssign (K,) the product of their signs, and the ideal cell's factor."""
    from ..cells.quality import SAMPLES

    G, factor = SAMPLES[name]
    cols, samp, ssign = [], np.zeros((G.shape[0], 3), dtype=np.int64), np.ones(G.shape[0])
    for k in range(G.shape[0]):
        for d in range(3):
            c = np.asarray(G[k][:, d], dtype=np.float64)
            for i, e in enumerate(cols):
                if np.array_equal(e, c) or np.array_equal(e, -c):
                    samp[k, d] = i
                    ssign[k] *= 1.0 if np.array_equal(e, c) else -1.0
                    break
            else:
                cols.append(c)
                samp[k, d] = len(cols) - 1
    nz = [np.flatnonzero(c) for c in cols]
    vptr = np.cumsum([0] + [len(z) for z in nz]).astype(np.int64)
    vnode = np.concatenate(nz).astype(np.int64)
    vw = np.concatenate([c[z] for c, z in zip(cols, nz)])
    return vptr, vnode, vw, samp, ssign, float(factor)

