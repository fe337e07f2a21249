"""Sum-of-squares (SOSP) and moment (SOSD) relaxations of min det J over [0, 1]^3, solved with Clarabel.

For a polynomial f (det J of one hex) and constraint polynomials g_i >= 0 describing the cube, a
relaxation asks for the largest lambda with

    f - lambda = sigma_0 + sum_i sigma_i g_i,    sigma_i = m_i^T Q_i m_i,  Q_i PSD          (SOSP)

for monomial vectors m_i. Its conic dual is the moment relaxation (SOSD): minimize E_y[f] over
pseudo-moments y (y_0 = 1) with moment and localizing matrices PSD. Clarabel solves both at once: in
the *primal SOS form* below the dual variables of the coefficient-matching equalities are exactly the
moments y, and the dual variables of the Gram blocks are the moment and localizing matrices.

Registry (:data:`RELAXATIONS`)
------------------------------
``"quad2"`` (default)
    Order 2 with the quadratic box constraints u(1-u), v(1-v), w(1-w) >= 0: sigma_0 on monomials of
    degree <= 2 (10x10), sigma_i on degree <= 1 (4x4). Matches coefficients up to degree 4.
``"paper"``
    The paper's section 4.2: the six linear constraints u, 1-u, v, 1-v, w, 1-w, each multiplier an SOS
    of degree 4 (10x10), sigma_0 of degree 4. Matches coefficients up to degree 5.
Order 2 with the *linear* constraints is unbounded (the relaxation is not Archimedean at that degree)
and is deliberately not offered.

Clarabel's PSD cone takes the upper triangle of a symmetric matrix column by column with off-diagonal
entries times sqrt(2) (:func:`svec`); getting this wrong makes the solver report success on matrices
that are not PSD. Only the status ``Solved`` is taken as a solution; every other status is reported.

Neither objective of an interior-point solution is a rigorous bound. :meth:`SOSSolution.certified_lower`
turns the solution into one: it factors the Gram matrices into explicit squares (clipping negative
eigenvalues), computes the residual polynomial ``r = f - lambda - sum sigma_i g_i`` with a bound on its
rounding, and returns ``lambda - sum |r_alpha| - rounding``, a lower bound valid on the whole cube.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from itertools import product

import numpy as np

from ..errors import DependencyError, InvalidInputError, SolverError
from ..cells.hexahedron import MONOMIALS, UNIT_ROUND

__all__ = [
    "RELAXATIONS",
    "Relaxation",
    "SOSSolution",
    "SOSSolver",
    "SOSBatch",
    "svec",
    "smat",
    "monomials_upto",
    "paper_relaxation",
]

_SQRT2 = np.sqrt(2.0)


def monomials_upto(d: int):
    """Exponent triples of total degree <= d, graded then lexicographic (u first)."""
    return [m for m in sorted(product(range(d + 1), repeat=3), key=lambda m: (sum(m), tuple(-e for e in m)))
            if sum(m) <= d]


_SVEC_INDEX = {}


def _svec_index(n: int):
    """Rows, columns and weights of Clarabel's svec order for n x n: (0,0), (0,1), (1,1), (0,2), ..."""
    if n not in _SVEC_INDEX:
        rows = np.array([i for j in range(n) for i in range(j + 1)])
        cols = np.array([j for j in range(n) for i in range(j + 1)])
        _SVEC_INDEX[n] = (rows, cols, np.where(rows == cols, 1.0, _SQRT2))
    return _SVEC_INDEX[n]


def svec(S) -> np.ndarray:
    """Clarabel's vectorization of a symmetric n x n matrix: upper triangle column by column,
    off-diagonal entries times sqrt(2)."""
    return _svec_many(np.asarray(S, dtype=np.float64)[None])[0]


def smat(v, n: int) -> np.ndarray:
    """Inverse of :func:`svec`."""
    return _smat_many(np.asarray(v, dtype=np.float64)[None], n)[0]


def _svec_many(S) -> np.ndarray:
    """:func:`svec` of a stack (N, n, n)."""
    rows, cols, w = _svec_index(S.shape[1])
    return S[:, rows, cols] * w


