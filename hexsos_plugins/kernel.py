"""The compiled kernel: det J's Bernstein coefficients with rigorous bounds, certified brackets, polish.

One compiled path for every cell type, driven by the tables of :mod:`hexsos_plugins.jacobian` (numba,
``cache=True``). Per cell:

1. **coefficients**: the nodes are scaled by a power of two 2^-k (the cell's extent lands in [1, 2):
   nothing overflows, whatever the units) and taken relative to node 0; the geometry's control points
   (sparse tables of dyadic weights; a control point that is a node is copied, with no rounding term), the
   Jacobian's columns (scaled differences of control points) and det J = x_r . (x_s x x_t) by Bernstein
   products give the coefficients ``b`` and a rigorous bound ``err`` on ``|b - b_exact|`` for the cell *as
   given*, with relative rounding (u = 2^-53) and absolute underflow (eta = 2^-1074) terms (derivation:
   :mod:`hexsos_plugins.jacobian`). The size of det J's terms is the permanent ``perm(A)`` of the largest
   |column coefficient| per component and direction: it scales like det J under any scaling of the axes.
   For the types with small tables (:data:`GENERATED`) the cross and dot products (and, for the linear types,
   whose control points are their nodes, the columns) run as straight-line code generated from the tables
   (``_kernel_gen.py``, :func:`write_generated`: the same operations in the same order, so the same results
   bit for bit; used only while its recorded fingerprint matches the tables');
2. **bracket**: best-first branch-and-bound over boxes (lines halved, triangles and tetrahedra cut into 4
   and 8 by their edge midpoints: fixed matrices with dyadic entries), pruning boxes whose smallest
   coefficient minus its error bound is above the best value found minus the tolerance; the smallest bound
   of all boxes is a proven lower bound, the vertex coefficients are values (the upper bound);
3. **polish**: projected Newton from the best vertex (monomial form; the reference element's faces as
   active constraints), kept only where it lowers the value;
4. **witness**: the value at the final point from the root coefficients, with explicit non-negative basis
   weights, and its rounding bound.

No fastmath anywhere: every bound assumes IEEE-754 round-to-nearest per operation (a fused multiply-add only
removes a rounding; reassociation would break the bounds). The chunk functions release the GIL, so cells run
in parallel on Python threads (:func:`set_threads`); each chunk owns its scratch arrays, nothing is pickled, and
a small call runs in the calling thread at once.
"""

from __future__ import annotations

import hashlib
import os
from functools import lru_cache
from math import factorial, prod
from pathlib import Path

import numpy as np

from .jacobian import _indices as _factor_indices
from .jacobian import space

__all__ = ["run_cells", "coefficients", "evaluate", "polish", "scaled_jacobian", "det_at", "tables", "Tables",
           "set_threads", "implementation",
           "U", "ETA"]

U = 2.0**-53  # unit roundoff
ETA = 2.0**-1074  # smallest subnormal: bounds the error of any rounding in the subnormal range
_NO_EXTENT = -100000  # scaling exponent of a cell whose nodes all coincide
_CHUNK = 4096  # cells per task on a thread (each task allocates its scratch once)

# --- Python-facing wrappers ------------------------------------------------------------------------------------------
def source_hash() -> str:
    """SHA-256 of the kernel's source (:mod:`hexsos_plugins._kernel_src` and the products generated from the
    tables, :mod:`hexsos_plugins._kernel_gen`): the compiled extension records it."""
    h = hashlib.sha256()
    for name in ("_kernel_src.py", "_kernel_gen.py"):
        h.update(Path(__file__).with_name(name).read_bytes())
    return h.hexdigest()


def _load():
    """The compiled extension if it exists and was built from this source (``HEXSOS_KERNEL=jit`` forces the
    just-in-time path, ``=aot`` requires the extension); else numba's just-in-time compilation of the source."""
    want = os.environ.get("HEXSOS_KERNEL", "").lower()
    if want != "jit":
        try:
            from . import _kernel_aot as aot

            if aot.source_hash_prefix() == int(source_hash()[:15], 16):
                return aot, "aot"
            if want == "aot":
                raise ImportError("hexsos_plugins._kernel_aot was built from another source")
        except ImportError:
            if want == "aot":
                raise
    from . import _kernel_src as jit

    return jit, "jit"


