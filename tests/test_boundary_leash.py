"""The boundary's leash and its deviation: the second run that holds boundary vertices near their input positions
where the first left the surface far from the input's (``meshrepair.driver._leashed_again``)."""

import numpy as np
import pytest

import hexsos_plugins as hs
from hexsos_plugins.examples import cubed_ball, structured_grid
from hexsos_plugins.meshrepair import driver, step_words
from hexsos_plugins.meshrepair.boundary import boundary_model
from hexsos_plugins.meshrepair.fidelity import boundary_fidelity


def _top_vertex(P, z=1.0):
    """A vertex in the middle of the grid's top face (a surface vertex: no feature edge)."""
    top = np.flatnonzero(np.isclose(P[:, 2], z))
    c = P[top, :2].mean(axis=0)
    return int(top[np.argmin(np.linalg.norm(P[top, :2] - c, axis=1))])


def test_a_leashed_vertex_is_projected_within_its_leash_and_the_others_as_before():
    P, H = structured_grid(4)
    bm = boundary_model(P, [("hexahedron", H)])
    v = _top_vertex(P)
    w = int(np.flatnonzero(np.isclose(P[:, 2], 1.0) & np.isclose(P[:, 0], 0.25) & np.isclose(P[:, 1], 0.25))[0])
    assert bm.kind[np.searchsorted(bm.vertices, [v, w])].tolist() == [0, 0]
    X = P.copy()
    X[v] += [0.3, 0.1, 0.05]  # off the surface and along it, 0.32 from its input position
    X[w] += [0.3, 0.1, 0.05]
    free = bm.closest(X)
    assert np.allclose(free[v], P[v] + [0.3, 0.1, 0.0], atol=1e-12)  # the nearest point, however far
    held = bm.leashed([v], 0.1)
    C = held.closest(X)
    d = C[v] - P[v]
    assert np.linalg.norm(d) == pytest.approx(0.1, rel=1e-12)  # within the leash, at its rim ...
    assert C[v][2] == pytest.approx(1.0, abs=1e-12)  # ... on the surface ...
    assert np.allclose(d / np.linalg.norm(d), [0.3, 0.1, 0.0] / np.linalg.norm([0.3, 0.1, 0.0]), atol=1e-12)
    assert np.array_equal(C[w], free[w])  # the other vertex as without a leash
    assert np.allclose(held.closest_point(X[v], v), C[v], atol=1e-12)
    assert np.array_equal(bm.closest_point(X[v], v), free[v])  # the model without the leash is unchanged
    inside = X.copy()
    inside[v] = P[v] + [0.05, 0.0, 0.02]
    assert np.allclose(held.closest(inside)[v], P[v] + [0.05, 0.0, 0.0], atol=1e-12)  # within it: as before
    # band: project() keeps a leashed vertex's closest point within the leash, its band on top
    band = boundary_model(P, [("hexahedron", H)], tolerance=0.2).leashed([v], 0.1)
    W = band.project(X, [v])
    assert np.linalg.norm(W[v] - P[v]) <= 0.1 + band.band_width().max() + 1e-12
    assert np.linalg.norm(W[v] - P[v]) > 0.1  # the band: off the surface by up to its width


def test_a_leash_on_a_curved_surface_ends_within_it_and_near_the_surface():
    P, H = cubed_ball(3)
    bm = boundary_model(P, [("hexahedron", H)])
    surf = bm.vertices[bm.kind == 0]
    v = int(surf[0])
    t = np.cross(P[v], [0.0, 0.0, 1.0] if abs(P[v][2]) < 0.9 else [1.0, 0.0, 0.0])
    X = P.copy()
    X[v] = P[v] + 0.6 * t / np.linalg.norm(t)
    r = 0.15
    C = bm.leashed([v], r).closest(X)
    assert np.linalg.norm(C[v] - P[v]) <= r * (1 + 1e-12)
    assert np.linalg.norm(bm.closest(X)[v] - P[v]) > 2 * r  # without it: far
    assert bm.distance(C, [v])[0] < 0.05 * r  # the last pull leaves it a little off the faceted surface


def test_the_deviation_is_the_distance_between_the_surfaces_where_they_differ_and_zero_elsewhere():
    P, H = structured_grid(4)
    bm = boundary_model(P, [("hexahedron", H)])
    assert np.array_equal(bm.deviation(P), np.zeros(bm.surf_F.shape[0]))
    v = _top_vertex(P)
    V = P.copy()
    V[v, 2] += 0.03
    dev = bm.deviation(V)
    touch = (bm.surf_F == v).any(axis=1)
    assert dev.max() == pytest.approx(0.03, rel=1e-12)  # the vertex's own distance to the input plane
    assert (dev[touch] > 0).all() and (dev[~touch] == 0).all()
    ref = boundary_fidelity(P, V, H)["hausdorff_max"]  # pymeshlab's, sampled its own way
    assert dev.max() == pytest.approx(ref, rel=1e-6)


def _dent(n=4, depth=1.5):
    """A grid whose top face's middle vertex is pushed down through the layer below: its hexes inverted, the input's
    boundary folded there."""
    P, H = structured_grid(n)
    v = _top_vertex(P)
    P = P.copy()
    P[v, 2] -= depth / n
    return P, H, v


