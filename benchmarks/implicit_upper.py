"""Outer steps, finest steps, linear solves and CPU seconds of the implicit upper bound (scene
two_sided_heated_2d) against the constant ceiling (two_sided_2d), method newton, both hierarchies:

    OPENBLAS_NUM_THREADS=1 python benchmarks/implicit_upper.py 31 127 255     # grid parameters m (n = m^2)
"""
import sys, time
import nrmicp
from nrmicp import scenes
for m in (int(a) for a in sys.argv[1:]):
    p = scenes.two_sided_membrane_heated_2d(m, exact=False)
    box = scenes.two_sided_membrane_2d(m, exact=False)
    for hname in ("geometric", "amg"):
        h = p.prolongations() if hname == "geometric" else "amg"
        for label, prob, up in (("heated (implicit u)", p, p.upper), ("constant ceiling", box, box.upper)):
            t = time.process_time()
            r = nrmicp.solve(prob.A, prob.q, prob.zeta, upper=up, method="newton", hierarchy=h, tol=1e-8)
            cpu = time.process_time() - t
            print(f"m={m} n={p.n} {hname:9s} {label:20s} success={r.success} Res={r.residual:.2e} "
                  f"outer={r.outer_iterations} nit={r.nit} linear_solves={r.linear_solves} "
                  f"level_steps={list(r.level_steps)} cpu={cpu:.2f}s", flush=True)
