"""Issue 37's remaining QVI targets in one run: impulse control (nrmicp.scenes.impulse_control) with
its sparse Jacobian (a selection matrix) and without one (the outer fixed point), and the 2D obstacle
scene with zeta = psi + 0.2 sin z and zeta' = diag(0.2 cos z) (sparse, or as a LinearOperator), over
n (the scene's geometric hierarchy: m = 2^k - 1 halves down to a small grid; m = 999 stops at 124^2,
whose cold solve took 13 Newton steps). Columns: Newton steps on the whole ICP (calls of zeta_jacobian;
'' without one), outer steps (obstacle solves), linear solves, nit, Anderson rejections, status, Res,
numpy error (impulse control: max |z - z_exact| against the scene's policy iteration; sin:
||min(Az + q, z - zeta(z))||_inf), CPU s and CPU microseconds per unknown.

    OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 python benchmarks/qvi_scaling.py
    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_scaling.py --impulse 101 401 --sin 99 --forms sparse
    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_scaling.py --impulse --sin 1023     # n = 1.05e6 alone
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import nrmicp
from nrmicp import scenes
from nrmicp.scenes.impulse import impulse_zeta_jacobian as impulse_jacobian
from qvi_operator import counted  # benchmarks/: the one call counter


def sin_problem(m: int):
    """(A, q, zeta, {form: zeta_jacobian}, hierarchy): the 2D obstacle scene, zeta = psi + 0.2 sin z."""
    pb = scenes.obstacle_2d(m, exact=False)
    psi, n = np.asarray(pb.zeta, dtype=float), pb.n

    def sparse_jacobian(z):
        return sp.diags(0.2 * np.cos(z), format="csr")

    def operator_jacobian(z):
        d = 0.2 * np.cos(z)
        return spla.LinearOperator((n, n), matvec=lambda v: d * v.ravel(), dtype=float)

    return (pb.A, pb.q, (lambda z: psi + 0.2 * np.sin(z)),
            {"sparse": sparse_jacobian, "operator": operator_jacobian}, pb.prolongations())


def run(label, n, A, q, zeta, jac, err, tol, **kw):
    """One solve and its row."""
    j = counted(jac) if jac is not None else None
    t0 = time.process_time()
    r = nrmicp.solve(A, q, zeta, method="newton", tol=tol, zeta_jacobian=j, **kw)
    cpu = time.process_time() - t0
    print(f"| {label} | {n:,} | {j.calls if j else ''} | {r.outer_iterations} | {r.linear_solves} | {r.nit} | "
          f"{r.counters.get('anderson_rejections', 0)} | {r.status.name} | {r.residual:.1e} | {err(r.z):.1e} | "
          f"{cpu:.2f} | {1e6 * cpu / n:.1f} |", flush=True)
    return r


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--impulse", type=int, nargs="*", default=[101, 401, 1601, 6401], help="impulse-control sizes n")
    ap.add_argument("--sin", type=int, nargs="*", default=[127, 255, 511],
                    help="2D grid sides m (n = m^2) of the sin QVI; 2^k - 1 keeps the scene's hierarchy deep")
    ap.add_argument("--jacobian", nargs="+", default=["with", "without"], choices=["with", "without"],
                    help="impulse control with its Jacobian, without (the outer fixed point)")
    ap.add_argument("--forms", nargs="+", default=["sparse", "operator"], choices=["sparse", "operator"],
                    help="the sin QVI's zeta' as a sparse matrix, as a LinearOperator")
    ap.add_argument("--tol", type=float, default=1e-8)
    args = ap.parse_args(argv)
    print("| problem | n | Newton steps | outer steps | linear solves | nit | rejected mixes | status | Res | "
          "numpy err | CPU s | CPU µs / unknown |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n in args.impulse:
        pb = scenes.impulse_control(n)
        for which in args.jacobian:
            jac = impulse_jacobian(pb) if which == "with" else None
            run(f"impulse control, {which} zeta'", n, pb.A, pb.q, pb.zeta, jac,
                lambda z, pb=pb: float(np.abs(z - pb.z_exact).max()), args.tol)
    for m in args.sin:
        A, q, zeta, jacs, P = sin_problem(m)
        for form in args.forms:
            run(f"ψ + 0.2 sin z, zeta' {form}", m * m, A, q, zeta, jacs[form],
                lambda z: float(np.abs(np.minimum(A @ z + q, z - zeta(z))).max()), args.tol, hierarchy=P)


if __name__ == "__main__":
    main()
