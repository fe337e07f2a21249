"""Repair: Algorithm 1 (per hex), Algorithm 2 (mesh), pinning, fidelity and ``hexsos repair`` end to end.

Every verdict after a repair is re-established by an independent ``check`` call on the returned coordinates
(never taken from the repair's own bookkeeping).
"""

import hashlib
import json

import meshio
import numpy as np
import pytest

import hexsos_plugins as hs
from hexsos_plugins.meshrepair import paper as rp
from hexsos_plugins.errors import DependencyError, InvalidInputError
from hexsos_plugins.examples import (demo_mesh, gmsh_mesh, hexes_to_mesh, inside_invalid_hex, random_hexes,
                                     structured_grid, twisted_hex, unit_cube)
from hexsos_plugins.cells.hexahedron import det_at
from oracle import dense_min


def _status(X):
    return hs.check(*hexes_to_mesh(X)).status


def _fingerprint(*arrays):
    return [hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest() + str(a.dtype) + str(a.shape)
            for a in arrays]


def _perturbed(kind, n, *, frac, amp, seed):
    """A Gmsh mesh with a fraction of its interior vertices moved by Gaussian noise of amp x edge length."""
    P, H = gmsh_mesh(kind, n)
    P = P.copy()
    interior = np.flatnonzero(~rp.boundary_vertex_mask(H, len(P)))
    rng = np.random.default_rng(seed)
    pick = rng.choice(interior, size=max(1, int(frac * interior.size)), replace=False)
    h = float(np.median(rp.hex_edge_length(P[H])))
    P[pick] += amp * h * rng.standard_normal((pick.size, 3))
    return P, H


# ------------------------------------------------------------------------------------------------ Algorithm 1


def test_random_invalid_hexes_become_proven_valid_and_valid_ones_stay_bit_for_bit():
    X = random_hexes(300, sigma=0.3, seed=7)
    before = _status(X)
    assert 60 < (before != 1).sum() < 240  # both kinds present
    fp = _fingerprint(X)
    Y, info = rp.repair_hex(X)
    assert _fingerprint(X) == fp  # input not mutated
    after = _status(Y)
    assert (after == 1).all()
    assert info["valid"].all() and (info["status"] == after).all()
    valid = before == 1
    assert np.array_equal(Y[valid], X[valid])  # bit for bit
    assert (info["steps"][valid] == 0).all()
    assert np.any(Y[~valid] != X[~valid], axis=(1, 2)).all()
    # Table 1 counting: one kernel evaluation per projection plus the first check
    assert info["sos_steps_total"] == info["projection_steps"] + 300
    # the repair is small: median Frobenius move well under one edge length
    d = np.linalg.norm((Y - X)[~valid].reshape(-1, 24), axis=1)
    assert np.median(d) < 0.3


def test_inside_invalid_and_twisted_hexes_are_repaired():
    X = np.stack([inside_invalid_hex(), twisted_hex(np.pi), twisted_hex(np.pi, shear=0.5)])
    r0 = hs.check(*hexes_to_mesh(X))
    assert r0.status.tolist() == [0, 0, 0]
    assert (r0.corner_min_det > 0).all()  # corner checks see nothing wrong in any of them
    Y, info = rp.repair_hex(X)
    assert (_status(Y) == 1).all()
    # independent oracle: the dense minimum of det J is positive too
    dense, _, _ = dense_min(Y)
    assert (dense > 0).all()
    # margin: det J at the last argmin is at least the margin asked (relative to the hex's size)
    h3 = rp.hex_edge_length(X) ** 3
    assert (det_at(Y, info["argmin"])[0] >= 0.99 * rp.DEFAULT_MARGIN * h3).all()


