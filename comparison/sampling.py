"""Experiment 1: exactness of our minima against dense sampling (paper section 6.1, Figure 8 left).

    python -m comparison.sampling [--quick | --tiny] [--out DIR] [--jobs N]

Random hexes of the paper's family (unit cube + Gaussian noise, sigma 0.3). The dense minimum follows the
paper's recipe: det J at the centres of the 100^3 sub-cubes of [0, 1]^3, then at the centres of the 100^3
sub-cubes of the best sub-cube. Ours: ``check`` with ``method="auto"`` and with ``method="sos"`` for both
relaxations (``quad2`` and the paper's). Reported: |ours - dense| (histogram: Figure 8 left), and the
sanity checks that the dense minimum is never below our certified lower bound and never below our minimum.

Centres never touch the boundary of the cube, where most minima lie (experiment 5), so the paper's recipe
misses a boundary minimum by about |grad det J| * 5e-5. A second dense minimum on *closed* grids (101^3
nodes including the faces, then 101^3 nodes on the box of +-1/100 around the best node) shows how close
our minima are when the sampling can reach them.

The dense evaluation does not use the kernel: det J is computed from the shape-function derivatives at
the 27 points {0, 1/2, 1}^3 with ``numpy.linalg.det``; since det J has degree <= 2 in each variable, its
tensor quadratic Lagrange interpolant through those 27 values *is* det J, which makes a 100^3 tensor grid
three small matrix products (about 5 ms per grid per hex). The value at each dense argmin is recomputed
directly from the Jacobian as a check of the interpolation (``interp_err``).
"""

from __future__ import annotations

from comparison import common as C  # first: sets BLAS threads before numpy is imported

import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

NAME = "sampling"
TITLE = "1. Exactness against dense sampling (Figure 8 left)"
SEED = 1
SIGMA = 0.3
PAPER_SIZE = "50,000 hexes (sigma 0.3)"
SIZES = {"tiny": {"hexes": 12, "grid": 100}, "quick": {"hexes": 1000, "grid": 100},
         "full": {"hexes": 50_000, "grid": 100}}
#: A dense value below our certified lower bound by more than this (times the hex's scale) is a violation;
#: the slack covers the rounding of the dense evaluation itself (~1e-15).
RTOL_ROUND = 1e-12

_CORNERS = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)],
                    float)
_NODES = np.array([0.0, 0.5, 1.0])
_G27 = np.stack(np.meshgrid(_NODES, _NODES, _NODES, indexing="ij"), -1).reshape(-1, 3)


def det_direct(X, p):
    """det J of hexes X (m, 8, 3) at points p (m, K, 3) or (K, 3): (m, K). Shape-function derivatives and
    ``numpy.linalg.det``, independent of the kernel."""
    X = np.asarray(X, float)
    p = np.broadcast_to(np.asarray(p, float), (X.shape[0],) + np.shape(p)[-2:])
    u, v, w = p[..., 0], p[..., 1], p[..., 2]
    J = np.zeros(p.shape[:2] + (3, 3))
    for n, (a, b, c) in enumerate(_CORNERS):
        lu, lv, lw = (u if a else 1 - u), (v if b else 1 - v), (w if c else 1 - w)
        dN = np.stack([(2 * a - 1) * lv * lw, (2 * b - 1) * lu * lw, (2 * c - 1) * lu * lv], -1)  # (m, K, 3)
        J += X[:, None, n, :, None] * dN[:, :, None, :]  # J[m, k, comp, dir]
    return np.linalg.det(J)


def _lagrange(t):
    """Quadratic Lagrange basis through 0, 1/2, 1 at t (..., n): (..., 3, n)."""
    t = np.asarray(t, float)
    return np.stack([2.0 * (t - 0.5) * (t - 1.0), -4.0 * t * (t - 1.0), 2.0 * t * (t - 0.5)], axis=-2)