_impl, _KIND = _load()


def implementation() -> str:
    """``"aot"`` (the extension compiled at install) or ``"jit"`` (numba, compiled at first use, cached)."""
    return _KIND


def _jit_cached(dispatcher):
    """Whether numba's cache holds machine code of this ``cache=True`` function for its current source (None:
    numba's cache cannot be read)."""
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # numba's cache internals: unknown, not an error
        return None


def compiles_at_first_use() -> bool:
    """Whether the kernel runs just in time with nothing cached for this source yet: its first call compiles it
    (one to two minutes, once)."""
    return _KIND == "jit" and _jit_cached(_impl.run_chunk) is False


_DIMS = {"line": 1, "tri": 2, "tet": 3}


class Tables:
    """One cell type's tables (:func:`hexsos_plugins.jacobian.formulation` and :func:`~hexsos_plugins.jacobian.space`)
    in the kernel's array layout (floats rounded from the exact rationals)."""

    def __init__(self, name, generated=True):
        from .jacobian import formulation

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
        # consts[6]: the number of this type's generated products in _kernel_gen (0: the table loops), only if
        # that file was generated from these very tables
        gid = _generated_id(self) if generated else 0
        self.consts = np.array([c_rel, c_abs, level_rel, level_abs, eval_rel, eval_abs, float(gid)])
        self.sizes = sp.sizes.astype(np.int64)
        self.S = np.ascontiguousarray(sp.S)
        # the child matrices' nonzero columns by row (25-37% of a simplex factor's entries): Snz[k, c, r, 0] of
        # them, in Snz[k, c, r, 1:] ascending (the subdivision sums only these: the same numbers)
        self.Snz = _nonzero_columns(self.S)
        self.nchildren = sp.nchildren.astype(np.int64)
        self.cmaps = np.ascontiguousarray(_composed_child_maps(sp))
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
            for j, alpha in enumerate(_factor_indices(kind, p)):
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
_GEN_FILE = Path(__file__).with_name("_kernel_gen.py")
_TINY = 2.2250738585072014e-308  # the smallest normal double: edge products below it give 0 (Verdict)


def _code_fingerprint(t) -> str:
    """SHA-256 of what a type's generated code is computed from: its control points, columns and product tables."""
    h = hashlib.sha256()
    for a in (t.cptr, t.cidx_, t.cval, t.col_a, t.col_b, t.col_w, t.col_off, t.xp, t.xi, t.xj, t.xw, t.dp, t.di,
              t.dj, t.dw):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(f"{t.nx} {t.nb}".encode())
    return h.hexdigest()


def _nodes_only(t) -> bool:
    """Whether every control point of the type is exactly one node with weight 1 (the linear types)."""
    return bool(np.all(np.diff(t.cptr) == 1) and np.all(t.cval[t.cptr[:-1]] == 1.0))


@lru_cache(maxsize=1)
def _generated_fingerprints() -> dict:
    """{type: fingerprint of the tables its code in _kernel_gen.py was generated from}, from the file's header."""
    try:
        lines = _GEN_FILE.read_text().splitlines()
    except OSError:
        return {}
    out = {}
    for line in lines:
        for head, key in (("# code of ", ""), ("# scaled Jacobian of ", "sj:")):
            if line.startswith(head):
                name, fp = line[len(head):].split(": ")
                out[key + name] = fp
    return out


def _sj_fingerprint(name) -> str:
    """SHA-256 of what a type's generated scaled Jacobian is computed from: sj_tables and the type's rule."""
    h = hashlib.sha256()
    vptr, vnode, vw, samp, ssign, factor = sj_tables(name)
    for a in (vptr, vnode, vw, samp, ssign):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(f"{factor!r} {name in ('tetra', 'pyramid')} {name == 'pyramid'}".encode())
    return h.hexdigest()


