"""det J coefficients, values and gradients against exact arithmetic, finite differences and the oracle."""

import numpy as np
import pytest

from hexsos_plugins import kernel
from hexsos_plugins.cells import hexahedron as hx
from hexsos_plugins.examples import inside_invalid_hex, random_hexes, unit_cube
from oracle import det_j


def test_conventions_vtk_order_and_lexicographic_map():
    # node k sits at the documented corner; LEX_TO_VTK inverts the paper's lexicographic order
    assert hx.CORNERS.tolist() == [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]
    for lex, vtk in enumerate(hx.LEX_TO_VTK):
        assert 4 * hx.CORNERS[vtk][0] + 2 * hx.CORNERS[vtk][1] + hx.CORNERS[vtk][2] == lex
    # a voxel (x fastest) reordered by VOXEL_TO_VTK is the unit cube in VTK order
    voxel = np.array([(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0), (0, 0, 1), (1, 0, 1), (0, 1, 1), (1, 1, 1)])
    assert (voxel[hx.VOXEL_TO_VTK] == hx.CORNERS).all()


def test_twenty_monomials_of_total_degree_at_most_four():
    assert len(hx.MONOMIALS) == 20
    assert max(sum(m) for m in hx.MONOMIALS) == 4
    assert max(max(m) for m in hx.MONOMIALS) == 2
    for gone in [(2, 2, 0), (2, 0, 2), (0, 2, 2), (2, 1, 2), (2, 2, 2)]:
        assert gone not in hx.MONOMIALS


def test_unit_cube_has_det_one_everywhere():
    B, err = kernel.det_bernstein(unit_cube())
    assert np.allclose(B, 1.0, atol=0, rtol=1e-15)
    assert 0 < err[0] < 1e-12


def test_bernstein_coefficients_match_exact_rational_arithmetic_within_the_bound():
    X = random_hexes(20, sigma=0.5, seed=3)
    B, err = kernel.det_bernstein(X)
    for m in range(20):
        exact = np.array([float(c) for c in hx.bernstein_exact(X[m])])
        assert np.all(np.abs(B[:, m] - exact) <= err[m])
        assert np.abs(B[:, m] - exact).max() < 1e-13  # far inside the rigorous bound


def test_corner_coefficients_are_the_corner_values():
    X = random_hexes(10, seed=4)
    B, _ = kernel.det_bernstein(X)
    for n, c in enumerate(hx.CORNERS):
        k = 9 * 2 * c[0] + 3 * 2 * c[1] + 2 * c[2]
        assert np.allclose(B[k], det_j(X, np.broadcast_to(c.astype(float), (10, 1, 3)))[:, 0], rtol=1e-13, atol=1e-13)


def test_values_agree_in_all_three_evaluations_and_with_the_oracle():
    X = random_hexes(50, sigma=0.4, seed=5)
    rng = np.random.default_rng(0)
    p = rng.random((50, 3))
    B, _ = kernel.det_bernstein(X)
    C = hx.bernstein_to_monomial(B)
    mono = sum(C[i] * p[:, 0] ** a * p[:, 1] ** b * p[:, 2] ** c for i, (a, b, c) in enumerate(hx.MONOMIALS))
    direct, err = hx.det_at(X, p)
    ref = det_j(X, p[:, None, :])[:, 0]
    assert np.allclose(hx.det_at_bernstein(B, p), ref, rtol=0, atol=1e-12)
    assert np.allclose(mono, ref, rtol=0, atol=1e-12)
    assert np.all(np.abs(direct - ref) <= err)


def test_monomial_form_has_no_other_terms():
    # the tensor expansion of det J has exactly the 20 monomials: the other 7 tensor terms vanish
    X = random_hexes(30, sigma=0.6, seed=6)
    B, _ = kernel.det_bernstein(X)
    T = B.reshape(3, 3, 3, -1).copy()
    for ax in range(3):
        T = np.moveaxis(T, ax, 0)
        b0, b1, b2 = T[0].copy(), T[1].copy(), T[2].copy()
        T[0], T[1], T[2] = b0, 2 * (b1 - b0), b0 - 2 * b1 + b2
        T = np.moveaxis(T, 0, ax)
    scale = np.abs(B).max(axis=0)
    for i, j, k in [(2, 2, 0), (2, 0, 2), (0, 2, 2), (2, 2, 1), (2, 1, 2), (1, 2, 2), (2, 2, 2)]:
        assert np.all(np.abs(T[i, j, k]) < 1e-12 * scale)


def test_gradient_and_hessian_by_finite_differences():
    X = random_hexes(8, seed=7)
    B, _ = kernel.det_bernstein(X)
    p = np.random.default_rng(1).uniform(0.1, 0.9, (8, 3))
    f, g, H = hx.det_derivatives(B, p)
    h = 1e-6
    for ax in range(3):
        e = np.zeros(3)
        e[ax] = h
        fp, gp, _ = hx.det_derivatives(B, p + e)
        fm, gm, _ = hx.det_derivatives(B, p - e)
        assert np.allclose((fp - fm) / (2 * h), g[:, ax], atol=1e-7)
        assert np.allclose((gp - gm) / (2 * h), H[:, :, ax], atol=1e-6)
    assert np.allclose(H, H.transpose(0, 2, 1))


def test_vertex_gradient_by_finite_differences():
    X = random_hexes(6, seed=8)
    p = np.random.default_rng(2).random((6, 3))
    G = hx.det_vertex_gradient(X, p)
    h = 1e-6
    for n in range(8):
        for c in range(3):
            Xp, Xm = X.copy(), X.copy()
            Xp[:, n, c] += h
            Xm[:, n, c] -= h
            fd = (hx.det_at(Xp, p)[0] - hx.det_at(Xm, p)[0]) / (2 * h)
            assert np.allclose(fd, G[:, n, c], atol=1e-7)


def test_inside_invalid_fixture_is_positive_at_corners_and_centre():
    X = inside_invalid_hex()
    pts = np.vstack([hx.CORNERS, [[0.5, 0.5, 0.5]]]).astype(float)
    vals = det_j(X[None], pts[None])[0]
    assert np.all(vals > 0)  # what VTK's and pyvista's checks see
    assert det_j(X[None], np.array([[[1.0, 0.0, 0.468061]]]))[0, 0] == pytest.approx(-0.199276, abs=1e-6)


def test_exact_det_is_exact():
    X = inside_invalid_hex()
    v = hx.det_exact(X, (1.0, 0.0, 0.5))
    assert abs(float(v) - det_j(X[None], np.array([[[1.0, 0.0, 0.5]]]))[0, 0]) < 1e-14
    # a collapsed edge gives exactly zero at the corner, in float and exactly
    Y = unit_cube()
    Y[1] = Y[0]
    assert hx.det_exact(Y, (0, 0, 0)) == 0
    assert hx.det_at(Y, np.zeros(3))[0][0] == 0.0


@pytest.mark.parametrize("shape", ["soa", "aos", "single"])
def test_input_layouts_agree(shape):
    X = random_hexes(3, seed=9)
    ref, _ = kernel.det_bernstein(hx.gather(X.reshape(-1, 3), np.arange(24).reshape(3, 8)), layout="soa")
    if shape == "soa":
        B, _ = kernel.det_bernstein(np.ascontiguousarray(X.transpose(2, 1, 0)), layout="soa")
    elif shape == "aos":
        B, _ = kernel.det_bernstein(X)
    else:
        B = np.stack([kernel.det_bernstein(X[m])[0][:, 0] for m in range(3)], axis=1)
    assert np.array_equal(B, ref)