def _grid_min(F, tu, tv, tw):
    """Minimum of det J over the tensor grids tu x tv x tw, per hex. F (m, 3, 3, 3) values at {0, 1/2, 1}^3;
    tu, tv, tw (m, n). Returns (value (m,), point (m, 3))."""
    m, n = tu.shape
    Lu, Lv, Lw = _lagrange(tu), _lagrange(tv), _lagrange(tw)  # (m, 3, n)
    A = np.einsum("mabc,mcz->mabz", F, Lw)
    A = np.einsum("mabz,mby->mayz", A, Lv)
    V = np.einsum("mayz,max->mxyz", A, Lu).reshape(m, -1)  # (m, n^3), index (x, y, z)
    k = V.argmin(axis=1)
    val = V[np.arange(m), k]
    i, j, l = np.unravel_index(k, (n, n, n))
    pt = np.stack([tu[np.arange(m), i], tv[np.arange(m), j], tw[np.arange(m), l]], axis=1)
    return val, pt


def dense_min(X, *, grid: int = 100, recipe: str = "paper", batch: int = 2):
    """Dense minimum of det J over [0, 1]^3 for hexes X (m, 8, 3).

    ``recipe="paper"``: centres of the grid^3 sub-cubes, then centres of the grid^3 sub-cubes of the best
    one. ``recipe="closed"``: the (grid+1)^3 nodes of the closed cube, then (grid+1)^3 nodes on the box of
    +-1/grid around the best node (clipped to the cube).

    Returns
    -------
    value : (m,) the smallest sampled value; point : (m, 3) where; interp_err : (m,) |interpolated value -
    direct det J| at that point.
    """
    X = np.asarray(X, float).reshape(-1, 8, 3)
    m = X.shape[0]
    val, pt = np.empty(m), np.empty((m, 3))
    F_all = det_direct(X, _G27).reshape(m, 3, 3, 3)
    for s in range(0, m, batch):
        F = F_all[s : s + batch]
        b = F.shape[0]
        if recipe == "paper":
            c = (np.arange(grid) + 0.5) / grid
            T = np.broadcast_to(c, (b, grid))
            v1, p1 = _grid_min(F, T, T, T)
            lo = np.floor(p1 * grid) / grid  # the best sub-cube [lo, lo + 1/grid]
            fine = (np.arange(grid) + 0.5) / grid**2
            tu, tv, tw = (lo[:, i : i + 1] + fine[None] for i in range(3))
        elif recipe == "closed":
            c = np.linspace(0.0, 1.0, grid + 1)
            T = np.broadcast_to(c, (b, grid + 1))
            v1, p1 = _grid_min(F, T, T, T)
            lo, hi = np.clip(p1 - 1.0 / grid, 0, 1), np.clip(p1 + 1.0 / grid, 0, 1)
            s01 = np.linspace(0.0, 1.0, grid + 1)
            tu, tv, tw = (lo[:, i : i + 1] + (hi - lo)[:, i : i + 1] * s01[None] for i in range(3))
        else:
            raise ValueError(f"recipe: expected 'paper' or 'closed', found {recipe!r}")
        v2, p2 = _grid_min(F, tu, tv, tw)
        better = v2 < v1
        val[s : s + b] = np.where(better, v2, v1)
        pt[s : s + b] = np.where(better[:, None], p2, p1)
    direct = det_direct(X, pt[:, None, :])[:, 0]
    return val, pt, np.abs(direct - val)


def _dense_chunk(X, grid):
    """Worker: both recipes on a chunk of hexes."""
    a = dense_min(X, grid=grid, recipe="paper")
    b = dense_min(X, grid=grid, recipe="closed")
    return a + b


