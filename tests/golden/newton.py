"""Every observable of ~730 method="newton" / polish solves, to check that a refactoring of the
Newton member changes nothing: z, w, nit, iterations, Res, status, message, linear_solves,
fallback_sweeps, outer_iterations, level_steps, path, inner, polished and the Res history (not
timings). Problems: the scenes the Newton tests use (obstacle 1D/2D/3D, convection–diffusion,
American put, thermoforming 1D/2D, impulse control, Bai, the cycling P-matrix, the American put
march) with hierarchy None / "amg" / geometric, ζ none / constant / Affine / callable /
callable + zeta_jacobian, tol 1e-8 / 1e-10 / 1e-16 (a settled active set), small maxiter,
inner="cg", scale="both", a callback stop, polish=True on nrmgs / nrm / nrmsor, and every case
of tests/test_hard_cases.py.

    python tests/golden/newton.py before.pkl      # on the old build (or: make golden)
    python tests/golden/newton.py after.pkl       # on the new build
    python tests/golden/newton.py --diff before.pkl after.pkl
"""

import numpy as np
import scipy.sparse as sp

from harness import main  # tests/golden/harness.py; puts tests/ on the path
import nrmicp
from nrmicp import scenes
from test_newton import impulse_jacobian  # tests/: the impulse-control Jacobian, written once


def hierarchies(p):
    out = {"none": None, "amg": "amg"}
    P = p.prolongations()
    if P:
        out["geom"] = P
    return out


