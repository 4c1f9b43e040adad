"""Time stepping with one Solver: an American put on the average of two assets (a 2D obstacle
problem no scene of nrmicp has: nonsymmetric, and with correlated assets no M-matrix).

    OPENBLAS_NUM_THREADS=1 python benchmarks/time_stepping.py --m 129 257 513

Black–Scholes in log prices x = log S on [log K − 1.5, log K + 1.5]², σ = (0.3, 0.2), ρ = 0.5,
r = 0.05, K = 100, T = 1; central differences (the cross term ρσ₁σ₂ ∂₁₂ puts positive entries off
the diagonal), implicit Euler with 20 steps, each the LCP (I − Δt L) u ≥ payoff, u = previous
step's value on the right-hand side, boundary values frozen at the payoff (Dirichlet, dropped from
the unknowns: m² unknowns). Peers, each for the whole march in its own process, CPU seconds:

    newton-warm   one Solver(A, method="newton") (hierarchy 'auto' = 'amg'), x0 = the previous step
    newton-nested the same Solver, x0 not given: a nested start at every step
    nrmgs+aa      nrmicp.solve(method="nrmgs", accelerate="anderson"), x0 = the previous step

Printed: CPU s of the march, mean finest Newton steps (or iterations) per time step, the worst
step's Res, and the value at S₁ = S₂ = K (the peers agree to the tolerance).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np
import scipy.sparse as sp

PEERS = ("newton-warm", "newton-nested", "nrmgs+aa")


def basket(m, sigma=(0.3, 0.2), rho=0.5, r=0.05, K=100.0, T=1.0, steps=20):
    """(A, payoff, x, dt, steps): the implicit-Euler matrix on the m × m interior nodes."""
    x = np.linspace(np.log(K) - 1.5, np.log(K) + 1.5, m + 2)
    h = x[1] - x[0]
    e = np.ones(m)
    d2 = sp.diags([e[:-1], -2 * e, e[:-1]], [-1, 0, 1]) / h ** 2
    d1 = sp.diags([-e[:-1], e[:-1]], [-1, 1]) / (2 * h)
    eye = sp.identity(m)
    s1, s2 = sigma
    L = (0.5 * s1 ** 2 * sp.kron(eye, d2) + 0.5 * s2 ** 2 * sp.kron(d2, eye) + rho * s1 * s2 * sp.kron(d1, d1)
         + (r - 0.5 * s1 ** 2) * sp.kron(eye, d1) + (r - 0.5 * s2 ** 2) * sp.kron(d1, eye) - r * sp.identity(m * m))
    dt = T / steps
    A = sp.csr_matrix(sp.identity(m * m) - dt * L)
    X1, X2 = np.meshgrid(x[1:-1], x[1:-1])
    payoff = np.maximum(K - 0.5 * (np.exp(X1) + np.exp(X2)), 0.0).ravel()
    return A, payoff, x, dt, steps


def boundary_load(m, x, dt, sigma=(0.3, 0.2), rho=0.5, r=0.05, K=100.0):
    """The frozen boundary values' (the payoff's) contribution to the right-hand side: −Δt L_B g."""
    X1, X2 = np.meshgrid(x, x)
    g = np.maximum(K - 0.5 * (np.exp(X1) + np.exp(X2)), 0.0)
    h = x[1] - x[0]
    s1, s2 = sigma
    # the full (m+2)² operator applied to g with the interior zeroed: what the boundary adds to interior rows
    gb = g.copy()
    gb[1:-1, 1:-1] = 0.0
    a, b, c = 0.5 * s1 ** 2 / h ** 2, 0.5 * s2 ** 2 / h ** 2, rho * s1 * s2 / (4 * h * h)
    d1, d2 = (r - 0.5 * s1 ** 2) / (2 * h), (r - 0.5 * s2 ** 2) / (2 * h)
    i = slice(1, -1)
    Lg = (a * (gb[i, 2:] + gb[i, :-2]) + b * (gb[2:, i] + gb[:-2, i])
          + c * (gb[2:, 2:] - gb[2:, :-2] - gb[:-2, 2:] + gb[:-2, :-2])
          + d1 * (gb[i, 2:] - gb[i, :-2]) + d2 * (gb[2:, i] - gb[:-2, i]))
    return dt * Lg.ravel()


def child(peer, m, tol):
    import nrmicp
    import pyamg  # noqa: F401  (imported outside the timed region, as a user's process has it)

    A, payoff, x, dt, steps = basket(m)
    load = boundary_load(m, x, dt)
    u = payoff.copy()
    its, worst = [], 0.0
    c0 = time.process_time()
    solver = nrmicp.Solver(A, method="newton", tol=tol) if peer.startswith("newton") else None
    for k in range(steps):
        q = -(u + load)
        if peer == "newton-warm":
            res = solver.solve(q, zeta=payoff, x0=u)
        elif peer == "newton-nested":
            res = solver.solve(q, zeta=payoff)
        else:
            res = nrmicp.solve(A, q, zeta=payoff, x0=u, method="nrmgs", accelerate="anderson", tol=tol,
                               maxiter=200_000)
        if not res.success:
            return dict(status=f"step {k}: {res.status.name}")
        u = res.z
        its.append(res.nit)
        worst = max(worst, res.residual)
    cpu = time.process_time() - c0
    mid = np.argmin(np.abs(x[1:-1] - np.log(100.0)))
    return dict(status="converged", cpu=cpu, steps=float(np.mean(its)), worst_res=worst,
                value=float(u.reshape(m, m)[mid, mid]), n=m * m)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--m", type=int, nargs="+", default=[129, 257, 513])
    ap.add_argument("--peers", nargs="+", default=list(PEERS), choices=PEERS)
    ap.add_argument("--tol", type=float, default=1e-9)
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print("RESULT " + json.dumps(child(args.child[0], int(args.child[1]), args.tol)))
        return
    print(f"# American put on the average of two assets, 20 implicit Euler steps, tol {args.tol}, "
          f"load {os.getloadavg()[0]:.1f}")
    print("| m | n | " + " | ".join(args.peers) + " |")
    print("|---|---|" + "---|" * len(args.peers))
    for m in args.m:
        cells = []
        for peer in args.peers:
            out = subprocess.run([sys.executable, __file__, "--tol", str(args.tol), "--child", peer, str(m)],
                                 capture_output=True, text=True)
            lines = [ln for ln in out.stdout.splitlines() if ln.startswith("RESULT ")]
            if not lines:
                cells.append(f"failed: {out.stderr.strip().splitlines()[-1:]}")
                continue
            r = json.loads(lines[-1][7:])
            cells.append(r["status"] if r["status"] != "converged" else
                         f"{r['cpu']:.2f} s, {r['steps']:.1f} per step, Res ≤ {r['worst_res']:.0e}, value {r['value']:.5f}")
        print(f"| {m} | {m * m:,} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
