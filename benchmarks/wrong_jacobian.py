"""method 'newton' on a callable ζ with a Jacobian that does not deliver: the 2D obstacle with a
nonlocal obstacle ζ(z) = ψ + c·S^k z (S the row-normalized 5-point averaging matrix, so c·S^k
contracts with factor c and its exact Jacobian c·S^k is sparse), given the exact Jacobian, its
local (diagonal) part, zero, the negated Jacobian, ten times the Jacobian, or none (the outer
fixed point); and scenes.thermoforming_2d with a strong heat coupling and the local part of its
dense Jacobian (the issue's 'thermoforming-like ζ with an approximate Jacobian'). Newton steps,
outer steps, linear solves, fallback sweeps, CPU s, status, path, and the complementarity of the answer measured here in numpy (min(Az+q, z−ζ(z)), independent of nrmicp).

    OPENBLAS_NUM_THREADS=1 python benchmarks/wrong_jacobian.py --m 63 127 255   # --problem averaging thermoforming
"""
from __future__ import annotations

import argparse
import time

import numpy as np

JACOBIANS = ("exact", "local", "zero", "negated", "10x", "none")


def problems():
    """{name: builder(m) -> (A, q, ζ, {jacobian: zeta_jacobian or None})}: tests/test_wrong_jacobian.py's."""
    from tests_modules import load
    t = load("test_wrong_jacobian")
    return {"averaging": t.averaging_problem, "thermoforming": t.thermoforming_problem}


def complementarity(A, q, zeta, z) -> float:
    """‖min(Az + q, z − ζ(z))‖₂, in numpy."""
    return float(np.linalg.norm(np.minimum(A @ z + q, z - zeta(z))))


def run(problem: str, m: int, which: str, maxiter: int = 20000) -> dict:
    import nrmicp
    A, q, zeta, jacs = problems()[problem](m)
    if which not in jacs:
        return {}
    jac = {} if jacs[which] is None else {"zeta_jacobian": jacs[which]}
    t = time.process_time()
    r = nrmicp.solve(A, q, zeta, method="newton", maxiter=maxiter, **jac)  # the default rule, hierarchy "auto"
    cpu = time.process_time() - t
    return dict(n=m * m, jacobian=which, status=str(r.status), nit=r.nit, outer=r.outer_iterations,
                solves=r.linear_solves, sweeps=r.fallback_sweeps, path=r.path, cpu=cpu,
                res=r.residual, comp=complementarity(A, q, zeta, r.z), message=r.message)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problem", nargs="+", default=["averaging", "thermoforming"],
                    choices=["averaging", "thermoforming"])
    ap.add_argument("--m", type=int, nargs="+", default=[63, 127])
    ap.add_argument("--jacobian", nargs="+", default=list(JACOBIANS), choices=JACOBIANS)
    ap.add_argument("--messages", action="store_true", help="print each result's message")
    args = ap.parse_args(argv)
    print(f"{'problem':>13} {'n':>7} {'jacobian':>8} {'status':>15} {'nit':>5} {'outer':>5} {'solves':>6} {'sweeps':>6} "
          f"{'path':>16} {'cpu s':>7} {'Res':>8} {'numpy':>8}")
    for problem, m, which in ((p, m, j) for p in args.problem for m in args.m for j in args.jacobian):
        d = run(problem, m, which)
        if not d:
            continue
        print(f"{problem:>13} {d['n']:7d} {which:>8} {d['status']:>15} {d['nit']:5d} {d['outer']:5d} {d['solves']:6d} "
              f"{d['sweeps']:6d} {d['path']:>16} {d['cpu']:7.2f} {d['res']:8.1e} {d['comp']:8.1e}", flush=True)
        if args.messages:
            print("        ", d["message"])


if __name__ == "__main__":
    main()
