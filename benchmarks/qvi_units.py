"""A change of units on QVIs (issue 37): method 'newton' on a callable zeta without zeta_jacobian (the outer
fixed point z -> S(zeta(z))) under the default stopping rule, with tol = 1e-8 on A, and under the default
rule again with A and q multiplied together by s (z, hence the answer, unchanged). Prints status, outer
steps, linear solves, fallback sweeps, Anderson rejections, the error against an independent reference
(max|z - z_ref| / max|z_ref|, z_ref a plain fixed point of exact obstacle solves in numpy:
scenes/_exact.solve_exact_qvi), the paper's Res in A's units, and CPU s (docs/MEASUREMENTS.md, "The outer
fixed point in z's units").

    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_units.py
    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_units.py --thermo 511 --achp --scales 1e-4 1e4 --messages
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import nrmicp
from nrmicp import scenes
from nrmicp.scenes._exact import solve_exact_qvi

try:
    from qvi_outer import achp_problem
except ImportError:   # run from the repository root as a module path
    from benchmarks.qvi_outer import achp_problem


def problems(thermo, achp):
    for n in thermo:
        p = scenes.thermoforming_1d(n, exact=False)
        yield "thermoforming_1d", n, p.A, p.q, p.zeta
    for n in achp:
        A, q, zeta, _ = achp_problem(n)
        yield "ACHP-style 1D", n, A, q, zeta


def reference(A, q, zeta):
    """The plain outer fixed point with exact obstacle solves (policy iteration, spsolve), in numpy, started
    from a tol = 1e-8 solve (from zeros the policy iteration peels one node a step: > 500 steps at n = 4095)."""
    z0 = nrmicp.solve(A, q, zeta, method="newton", tol=1e-8).z
    return solve_exact_qvi(A, q, lambda z: np.array(zeta(z)), 0.5, z0=z0, tol=1e-14, maxiter=500)


def run(label, n, case, A, q, zeta, z_ref, messages, **kw):
    t0 = time.process_time()
    r = nrmicp.solve(A, q, zeta, method="newton", **kw)
    cpu = time.process_time() - t0
    err = float(np.max(np.abs(r.z - z_ref)) / np.max(np.abs(z_ref)))
    print(f"| {label} | {n:,} | {case} | {r.status.name} | {r.outer_iterations} | {r.linear_solves} | "
          f"{r.fallback_sweeps} | {r.counters.get('anderson_rejections', 0)} | {err:.1e} | {r.residual:.1e} | "
          f"{cpu:.2f} |", flush=True)
    if messages:
        print(f"|   |   |   | {r.message} |", flush=True)
    return r


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--thermo", type=int, nargs="*", default=[127, 255, 511, 1023, 4095], help="thermoforming_1d n")
    ap.add_argument("--achp", type=int, nargs="*", default=[1023, 4095], help="ACHP-style 1D N")
    ap.add_argument("--scales", type=float, nargs="*", default=[1e-4, 1e4], help="s multiplying A and q")
    ap.add_argument("--maxiter", type=int, default=10_000)
    ap.add_argument("--messages", action="store_true", help="print each solve's message under its row")
    args = ap.parse_args(argv)
    print("| problem | n | rule | status | outer steps | linear solves | fallback sweeps | Anderson rejected | "
          "rel. error | Res (paper, s A) | CPU s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for label, n, A, q, zeta in problems(args.thermo, args.achp):
        z_ref = reference(A, q, zeta)
        common = dict(maxiter=args.maxiter, messages=args.messages)
        run(label, n, "default", A, q, zeta, z_ref, **common)
        run(label, n, "tol 1e-8", A, q, zeta, z_ref, tol=1e-8, **common)
        for s in args.scales:
            run(label, n, f"default, s = {s:g}", s * A, s * q, zeta, z_ref, **common)


if __name__ == "__main__":
    main()
