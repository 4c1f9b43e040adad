"""hierarchy='auto''s threshold (python/nrmicp/_newton.py AUTO_AMG_MIN_N): method 'newton' started cold
(hierarchy=None) against hierarchy='amg', per solve, on 1D, 2D, 3D and finite-element scenes around it.
CPU ms of one solve, the amg set-up included, min of 3, pyamg imported first; tol 1e-8
(docs/MEASUREMENTS.md, "`AUTO_AMG_MIN_N` = 1000").

    OPENBLAS_NUM_THREADS=1 python benchmarks/auto_hierarchy.py     # about a minute
"""
import gc
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import pyamg  # noqa: F401  (imported before timing: a process pays it once)

import nrmicp
from nrmicp import scenes
from qvi_outer import achp_problem


def timed(A, q, zeta, hierarchy, **kw):
    """(result, min CPU s of 3 solves)."""
    best = float("inf")
    for _ in range(3):
        gc.collect()
        t0 = time.process_time()
        r = nrmicp.solve(A, q, zeta, method="newton", hierarchy=hierarchy, tol=1e-8, **kw)
        best = min(best, time.process_time() - t0)
    return r, best


def cases():
    for n in [255, 511, 1023, 2047, 4095]:
        yield "obstacle_1d", lambda n=n: scenes.obstacle_1d(n, exact=False)
    for ns in [512, 1024, 2048, 4096]:
        yield "american_put (first LCP)", lambda ns=ns: scenes.american_put(n_space=ns, exact=False)
    for n in [255, 1023, 4095]:
        yield "ACHP 1D QVI (ζ′)", lambda n=n: achp_problem(n)
    for m in [23, 31, 45, 63]:
        yield "obstacle_2d", lambda m=m: scenes.obstacle_2d(m, exact=False)
    for m in [8, 10, 13, 16]:
        yield "obstacle_3d", lambda m=m: scenes.obstacle_3d(m, exact=False)
    for el in ["P1", "P2"]:
        for k in [1, 2]:
            yield f"fe_obstacle {el} r={k}", lambda el=el, k=k: scenes.fe_obstacle(el, k, exact=False)


def main():
    print("| problem | n | cold ms | amg ms | cold / amg | cold steps | amg finest steps |")
    print("|---|---|---|---|---|---|---|")
    for name, make in cases():
        pb = make()
        if isinstance(pb, tuple):   # (A, q, zeta, zeta_jacobian)
            A, q, zeta, jac = pb
            kw = {"zeta_jacobian": jac}
        else:
            A, q, zeta, kw = pb.A, pb.q, pb.zeta, {}
        cold, t_cold = timed(A, q, zeta, None, **kw)
        amg, t_amg = timed(A, q, zeta, "amg", **kw)
        print(f"| {name} | {A.shape[0]:,} | {1e3 * t_cold:.1f} | {1e3 * t_amg:.1f} | {t_cold / t_amg:.2f} | "
              f"{cold.level_steps[0]} ({cold.status.name}) | {amg.level_steps[0]} ({amg.status.name}) |", flush=True)


if __name__ == "__main__":
    main()
