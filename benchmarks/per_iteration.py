#!/usr/bin/env python
"""Per-iteration cost, nrmicp vs the plain scipy implementation, at a fixed iteration count
(no convergence test decides anything: both run exactly --iters iterations on obstacle0,
which converges slowly). Interleaves the two, --repeat times, and reports medians and
nrmicp's own timing split (spmv / inner_solve / rest).

    python benchmarks/per_iteration.py --sizes 1e5 1e6 --methods nrmgs nrm --iters 200
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import run_peers  # noqa: E402
import scipy_modulus  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", nargs="+", default=["1e5", "1e6"])
    ap.add_argument("--methods", nargs="+", default=["nrmgs", "nrm"])
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scene", default="obstacle0")
    args = ap.parse_args()
    import nrmicp

    print("| n | method | nrmicp µs/iter | scipy µs/iter | scipy / nrmicp | nrmicp spmv µs | "
          "nrmicp inner_solve µs | nrmicp other µs | scipy setup s | nrmicp setup s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n in (int(float(s)) for s in args.sizes):
        A, q, info = run_peers.build_scene(args.scene, n)
        for meth in args.methods:
            a, b, split, su = [], [], [], []
            for _ in range(args.repeat):
                r = nrmicp.solve(A, q, method=meth, tol=1e-300, maxiter=args.iters)
                t = r.timings
                a.append(t["iterations"] / r.nit)
                split.append((t["spmv"] / r.nit, t["inner_solve"] / r.nit))
                s = scipy_modulus.ScipyNRM(A, meth)
                o = s.solve(q, tol=1e-300, maxiter=args.iters)
                b.append(o["t_iter"] / o["nit"])
                su.append((o["t_setup"], t["setup"]))
            ma, mb = statistics.median(a), statistics.median(b)
            sp_, inn = (statistics.median(x) for x in zip(*split))
            print(f"| {info['n']} | {meth} | {ma * 1e6:.0f} | {mb * 1e6:.0f} | {mb / ma:.2f} | "
                  f"{sp_ * 1e6:.0f} | {inn * 1e6:.0f} | {(ma - sp_ - inn) * 1e6:.0f} | "
                  f"{statistics.median(x[0] for x in su):.2f} | "
                  f"{statistics.median(x[1] for x in su):.2f} |", flush=True)


if __name__ == "__main__":
    main()
