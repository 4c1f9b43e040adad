"""Peers for a symmetric LCP(q, A): the convex QP  min 1/2 z'Az + q'z  s.t. z >= 0
(its KKT conditions are exactly the LCP), solved with off-the-shelf QP solvers, plus
projected SOR (the classical LCP iteration).

Each wrapper is  f(A, q, eps) -> dict(z, seconds, status, iters)  where `eps` is the single
accuracy knob listed in SETTINGS (what it sets is spelled out there). `solve_to_target`
tightens eps by 10x until Res(z) = ||min(Az + q, z)||_2 <= target and reports the setting
that was needed. z is used as returned (no clipping to z >= 0): a slightly negative z
counts against the solver through min(., z).

Wall time covers everything a user pays: building the solver's matrices from A (triu,
identity constraint block), set-up (scaling, symbolic + numeric factorization) and solve.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from scipy_modulus import residual

INF = 1e20  # finite "infinity" accepted by every solver here


def _triu(A):
    return sp.triu(A, format="csc").astype(float)


def osqp_solve(A, q, eps, *, polish=True, max_iter=1_000_000):
    import osqp
    t0 = time.perf_counter()
    n = A.shape[0]
    m = osqp.OSQP()
    m.setup(P=_triu(A), q=np.asarray(q, float), A=sp.identity(n, format="csc"),
            l=np.zeros(n), u=np.full(n, np.inf), eps_abs=eps, eps_rel=eps,
            polish=polish, max_iter=max_iter, verbose=False)
    r = m.solve()
    t1 = time.perf_counter()
    return dict(z=np.array(r.x), seconds=t1 - t0, status=str(r.info.status),
                iters=int(r.info.iter))


def clarabel_solve(A, q, eps, *, max_iter=500):
    import clarabel
    t0 = time.perf_counter()
    n = A.shape[0]
    s = clarabel.DefaultSettings()
    s.verbose = False
    s.max_iter = max_iter
    s.tol_gap_abs = s.tol_gap_rel = s.tol_feas = eps
    s.tol_ktratio = max(eps, 1e-12)
    # z >= 0  <=>  -I z + s = 0, s in R^n_+
    solver = clarabel.DefaultSolver(_triu(A), np.asarray(q, float),
                                    -sp.identity(n, format="csc"), np.zeros(n),
                                    [clarabel.NonnegativeConeT(n)], s)
    r = solver.solve()
    t1 = time.perf_counter()
    return dict(z=np.array(r.x), seconds=t1 - t0, status=str(r.status), iters=int(r.iterations))


def piqp_solve(A, q, eps, *, max_iter=500):
    import piqp
    t0 = time.perf_counter()
    n = A.shape[0]
    s = piqp.SparseSolver()
    s.settings.verbose = False
    s.settings.max_iter = max_iter
    s.settings.eps_abs = eps
    s.settings.eps_rel = eps
    s.settings.eps_duality_gap_abs = eps
    s.settings.eps_duality_gap_rel = eps
    s.setup(_triu(A), np.asarray(q, float), x_l=np.zeros(n), x_u=np.full(n, np.inf))
    status = s.solve()
    t1 = time.perf_counter()
    return dict(z=np.array(s.result.x), seconds=t1 - t0, status=str(status),
                iters=int(s.result.info.iter))


def proxsuite_solve(A, q, eps, *, max_iter=100_000):
    import proxsuite
    t0 = time.perf_counter()
    n = A.shape[0]
    qp = proxsuite.proxqp.sparse.QP(n, 0, n)
    qp.settings.eps_abs = eps
    qp.settings.eps_rel = 0.0
    qp.settings.max_iter = max_iter
    qp.settings.verbose = False
    qp.init(sp.csc_matrix(A, dtype=float), np.asarray(q, float), None, None,
            sp.identity(n, format="csc"), np.zeros(n), np.full(n, INF))
    qp.solve()
    t1 = time.perf_counter()
    return dict(z=np.array(qp.results.x), seconds=t1 - t0, status=str(qp.results.info.status),
                iters=int(qp.results.info.iter))


def grid_colors(m):
    """Red-black colouring of an m x m grid (row-major numbering)."""
    i, j = np.divmod(np.arange(m * m), m)
    return ((i + j) % 2).astype(np.int8)


def greedy_colors(A):
    """Greedy colouring of A's graph (pure Python loop: fine up to ~1e5 rows)."""
    A = sp.csr_matrix(A)
    n = A.shape[0]
    col = np.full(n, -1, dtype=np.int64)
    ip, ix = A.indptr, A.indices
    for i in range(n):
        used = {int(col[j]) for j in ix[ip[i]:ip[i + 1]] if j != i and col[j] >= 0}
        c = 0
        while c in used:
            c += 1
        col[i] = c
    return col


