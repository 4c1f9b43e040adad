"""Method 'newton' on QVIs with the exact zeta' as a LinearOperator (a matrix-free Newton step on the
whole ICP: FGMRES preconditioned by the LCP piece, cpp/include/nrmicp/detail/matrix_free.hpp)
against the outer fixed point without a Jacobian, in the same run (docs/MEASUREMENTS.md,
"Matrix-free Newton steps").

Problems:
- ``achp``: the 1D ACHP-style thermoforming QVI of benchmarks/qvi_outer.py, N = 63 -> 4095; zeta' =
  -phi (k I - T'' - diag(g' psi))^{-1} diag(g') at T(-z): dense, one banded solve a product.
- ``thermo2d``: nrmicp.scenes.thermoforming_2d (kappa = 2, delta = 1: a strong, long-range coupling,
  or the scene's defaults with --defaults), m = 127 -> 511 (n = 1.6e4 -> 2.6e5), its geometric
  hierarchy; zeta' = kappa (I + delta L)^{-1} diag(s'(z)): one sparse triangular pair a product.
- ``sin``: the 2D obstacle scene with zeta = psi + 0.2 sin z (zeta' diagonal, given as an operator).

Columns: Newton steps on the whole ICP (the calls of zeta'), outer steps (obstacle solves with
psi = zeta(z): the start and each step's active-set prediction with zeta'; the outer fixed point's
steps without), linear solves (every reduced system, obstacle solves included), FGMRES iterations of
the matrix-free steps and the iterations of their preconditioner's own solve (CG on the LCP piece
with a hierarchy; 0 when it is factorized), the obstacle solves' CG iterations, status, Res, numpy
complementarity ||min(Az + q, z - zeta(z))||_inf, CPU s of the solve (zeta and its products
included), and the largest difference between the two answers.

    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_operator.py
    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_operator.py --achp 63 255 --thermo2d 31 --sin 31
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import nrmicp
from nrmicp import scenes

try:
    from qvi_outer import achp_problem
except ImportError:   # run from the repository root as a module path
    from benchmarks.qvi_outer import achp_problem


def thermo2d_problem(m: int, kappa: float = 0.05, delta: float = 0.01):
    """(A, q, zeta, zeta_jacobian, hierarchy) of scenes.thermoforming_2d with its exact zeta' as an operator."""
    pb = scenes.thermoforming_2d(m, kappa=kappa, delta=delta, exact=False)
    phi0, ell, n = pb.reference["phi0"], pb.reference["ell"], pb.n
    lu = spla.splu(sp.csc_matrix(sp.identity(n) + delta * pb.A))

    def zeta_jacobian(z):
        u = (z - phi0) / ell
        ds = kappa * -2.0 * u / ell / (1.0 + u * u) ** 2
        return spla.LinearOperator((n, n), matvec=lambda v: lu.solve(ds * v.ravel()), dtype=float)

    return pb.A, pb.q, pb.zeta, zeta_jacobian, pb.prolongations()


def sin_problem(m: int):
    """(A, q, zeta, zeta_jacobian, hierarchy): the 2D obstacle scene with zeta = psi + 0.2 sin z."""
    pb = scenes.obstacle_2d(m, exact=False)
    psi, n = np.asarray(pb.zeta, dtype=float), pb.n

    def zeta_jacobian(z):
        d = 0.2 * np.cos(z)
        return spla.LinearOperator((n, n), matvec=lambda v: d * v.ravel(), dtype=float)

    return pb.A, pb.q, (lambda z: psi + 0.2 * np.sin(z)), zeta_jacobian, pb.prolongations()


def counted(f):
    """f, counting its calls in .calls."""
    def g(*a):
        g.calls += 1
        return f(*a)
    g.calls = 0
    return g


def solve(A, q, zeta, zeta_jacobian, hierarchy, tol):
    """One solve: (result, Newton steps on the ICP (calls of zeta_jacobian), CPU s)."""
    jac = counted(zeta_jacobian) if zeta_jacobian is not None else None
    t0 = time.process_time()
    r = nrmicp.solve(A, q, zeta, method="newton", tol=tol, hierarchy=hierarchy, zeta_jacobian=jac)
    return r, (jac.calls if jac else 0), time.process_time() - t0


def row(label, n, r, steps, cpu, err, diff=None):
    fgmres = r.counters.get("matrix_free_iterations", 0)
    pre = r.counters.get("matrix_free_preconditioner_iterations", 0)
    print(f"| {label} | {n:,} | {steps} | {r.outer_iterations} | {r.linear_solves} | {fgmres} | {pre} | "
          f"{r.inner_iterations - fgmres} | {r.status.name} | {r.residual:.1e} | {err:.1e} | {cpu:.2f} | "
          f"{'' if diff is None else f'{diff:.1e}'} |", flush=True)


def compare(label, n, A, q, zeta, zeta_jacobian, hierarchy, tol):
    """Rows with zeta' (operator) and without (the outer fixed point) on one problem."""
    def err(z):
        return float(np.max(np.abs(np.minimum(A @ z + q, z - zeta(z)))))
    with_j, steps, cpu = solve(A, q, zeta, zeta_jacobian, hierarchy, tol)
    e_with = err(with_j.z)
    without, _, cpu_without = solve(A, q, zeta, None, hierarchy, tol)
    row(f"{label}, zeta' operator", n, with_j, steps, cpu, e_with)
    row(f"{label}, outer fixed point", n, without, "", cpu_without, err(without.z),
        float(np.max(np.abs(without.z - with_j.z))))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--achp", type=int, nargs="*", default=[63, 255, 1023, 4095], help="1D sizes N")
    ap.add_argument("--thermo2d", type=int, nargs="*", default=[127, 255, 511], help="2D grid sides m (n = m^2)")
    ap.add_argument("--sin", type=int, nargs="*", default=[127, 255, 511], help="2D grid sides m of zeta = psi + 0.2 sin z")
    ap.add_argument("--defaults", action="store_true", help="thermoforming_2d at the scene's kappa, delta")
    ap.add_argument("--tol", type=float, default=1e-8)
    args = ap.parse_args(argv)
    print("| problem | n | Newton steps | outer steps | linear solves | FGMRES its | its in its preconditioner | "
          "obstacle solves' CG its | status | Res | numpy err | CPU s | max diff |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n in args.achp:
        A, q, zeta, jac = achp_problem(n)
        compare("ACHP 1D", n, A, q, zeta, jac, "auto", args.tol)
    coupling = {} if args.defaults else {"kappa": 2.0, "delta": 1.0}
    for m in args.thermo2d:
        A, q, zeta, jac, P = thermo2d_problem(m, **coupling)
        compare("thermoforming_2d" + ("" if args.defaults else " κ=2 δ=1"), m * m, A, q, zeta, jac, P, args.tol)
    for m in args.sin:
        A, q, zeta, jac, P = sin_problem(m)
        compare("ψ + 0.2 sin z", m * m, A, q, zeta, jac, P, args.tol)


if __name__ == "__main__":
    main()