def dense_both(X, jobs: int = 1, *, grid: int = 100, desc: str = "dense sampling"):
    """Both dense recipes for hexes X (M, 8, 3), spread over ``jobs`` processes. Returns a dict of arrays."""
    parts = C.chunks(len(X), jobs, per_job=8, max_size=250)
    res = C.pmap(_dense_chunk, [(X[a:b], grid) for a, b in parts], jobs, desc=desc, weights=[b - a for a, b in parts])
    keys = ("paper", "paper_point", "paper_interp_err", "closed", "closed_point", "closed_interp_err")
    return {k: np.concatenate([r[i] for r in res]) for i, k in enumerate(keys)}


def sanity_counts(r, dense) -> tuple:
    """(dense minimum below our certified lower bound, our minimum above the dense minimum): hexes where a
    sampled value contradicts a proof or our minimum. Both must be 0; slack ``RTOL_ROUND`` x scale."""
    tol = RTOL_ROUND * r.scale
    d = np.minimum(dense["paper"], dense["closed"])
    return int(np.sum(d < r.lower_bound - tol)), int(np.sum(r.min_det > d + tol))


def sample_hexes(m: int) -> np.ndarray:
    """The hexes of experiments 1 and 4: ``random_hexes(m, sigma=0.3, seed=1)``."""
    from hexsos_plugins.examples import random_hexes

    return random_hexes(m, sigma=SIGMA, seed=SEED)


