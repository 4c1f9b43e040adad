"""Which stabilizer turns which hard case from failure into convergence, and what it costs on easy ones.

    python benchmarks/stabilizers.py [--method nrmgs] [--size moderate] [--easy-m 32] [--evidence 64 128]

Stabilizers (combined with the plain method):
  plain      the paper's z-update: 'solve' for an ICP, explicit for an LCP (set explicitly:
             nrmicp's default 'auto' is now 'explicit', chosen from this table)
  explicit   z_update='explicit'
  anderson   accelerate='anderson', anderson_m=5
  scale      scale='both' (power-of-two Ruiz equilibration; success judged on the original Res)
  and combinations.

Prints markdown tables: (1) status/iterations on the hard-case suite of tests/test_hard_cases.py at
moderate size, with the cases each stabilizer turns from failure into convergence; (2) iterations
and time ratio vs plain on Bai μ = 4 problems (tests/problems.py); (3) the documented trouble case,
2D Laplacian μ = 0 with ζ = 0.05 sin z + s, for NRM and NRMGS.
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

import nrmicp  # noqa: E402
from tests_modules import load  # noqa: E402

problems = load("problems")
hc = load("test_hard_cases")

STABILIZERS = {
    "plain": dict(),
    "explicit": dict(z_update="explicit"),
    "anderson": dict(accelerate="anderson", anderson_m=5),
    "scale": dict(scale="both"),
    "anderson+explicit": dict(accelerate="anderson", anderson_m=5, z_update="explicit"),
    "anderson+scale": dict(accelerate="anderson", anderson_m=5, scale="both"),
    "explicit+scale": dict(z_update="explicit", scale="both"),
    "all three": dict(accelerate="anderson", anderson_m=5, z_update="explicit", scale="both"),
}


def paper(opts, zeta):
    """Stabilizers that do not choose a z-update get the paper's: 'solve' for an ICP."""
    if "z_update" in opts:
        return opts
    return dict(opts, z_update="explicit" if zeta is None else "solve")


def run(case, method, opts, maxiter):
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = nrmicp.solve(case.A, case.q, case.zeta, method=method, tol=1e-8, maxiter=maxiter,
                             **dict(paper(opts, case.zeta), **case.setup))
    except Exception as exc:  # documented refusals (non-positive diagonal, singular factorization)
        return None, type(exc).__name__, time.perf_counter() - t0
    ok = r.success and hc.numpy_residual(case, r.z)[0] < 1e-8
    return ok, f"{r.status.name}({r.iterations})", time.perf_counter() - t0


def hard_table(method, size, maxiter):
    cases = hc.build_cases(size)
    names = list(STABILIZERS)
    print(f"\n### Hard cases ({size}, method={method}, tol=1e-8, maxiter={maxiter})\n")
    print("| case | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    fixed = {s: [] for s in names}
    broke = {s: [] for s in names}
    for case in cases:
        cells, oks = [], {}
        for s in names:
            ok, txt, _ = run(case, method, STABILIZERS[s], maxiter)
            oks[s] = ok
            cells.append(("**" + txt + "**") if ok else txt)
        for s in names[1:]:
            if oks[s] and not oks["plain"]:
                fixed[s].append(case.name)
            if oks["plain"] and not oks[s]:
                broke[s].append(case.name)
        print(f"| {case.name} | " + " | ".join(cells) + " |")
    print("\n(bold: converged with Res < tol recomputed in numpy)\n")
    print("| stabilizer | turns failure into convergence | turns convergence into failure |")
    print("|---|---|---|")
    for s in names[1:]:
        print(f"| {s} | {', '.join(fixed[s]) or '-'} | {', '.join(broke[s]) or '-'} |")


def easy_table(method, m, repeats=3):
    print(f"\n### Cost on easy problems (Bai μ = 4, m = {m}, n = {m * m}, method={method})\n")
    names = list(STABILIZERS)
    print("| problem | " + " | ".join(f"{s} it (t/plain)" for s in names) + " |")
    print("|---|" + "---|" * len(names))
    for kind in ("lcp", "icp", "affine", "obstacle"):
        for sym in (True, False):
            p = problems.make_problem(kind, m, sym)
            zeta = p.zeta
            if kind == "affine":
                zeta = nrmicp.Affine(p.zeta.B, p.zeta.c)
            elif kind == "obstacle":
                zeta = p.zeta.c
            cells, t_plain = [], None
            for s in names:
                best = np.inf
                for _ in range(repeats):
                    t0 = time.perf_counter()
                    r = nrmicp.solve(p.A, p.q, zeta, method=method, tol=1e-8, **paper(STABILIZERS[s], zeta))
                    best = min(best, time.perf_counter() - t0)
                if t_plain is None:
                    t_plain = best
                flag = "" if r.success else " FAIL"
                cells.append(f"{r.iterations} ({best / t_plain:.2f}){flag}")
            print(f"| {p.name} | " + " | ".join(cells) + " |")


def evidence(ms, maxiter):
    print("\n### Laplacian μ = 0, ζ = 0.05 sin z + s (known solution)\n")
    print("| m | method | plain | explicit | anderson | anderson+explicit |")
    print("|---|---|---|---|---|---|")
    for m in ms:
        case = hc._known_sin_icp(f"lap-mu0-m{m}", hc.lap2d(m), 0.05)
        for method in ("nrm", "nrmgs"):
            cells = []
            for s in ("plain", "explicit", "anderson", "anderson+explicit"):
                ok, txt, t = run(case, method, STABILIZERS[s], maxiter)
                cells.append(f"{txt} {t:.2f}s" + ("" if ok else " ✗"))
            print(f"| {m} | {method} | " + " | ".join(cells) + " |")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--method", default="nrmgs")
    ap.add_argument("--size", default="moderate", choices=["small", "moderate"])
    ap.add_argument("--maxiter", type=int, default=5000)
    ap.add_argument("--easy-m", type=int, default=32)
    ap.add_argument("--evidence", type=int, nargs="*", default=[64])
    args = ap.parse_args()
    hard_table(args.method, args.size, args.maxiter)
    easy_table(args.method, args.easy_m)
    if args.evidence:
        evidence(args.evidence, args.maxiter)


if __name__ == "__main__":
    main()