def _sj_id(name) -> int:
    """1 + the type's index in SJ_GENERATED if _kernel_gen.py holds its scaled Jacobian for the current samples,
    else 0 (the table loop)."""
    if name not in SJ_GENERATED or _generated_fingerprints().get("sj:" + name) != _sj_fingerprint(name):
        return 0
    return SJ_GENERATED.index(name) + 1


def _generated_id(t) -> int:
    """1 + the type's index in GENERATED if _kernel_gen.py holds its products for these very tables, else 0."""
    if t.name not in GENERATED or _generated_fingerprints().get(t.name) != _code_fingerprint(t):
        return 0
    return GENERATED.index(t.name) + 1


def generated_source() -> str:
    """The text of _kernel_gen.py: for each type of GENERATED, its cross product (columns 1 x 2) and dot product
    (column 0 . X) as straight-line code with the tables' weights and indices as constants, the same operations
    in the same order as the table loops of _kernel_src (so the same results, bit for bit), and ``products``,
    which runs the type's (returns False for a type without); for the types whose control points are their
    nodes also the columns (``columns``, likewise)."""
    tabs = [Tables(name, generated=False) for name in GENERATED]
    out = ['"""Generated by hexsos_plugins.kernel.write_generated() from the tables: do not edit."""']
    out += [f"# code of {t.name}: {_code_fingerprint(t)}" for t in tabs]
    out += [f"# scaled Jacobian of {name}: {_sj_fingerprint(name)}" for name in SJ_GENERATED]
    out += ["", "import math", "", "from numba import njit", "", "U = 2.0**-53  # unit roundoff", "F = 1.0 + 4.0 * U",
            ""]
    for t in tabs:
        name = t.name
        o0, o1, o2 = (int(v) for v in t.col_off[:3])
        body = []
        if _nodes_only(t):
            out += _columns_source(t)
        for g in range(t.nx):
            terms = [(o1 + int(t.xi[q]), o2 + int(t.xj[q]), repr(float(t.xw[q]))) for q in range(t.xp[g], t.xp[g + 1])]
            body.append("    s0 = s1 = s2 = 0.0")
            for a, b, w in terms:
                body.append(f"    s0 += {w} * (col[{a}, 1] * col[{b}, 2] - col[{a}, 2] * col[{b}, 1])")
                body.append(f"    s1 += {w} * (col[{a}, 2] * col[{b}, 0] - col[{a}, 0] * col[{b}, 2])")
                body.append(f"    s2 += {w} * (col[{a}, 0] * col[{b}, 1] - col[{a}, 1] * col[{b}, 0])")
            body.append(f"    X[{g}, 0] = s0")
            body.append(f"    X[{g}, 1] = s1")
            body.append(f"    X[{g}, 2] = s2")
        for i in range(t.nb):
            body.append("    s0 = 0.0")
            for q in range(t.dp[i], t.dp[i + 1]):
                a, j, w = o0 + int(t.di[q]), int(t.dj[q]), repr(float(t.dw[q]))
                body.append(f"    tt = col[{a}, 0] * X[{j}, 0]")
                body.append(f"    tt += col[{a}, 1] * X[{j}, 1]")
                body.append(f"    tt += col[{a}, 2] * X[{j}, 2]")
                body.append(f"    s0 += {w} * tt")
            body.append(f"    b[{i}] = s0")
        out += ["", '@njit(cache=True, nogil=True, inline="always")', f"def _products_{name}(col, X, b):",
                f'    """{name}: X = column 1 x column 2, b = column 0 . X."""'] + body + [""]
    out += ["", '@njit(cache=True, nogil=True, inline="always")', "def columns(gid, D, col, A, E):",
            '    """The columns of the type with this generated id, read from its nodes; False if it has none."""']
    for gid, t in enumerate(tabs, start=1):
        if _nodes_only(t):
            out += [f"    if gid == {gid}:", f"        _columns_{t.name}(D, col, A, E)", "        return True"]
    out += ["    return False", ""]
    with_columns = [gid for gid, t in enumerate(tabs, start=1) if _nodes_only(t)]
    out += ["", '@njit(cache=True, nogil=True, inline="always")', "def has_columns(gid):",
            '    """Whether the type with this generated id has generated columns."""',
            f"    return {' or '.join(f'gid == {g}' for g in with_columns) or 'False'}", ""]
    out += ["", '@njit(cache=True, nogil=True, inline="always")', "def products(gid, col, X, b):",
            '    """The products of the type with this generated id (kernel.GENERATED); False if it has none."""']
    for gid, name in enumerate(GENERATED, start=1):
        out += [f"    if gid == {gid}:", f"        _products_{name}(col, X, b)", "        return True"]
    out += ["    return False", ""]
    out += ["", '@njit(cache=True, nogil=True, inline="always")', "def products_only(gid, col, X, b):",
            '    """products for the types without generated columns (the others take both, in their own loop)."""']
    for gid, t in enumerate(tabs, start=1):
        if not _nodes_only(t):
            out += [f"    if gid == {gid}:", f"        _products_{t.name}(col, X, b)", "        return True"]
    out += ["    return False", ""]
    for name in SJ_GENERATED:
        out += _sj_source(name)
    out += ["", "@njit(cache=True, nogil=True)", "def scaled_jacobian_loop(sid, points, conn, ids, start, stop, out):",
            '    """The scaled Jacobian of cells ids[start:stop] of the type with this id (SJ_GENERATED) into out;',
            '    False for an id without generated code."""']
    for sid, name in enumerate(SJ_GENERATED, start=1):
        out += [f"    if sid == {sid}:", "        for t in range(start, stop):",
                f"            out[t] = _sj_{name}(points, conn, ids[t])", "        return True"]
    out += ["    return False", ""]
    return "\n".join(out)


