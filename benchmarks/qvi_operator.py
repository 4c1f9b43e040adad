"""Issue 37's QVI table in one run: per scene and size, method 'newton' with zeta' (Newton on the whole
ICP) and without it (the outer fixed point on zeta), and one obstacle solve of the same size (zeta frozen
at the answer's zeta(z*), the same A, q, hierarchy and tol) for the ratio of their CPU times
(docs/MEASUREMENTS.md, "QVIs at Newton speed: the issue-37 table").

Scenes:
- ``achp``: the 1D ACHP-style thermoforming QVI of benchmarks/qvi_outer.py, N = 63 -> 4095 (hierarchy
  'auto'); zeta' = -phi (k I - T'' - diag(g' psi))^{-1} diag(g') at T(-z), a LinearOperator (dense: one
  banded solve a product).
- ``thermo2d``: nrmicp.scenes.thermoforming_2d (kappa = 2, delta = 1: a strong, long-range coupling, or
  the scene's defaults with --defaults), m = 127 -> 1023 (n = 1.6e4 -> 1.05e6), its geometric hierarchy;
  zeta' = kappa (I + delta A)^{-1} diag(s'(z)) as a LinearOperator (scenes.thermoforming's: one solve with the
  scene's sparse LU a product).
- ``impulse``: nrmicp.scenes.impulse_control, n = 101 -> 6401 (hierarchy 'auto'), its sparse selection
  Jacobian.
- ``sin``: the 2D obstacle scene with zeta = psi + 0.2 sin z, m = 127 -> 1023 (n = 16,129 -> 1.05e6), its
  geometric hierarchy (m = 2^k - 1: every size nests to the coarsest grid; m = 99 halves twice only);
  zeta' = diag(0.2 cos z) as a LinearOperator (or sparse, --sin-form sparse).

Columns: with zeta': Newton steps on the whole ICP (calls of zeta_jacobian), linear solves (every reduced
system: obstacle solves, matrix-free steps' preconditioner solves), status and Res; without: outer steps
(obstacle solves with psi = zeta(z)), linear solves, status and Res; numpy err = the larger of the two
answers' ||min(Az + q, z - zeta(z))||_inf; CPU s of each whole QVI (zeta and its products included) and
of the obstacle solve; the QVIs' CPU over the obstacle's; CPU microseconds per unknown with zeta'.

    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_operator.py
    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_operator.py --achp 63 255 --thermo2d 31 --impulse 101 --sin 31
    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_operator.py --achp --thermo2d --impulse --sin 1023  # one scene
    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_operator.py --achp --thermo2d --impulse --tol default  # the default stop
"""
from __future__ import annotations

import argparse
import gc
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import pyamg  # noqa: F401  (imported before timing: else the first solve with an 'amg' hierarchy pays it)

import nrmicp
from nrmicp import scenes
from nrmicp.scenes.impulse import impulse_zeta_jacobian
from nrmicp.scenes.thermoforming import thermoforming_zeta_jacobian

try:
    from qvi_outer import achp_problem
except ImportError:   # run from the repository root as a module path
    from benchmarks.qvi_outer import achp_problem


def thermo2d_problem(m: int, kappa: float = 0.05, delta: float = 0.01):
    """(A, q, zeta, zeta_jacobian, hierarchy) of scenes.thermoforming_2d with its exact zeta' as an operator."""
    pb = scenes.thermoforming_2d(m, kappa=kappa, delta=delta, exact=False)
    return pb.A, pb.q, pb.zeta, thermoforming_zeta_jacobian(pb), pb.prolongations()


def sin_problem(m: int, form: str = "operator"):
    """(A, q, zeta, zeta_jacobian, hierarchy): the 2D obstacle scene with zeta = psi + 0.2 sin z, zeta' as a
    LinearOperator or a sparse diagonal."""
    pb = scenes.obstacle_2d(m, exact=False)
    psi, n = np.asarray(pb.zeta, dtype=float), pb.n

    def zeta_jacobian(z):
        d = 0.2 * np.cos(z)
        if form == "sparse":
            return sp.diags(d, format="csr")
        return spla.LinearOperator((n, n), matvec=lambda v: d * v.ravel(), dtype=float)

    return pb.A, pb.q, (lambda z: psi + 0.2 * np.sin(z)), zeta_jacobian, pb.prolongations()