def test_a_repair_far_from_the_input_surface_runs_again_leashed_and_keeps_the_nearer_mesh(monkeypatch):
    # a coarse ball: its boundary quads cannot be square on the sphere, and the repair moves its boundary 11.6% of
    # the diagonal from the input's (along the surface and within the band), far past the trigger
    P, H = cubed_ball(2)
    # as it is: far everywhere (every boundary vertex), so no second run
    info0 = hs.repair(P, H, jobs=0).stats["boundary_leash"]
    assert info0["vertices"] == 26 and not info0["run"] and "more than 25%" in info0["why"]
    monkeypatch.setattr(driver, "LEASH_MAX_SHARE", 1.0)  # a second run wherever it is far
    monkeypatch.setattr(driver, "LEASH_FRACTION", 0.001)  # held within 0.1% of the diagonal
    monkeypatch.setattr(driver, "LEASH_COST", 1.0)
    seen = []
    r = hs.repair(P, H, jobs=0, callback=lambda e, V: seen.append(e))
    info = r.stats["boundary_leash"]
    # the second run's steps are told apart, for the callback (the doors' progress lines) and in the history
    held = [bool(e.get("boundary_held")) for e in seen]
    assert any(held) and not all(held) and held == sorted(held), held
    assert all(e.get("boundary_held") for e in r.history)
    words = {step_words(e) for e in seen if e.get("boundary_held")}
    assert words and all(w.endswith(", boundary held") and w[:-len(", boundary held")] in
                         {"vertex steps", "joint steps", "raising the quality", "untangling", "input",
                          "standing quads back up", "back into the band", "smoothing"} for w in words), words
    bm = boundary_model(P, [("hexahedron", H)], tolerance=driver.SURFACE_TOLERANCE)
    assert info["deviation"] > driver.LEASH_TRIGGER * driver.FAR_FRACTION
    assert info["run"] and info["kept"] and info["vertices"] > 0
    assert r.success and hs.check(r.points, H).status.min() == 1
    assert info["deviation_leashed"] < info["deviation"]
    diag = float(np.linalg.norm(P[bm.vertices].max(0) - P[bm.vertices].min(0)))
    assert info["deviation_leashed"] == pytest.approx(bm.deviation(r.points).max() / diag, rel=1e-12)
    assert info["min_sj_leashed"] == r.stats["min_sj_after"]
    assert r.stats["seconds"] >= info["seconds"]
    line = [x for x in r.summary().splitlines() if x.startswith("boundary leash")]
    assert len(line) == 1 and "held within 0.1%" in line[0] and line[0].rstrip().endswith("s)") and "kept (" in line[0]
    # a second run that costs more than LEASH_COST is not kept: the first run's mesh is returned
    monkeypatch.setattr(driver, "LEASH_COST", -1.0)
    r2 = hs.repair(P, H, jobs=0)
    info2 = r2.stats["boundary_leash"]
    assert info2["run"] and not info2["kept"] and r2.success
    assert r2.stats["min_sj_after"] == info2["min_sj_free"] != info2["min_sj_leashed"]
    assert "not kept (the first run's mesh is returned)" in r2.summary()
    assert not any(e.get("boundary_held") for e in r2.history)
    assert bm.deviation(r2.points).max() / diag == pytest.approx(info2["deviation"], rel=1e-12)
    # every boundary vertex of this ball is held: the projections take them nearer their input positions (a
    # projection that would lower the minimum stops short: the faces' middle vertices, pulled in, stay off the
    # surface; the leash is no bound on where a vertex ends)
    move = np.linalg.norm(r.points[bm.vertices] - P[bm.vertices], axis=1)
    free = np.linalg.norm(r2.points[bm.vertices] - P[bm.vertices], axis=1)
    assert move.mean() < 0.95 * free.mean(), (move.mean(), free.mean())
    # a leash wider than any vertex slid holds nothing: it does not run, and says why
    monkeypatch.setattr(driver, "LEASH_FRACTION", 2.0)
    r4 = hs.repair(P, H, jobs=0)
    info4 = r4.stats["boundary_leash"]
    assert not info4["run"] and "slid farther" in info4["why"] and info4["vertices"] > 0
    monkeypatch.setattr(driver, "LEASH_FRACTION", 0.001)
    # without the seconds for it, it does not run, and says why
    monkeypatch.setattr(driver, "LEASH_MIN_SECONDS", 1e6)
    r3 = hs.repair(P, H, jobs=0)
    info3 = r3.stats["boundary_leash"]
    assert not info3["run"] and info3["why"].startswith("not run") and info3["vertices"] > 0
    assert "were not held (not run: " in r3.summary()
    # nor with a time limit, a fixed boundary or a local fix
    for kw in ({"time_limit": 30.0}, {"boundary": "fixed"}, {"local": True}):
        assert "boundary_leash" not in hs.repair(P, H, jobs=0, **kw).stats, kw


def test_where_the_input_boundary_was_folded_no_vertex_is_leashed(monkeypatch):
    P, H, v = _dent()
    bad = hs.check(P, H).status != 1
    assert bad.any()
    suspect = np.zeros(P.shape[0], dtype=bool)
    suspect[H[bad].ravel()] = True
    monkeypatch.setattr(driver, "LEASH_TRIGGER", 1e-6)
    # only the inverted hexes' vertices may move: the surface differs only where it was folded
    r = hs.repair(P, H, jobs=0, pinned=~suspect)
    assert r.success
    info = r.stats["boundary_leash"]
    assert info["deviation"] > 1e-6 * driver.FAR_FRACTION  # it moved the fold ...
    assert info["vertices"] == 0 and not info["run"]  # ... and held nothing
    # the same fold with every vertex free: the surface moves beside it too, and those vertices are held
    monkeypatch.setattr(driver, "LEASH_MAX_SHARE", 1.0)
    monkeypatch.setattr(driver, "LEASH_FRACTION", 1e-6)
    r2 = hs.repair(P, H, jobs=0)
    info2 = r2.stats["boundary_leash"]
    assert info2["run"] and info2["vertices"] > 0 and r2.success