def _sj_source(name) -> list:
    """Straight-line code of a linear type's scaled Jacobian: the loops of _kernel_src's scaled_jacobian_chunk
    with sj_tables' nodes, weights and samples as constants, the same operations in the same order."""
    vptr, vnode, vw, samp, ssign, factor = sj_tables(name)
    grouped, reflect = name in ("tetra", "pyramid"), name == "pyramid"
    used = sorted({int(q) for q in vnode})
    lines = ["", '@njit(cache=True, nogil=True, inline="always")', f"def _sj_{name}(points, conn, m):",
             f'    """{name}: Verdict\'s scaled Jacobian of cell m (see _kernel_src.scaled_jacobian_chunk)."""']
    lines += [f"    i{i} = conn[m, {i}]" for i in used]
    lines += [f"    x{i}_{a} = points[i{i}, {a}]" for i in used for a in range(3)]
    for v in range(len(vptr) - 1):
        for a in range(3):
            lines.append(f"    v{v}_{a} = 0.0")
            for q in range(vptr[v], vptr[v + 1]):
                lines.append(f"    v{v}_{a} += {float(vw[q])!r} * x{int(vnode[q])}_{a}")
        lines.append(f"    n{v} = math.sqrt(v{v}_0 * v{v}_0 + v{v}_1 * v{v}_1 + v{v}_2 * v{v}_2)")
    lines.append("    best = math.inf")
    for k in range(samp.shape[0]):
        a, b, c = (int(x) for x in samp[k])
        lines.append(f"    det = (v{a}_0 * (v{b}_1 * v{c}_2 - v{b}_2 * v{c}_1) - v{b}_0 * (v{a}_1 * v{c}_2 - v{a}_2 * v{c}_1)"
                     f" + v{c}_0 * (v{a}_1 * v{b}_2 - v{a}_2 * v{b}_1)) * {float(ssign[k])!r}")
        lines.append(f"    lengths = n{a} * n{b} * n{c}")
        if grouped:
            if k % 4 == 0:
                lines += ["    gdet = det", "    gbig = lengths"]
            else:
                lines += ["    if lengths > gbig:", "        gbig = lengths"]
            if k % 4 == 3:
                lines += [f"    val = {factor!r} * gdet / gbig if gbig > {_TINY!r} else 0.0",
                          "    if val < best:", "        best = val"]
        else:
            lines += [f"    val = {factor!r} * det / lengths if lengths > {_TINY!r} else 0.0",
                      "    if val < best:", "        best = val"]
    if reflect:
        lines += ["    if best > 1.0:", "        best = 2.0 - best"]
    return lines + ["    return best", ""]


