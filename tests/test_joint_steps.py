"""The repair's joint steps (:mod:`hexsos_plugins.meshrepair.jointsteps`): the linearizations they rest on, what they
gain where the vertex-by-vertex steps stop, and the limits every kept step holds (validity, the band, the edge
floor)."""

from __future__ import annotations

import os

import numpy as np
import pytest

import hexsos_plugins as hs
from hexsos_plugins.cells.quality import hex_edge_ratio, sample_scaled_jacobians
from hexsos_plugins.examples import cubed_ball, structured_grid
from hexsos_plugins.meshrepair import SURFACE_TOLERANCE, localopt
from hexsos_plugins.meshrepair.boundary import boundary_model
from hexsos_plugins.meshrepair.jointsteps import (DELTA_MAX, RATIO_SLACK, bernstein_gradients, binding_rows,
                                                 joint_steps, next_delta, sample_gradients)
from hexsos_plugins.meshrepair.optimize import bernstein_coefficients



def _certified(P, H):
    return bool((hs.check(P, H).status == 1).all())


def _sheared_layers():
    """A 6^3 grid whose two middle layers of hexes are sheared alike: 72 hexes share the minimum (0.857)."""
    P, H = structured_grid(6, 6, 6)
    h = P[:, 1].max() / 6
    Q = P.copy()
    Q[:, 0] += 0.6 * np.clip(P[:, 1], 3 * h, 5 * h)
    return Q, H


def test_gradients_match_finite_differences():
    """The programs' rows: the scaled Jacobian samples and the Bernstein coefficients, and their gradients against
    central differences, on distorted hexes (a sign or an index wrong in either shows here)."""
    rng = np.random.default_rng(3)
    P, H = structured_grid(1, 1, 1)
    X = np.stack([P[H[0]] + 0.2 * rng.standard_normal((8, 3)) for _ in range(4)])
    sj, g = sample_gradients(X)
    b, db = bernstein_gradients(X)
    assert np.allclose(sj, sample_scaled_jacobians(X, "hexahedron"), rtol=1e-12, atol=1e-14)
    assert np.allclose(b, bernstein_coefficients(X), rtol=1e-10, atol=1e-12)
    h = 1e-6
    for n in range(8):
        for a in range(3):
            Xp, Xm = X.copy(), X.copy()
            Xp[:, n, a] += h
            Xm[:, n, a] -= h
            fd = (sample_gradients(Xp)[0] - sample_gradients(Xm)[0]) / (2 * h)
            assert np.allclose(g[:, :, n, a], fd, rtol=1e-5, atol=1e-6)
            fdb = (bernstein_gradients(Xp)[0] - bernstein_gradients(Xm)[0]) / (2 * h)
            assert np.allclose(db[:, :, n, a], fdb, rtol=1e-5, atol=1e-6)


def test_the_low_coefficients_gradients_are_the_full_ones_at_those_coefficients():
    """``bernstein_gradients(X, low=...)``, what the joint steps use: exactly the coefficients below ``low`` of
    their hex's largest, each with its row of the full gradient (up to rounding: other summation order), on
    distorted hexes whose coefficients spread widely."""
    rng = np.random.default_rng(5)
    P, H = structured_grid(1, 1, 1)
    X = np.stack([P[H[0]] + 0.25 * rng.standard_normal((8, 3)) for _ in range(40)])
    b, db = bernstein_gradients(X)
    for low in (0.1, 0.3, 0.6):
        b2, (hh, pp, dbl) = bernstein_gradients(X, low=low)
        assert np.array_equal(b2, b)
        want = np.argwhere(b < low * b.max(axis=1)[:, None])
        assert 0 < len(want) < b.size and np.array_equal(np.column_stack([hh, pp]), want)
        assert np.allclose(dbl, db[hh, pp], rtol=1e-12, atol=1e-12 * np.abs(db).max())


