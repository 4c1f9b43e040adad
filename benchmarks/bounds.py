#!/usr/bin/env python
"""Bounds and free unknowns (issue 36): one command, three tables.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bounds.py [--out rows.jsonl]   # n = 16k … 1M (tens of minutes)
    OPENBLAS_NUM_THREADS=1 python benchmarks/bounds.py --quick              # n <= 4k, seconds

Scenes (nrmicp.scenes): the two-sided membrane 2D (two_sided_membrane_2d, m = 127 … 1023, n = 16k …
1M) and elastic contact (elastic_contact, vector P1 at r = 6, 7, 8 and P2 at r = 5, 6, 7: n = 16k,
66k, 263k, of which about √n are bounded and all the others free).

1. Scaling: ``nrmicp.solve(A, q, zeta=lower, upper=upper, **problem.solver_options)`` with every
   default (hierarchy 'auto', the units-free stop; elastic contact's scene passes components=2, the
   interleaved displacement components, to the 'amg' hierarchy): finest Newton steps (and per level,
   finest first), CPU seconds of the call (set-up and hierarchy included), Res/Res(0), CG iterations /
   linear solves.
2. Peers at the largest size of each scene, all stopped at the same target Res < 1e-8·Res(0)
   (Res = ‖mid(z − lower, z − upper, Az + q)‖₂, recomputed in numpy for every solver; nrmicp
   with rtol=1e-8):
     piqp          PIQP (sparse interior point) on min ½zᵀAz + qᵀz, lower ≤ z ≤ upper: everything
                   from the upper triangle to the solve; eps from 1e-8 down by 10× until the
                   target is met (the CPU of that last run; the tuning runs before it are not counted)
     vinewtonrsls  PETSc SNES vinewtonrsls with SNESVISetVariableBounds (±PETSC_INFINITY where a bound
                   is absent), cold (from 0), KSP CG + PCHYPRE BoomerAMG (its defaults), ksp_rtol 1e-6;
                   snes_atol from the target down by 10× until the numpy Res meets it. Run by the
                   interpreter of --petsc-python (petsc4py) on the matrices saved to .npz; the CPU of
                   SNESSolve (the matrix's assembly from CSR not counted).
3. Contact against obstacle problems of the same mesh and size, both with every default; the
   issue's ≤ 1.5× is contact / finite (free unknowns against bounded rows of the same A):
     membranes     the same mesh, elements and unknowns (same n, the same interleaved numbering, the
                   top edge held at 0), each displacement component replaced by a membrane: A =
                   the vector Laplacian (two uncoupled P_k stiffness matrices), load −0.2 on both,
                   every unknown bounded below by ψ = −0.02 − 0.5(x − 0.9)² (the floor's shape): an
                   obstacle problem with a 2D contact region, 1/2.4 of elasticity's nonzeros (another A).
     finite        the contact problem itself with the free unknowns' −inf replaced by −1 (inactive:
                   |u| ≤ 0.05): the same A, q and answer, every row bounded (the issue's workaround).
     mesh          the contact problem with the scene's mesh hierarchy (Problem.prolongations(),
                   built untimed) instead of the default 'amg': where the default's time goes.
     scalar        the contact problem without components=2: the scalar 'amg' (Ruge–Stüben on the
                   whole vector operator), what the scene's option saves.

Every solve runs in its own subprocess (CPU seconds of the child, building the problem excluded).
A peer that runs longer than --budget seconds is stopped and reported as such. With --out, each
row's measurements are written as JSON lines.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

RTOL = 1e-8   # the peers' common target: Res < RTOL · Res(0)
SIZES = {"membrane": [127, 255, 511, 1023], "contact_p1": [6, 7, 8], "contact_p2": [5, 6, 7]}
QUICK = {"membrane": [31, 63], "contact_p1": [3, 4], "contact_p2": [2, 3]}
PETSC_PYTHON = "/work/main/build/mpi-venv/bin/python"


# ----------------------------------------------------------------------------- problems

def res_mid(A, q, lower, upper, z) -> float:
    """‖mid(z − lower, z − upper, Az + q)‖₂ in numpy (PATH's Res; the paper's without bounds)."""
    w = A @ z + q
    with np.errstate(invalid="ignore"):
        return float(np.linalg.norm(np.minimum(z - lower, np.maximum(z - upper, w))))


def build(scene, size):
    """(A, q, lower, upper, Problem) of a scene at its size parameter."""
    from nrmicp import scenes

    if scene == "membrane":
        p = scenes.two_sided_membrane_2d(size, exact=False)
    else:
        p = scenes.elastic_contact(scene[-2:].upper(), size, exact=False)
    upper = np.full(p.n, np.inf) if p.upper is None else p.upper
    return p.A, p.q, np.asarray(p.zeta, float), upper, p


def membranes(element, r, load=0.2, curvature=0.5, centre=0.9):
    """(A, q, ψ) of the obstacle problem of the same mesh and size as elastic contact (module
    docstring, table 3): each displacement component a membrane over the floor's shape."""
    import scipy.sparse as sp
    import skfem
    from skfem.models.poisson import laplace

    from nrmicp.scenes.elastic_contact import _basis, _mesh, _scalar

    basis, _, free = _basis(element, r)
    scalar = skfem.Basis(_mesh(r), _scalar(element))
    K = sp.kron(skfem.asm(laplace, scalar), sp.identity(2), format="csr")   # the interleaved components
    f = np.repeat(skfem.asm(skfem.LinearForm(lambda v, w: -load * v), scalar), 2)
    A = sp.csr_matrix(K[free][:, free])
    A.sort_indices()
    x = basis.doflocs[0, free]
    return A, -f[free], -0.02 - curvature * (x - centre) ** 2


