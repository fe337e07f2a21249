"""Branch-and-bound brackets and the local polish."""

import numpy as np

from hexsos_plugins import bernstein as bn
from hexsos_plugins import hexahedron as hx
from hexsos_plugins.examples import random_hexes, twisted_hex
from oracle import dense_min


def test_subdivision_matrix_children_represent_the_same_polynomial():
    X = random_hexes(5, seed=11)
    B, _ = hx.det_bernstein(X)
    kids = (B.T @ bn.subdivision_matrix()).reshape(5, 8, 27)
    rng = np.random.default_rng(0)
    for c in range(8):
        off = np.array([(c >> 2) & 1, (c >> 1) & 1, c & 1]) * 0.5
        q = rng.random((5, 3))  # local coordinates in the child
        child = hx.det_at_bernstein(kids[:, c, :].T, q)
        parent = hx.det_at_bernstein(B, off + 0.5 * q)
        assert np.allclose(child, parent, rtol=0, atol=1e-13)
    # and a wrong matrix (children swapped) does not
    T = bn.subdivision_matrix()
    wrong = np.concatenate([T[:, 27:54], T[:, :27], T[:, 54:]], axis=1)
    bad = (B.T @ wrong).reshape(5, 8, 27)
    q = rng.random((5, 3))
    assert not np.allclose(hx.det_at_bernstein(bad[:, 0, :].T, q), hx.det_at_bernstein(B, 0.5 * q), atol=1e-6)


def test_bracket_contains_the_dense_minimum_and_closes():
    X = np.concatenate([random_hexes(150, sigma=0.3, seed=12), random_hexes(50, sigma=1.0, seed=13),
                        np.stack([twisted_hex(a, shear=s) for a in np.linspace(0.3, 2.8, 6) for s in (0.0, 0.4, 0.8)])])
    B, err = hx.det_bernstein(X)
    br = bn.bracket(B, err)
    dense, _, _ = dense_min(X)
    scale = np.abs(B).max(axis=0)
    assert np.all(br.lower <= dense + 1e-15 * scale)  # sound
    assert np.all(br.upper <= dense + 1e-9 * scale)  # found the global minimum
    assert br.closed.all()
    assert np.all(br.upper - br.lower <= 1e-9 * scale)
    # upper is a value: det J at argmin
    assert np.allclose(hx.det_at(X, br.argmin)[0], br.upper, rtol=0, atol=1e-12 * scale.max())


def test_bracket_depth_limit_leaves_it_open_but_sound():
    X = random_hexes(200, sigma=0.5, seed=14)
    B, err = hx.det_bernstein(X)
    br = bn.bracket(B, err, max_depth=2)
    dense, _, _ = dense_min(X)
    assert (~br.closed).sum() > 0  # two levels are not enough for everything
    assert np.all(br.lower <= dense)
    assert np.all(br.upper >= dense - 1e-12)


def test_box_cap_keeps_the_bound_sound():
    # with one box kept per level, the box holding the minimum is often dropped: its bound must still count
    X = random_hexes(2000, sigma=1.0, seed=21)[[43, 126, 138, 147, 275, 310, 362, 370, 504, 558]]
    B, err = hx.det_bernstein(X)
    capped = bn.bracket(B, err, max_boxes=1)
    dense, _, _ = dense_min(X)
    assert np.all(capped.lower <= dense)
    assert np.all(capped.upper >= dense - 1e-12)


def test_polish_never_worsens_and_reaches_the_minimum():
    X = random_hexes(300, sigma=0.3, seed=15)
    B, _ = hx.det_bernstein(X)
    rng = np.random.default_rng(3)
    start = rng.random((300, 3))
    f0 = hx.det_at_bernstein(B, start)
    x, f = bn.polish(B, start)
    assert np.all(f <= f0)
    assert np.all((x >= 0) & (x <= 1))
    assert np.allclose(f, hx.det_at_bernstein(B, x))
    # from the bracket's argmin, polishing lands on the dense minimum's location
    br = bn.bracket(B, *hx.det_bernstein(X)[1:])
    x, f = bn.polish(B, br.argmin)
    dense, p, unique = dense_min(X)
    assert np.all(np.abs(f - dense) < 1e-9)
    assert np.all(np.abs(x - p)[unique].max(axis=1) < 1e-4)
