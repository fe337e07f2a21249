"""``comparison.repair_fuzz``: its damages are what they say, and it tells a traceback, a warning and a false
certificate from a certified repair, a refusal and an honest failure (each judged on a case made to be one)."""

import io
import os
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import hexsos_plugins as hs
from comparison import repair_fuzz
from hexsos_plugins.cells.topology import collapsed_cells, face_diagonals
from hexsos_plugins.examples import structured_grid


def test_each_damage_does_what_it_says():
    P, H = structured_grid(3)
    rng = lambda: np.random.default_rng(7)  # noqa: E731  the same hex each time
    h = int(np.random.default_rng(7).integers(len(H)))
    Q, G = repair_fuzz.damage(P, H, rng(), "one hex at a point")
    assert np.ptp(Q[G[h]], axis=0).max() == 0 and np.array_equal(G, H)
    Q, G = repair_fuzz.damage(P, H, rng(), "a face's diagonal collapsed")
    assert G[h, 2] == G[h, 0] and collapsed_cells("hexahedron", G, face_diagonals("hexahedron")).sum() == 1
    assert not collapsed_cells("hexahedron", G).any()
    Q, G = repair_fuzz.damage(P, H, rng(), "the hex's diagonal collapsed")
    assert G[h, 6] == G[h, 0] and not collapsed_cells("hexahedron", G, face_diagonals("hexahedron")).any()
    Q, G = repair_fuzz.damage(P, H, rng(), "an edge collapsed")
    assert collapsed_cells("hexahedron", G).sum() == 1
    Q, G = repair_fuzz.damage(P, H, rng(), "hex named twice")
    assert len(G) == len(H) + 3 and np.array_equal(G[:len(H)], H)
    Q, G = repair_fuzz.damage(P, H, rng(), "flattened")
    assert np.ptp(Q[:, 2]) <= 1e-6 * np.ptp(P[:, 2]) and np.array_equal(Q[:, :2], P[:, :2])
    Q, _ = repair_fuzz.damage(P, H, rng(), "none")
    assert np.array_equal(Q, P)
    with pytest.raises(ValueError, match="unknown damage 'bent'"):
        repair_fuzz.damage(P, H, rng(), "bent")


def test_the_outcomes_are_told_apart(monkeypatch):
    P, H = structured_grid(3)
    Q = P.copy()
    Q[H[13][6]] = Q[H[13][0]] - 0.2  # the middle hex inverted, its neighbours with it
    assert (hs.check(Q, H).status != 1).any()
    assert repair_fuzz.run_one(Q, H, {}, 30)["outcome"] == "certified"
    G = H.copy()
    G[13, 1] = G[13, 0]
    refused = repair_fuzz.run_one(P, G, {}, 30)
    assert refused["outcome"] == "refused" and "InvalidInputError" in refused["why"]
    real = hs.repair

    def raising(*a, **k):
        return 1 / 0

    def false_claim(points, hexes, **k):  # success, the points as given: an inverted hex "certified"
        r = real(points, hexes, **k)
        return SimpleNamespace(points=np.array(points), success=True, message="certified", stats=r.stats)

    def warning(points, hexes, **k):
        warnings.warn("divide by zero encountered in divide", RuntimeWarning)
        return real(points, hexes, **k)

    def unnamed(points, hexes, **k):
        r = real(points, hexes, **k)
        return SimpleNamespace(points=r.points, success=False, message="something went wrong", stats=r.stats)

    for fake, what in ((raising, "traceback: "), (false_claim, "success without every hex proven valid"),
                       (warning, "RuntimeWarning: divide by zero"), (unnamed, "no success and no cell named")):
        monkeypatch.setattr(hs, "repair", fake)
        out = repair_fuzz.run_one(Q, H, {}, 30)
        assert out["outcome"] == "failure" and out["why"].startswith(what), (fake.__name__, out)
    monkeypatch.setattr(hs, "repair", real)
    D = H.copy()
    D[13, 6] = D[13, 0]  # one point at both ends of the hex's own diagonal: tried, never proven valid
    left = repair_fuzz.run_one(P, D, {}, 3)
    assert left["outcome"] == "not finished" and "1 hex not proven valid (hexes 13)" in left["why"], left


@pytest.mark.skipif(not os.path.exists(os.path.join(repair_fuzz.SHARED, "hexalab", "rockarm.vtk")),
                    reason="../shared/data absent")
def test_pieces_of_a_published_mesh_are_cut_as_said_and_two_runs_end_without_failure():
    from hexsos_plugins.io import read

    m = read(os.path.join(repair_fuzz.SHARED, "hexalab", "rockarm.vtk"))
    P, H = repair_fuzz.piece(m.points, m.hexes, np.random.default_rng(3), 50)
    assert H.shape == (50, 8) and P.shape[0] == len(np.unique(H)) and H.max() == len(P) - 1
    assert set(map(tuple, np.round(P, 12))) <= set(map(tuple, np.round(m.points, 12)))
    log = io.StringIO()
    rows = repair_fuzz.fuzz(2, seed=8, time_limit=20, max_hexes=80, log=log)
    assert len(rows) == 2 and log.getvalue().count("\n") == 2 and all(r["outcome"] != "failure" for r in rows), rows
    assert "| damage | runs |" in repair_fuzz.table(rows)