def _smat_many(V, n: int) -> np.ndarray:
    """:func:`smat` of a stack of vectors (N, n(n+1)/2)."""
    rows, cols, w = _svec_index(n)
    S = np.empty((V.shape[0], n, n))
    vals = V / w
    S[:, rows, cols] = vals
    S[:, cols, rows] = vals
    return S


@dataclass(frozen=True)
class Relaxation:
    """A relaxation: blocks of (constraint polynomial g, multiplier basis); block 0 is g = 1."""

    name: str
    description: str
    blocks: tuple  # ((g as {exponent: coefficient}, (basis exponents...)), ...)

    @property
    def degree(self) -> int:
        return max(max(sum(e) for e in g) + 2 * max(sum(m) for m in basis) for g, basis in self.blocks)


def _box_quadratic():
    basis2, basis1 = tuple(monomials_upto(2)), tuple(monomials_upto(1))
    blocks = [({(0, 0, 0): 1.0}, basis2)]
    for ax in range(3):
        e1 = tuple(1 if i == ax else 0 for i in range(3))
        e2 = tuple(2 if i == ax else 0 for i in range(3))
        blocks.append(({e1: 1.0, e2: -1.0}, basis1))
    return tuple(blocks)


def _box_linear(degree: int = 4):
    half = degree // 2
    basis = tuple(monomials_upto(half))
    blocks = [({(0, 0, 0): 1.0}, basis)]
    for ax in range(3):
        e1 = tuple(1 if i == ax else 0 for i in range(3))
        blocks.append(({e1: 1.0}, basis))
        blocks.append(({(0, 0, 0): 1.0, e1: -1.0}, basis))
    return tuple(blocks)


def paper_relaxation(degree: int = 4) -> Relaxation:
    """The paper's relaxation with SOS multipliers (and sigma_0) of the given even degree (4, 6, 8, ...)."""
    if degree < 4 or degree % 2:
        raise InvalidInputError(f"degree: expected an even number >= 4, found {degree}")
    return Relaxation(f"paper{degree}" if degree != 4 else "paper",
                      f"degree-{degree} SOS multipliers on the six linear constraints (paper, section 4.2)",
                      _box_linear(degree))


#: The relaxations hexsos offers, by name.
RELAXATIONS = {
    "quad2": Relaxation("quad2", "order 2, quadratic box constraints u(1-u), v(1-v), w(1-w)", _box_quadratic()),
    "paper": paper_relaxation(4),
}


def _structure(relax: Relaxation):
    """Support monomials and, per block, the (support x svec) matrix mapping svec(Q) to coefficients."""
    import scipy.sparse as sp  # imported here: the registry costs nothing until a solver is built

    support = monomials_upto(relax.degree)
    index = {m: i for i, m in enumerate(support)}
    mats = []
    for g, basis in relax.blocks:
        n = len(basis)
        rows, cols, vals = [], [], []
        k = 0
        for j in range(n):
            for i in range(j + 1):
                w = 1.0 if i == j else _SQRT2  # Q_ij + Q_ji = sqrt(2) * svec entry
                for ge, gc in g.items():
                    e = tuple(ge[t] + basis[i][t] + basis[j][t] for t in range(3))
                    rows.append(index[e])
                    cols.append(k)
                    vals.append(w * gc)
                k += 1
        mats.append(sp.csc_matrix((vals, (rows, cols)), shape=(len(support), k)))
    return support, index, mats


@dataclass
class SOSSolution:
    """The outcome of one relaxation solve (values in det J units)."""

    status: str  # Clarabel's status, e.g. "Solved", "AlmostSolved", "MaxIterations"
    value: float  # the relaxation's optimum (NaN unless Clarabel reports Solved)
    argmin: np.ndarray  # (3,) first moments, clipped to [0, 1]
    recovery_ratio: float  # lambda_2 / lambda_1 of the moment matrix (0 for exact rank one)
    iterations: int
    seconds: float
    moments: np.ndarray = field(repr=False, default=None)  # y over the support monomials
    gram: list = field(repr=False, default=None)  # Gram matrices Q_i (normalized units)
    lam: float = float("nan")  # lambda of the certificate (normalized units)
    scale: float = 1.0
    relaxation: str = "quad2"

    @property
    def solved(self) -> bool:
        return self.status == "Solved"