def test_single_hex_shape_and_valid_hex_unchanged():
    cube = unit_cube()
    Y, info = rp.repair_hex(cube)
    assert Y.shape == (8, 3) and np.array_equal(Y, cube) and Y is not cube
    assert info["projection_steps"] == 0 and info["sos_steps_total"] == 1
    mirrored = cube * [-1, 1, 1]  # inverted everywhere: det J = -1
    Y, info = rp.repair_hex(mirrored)
    assert _status(Y[None])[0] == 1
    # a flat hex (det J == 0 everywhere: undecided) has no gradient to follow at first; it is repaired too
    P, H = hexes_to_mesh(np.stack([cube * [1, 1, 0], cube]))
    r = rp.repair_paper(P, H)
    assert r.stats["undecided_before"] == 1 and r.success and (hs.check(r.points, H).status == 1).all()
    assert np.array_equal(r.points[8:], P[8:])  # the valid hex beside it (no shared vertex) never moved


def test_initial_anchor_is_its_own_repair_and_certified():
    # anchor="initial": the vertex update weighs the repaired hexes against the input's positions, not the current
    P, H = _perturbed("box", 5, frac=0.3, amp=0.45, seed=11)
    assert (hs.check(P, H).status != 1).sum() >= 2
    runs = {a: rp.repair_paper(P, H, anchor=a) for a in ("current", "initial")}
    for a, r in runs.items():
        assert r.success and r.stats["anchor"] == a
        assert (hs.check(r.points, H).status == 1).all()  # judged anew, not from the repair's bookkeeping
    assert not np.array_equal(runs["initial"].points, runs["current"].points)  # the knob reaches the update


def test_margin_must_be_positive_and_shapes_checked():
    for bad in (0.0, -1e-3, float("nan")):
        with pytest.raises(InvalidInputError, match="margin"):
            rp.repair_hex(inside_invalid_hex(), margin=bad)
    with pytest.raises(InvalidInputError, match="shape"):
        rp.repair_hex(np.zeros((7, 3)))
    P, H = hexes_to_mesh(inside_invalid_hex())
    with pytest.raises(InvalidInputError, match="rho"):
        rp.repair_paper(P, H, rho=0)
    with pytest.raises(InvalidInputError, match="anchor"):
        rp.repair_paper(P, H, anchor="nowhere")


def test_projection_is_feasible_and_matches_a_generic_solver():
    from scipy.optimize import minimize

    # the exact projection onto intersections of half-spaces against SLSQP (the oracle), random problems
    rng = np.random.default_rng(3)
    G = rng.standard_normal((60, 4, 5))
    b = rng.standard_normal((60, 4))
    act = rng.random((60, 4)) < 0.75
    y, ok = rp.halfspace_projection(G, b, act)
    assert ok.all()
    for i in range(60):
        cons = [{"type": "ineq", "fun": (lambda z, g=G[i, j], c=b[i, j]: g @ z - c)} for j in range(4) if act[i, j]]
        ref = minimize(lambda z: z @ z, np.zeros(5), constraints=cons, method="SLSQP",
                       options={"ftol": 1e-14, "maxiter": 500})
        assert y[i] @ y[i] == pytest.approx(ref.fun, rel=1e-6, abs=1e-12)
        assert (G[i, act[i]] @ y[i] >= b[i, act[i]] - 1e-8).all()
    # (R) on hexes: det J(u*) reaches the floor, judged by evaluating it; pinned vertices do not move
    X = random_hexes(50, sigma=0.3, seed=5)
    r = hs.check(*hexes_to_mesh(X))
    bad = np.flatnonzero(r.status != 1)
    uvw = r.argmin[bad][:, None, :]
    floor = 1e-3 * rp.hex_edge_length(X[bad]) ** 3
    free = np.ones((bad.size, 8), dtype=bool)
    free[:, 0] = False
    Y, feas, stuck = rp.project(X[bad], uvw, np.ones((bad.size, 1), bool), 1.25 * floor, floor, free,
                                 np.full(bad.size, 10.0))
    d = det_at(Y, r.argmin[bad])[0]
    assert (feas == (d >= floor)).all() and feas.mean() > 0.9
    assert np.array_equal(Y[:, 0], X[bad, 0])


# ------------------------------------------------------------------------------------------------ Algorithm 2


@pytest.fixture(scope="module")
def demo():
    P, H, info = demo_mesh()
    return P, H, info


