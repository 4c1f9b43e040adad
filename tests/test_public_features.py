"""Public features no other test exercises: Result.timings and history["seconds"], the Solver's
parameters/levels/scaling, `nrmicp demo`, and the documented switch points of the 'auto'
choices (hierarchy='auto' from n = 1,000, inner='auto' picking CG/BiCGSTAB with a hierarchy from n = 1,000).
Timings are checked for their structure (keys, signs, order), never for their values."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from nrmicp import scenes
from reference_impl import residual as reference_residual

TIMING_KEYS = {"setup", "factorization", "iterations", "zeta", "spmv", "inner_solve", "total"}


def tridiag(n, diag=2.5, sub=-1.0, sup=-1.0):
    return sp.diags([np.full(n - 1, sub), np.full(n, diag), np.full(n - 1, sup)], [-1, 0, 1], format="csr")


@pytest.mark.parametrize("method", ["nrmgs", "nrm", "newton"])
def test_timings_and_history_seconds(method):
    P = scenes.bai(8, kind="icp")
    res = nrmicp.solve(P.A, P.q, P.zeta, method=method, record_history=True, tol=1e-10)
    assert res.success
    t = res.timings
    assert set(t) >= TIMING_KEYS, t
    assert all(np.isfinite(v) and v >= 0 for v in t.values()), t
    # the factorizations happen in setup or, for A with z_update 'solve', lazily in the first solve
    assert t["factorization"] <= t["setup"] + t["total"]
    assert t["zeta"] <= t["total"] and t["spmv"] <= t["total"] and t["inner_solve"] <= t["total"]
    h = res.history
    assert len(h["seconds"]) == len(h["residual"]) == len(h["iteration"])
    assert np.all(np.diff(h["seconds"]) >= 0) and h["seconds"][0] >= 0
    assert h["iteration"][-1] == res.iterations


def test_solver_parameters_levels_and_scaling():
    A = tridiag(50)
    s = nrmicp.Solver(A, method="nrmsor", alpha=1.2)
    p = s.parameters
    np.testing.assert_array_equal(p["omega2"], A.diagonal())  # SPEC: Ω2 = D for the AOR types
    np.testing.assert_array_equal(p["omega1"], np.ones(50))
    np.testing.assert_array_equal(p["phi"], np.zeros(50))
    assert (p["alpha"], p["beta"], p["gamma"]) == (1.2, 1.2, 1.0)
    assert s.levels == 1 and s.scaling is None
    P0 = sp.csr_matrix((np.ones(50), (np.arange(50), np.arange(50) // 2)), shape=(50, 25))
    P1 = sp.csr_matrix((np.ones(25), (np.arange(25), np.arange(25) // 5)), shape=(25, 5))
    assert nrmicp.Solver(A, method="newton", hierarchy=[P0, P1]).levels == 3
    assert nrmicp.Solver(A, method="newton", hierarchy=None).levels == 1
    rng = np.random.default_rng(0)
    dr_in, dc_in = 10.0 ** rng.uniform(-3, 3, 50), 10.0 ** rng.uniform(-3, 3, 50)
    B = sp.csr_matrix(sp.diags(dr_in) @ A @ sp.diags(dc_in))
    s = nrmicp.Solver(B, method="nrmgs", scale="both")
    dr, dc = s.scaling
    S = sp.diags(dr) @ B @ sp.diags(dc)
    assert np.all(dr > 0) and np.all(dc > 0)
    # equilibrated: every row and column of D_r B D_c has its largest entry within a factor 4 of 1
    big_r, big_c = abs(S).max(axis=1).toarray().ravel(), abs(S).max(axis=0).toarray().ravel()
    assert np.all((big_r > 0.25) & (big_r <= 4)) and np.all((big_c > 0.25) & (big_c <= 4)), (big_r, big_c)
    q = -np.ones(50)
    res = s.solve(q, tol=1e-8)
    assert res.success and reference_residual(B, q, res.z) < 1e-8  # the paper's tol: judged on the original problem
    res = s.solve(q)   # the default rule: judged on the equilibrated problem, relative to its Res at 0
    dq = dr * q
    assert res.success and np.linalg.norm(np.minimum(S @ (res.z / dc) + dq, res.z / dc)) < \
        1e-10 * np.linalg.norm(np.minimum(dq, 0))


def test_hierarchy_auto_switches_at_1000():
    """'auto': no hierarchy below n = 1,000, AMG from there on (method 'newton'): n = 4,095, a 2^k - 1
    size, nests (cold, a 1D obstacle took 147 finest steps there; docs/MEASUREMENTS.md)."""
    assert nrmicp.Solver(tridiag(999), method="newton").levels == 1
    assert nrmicp.Solver(tridiag(1000), method="newton").levels > 1
    assert nrmicp.Solver(tridiag(4095), method="newton").levels > 1



def test_hierarchy_auto_leaves_a_dense_matrix_without_amg():
    """'auto' builds AMG only on a sparse A (at most 10% of the n² entries stored): a dense SPD
    matrix of n = 5,000 took 79 CPU s with it against 8 s cold (docs/MEASUREMENTS.md)."""
    n, rng = 4096, np.random.default_rng(3)
    for density, levels in ((0.12, 1), (0.08, 2)):
        R = sp.random(n, n, density=density / 2, random_state=rng)
        A = sp.csr_matrix(-(R + R.T))
        A.setdiag(-A.sum(axis=1).A1 + 1.0)   # diagonally dominant, positive diagonal
        assert (A.nnz / n**2 > 0.1) == (levels == 1)
        got = nrmicp.Solver(A, method="newton").levels
        assert (got == 1) if levels == 1 else (got > 1), (density, got)
        if levels == 1:
            assert nrmicp.Solver(A, method="newton", hierarchy="amg").levels > 1   # asked for, it is built

@pytest.mark.parametrize("symmetric, krylov", [(True, "cg"), (False, "bicgstab")])
def test_inner_auto_picks_a_krylov_solve_with_a_hierarchy_from_1000(symmetric, krylov):
    """inner='auto' with a hierarchy: the direct solve below n = 1,000, from there on CG for a
    symmetric A (an LCP), BiCGSTAB for a nonsymmetric one; without a hierarchy the direct solve."""
    for n, hierarchy, expected in ((998, True, None), (1000, True, krylov), (1000, False, None)):
        A = tridiag(n, sub=-1.0, sup=-1.0 if symmetric else -0.5)
        q = np.sin(np.arange(n))
        P = sp.csr_matrix(np.kron(np.eye(n // 2), [[0.5], [1.0]]))   # n/2 coarse points
        res = nrmicp.solve(A, q, method="newton", hierarchy=[P] if hierarchy else None, tol=1e-10)
        assert res.success and reference_residual(A, q, res.z) < 1e-10
        if expected is None:
            assert res.inner not in ("cg", "bicgstab"), res.inner
        else:
            assert res.inner == expected


def test_demo_runs_every_method():
    proc = subprocess.run([sys.executable, "-m", "nrmicp", "demo", "--m", "16"], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    for method in nrmicp.METHODS:
        rows = [line.split() for line in proc.stdout.splitlines() if line.split()[:1] == [method]]
        rows = [r for r in rows if r[1] in {s.name.lower() for s in nrmicp.Status}]
        assert len(rows) == 2, (method, proc.stdout)  # the LCP and the ICP
        assert all(r[1] == "converged" and float(r[4]) < 1e-8 for r in rows), rows