def cases():
    C = []
    obst = {
        "obstacle_1d": lambda: scenes.obstacle_1d(127),
        "obstacle_2d_31": lambda: scenes.obstacle_2d(31, exact=False),
        "obstacle_2d_63": lambda: scenes.obstacle_2d(63, exact=False),
        "obstacle_2d_16": lambda: scenes.obstacle_2d(16, exact=False),
        "obstacle_3d": lambda: scenes.obstacle_3d(11, exact=False),
        "convection": lambda: scenes.convection_diffusion_obstacle(31, exact=False),
        "convection_63": lambda: scenes.convection_diffusion_obstacle(63, exact=False),
        "american_put": lambda: scenes.american_put(n_space=256, exact=False),
    }
    for name, build in obst.items():
        p = build()
        psi = np.asarray(p.zeta)
        n = p.n
        Z = sp.csr_matrix((n, n))
        B = sp.csr_matrix(0.1 * sp.eye(n))
        zetas = {
            "const": (psi, {}),
            "none": (None, {}),
            "affine": (nrmicp.Affine(B, psi), {}),
            "callable": (lambda z, psi=psi: psi, {}),
            "callable+jac": (lambda z, psi=psi: psi, {"zeta_jacobian": lambda z, Z=Z: Z}),
        }
        for hname, h in hierarchies(p).items():
            for zname, (zeta, extra) in zetas.items():
                q = p.q + p.A @ psi if zname == "none" else p.q
                for tol in (1e-8, 1e-10, 1e-16):
                    C.append((f"{name}/{hname}/{zname}/tol{tol}",
                              lambda p=p, q=q, zeta=zeta, extra=extra, h=h, tol=tol: nrmicp.solve(
                                  p.A, q, zeta, method="newton", hierarchy=h, tol=tol, record_history=True, **extra)))
            C.append((f"{name}/{hname}/const/maxiter1",
                      lambda p=p, h=h: nrmicp.solve(p.A, p.q, p.zeta, method="newton", hierarchy=h, maxiter=1,
                                                    record_history=True)))
            C.append((f"{name}/{hname}/const/inner-cg",
                      lambda p=p, h=h: nrmicp.solve(p.A, p.q, p.zeta, method="newton", hierarchy=h, inner="cg",
                                                    tol=1e-10, record_history=True)))
            C.append((f"{name}/{hname}/const/scale",
                      lambda p=p, h=h: nrmicp.solve(p.A, p.q, p.zeta, method="newton", hierarchy=h, scale="both",
                                                    tol=1e-10, record_history=True)))
        # x0 (used without hierarchy)
        C.append((f"{name}/x0", lambda p=p: nrmicp.solve(p.A, p.q, p.zeta, method="newton", hierarchy=None,
                                                         x0=np.asarray(p.zeta) + 0.01, record_history=True)))
        for m in ("nrmgs", "nrm", "nrmsor"):
            for zname, (zeta, extra) in zetas.items():
                if extra:
                    continue
                q = p.q + p.A @ psi if zname == "none" else p.q
                C.append((f"{name}/polish/{m}/{zname}",
                          lambda p=p, q=q, zeta=zeta, m=m: nrmicp.solve(p.A, q, zeta, method=m, accelerate="anderson",
                                                                      tol=1e-6, polish=True, record_history=True)))
    # callback stop
    def cb_case():
        p = scenes.obstacle_2d(15)
        seen = []
        def callback(intermediate_result):
            seen.append(1)
            if len(seen) == 3:
                raise StopIteration
        return p.solve(method="newton", hierarchy=None, callback=callback, record_history=True)
    C.append(("callback_stop", cb_case))
    # implicit scenes
    impl = {
        "thermo_1d_63": lambda: scenes.thermoforming_1d(63, exact=False),
        "thermo_1d_127": lambda: scenes.thermoforming_1d(127, exact=False),
        "thermo_2d_15": lambda: scenes.thermoforming_2d(15, exact=False),
        "impulse_101": lambda: scenes.impulse_control(101, exact=False),
        "impulse_33": lambda: scenes.impulse_control(33, exact=False),
    }
    for name, build in impl.items():
        p = build()
        hs = hierarchies(p)
        for hname, h in hs.items():
            for tol in (1e-8, 1e-10):
                C.append((f"{name}/{hname}/tol{tol}", lambda p=p, h=h, tol=tol: nrmicp.solve(p.A, p.q, p.zeta,
                    method="newton", hierarchy=h, tol=tol, record_history=True)))
            C.append((f"{name}/{hname}/maxiter3", lambda p=p, h=h: nrmicp.solve(p.A, p.q, p.zeta,
                method="newton", hierarchy=h, maxiter=3, record_history=True)))
            C.append((f"{name}/{hname}/tol1e-16", lambda p=p, h=h: nrmicp.solve(p.A, p.q, p.zeta,
                method="newton", hierarchy=h, tol=1e-16, record_history=True)))
        if name.startswith("impulse"):
            for hname, h in hs.items():
                C.append((f"{name}/{hname}/jac", lambda p=p, h=h: nrmicp.solve(
                    p.A, p.q, p.zeta, method="newton", hierarchy=h, tol=1e-10, record_history=True,
                    zeta_jacobian=impulse_jacobian(p))))
                C.append((f"{name}/{hname}/jac/maxiter2", lambda p=p, h=h: nrmicp.solve(
                    p.A, p.q, p.zeta, method="newton", hierarchy=h, maxiter=2, record_history=True,
                    zeta_jacobian=impulse_jacobian(p))))
        for m in ("nrmgs", "nrm"):
            C.append((f"{name}/polish/{m}", lambda p=p, m=m: p.solve(method=m, accelerate="anderson", tol=1e-6,
                                                                    polish=True, maxiter=3000, record_history=True)))
    # bai
    for kind in ("lcp", "icp", "affine"):
        for sym in (True, False):
            p = scenes.bai(16, kind=kind, symmetric=sym)
            for h in (None, "amg"):
                C.append((f"bai/{kind}/{sym}/{h}", lambda p=p, h=h: p.solve(method="newton", hierarchy=h, tol=1e-12,
                                                                          record_history=True)))
            C.append((f"bai/{kind}/{sym}/polish", lambda p=p: p.solve(method="nrmgs", tol=1e-6, polish=True)))
            if kind == "icp":
                C.append((f"bai/icp/{sym}/jac", lambda p=p: p.solve(
                    method="newton", hierarchy=None, tol=1e-12, record_history=True,
                    zeta_jacobian=lambda z: sp.diags(0.5 * np.cos(z), format="csr"))))
    # p-matrix
    for b in (1, 2, 4, 8):
        p = scenes.p_matrix_cycling(b)
        for tol in (1e-8, 1e-12, 1e-16):
            C.append((f"pmatrix/{b}/{tol}", lambda p=p, tol=tol: p.solve(method="newton", hierarchy=None, tol=tol,
                                                                        record_history=True)))
        C.append((f"pmatrix/{b}/maxiter5", lambda p=p: p.solve(method="newton", hierarchy=None, maxiter=5,
                                                               record_history=True)))
        C.append((f"pmatrix/{b}/callable", lambda p=p: nrmicp.solve(p.A, p.q, lambda z: 0 * z, method="newton",
                                                                    tol=1e-12, record_history=True)))
        C.append((f"pmatrix/{b}/callable+jac", lambda p=p: nrmicp.solve(
            p.A, p.q, lambda z: 0 * z, method="newton", tol=1e-12, record_history=True,
            zeta_jacobian=lambda z: sp.csr_matrix((z.size, z.size)))))
        C.append((f"pmatrix/{b}/affine", lambda p=p: nrmicp.solve(
            p.A, p.q, nrmicp.Affine(sp.csr_matrix((p.n, p.n)), np.zeros(p.n)), method="newton", tol=1e-12,
            record_history=True)))
    # american put march
    def march(h):
        price, info = scenes.american_put_price(100.0, n_space=256, n_time=20, method="newton", full_output=True,
                                                tol=1e-10, hierarchy=h)
        return type("R", (), {"z": np.asarray(info["V"]), "nit": np.asarray(info["nit"]).tolist(),
                              "residual": price, "success": info["success"]})()
    for h in (None, "amg"):
        C.append((f"american_march/{h}", lambda h=h: march(h)))
    # hard cases
    import test_hard_cases as hard
    for case in hard.CASES:
        for cfg, opts in {"newton": dict(method="newton"), "newton+scale": dict(method="newton", scale="both"),
                          "nrmgs+polish": dict(method="nrmgs", polish=True)}.items():
            o = dict(opts, **case.setup)
            C.append((f"hard/{case.name}/{cfg}", lambda case=case, o=o: nrmicp.solve(
                case.A, case.q, case.zeta, tol=hard.TOL, maxiter=3000, record_history=True, **o)))
    return C


if __name__ == "__main__":
    main(cases)