def _columns_source(t) -> list:
    """Straight-line code of a nodes-only type's columns: the column loop of _kernel_src's _cell_coefficients
    with the node rows, weights and offsets as constants. Each control point is a node, exact, so the loop's
    error terms are U |v| + w (0 + 0) = U |v|; their maximum is U times the largest |v| (a product by U rounds
    monotonically), which is how it is formed here: the same A and E bit for bit."""
    lines = ["", '@njit(cache=True, nogil=True, inline="always")', f"def _columns_{t.name}(D, col, A, E):",
             f'    """{t.name}: the columns\' coefficients col, their largest magnitudes A and errors E."""']
    for d in range(3):
        lines.append("    a0 = a1 = a2 = 0.0")
        for e in range(int(t.col_off[d]), int(t.col_off[d + 1])):
            ra, rb = int(t.cidx_[t.col_a[e]]), int(t.cidx_[t.col_b[e]])
            w = repr(float(t.col_w[e]))
            for c in range(3):
                lines.append(f"    v{c} = {w} * (D[{rb}, {c}] - D[{ra}, {c}])")
                lines.append(f"    col[{e}, {c}] = v{c}")
                lines.append(f"    a{c} = max(a{c}, abs(v{c}))")
        lines.append(f"    A[0, {d}], A[1, {d}], A[2, {d}] = a0, a1, a2")
        lines.append(f"    E[0, {d}], E[1, {d}], E[2, {d}] = U * a0 * F, U * a1 * F, U * a2 * F")
    return lines + [""]


def write_generated(path=_GEN_FILE) -> str:
    """Write _kernel_gen.py from the current tables (after an edit of the registry or the formulation)."""
    Path(path).write_text(generated_source())
    _generated_fingerprints.cache_clear()
    return str(path)


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
_TABLE_FILE = Path(__file__).with_name("_tables.npz")
_TABLE_FIELDS = ("cptr", "cidx_", "cval", "col_a", "col_b", "col_w", "col_off", "xp", "xi", "xj", "xw", "dp", "di",
                 "dj", "dw", "consts", "sizes", "S", "Snz", "nchildren", "cmaps", "ctrl", "vidx", "cidx", "M", "Mptr",
                 "Midx", "Mval", "exps", "G", "h", "fdim", "fslot", "fexp", "fcoef")
_TABLE_SCALARS = ("nb", "n_nodes", "nctrl", "nx")


def tables_fingerprint() -> str:
    """SHA-256 of the sources the tables come from (the registry, the formulation, this module)."""
    h = hashlib.sha256()
    for name in ("elements.py", "jacobian.py", "kernel.py", "_kernel_gen.py"):
        h.update(Path(__file__).with_name(name).read_bytes())
    return h.hexdigest()


def write_tables(path=_TABLE_FILE) -> str:
    """Compute every type's tables (exact rational arithmetic, rounded) and save them for fast loading."""
    from .elements import CELL_TYPES

    data = {"fingerprint": np.array(tables_fingerprint())}
    for name in CELL_TYPES:
        t = Tables(name)
        for f in _TABLE_FIELDS:
            data[f"{name}/{f}"] = getattr(t, f)
        for f in _TABLE_SCALARS:
            data[f"{name}/{f}"] = np.array(getattr(t, f))
    tmp = Path(path).with_suffix(".tmp.npz")
    np.savez(tmp, **data)
    os.replace(tmp, path)
    return str(path)


