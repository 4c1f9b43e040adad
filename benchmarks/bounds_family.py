"""The stationary members with bounds (cpp detail/modulus.hpp) on Bai's matrices.

Part 1 (always): iterations to the paper's tol of every member on Bai's LCP and on box versions of
it: an upper bound at 0.75 max z* of the LCP's solution (two-sided rows), and the same with
every fifth row free below (lower = -inf). Newton's steps for scale.

Part 2 (--old SITE --new SITE): CPU seconds of the LCP path (no bounds) on two builds, alternating
in one invocation (SITE: a directory holding an nrmicp package): nrmgs on Bai's μ = 4 LCP to
tol = 1e-8 (n = 10^6), and fixed work (200 iterations, tol = 1e-300) on the unshifted 2D obstacle,
where Res never reaches 0: nrmgs (n = 10^6), two_sweep, nrmgs + Anderson, and nrm (n = 65,025:
its set-up factorizes Ω2 + A).

    OPENBLAS_NUM_THREADS=1 python benchmarks/bounds_family.py --m 32 64 128
    OPENBLAS_NUM_THREADS=1 python benchmarks/bounds_family.py --old OLD_SITE --new NEW_SITE
"""
import argparse
import json
import subprocess
import sys

import numpy as np

CHILD = r'''
import json, sys, time
sys.path.insert(0, sys.argv[1])
import nrmicp
from nrmicp import scenes
scene, method, m, iters = sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5])
p = scenes.bai(m, kind="lcp", symmetric=False) if scene == "bai" else scenes.obstacle_2d(m, exact=False)
kw = dict(method=method.split("+")[0], tol=1e-8 if iters == 0 else 1e-300, maxiter=iters or 10000,
          stall_iterations=10**9)
if method.endswith("+anderson"):
    kw["accelerate"] = "anderson"
t = time.process_time()
r = nrmicp.solve(p.A, p.q, p.zeta, **kw)
print(json.dumps({"cpu": time.process_time() - t, "nit": int(r.iterations), "residual": float(r.residual)}))
'''


def iteration_counts(ms, tol):
    import nrmicp
    from nrmicp import scenes
    rows = []
    for m in ms:
        p = scenes.bai(m, kind="lcp", symmetric=False)
        n = p.A.shape[0]
        z = nrmicp.solve(p.A, p.q, method="newton", tol=1e-12).z
        upper = np.full(n, 0.75 * z.max())
        lower = np.where(np.arange(n) % 5 == 0, -np.inf, 0.0)
        cases = {"lcp": (None, None), "box": (None, upper), "box+free": (lower, upper)}
        for method in nrmicp.METHODS:
            its = {}
            for name, (lo, up) in cases.items():
                r = nrmicp.solve(p.A, p.q, lo, upper=up, method=method, tol=tol, maxiter=20000)
                its[name] = f"{r.nit}" if r.success else f"{r.nit} ({r.status.name})"
                if name != "lcp":
                    at_up = int(np.sum(r.active_mask == 1))
            rows.append((n, method, its["lcp"], its["box"], its["box+free"], at_up))
    print("| n | method | LCP | box (upper = 0.75 max z*) | box + free rows | rows at upper |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(str(v) for v in r) + " |")


#: (scene, method, m, iterations; 0: to tol = 1e-8)
TIMED = (("bai", "nrmgs", 1000, 0), ("obstacle_2d", "nrmgs", 1000, 200), ("obstacle_2d", "two_sweep", 1000, 200),
         ("obstacle_2d", "nrmgs+anderson", 1000, 200), ("obstacle_2d", "nrm", 255, 200))


def timings(old, new, repeats, only):
    for scene, method, m, iters in TIMED:
        if only and f"{scene}/{method}" not in only:
            continue
        runs = {"old": [], "new": []}
        for _ in range(repeats):
            for name, site in (("old", old), ("new", new)):
                out = subprocess.run([sys.executable, "-c", CHILD, site, scene, method, str(m), str(iters)],
                                     capture_output=True, text=True, check=True).stdout
                runs[name].append(json.loads(out.strip().splitlines()[-1]))
        best = {k: min(r["cpu"] for r in v) for k, v in runs.items()}
        same = {(r["nit"], r["residual"]) for v in runs.values() for r in v}
        print(f"{scene} {method} m = {m} ({runs['new'][0]['nit']} iterations): old {best['old']:.3f} s, "
              f"new {best['new']:.3f} s CPU (min of {repeats}), new/old {best['new'] / best['old']:.3f}; "
              f"(nit, Res) identical: {len(same) == 1}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--m", type=int, nargs="+", default=[32, 64])
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--old")
    ap.add_argument("--new")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--only", nargs="*", help="timed cases to run, as scene/method (e.g. obstacle_2d/nrmgs)")
    a = ap.parse_args()
    if a.old and a.new:
        timings(a.old, a.new, a.repeats, a.only)
    else:
        iteration_counts(a.m, a.tol)


if __name__ == "__main__":
    main()