def problem(case, scene, size):
    """(A, q, lower, upper, solve options) of one case: the scene, or table 3's variants of it."""
    A, q, lower, upper, p = build(scene, size)
    if case == "membranes":
        A, q, lower = membranes(scene[-2:].upper(), size)
        return A, q, lower, np.full(len(q), np.inf), {}
    if case == "finite":
        return A, q, np.where(np.isfinite(lower), lower, -1.0), upper, dict(p.solver_options)
    if case == "mesh":
        return A, q, lower, upper, {"hierarchy": p.prolongations()}
    if case == "scalar":
        return A, q, lower, upper, {}
    return A, q, lower, upper, {**p.solver_options, **({"rtol": RTOL} if case == "target" else {})}


# ----------------------------------------------------------------------------- children

def child_nrmicp(case, scene, size):
    """One nrmicp.solve in this process: CPU seconds of the call and what the table shows."""
    import nrmicp
    import pyamg  # noqa: F401  (imported outside the timed region, as a user's process has it)

    A, q, lower, upper, opts = problem(case, scene, size)
    bounds = {} if np.all(upper == np.inf) else {"upper": upper}
    c0, t0 = time.process_time(), time.perf_counter()
    r = nrmicp.solve(A, q, zeta=lower, **bounds, **opts)
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    res0 = res_mid(A, q, lower, upper, np.zeros(len(q)))
    return dict(case=case, scene=scene, size=size, n=len(q), status=r.status.name.lower(), cpu=cpu, wall=wall,
                steps=int(r.level_steps[0]), level_steps=[int(s) for s in r.level_steps],
                level_seconds=[round(s, 3) for s in r.level_seconds], solves=int(r.linear_solves),
                inner_iterations=int(r.inner_iterations), inner=str(getattr(r, "inner", "")),
                res=res_mid(A, q, lower, upper, r.z), res0=res0, hierarchy=dict(r.hierarchy),
                timings={k: round(v, 3) for k, v in r.timings.items()},
                at_lower=int((r.active_mask == -1).sum()), at_upper=int((r.active_mask == 1).sum()))


def child_piqp(path):
    """PIQP on the box QP of the .npz at `path`, eps tuned down to the target (module docstring)."""
    import piqp
    import scipy.sparse as sp

    d = np.load(path)
    A = sp.csr_matrix((d["data"], d["indices"], d["indptr"]), shape=(len(d["q"]),) * 2)
    q, lower, upper, target = d["q"], d["lower"], d["upper"], float(d["target"])
    tried = []
    for eps in (1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13):
        c0 = time.process_time()
        s = piqp.SparseSolver()
        s.settings.verbose = False
        s.settings.eps_abs = s.settings.eps_rel = eps
        s.settings.eps_duality_gap_abs = s.settings.eps_duality_gap_rel = eps
        s.setup(sp.triu(A, format="csc"), q, x_l=lower, x_u=upper)
        status = s.solve()
        cpu = time.process_time() - c0
        res = res_mid(A, q, lower, upper, np.asarray(s.result.x))
        tried.append((eps, res, cpu))
        if res < target:
            break
    missed = f"target not met: Res {res:.1e} at eps {eps:.0e}, {getattr(status, 'name', status)}"
    return dict(status="converged" if res < target else missed, cpu=cpu, eps=eps, res=res,
                iterations=int(s.result.info.iter), tuning_cpu=sum(t[2] for t in tried), tried=tried)


