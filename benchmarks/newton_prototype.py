#!/usr/bin/env python
"""The peer "a user could assemble by hand": nested primal–dual active-set (semismooth)
Newton for LCP(q, A) in plain scipy/pyamg. Not part of nrmicp: benchmarks/mesh_independent.py
runs it next to ``method="newton"``.

    python benchmarks/newton_prototype.py --m 255 --hierarchy amg --inner splu

Active set at y: {D y < w}, D = diag(A), w = A y + q (the scaling of the modulus method with
Ω1 = I, Ω2 = D); a step solves A_II y_I = −q_I and sets y = 0 elsewhere. Nested iteration:
Galerkin levels A_{l+1} = P_lᵀ A_l P_l, q_{l+1} = P_lᵀ q_l from the coarsest (cold start y = 0)
to the finest, each start the projected prolongation max(P y_coarse, 0).
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def _inner_solve(M, b, x0, inner, rtol):
    """Solve M x = b: sparse LU (``splu``) or RS-AMG-preconditioned CG (SPD M only)."""
    if inner == "splu":
        return spla.splu(sp.csc_matrix(M)).solve(b)
    import pyamg
    ml = pyamg.ruge_stuben_solver(sp.csr_matrix(M))
    return ml.solve(b, x0=x0, tol=rtol, accel="cg", maxiter=200)


def active_set_newton(A, q, y, tol, maxiter, inner="splu", rtol=1e-10):
    """PDAS from y (≥ 0) until Res = ‖min(Ay + q, y)‖ ≤ tol or the active set repeats.
    Returns (y, steps, res)."""
    d = A.diagonal()
    res, steps, prev = np.inf, 0, None
    for steps in range(maxiter + 1):
        w = A @ y + q
        res = np.linalg.norm(np.minimum(w, y))
        active = d * y < w
        if res <= tol or (prev is not None and np.array_equal(active, prev)) or steps == maxiter:
            break
        inactive = np.flatnonzero(~active)
        y = np.zeros_like(y)
        if inactive.size:
            AII = A[inactive][:, inactive]
            b = -q[inactive]
            rt = min(rtol, 0.1 * tol / max(np.linalg.norm(b), 1e-300)) if tol > 0 else rtol
            y[inactive] = _inner_solve(AII, b, None, inner, rt)
        prev = active
    return y, steps, res


def amg_prolongations(A):
    import pyamg
    return [sp.csr_matrix(lv.P) for lv in pyamg.ruge_stuben_solver(sp.csr_matrix(A)).levels[:-1]]


def solve(A, q, prolongations=None, tol=1e-8, inner="splu", maxiter=200):
    """LCP(q, A) by (nested) active-set Newton. ``prolongations``: None (cold), "amg" or a
    list P_0, P_1, … (P_l: level l+1 → l). Returns dict(z, steps (finest level), solves (all
    levels), steps_per_level (finest first), res, seconds)."""
    t0 = time.perf_counter()
    A = sp.csr_matrix(A, dtype=float)
    q = np.asarray(q, dtype=float)
    Ps = amg_prolongations(A) if isinstance(prolongations, str) else list(prolongations or [])
    levels = [(A, q)]
    for P in Ps:
        Ac, qc = levels[-1]
        levels.append((sp.csr_matrix(P.T @ Ac @ P), P.T @ qc))
    y = np.zeros(levels[-1][0].shape[0])
    steps = []
    for lvl in range(len(levels) - 1, -1, -1):
        Al, ql = levels[lvl]
        if lvl < len(levels) - 1:
            y = np.maximum(Ps[lvl] @ y, 0.0)
        # coarse levels: to the fixed point of the active set (they are cheap); finest: to tol
        y, k, res = active_set_newton(Al, ql, y, tol if lvl == 0 else 0.0, maxiter, inner)
        steps.append(k)
    return dict(z=y, steps=steps[-1], solves=int(sum(steps)), steps_per_level=steps[::-1],
                res=float(res), seconds=time.perf_counter() - t0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--m", type=int, default=255, help="grid side (obstacle_2d, scaled by h^2)")
    ap.add_argument("--hierarchy", choices=["amg", "geometric", "none"], default="amg")
    ap.add_argument("--inner", choices=["splu", "cg"], default="splu")
    ap.add_argument("--tol", type=float, default=1e-8)
    a = ap.parse_args()
    from nrmicp import scenes
    P = scenes.obstacle_2d(a.m, exact=False)
    h2 = P.reference["h"] ** 2
    A, q = sp.csr_matrix(P.A * h2), h2 * (P.q + P.A @ P.zeta)   # shifted LCP in z − ψ
    pro = {"amg": "amg", "geometric": P.prolongations(), "none": None}[a.hierarchy]
    out = solve(A, q, pro, tol=a.tol, inner=a.inner)
    print(f"n={P.n} {a.hierarchy}/{a.inner}: finest steps {out['steps']}, solves {out['solves']}, "
          f"per level {out['steps_per_level']}, Res {out['res']:.2e}, {out['seconds']:.2f} s")


if __name__ == "__main__":
    main()