def test_demo_mesh_repaired_certified_and_local(demo):
    P, H, info = demo
    fp = _fingerprint(P, H)
    r0 = hs.check(P, H)
    assert (r0.status == 0).sum() >= 3 and r0.invalid_inside_only.any()
    r = rp.repair_paper(P, H)
    assert _fingerprint(P, H) == fp  # inputs not mutated
    assert r.points is not P and r.points.shape == P.shape
    assert r.success, r.message
    chk = hs.check(r.points, H)  # independent certificate
    assert (chk.status == 1).all()
    assert np.array_equal(r.check.status, chk.status)
    assert np.array_equal(r.displacement, r.points - P)
    s = r.stats
    assert s["invalid_before"] == int((r0.status == 0).sum()) and s["invalid_after"] == 0
    assert s["outer_iterations"] == len(r.history) - 1 and s["outer_iterations"] >= 1
    assert s["sos_steps"] == sum(h["sos_steps"] for h in r.history)
    assert s["projection_steps"] == sum(h["projection_steps"] for h in r.history) > 0
    assert r.history[0]["invalid"] == s["invalid_before"] and r.history[-1]["invalid"] == 0
    # locality: vertices two or more hex rings away from every initially invalid hex do not move at all
    near = np.zeros(len(P), dtype=bool)
    near[H[r0.status != 1].ravel()] = True
    for _ in range(2):
        near[H[near[H].any(axis=1)].ravel()] = True
    norm = np.linalg.norm(r.displacement, axis=1)
    assert near.sum() < 0.4 * len(P)
    assert norm[~near].max() == 0.0
    assert s["moved_vertices"] == int((norm > 0).sum()) < 0.1 * len(P)
    assert s["max_displacement"] == pytest.approx(norm.max())


def test_perturbed_gmsh_mesh_all_proven_valid_connectivity_unchanged():
    P, H = _perturbed("ring", 6, frac=0.04, amp=0.5, seed=11)
    H_copy = H.copy()
    r0 = hs.check(P, H)
    assert (r0.status != 1).sum() >= 10
    seen = []
    r = rp.repair_paper(P, H, progress=lambda d, t: seen.append((d, t)), callback=lambda e, V: None)
    assert r.success, r.message
    assert (hs.check(r.points, H).status == 1).all()
    assert np.array_equal(H, H_copy)
    assert seen[-1][0] == seen[-1][1] == (r0.status != 1).sum()
    # far from the damage nothing moves; where it moves, by less than an edge length on average
    h = float(np.median(rp.hex_edge_length(P[H])))
    assert r.stats["mean_displacement"] < 0.5 * h
    assert r.stats["moved_vertices"] < 0.25 * len(P)


def test_bunny_45_invalid_before_0_after_certified(bunny_path):
    from hexsos_plugins.io import read

    mesh = read(bunny_path)
    r0 = hs.check(mesh.points, mesh.hexes)
    assert int((r0.status == 0).sum()) == 45
    r = rp.repair_paper(mesh.points, mesh.hexes)
    assert r.success and r.stats["invalid_before"] == 45 and r.stats["invalid_after"] == 0
    assert (hs.check(r.points, mesh.hexes).status == 1).all()
    assert r.stats["seconds"] < 60  # 0.2-0.3 s measured; generous on a shared machine


def test_max_iter_reached_returns_best_mesh_and_says_so():
    # a corner vertex of a 2x2x2 grid pushed through the mesh's centre: a severe tangle
    P, H = structured_grid(2)
    P = P.copy()
    P[0] = [0.8, 0.8, 0.8]
    r = rp.repair_paper(P, H, max_iter=0)
    assert not r.success and "max_iter" in r.message
    assert np.array_equal(r.points, P) and r.stats["outer_iterations"] == 0
    r = rp.repair_paper(P, H, max_iter=5)
    assert not r.success and r.stats["outer_iterations"] == 5
    # the best mesh seen: no more hexes not proven valid than any iteration recorded
    bad = [h["invalid"] + h["undecided"] for h in r.history]
    assert r.stats["invalid_after"] + r.stats["undecided_after"] == min(bad)


