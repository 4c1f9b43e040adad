"""Command line: ``python -m nrmicp demo`` and ``python -m nrmicp bench``."""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def _table(rows, headers):
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(headers)]
    line = "  ".join(str(h).ljust(w) for h, w in zip(headers, widths))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(str(c).ljust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join(out)


def demo(argv=None) -> int:
    """Every method on Bai's problem (LCP and ICP, known solution): iterations, seconds, Res."""
    import nrmicp
    from nrmicp import scenes

    p = argparse.ArgumentParser(prog="python -m nrmicp demo", description=demo.__doc__)
    p.add_argument("--m", type=int, default=256, help="grid side: n = m*m (default 256, n = 65,536)")
    p.add_argument("--tol", type=float, default=1e-8)
    p.add_argument("--nonsymmetric", action="store_true", help="Bai's nonsymmetric matrix")
    args = p.parse_args(argv)

    print(f"nrmicp {nrmicp.__version__}; inner solvers compiled in: "
          + ", ".join(k for k, v in nrmicp.backends().items() if v))
    for kind in ("lcp", "icp"):
        P = scenes.bai(args.m, symmetric=not args.nonsymmetric, kind=kind)
        print(f"\n{P.description}" + ("" if kind == "lcp" else " (zeta is a Python callable)"))
        rows = []
        for method in nrmicp.METHODS:
            t0 = time.perf_counter()
            r = nrmicp.solve(P.A, P.q, P.zeta, method=method, tol=args.tol)
            dt = time.perf_counter() - t0
            err = np.max(np.abs(r.z - P.z_exact))
            rows.append((method, r.status.name.lower(), r.nit, f"{dt:.4f}", f"{r.residual:.2e}", f"{err:.1e}",
                         r.inner))
        print(_table(rows, ("method", "status", "iterations", "seconds", "Res", "max|z-z*|", "left solve")))
    print("\nDefaults: Omega1 = I; Omega2 = diag(A) for the AOR types, I for nrm (the paper's), "
          "alpha*I for nrmm; phi = 0.\nz-update 'explicit' (no solve with A), except 'solve' (the paper's) on the "
          "ICP for nrm and the baseline mms.\nnrm with the paper's Omega2 = I is slow when diag(A) is far from 1 "
          "(here 8).")
    return 0


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: python -m nrmicp {demo,bench} [options]\n\n"
              "  demo   every method on a built-in problem (Bai's test matrices)\n"
              "  bench  work-precision sweep: time and iterations against tol, CSV and PNG")
        return 0
    cmd, rest = argv[0], argv[1:]
    if cmd == "demo":
        return demo(rest)
    if cmd == "bench":
        from . import bench
        return bench.main(rest)
    print(f"unknown command {cmd!r}; use demo or bench", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
