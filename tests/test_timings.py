"""Result.timings add up (docs/SPEC.md, "Timings"): every field for every member, each part inside
the one that contains it, ``total`` the whole call. Structure only, never speed: the one clock
read here is a wall-clock bracket around a call, which ``total`` may not exceed."""
from __future__ import annotations

import time

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from nrmicp import _newton, scenes
from problems import readme_membrane

KEYS = {"setup", "factorization", "iterations", "zeta", "spmv", "inner_solve", "total"}
EPS = 1e-6  # seconds: the parts are sums of intervals of one clock, equal to their container up to rounding


def membrane(m):
    """The README's membrane (5-point −Δ_h, obstacle ψ, q = −8) on an m × m grid."""
    return readme_membrane(m)


def check_sums(t, wall=None):
    """The documented containment: setup and iterations are disjoint parts of total; factorization
    lies in setup + iterations; zeta, spmv and inner_solve in iterations."""
    assert set(t) == KEYS, t
    assert all(np.isfinite(v) and v >= 0 for v in t.values()), t
    assert t["setup"] + t["iterations"] <= t["total"] + EPS, t
    assert t["factorization"] <= t["setup"] + t["iterations"] + EPS, t
    assert t["zeta"] + t["spmv"] + t["inner_solve"] <= t["iterations"] + EPS, t
    if wall is not None:
        assert t["total"] <= wall, (t, wall)


def timed(f, *args, **kw):
    """f(*args, **kw) and the wall-clock seconds around it."""
    t0 = time.perf_counter()
    out = f(*args, **kw)
    return out, time.perf_counter() - t0


BAI = scenes.bai(6, kind="icp")   # n = 36, ζ a Python callable
ZETAS = {"lcp": None, "constant": np.full(BAI.A.shape[0], -0.5),
         "affine": nrmicp.Affine(0.1 * sp.identity(BAI.A.shape[0], format="csr"), np.zeros(BAI.A.shape[0])),
         "callable": BAI.zeta}


@pytest.mark.parametrize("kind", list(ZETAS))
@pytest.mark.parametrize("method", nrmicp.METHODS)
def test_every_member_fills_timings_that_add_up(method, kind):
    res, wall = timed(nrmicp.solve, BAI.A, BAI.q, ZETAS[kind], method=method, maxiter=300)
    check_sums(res.timings, wall)
    assert res.timings["iterations"] > 0
    if kind == "callable":
        assert res.timings["zeta"] > 0   # ζ was called: its time is ζ's
    if method != "newton":
        assert res.timings["spmv"] > 0


@pytest.mark.parametrize("hierarchy", [None, "amg"])
def test_newton_times_its_factorizations_and_reduced_solves(hierarchy):
    """Direct solves (no hierarchy) and CG with the V-cycle (amg, n >= 1000): each Newton step's
    factorization (or V-cycle update) and its reduced solve are timed, and the set-up is in setup."""
    A, q, psi = membrane(40)
    res, wall = timed(nrmicp.solve, A, q, zeta=psi, method="newton", hierarchy=hierarchy)
    assert res.success and res.linear_solves > 0
    assert res.inner == ("cg" if hierarchy else res.inner)
    t = res.timings
    check_sums(t, wall)
    assert t["factorization"] > 0 and t["inner_solve"] > 0 and t["spmv"] > 0 and t["setup"] > 0


def test_newton_callable_zeta_times_zeta_and_its_jacobian():
    A, q, psi = membrane(20)
    zeta = lambda z: psi + 0.1 * np.tanh(z)   # noqa: E731
    jac = lambda z: sp.diags(0.1 / np.cosh(z) ** 2, format="csr")   # noqa: E731
    for kw in ({}, {"zeta_jacobian": jac}):
        res, wall = timed(nrmicp.solve, A, q, zeta=zeta, method="newton", hierarchy=None, **kw)
        assert res.success
        check_sums(res.timings, wall)
        assert res.timings["zeta"] > 0 and res.timings["factorization"] > 0


