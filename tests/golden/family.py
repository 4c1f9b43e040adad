"""Every observable of ~650 solves by the stationary members (nrm, nrmm, nrmaor, nrmsor, nrmgs,
nrmj, mms, two_sweep), to check that a refactoring changes nothing (tests/golden/harness.py):
the small scenes (obstacle 1D/2D, convection–diffusion, American put, Bai LCP/ICP/affine,
thermoforming, impulse control, the cycling P-matrix) with accelerate none / anderson,
z_update auto / explicit / solve, ζ as given / as a callable, scale="both", a small maxiter,
explicit parameters (omega, gamma, alpha, beta, phi, theta), a callback stop and Solver reuse.

    python tests/golden/family.py before.pkl      # on the old build (or: make golden)
    python tests/golden/family.py --diff before.pkl after.pkl
"""
import numpy as np

from harness import main  # tests/golden/harness.py; puts tests/ on the path
import nrmicp
from nrmicp import scenes

STATIONARY = [m for m in nrmicp.METHODS if m != "newton"]


def problems():
    P = {
        "obstacle_1d": scenes.obstacle_1d(63),
        "obstacle_2d": scenes.obstacle_2d(15, exact=False),
        "convection": scenes.convection_diffusion_obstacle(15, exact=False),
        "american_put": scenes.american_put(n_space=64, exact=False),
        "thermo_1d": scenes.thermoforming_1d(31, exact=False),
        "impulse": scenes.impulse_control(33, exact=False),
        "pmatrix": scenes.p_matrix_cycling(2),
    }
    for kind in ("lcp", "icp", "affine"):
        for sym in (True, False):
            P[f"bai_{kind}_{'sym' if sym else 'nonsym'}"] = scenes.bai(6, kind=kind, symmetric=sym)
    return P


def as_callable(zeta, n):
    if zeta is None:
        return lambda z: np.zeros(n)
    if callable(zeta):
        return zeta
    return lambda z: nrmicp.scenes.evaluate_zeta(zeta, z)


def cases():
    C = []
    for pname, p in problems().items():
        for m in STATIONARY:
            base = dict(method=m, tol=1e-8, maxiter=2000, record_history=True)
            for acc in ("none", "anderson"):
                C.append((f"{pname}/{m}/{acc}", lambda p=p, o=dict(base, accelerate=acc): nrmicp.solve(
                    p.A, p.q, p.zeta, **o)))
            for zu in ("explicit", "solve"):
                C.append((f"{pname}/{m}/z_update={zu}", lambda p=p, o=dict(base, z_update=zu): nrmicp.solve(
                    p.A, p.q, p.zeta, **o)))
            C.append((f"{pname}/{m}/callable", lambda p=p, o=base: nrmicp.solve(
                p.A, p.q, as_callable(p.zeta, p.n), **o)))
        C += extras(pname, p)
    C += solver_reuse()
    return C


def extras(pname, p):
    """Options beyond the method: scaling, a small maxiter, explicit parameters, a callback stop."""
    C = []
    opts = {
        "scale": dict(method="nrmgs", scale="both"),
        "maxiter7": dict(method="nrmsor", maxiter=7),
        "params": dict(method="nrmaor", omega1=0.9, omega2=2.0, gamma=1.5, alpha=1.1, beta=0.9),
        "phi": dict(method="nrmgs", phi=0.1),
        "theta": dict(method="two_sweep", theta=1.2),
        "nrmm_alpha": dict(method="nrmm", alpha=2.0),
        "tol1e-14": dict(method="nrmgs", tol=1e-14, accelerate="anderson", anderson_m=3),
        "stall": dict(method="nrmj", stall_iterations=5, tol=1e-15),
    }
    for name, o in opts.items():
        o = dict(dict(tol=1e-8, maxiter=2000, record_history=True), **o)
        C.append((f"{pname}/{name}", lambda p=p, o=o: nrmicp.solve(p.A, p.q, p.zeta, **o)))

    def stop_at_3(p=p):
        seen = []

        def callback(intermediate_result):
            seen.append(intermediate_result.residual)
            if len(seen) == 3:
                raise StopIteration
        return nrmicp.solve(p.A, p.q, p.zeta, method="nrmgs", callback=callback, record_history=True)
    C.append((f"{pname}/callback_stop", stop_at_3))
    return C


def solver_reuse():
    """One Solver, several right-hand sides and per-solve options."""
    C = []
    p = scenes.obstacle_2d(15, exact=False)
    for m in ("nrm", "nrmgs", "two_sweep"):
        s = nrmicp.Solver(p.A, method=m)
        for k, scale in enumerate((1.0, 0.5, 2.0)):
            C.append((f"reuse/{m}/{k}", lambda s=s, q=scale * p.q: s.solve(q, p.zeta, tol=1e-10, record_history=True)))
        C.append((f"reuse/{m}/anderson", lambda s=s: s.solve(p.q, p.zeta, accelerate="anderson", maxiter=50)))
    return C


if __name__ == "__main__":
    main(cases)
