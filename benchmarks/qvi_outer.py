"""The Newton member's outer fixed point z -> S(zeta(z)) (a callable zeta, no zeta_jacobian) on QVIs:
outer steps, linear solves, fallback sweeps, status, Res, CPU s (docs/MEASUREMENTS.md, "The outer
fixed point, accelerated").

Problems:
- ``achp``: a 1D thermoforming QVI in the style of Alphonse, Christof, Hintermüller & Papadopoulos
  (2024, Test 1). Membrane u on (0, 1), -u'' = f, u <= Phi0 + phi T, u = 0 at both ends; the mould's
  temperature T solves the nonlinear Neumann problem k T - T'' = g(Psi0 + psi T - u), g a clipped
  (nondifferentiable) heat-transfer law, by a few Newton iterations (scipy's banded solve) at every
  evaluation of zeta. In z = -u the ICP is A z + q >= 0, z >= zeta(z) = -(Phi0 + phi T(-z)).
- ``thermo2d``: the product's scene nrmicp.scenes.thermoforming_2d with its geometric hierarchy,
  at its defaults and at kappa = 2, delta = 1 (a stronger, longer-range coupling), the latter also
  with hierarchy 'auto' (the algebraic one from n = 1000).

    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_outer.py
    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_outer.py --achp 63 255 --thermo2d 31 63
    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_outer.py --achp 1023 4095 --thermo2d --tol default --messages
    OPENBLAS_NUM_THREADS=1 python benchmarks/qvi_outer.py --obstacle

--obstacle adds the CPU s of one obstacle solve of the same size (the same A, q, method and tol, zeta frozen
at the answer's zeta(z) as a constant obstacle) and the QVI's CPU over it.

Run it against two builds with PYTHONPATH to compare them. Every answer is checked in numpy:
err = ||min(A z + q, z - zeta(z))||_inf, measured independently of the solver's Res.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.linalg as sla
from scipy.sparse.linalg import LinearOperator

import nrmicp
from nrmicp import scenes
from nrmicp.scenes._operators import grid_1d, neg_laplacian_1d


def achp_problem(n: int, f: float = 25.0, k: float = 1.0, a: float = 0.6):
    """(A, q, zeta, zeta_jacobian) of the 1D thermoforming QVI on n interior nodes (z = -u).
    zeta_jacobian(z) is the exact derivative -phi (k I - T'' - diag(g'(s) psi))^{-1} diag(g'(s)) at
    T = T(-z), s = Psi0 + psi T + z, as a LinearOperator (dense: only its products exist)."""
    h = 1.0 / (n + 1)
    x = grid_1d(n)
    A = neg_laplacian_1d(n)
    q = np.full(n, f)
    phi0 = 1.0 - 2.0 * np.maximum(np.abs(x - 0.5) - 0.25, 0.0)   # a plateau mould
    phi = np.sin(np.pi * x)                                       # where the mould expands
    psi0, psi = phi0, phi                                         # g's argument: the gap Phi(T) - u
    # k T - T'' with Neumann ends, as a banded matrix (upper, diagonal, lower)
    band = np.zeros((3, n))
    band[0, 1:] = -1.0 / h**2
    band[2, :-1] = -1.0 / h**2
    band[1, :] = k + 2.0 / h**2
    band[1, 0] = band[1, -1] = k + 1.0 / h**2

    def g(s):
        return a * np.clip(1.0 - s, 0.0, 1.0)

    def dg(s):
        return np.where((s > 0.0) & (s < 1.0), -a, 0.0)

    state = {"T": np.zeros(n)}

    def temperature(u):
        """T solving k T - T'' = g(Psi0 + psi T - u) by semismooth Newton from the last T: g is
        piecewise linear, so a step whose pieces repeat those it was taken on is exact."""
        T = state["T"].copy()
        pieces = None
        for _ in range(30):
            s = psi0 + psi * T - u
            now = (s > 0.0).astype(np.int8) + (s >= 1.0)
            if pieces is not None and np.array_equal(now, pieces):
                break
            pieces = now
            J = band.copy()
            J[1] -= dg(s) * psi
            T = sla.solve_banded((1, 1), J, g(s) - dg(s) * psi * T)
        state["T"] = T
        return T

    def zeta(z):
        return -(phi0 + phi * temperature(-z))

    def zeta_jacobian(z):
        T = temperature(-z)
        dgs = dg(psi0 + psi * T + z)
        M = band.copy()
        M[1] -= dgs * psi

        def matvec(v):
            return -phi * sla.solve_banded((1, 1), M, dgs * v.ravel())
        return LinearOperator((n, n), matvec=matvec, dtype=float)

    return A, q, zeta, zeta_jacobian


def check(A, q, zeta, z):
    """||min(A z + q, z - zeta(z))||_inf in numpy."""
    return float(np.max(np.abs(np.minimum(A @ z + q, z - zeta(z)))))


def run(label, n, A, q, zeta, tol=1e-8, messages=False, obstacle=False, **kw):
    tols = {} if tol is None else {"tol": tol}
    t0 = time.process_time()
    r = nrmicp.solve(A, q, zeta, method="newton", **tols, **kw)
    cpu = time.process_time() - t0
    err = check(A, q, zeta, r.z)
    extra = ""
    if obstacle:   # one obstacle solve of the same size: zeta frozen at zeta(z*)
        psi = np.array(zeta(r.z))
        t0 = time.process_time()
        nrmicp.solve(A, q, psi, method="newton", **tols, **kw)
        cpu_obstacle = time.process_time() - t0
        extra = f" {cpu_obstacle:.3f} | {cpu / cpu_obstacle:.1f} |"
    print(f"| {label} | {n:,} | {r.outer_iterations} | {r.linear_solves} | {r.fallback_sweeps} | {r.status.name} | "
          f"{r.residual:.1e} | {err:.1e} | {cpu:.3f} |{extra}", flush=True)
    if messages:
        print(f"|   | {r.message} |", flush=True)
    return r


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--achp", type=int, nargs="*", default=[63, 255, 1023, 4095], help="1D sizes N")
    ap.add_argument("--thermo2d", type=int, nargs="*", default=[31, 63, 127], help="2D grid sides m (n = m^2)")
    ap.add_argument("--tol", default="1e-8", help="tol of every solve ('default': the default stopping rule)")
    ap.add_argument("--messages", action="store_true", help="print each solve's message under its row")
    ap.add_argument("--obstacle", action="store_true", help="also one obstacle solve of the same size (zeta frozen)")
    args = ap.parse_args(argv)
    kw = {"tol": None if args.tol == "default" else float(args.tol), "messages": args.messages,
          "obstacle": args.obstacle}
    extra = (" obstacle CPU s | QVI / obstacle |", "---|---|") if args.obstacle else ("", "")
    print("| problem | n | outer steps | linear solves | fallback sweeps | status | Res | numpy err | CPU s |" + extra[0])
    print("|---|---|---|---|---|---|---|---|---|" + extra[1])
    for n in args.achp:
        run("ACHP-style 1D", n, *achp_problem(n)[:3], **kw)
    strong = {"kappa": 2.0, "delta": 1.0}
    for params, label, geometric in (({}, "thermoforming_2d", True), (strong, "thermoforming_2d κ=2 δ=1", True),
                                     (strong, "thermoforming_2d κ=2 δ=1, hierarchy 'auto'", False)):
        for m in args.thermo2d:
            p = scenes.thermoforming_2d(m, exact=False, **params)
            run(label, p.n, p.A, p.q, p.zeta, hierarchy=p.prolongations() if geometric else "auto", **kw)


if __name__ == "__main__":
    main()