# ------------------------------------------------------------------------------------------------ pinning


def test_pinned_boundary_does_not_move_at_all(demo):
    P, H, info = demo
    r = rp.repair_paper(P, H, pin_boundary=True)
    assert r.success, r.message
    assert (hs.check(r.points, H).status == 1).all()
    b = rp.boundary_vertex_mask(H, len(P))
    assert b.sum() == r.stats["pinned_vertices"] > 0
    assert np.array_equal(r.points[b], P[b])  # exactly 0
    assert r.stats["max_displacement"] > 0  # interior vertices did move
    # the inside-only hex sits on the boundary, its distorted face pinned: repaired through its inner vertices
    assert set(info["inside_only_vertices"]) <= set(np.flatnonzero(b))


def test_pinned_repair_that_cannot_succeed_says_why():
    P, H = hexes_to_mesh(inside_invalid_hex())  # one hex: every vertex is on the boundary
    r = rp.repair_paper(P, H, pin_boundary=True)
    assert not r.success and "pin" in r.message and np.array_equal(r.points, P)
    # a hex with 7 of 8 vertices on the boundary of a 2x2x2 grid, its corner pushed through the mesh
    P, H = structured_grid(2)
    P = P.copy()
    P[0] = [0.8, 0.8, 0.8]
    r = rp.repair_paper(P, H, pin_boundary=True)
    assert not r.success and "pin" in r.message
    b = rp.boundary_vertex_mask(H, len(P))
    assert np.array_equal(r.points[b], P[b])


# ------------------------------------------------------------------------------------------------ fidelity


def test_boundary_fidelity_measures_what_moved():
    pytest.importorskip("pymeshlab")
    from hexsos_plugins.meshrepair.fidelity import boundary_fidelity

    P, H = structured_grid(3)
    f = boundary_fidelity(P, P, H)
    assert f["hausdorff_max"] == 0.0 and f["boundary_quads"] == 54 and f["self_intersecting_after"] == 0
    # an interior vertex moved: the boundary did not
    inner = np.flatnonzero(~rp.boundary_vertex_mask(H, len(P)))[0]
    Q = P.copy()
    Q[inner] += 0.1
    assert boundary_fidelity(P, Q, H)["hausdorff_max"] == 0.0
    # a top-face vertex lifted by 0.05 along the normal: the Hausdorff distance is 0.05
    top = np.flatnonzero((P[:, 2] == 1.0) & (P[:, 0] > 0) & (P[:, 0] < 1) & (P[:, 1] > 0) & (P[:, 1] < 1))[0]
    Q = P.copy()
    Q[top, 2] += 0.05
    f = boundary_fidelity(P, Q, H)
    assert f["hausdorff_max"] == pytest.approx(0.05, rel=1e-4)
    assert f["hausdorff_max_relative"] == pytest.approx(0.05 / np.sqrt(3), rel=1e-4)
    assert 0 < f["hausdorff_mean"] < 0.05
    # pushed down through the bottom: its boundary faces cross other boundary faces
    Q[top, 2] = -0.5
    f = boundary_fidelity(P, Q, H)
    assert f["self_intersecting_before"] == 0 and f["self_intersecting_after"] > 0


def test_boundary_fidelity_of_a_surface_of_no_area_says_so_instead_of_crashing():
    """pymeshlab's Hausdorff filter crashes the process sampling a surface of no area and does not return targeting
    one: such a surface, before or after, gets no Hausdorff distance and a note, the self-intersections still."""
    pytest.importorskip("pymeshlab")
    from hexsos_plugins.meshrepair.fidelity import boundary_fidelity, surface_area

    P, H = structured_grid(2)
    point = np.zeros_like(P)  # every point coincident
    line = np.zeros_like(P)
    line[:, 0] = np.arange(len(P))  # every point on one line
    for before, after, which in ((point, P, "before"), (P, line, "after"), (line, point, "before and after")):
        f = boundary_fidelity(before, after, H)
        assert f["hausdorff_max"] is None and f["hausdorff_max_relative"] is None
        assert f"surface {which} the repair has no area" in f["hausdorff_note"]
        assert f["self_intersecting_before"] == 0 and f["boundary_quads"] == 24
    # the negative case: a surface with an area has its distance, and no note
    Q = P.copy()
    Q[P[:, 2] == 1.0, 2] += 0.25
    f = boundary_fidelity(P, Q, H)
    assert f["hausdorff_max"] == pytest.approx(0.25, rel=1e-4) and "hausdorff_note" not in f
    assert surface_area(P, np.array([[0, 1, 3]])) == pytest.approx(0.125)  # a right triangle of legs 0.5
    assert surface_area(line, np.array([[0, 1, 2]])) == 0.0


