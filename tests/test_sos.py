"""The SOS / moment relaxations on Clarabel, and Clarabel's PSD cone layout on its own."""

import clarabel
import numpy as np
import pytest
import scipy.sparse as sp

from hexsos_plugins.cells import hexahedron as hx
from hexsos_plugins import kernel
from hexsos_plugins.kernel import sos
from hexsos_plugins.examples import inside_invalid_hex, random_hexes, unit_cube
from oracle import dense_min


def _min_eig_sdp(C, vec):
    """min <C, X> s.t. trace X = 1, X PSD (optimum: the smallest eigenvalue of C), with a given svec."""
    n = C.shape[0]
    m = n * (n + 1) // 2
    diag = vec(np.eye(n))
    A = sp.vstack([sp.csc_matrix(diag[None, :]), -sp.identity(m)]).tocsc()
    b = np.r_[1.0, np.zeros(m)]
    s = clarabel.DefaultSettings()
    s.verbose = False
    solver = clarabel.DefaultSolver(sp.csc_matrix((m, m)), vec(C), A, b,
                                    [clarabel.ZeroConeT(1), clarabel.PSDTriangleConeT(n)], s)
    sol = solver.solve()
    return str(sol.status), np.array(sol.x)


def test_clarabel_psd_cone_layout_upper_triangle_by_columns_with_sqrt2():
    rng = np.random.default_rng(0)
    R = rng.standard_normal((4, 4))
    C = R + R.T
    status, x = _min_eig_sdp(C, sos.svec)
    X = sos.smat(x, 4)
    assert status == "Solved"
    assert np.trace(C @ X) == pytest.approx(np.linalg.eigvalsh(C)[0], abs=1e-7)
    assert np.linalg.eigvalsh(X)[0] > -1e-7
    assert np.allclose(sos.svec(sos.smat(x, 4)), x)
    # the order is (0,0), (0,1), (1,1), (0,2), (1,2), (2,2), ...
    S = np.arange(16.0).reshape(4, 4)
    S = S + S.T
    assert np.allclose(sos.svec(S)[:4], [S[0, 0], np.sqrt(2) * S[0, 1], S[1, 1], np.sqrt(2) * S[0, 2]])


def test_a_wrong_psd_layout_is_caught():
    # row-major upper triangle without sqrt(2): the checks above tell it apart from the right layout
    def wrong(S):
        n = S.shape[0]
        return np.array([S[i, j] for i in range(n) for j in range(i, n)])

    rng = np.random.default_rng(1)
    R = rng.standard_normal((4, 4))
    C = R + R.T
    status, x = _min_eig_sdp(C, wrong)
    X = sos.smat(x, 4)  # read back the way Clarabel really lays it out
    right = (status == "Solved" and abs(np.trace(C @ X) - np.linalg.eigvalsh(C)[0]) < 1e-6
             and np.linalg.eigvalsh(X)[0] > -1e-7)
    assert not right


@pytest.mark.parametrize("relaxation", ["quad2", "paper"])
def test_relaxations_on_the_fixtures(relaxation):
    S = sos.SOSSolver(relaxation=relaxation)
    for X, value, where in [(unit_cube(), 1.0, None), (inside_invalid_hex(), -0.19927623, (1.0, 0.0, 0.468061))]:
        B, err = kernel.det_bernstein(X)
        C = hx.bernstein_to_monomial(B)[:, 0]
        r = S.solve(C, scale=np.abs(B).max())
        assert r.solved
        assert r.value == pytest.approx(value, abs=1e-6)
        low = S.certified_lower(r, C, 128 * err[0])
        assert value - 1e-6 < low <= value
        if where is not None:
            assert np.allclose(r.argmin, where, atol=1e-3)
            assert r.recovery_ratio < 1e-4  # rank one: exact recovery


def test_relaxation_registry_has_no_unbounded_member():
    assert set(sos.RELAXATIONS) == {"quad2", "paper"}
    with pytest.raises(ValueError, match="unknown relaxation"):
        sos.SOSSolver(relaxation="linear2")
    # the paper's multipliers are degree-4 SOS on linear constraints: coefficients up to degree 5
    assert sos.RELAXATIONS["paper"].degree == 5
    assert sos.RELAXATIONS["quad2"].degree == 4


def test_certified_lower_bound_is_sound_and_tight_on_random_hexes():
    X = random_hexes(40, sigma=0.5, seed=31)
    B, err = kernel.det_bernstein(X)
    C = hx.bernstein_to_monomial(B)
    dense, _, _ = dense_min(X)
    S = sos.SOSSolver()
    for m in range(40):
        r = S.solve(C[:, m], scale=np.abs(B[:, m]).max())
        assert r.solved
        low = S.certified_lower(r, C[:, m], 128 * err[m])
        assert low <= dense[m]
        assert dense[m] - low < 1e-6 * np.abs(B[:, m]).max()


def test_certificate_rejects_a_tampered_lambda():
    X = random_hexes(1, seed=32)[0]
    B, err = kernel.det_bernstein(X)
    C = hx.bernstein_to_monomial(B)[:, 0]
    S = sos.SOSSolver()
    r = S.solve(C, scale=np.abs(B).max())
    true_min, _, _ = dense_min(X[None])
    honest = S.certified_lower(r, C, 128 * err[0])
    r.lam += 0.1  # claim a bound 0.1 higher: the residual must grow and cancel the claim
    tampered = S.certified_lower(r, C, 128 * err[0])
    assert tampered <= true_min[0]
    # and the certificate still proves something: a bound that ignored lambda (or gave up, -inf) fails here
    assert true_min[0] - 1e-6 * np.abs(B).max() < honest <= true_min[0]
    assert abs(tampered - honest) < 1e-6 * np.abs(B).max()


def test_non_solved_status_is_reported_not_used():
    X = inside_invalid_hex()
    B, _ = kernel.det_bernstein(X)
    C = hx.bernstein_to_monomial(B)[:, 0]
    S = sos.SOSSolver(max_iter=2)
    r = S.solve(C)
    assert r.status != "Solved" and not r.solved
    assert np.isnan(r.value)


def test_batched_solves_and_certificates_equal_one_at_a_time():
    """solve_many (what the check runs) gives every hex exactly what solve + certified_lower give it alone, in any
    batch: the bound of a hex does not depend on its neighbours; a hex the solver cannot finish (2 iterations)
    keeps its status and is not given a bound by the others."""
    X = random_hexes(12, sigma=0.4, seed=33)
    B, err = kernel.det_bernstein(X)
    C = hx.bernstein_to_monomial(B)
    S = sos.SOSSolver()
    ce, sc = 128 * err, np.abs(B).max(axis=0)
    whole = S.solve_many(C, sc, coeff_err=ce)
    odd = S.solve_many(C[:, 1::2], sc[1::2], coeff_err=ce[1::2])
    for m in range(12):
        one = S.solve(C[:, m], scale=sc[m])
        assert whole.status[m] == one.status == "Solved"
        assert whole.value[m] == one.value and np.array_equal(whole.argmin[m], one.argmin)
        assert whole.lower[m] == S.certified_lower(one, C[:, m], ce[m])
        if m % 2:
            assert odd.lower[m // 2] == whole.lower[m] and odd.value[m // 2] == whole.value[m]
    dense, _, _ = dense_min(X)
    assert np.all(whole.lower <= dense) and np.all(dense - whole.lower < 1e-6 * np.abs(B).max(axis=0))
    short = sos.SOSSolver(max_iter=2).solve_many(C[:, :3], sc[:3], coeff_err=ce[:3])
    assert not short.solved.any() and np.isnan(short.value).all()