class SOSSolver:
    """Solves one relaxation for many hexes, reusing one Clarabel solver.

    Parameters
    ----------
    relaxation : str or Relaxation, keyword-only
        A name of :data:`RELAXATIONS` (default ``"quad2"``), or a :class:`Relaxation` such as
        ``paper_relaxation(6)``.
    tol : float, keyword-only
        Clarabel's gap and feasibility tolerances. Default 1e-8.
    max_iter : int, keyword-only
        Clarabel's iteration cap. Default 100.
    """

    def __init__(self, *, relaxation="quad2", tol: float = 1e-8, max_iter: int = 100):
        if isinstance(relaxation, Relaxation):
            relax = relaxation
        elif relaxation in RELAXATIONS:
            relax = RELAXATIONS[relaxation]
        else:
            raise InvalidInputError(f"unknown relaxation {relaxation!r}: expected one of {sorted(RELAXATIONS)}")
        import scipy.sparse as sp

        try:
            import clarabel
        except ImportError as exc:  # pragma: no cover - clarabel is a core dependency
            raise DependencyError("the SOS relaxation needs clarabel: pip install clarabel") from exc
        self._clarabel = clarabel
        self.relaxation = relax
        self.support, self.index, self.block_maps = _structure(self.relaxation)
        # dense copies for the certificate check (at most 56 x 55: dense products beat sparse ones here)
        self._dense_maps = [Am.toarray() for Am in self.block_maps]
        self._abs_maps = [np.abs(D) for D in self._dense_maps]
        self.sizes = [len(b) for _, b in self.relaxation.blocks]
        self._fidx = np.array([self.index[m] for m in MONOMIALS])
        ns = len(self.support)
        nq = [Am.shape[1] for Am in self.block_maps]
        self._offsets = np.cumsum([1] + nq)
        # primal SOS form: x = [lambda, svec(Q_0), svec(Q_1), ...]; minimize -lambda
        #   rows 0..ns-1 (zero cone): lambda [alpha = 0] + sum_i A_i svec(Q_i) = f
        #   then per block (PSD cone): -svec(Q_i) + s = 0
        e0 = sp.csc_matrix(([1.0], ([self.index[(0, 0, 0)]], [0])), shape=(ns, 1))
        A_eq = sp.hstack([e0] + self.block_maps)
        A_psd = sp.hstack([sp.csc_matrix((sum(nq), 1)), -sp.identity(sum(nq))])
        self._A = sp.vstack([A_eq, A_psd]).tocsc()
        self._P = sp.csc_matrix((self._A.shape[1], self._A.shape[1]))
        self._q = np.zeros(self._A.shape[1])
        self._q[0] = -1.0
        self._cones = [clarabel.ZeroConeT(ns)] + [clarabel.PSDTriangleConeT(n) for n in self.sizes]
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        settings.tol_gap_abs = tol
        settings.tol_gap_rel = tol
        settings.tol_feas = tol
        settings.max_iter = max_iter
        # measured: iterative refinement costs ~20% and changed no status on the paper's families; the
        # certificate check (certified_lower) makes the result rigorous either way
        settings.iterative_refinement_enable = False
        # data updates (solver reuse) need these off
        settings.presolve_enable = False
        settings.chordal_decomposition_enable = False
        settings.input_sparse_dropzeros = False
        self._settings = settings
        self._solver = None
        self._ns = ns

    def _rhs(self, coeffs):
        b = np.zeros(self._A.shape[0])
        b[self._fidx] = coeffs
        return b

    def _scales(self, C, scales):
        if scales is None:
            scales = np.abs(C).max(axis=0)
        scales = np.array(scales, dtype=np.float64).reshape(-1)
        scales[~np.isfinite(scales) | (scales <= 0.0)] = 1.0
        return scales

    def solve(self, coeffs, scale: float | None = None) -> SOSSolution:
        """Solve the relaxation for one hex.

        Parameters
        ----------
        coeffs : array_like, shape (20,)
            Monomial coefficients of det J in the order of :data:`~hexsos_plugins.cells.hexahedron.MONOMIALS`.
        scale : float, optional
            Divide the coefficients by this before solving (default: their largest magnitude).
        """
        C = np.asarray(coeffs, dtype=np.float64).reshape(-1, 1)
        r = self.solve_many(C, None if scale is None else [scale], keep=True)
        return SOSSolution(status=r.status[0], value=float(r.value[0]), argmin=r.argmin[0],
                           recovery_ratio=float(r.recovery_ratio[0]), iterations=int(r.iterations[0]),
                           seconds=float(r.seconds[0]), moments=r.moments[0], gram=[Q[0] for Q in r.gram],
                           lam=float(r.lam[0]), scale=float(r.scale[0]), relaxation=self.relaxation.name)

    def solve_many(self, C, scales=None, coeff_err=None, *, keep: bool = False) -> "SOSBatch":
        """Solve the relaxation for many hexes, one Clarabel solve each (the solver reused; Clarabel releases
        the GIL while it solves), then everything else for all of them at once: the moments and their point,
        the recovery ratio and, with ``coeff_err``, the certified lower bounds (:meth:`certified_lower`).

        Parameters
        ----------
        C : array_like, shape (20, N)
            Monomial coefficients of det J per hex (columns).
        scales : array_like (N,), optional
            Divide each hex's coefficients by this before solving (default: their largest magnitude).
        coeff_err : array_like (N,), optional
            A bound on the error of each hex's coefficients (det J units): certified lower bounds are returned.
        keep : bool
            Also return the Gram matrices and the moments.
        """
        C = np.asarray(C, dtype=np.float64)
        n = C.shape[1]
        scales = self._scales(C, scales)
        F = np.zeros((n, self._A.shape[0]))
        F[:, self._fidx] = (C / scales).T
        nx, nz = self._A.shape[1], self._A.shape[0]
        X = np.full((n, nx), np.nan)
        Z = np.full((n, nz), np.nan)
        status, iterations, seconds = [], np.zeros(n, dtype=np.int64), np.zeros(n)
        for j in range(n):
            t0 = time.perf_counter()
            try:
                if self._solver is None:
                    self._solver = self._clarabel.DefaultSolver(self._P, self._q, self._A, F[j], self._cones,
                                                                self._settings)
                else:
                    self._solver.update(b=F[j])
                sol = self._solver.solve()
            except Exception as exc:  # Clarabel raises plain exceptions on malformed data
                raise SolverError(f"Clarabel failed to run the {self.relaxation.name!r} relaxation: {exc}") from exc
            seconds[j] = time.perf_counter() - t0
            status.append(str(sol.status))
            X[j] = sol.x
            Z[j] = sol.z
            iterations[j] = sol.iterations
        solved = np.array([st == "Solved" for st in status], dtype=bool)  # the rest is reported, never used
        lam = X[:, 0].copy()
        gram = [_smat_many(X[:, self._offsets[i] : self._offsets[i + 1]], m) for i, m in enumerate(self.sizes)]
        y = Z[:, : self._ns].copy()
        M0 = _smat_many(Z[:, self._ns : self._ns + self.block_maps[0].shape[1]], self.sizes[0])
        ratio = np.full(n, np.nan)
        good = np.isfinite(M0).all(axis=(1, 2))
        if good.any():
            try:
                ev = np.linalg.eigvalsh(M0[good])
            except np.linalg.LinAlgError:
                ev = np.full((int(good.sum()), M0.shape[1]), np.nan)
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio[good] = np.where(ev[:, -1] > 0, ev[:, -2] / ev[:, -1], np.nan)
        y0 = y[:, self.index[(0, 0, 0)]]
        first = y[:, [self.index[e] for e in ((1, 0, 0), (0, 1, 0), (0, 0, 1))]]
        usable = np.isfinite(y0) & (y0 != 0)
        first[usable] /= y0[usable, None]
        argmin = np.clip(np.nan_to_num(first, nan=0.5), 0.0, 1.0)
        value = np.where(solved, lam * scales, np.nan)
        lower = None
        if coeff_err is not None:
            lower = self._certified(lam, gram, F[:, : self._ns], np.asarray(coeff_err, dtype=np.float64), scales)
        return SOSBatch(status=status, solved=solved, value=value, lam=lam, scale=scales, argmin=argmin,
                        recovery_ratio=ratio, iterations=iterations, seconds=seconds, lower=lower,
                        gram=gram if keep else None, moments=y if keep else None)

    def certified_lower(self, solution: SOSSolution, coeffs, coeff_err: float = 0.0) -> float:
        """A rigorous lower bound on min det J over [0, 1]^3 from an SOS certificate (or -inf).

        The Gram matrices are factored into explicit squares (negative eigenvalues dropped), so
        ``sigma_i = sum_k (l_k . m_i)^2`` is exactly a sum of squares; with ``g_i >= 0`` on the cube,
        ``f - lambda - sum_i sigma_i g_i = r`` gives ``f >= lambda + r >= lambda - sum_alpha |r_alpha|``
        there (every monomial lies in [0, 1] on the cube). The residual's rounding is bounded by
        ``gamma * (sum of the magnitudes of all terms)`` and subtracted too.

        Parameters
        ----------
        solution : SOSSolution
        coeffs : array_like (20,), the monomial coefficients of det J (det J units)
        coeff_err : float, a bound on the error of each of ``coeffs`` (det J units)
        """
        if solution.gram is None or not np.isfinite(solution.lam):
            return float("-inf")
        s = np.array([solution.scale], dtype=np.float64)
        f = self._rhs(np.asarray(coeffs, dtype=np.float64) / s[0])[: self._ns]
        return float(self._certified(np.array([solution.lam]), [Q[None] for Q in solution.gram], f[None],
                                     np.array([coeff_err], dtype=np.float64), s)[0])

    def _certified(self, lam, gram, f, coeff_err, scales):
        """:meth:`certified_lower` of N hexes at once: lam (N,), gram per block (N, n, n), f (N, support) the
        normalized coefficients, coeff_err and scales (N,). Every hex's numbers are computed on its own (batched
        LAPACK per matrix, einsum per row): a hex's bound does not depend on the others in its batch."""
        n = lam.shape[0]
        total = np.zeros((n, self._ns))
        mag = np.zeros((n, self._ns))
        ok = np.isfinite(lam)
        nterms = 0
        for (g, basis), Q in zip(self.relaxation.blocks, gram):
            ok &= np.isfinite(Q).all(axis=(1, 2))
            nterms = max(nterms, len(basis) + 4)
        for Q, Am, Aabs in zip(gram, self._dense_maps, self._abs_maps):
            Q = np.where(ok[:, None, None], Q, 0.0)
            w, V = np.linalg.eigh(Q)
            L = V * np.sqrt(np.clip(w, 0.0, None))[:, None, :]  # Q+ = L L^T, explicit squares
            La = np.abs(L)
            total += np.einsum("ak,nk->na", Am, _svec_many(np.einsum("nik,njk->nij", L, L)))
            mag += np.einsum("ak,nk->na", Aabs, _svec_many(np.einsum("nik,njk->nij", La, La)))
        r = f - total
        r[:, self.index[(0, 0, 0)]] -= lam
        gamma = 4 * (nterms + 8) * UNIT_ROUND / (1 - 4 * (nterms + 8) * UNIT_ROUND)
        with np.errstate(invalid="ignore", over="ignore"):
            bound = (np.abs(r).sum(axis=1) + gamma * (mag.sum(axis=1) + np.abs(f).sum(axis=1) + np.abs(lam))
                     + 20 * coeff_err / scales)
            out = (lam - bound) * scales
        out[~ok | ~np.isfinite(out)] = -np.inf
        return out


@dataclass
class SOSBatch:
    """The outcome of :meth:`SOSSolver.solve_many` (one entry per hex; values in det J units)."""

    status: list  # Clarabel's statuses
    solved: np.ndarray  # status == "Solved": only these values and bounds mean anything
    value: np.ndarray  # the relaxation's optimum (NaN unless Solved)
    lam: np.ndarray  # lambda of the certificate (normalized units)
    scale: np.ndarray
    argmin: np.ndarray  # (N, 3) first moments, clipped to [0, 1]
    recovery_ratio: np.ndarray
    iterations: np.ndarray
    seconds: np.ndarray
    lower: np.ndarray = None  # certified lower bounds (with coeff_err)
    gram: list = field(repr=False, default=None)  # per block (N, n, n) (keep=True)
    moments: np.ndarray = field(repr=False, default=None)  # (N, support) (keep=True)
