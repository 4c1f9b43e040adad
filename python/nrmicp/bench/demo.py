"""``nrmicp demo``: every method on Bai's problem (LCP and ICP, known solution), one table each."""
from __future__ import annotations

import argparse
import time
from typing import Optional

import numpy as np

from .argtypes import int_at_least, positive_float


def _table(rows, headers):
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(headers)]
    line = "  ".join(str(h).ljust(w) for h, w in zip(headers, widths))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(str(c).ljust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join(out)


#: The demo table's columns: nit, wall-clock seconds of the solve() call, Res(z), the error against the
#: known solution, Result.inner.
DEMO_COLUMNS = ("method", "status", "iterations (nit)", "wall s", "Res", "max|z-z*|", "inner solver")


def demo(argv: Optional[list[str]] = None, prog: str = "python -m nrmicp demo") -> int:
    """Every method on Bai's problem (LCP and ICP, known solution): iterations, seconds, Res."""
    import nrmicp
    from nrmicp import scenes

    p = argparse.ArgumentParser(prog=prog, description=demo.__doc__)
    p.add_argument("--m", type=int_at_least(1), default=256, help="grid side: n = m*m (default 256, n = 65,536)")
    p.add_argument("--tol", type=positive_float, default=1e-8)
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
        print(_table(rows, DEMO_COLUMNS))
    print("\ninner solver (Result.inner): the linear solver of each iteration, for the left matrix of "
          "the stationary\nmembers and for newton's step; wall s: the solve() call's wall-clock seconds.")
    print("\nDefaults: Omega1 = I; Omega2 = diag(A) for the AOR types, I for nrm (the paper's), "
          "alpha*I for nrmm; phi = 0.\nz-update 'explicit' (no solve with A), except 'solve' (the paper's) on the "
          "ICP for nrm and the baseline mms.\nnrm with the paper's Omega2 = I is slow when diag(A) is far from 1 "
          "(here 8).")
    return 0
