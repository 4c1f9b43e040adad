"""The callback contract: called once for every iterate k = 0, 1, ..., the last one too (the
iterates of ``result.history``), so that for a converged solve the last call has ``result.z``
and ``result.residual`` — as scipy's minimize calls its callback after the last iteration too.
Every member, and each of the Newton member's loops (obstacle, Affine ζ, callable ζ with and
without its Jacobian)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from reference_impl import units_residual
from nrmicp import scenes

STATIONARY = [m for m in nrmicp.METHODS if m != "newton"]


def _bai(m=5):
    P = scenes.bai(m)
    return sp.csr_matrix(P.A), P.q


def _sine(n):
    """ζ(z) = 0.1 sin z − 0.2 (Lipschitz 0.1) and its Jacobian."""
    return (lambda z: 0.1 * np.sin(z) - 0.2), (lambda z: sp.diags(0.1 * np.cos(z), format="csr"))


def _record(**kwargs):
    """Solve with a callback that records (nit, z, residual) of every call."""
    calls = []

    def cb(intermediate_result):
        calls.append((intermediate_result.nit, intermediate_result.z.copy(), intermediate_result.residual))

    res = nrmicp.solve(callback=cb, record_history=True, **kwargs)
    return res, calls


def _check_last_call_is_the_result(res, calls):
    assert res.success, res.message
    assert calls, "the callback was never called"
    nit, z, r = calls[-1]
    assert np.array_equal(z, res.z), np.abs(z - res.z).max()
    # the same z; its stopping measure (the default rule's Res_E) is re-measured in numpy for a
    # constant or Affine ζ (equal to rounding)
    assert r == pytest.approx(res.criterion["value"], rel=1e-9, abs=1e-12)
    assert r < res.criterion["target"]
    # the callback saw exactly the iterates of the history
    assert [k for k, _, _ in calls] == list(res.history["iteration"])
    assert [rk for _, _, rk in calls] == list(res.history["residual"])


@pytest.mark.parametrize("accelerate", ["none", "anderson"])
@pytest.mark.parametrize("method", STATIONARY)
def test_last_callback_is_the_converged_iterate_stationary(method, accelerate):
    A, q = _bai()
    res, calls = _record(A=A, q=q, method=method, accelerate=accelerate, maxiter=5000)
    _check_last_call_is_the_result(res, calls)
    assert [k for k, _, _ in calls] == list(range(res.nit + 1))  # k = 0 .. nit, each once
    for k, z, r in calls[::7]:  # each is the iterate with its own Res_E, recomputed in numpy
        assert units_residual(A, q, z) == pytest.approx(r, rel=1e-9, abs=1e-14)


@pytest.mark.parametrize("zkind", ["constant", "affine", "callable"])
def test_last_callback_is_the_converged_iterate_with_zeta(zkind):
    A, q = _bai()
    n = A.shape[0]
    zeta = {"constant": np.full(n, -0.3), "affine": nrmicp.Affine(0.1 * sp.eye(n, format="csr"), -0.2),
            "callable": _sine(n)[0]}[zkind]
    res, calls = _record(A=A, q=q, zeta=zeta, method="nrmgs")
    _check_last_call_is_the_result(res, calls)


@pytest.mark.parametrize("zkind", ["none", "constant", "affine", "callable", "callable+jacobian"])
def test_last_callback_is_the_converged_iterate_newton(zkind):
    A, q = _bai()
    n = A.shape[0]
    zeta, jac = _sine(n)
    kw = {"none": {}, "constant": dict(zeta=np.full(n, -0.3)),
          "affine": dict(zeta=nrmicp.Affine(0.1 * sp.eye(n, format="csr"), -0.2)),
          "callable": dict(zeta=zeta), "callable+jacobian": dict(zeta=zeta, zeta_jacobian=jac)}[zkind]
    res, calls = _record(A=A, q=q, method="newton", hierarchy=None, **kw)
    _check_last_call_is_the_result(res, calls)


def test_last_callback_is_the_converged_iterate_newton_nested():
    problem = scenes.obstacle_2d(15)
    res, calls = _record(A=problem.A, q=problem.q, zeta=problem.zeta, method="newton",
                         hierarchy=problem.prolongations())
    _check_last_call_is_the_result(res, calls)


def test_the_semismooth_loops_iterates_are_numbered_as_the_history_and_nit_count_them():
    """Found by review: with zeta_jacobian the callback saw k = 10, 11, 12, 13 and the history said 15, 16, 17, 18
    (nit 18): the outer steps between the Newton steps were counted into the history only. Each iterate is now
    numbered when it is looked at, the outer steps before it included."""
    n = 200
    A = sp.csr_matrix(sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n)) * (n + 1) ** 2)
    x = np.linspace(0, 1, n + 2)[1:-1]
    psi = -2 + 2 * (x - 0.5) ** 2
    res, calls = _record(A=A, q=50 * np.ones(n), zeta=lambda z: psi + 0.2 * np.sin(z), method="newton",
                         zeta_jacobian=lambda z: sp.diags(0.2 * np.cos(z)))
    _check_last_call_is_the_result(res, calls)
    assert res.outer_iterations > 0 and calls[-1][0] == res.nit


def test_callback_is_called_at_the_last_iterate_of_a_non_converged_solve():
    A, q = _bai()
    res, calls = _record(A=A, q=q, method="nrm", maxiter=7, tol=1e-300)
    assert res.status == nrmicp.Status.MAX_ITERATIONS
    assert [k for k, _, _ in calls] == list(range(8))


def test_stop_iteration_at_the_converged_iterate_keeps_converged():
    A, q = _bai()
    first = nrmicp.solve(A, q)

    def cb(intermediate_result):
        if intermediate_result.nit == first.nit:
            raise StopIteration

    res = nrmicp.solve(A, q, callback=cb)
    assert res.status == nrmicp.Status.CONVERGED and res.nit == first.nit


def test_callback_nit_counts_on_over_scaled_re_solves():
    """With scale=, the core may be re-run from its last iterate with a tighter tolerance; the
    callback's nit counts on as the history's iterations do."""
    problem = scenes.obstacle_2d(8, exact=False)
    d = 10.0 ** np.random.default_rng(0).uniform(0, 4, problem.A.shape[0])  # badly scaled rows
    A = sp.csr_matrix(sp.diags(d) @ problem.A)
    A.sort_indices()
    res, calls = _record(A=A, q=d * problem.q, zeta=problem.zeta, method="nrmgs", scale="both", tol=1e-8)
    assert res.success and res.scaling["refinements"] >= 1  # the case this test is about
    assert [k for k, _, _ in calls] == list(res.history["iteration"])
    assert [k for k, _, _ in calls][-1] == res.iterations