def test_cli_repair_of_a_mesh_with_every_point_coincident_ends_without_a_crash(tmp_path):
    """Every point of the input at one place: the repair's report has no Hausdorff distance, says why, and the
    process exits with a code (before: a segmentation fault in pymeshlab, with no output file written)."""
    import subprocess
    import sys

    pytest.importorskip("pymeshlab")
    P, H = structured_grid(2)
    src, out = tmp_path / "coincident.vtu", tmp_path / "out.vtu"
    meshio.write(str(src), meshio.Mesh(np.zeros_like(P), [("hexahedron", H)]))
    run = subprocess.run([sys.executable, "-m", "hexsos_plugins", "repair", str(src), "-o", str(out), "--no-progress"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode in (0, 1), run.stderr
    assert "Traceback" not in run.stderr
    assert "Hausdorff not computed: the boundary surface before the repair has no area" in run.stdout
    # no input normal: none counts as turned or tilted
    assert "0 -> 0 boundary quads turned over" in run.stdout and "0 -> 0 of 24 tilted more than 60 degrees" in run.stdout
    assert out.exists()


def test_cli_repair_warns_when_the_boundary_ends_far_from_the_input(tmp_path, capsys):
    """A flat input (every point in one plane) is certified only by inflating it: the boundary ends many
    diagonals away, and the run says so; a repair that moves one interior vertex does not."""
    from hexsos_plugins.cli import main
    from hexsos_plugins.meshrepair.fidelity import FAR_FRACTION

    pytest.importorskip("pymeshlab")
    P, H = structured_grid(2)
    flat, out = tmp_path / "flat.vtu", tmp_path / "out.vtu"
    meshio.write(str(flat), meshio.Mesh(P * [1.0, 1.0, 0.0], [("hexahedron", H)]))
    assert main(["repair", str(flat), "-o", str(out), "--json"]) == 0
    got = capsys.readouterr()
    d = json.loads(got.out)
    assert d["hausdorff_relative"] > 1.0
    far = [w for w in d["warnings"] if "from the input's (Hausdorff), more than 2%" in w]
    assert len(far) == 1 and f"{100 * d['hausdorff_relative']:.4g}%" in far[0]
    assert main(["repair", str(flat), "-o", str(out)]) == 0
    assert "hexsos: warning: the boundary ended" in capsys.readouterr().err
    near = P.copy()
    near[13] += 0.7  # the centre vertex of the 2^3 grid, through a face of its hexes
    src = tmp_path / "near.vtu"
    meshio.write(str(src), meshio.Mesh(near, [("hexahedron", H)]))
    assert main(["repair", str(src), "-o", str(out), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["invalid_before"] > 0 and d["hausdorff_relative"] < FAR_FRACTION
    assert not any("more than 2%" in w for w in d["warnings"])


def test_fidelity_without_pymeshlab_names_the_extra(monkeypatch):
    import sys

    from hexsos_plugins.meshrepair.fidelity import boundary_fidelity

    monkeypatch.setitem(sys.modules, "pymeshlab", None)
    P, H = structured_grid(1)
    with pytest.raises(DependencyError, match="fidelity"):
        boundary_fidelity(P, P, H)


# ------------------------------------------------------------------------------------------------ CLI


def _write_input(path, P, H):
    """A mesh with more than hexes: a quad block, point/cell/field data."""
    quads = __import__("hexsos_plugins.meshrepair.fidelity", fromlist=["boundary_quads"]).boundary_quads(H)
    m = meshio.Mesh(
        P, [("hexahedron", H), ("quad", quads)],
        point_data={"temperature": np.arange(len(P), dtype=np.float64)},
        cell_data={"region": [np.full(len(H), 7, dtype=np.int32), np.full(len(quads), 3, dtype=np.int32)]},
        field_data={"units": np.array([1.0])},
    )
    m.write(path)
    return m


def test_cli_repair_end_to_end(tmp_path, demo, capsys):
    from hexsos_plugins.cli import main

    P, H, _ = demo
    src = tmp_path / "in.vtu"
    m = _write_input(str(src), P, H)
    raw = src.read_bytes()
    out, png = tmp_path / "out.vtu", tmp_path / "conv.png"
    rc = main(["repair", str(src), "-o", str(out), "--json", "--plot", str(png), "--no-progress", "--method", "paper"])
    stdout = capsys.readouterr().out
    assert rc == 0
    assert src.read_bytes() == raw  # input untouched
    d = json.loads(stdout)
    for key in ("hexes", "invalid_before", "invalid_after", "outer_iterations", "sos_steps", "projection_steps",
                "seconds", "max_displacement", "hausdorff"):
        assert key in d, key
    assert d["hexes"] == len(H) and d["invalid_after"] == 0 and d["invalid_before"] > 0
    assert d["output_certified"] is True
    if d["hausdorff"] is not None:
        assert d["hausdorff"] > 0  # the inside-only hex's boundary face was moved back
    # OUT: every input block and array, the same connectivity, plus the new arrays
    o = meshio.read(str(out))
    assert [c.type for c in o.cells] == [c.type for c in m.cells]
    assert np.array_equal(o.cells[0].data, H) and np.array_equal(o.cells[1].data, m.cells[1].data)
    assert np.array_equal(o.point_data["temperature"], m.point_data["temperature"])
    assert np.array_equal(o.cell_data["region"][0], m.cell_data["region"][0])
    assert "hexsos_displacement" in o.point_data and "hexsos_status" in o.cell_data
    assert np.array_equal(o.point_data["hexsos_displacement"], o.points - P)
    assert (o.cell_data["hexsos_status"][0] == 1).all()
    assert (hs.check(o.points, o.cells[0].data).status == 1).all()  # certified as written
    with open(png, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size > 5000


def test_cli_repair_not_successful_exit_1_and_output_written(tmp_path, capsys):
    from hexsos_plugins.cli import main

    P, H = structured_grid(2)
    P = P.copy()
    P[0] = [0.8, 0.8, 0.8]
    src, out = tmp_path / "in.vtk", tmp_path / "out.vtk"
    meshio.write(str(src), meshio.Mesh(P, [("hexahedron", H)]), binary=False)
    rc = main(["repair", str(src), "-o", str(out), "--max-iter", "2", "--no-fidelity", "--boundary", "fixed"])
    text = capsys.readouterr().out
    assert rc == 1 and out.exists() and "NOT every cell proven valid" in text
    # one count of cells for one mesh: the untangling's stricter test is said to be stricter, on the mesh returned
    assert "1 hex not proven valid (hexes 0)" in text
    assert "its own test, stricter than the certificate" in text and "fails on 1 cell of the mesh returned" in text
    # the input as output is refused
    rc = main(["repair", str(src), "-o", str(src)])
    assert rc == 2 and "input" in capsys.readouterr().err



# ------------------------------------------------------------------------------------------ interruption


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_interrupted_repair_leaves_no_output_and_saves_a_checkpoint(tmp_path, sig):
    import re
    import signal
    import subprocess
    import sys

    import meshio

    from comparison.stress import graded_solid, stress
    from hexsos_plugins.cli.repair import checkpoint_path

    P, H = graded_solid(20)
    P = stress(P, H, frac=0.8, amp=1.0, seed=2)  # 32,000 hexes, most inverted: a repair of many seconds (~15 s)
    src = tmp_path / "tangle.vtu"
    meshio.write(src, meshio.Mesh(P, [("hexahedron", H)], point_data={"t": np.arange(len(P), dtype=float)}))
    before = src.read_bytes()
    out = tmp_path / "out.vtu"
    proc = subprocess.Popen([sys.executable, "-m", "hexsos_plugins", "repair", str(src), "-o", str(out),
                             "--no-fidelity", "--progress"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    ckpt = checkpoint_path(str(out))
    # the signal goes in once the repair reports cells repaired (its progress bar on stderr), not after a guess
    seen = ""
    while not re.search(r"repairing \[[#.]+\]\s+[\d.]+% [1-9][\d,]*/", seen):
        ch = proc.stderr.read(1)
        assert ch, f"the repair ended before its first progress report: {seen!r}"
        seen += ch
    assert proc.poll() is None
    proc.send_signal(getattr(signal, sig))
    stdout, stderr = proc.communicate(timeout=60)
    stderr = seen + stderr
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and not out.exists()  # no OUT, not even half of one
    assert not list(tmp_path.glob(".out*"))  # no temporary file left behind
    assert f"saved in {ckpt}" in stderr and "resume with: hexsos repair" in stderr
    m = meshio.read(ckpt)
    assert np.array_equal(m.cells_dict["hexahedron"], H) and "t" in m.point_data
    moved = m.points - P
    assert np.allclose(m.point_data["hexsos_displacement"], moved) and np.abs(moved).max() > 0
    assert src.read_bytes() == before
    # resuming from the checkpoint works like any repair
    r = subprocess.run([sys.executable, "-m", "hexsos_plugins", "repair", ckpt, "-o", str(out), "--max-iter", "2",
                        "--no-fidelity", "--json", "--method", "paper"], capture_output=True, text=True, timeout=300)
    assert r.returncode in (0, 1) and out.exists()


def test_unwritable_output_fails_before_the_repair(tmp_path, capsys, monkeypatch):
    import meshio

    from hexsos_plugins import cli

    P, H = structured_grid(2)
    P = P.copy()
    P[0] = [0.8, 0.8, 0.8]
    src = tmp_path / "tangle.vtu"
    meshio.write(src, meshio.Mesh(P, [("hexahedron", H)]))
    calls = []
    monkeypatch.setattr("hexsos_plugins.meshrepair.driver._Optimize.run", lambda *a, **k: calls.append(1))
    assert cli.main(["repair", str(src), "-o", str(tmp_path / "missing" / "out.vtu")]) == 2
    assert "does not exist" in capsys.readouterr().err and calls == []  # refused before any repair work


def test_cli_repair_of_a_mesh_without_hexahedra_says_what_it_found(tmp_path, capsys):
    """A quadratic mesh (Gmsh-made, order 2 serendipity: no 8-node hexahedra) goes to the curved repair: OUT is
    written with the same cells, exit 0 or 1 by the kernel's verdict on every cell; a mesh with no 3-D cell at all
    is refused in one line naming what it holds (exit 2, nothing written)."""
    import meshio

    from hexsos_plugins import check, cli, read
    from hexsos_plugins.examples import mixed_msh

    path = tmp_path / "quadratic.msh"
    mixed_msh(path, order=2, incomplete=True, damage=0.1, seed=1)
    out = tmp_path / "out.msh"
    code = cli.main(["repair", str(path), "-o", str(out), "--time-limit", "5"])
    assert code in (0, 1) and out.exists()
    m_in, m_out = read(path), read(out)
    assert [t for t, _ in m_out.cells] == [t for t, _ in m_in.cells]
    assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(m_in.cells, m_out.cells))
    after = check(m_out.points, m_out.cells)
    assert code == (0 if (after.status == 1).all() else 1)
    assert "curved" in capsys.readouterr().out
    flat = tmp_path / "flat.vtu"
    meshio.write(flat, meshio.Mesh(np.eye(3), [("triangle", np.array([[0, 1, 2]]))]))
    out2 = tmp_path / "out2.vtu"
    assert cli.main(["repair", str(flat), "-o", str(out2)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hexsos: error: ") and len(err.strip().splitlines()) == 1 and "triangle" in err
    assert not out2.exists()