"""Time the Bai n = 10^6 solves of one build: one JSON line per solve (loop seconds from timings).

    PYTHONPATH=<copy of an installed nrmicp package> python benchmarks/bai_1e6.py LABEL REPS lcp:nrmgs,icp:nrmgs

To compare two builds, copy each installed package aside and alternate processes (the machine
is shared and noisy: compare medians of alternating runs, never two runs taken apart).
"""
import json
import sys
import time
import warnings

import nrmicp
from nrmicp import scenes


def main():
    label, reps, which = sys.argv[1], int(sys.argv[2]), sys.argv[3].split(",")
    warnings.simplefilter("ignore")
    cases = [c.split(":") for c in which]
    problems = {kind: scenes.bai(1000, kind=kind) for kind in {c[0] for c in cases}}
    for _ in range(reps):
        for kind, method in cases:
            p = problems[kind]
            t = time.perf_counter()
            r = nrmicp.solve(p.A, p.q, p.zeta, method=method)
            wall = time.perf_counter() - t
            print(json.dumps(dict(label=label, kind=kind, method=method, nit=r.nit, status=r.status.name,
                                  wall=wall, loop=r.timings["iterations"], inner=r.timings["inner_solve"])),
                  flush=True)


if __name__ == "__main__":
    main()
