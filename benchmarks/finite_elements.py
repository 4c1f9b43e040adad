#!/usr/bin/env python
"""Finite-element matrices users bring (issue 17): one command, one table.

    OPENBLAS_NUM_THREADS=1 python benchmarks/finite_elements.py            # P1/P2/P3 n = 8k … 523k, disk scene
    OPENBLAS_NUM_THREADS=1 python benchmarks/finite_elements.py --quick    # n <= 33k

    OPENBLAS_NUM_THREADS=1 python benchmarks/finite_elements.py --cases Q1 Q2 tetP1 tetP2 materials \\
        aniso rotated graph plate --peers newton-amg nrmgs+aa --budget 30   # other matrices

Cases: the scikit-fem membrane over an off-centre obstacle (nrmicp.scenes.finite_elements,
P1, P2 and P3 on nested refinements of a disk-like polygon) and the numpy/scipy-only P1 contact
problem on a Delaunay mesh of scattered points (nrmicp.scenes.unstructured, no mesh hierarchy).
Target Res = ‖min(Az + q, z − ψ)‖₂ < 1e-9 (A = the stiffness matrix as assembled).

Peers, each in its own subprocess (CPU seconds of the child; extra peak memory = the child's
VmHWM during the solve, reset after building the problem, minus its resident size before):

    newton-amg   nrmicp method="newton", hierarchy="amg" (what a user without a mesh hierarchy gets)
    newton-fe    the same with the finite-element hierarchy's own nested interpolation
                 (Problem.prolongations(); its construction is not timed, see the note)
    newton-whole newton-amg on the whole A, rows with a lone diagonal not solved apart (the private
                 Solver(..., _decouple=False); the "dirrows" case's comparison, docs/finite_elements.md)
    nrmgs+aa     nrmicp nrmgs, accelerate="anderson"
    psor         multicolour projected SOR (nrmicp.bench.peers.psor, greedy colouring, ω from the
                 Jacobi spectral radius)

A peer that exceeded --budget CPU seconds is not run at larger sizes of that case.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time


import other_matrices  # noqa: E402  (this directory is on sys.path when a script here runs)

TOL = 1e-9
SCENES = ["P1", "P2", "P3", "disk"]   # the default run; the other_matrices cases by --cases
CASES = {"P1": [3, 4, 5, 6], "P2": [2, 3, 4, 5], "P3": [2, 3, 4], "disk": [32_000, 130_000, 520_000],
         **other_matrices.SIZES}
QUICK = {"P1": [3, 4], "P2": [2, 3], "P3": [1, 2], "disk": [32_000], **other_matrices.QUICK}
PEERS = ["newton-amg", "newton-fe", "nrmgs+aa", "psor"]
EXTRA_PEERS = ["newton-whole"]


def build(case, size):
    if case in other_matrices.SIZES:
        return other_matrices.build(case, size)
    if case == "disk":
        from nrmicp.scenes.unstructured import contact_disk_p1
        return contact_disk_p1(size, exact=False)
    from nrmicp.scenes.finite_elements import fe_obstacle
    return fe_obstacle(case, size, exact=False)


from mesh_independent import _status_kb  # noqa: E402  (this directory is on sys.path when a script here runs)


def child(peer, case, size, budget):
    import nrmicp
    import pyamg  # noqa: F401  (imported outside the timed region, as a user's process has it)
    from nrmicp.bench import peers

    p = build(case, size)
    pre = {}
    if peer == "newton-fe":
        t = time.process_time()
        Ps = p.prolongations()
        pre["note"] = f"interpolation built in {time.process_time() - t:.2f} s (untimed)"
        if Ps is None:
            return dict(status="no mesh hierarchy")
    if peer == "psor":
        t = time.process_time()
        colour, omega = peers.colours(p.A), peers.sor_omega(p.A)
        pre["note"] = f"{colour.max() + 1} colours, omega={omega:.3f}; set-up {time.process_time() - t:.1f} s (untimed)"
    rss0 = _status_kb("VmRSS")
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
    c0 = time.process_time()
    out = dict(pre)
    if peer.startswith("newton"):
        if peer == "newton-whole":   # the private flag: rows with a lone diagonal not solved apart
            solver = nrmicp.Solver(p.A, method="newton", hierarchy="amg", tol=TOL, maxiter=1000, _decouple=False)
            r = solver.solve(p.q, p.zeta)
        else:
            r = p.solve(method="newton", hierarchy="amg" if peer == "newton-amg" else Ps, tol=TOL, maxiter=1000)
        z = r.z
        out.update(status=r.status.name.lower(), steps=int(r.level_steps[0]), solves=int(r.linear_solves),
                   levels=len(r.level_steps), level_steps=list(r.level_steps),
                   level_seconds=[round(s, 2) for s in r.level_seconds])
    elif peer == "nrmgs+aa":
        r = p.solve(method="nrmgs", accelerate="anderson", tol=TOL, maxiter=200_000)
        z = r.z
        out.update(status=r.status.name.lower(), steps=int(r.nit))
    else:
        A, q, c = peers.shifted_lcp(p)
        o = peers.psor(A, q, c, TOL, omega=omega, colour=colour, maxiter=10**7, time_limit=budget)
        z = o["z"]
        out.update(status=o["status"], steps=int(o["nit"]))
    out.update(cpu=time.process_time() - c0, res=p.residual(z), n=p.n,
               extra_mb=(_status_kb("VmHWM") - rss0) / 1024)
    return out


def run(peer, case, size, budget):
    cmd = [sys.executable, os.path.abspath(__file__), "--child", peer, case, str(size), str(budget)]
    try:
        cp = subprocess.run(cmd, capture_output=True, text=True, timeout=3 * budget + 300)
    except subprocess.TimeoutExpired:
        return dict(status="timeout")
    if cp.returncode != 0:
        return dict(status="failed", note=cp.stderr.strip().splitlines()[-1] if cp.stderr.strip() else "")
    return json.loads(cp.stdout.strip().splitlines()[-1])


def cell(r):
    if "cpu" not in r:
        return r.get("status", "")
    what = f"{r['steps']} st / {r['solves']} sol" if "solves" in r else f"{r['steps']} it"
    flag = "" if r["status"] == "converged" else f" ({r['status']})"
    return f"{r['cpu']:.2f} s, {what}, {r['extra_mb']:.0f} MB{flag}"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--budget", type=float, default=120.0, help="CPU seconds after which a peer stops growing")
    ap.add_argument("--peers", nargs="+", default=PEERS, choices=PEERS + EXTRA_PEERS)
    ap.add_argument("--cases", nargs="+", default=SCENES, choices=list(CASES),
                    help="default: the scenes; the rest are benchmarks/other_matrices.py's")
    ap.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        peer, case, size, budget = a.child
        print(json.dumps(child(peer, case, int(size), float(budget))))
        return
    sizes = QUICK if a.quick else CASES
    print(f"# finite elements, tol {TOL}, load {os.getloadavg()[0]:.1f}, OPENBLAS_NUM_THREADS="
          f"{os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}", flush=True)
    print("| case | n | " + " | ".join(a.peers) + " | nrmgs+aa / amg | psor / amg |")
    print("|---" * (len(a.peers) + 4) + "|", flush=True)
    stopped = set()
    for case in a.cases:
        for size in sizes[case]:
            rows, n = {}, None
            for peer in a.peers:
                if (case, peer) in stopped:
                    rows[peer] = dict(status="over budget at a smaller size")
                    continue
                rows[peer] = r = run(peer, case, size, a.budget)
                n = r.get("n", n)
                if r.get("cpu", 0) > a.budget or r.get("status") in ("timeout", "failed", "time_limit"):
                    stopped.add((case, peer))
                print(f"#   {case} {size} {peer}: {json.dumps(r)}", file=sys.stderr, flush=True)
            label = f"{case}, r={size}" if case in ("P1", "P2", "P3") else f"{case} ({size:,})"
            ratios = " | ".join(ratio(rows.get(peer, {}), rows.get("newton-amg", {})) for peer in ("nrmgs+aa", "psor"))
            print(f"| {label} | {n or ''} | " + " | ".join(cell(rows[p]) for p in a.peers) + f" | {ratios} |",
                  flush=True)


def ratio(peer, amg) -> str:
    """The peer's CPU time over newton-amg's, when both converged."""
    ok = all("cpu" in r and r.get("status") == "converged" for r in (peer, amg))
    return f"{peer['cpu'] / amg['cpu']:.1f}x" if ok else ""


if __name__ == "__main__":
    main()
