"""Experiment 6: Figures 1 and 2 of the paper: corner checks against the true minimum.

    python -m comparison.figures_1_2 [--quick | --tiny] [--out DIR] [--jobs N]

Figure 1, the twist. A pure twist of congruent faces stays valid up to a half turn (det J = h det((1-w) R +
w I) > 0 for angles below pi), and so does ``examples.twisted_hex(angle, shear=s)`` for every shear (the
shear moves x_w only; x_u and x_v stay horizontal, so det J = h det((1-w) R + w I) still). Our sequence
(``examples.folding_twist``) twists the bottom face of a hex whose top face is a 1.8 x 0.55 rectangle with
one vertex nudged (so the minimizer is unique): the slices between a rotated square and a rectangle fold near
w = 1/2 from about 145 degrees on, while all 8 corners keep det J = 0.99 or more.

Figure 2, the ball. Starting from a valid, already distorted hex (:func:`ball_start_hex`: the Figure 1 hex
at 125 degrees, true minimum 0.158), vertex 0 is displaced to every point of a grid inside a ball of radius
0.8; each position is valid, corner-invalid (det J <= 0 at a corner), or invalid inside only. From the unit
cube, single-vertex moves never give inside-only invalidity (measured), hence the distorted start. The start
(125 degrees, vertex 0, radius 0.8) was chosen by a scan over 115/125/135 degrees, the 8 vertices and radii
0.5/0.8 for a picture with both regions large (35% inside-only, 10% corner-invalid on a 13^3 grid).
"""

from __future__ import annotations

from comparison import common as C

import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

NAME = "figures_1_2"
TITLE = "6. Figures 1 and 2: the twist, and one vertex moved inside a ball"
PAPER_SIZE = "- (pictures)"
SIZES = {"tiny": {"angles": 37, "ball": 9, "slice": 31}, "quick": {"angles": 181, "ball": 21, "slice": 81},
         "full": {"angles": 721, "ball": 41, "slice": 161}}
BALL = {"angle_deg": 125.0, "vertex": 0, "radius": 0.8}


def twist_hex(angle: float) -> np.ndarray:
    """Figure 1's hex at a twist ``angle`` (radians): :func:`hexsos_plugins.examples.folding_twist`."""
    from hexsos_plugins.examples import folding_twist

    return folding_twist(angle)


def ball_start_hex() -> np.ndarray:
    """The valid, distorted start of Figure 2: ``twist_hex`` at 125 degrees."""
    return twist_hex(np.radians(BALL["angle_deg"]))


def _det_slice(X, w, n=60):
    """det J of one hex on the parameter slice w = const, (n, n) over (u, v), from the kernel."""
    from hexsos_plugins.cells.hexahedron import det_at

    t = np.linspace(0, 1, n)
    U, V = np.meshgrid(t, t, indexing="ij")
    uvw = np.stack([U.ravel(), V.ravel(), np.full(U.size, w)], 1)
    d, _ = det_at(np.repeat(X[None], U.size, 0), uvw)
    return d.reshape(n, n)


def figure1(n_angles, out):
    from hexsos_plugins import check
    from hexsos_plugins.examples import hexes_to_mesh, twisted_hex

    ang = np.linspace(0.0, np.pi, n_angles)
    r = check(*hexes_to_mesh(np.stack([twist_hex(a) for a in ang])))
    rs = check(*hexes_to_mesh(np.stack([twisted_hex(a, shear=0.6) for a in ang])))
    deg = np.degrees(ang)
    inside = r.invalid_inside_only
    plt = C.pyplot()
    fig = plt.figure(figsize=(11, 6.2))
    ax = fig.add_axes([0.07, 0.42, 0.88, 0.52])
    ax.plot(deg, r.corner_min_det, "C0-", lw=2, label="min det J over the 8 corners")
    ax.plot(deg, r.min_det, "k-", lw=2, label="true min det J (hexsos)")
    ax.plot(deg, rs.min_det, "C2--", lw=1.2, label="true min, twisted_hex(angle, shear=0.6): stays >= 0")
    ax.axhline(0, color="grey", lw=0.8)
    if inside.any():
        ax.axvspan(deg[inside].min(), deg[inside].max(), color="red", alpha=0.15,
                   label="invalid inside only (corners say valid)")
    ax.set_xlabel("twist of the bottom face (degrees)")
    ax.set_ylabel("det J")
    ax.set_xlim(0, 180)
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title("Figure 1: corner minimum vs true minimum as the bottom vertices twist")
    picks = [0.0, 90.0, 140.0, 170.0]
    for j, a in enumerate(picks):
        i = int(np.argmin(np.abs(deg - a)))
        X = twist_hex(ang[i])
        w = float(r.argmin[i, 2])
        S = _det_slice(X, w)
        axi = fig.add_axes([0.07 + j * 0.23, 0.04, 0.17, 0.26])
        lim = max(abs(S.min()), abs(S.max()))
        im = axi.imshow(S.T, origin="lower", extent=(0, 1, 0, 1), cmap="RdBu", vmin=-lim, vmax=lim)
        axi.plot(*r.argmin[i, :2], "y*", ms=12, mec="k", clip_on=False, zorder=5)
        axi.set_title(f"{deg[i]:.0f} deg: det J on w = {w:.2f}", fontsize=8)
        axi.set_xlabel("u", fontsize=7)
        axi.set_ylabel("v", fontsize=7)
        axi.tick_params(labelsize=6)
        fig.colorbar(im, ax=axi, fraction=0.046, pad=0.04).ax.tick_params(labelsize=6)
    name = C.save(fig, out, "fig1_twist.png")
    crossing = float(deg[r.min_det <= 0].min()) if np.any(r.min_det <= 0) else None
    a, b = 1.8, 0.55  # the top rectangle of examples.folding_twist
    return name, {
        "angles": n_angles,
        "first_invalid_deg": crossing,
        "inside_only_range_deg": [float(deg[inside].min()), float(deg[inside].max())] if inside.any() else None,
        "corner_invalid": int(np.sum(r.corner_min_det <= 0)),
        "corner_min_range": [float(r.corner_min_det.min()), float(r.corner_min_det.max())],
        "min_det_at_180": float(r.min_det[-1]),
        "shear_0.6_first_invalid_deg": float(deg[rs.min_det <= 0].min()) if np.any(rs.min_det <= 0) else None,
        "unbumped_theory_deg": float(np.degrees(np.arccos(-(1 + a * b) / (a + b)))),
    }


