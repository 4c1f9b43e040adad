"""Defaults on the matrices users bring (issue 14): a zero diagonal (monotone LCPs from contact
and games), a best iterate never worse than the start, ``verbose=True``, and the American put
march's first step. Each test failed before its fix."""
from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from nrmicp import scenes

#: A zero-diagonal LCP matrix (the issue's example).
ZERO_DIAG = sp.csr_matrix(np.array([[0.0, -1.0, -1.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]))
#: q for which LCP(q, ZERO_DIAG) has solutions: (1, 1, 0) and (2, 0, 1) for the first; the second
#: has z = (1, t, 1 - t), t in [0, 1].
SOLVABLE_Q = (np.array([1.0, -1.0, 2.0]), np.array([1.0, -1.0, 1.0]))
AOR_TYPES = ("nrmaor", "nrmsor", "nrmgs", "nrmj", "mms", "two_sweep")


def row_maxima(A):
    return np.asarray(abs(A).max(axis=1).todense()).ravel()


def assert_solves_lcp(A, q, z, tol=1e-8):
    """An independent check in numpy: z ≥ 0, w = Az + q ≥ 0, and zᵀw = 0 up to tol."""
    w = A @ z + q
    assert np.linalg.norm(np.minimum(w, z)) < tol
    assert z.min() > -tol and w.min() > -tol
    assert abs(z @ w) < 10 * tol * (1 + np.abs(z).max())


@pytest.mark.parametrize("q", SOLVABLE_Q, ids=["q1", "q2"])
def test_newton_solves_a_zero_diagonal_lcp_with_its_default_omega2(q):
    res = nrmicp.solve(ZERO_DIAG, q, method="newton")
    assert res.success, res.message
    assert_solves_lcp(ZERO_DIAG, q, res.z)


def test_newton_default_omega2_is_the_diagonal_where_positive_else_the_row_maximum_plus_its_diagonal():
    # a_ii < 0: + |a_ii| keeps the fallback's Omega2 + A off a zero diagonal where a_ii = -max |a_ij|
    A = sp.csr_matrix(np.array([[2.0, -1.0, 0.0], [-3.0, 0.0, 0.5], [0.0, -4.0, -1.0]]))
    omega2 = nrmicp.Solver(A, method="newton", hierarchy=None).parameters["omega2"]
    assert np.array_equal(omega2, [2.0, 3.0, 5.0])


def test_nrm_advice_on_a_zero_diagonal_names_only_what_runs_there():
    q = SOLVABLE_Q[0]
    res = nrmicp.solve(ZERO_DIAG, q, method="nrm")
    assert not res.success
    assert "omega2=A.diagonal()" in res.message and "does not apply" in res.message
    advice = res.message.split("try ", 1)[1]
    assert "method 'newton'" in advice and "accelerate='anderson'" in advice
    for option in ({"method": "newton"}, {"method": "nrm", "accelerate": "anderson"}):
        tried = nrmicp.solve(ZERO_DIAG, q, **option)
        assert tried.success, (option, tried.message)
        assert_solves_lcp(ZERO_DIAG, q, tried.z)


def test_nrm_advice_for_a_far_from_one_diagonal_is_unchanged():
    A = sp.csr_matrix(1e4 * (4 * sp.identity(4) - sp.eye(4, k=1) - sp.eye(4, k=-1)))
    res = nrmicp.solve(A, -np.ones(4), method="nrm", maxiter=3)
    assert "pass omega2=A.diagonal() or use method 'nrmm' or 'nrmgs'" in res.message
    # the advice, followed, converges within the same budget of iterations (issue 38)
    for option in ({"method": "nrm", "omega2": A.diagonal()}, {"method": "nrmm"}, {"method": "nrmgs"}):
        tried = nrmicp.solve(A, -np.ones(4), maxiter=50, **option)
        assert tried.success, (option, tried.message)
        assert_solves_lcp(A, -np.ones(4), tried.z)


@pytest.mark.parametrize("method", AOR_TYPES)
def test_aor_type_refusal_names_the_members_that_run(method):
    with pytest.raises(ValueError, match=r"A\[0,0\] = 0.*method 'newton'.*omega2.*accelerate='anderson'") as info:
        nrmicp.solve(ZERO_DIAG, SOLVABLE_Q[0], method=method)
    assert re.search(rf"method '{method}'", str(info.value))
    # The advice, followed, converges (two_sweep with omega2 + Anderson only on the first q).
    for q in SOLVABLE_Q if method != "two_sweep" else SOLVABLE_Q[:1]:
        assert nrmicp.solve(ZERO_DIAG, q, method="newton").success
        res = nrmicp.solve(ZERO_DIAG, q, method=method, omega2=row_maxima(ZERO_DIAG), accelerate="anderson")
        assert res.success, res.message
        assert_solves_lcp(ZERO_DIAG, q, res.z)


@pytest.mark.parametrize("method,options", [("nrm", {}), ("nrmm", {"alpha": 1.0}), ("nrmgs", {"omega2": 1.0})])
def test_best_iterate_is_never_worse_than_the_start(method, options):
    # Iterate 0 is the modulus image of the start, not the start: here it and all later iterates
    # had a larger Res than z = 0 (before the fix: Res 7.87 returned, 3.74 at z = 0).
    q = np.array([-2.0, -1.0, -3.0])
    res = nrmicp.solve(ZERO_DIAG, q, method=method, maxiter=200, **options)
    start = nrmicp.residual(ZERO_DIAG, q, np.zeros(3))
    assert not res.success
    assert res.residual == pytest.approx(start) and np.array_equal(res.z, np.zeros(3))
    assert res.nit == 0 and "initial guess" in res.message
    x0 = np.array([0.5, 0.0, 0.25])
    res = nrmicp.solve(ZERO_DIAG, q, method=method, maxiter=200, x0=x0, **options)
    assert res.residual <= nrmicp.residual(ZERO_DIAG, q, x0)
    assert nrmicp.residual(ZERO_DIAG, q, res.z) == pytest.approx(res.residual)


def test_best_iterate_from_the_start_with_a_constant_obstacle_is_in_the_original_variables():
    psi = np.array([0.5, -1.0, 2.0])
    q = np.array([-2.0, -1.0, -3.0])
    x0 = np.array([1.0, 0.0, 2.5])
    res = nrmicp.solve(ZERO_DIAG, q, zeta=psi, method="nrm", maxiter=200, x0=x0)
    assert res.residual <= nrmicp.residual(ZERO_DIAG, q, x0, psi) + 1e-15
    assert nrmicp.residual(ZERO_DIAG, q, res.z, psi) == pytest.approx(res.residual)


def test_verbose_true_means_one_and_false_means_silent(caplog):
    P = scenes.bai(8)
    with caplog.at_level("INFO", logger="nrmicp"):
        on = nrmicp.solve(P.A, P.q, verbose=True)
    lines = [r.getMessage() for r in caplog.records if r.name == "nrmicp"]
    assert on.success and lines and "converged" in lines[-1]
    caplog.clear()
    with caplog.at_level("INFO", logger="nrmicp"):
        nrmicp.Solver(P.A, verbose=np.bool_(True)).solve(P.q, verbose=False)
    assert not [r for r in caplog.records if r.name == "nrmicp"]


def test_american_put_march_takes_its_first_newton_step_from_the_nested_start():
    # n_space = 3200 is below hierarchy='auto''s AMG threshold: cold from the payoff the first
    # step took 29 Newton steps (the exercise boundary moves about one node per step).
    price, info = scenes.american_put_price(100.0, n_space=3200, n_time=10, method="newton", full_output=True)
    assert info["success"]
    assert info["nit"][0] <= 3
    exact = scenes.american_put_price(100.0, n_space=3200, n_time=10, method="exact")
    assert price == pytest.approx(exact, abs=1e-6)


def test_american_put_march_keeps_an_explicit_cold_start():
    _, info = scenes.american_put_price(100.0, n_space=800, n_time=2, method="newton", hierarchy=None,
                                        full_output=True)
    assert info["nit"][0] > 3  # the caller asked for no hierarchy: the first step starts cold
