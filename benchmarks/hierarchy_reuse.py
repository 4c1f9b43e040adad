"""A Hierarchy built once against hierarchy='amg' built by each Solver: set-up and solve CPU seconds of
nrmicp.Solver(A, method='newton') on the 2D obstacle scene, the two alternating three times (min of each).

    OPENBLAS_NUM_THREADS=1 python benchmarks/hierarchy_reuse.py [--m 511 1023]
"""
import argparse
import time

import scipy.sparse as sp

import nrmicp
from nrmicp.scenes import obstacle


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, nargs="+", default=[511, 1023])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print("| n | Hierarchy.amg s | Solver set-up, 'amg' | Solver set-up, Hierarchy | ratio | solve, 'amg' | solve, Hierarchy | finest steps |")
    print("|---|---|---|---|---|---|---|---|")
    for m in args.m:
        pb = obstacle.obstacle_2d(m, exact=False)
        A = sp.csr_matrix(pb.A)
        t = time.process_time()
        h = nrmicp.Hierarchy.amg(A)
        built = time.process_time() - t
        rows = {"amg": [], "Hierarchy": []}
        for _ in range(args.repeat):
            for name, hierarchy in (("amg", "amg"), ("Hierarchy", h)):
                t = time.process_time()
                s = nrmicp.Solver(A, method="newton", hierarchy=hierarchy)
                setup = time.process_time() - t
                t = time.process_time()
                r = s.solve(pb.q, pb.zeta)
                rows[name].append((setup, time.process_time() - t, r.level_steps[0], r.status.name))
        a, b = (min(x[0] for x in rows[k]) for k in ("amg", "Hierarchy"))
        sa, sb = (min(x[1] for x in rows[k]) for k in ("amg", "Hierarchy"))
        steps = sorted({(x[2], x[3]) for k in rows for x in rows[k]})
        print(f"| {A.shape[0]:,} | {built:.3f} | {a:.3f} | {b:.3f} | {a / b:.1f}x | {sa:.3f} | {sb:.3f} | {steps} |")


if __name__ == "__main__":
    main()