def _classify(X, jobs):
    """0 valid, 1 corner-invalid, 2 invalid inside only, -1 undecided; and the result."""
    r = C.check_hexes(X, jobs if len(X) > 20000 else 1)
    cls = np.where(r.status == 1, 0, np.where(r.status == -1, -1, np.where(r.corner_min_det <= 0, 1, 2)))
    return cls, r


def figure2(n_ball, n_slice, jobs, out):
    from hexsos_plugins import check

    X0 = ball_start_hex()
    k, R = BALL["vertex"], BALL["radius"]
    r0 = check(X0, [range(8)])
    g = np.linspace(-1, 1, n_ball)
    D = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    D = D[np.linalg.norm(D, axis=1) <= 1.0] * R
    X = np.repeat(X0[None], len(D), 0)
    X[:, k] += D
    C.log(f"{NAME}: Figure 2: {len(D):,} positions in the ball")
    cls, _ = _classify(X, jobs)
    # a finer slice through the vertex, in the plane z = const
    s = np.linspace(-1, 1, n_slice)
    S2 = np.stack(np.meshgrid(s, s, indexing="ij"), -1).reshape(-1, 2)
    ins = np.linalg.norm(S2, axis=1) <= 1.0
    D2 = np.zeros((int(ins.sum()), 3))
    D2[:, :2] = S2[ins] * R
    X2 = np.repeat(X0[None], len(D2), 0)
    X2[:, k] += D2
    cls2, _ = _classify(X2, jobs)
    img = np.full(n_slice * n_slice, np.nan)
    img[ins] = cls2

    plt = C.pyplot()
    from matplotlib.colors import ListedColormap

    fig = plt.figure(figsize=(12, 5.4))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    edges = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
    for a, b in edges:
        ax.plot(*X0[[a, b]].T, "k-", lw=1.2)
    P = X0[k] + D
    for c, col, lab, sz, al in ((2, "tab:red", "invalid inside only", 4, 0.12), (1, "tab:blue", "corner-invalid", 9, 0.8)):
        sel = cls == c
        ax.scatter(*P[sel].T, s=sz, c=col, alpha=al, depthshade=False, label=f"{lab} ({sel.mean():.0%})")
    ax.scatter(*X0[k], s=120, c="yellow", edgecolors="k", depthshade=False, label=f"vertex {k}")
    ax.set_title(f"Figure 2: vertex {k} moved inside a ball of radius {R}", fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    ax.set_box_aspect(np.ptp(np.vstack([X0, P]), axis=0))
    ax.view_init(elev=28, azim=-110)
    ax2 = fig.add_subplot(1, 2, 2)
    cmap = ListedColormap(["#f0f0f0", "tab:blue", "tab:red"])
    Z = img.reshape(n_slice, n_slice).T
    ax2.imshow(np.where(Z < 0, np.nan, Z), origin="lower", cmap=cmap, vmin=-0.5, vmax=2.5,
               extent=(X0[k, 0] - R, X0[k, 0] + R, X0[k, 1] - R, X0[k, 1] + R))
    for a, b in edges:
        ax2.plot(*X0[[a, b], :2].T, "k-", lw=0.6, alpha=0.5)
    ax2.plot(*X0[k, :2], "o", ms=10, mfc="yellow", mec="k")
    ax2.set_aspect("equal")
    ax2.set_xlabel("x")
    ax2.set_ylabel("y")
    ax2.set_title(f"slice z = {X0[k, 2]:.2f} through the vertex (grey valid, blue corner-invalid, "
                  "red inside only)", fontsize=9)
    name = C.save(fig, out, "fig2_ball.png")
    n = len(cls)
    return name, {
        "start_min_det": float(r0.min_det[0]), "start_status": int(r0.status[0]),
        "vertex": k, "radius": R, "angle_deg": BALL["angle_deg"], "positions": n,
        "valid": int(np.sum(cls == 0)), "corner_invalid": int(np.sum(cls == 1)),
        "inside_only": int(np.sum(cls == 2)), "undecided": int(np.sum(cls == -1)),
        "slice_positions": int(ins.sum()), "slice_inside_only": int(np.sum(cls2 == 2)),
        "slice_corner_invalid": int(np.sum(cls2 == 1)),
    }


def unit_cube_moves(n: int = 15, radius: float = 1.5):
    """Single-vertex moves of the unit cube inside a ball: how many are invalid inside only (0 measured)."""
    from hexsos_plugins.examples import unit_cube

    g = np.linspace(-1, 1, n)
    D = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    D = D[np.linalg.norm(D, axis=1) <= 1.0] * radius
    X = np.repeat(unit_cube()[None], len(D), 0)
    X[:, 0] += D
    cls, _ = _classify(X, 1)
    return {"positions": len(D), "radius": radius, "corner_invalid": int(np.sum(cls == 1)),
            "inside_only": int(np.sum(cls == 2))}


def run(quick: bool = False, out="comparison-out", jobs: int = 1, *, size: str | None = None):
    t0 = time.perf_counter()
    size = C.resolve_size(quick, size)
    cfg = SIZES[size]
    out = Path(out)
    C.log(f"{NAME}: Figure 1, {cfg['angles']} angles")
    f1, s1 = figure1(cfg["angles"], out)
    f2, s2 = figure2(cfg["ball"], cfg["slice"], jobs, out)
    cube = unit_cube_moves(9 if size == "tiny" else 15)
    n = s2["positions"]
    rows1 = [["twist_hex (top 1.8 x 0.55, vertex 6 nudged)", s1["angles"], s1["corner_min_range"][0],
              s1["corner_invalid"], s1["first_invalid_deg"],
              "-" if s1["inside_only_range_deg"] is None else "{:.0f}-{:.0f}".format(*s1["inside_only_range_deg"]),
              s1["min_det_at_180"]],
             ["twisted_hex(angle, shear=0.6)", s1["angles"], None, 0, s1["shear_0.6_first_invalid_deg"], "-", None]]
    rows2 = [[f"twist_hex({BALL['angle_deg']:.0f} deg), vertex {s2['vertex']}, radius {s2['radius']}",
              s2["start_min_det"], n, s2["valid"], s2["corner_invalid"], 100 * s2["corner_invalid"] / n,
              s2["inside_only"], 100 * s2["inside_only"] / n, s2["undecided"]],
             [f"unit cube, vertex 0, radius {cube['radius']}", 1.0, cube["positions"],
              cube["positions"] - cube["corner_invalid"] - cube["inside_only"], cube["corner_invalid"],
              100 * cube["corner_invalid"] / cube["positions"], cube["inside_only"],
              100 * cube["inside_only"] / cube["positions"], 0]]
    summary = {NAME: {"figure1": s1, "figure2": s2, "unit_cube_moves": cube}}
    md = [
        C.table(["sequence", "angles", "min corner det J", "corner-invalid", "first invalid (deg)",
                 "invalid inside only (deg)", "min det J at 180 deg"], rows1,
                "Figure 1: as the bottom face twists, the smallest det J at the corners against the true minimum, and "
                "the range of angles where the hex is invalid inside only (corners positive)."),
        f"(Without the nudge of vertex 6, the middle slice folds at arccos(-(1+ab)/(a+b)) = "
        f"{s1['unbumped_theory_deg']:.1f} degrees for the a x b = 1.8 x 0.55 top.) The second row shows that a "
        "horizontal shear of a pure twist (`examples.twisted_hex(angle, shear=0.6)`) never folds: it moves x_w only.",
        "",
        f"![Figure 1]({f1})",
        "",
        C.table(["start", "start min det J", "positions", "valid", "corner-invalid", "%", "invalid inside only", "%",
                 "undecided"], rows2,
                "Figure 2: moving one vertex of a valid hex inside a ball, the positions where the hex becomes invalid "
                "at a corner (what corner checks see) and where it becomes invalid inside only (what they miss)."),
        f"![Figure 2]({f2})",
    ]
    return C.result(NAME, TITLE, summary, "\n".join(md) + "\n", [f1, f2], t0)


def main(argv=None):
    return C.standalone(run, __doc__, argv)


if __name__ == "__main__":
    raise SystemExit(main())