def test_held_coefficients_are_the_split_where_the_27_are_near_0():
    """``held_coefficients``: a hex whose least coefficient is below ``split_below`` of its largest is held by the
    216 coefficients of its split (a cube twisted by 110 degrees: valid, its 27 partly negative, its split's all
    positive), with their gradients against central differences; the others by their 27, as before."""
    from hexsos_plugins.meshrepair import kernels as nb
    from hexsos_plugins.meshrepair.jointsteps import held_coefficients
    from hexsos_plugins.examples import twisted_hex
    from hexsos_plugins.meshrepair.optimize import bernstein_split_matrix

    rng = np.random.default_rng(7)
    P, H = structured_grid(1, 1, 1)
    X = np.stack([twisted_hex(np.radians(110.0)), twisted_hex(np.radians(30.0)),
                  P[H[0]] + 0.1 * rng.standard_normal((8, 3))])
    S = bernstein_split_matrix()
    b = bernstein_gradients(X)[0]
    assert b[0].min() < 0 < b[1:].min()
    least, largest, (hh, vals, db) = held_coefficients(X, 0.3)
    c0 = S @ b[0]
    assert least[0] == pytest.approx(c0.min()) and least[0] > 0 and largest[0] == pytest.approx(c0.max())
    assert np.allclose(least[1:], b[1:].min(axis=1)) and np.allclose(largest[1:], b[1:].max(axis=1))
    assert np.array_equal(np.sort(vals[hh == 0]), np.sort(c0[c0 < 0.3 * c0.max()]))
    assert np.array_equal(np.sort(vals[hh == 1]), np.sort(b[1][b[1] < 0.3 * b[1].max()]))
    h = 1e-6
    for k in np.flatnonzero(hh == 0)[:6]:
        q = int(np.flatnonzero(c0 == vals[k])[0])
        for n in range(8):
            for a in range(3):
                Xp, Xm = X.copy(), X.copy()
                Xp[0, n, a] += h
                Xm[0, n, a] -= h
                fd = (S[q] @ bernstein_gradients(Xp)[0][0] - S[q] @ bernstein_gradients(Xm)[0][0]) / (2 * h)
                assert db[k, n, a] == pytest.approx(fd, rel=1e-5, abs=1e-6)
    # and the kernel's split is the same
    V = np.ascontiguousarray(X[0])
    assert np.allclose(nb.hex_bernstein_split(V, np.arange(8, dtype=np.int64)[None])[0], c0, rtol=1e-12, atol=1e-12)


def _stalled_ball():
    """A 3^3 cubed ball after the vertex steps with its band, where they stall: (V, hexes, boundary model, movable,
    the last vertex steps' info)."""
    Q, H = cubed_ball(3)
    bm = boundary_model(Q, [("hexahedron", H)], tolerance=SURFACE_TOLERANCE)
    mv = np.ones(len(Q), dtype=bool)
    W = Q
    for _ in range(3):
        W, info = localopt.local_sweeps(W, H, mv, boundary=bm, band_below=np.inf, patience=20)
    return W, H, bm, mv, info


def test_joint_steps_lift_where_the_vertex_steps_stop():
    """A 3^3 cubed ball with its band: the vertex steps stop at 0.855 (20 sweeps more gain nothing: each vertex alone
    cannot move without lowering a neighbour); the joint steps from there reach 0.89, valid, every boundary vertex
    within the band (or no farther off than it was), no hex's edge ratio below its floor. Without a boundary model
    the same steps take the boundary vertices off the sphere by more than twice the band: the band is what holds
    them."""
    W, H, bm, mv, info = _stalled_ball()
    assert info["min_after"] == info["min_before"]  # stalled
    J, jinfo = joint_steps(W, H, mv, boundary=bm)
    sj = sample_scaled_jacobians(J[H], "hexahedron").min()
    assert jinfo["steps"] > 0 and jinfo["min_before"] == pytest.approx(info["min_after"])
    assert sj == pytest.approx(jinfo["min_after"], abs=1e-12) and sj > info["min_after"] + 0.03, (info, jinfo)
    assert _certified(J, H)
    width = bm.band_width()
    before, after = bm.distance(W), bm.distance(J)
    assert (after <= np.maximum(width, before) * (1 + 1e-6)).all()
    floor = np.minimum(hex_edge_ratio(W, H), localopt.RATIO_FLOOR)
    assert (hex_edge_ratio(J, H) >= (1 - RATIO_SLACK) * floor).all()
    F, _ = joint_steps(W, H, mv, boundary=None)
    assert (bm.distance(F) > 2 * width).any()


