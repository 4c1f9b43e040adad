"""Direct vs iterative inner solve of method 'newton' on one scene, each run in its own process
(peak memory): Newton steps, linear solves, Krylov iterations, CPU seconds, peak RSS.

    OPENBLAS_NUM_THREADS=1 python benchmarks/newton_inner.py --scene convection_2d --m 255 511 1023

Scenes: convection_2d (scenes.convection_diffusion_obstacle), convection_3d (the same upwind
operator on an m³ grid, built here), obstacle_2d, obstacle_3d."""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np
import scipy.sparse as sp


def convection_3d(m, eps=0.1, b=(1.0, 0.5, 0.25), a=0.1):
    """−ε Δu + b·∇u (first-order upwind, b ≥ 0) on m³ interior nodes, ψ = a − |x − ½|²."""
    h = 1.0 / (m + 1)
    I = sp.identity(m, format="csr")
    L = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1]) / h**2
    D = sp.diags([-np.ones(m - 1), np.ones(m)], [-1, 0]) / h  # backward difference (b > 0)
    ops = [L * eps + bk * D for bk in b]
    A = (sp.kron(sp.kron(ops[0], I), I) + sp.kron(sp.kron(I, ops[1]), I) + sp.kron(sp.kron(I, I), ops[2])).tocsr()
    x = np.arange(1, m + 1) * h
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    psi = (a - (X - .5) ** 2 - (Y - .5) ** 2 - (Z - .5) ** 2).ravel()
    return A, np.zeros(m ** 3), psi


def problem(scene, m):
    from nrmicp import scenes
    if scene == "convection_3d":
        return convection_3d(m)
    pb = {"convection_2d": scenes.convection_diffusion_obstacle, "obstacle_2d": scenes.obstacle_2d,
          "obstacle_3d": scenes.obstacle_3d}[scene](m, exact=False)
    return pb.A, pb.q, pb.zeta


def one(scene, m, inner, tol):
    import nrmicp
    A, q, psi = problem(scene, m)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t = time.process_time()
    r = nrmicp.solve(A, q, zeta=psi, method="newton", inner=inner, hierarchy="amg", tol=tol)
    cpu = time.process_time() - t
    print(json.dumps(dict(scene=scene, n=A.shape[0], inner=r.inner, status=str(r.status), residual=r.residual,
                          nit=r.nit, finest_steps=r.level_steps[0], linear_solves=r.linear_solves,
                          inner_iterations=r.inner_iterations, cpu=round(cpu, 2),
                          extra_mb=round((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024))),
          flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="convection_2d")
    ap.add_argument("--m", type=int, nargs="+", default=[255])
    ap.add_argument("--inner", nargs="+", default=["umfpack", "cg"])
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        one(a.scene, a.m[0], a.inner[0], a.tol)
        return
    for m in a.m:
        for inner in a.inner:
            subprocess.run([sys.executable, __file__, "--one", "--scene", a.scene, "--m", str(m), "--inner", inner,
                            "--tol", str(a.tol)], check=False)


if __name__ == "__main__":
    main()