def run(quick: bool = False, out="comparison-out", jobs: int = 1, *, size: str | None = None, hexes: int | None = None):
    """Run experiment 1; returns the result dict (see :mod:`comparison.common`)."""
    t0 = time.perf_counter()
    size = C.resolve_size(quick, size)
    cfg = dict(SIZES[size])
    if hexes is not None:
        cfg["hexes"] = hexes
    m, grid = cfg["hexes"], cfg["grid"]
    out = Path(out)
    X = sample_hexes(m)
    C.log(f"{NAME}: {m} hexes, sigma {SIGMA}, seed {SEED}; dense grid {grid}^3 + {grid}^3")

    t = time.perf_counter()
    D = dense_both(X, jobs, grid=grid)
    t_dense = time.perf_counter() - t
    runs = {}
    from hexsos_plugins.examples import hexes_to_mesh
    from hexsos_plugins import check

    runs["auto"] = check(*hexes_to_mesh(X))
    runs["sos, quad2"], _ = C.cached_check(X, out, jobs, desc=f"{NAME}: method='sos', quad2", method="sos",
                                           relaxation="quad2")
    runs["sos, paper"], _ = C.cached_check(X, out, jobs, desc=f"{NAME}: method='sos', paper", method="sos",
                                           relaxation="paper")

    rows, per = [], {}
    for label, r in runs.items():
        d_paper = r.min_det - D["paper"]
        d_closed = r.min_det - D["closed"]
        below_lb, above = sanity_counts(r, D)
        st = {
            "max_abs_diff": float(np.max(np.abs(d_paper))),
            "median_abs_diff": float(np.median(np.abs(d_paper))),
            "max_abs_diff_closed": float(np.max(np.abs(d_closed))),
            "dense_below_lower_bound": below_lb,
            "ours_above_dense": above,
            "max_gap": float(np.max(r.gap)),
            "seconds": float(r.seconds),
            "status_counts": r.counts(),
            "sos_not_solved": int(np.sum((r.sos_status != 1) & (r.sos_status != 0))),
        }
        per[label] = st
        rows.append([label, m, st["max_abs_diff"], st["median_abs_diff"], st["max_abs_diff_closed"], st["max_gap"],
                     below_lb, above, st["sos_not_solved"], 1e3 * r.seconds / m])

    # Figure 8 left: one panel per dense recipe; the three ways of computing ours in distinct line styles
    plt = C.pyplot()
    fig, axs = plt.subplots(1, 2, figsize=(12, 4.2), sharey=True)
    floor = 1e-17
    bins = np.logspace(-17, -1, 65)
    styles = (dict(lw=4, alpha=0.35, color="C0"), dict(lw=1.6, ls="--", color="C1"), dict(lw=1.2, ls=":", color="k"))
    for ax, key, what in ((axs[0], "paper", "paper's recipe (sub-cube centres)"),
                          (axs[1], "closed", "closed grids (nodes incl. the faces)")):
        for (label, r), st in zip(runs.items(), styles):
            ax.hist(np.maximum(np.abs(r.min_det - D[key]), floor), bins=bins, histtype="step", label=label, **st)
        ax.set_xscale("log")
        ax.set_xlabel("|our min det J - dense minimum| (below 1e-17 drawn at 1e-17)")
        ax.set_title(f"vs dense minimum, {what}", fontsize=10)
        ax.legend(fontsize=8, loc="upper left", title="ours (the curves coincide)", title_fontsize=8)
    axs[0].set_ylabel("hexes")
    fig.suptitle(f"Figure 8 (left): {m:,} random hexes, sigma {SIGMA}, dense {grid}^3 + {grid}^3", fontsize=11)
    fig.tight_layout()
    figs = [C.save(fig, out, "fig8_left_sampling.png")]

    auto = per["auto"]
    max_diff = max(s["max_abs_diff"] for s in per.values())
    summary = {NAME: {
        "hexes": m, "sigma": SIGMA, "seed": SEED, "grid": grid,
        "max_abs_diff": max_diff,
        "max_abs_diff_closed_grid": max(s["max_abs_diff_closed"] for s in per.values()),
        "dense_below_lower_bound": sum(s["dense_below_lower_bound"] for s in per.values()),
        "ours_above_dense": sum(s["ours_above_dense"] for s in per.values()),
        "max_interp_err": float(max(D["paper_interp_err"].max(), D["closed_interp_err"].max())),
        "dense_seconds": t_dense,
        "methods": per,
    }}
    invalid = int(np.sum(runs["auto"].status == 0))
    md = [
        f"{m:,} random hexes (unit cube + Gaussian noise, sigma {SIGMA}, seed {SEED}; {invalid:,} of them invalid). "
        f"Dense minimum by the paper's recipe ({grid}^3 sub-cube centres, then {grid}^3 centres inside the best "
        "sub-cube) and on closed grids (nodes including the faces, then the box of +-1/100 around the best node); "
        "det J for the dense minimum is computed without the kernel (see the module docstring); "
        f"dense sampling took {t_dense:.1f} s in all.",
        "",
        C.table(["ours", "hexes", "max abs diff (paper's recipe)", "median abs diff", "max abs diff (closed grids)",
                 "max certified gap", "dense < our lower bound", "ours > dense", "SOS not Solved", "ms/hex"],
                rows,
                "How far our minimum is from the dense minimum, and the sanity checks: the dense minimum (a sampled "
                "value) is never below our certified lower bound, and never below our minimum (both counts must be 0; "
                f"slack {RTOL_ROUND:g} x the hex's scale for the rounding of the dense evaluation)."),
        f"The paper's recipe never samples the boundary of the cube, where almost all minima lie (experiment 5), so "
        f"its differences (median {auto['median_abs_diff']:.1e}) measure the grid, not our minima: with closed grids "
        f"the largest difference drops to {auto['max_abs_diff_closed']:.1e} (auto). The paper reports < 1e-7 on "
        "50,000 hexes with the centre recipe; "
        + ("with grids that include the faces we reach that. " if auto["max_abs_diff_closed"] < 1e-7 else
           "no dense grid reaches that on every hex here (a few minima sit in narrow valleys that a 100^3 grid and "
           "one refinement do not resolve); since no dense value is ever below our minimum, what remains is the "
           "grid's error. ") +
        f"Interpolation check of the dense evaluation: max |interpolated - direct| = {summary[NAME]['max_interp_err']:.1e}.",
        "",
        f"![Figure 8 left]({figs[0]})",
    ]
    return C.result(NAME, TITLE, summary, "\n".join(md) + "\n", figs, t0)


def main(argv=None):
    return C.standalone(run, __doc__, argv)


if __name__ == "__main__":
    raise SystemExit(main())
