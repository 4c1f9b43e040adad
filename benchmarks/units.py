"""A change of units under the defaults (README "What you get back"): each problem solved with
nrmicp's defaults by every member, with A and q scaled together by 1e-6, 1 and 1e6. Prints, per
problem and member, the verdicts, the largest relative error of a reported success against an
exact solution (policy iteration with direct solves), whether every success found the exact
contact set, and CPU seconds; then the default (method="auto") against the member it should match.

    OPENBLAS_NUM_THREADS=1 python benchmarks/units.py [--quick] [--large]
"""
import argparse
import time

import numpy as np
import scipy.sparse as sp

import nrmicp
from nrmicp.scenes._exact import solve_exact_obstacle
from nrmicp.scenes.bai import bai_matrix

SCALES = (1e-6, 1.0, 1e6)


def readme_membrane(m):
    h = 1 / (m + 1)
    T = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m))
    A = ((sp.kron(sp.identity(m), T) + sp.kron(T, sp.identity(m))) / h**2).tocsr()
    x = np.linspace(h, 1 - h, m)
    X, Y = np.meshgrid(x, x)
    return A, np.full(m * m, 8.0), (0.3 - 2 * ((X - .5)**2 + (Y - .5)**2)).ravel()


def bai(m):
    A = bai_matrix(m)
    rng = np.random.default_rng(0)
    return A, rng.uniform(-2, 1, A.shape[0]), rng.uniform(-0.5, 0.5, A.shape[0])


def fe(element, r):
    from nrmicp.scenes.finite_elements import fe_obstacle
    p = fe_obstacle(element, refinements=r, exact=False)
    return p.A, p.q, p.zeta


def timed(*args, **kw):
    t = time.process_time()
    r = nrmicp.solve(*args, **kw)
    return r, time.process_time() - t


def units_table(problems, methods):
    print("| problem | n | member | verdicts at 1e-6 / 1 / 1e6 | max rel. error of a success | contact set | CPU s (at 1) |")
    print("|---|---|---|---|---|---|---|")
    for name, (A, q, psi) in problems.items():
        exact = solve_exact_obstacle(A, q, psi)
        scale = np.abs(exact).max()
        contact = exact - psi <= 1e-7 * scale   # the same threshold for both sides
        for method in methods:
            verdicts, errs, same, secs, ran = [], [], True, 0.0, method
            for s in SCALES:
                r, t = timed(s * A, s * q, zeta=psi, method=method)
                ran = r.method
                verdicts.append("ok" if r.success else str(r.status).lower())
                if s == 1.0:
                    secs = t
                if r.success:
                    errs.append(np.abs(r.z - exact).max() / scale)
                    same &= bool(np.array_equal(r.z - psi <= 1e-7 * scale, contact))
            label = f"auto ({ran})" if method == "auto" else method
            print(f"| {name} | {A.shape[0]:,} | {label} | {' / '.join(verdicts)} | "
                  f"{max(errs):.1e} | {'same' if errs and same else ('differs' if errs else '–')} | {secs:.2f} |"
                  if errs else f"| {name} | {A.shape[0]:,} | {label} | {' / '.join(verdicts)} | – | – | {secs:.2f} |",
                  flush=True)


def default_speed(problems, repeats=3):
    """The default call against the member it picks given explicitly, and against that member
    under the paper's absolute tol = 1e-8 (the default before the units-free rule); min of
    `repeats` CPU times each."""
    print("\n| problem | n | default (auto): member, steps | CPU s | that member, explicit | ratio "
          "| that member, tol=1e-8 (paper's Res) | CPU s |")
    print("|---|---|---|---|---|---|---|---|")
    for name, (A, q, psi) in problems.items():
        best = {}
        for key, kw in (("auto", {}), ("member", None), ("paper", None)):
            for _ in range(repeats):
                if kw is None:
                    kw = dict(method=best["auto"][0].method, **({"tol": 1e-8} if key == "paper" else {}))
                r, t = timed(A, q, zeta=psi, **kw)
                if key not in best or t < best[key][1]:
                    best[key] = (r, t)
        (ra, ta), (rm, tm), (rp, tp) = best["auto"], best["member"], best["paper"]
        print(f"| {name} | {A.shape[0]:,} | {ra.method}: {ra.status}, {ra.nit} | {ta:.2f} | {rm.status}, "
              f"{tm:.2f} s | {ta / tm:.2f} | {rp.status}, {rp.nit} | {tp:.2f} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (seconds)")
    ap.add_argument("--large", action="store_true", help="the default-speed table at n = 10^6 too")
    a = ap.parse_args()
    m, mb, r1, r2 = (31, 32, 1, 1) if a.quick else (255, 256, 3, 2)
    problems = {"README membrane": readme_membrane(m), "Bai (mu = 4)": bai(mb)}
    try:
        problems["scikit-fem P1"] = fe("P1", r1)
        problems["scikit-fem P2"] = fe("P2", r2)
    except ImportError:
        print("(scikit-fem not installed: the finite-element rows are skipped)")
    units_table(problems, ("auto",) + nrmicp.METHODS)
    speed = {"README membrane": problems["README membrane"], "Bai (mu = 4)": problems["Bai (mu = 4)"]}
    if a.large:
        speed["README membrane, n = 10^6"] = readme_membrane(1023)
        speed["Bai, n = 10^6"] = bai(1000)
    default_speed(speed)


if __name__ == "__main__":
    main()