def test_fallback_sweeps_are_timed_inside_the_newton_solve():
    """A 3×3 P-matrix on which the Newton steps cycle (tests/test_newton.py) makes Newton fall
    back to nrm: the fallback's factorization and sweeps count in the Newton solve's timings."""
    M = sp.csr_matrix(np.array([[1.0, -1.5, -2.5], [0.0, 1.5, -0.5], [3.0, -0.5, 1.5]]))
    res, wall = timed(nrmicp.solve, M, np.array([1.3, -0.1, -0.9]), method="newton", hierarchy=None, tol=1e-12)
    assert res.success and res.fallback_sweeps > 0
    check_sums(res.timings, wall)
    assert res.timings["factorization"] > 0 and res.timings["inner_solve"] > 0


def test_solve_counts_the_set_up_and_solver_solve_only_its_call(monkeypatch):
    """nrmicp.solve's total is the whole call, the Python set-up (here a hierarchy made slow on
    purpose) included; Solver.solve counts its own call, the constructor's are setup_timings."""
    slow = 0.05
    make_core = _newton.make_core

    def slow_make_core(*args, **kw):
        time.sleep(slow)
        return make_core(*args, **kw)

    monkeypatch.setattr(_newton, "make_core", slow_make_core)
    A, q, psi = membrane(20)
    res, wall = timed(nrmicp.solve, A, q, zeta=psi, method="newton", hierarchy="amg")
    check_sums(res.timings, wall)
    assert res.timings["setup"] >= slow and res.timings["total"] >= slow + res.timings["iterations"]

    s, built = timed(nrmicp.Solver, A, method="newton", hierarchy="amg")
    assert slow <= s.setup_timings["setup"] <= built
    for k in range(2):   # the first solve and a later one: neither counts the constructor
        res, wall = timed(s.solve, (1 + 0.1 * k) * q, zeta=psi)
        assert res.success
        check_sums(res.timings, wall)


def test_stationary_solver_reports_its_factorization_at_set_up():
    A, q, psi = membrane(20)
    s = nrmicp.Solver(A, method="nrm")
    assert 0 < s.setup_timings["factorization"] <= s.setup_timings["setup"]
    res = s.solve(q, zeta=psi, maxiter=50)
    check_sums(res.timings)
    assert res.timings["inner_solve"] > 0
    whole = nrmicp.solve(A, q, zeta=psi, method="nrm", maxiter=50)
    assert whole.timings["factorization"] > 0   # the set-up's, in the call that did it


@pytest.mark.parametrize("case", ["decoupled", "decoupled_affine", "scaled", "polish"])
def test_python_paths_keep_the_sum(case):
    """The rows-decoupled Newton path (and its whole-A solver for a coupling ζ), the scaled
    re-solve rounds and polish: their parts still inside total."""
    A, q, psi = membrane(20)
    n = A.shape[0]
    if case.startswith("decoupled"):
        A = A.tolil()
        A[0, :] = 0
        A[0, 0] = 1.0   # an identity row (a Dirichlet row kept in the matrix)
        A = A.tocsr()
        zeta = psi if case == "decoupled" else nrmicp.Affine(0.1 * sp.identity(n, format="csr"), psi)
        res, wall = timed(nrmicp.solve, A, q, zeta, method="newton")
    elif case == "scaled":
        d = 10.0 ** np.linspace(-3, 3, n)
        B = sp.csr_matrix(sp.diags(d) @ A)
        B.sort_indices()
        res, wall = timed(nrmicp.solve, B, d * q, psi, method="nrmgs", scale=True, accelerate="anderson",
                          maxiter=3000)
        assert res.scaling["kind"] == "both"
    else:
        res, wall = timed(nrmicp.solve, A, q, psi, method="nrmgs", maxiter=50, polish=True)
        assert res.polished
    check_sums(res.timings, wall)
