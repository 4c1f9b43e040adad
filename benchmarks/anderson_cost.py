#!/usr/bin/env python
"""Anderson's cost per iteration relative to a plain nrmgs iteration (obstacle_2d, n = 16,384
and 65,536; interleaved runs, best of 5, on the core's iteration clock), and how nrmgs +
Anderson's iteration count grows with n on the unshifted scenes (obstacle_2d, thermoforming_2d,
one American-put step; tol 1e-8). The README's "Which method for which problem" quotes its output.

    python benchmarks/anderson_cost.py
"""
import math, nrmicp
from nrmicp import scenes

def per_iter(P, acc, iters=1500):
    r = nrmicp.solve(P.A, P.q, P.zeta, method="nrmgs", accelerate=acc, tol=1e-300, maxiter=iters,
                     stall_iterations=10**6)
    return r.timings["iterations"] / r.iterations, r.iterations, r.status

for m in (128, 256):
    P = scenes.obstacle_2d(m, exact=False)
    best = {"none": math.inf, "anderson": math.inf}
    for rep in range(5):                     # interleaved, best of 5
        for acc in best:
            t, k, st = per_iter(P, acc)
            best[acc] = min(best[acc], t)
    print(f"obstacle_2d({m}) n={P.n}: plain {best['none']*1e3:.3f} ms/it, anderson {best['anderson']*1e3:.3f} ms/it,"
          f" ratio {best['anderson']/best['none']:.2f}", flush=True)

def growth(label, make, sizes, **kw):
    rows = []
    for s in sizes:
        P = make(s)
        r = nrmicp.solve(P.A, P.q, P.zeta, method="nrmgs", accelerate="anderson", maxiter=100000, **kw)
        rows.append((P.n, r.nit, str(r.status)))
    (n0, k0, _), (n1, k1, _) = rows[0], rows[-1]
    print(f"{label}: " + ", ".join(f"n={n} {k} it {st}" for n, k, st in rows)
          + f"; exponent of n {math.log(k1 / k0) / math.log(n1 / n0):.2f}", flush=True)

growth("obstacle_2d + anderson, tol 1e-8", lambda m: scenes.obstacle_2d(m, exact=False), (64, 128, 256))
growth("thermoforming_2d + anderson, tol 1e-8", lambda m: scenes.thermoforming_2d(m), (24, 48, 96))
growth("american_put (one step) + anderson, tol 1e-8", lambda ns: scenes.american_put(n_space=ns), (1600, 3200, 6400))