_SAVED = None


def _saved(name):
    """The tables of a type from the file written at build time, if it exists and matches the sources (only
    that type's arrays are read)."""
    global _SAVED
    if _SAVED is None:
        _SAVED = False
        try:
            z = np.load(_TABLE_FILE)
            if str(z["fingerprint"]) == tables_fingerprint():
                _SAVED = z
        except (OSError, KeyError, ValueError):
            pass
    if not _SAVED or f"{name}/nb" not in _SAVED.files:
        return None
    t = Tables.__new__(Tables)
    t.name = name
    for f in _TABLE_FIELDS:
        setattr(t, f, np.ascontiguousarray(_SAVED[f"{name}/{f}"]))
    for f in _TABLE_SCALARS:
        setattr(t, f, int(_SAVED[f"{name}/{f}"]))
    return t


def tables(name: str) -> Tables:
    """The kernel's tables of a cell type: from the file written at build time, else computed (once per process)."""
    if name not in _TABLES:
        _TABLES[name] = _saved(name) or Tables(name)
    return _TABLES[name]


_THREADS = 1  # threads the kernel may use (set_threads); chunks of _CHUNK cells are spread over them
_LIGHT_CHUNK = 32768  # cells per task of a pass of a few nanoseconds a cell (the verdicts): ~0.3 ms of work
_POOL = None
#: The Python threads that have run the kernel's chunks since this was last reset to an empty set (for tests and
#: benchmarks: a light pass's short tasks may all go to one thread, so one call alone proves little).
last_threads: set = set()


def cores() -> int:
    """The cores this process may run on (its CPU affinity, which a container or ``taskset`` narrows)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not on Linux
        return os.cpu_count() or 1


def set_threads(n: int) -> int:
    """Let the kernel use n threads (its chunk functions release the GIL); returns the previous setting."""
    global _THREADS
    old, _THREADS = _THREADS, max(1, int(n))
    return old


def _spread(fn, n_ids, args_of, min_chunk=_CHUNK):
    """fn(*args_of(start, stop)) over chunks of cells: inline for one thread or a small input, else on a pool,
    each task at least ``min_chunk`` cells (more for a light pass, whose cells take nanoseconds)."""
    global _POOL, last_threads
    if _THREADS <= 1 or n_ids <= min_chunk:
        fn(*args_of(0, n_ids))
        return
    import threading
    from concurrent.futures import ThreadPoolExecutor

    if _POOL is None or _POOL._max_workers != _THREADS:
        _POOL = ThreadPoolExecutor(max_workers=_THREADS, thread_name_prefix="hexsos-kernel")
    # about four chunks per thread keeps them busy without many tiny tasks
    size = max(min_chunk, -(-n_ids // (4 * _THREADS)))
    seen = set()

    def task(start, stop):
        seen.add(threading.get_ident())
        fn(*args_of(start, stop))

    futures = [_POOL.submit(task, s, min(s + size, n_ids)) for s in range(0, n_ids, size)]
    for f in futures:
        f.result()
    last_threads = last_threads | seen


def _run_outputs(m):
    """Empty output arrays of run_cells for m cells."""
    return {"lower": np.empty(m), "value": np.empty(m), "argmin": np.empty((m, 3)), "err": np.empty(m),
            "scale": np.empty(m), "corner": np.empty(m), "depth": np.empty(m, dtype=np.int64),
            "closed": np.empty(m, dtype=np.bool_), "flat": np.empty(m, dtype=np.bool_),
            "k": np.empty(m, dtype=np.int64), "boxes": np.empty(m, dtype=np.int64), "lowroot": np.empty(m),
            "size": np.empty(m)}


def _run_args(points, conn, ids, t, out, start, stop, rtol=1e-9, flat_rtol=1e-12, max_depth=30, max_iter=2000,
              polish_iter=30, cap=256):
    """The arguments of the entry point run_chunk, in its order (also used to derive its compiled signature)."""
    return ((points, conn, ids, int(start), int(stop)) + t.formulation_args +
            (t.sizes, t.S, t.Snz, t.nchildren, t.cmaps, t.ctrl, t.vidx, t.cidx, t.Mptr, t.Midx, t.Mval, t.exps, t.G,
             t.h, t.fdim, t.fslot, t.fexp, t.fcoef, t.nctrl, t.nx, float(rtol), float(flat_rtol), int(max_depth),
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
        out = _run_outputs(m)
    _spread(_impl.run_chunk, m, lambda a, b: _run_args(points, conn, ids, t, out, a, b, rtol, flat_rtol, max_depth,
                                                        max_iter, polish_iter, cap))
    return out


def _coefficient_args(points, conn, ids, t, outs, start, stop):
    return (points, conn, ids, int(start), int(stop)) + t.formulation_args + (t.nctrl, t.nx) + tuple(outs)


def coefficients(points, conn, ids, name):
    """Bernstein coefficients (len(ids), nb) of the cells ``conn[ids]`` in scaled units, their error bounds,
    the scaling exponents k (world det J = scaled times 2^(3 k)) and the sizes of det J's terms."""
    t = tables(name)
    ids = np.ascontiguousarray(ids, dtype=np.int64)
    points = np.ascontiguousarray(points, dtype=np.float64)
    conn = np.ascontiguousarray(conn, dtype=np.int64)
    outs = (np.empty((ids.size, t.nb)), np.empty(ids.size), np.empty(ids.size, dtype=np.int64), np.empty(ids.size))
    _spread(_impl.coefficients_chunk, int(ids.size), lambda s, e: _coefficient_args(points, conn, ids, t, outs, s, e))
    return outs