def test_joint_steps_move_only_what_may_move():
    """Pinned vertices and boundary vertices without a band stay bit for bit; a target stops the steps."""
    P, H = structured_grid(4, 4, 4)
    Q = P + 0.2 * np.random.default_rng(1).uniform(-1, 1, P.shape) * (P.max() / 4)
    bm = boundary_model(Q, [("hexahedron", H)], tolerance=0.0)  # no band: the boundary stays
    mv = np.ones(len(Q), dtype=bool)
    mv[::5] = False
    J, info = joint_steps(Q, H, mv, boundary=bm)
    assert info["steps"] > 0 and info["min_after"] > info["min_before"]
    still = ~mv
    still[bm.vertices] = True
    assert np.array_equal(J[still], Q[still]) and not np.array_equal(J, Q)
    T, tinfo = joint_steps(Q, H, mv, boundary=bm, target=info["min_before"] + 0.01)
    assert info["min_before"] + 0.01 <= tinfo["min_after"] < info["min_after"]


def _joint_stage(name):
    """The default repair of a published mesh (``../shared/data/hexalab/NAME``) and the minimum scaled Jacobian
    before and after its joint steps."""
    from conftest import published

    m = hs.read(published(os.path.join("hexalab", name)))
    m = m.flipped(cells=m.mirrored_cells())  # as `hexsos repair --fix-orientation` (kitten folds over itself)
    r = hs.repair(m.points, m.hexes)
    stages = [h["stage"] for h in r.history]
    assert r.success and "joint" in stages, stages
    j = stages.index("joint")
    return r, r.history[j - 1]["min_sj"], r.history[j]["min_sj"]


def test_published_cat_2_joint_steps_lift_the_worst_cluster():
    """cat_2 (published): after the vertex steps its worst hexes, a cluster of eight around a feature corner, sit at
    0.66-0.68 (0.735 since stage 2 keeps a chunk of rounds below its start that the vertex steps lift past it); the
    repair's joint steps take the certified minimum past 0.80 (0.862 measured), 0.05 at least above where they
    began."""
    r, before, after = _joint_stage("cat_2.mesh")
    assert before < 0.76 and after > max(0.80, before + 0.05), (before, after)
    assert r.stats["joint_steps"] > 0 and r.stats["min_sj_after"] > 0.80
    assert f"joint steps {r.stats['stage_seconds']['joint']:.2f} s ({r.stats['joint_steps']} kept)" in r.summary()


def test_published_kitten_joint_steps_lift_its_plateau():
    """kitten_with_bifur_3 (published, 34,880 hexes), its 40 hexes folded over their neighbours flipped first: the
    joint steps lift the minimum from the vertex steps' 0.59 to 0.71 (one run; 0.54 to 0.67 when stage 2's rounds
    were judged by their minimum). As written, beside its worst hexes
    sat the folded ones with a Bernstein coefficient of det J near 0 (5e-6 of their largest), where a step of the
    trust region's size went below 0 at second order and every step was refused (0.277, 0.05 above the start);
    the steps near such a coefficient are at most 0.3 sqrt(r) of the edge length (``NEAR_ZERO_STEP``) since, and
    went from about 0.24 past 0.44 there."""
    _, before, after = _joint_stage("kitten_with_bifur_3.mesh")
    assert before < 0.65 and after > before + 0.05 and after > 0.65, (before, after)