def child_petsc(path):
    """vinewtonrsls on the .npz at `path` (module docstring); run by --petsc-python."""
    import petsc4py

    petsc4py.init([])
    import scipy.sparse as sp
    from petsc4py import PETSc

    d = np.load(path)
    A = sp.csr_matrix((d["data"], d["indices"], d["indptr"]), shape=(len(d["q"]),) * 2)
    q, lower, upper, target = d["q"], d["lower"], d["upper"], float(d["target"])
    M = PETSc.Mat().createAIJ(size=A.shape, csr=(A.indptr.astype(PETSc.IntType), A.indices.astype(PETSc.IntType),
                                                  A.data))
    qv = M.createVecLeft()
    qv.setArray(q)
    big = PETSc.INFINITY   # PETSC_INFINITY: SNESVI treats ±it as no bound
    xl, xu = M.createVecRight(), M.createVecRight()
    xl.setArray(np.where(np.isfinite(lower), lower, -big))
    xu.setArray(np.where(np.isfinite(upper), upper, big))

    def residual(snes, x, f):
        M.mult(x, f)
        f.axpy(1.0, qv)

    tried = []
    for atol in (target, target / 10, target / 100):
        snes = PETSc.SNES().create()
        snes.setType("vinewtonrsls")
        snes.setFunction(residual, M.createVecLeft())
        # the Jacobian is A, assembled once: a callback that leaves it be (without any callback, SNES
        # took steps that failed every line search, even with LU)
        snes.setJacobian(lambda snes_, x_, J, P: None, M, M)
        snes.setVariableBounds(xl, xu)
        snes.setTolerances(atol=atol, rtol=1e-50, stol=1e-50, max_it=100_000)
        ksp = snes.getKSP()
        ksp.setType("cg")
        ksp.getPC().setType("hypre")
        ksp.setTolerances(rtol=1e-6)
        x = M.createVecRight()
        x.set(0.0)
        c0 = time.process_time()
        snes.solve(None, x)
        cpu = time.process_time() - c0
        res = res_mid(A, q, lower, upper, x.getArray().copy())
        tried.append((atol, res, cpu, snes.getIterationNumber()))
        if res < target:
            break
    missed = f"target not met: Res {res:.1e}, reason {snes.getConvergedReason()}"
    return dict(status="converged" if res < target else missed, cpu=cpu, res=res,
                iterations=snes.getIterationNumber(), ksp_iterations=snes.getLinearSolveIterations(), atol=atol,
                tuning_cpu=sum(t[2] for t in tried), tried=tried)


# ----------------------------------------------------------------------------- the parent

def run(cmd, budget):
    """A child's JSON (its last stdout line), or a status saying why there is none."""
    try:
        cp = subprocess.run(cmd, capture_output=True, text=True, timeout=budget)
    except subprocess.TimeoutExpired:
        return dict(status=f"over budget ({budget:.0f} s)")
    if cp.returncode != 0:
        return dict(status="failed", note=(cp.stderr.strip().splitlines() or [""])[-1][:200])
    return json.loads(cp.stdout.strip().splitlines()[-1])


def ours(case, scene, size, budget):
    return run([sys.executable, os.path.abspath(__file__), "--child", case, scene, str(size)], budget)


def peers(scene, size, names, budget, petsc_python, tmp):
    """The peers on the scene at `size`, at the target RTOL · Res(0)."""
    A, q, lower, upper, _ = build(scene, size)
    target = RTOL * res_mid(A, q, lower, upper, np.zeros(len(q)))
    path = os.path.join(tmp, f"{scene}-{size}.npz")
    np.savez(path, data=A.data, indices=A.indices, indptr=A.indptr, q=q, lower=lower, upper=upper, target=target)
    out = {}
    for name in names:
        python = sys.executable if name == "piqp" else petsc_python
        out[name] = run([python, os.path.abspath(__file__), f"--{name}-child", path], budget)
    os.remove(path)
    return out


def cell(r, what="steps"):
    if "cpu" not in r:
        return r.get("status", "")
    flag = "" if r["status"] == "converged" else f" ({r['status']})"
    return f"{r['cpu']:.2f} s, {r[what]} {'st' if what == 'steps' else 'it'}{flag}"