def impulse_problem(n: int):
    """(A, q, zeta, zeta_jacobian, hierarchy) of scenes.impulse_control with its sparse selection Jacobian."""
    pb = scenes.impulse_control(n)
    return pb.A, pb.q, pb.zeta, impulse_zeta_jacobian(pb), "auto"


def counted(f):
    """f, counting its calls in .calls."""
    def g(*a):
        g.calls += 1
        return f(*a)
    g.calls = 0
    return g


def timed(A, q, zeta, hierarchy, tol, zeta_jacobian=None):
    """One method='newton' solve: (result, CPU s); the garbage of the solves before it collected first."""
    gc.collect()
    t0 = time.process_time()
    stop = {} if tol is None else {"tol": tol}   # None: the library's default (units-free, relative) stop
    r = nrmicp.solve(A, q, zeta, method="newton", hierarchy=hierarchy, zeta_jacobian=zeta_jacobian, **stop)
    return r, time.process_time() - t0


def compare(label, n, A, q, zeta, zeta_jacobian, hierarchy, tol):
    """One row: the QVI with zeta', without it, and one obstacle solve at zeta(z*) of the answer with zeta'."""
    def err(z):
        return float(np.max(np.abs(np.minimum(A @ z + q, z - zeta(z)))))
    jac = counted(zeta_jacobian)
    with_j, cpu_with = timed(A, q, zeta, hierarchy, tol, jac)
    without, cpu_without = timed(A, q, zeta, hierarchy, tol)
    e = max(err(with_j.z), err(without.z))
    psi = np.array(zeta(with_j.z))   # a copy: some scenes' zeta overwrites its buffer
    _, cpu_obstacle = timed(A, q, psi, hierarchy, tol)
    obstacle = max(cpu_obstacle, 1e-6)
    print(f"| {label} | {n:,} | {jac.calls} | {with_j.linear_solves} | {with_j.status.name}, {with_j.residual:.1e} | "
          f"{without.outer_iterations} | {without.linear_solves} | {without.status.name}, {without.residual:.1e} | "
          f"{e:.1e} | {cpu_with:.2f} | {cpu_without:.2f} | {cpu_obstacle:.3f} | {cpu_with / obstacle:.1f} | "
          f"{cpu_without / obstacle:.1f} | {1e6 * cpu_with / n:.1f} |", flush=True)
    return with_j, without


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--achp", type=int, nargs="*", default=[63, 255, 1023, 4095], help="1D sizes N")
    ap.add_argument("--thermo2d", type=int, nargs="*", default=[127, 255, 511, 1023],
                    help="2D grid sides m (n = m^2); 2^k - 1 keeps the scene's hierarchy deep")
    ap.add_argument("--impulse", type=int, nargs="*", default=[101, 401, 1601, 6401], help="impulse-control sizes n")
    ap.add_argument("--sin", type=int, nargs="*", default=[127, 255, 511, 1023], help="2D grid sides m of zeta = psi + 0.2 sin z")
    ap.add_argument("--sin-form", default="operator", choices=["operator", "sparse"], help="the sin QVI's zeta'")
    ap.add_argument("--defaults", action="store_true", help="thermoforming_2d at the scene's kappa, delta")
    ap.add_argument("--tol", type=lambda t: None if t == "default" else float(t), default=1e-8,
                    help="the solves' tol, or 'default': nrmicp's default stop (relative to Res(0), units-free)")
    args = ap.parse_args(argv)
    print("| problem | n | ζ′: Newton steps | ζ′: linear solves | ζ′: status, Res | no ζ′: outer steps | "
          "no ζ′: linear solves | no ζ′: status, Res | numpy err | ζ′: CPU s | no ζ′: CPU s | obstacle CPU s | "
          "ζ′ / obstacle | no ζ′ / obstacle | ζ′: µs / unknown |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n in args.achp:
        compare("ACHP 1D", n, *achp_problem(n), "auto", args.tol)
    coupling = {} if args.defaults else {"kappa": 2.0, "delta": 1.0}
    for m in args.thermo2d:
        compare("thermoforming_2d" + ("" if args.defaults else " κ=2 δ=1"), m * m, *thermo2d_problem(m, **coupling),
                args.tol)
    for n in args.impulse:
        compare("impulse control", n, *impulse_problem(n), args.tol)
    for m in args.sin:
        compare("ψ + 0.2 sin z" + ("" if args.sin_form == "operator" else " (ζ′ sparse)"), m * m,
                *sin_problem(m, args.sin_form), args.tol)


if __name__ == "__main__":
    main()
