"""Peers for a symmetric LCP(q, A): the convex QP  min 1/2 z'Az + q'z  s.t. z >= 0
(its KKT conditions are exactly the LCP), solved with off-the-shelf QP solvers, plus
projected SOR (the classical LCP iteration).

Each wrapper is  f(A, q, eps) -> dict(z, seconds, status, iters)  where `eps` is the single
accuracy knob listed in SETTINGS (what it sets is spelled out there). `solve_to_target`
tightens eps by 10x until Res(z) = ||min(Az + q, z)||_2 < target and reports the setting
that was needed. z is used as returned (no clipping to z >= 0): a slightly negative z
counts against the solver through min(., z).

Wall time covers everything a user pays: building the solver's matrices from A (triu,
identity constraint block), set-up (scaling, symbolic + numeric factorization) and solve.

PSOR, the PIQP/OSQP calls and the eps tuning are nrmicp._peers's (the work-precision bench's
peers), written once; Clarabel and proxsuite are only here.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from peers_impl import peers

INF = 1e20  # finite "infinity" accepted by every solver here


def _triu(A):
    return sp.triu(A, format="csc").astype(float)


def _timed(name, **kw):
    """nrmicp.bench.peers.qp_once as a wrapper f(A, q, eps) -> dict(z, seconds, status, iters)."""
    def solve(A, q, eps):
        t0 = time.perf_counter()
        y, status, iters = peers.qp_once(name, sp.csr_matrix(A, dtype=float), np.asarray(q, float), eps, **kw)
        return dict(z=y, seconds=time.perf_counter() - t0, status=status, iters=iters)
    return solve


osqp_solve = _timed("osqp")             # polishing on, max_iter 10⁶
piqp_solve = _timed("piqp", max_iter=500)


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


def psor_solve(A, q, tol, *, omega=1.0, colors=None, maxiter=1_000_000, time_limit=None):
    """Projected SOR  z_i <- max(0, z_i - omega (Az + q)_i / a_ii)  in a multicolour
    ordering (nrmicp.bench.peers.psor): rows of one colour do not couple, so each colour's
    half-sweep is one vectorised SpMV on that colour's rows and is exactly Gauss-Seidel/SOR in
    that ordering (red-black for the 5-point grid; default: the greedy colouring of A's graph).
    Stops on Res(z) < tol, checked every sweep (one extra SpMV)."""
    t0 = time.perf_counter()
    A = sp.csr_matrix(A, dtype=float)
    q = np.asarray(q, float)
    if colors is None:
        colors = peers.colours(A)
    o = peers.psor(A, q, np.zeros(A.shape[0]), tol, omega=omega, colour=colors, maxiter=maxiter,
                    time_limit=time_limit)
    return dict(z=o["z"], seconds=time.perf_counter() - t0, status=o["status"], iters=o["nit"],
                residual=o["residual"])


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
    Res(z) < target (nrmicp.bench.peers.tune_eps). Returns the last attempt plus `eps`, `res`,
    `reached`, `attempts` (list of (eps, res, seconds)). `seconds` is the time of the final
    (successful) run alone; `tuning_seconds` adds up all attempts."""
    f = QP_SOLVERS[name]

    def run(eps):
        out = f(A, q, eps)
        return out["z"], out["status"], out["iters"]

    o = peers.tune_eps(run, A, q, target, eps_start=eps_start, eps_min=eps_min, time_budget=time_budget)
    return dict(z=o["y"], seconds=o["seconds"], status=o["status"], iters=o["iterations"],
                eps=o["eps"], res=o["residual"], reached=o["reached"], attempts=o["attempts"],
                tuning_seconds=o["tuning_seconds"], setting=SETTINGS[name].format(eps=o["eps"]))