def ratio(a, b):
    ok = all("cpu" in r and r.get("status") == "converged" for r in (a, b))
    return f"{a['cpu'] / b['cpu']:.1f}x" if ok else ""


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="the smallest sizes (seconds)")
    ap.add_argument("--scenes", nargs="+", default=list(SIZES), choices=list(SIZES))
    ap.add_argument("--peers", nargs="*", default=["piqp", "vinewtonrsls"], choices=["piqp", "vinewtonrsls"])
    ap.add_argument("--budget", type=float, default=1800.0, help="wall seconds after which a solve is stopped")
    ap.add_argument("--petsc-python", default=PETSC_PYTHON, help="an interpreter with petsc4py")
    ap.add_argument("--out", help="write each row's measurements here (JSON lines; the file is replaced)")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--piqp-child", help=argparse.SUPPRESS)
    ap.add_argument("--vinewtonrsls-child", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child or a.piqp_child or a.vinewtonrsls_child:
        out = child_nrmicp(a.child[0], a.child[1], int(a.child[2])) if a.child else \
            child_piqp(a.piqp_child) if a.piqp_child else child_petsc(a.vinewtonrsls_child)
        print(json.dumps(out))
        return
    sizes = QUICK if a.quick else SIZES
    peer_names = [p for p in a.peers if p != "vinewtonrsls" or os.path.exists(a.petsc_python)]
    if len(peer_names) < len(a.peers):
        print(f"# vinewtonrsls not run: no interpreter at {a.petsc_python} (--petsc-python)", flush=True)
    sink = open(a.out, "w") if a.out else None
    scaling, contact, compared = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for scene in a.scenes:
            for size in sizes[scene]:
                row = {"scene": scene, "size": size, "ours": ours("default", scene, size, a.budget)}
                if scene != "membrane":
                    row.update({c: ours(c, scene, size, a.budget) for c in ("membranes", "finite", "mesh", "scalar")})
                    contact.append(row)
                if size == sizes[scene][-1]:
                    row["target"] = ours("target", scene, size, a.budget)
                    row.update(peers(scene, size, peer_names, a.budget, a.petsc_python, tmp))
                    compared.append(row)
                scaling.append(row)
                print(f"#   {json.dumps(row)}", file=sys.stderr, flush=True)
                if sink:
                    print(json.dumps(row), file=sink, flush=True)
    if sink:
        sink.close()
    print_tables(scaling, contact, compared, peer_names)


def print_tables(scaling, contact, compared, peer_names):
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    print(f"# bounds, load {os.getloadavg()[0]:.1f}, OPENBLAS_NUM_THREADS={threads}; CPU seconds of the call, "
          "building the problem excluded\n")
    print("| scene | n | finest steps | steps per level (finest first) | CPU s | Res / Res(0) | CG it / solves |")
    print("|---|---|---|---|---|---|---|")
    for r in scaling:
        o = r["ours"]
        if "cpu" not in o:
            print(f"| {r['scene']} | | {o.get('status')} | | | | |")
            continue
        flag = "" if o["status"] == "converged" else f" ({o['status']})"
        print(f"| {r['scene']} | {o['n']:,} | {o['steps']}{flag} | {' '.join(map(str, o['level_steps']))} | "
              f"{o['cpu']:.2f} | {o['res'] / o['res0']:.1e} | {o['inner_iterations']} / {o['solves']} |")
    print("\nAt the largest sizes, every solver stopped at Res < 1e-8·Res(0) (CPU s, steps or iterations):\n")
    print("| scene | n | nrmicp newton | " + " | ".join(f"{p} | {p} / nrmicp" for p in peer_names) + " |")
    print("|---" * (3 + 2 * len(peer_names)) + "|")
    for r in compared:
        t = r["target"]
        cells = " | ".join(f"{cell(r[p], 'iterations')} | {ratio(r[p], t)}" for p in peer_names)
        print(f"| {r['scene']} | {t.get('n', 0):,} | {cell(t)} | {cells} |")
    print("\nElastic contact (free unknowns) against the obstacle problem of the same mesh and size (defaults):\n")
    print("| scene | n | contact | membranes (obstacle) | contact / membranes | finite bounds | contact / finite |"
          " contact, mesh hierarchy | contact, scalar 'amg' | scalar / contact |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in contact:
        o = r["ours"]
        print(f"| {r['scene']} | {o.get('n', 0):,} | {cell(o)} | {cell(r['membranes'])} | {ratio(o, r['membranes'])} | "
              f"{cell(r['finite'])} | {ratio(o, r['finite'])} | {cell(r['mesh'])} | {cell(r['scalar'])} | "
              f"{ratio(r['scalar'], o)} |")
    print("\nCG iterations per linear solve (all levels), default / scalar 'amg' / mesh hierarchy:\n")
    print("| scene | n | default | scalar 'amg' | mesh |")
    print("|---|---|---|---|---|")
    for r in contact:
        cg = [f"{x['inner_iterations'] / x['solves']:.1f}" if x.get("solves") else "" for x in
              (r["ours"], r["scalar"], r["mesh"])]
        print(f"| {r['scene']} | {r['ours'].get('n', 0):,} | {' | '.join(cg)} |")


if __name__ == "__main__":
    main()