def _evaluate_args(b, X, t, out):
    return (b, X, t.fdim, t.fslot, t.fexp, t.fcoef, t.sizes, int(t.S.shape[2]), out)


def _polish_args(b, X0, t, iterations, out, vals):
    return (b, X0, t.Mptr, t.Midx, t.Mval, t.exps, t.G, t.h, int(iterations), t.fdim, t.fslot, t.fexp, t.fcoef,
            t.sizes, int(t.S.shape[2]), out, vals)


def evaluate(b, X, name):
    """The polynomials with coefficients b (m, nb) at the points X (m, 3) (explicit Bernstein weights)."""
    t = tables(name)
    out = np.empty(np.shape(b)[0])
    _impl.evaluate(*_evaluate_args(np.ascontiguousarray(b, dtype=np.float64), np.ascontiguousarray(X, dtype=np.float64),
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
    _impl.polish_many(*_polish_args(b, X0, t, iterations, out, vals))
    return out, vals


@lru_cache(maxsize=None)
def sj_tables(name):
    """The scaled Jacobian's sample matrices G (K, n, 3) of :data:`quality.SAMPLES` as distinct columns up to
    sign: (vptr, vnode, vw) the columns' nonzero weights in node order, samp (K, 3) each sample's columns,
    ssign (K,) the product of their signs, and the ideal cell's factor."""
    from .quality import SAMPLES

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


def _sj_args(points, conn, ids, name, out, start, stop, generated=True):
    vptr, vnode, vw, samp, ssign, factor = sj_tables(name)
    return (points, conn, ids, int(start), int(stop), vptr, vnode, vw, samp, ssign, factor,
            name in ("tetra", "pyramid"), name == "pyramid", _sj_id(name) if generated else 0, out)


def scaled_jacobian(points, cells) -> np.ndarray:
    """Verdict's scaled Jacobian of every cell, compiled (the definitions and sample tables of
    :mod:`hexsos_plugins.quality`, which computes the same numbers with numpy). ``cells``: an (M, 8) hex array or
    (cell_type, conn) pairs. Quadratic cells get the value of their corner nodes' linear cell (their first
    nodes in VTK order), as Verdict computes hexahedron, wedge and tetrahedron metrics for any node count."""
    from .elements import ELEMENTS
    from .quality import SAMPLES, as_cell_list

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
            _spread(_impl.scaled_jacobian_chunk, conn.shape[0], lambda a, b: _sj_args(points, conn, ids, name, out, a, b))
        parts.append(out)
    return np.concatenate(parts) if parts else np.zeros(0)


def _det_at_args(points, conn, ids, dN, out, start, stop):
    return (points, conn, ids, int(start), int(stop), dN, out)


def det_at(points, conn, name, pcoords) -> np.ndarray:
    """det J (pyramids: the measure) of every cell ``conn`` (VTK order) of type ``name`` at one reference point,
    compiled, threaded as the kernel is. A sign test (no rounding bound): the orientation of node orders."""
    from .elements import element

    el = element(name)
    dN = np.ascontiguousarray(el.shape_derivatives(np.asarray(pcoords, dtype=np.float64).reshape(1, 3))[0])
    points = np.ascontiguousarray(points, dtype=np.float64)
    conn = np.ascontiguousarray(conn, dtype=np.int64)
    out = np.empty(conn.shape[0])
    ids = np.arange(conn.shape[0], dtype=np.int64)
    _spread(_impl.det_at_chunk, conn.shape[0], lambda a, b: _det_at_args(points, conn, ids, dN, out, a, b))
    return out


def _finish_outputs(m):
    return np.empty(m, dtype=np.int8), np.empty(m, dtype=np.bool_), np.empty(m, dtype=np.bool_)


def _finish_args(value, lower, err, corner, scale, k, flat, closed, status, near, bad, start, stop):
    return (value, lower, err, corner, scale, k, flat, closed, int(start), int(stop), status, near, bad)


def finish(value, lower, err, corner, scale, k, flat, closed):
    """The verdicts of cells from run_cells' outputs (scaled units), and their numbers in world units, in place
    (times 2^(3 k): exact where representable, else value, corner and scale to the nearest float of the same
    sign, lower to the largest float below; see _kernel_src.finish_chunk): returns status
    (1 valid: lower > 0; 0 invalid: value + err <= 0; -1 otherwise and where flat), near (undecided, not flat,
    and the bracket closed or the value within 64 err of 0: for the exact decision) and unrepresentable (value
    or lower). One compiled pass, threaded as the kernel is."""
    arrays = [np.ascontiguousarray(a, dtype=np.float64) for a in (value, lower, err, corner, scale)]
    if any(a is not b for a, b in zip(arrays, (value, lower, err, corner, scale))):
        raise TypeError("finish: expected contiguous float64 arrays (it writes them in place)")
    k = np.ascontiguousarray(k, dtype=np.int64)
    flat = np.ascontiguousarray(flat, dtype=np.bool_)
    closed = np.ascontiguousarray(closed, dtype=np.bool_)
    outs = _finish_outputs(value.shape[0])
    _spread(_impl.finish_chunk, value.shape[0], lambda a, b: _finish_args(*arrays, k, flat, closed, *outs, a, b),
            min_chunk=_LIGHT_CHUNK)
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
        "run_chunk": _run_args(P, conn, ids, t, _run_outputs(1), 0, 1),
        "coefficients_chunk": _coefficient_args(P, conn, ids, t, coeff_outs, 0, 1),
        "evaluate": _evaluate_args(b, X, t, np.empty(1)),
        "polish_many": _polish_args(b, X, t, 30, np.empty((1, 3)), np.empty(1)),
        "scaled_jacobian_chunk": _sj_args(P, conn, ids, "hexahedron", np.empty(1), 0, 1),
        "det_at_chunk": _det_at_args(P, conn, ids, np.zeros((8, 3)), np.empty(1), 0, 1),
        "finish_chunk": _finish_args(*(np.zeros(1) for _ in range(5)), np.zeros(1, dtype=np.int64),
                                     np.zeros(1, dtype=np.bool_), np.zeros(1, dtype=np.bool_),
                                     *_finish_outputs(1), 0, 1),
    }