def psor_solve(A, q, tol, *, omega=1.0, colors=None, maxiter=1_000_000, time_limit=None,
               check_every=1):
    """Projected SOR  z_i <- max(0, z_i - omega (Az + q)_i / a_ii)  in a multicolour
    ordering: rows of one colour do not couple, so each colour's half-sweep is one
    vectorised SpMV on that colour's rows and is exactly Gauss-Seidel/SOR in that
    ordering (red-black for the 5-point grid). Stops on the same Res(z) < tol (checked
    every `check_every` sweeps; the check costs one extra SpMV)."""
    t0 = time.perf_counter()
    A = sp.csr_matrix(A, dtype=float)
    q = np.asarray(q, float)
    n = A.shape[0]
    if colors is None:
        colors = greedy_colors(A)
    blocks = []
    for c in np.unique(colors):
        rows = np.flatnonzero(colors == c)
        Ac = A[rows]
        blocks.append((rows, Ac, omega / Ac[np.arange(len(rows)), rows].A1, q[rows]))
    z = np.zeros(n)
    k, status, res = 0, "max_iterations", np.inf
    while True:
        if k % check_every == 0:
            res = residual(A, q, z)
            if res < tol:
                status = "converged"
                break
            if not np.isfinite(res):
                status = "diverged"
                break
        if k >= maxiter:
            break
        if time_limit is not None and time.perf_counter() - t0 > time_limit:
            status = "time_limit"
            break
        for rows, Ac, wd, qc in blocks:
            zc = z[rows] - wd * (Ac @ z + qc)
            np.maximum(zc, 0.0, out=zc)
            z[rows] = zc
        k += 1
    t1 = time.perf_counter()
    return dict(z=z, seconds=t1 - t0, status=status, iters=k, residual=res)


QP_SOLVERS = {
    "osqp": osqp_solve,
    "clarabel": clarabel_solve,
    "piqp": piqp_solve,
    "proxsuite": proxsuite_solve,
}

# What the single `eps` knob sets, per solver (reported with the results).
SETTINGS = {
    "osqp": "eps_abs=eps_rel={eps:g}, polish=True",
    "clarabel": "tol_gap_abs=tol_gap_rel=tol_feas=tol_ktratio={eps:g}",
    "piqp": "eps_abs=eps_rel=eps_duality_gap_abs=eps_duality_gap_rel={eps:g}",
    "proxsuite": "eps_abs={eps:g}, eps_rel=0",
}


def solve_to_target(name, A, q, target, *, eps_start=None, eps_min=1e-14, time_budget=None):
    """Tighten the solver's eps by 10x (from eps_start, default = target) until
    Res(z) <= target. Returns the last attempt plus `eps`, `res`, `reached`, `attempts`
    (list of (eps, res, seconds)). `seconds` is the time of the final (successful) run
    alone; `tuning_seconds` adds up all attempts."""
    f = QP_SOLVERS[name]
    eps = target if eps_start is None else eps_start
    attempts, spent = [], 0.0
    while True:
        try:
            out = f(A, q, eps)
            res = residual(A, q, out["z"])
        except Exception as e:  # a solver crash is a result too
            out = dict(z=None, seconds=np.nan, status=f"error: {e}", iters=-1)
            res = np.inf
        attempts.append((eps, res, out["seconds"]))
        spent += out["seconds"] if np.isfinite(out["seconds"]) else 0.0
        out.update(eps=eps, res=res, reached=bool(res <= target), attempts=attempts,
                   tuning_seconds=spent, setting=SETTINGS[name].format(eps=eps))
        if out["reached"] or eps / 10 < eps_min * 0.999 or out["z"] is None:
            return out
        if time_budget is not None and spent > time_budget:
            out["status"] += " (tuning budget exhausted)"
            return out
        eps /= 10