def test_rows_that_cannot_bind_leave_the_program_as_it_was():
    """``binding_rows``: on programs shaped as the joint steps' (max t, sample rows ``t + a.d <= b``, other rows
    ``a.d <= b``, d in a box, some directions fixed), the rows left out never change the optimum, and most go. The
    sample row that bounds t least (here one with no move term: a hex whose vertices cannot move) must stay: leaving
    out the rows whose right side merely reaches their bound, that row with them, lets t rise past it."""
    from scipy.optimize import linprog
    from scipy.sparse import csr_matrix

    rng = np.random.default_rng(5)
    for trial in range(6):
        nv, ns, no = 60, 400, 80
        box = np.where(rng.random(nv) < 0.2, 0.0, 1.0)
        A = rng.standard_normal((ns + no, nv)) * (rng.random((ns + no, nv)) < 0.05) * 0.01
        b = np.concatenate([rng.random(ns) * 0.5, 0.02 + rng.random(no)])
        A[0] = 0.0
        b[0] = float(np.min(b[1:ns] + np.abs(A[1:ns]) @ box)) * 0.5  # binds, and defines the bound on t
        Afull = csr_matrix(np.column_stack([A, np.r_[np.ones(ns), np.zeros(no)]]))
        bounds = np.column_stack([-np.r_[box, 1.0], np.r_[box, 1.0]])
        bounds[-1] = (-np.inf, np.inf)
        cost = np.zeros(nv + 1)
        cost[-1] = -1.0
        full = linprog(cost, A_ub=Afull, b_ub=b, bounds=bounds, method="highs-ipm")
        Ar, br = binding_rows(Afull, b, box, ns)
        red = linprog(cost, A_ub=Ar, b_ub=br, bounds=bounds, method="highs-ipm")
        assert full.status == 0 and red.status == 0
        assert red.fun == pytest.approx(full.fun, abs=1e-9) and full.x[-1] == pytest.approx(b[0], abs=1e-9)
        assert (Afull @ red.x - b).max() < 1e-9  # the reduced program's optimum satisfies every row
        assert br.size < 0.5 * b.size, (br.size, b.size)
        reach = abs(Afull[:, :-1]) @ box
        need = reach + np.where(np.arange(b.size) < ns, b[0] + reach[0], 0.0)
        loose = ~(b >= need)  # ties left out too
        wrong = linprog(cost, A_ub=Afull[loose], b_ub=b[loose], bounds=bounds, method="highs-ipm")
        assert wrong.status == 0 and wrong.x[-1] > 1.5 * b[0], (trial, wrong.x[-1], b[0])


