"""CPU seconds of the same solves on two builds, alternating in one invocation (a developer's
check that a refactoring did not slow anything down; not a CI test):

    OPENBLAS_NUM_THREADS=1 python tests/golden/speed.py OLD_SITE NEW_SITE [--repeats 3]

OLD_SITE/NEW_SITE: directories holding an installed nrmicp package (e.g. pip install --target).
Cases: the 2D obstacle at n = 10^6 (nrmgs + Anderson, 300 iterations: fixed work), at
n = 261,121 (newton with the geometric hierarchy, to tol 1e-8), and newton with the default
amg hierarchy on the 2D (n = 1,046,529) and 3D (n = 1,092,727) obstacle (--cases picks some;
fe_obstacle_P2_4/newton-amg names the finite-element scene, element P2, refinement 4).
Prints each case's CPU seconds per build (the minimum over the repeats) and the ratio new/old.
"""
import json
import subprocess
import sys

CHILD = r'''
import json, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
import nrmicp
from nrmicp import scenes
case = sys.argv[2]
scene, m = case.split("/")[0].rsplit("_", 1)
if scene.startswith("fe_obstacle_"):   # fe_obstacle_P2_4: element P2, refinement 4
    p = scenes.fe_obstacle(scene.rsplit("_", 1)[1], int(m), exact=False)
else:
    p = getattr(scenes, scene)(int(m), exact=False)
if case.endswith("newton-amg"):
    kw = dict(method="newton", hierarchy="amg", tol=1e-8)
elif case.endswith("newton"):
    kw = dict(method="newton", hierarchy=p.prolongations(), tol=1e-8)
else:
    kw = dict(method="nrmgs", accelerate="anderson", maxiter=300, tol=1e-300)
t = time.process_time()
r = nrmicp.solve(p.A, p.q, p.zeta, **kw)
cpu = time.process_time() - t
print(json.dumps({"cpu": cpu, "nit": int(r.nit), "residual": float(r.residual), "file": nrmicp.__file__}))
'''

CASES = ("obstacle_2d_1000/nrmgs+anderson", "obstacle_2d_511/newton", "obstacle_2d_1023/newton-amg",
         "obstacle_3d_103/newton-amg")


def main():
    old, new = sys.argv[1], sys.argv[2]
    repeats = int(sys.argv[sys.argv.index("--repeats") + 1]) if "--repeats" in sys.argv else 3
    cases = sys.argv[sys.argv.index("--cases") + 1].split(",") if "--cases" in sys.argv else CASES
    for case in cases:
        runs = {"old": [], "new": []}
        for _ in range(repeats):
            for name, site in (("old", old), ("new", new)):
                out = subprocess.run([sys.executable, "-c", CHILD, site, case], capture_output=True, text=True,
                                     check=True).stdout
                runs[name].append(json.loads(out.strip().splitlines()[-1]))
        best = {k: min(r["cpu"] for r in v) for k, v in runs.items()}
        same = {(r["nit"], r["residual"]) for v in runs.values() for r in v}
        print(f"{case}: old {best['old']:.2f} s, new {best['new']:.2f} s CPU (min of {repeats}), "
              f"new/old {best['new'] / best['old']:.3f}; (nit, Res) identical: {len(same) == 1} {sorted(same)[:2]}")


if __name__ == "__main__":
    main()
