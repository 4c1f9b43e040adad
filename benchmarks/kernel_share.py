"""Share of wall time spent outside the sparse kernels, per method, at n = 250,000.

    python benchmarks/kernel_share.py [--m 500] [--repeat 3]

Kernels = factorization + inner (triangular/forward) solves + products with A (for the AOR
types on CSR input: the one-pass sweep) + ζ evaluations, from result.timings; "outside" is
the rest of the wall time of nrmicp.solve, Python validation included. Best of --repeat.
"""
import argparse
import time
import warnings

import nrmicp
from nrmicp import scenes


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, default=500, help="grid side, n = m*m (default 500: n = 250,000)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--tol", type=float, default=1e-8)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    print(f"n = {args.m ** 2:,} (Bai, mu = 4), tol {args.tol:g}; best of {args.repeat} wall times\n")
    print("| problem | method | nit | wall s | kernels s | outside s | outside share | status |")
    print("|---|---|---|---|---|---|---|---|")
    for kind in ("lcp", "affine", "icp"):
        P = scenes.bai(args.m, kind=kind)
        for method in ("nrmgs", "nrmj", "nrmm", "nrm", "two_sweep"):
            best = None
            for _ in range(args.repeat):
                t = time.perf_counter()
                r = nrmicp.solve(P.A, P.q, P.zeta, method=method, tol=args.tol)
                wall = time.perf_counter() - t
                tm = r.timings
                kernels = tm["factorization"] + tm["inner_solve"] + tm["spmv"] + tm["zeta"]
                if best is None or wall < best[0]:
                    best = (wall, kernels, r)
            wall, kernels, r = best
            print(f"| {kind} | {method} | {r.nit} | {wall:.3f} | {kernels:.3f} | {wall - kernels:.3f} | "
                  f"{100 * (wall - kernels) / wall:.1f}% | {r.status.name} |")


if __name__ == "__main__":
    main()