def test_a_program_s_move_is_spread_over_its_optimal_face_quietly():
    """``jointsteps._solve`` (HiGHS's interior point method without its crossover, ``LP_OPTIONS``): where the
    optimum leaves directions free (max t, t <= 1 + a.d and t <= 1 - a.d for 10 rows a over 30 directions, d in a
    box), the move is the face's middle, d = 0, not a vertex of it with directions at their bounds (what the
    crossover hands back); and scipy's warning that it passes the option to HiGHS as it is does not reach the
    user (a fresh interpreter with Python's default filters: pytest's own would show it here)."""
    import subprocess
    import sys

    from scipy.optimize import linprog

    from hexsos_plugins.meshrepair import jointsteps

    code = """if True:
        import numpy as np
        from scipy.sparse import csr_matrix
        from hexsos_plugins.meshrepair import jointsteps
        rng = np.random.default_rng(0)
        n, k = 30, 10
        a = rng.standard_normal((k, n))
        A = np.vstack([np.hstack([a, np.ones((k, 1))]), np.hstack([-a, np.ones((k, 1))])])
        p = {"cost": np.r_[np.zeros(n), -1.0], "A": csr_matrix(A), "b": np.ones(2 * k),
             "bounds": np.vstack([np.tile([-1.0, 1.0], (n, 1)), [-np.inf, np.inf]])}
    """
    ns = {}
    exec(code, ns)
    p, n = ns["p"], ns["n"]
    res = jointsteps._solve(p, None)
    assert res.status == 0 and res.x[-1] == pytest.approx(1.0, abs=1e-5)
    assert np.abs(res.x[:n]).max() < 1e-3, np.abs(res.x[:n]).max()
    crossed = linprog(p["cost"], A_ub=p["A"], b_ub=p["b"], bounds=p["bounds"], method=jointsteps.LP_METHOD)
    assert crossed.status == 0 and np.abs(crossed.x[:n]).max() > 0.5  # the same optimum at a vertex
    run = subprocess.run([sys.executable, "-c", code + "\nprint(jointsteps._solve(p, None).status)"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and run.stdout.strip() == "0", run.stderr
    assert run.stderr == "", run.stderr


def test_a_part_of_a_refused_step_is_kept_and_the_same_programs_reach_higher(monkeypatch):
    """On the cubed ball where the vertex steps stall, whole steps of the programs' moves are refused (their minimum
    falls at second order); half or a quarter of them is kept, so the same number of programs reaches higher than
    with whole steps alone (0.927 against 0.921 after 20)."""
    from hexsos_plugins.meshrepair import jointsteps

    W, H, bm, mv, _ = _stalled_ball()
    J, info = joint_steps(W, H, mv, boundary=bm, max_tries=20)
    monkeypatch.setattr(jointsteps, "STEP_PARTS", (1.0,))
    J1, whole = joint_steps(W, H, mv, boundary=bm, max_tries=20)
    assert info["tries"] == whole["tries"] == 20 and whole["part_steps"] == 0
    assert 0 < info["part_steps"] < info["steps"] and info["steps"] > whole["steps"]
    assert info["min_after"] > whole["min_after"] + 0.003, (info, whole)
    assert sample_scaled_jacobians(J[H], "hexahedron").min() == pytest.approx(info["min_after"], abs=1e-12)
    assert _certified(J, H)


def test_the_trust_region_grows_after_a_whole_step_stays_after_half_and_halves_otherwise(monkeypatch):
    """``next_delta``: x1.5 (capped) after the whole move kept, the same after half of it, half after a quarter or
    none; and the steps apply it once per round to the part the lead group kept (the cubed ball: one group, 20
    programs)."""
    from hexsos_plugins.meshrepair import jointsteps

    assert next_delta(0.02, 1.0) == pytest.approx(0.03) and next_delta(0.09, 1.0) == DELTA_MAX
    assert next_delta(0.02, 0.5) == 0.02
    assert next_delta(0.02, 0.25) == next_delta(0.02, 0.0) == 0.01
    monkeypatch.setattr(jointsteps, "HALF_KEEPS", False)
    assert next_delta(0.02, 0.5) == 0.01  # the rule before
    monkeypatch.setattr(jointsteps, "HALF_KEEPS", True)
    seen = []

    def record(delta, part):
        seen.append((delta, part))
        return next_delta(delta, part)

    monkeypatch.setattr(jointsteps, "next_delta", record)
    W, H, bm, mv, _ = _stalled_ball()
    _, info = joint_steps(W, H, mv, boundary=bm, max_tries=20)
    parts = [p for _, p in seen]
    assert len(seen) == info["tries"] and set(parts) <= {0.0, 0.25, 0.5, 1.0}
    assert sum(p > 0 for p in parts) == info["steps"] and sum(0 < p < 1 for p in parts) == info["part_steps"]
    assert 0.5 in parts  # a half step kept, and the next program saw the same region
    k = parts.index(0.5)
    assert k + 1 == len(seen) or seen[k + 1][0] == seen[k][0]


def test_a_plateau_larger_than_a_program_grows_the_program():
    """A 6^3 grid whose two middle layers of hexes are sheared alike: 72 hexes share the minimum (0.857), more than
    the 50 of :data:`~hexsos_plugins.meshrepair.jointsteps.MAX_HEXES`. A program of 50 of them lifts nothing (its
    hexes' neighbours on the plateau hold it down: no step kept); the default takes as many as the plateau holds
    and lifts the layers past 0.95, valid."""
    from hexsos_plugins.meshrepair.jointsteps import MAX_HEXES

    Q, H = _sheared_layers()
    s0 = sample_scaled_jacobians(Q[H], "hexahedron").min(axis=1)
    assert ((s0 < s0.min() + 1e-9).sum() == 72) and MAX_HEXES < 72
    mv = np.ones(len(Q), dtype=bool)
    _, fixed = joint_steps(Q, H, mv, max_tries=20, max_hexes=MAX_HEXES)
    assert fixed["steps"] == 0 and fixed["min_after"] == fixed["min_before"], fixed
    J, grown = joint_steps(Q, H, mv, max_tries=20)
    assert grown["hexes"] >= 72 and grown["min_after"] > 0.95, grown
    assert sample_scaled_jacobians(J[H], "hexahedron").min() == pytest.approx(grown["min_after"], abs=1e-12)
    assert _certified(J, H)


def test_past_their_budget_the_steps_go_on_while_they_gain(monkeypatch):
    """``go_on=(soft, window, gain)``: past ``soft`` the steps go on only while the minimum rose by at least ``gain``
    over the last ``window`` seconds. On a clock that moves one second a reading (two readings a program), on the
    sheared 6^3 grid: a gain no step reaches stops them at the first reading past ``soft``, where a run cut at as
    many programs ends, bit for bit; a gain of 0 never stops them (the minimum never falls): the run without
    ``go_on``; a gain between stops them at the first program whose last three gained less than it, and not
    before, and they then end as the run cut there."""
    from types import SimpleNamespace

    from hexsos_plugins.meshrepair import jointsteps

    Q, H = _sheared_layers()
    mv = np.ones(len(Q), dtype=bool)

    # HiGHS's own time limit runs on the wall clock: on a loaded machine a program cut by it in one run and not in
    # another sends the two runs different ways (seen once in the suite on two workers); no program is cut here
    monkeypatch.setattr(jointsteps, "LP_SECONDS", 1e3)

    def run(go_on=None, max_tries=40):
        ticks = iter(range(1, 10 ** 6))
        monkeypatch.setattr(jointsteps, "time", SimpleNamespace(perf_counter=lambda: float(next(ticks))))
        return joint_steps(Q, H, mv, max_tries=max_tries, go_on=go_on)

    # readings: 1 at the start, then 2 + 2i before program i and 3 + 2i after it
    full, finfo = run()
    assert finfo["tries"] > 8 and finfo["past_soft"] == 0.0
    never, ninfo = run(go_on=(5.0, 6.0, 1.0))  # past 5 at the reading before program 2
    cut, _ = run(max_tries=2)
    assert ninfo["tries"] == 2 and np.array_equal(never, cut) and ninfo["past_soft"] == 0.0  # ended at 5
    always, ainfo = run(go_on=(5.0, 6.0, 0.0))
    assert ainfo["tries"] == finfo["tries"] and np.array_equal(always, full)
    assert ainfo["past_soft"] == 2 * ainfo["tries"] + 1 - 5.0  # from 5 to the end of the last program

    def min_after(k):  # the minimum after k programs
        return run(max_tries=k)[1]["min_after"]

    gain = 1e-3
    mid, minfo = run(go_on=(5.0, 6.0, gain))
    k = minfo["tries"]
    assert 2 < k < finfo["tries"], (k, finfo)
    # stopped before program k: the three before it gained less than ``gain``; at the reading before, they had not
    assert min_after(k) - min_after(k - 3) < gain <= min_after(k - 1) - min_after(k - 4)
    assert np.array_equal(mid, run(max_tries=k)[0]) and minfo["past_soft"] == 2 * k + 1 - 5.0


def test_a_program_keeps_every_sample_a_part_of_its_height_above_the_minimum(monkeypatch):
    """``KEEP``: two hexes sharing a face whose four vertices are moved at random (the others fixed), one program
    each. With the default every sample ends at least ``KEEP`` of its height above the old minimum over the new one
    (the program holds it to first order; here it holds outright); with 0, on the two draws where raising the worst
    sample pulls a sample of the other hex down, that sample ends at the new minimum (its height lost by more than
    the bound allows), at about the same gain."""
    from hexsos_plugins.meshrepair import jointsteps

    assert 0 < jointsteps.KEEP < 1
    keep = jointsteps.KEEP

    def one_program(seed):
        P, H = structured_grid(2, 1, 1)
        mid = np.isclose(P[:, 0], 0.5 * P[:, 0].max())
        Q = P.copy()
        Q[mid] += 0.075 * P[:, 0].max() * np.random.default_rng(seed).standard_normal((mid.sum(), 3))
        s0 = sample_scaled_jacobians(Q[H], "hexahedron")
        J, info = joint_steps(Q, H, mid, max_tries=1)
        s = sample_scaled_jacobians(J[H], "hexahedron")
        assert info["steps"] == 1 and s.min() > s0.min() + 0.02 and _certified(J, H), info
        return s.min(), float(((s - s.min()) - keep * (s0 - s0.min())).min())

    kept = {seed: one_program(seed) for seed in range(6)}
    assert all(v >= -1e-9 for _, v in kept.values()), kept
    monkeypatch.setattr(jointsteps, "KEEP", 0.0)
    free = {seed: one_program(seed) for seed in (2, 3)}
    assert all(v < -1e-3 for _, v in free.values()), free
    assert all(abs(free[k][0] - kept[k][0]) < 2e-3 for k in free), (free, kept)


def test_vertex_groups_split_the_moving_vertices_where_no_hex_joins_them():
    """``vertex_groups``: on a row of 6 x 1 x 1 hexes, corner vertices at x = 0, 2 and 4 edge lengths share no hex:
    three groups, each with the hexes holding its vertex; the vertex at x = 1 shares a hex with those at 0 and 2 and
    joins them into one group. The groups' hexes never overlap and come largest first."""
    from hexsos_plugins.meshrepair.jointsteps import vertex_groups

    P, H = structured_grid(6, 1, 1)
    h = P[:, 0].max() / 6
    at = {i: int(np.flatnonzero(np.isclose(P[:, 0], i * h) & (P[:, 1] == 0) & (P[:, 2] == 0))[0]) for i in range(7)}

    def groups(xs):
        vmask = np.zeros(len(P), dtype=bool)
        vmask[[at[i] for i in xs]] = True
        return vertex_groups(vmask, H)

    def holding(vs):
        return set(np.flatnonzero(np.isin(H, vs).any(axis=1)))

    apart = groups([0, 2, 4])
    assert len(apart) == 3 and all(v.size == 1 for v, _ in apart)
    for v, hx in apart:
        assert set(hx) == holding(v)
    joined = groups([0, 1, 2, 4])
    assert [v.size for v, _ in joined] == [3, 1]
    assert set(joined[0][0]) == {at[0], at[1], at[2]} and set(joined[0][1]) == holding(joined[0][0])
    assert len(joined[0][1]) == 3 and set(joined[1][1]) == holding([at[4]]) and len(joined[1][1]) == 2
    assert not set(joined[0][1]) & set(joined[1][1])


def test_a_group_rises_while_the_lowest_cannot():
    """A 9 x 3 x 3 grid sheared alike (every hex at 0.857): on the left one interior vertex moves, every other vertex
    there is pinned (its hexes' corners away from it cannot rise); on the right every vertex moves. Two groups, one
    program each a round: the right's hexes rise past 0.88 while the left's stay; one program for both (the steps
    before) lifted nothing, the pinned corners holding its common lift at 0. On two threads the same mesh, bit for
    bit."""
    from hexsos_plugins.kernel.pool import threads_for

    P, H = structured_grid(9, 3, 3)
    h = P[:, 0].max() / 9
    Q = P.copy()
    Q[:, 0] += 0.6 * P[:, 1]
    mv = P[:, 0] > 5.5 * h
    inner = (np.isclose(P[:, 0], 2 * h) & (P[:, 1] > 0) & (P[:, 1] < P[:, 1].max()) & (P[:, 2] > 0)
             & (P[:, 2] < P[:, 2].max()))
    mv[np.flatnonzero(inner)[0]] = True
    s0 = sample_scaled_jacobians(Q[H], "hexahedron").min(axis=1)
    assert np.ptp(s0) < 1e-9
    J, info = joint_steps(Q, H, mv, max_tries=10)
    s1 = sample_scaled_jacobians(J[H], "hexahedron").min(axis=1)
    right = mv[H].any(axis=1) & (P[H][:, :, 0].min(axis=1) > 4 * h)
    assert info["programs"] == 2 * info["tries"] and info["steps"] > 0, info
    assert s1[right].min() > s0.min() + 0.02 and s1[~right].min() == pytest.approx(s0.min(), abs=1e-12)
    assert _certified(J, H)
    with threads_for(2):
        J2, info2 = joint_steps(Q, H, mv, max_tries=10)
    assert np.array_equal(J, J2) and info2["steps"] == info["steps"]


def test_split_layer_cuts_a_group_in_two_along_a_layer_of_vertices_that_stay():
    """``split_layer`` on every vertex of a 6^3 grid: cut at the median of x (x = 3 edge lengths), the vertices of
    the hexes across the cut on the lower side stay (the layer at x = 2, 49 vertices), and the rest falls into two
    groups, x <= 1 and x >= 3; the next turns cut along y, then z, and after three turns the upper side stays (the
    layer at x = 3)."""
    from hexsos_plugins.meshrepair.jointsteps import split_layer, vertex_groups

    P, H = structured_grid(6, 6, 6)
    h = P[:, 0].max() / 6
    vmask = np.ones(len(P), dtype=bool)
    verts = np.arange(len(P))
    for turn, axis, layer in ((0, 0, 2), (1, 1, 2), (2, 2, 2), (3, 0, 3), (4, 1, 3)):
        stay = split_layer(P, H, verts, vmask, turn)
        assert np.array_equal(np.flatnonzero(stay), np.flatnonzero(np.isclose(P[:, axis], layer * h))), turn
        groups = vertex_groups(vmask & ~stay, H)
        assert len(groups) == 2, turn
        sides = sorted((P[v, axis].min(), P[v, axis].max()) for v, _ in groups)
        assert sides[0][1] < layer * h - 0.5 * h and sides[1][0] > layer * h + 0.5 * h, (turn, sides)
        assert not set(groups[0][1]) & set(groups[1][1])
        # a group cut again, beside the other: on its own hexes as on the mesh's (the joint steps pass its own)
        rest = vmask & ~stay
        for t in range(3):
            whole = split_layer(P, H, groups[0][0], rest, t)
            assert whole.any() and np.array_equal(split_layer(P, H[groups[0][1]], groups[0][0], rest, t), whole)


def test_on_two_threads_a_large_group_is_cut_in_two_and_still_rises(monkeypatch):
    """The sheared 6^3 grid's plateau (72 hexes at 0.857, one group of 147 vertices) with
    :data:`~hexsos_plugins.meshrepair.jointsteps.SPLIT_VERTICES` at 100: on two threads each round cuts it in two
    (two programs a round, side by side), and the layers still rise past 0.95, valid; on one thread no cut (one
    program a round, the steps as before)."""
    from hexsos_plugins.kernel.pool import threads_for
    from hexsos_plugins.meshrepair import jointsteps

    Q, H = _sheared_layers()
    mv = np.ones(len(Q), dtype=bool)
    monkeypatch.setattr(jointsteps, "SPLIT_VERTICES", 100)
    one, info1 = joint_steps(Q, H, mv, max_tries=20)
    assert info1["splits"] == 0 and info1["programs"] == info1["tries"], info1
    with threads_for(2):
        two, info2 = joint_steps(Q, H, mv, max_tries=20)
    assert info2["splits"] == info2["tries"] and info2["programs"] >= 2 * info2["tries"], info2
    assert info2["min_after"] > 0.95 and _certified(two, H), info2
    assert sample_scaled_jacobians(two[H], "hexahedron").min() == pytest.approx(info2["min_after"], abs=1e-12)
