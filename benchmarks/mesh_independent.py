#!/usr/bin/env python
"""Mesh-independent solves (issue 7), re-measured on the product: one command.

    python benchmarks/mesh_independent.py --out bench-out/mesh            # everything (long)
    python benchmarks/mesh_independent.py --quick --out bench-out/mesh-q  # n <= 65k, minutes

Obstacle section: the membrane obstacle of benchmarks/run_peers.py ("obstacle0": 5-point
Laplacian, μ = 0, multiplied through by h² and shifted to the LCP in y = z − ψ) on 2D grids
m = 127 … 2047 (n = 16k … 4M), and its 3D 7-point twin (obstacle_3d, m = 47 and 103, n ≈ 1e5
and 1.1e6), target Res = ‖min(Ay + q, y)‖₂ < 1e-8. Peers, each in its own subprocess (peak
memory = the child's VmHWM during the solve, reset by /proc/self/clear_refs after building
the problem; "extra" subtracts the resident size before the solve; CPU seconds of the child,
all threads, next to wall seconds, since a loaded machine inflates wall time; for the QP
solvers the wall time is the final run's, CPU time includes the eps tuning):

    newton-amg / newton-geo / newton-cold   nrmicp method="newton", hierarchy "amg" /
                                            the scene's prolongations() / None
    nrmgs+aa                                nrmicp nrmgs, accelerate="anderson"
    psor                                    red-black projected SOR, grid-optimal ω
    piqp, osqp                              QP solvers (benchmarks/qp_peers.py), eps tightened
                                            10× at a time until Res < target
    proto-amg / proto-geo / proto-amg-cg    benchmarks/newton_prototype.py (scipy splu, or
                                            pyamg-preconditioned CG)

A peer whose time, extrapolated from its smaller sizes (power law), exceeds --budget is
skipped at that size and marked so; one that failed or timed out is skipped at larger sizes.
The prototype's SuperLU (splu) is not run above n = 1.1e6 in 2D and 1.5e5 in 3D (its fill
needs > 10 GB there).

The report is one table: CPU seconds of the solving child (all threads), finest-level Newton
steps / linear solves on all levels (or iterations), extra peak memory.

Other section (in this process): the American put march (Newton steps per time step,
warm-started). The QVIs (thermoforming, impulse control) are benchmarks/qvi_operator.py's.
Writes <out>.csv and <out>.md. Timings on a shared
machine are noisy: compare peers within one run; the load average is recorded.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import subprocess
import sys
import time

import numpy as np
from nrmicp.bench.peers import estimate

HERE = os.path.dirname(os.path.abspath(__file__))

TOL = 1e-8
GRIDS = {"2d": [127, 255, 511, 1023, 2047], "3d": [47, 103]}
QUICK_GRIDS = {"2d": [127, 255], "3d": [23]}
PEERS = ["newton-amg", "newton-geo", "newton-cold", "nrmgs+aa", "psor", "piqp", "osqp",
         "proto-amg", "proto-geo", "proto-amg-cg"]
# exponent p of time ~ n^p used to extrapolate before a peer has two sizes; in 3D a sparse
# Cholesky factorization costs ~n^2 flops (nested dissection), hence the "3d" entries
DEFAULT_P = {"newton-cold": 2.5, "nrmgs+aa": 2.0, "psor": 1.6, "piqp": 1.5, "osqp": 2.0,
             "3d": {"newton-amg": 2.0, "newton-geo": 2.0, "newton-cold": 2.5, "piqp": 2.0,
                    "proto-amg": 2.0, "proto-geo": 2.0}}
SPLU_MAX_N = {"2d": 1_100_000, "3d": 150_000}   # SuperLU's fill: > 10 GB beyond (2D 4M, 3D 1M)


# ----------------------------------------------------------------------------- child side
def build(dim, m):
    """(A, q, problem): the h²-scaled shifted LCP of obstacle_2d / obstacle_3d (the scene registry's)."""
    from nrmicp import scenes
    P = (scenes.obstacle_2d if dim == "2d" else scenes.obstacle_3d)(m, exact=False)
    A, q = scenes.scaled_lcp(P)
    return A, q, P


def _status_kb(field):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    return 0


def _colors(dim, m):
    """Red-black colouring of the grid (x fastest): (i + j [+ k]) mod 2."""
    d = 2 if dim == "2d" else 3
    return (np.indices((m,) * d).reshape(d, -1).sum(axis=0) % 2).astype(np.int8)


def run_peer(peer, dim, m, tol, budget, eps_start=None):
    """Run one peer on one case; returns a dict (JSON-serializable)."""
    import nrmicp  # noqa: F401  (imports outside the timed region, as a user's process has them)
    import pyamg  # noqa: F401
    import qp_peers
    import newton_prototype as proto
    from scipy_modulus import residual

    A, q, P = build(dim, m)
    rss0 = _status_kb("VmRSS")
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")          # reset VmHWM to the current RSS
    except OSError:
        pass
    out = dict(steps=None, solves=None, note="")
    if peer.endswith("-geo") and P.prolongations() is None:
        return dict(status="skipped (no geometric hierarchy)", note="")
    t0, c0 = time.perf_counter(), time.process_time()
    if peer.startswith("newton"):
        hier = {"newton-amg": "amg", "newton-geo": None, "newton-cold": None}[peer]
        if peer == "newton-geo":
            hier = P.prolongations()
        r = nrmicp.solve(A, q, method="newton", hierarchy=hier, tol=tol, maxiter=1000)
        z = r.z
        out.update(status=r.status.name.lower(), steps=int(r.nit), solves=int(r.linear_solves),
                   note=f"path={r.path}; level_steps={r.level_steps}; level_seconds="
                        f"{[round(t, 2) for t in r.level_seconds]}")
    elif peer == "nrmgs+aa":
        r = nrmicp.solve(A, q, method="nrmgs", accelerate="anderson", tol=tol, maxiter=200_000)
        z = r.z
        out.update(status=r.status.name.lower(), steps=int(r.nit))
    elif peer == "psor":
        h = 1.0 / (m + 1)
        rho = math.cos(math.pi * h)     # Jacobi spectral radius, 5- and 7-point Laplacian
        omega = 2.0 / (1.0 + math.sqrt(1.0 - rho**2))
        o = qp_peers.psor_solve(A, q, tol, omega=omega, colors=_colors(dim, m),
                                time_limit=1.5 * budget)
        z = o["z"]
        out.update(status=o["status"], steps=int(o["iters"]), note=f"omega={omega:.4f}")
    elif peer in ("piqp", "osqp"):
        # eps tightened 10x from the eps that worked at the previous size; `seconds` is the
        # final run's time (a user who knew the right eps), the tuning total is in the note
        o = qp_peers.solve_to_target(peer, A, q, tol, eps_start=eps_start, time_budget=budget)
        z = o["z"]
        out.update(status="converged" if o["reached"] else o["status"], steps=int(o["iters"]),
                   eps=o["eps"], final_seconds=o["seconds"],
                   note=f"{o['setting']}; with eps tuning {o['tuning_seconds']:.1f} s")
    elif peer.startswith("proto"):
        pro = {"proto-amg": "amg", "proto-geo": P.prolongations(), "proto-amg-cg": "amg"}[peer]
        o = proto.solve(A, q, pro, tol=tol, inner="cg" if peer.endswith("cg") else "splu")
        z = o["z"]
        out.update(status="converged" if o["res"] < tol else "not converged", steps=o["steps"],
                   solves=o["solves"], note=f"level_steps={o['steps_per_level']}")
    else:
        raise ValueError(peer)
    cpu = time.process_time() - c0
    seconds = out.pop("final_seconds", None) or time.perf_counter() - t0
    hwm = _status_kb("VmHWM")
    res = float(residual(A, q, z)) if z is not None else float("nan")
    if out["status"] == "converged" and not res < tol:
        out["status"] = "res above target"
    out.update(seconds=seconds, cpu_seconds=cpu, res=res, peak_mb=hwm / 1024, extra_mb=(hwm - rss0) / 1024)
    return out


# ----------------------------------------------------------------------------- parent side
def available(peer):
    if peer in ("piqp", "osqp"):
        try:
            __import__(peer)
        except ImportError:
            return False
    return True


def obstacle_section(args, log):
    rows = []
    grids = QUICK_GRIDS if args.quick else GRIDS
    for dim in args.dims:
        hist, dead, qp_eps = {}, {}, {}
        for m in args.m or grids[dim]:
            n = m ** (2 if dim == "2d" else 3)
            log(f"\n== obstacle {dim} m={m} n={n}  (load {os.getloadavg()[0]:.1f})")
            for peer in args.peers:
                row = dict(section="obstacle", case=f"obstacle_{dim}", m=m, n=n, peer=peer,
                           target=args.tol, load=round(os.getloadavg()[0], 2))
                p_default = DEFAULT_P[dim].get(peer) if dim in DEFAULT_P else None
                est = estimate(hist.get(peer, []), n, p_default or DEFAULT_P.get(peer, 1.3))
                if not available(peer):
                    row["status"] = "not installed"
                elif peer in dead:
                    row["status"] = dead[peer]
                elif peer in ("proto-amg", "proto-geo") and n > SPLU_MAX_N[dim]:
                    row["status"] = "skipped (splu fill > 10 GB)"
                elif est is not None and est > args.budget:
                    row["status"] = f"skipped (est. {est:.0f} s > budget {args.budget:.0f} s)"
                else:
                    cmd = [sys.executable, os.path.abspath(__file__), "--child",
                           json.dumps([peer, dim, m, args.tol, args.budget, qp_eps.get(peer)])]
                    try:
                        cp = subprocess.run(cmd, capture_output=True, text=True,
                                            timeout=2 * args.budget + 60)
                        lines = [ln for ln in cp.stdout.splitlines() if ln.startswith("{")]
                        if cp.returncode != 0 or not lines:
                            row["status"] = "error"
                            row["note"] = (cp.stderr.strip().splitlines() or ["?"])[-1][:200]
                        else:
                            row.update(json.loads(lines[-1]))
                    except subprocess.TimeoutExpired:
                        row["status"] = f"timeout (> {2 * args.budget + 60:.0f} s)"
                st = row.get("status", "")
                if st == "converged":   # extrapolated in CPU seconds: wall time follows the machine's load
                    hist.setdefault(peer, []).append((n, row.get("cpu_seconds") or row["seconds"]))
                    if "eps" in row:
                        qp_eps[peer] = row["eps"]
                elif not st.startswith(("skipped", "not installed")) and peer not in dead:
                    dead[peer] = f"skipped (failed at n={n}: {st})"
                rows.append(row)
                log(f"  {peer:13s} {st:28s} steps={row.get('steps')} solves={row.get('solves')} "
                    f"t={row.get('seconds', float('nan')):.2f}s cpu={row.get('cpu_seconds', float('nan')):.2f}s res={row.get('res', float('nan')):.1e} "
                    f"extra={row.get('extra_mb', float('nan')):.0f}MB {row.get('note', '')}")
    return rows


def _march(n_space, step):
    """The American-put march (S0 = K = 100, 100 steps, Rannacher 2): ``step(m, q, v)`` solves
    one LCP warm-started from v and returns (v_new, finest steps, linear solves, ok)."""
    from scipy.interpolate import CubicSpline
    from nrmicp.scenes.american import _March
    m = _March(400.0, 100.0, 0.05, 0.2, 1.0, n_space, 100, 2)
    t0 = time.perf_counter()
    v, nit, solves, ok = m.payoff.copy(), [], [], True
    for kind in m.steps():
        v, k, ls, good = step(m, m.q(kind, v), v)
        nit.append(k)
        solves.append(ls)
        ok = ok and good
    seconds = time.perf_counter() - t0
    price = float(CubicSpline(m.S, m.full(v))(100.0))
    return np.array(nit), np.array(solves), ok, seconds, price


def american_section(args, log):
    import nrmicp
    import newton_prototype as proto
    rows = []
    sizes = [800, 1600, 3200, 6400] if not args.quick else [800, 1600]
    makers = [("newton (hierarchy=auto)", dict(method="newton")),
              ("newton (x0 warm start, hierarchy=None)", dict(method="newton", hierarchy=None)),
              ("newton (hierarchy=amg)", dict(method="newton", hierarchy="amg")),
              ("nrmgs+aa", dict(method="nrmgs", accelerate="anderson", maxiter=100_000)),
              ("prototype (warm start)", None)]

    def proto_step(m, q, v):
        # the LCP in y = v − payoff, warm-started from the previous step
        y, k, res = proto.active_set_newton(m.A, q + m.A @ m.payoff, np.maximum(v - m.payoff, 0.0),
                                            args.tol, 200)
        return y + m.payoff, k, k, res < args.tol

    for n_space in sizes:
        log(f"\n== american put n_space={n_space}, 100 time steps")
        for peer, kw in makers:
            cache = {}

            def step(m, q, v, kw=kw, cache=cache):       # one Solver for the whole march
                if kw is None:
                    return proto_step(m, q, v)
                if "s" not in cache:
                    cache["s"] = nrmicp.Solver(m.A, **kw)
                r = cache["s"].solve(q, zeta=m.payoff, x0=v, tol=args.tol)
                return (np.asarray(r.z, dtype=float).copy(), int(r.nit),
                        int(getattr(r, "linear_solves", r.nit)), bool(r.success))

            nit, solves, ok, seconds, price = _march(n_space, step)
            row = dict(section="american", case="american_put", n=n_space - 1, peer=peer,
                       status="converged" if ok else "not converged", steps=float(nit.mean()),
                       solves=float(solves.mean()), seconds=seconds, res=float("nan"),
                       load=round(os.getloadavg()[0], 2),
                       note=f"price={price:.6f}; after the first time step: steps {nit[1:].mean():.2f} "
                            f"(max {nit[1:].max()}), linear solves {solves[1:].mean():.2f}; first {nit[0]}")
            rows.append(row)
            log(f"  {peer:40s} {row['status']} steps/step={row['steps']:.2f} solves/step={row['solves']:.2f} "
                f"t={row['seconds']:.2f}s {row['note']}")
    return rows


# ----------------------------------------------------------------------------- report
FIELDS = ["section", "case", "m", "n", "peer", "status", "steps", "solves", "seconds", "cpu_seconds", "res", "err",
          "peak_mb", "extra_mb", "target", "load", "note"]


def _cell(r):
    st = r.get("status", "")
    if st != "converged":
        return st.split(" (")[0] if st.startswith("skipped") else st
    s = f"{r['seconds']:.2f} s"
    if r.get("steps") is not None:
        unit = "steps" if r["peer"].startswith(("newton", "proto")) else "it"
        s = f"{r['steps']} {unit}, " + s
    return s


def _one_cell(r):
    """CPU s, Newton steps / linear solves (or iterations), extra peak MB; or why not run."""
    st = r.get("status", "")
    if st != "converged":
        return st.split(" (")[0] if st.startswith("skipped") else st
    if r["peer"].startswith(("newton", "proto")):
        count = f"{r['steps']} / {r['solves']}"
    else:
        count = f"{r['steps']} it"
    return f"{r['cpu_seconds']:.2f} s, {count}, {r['extra_mb']:.0f} MB"


def markdown(rows, meta):
    out = ["# Mesh-independent solves (benchmarks/mesh_independent.py)", "",
           f"{meta}", ""]
    obst = [r for r in rows if r["section"] == "obstacle"]
    if obst:
        peers = list(dict.fromkeys(r["peer"] for r in obst))
        tol = obst[0]["target"]
        newtons = [p for p in peers if p.startswith("newton")] if "psor" in peers else []
        out += [f"## Obstacle problems: CPU seconds to Res < {tol:g}, finest-level Newton steps / linear solves "
                "(all levels) or iterations, extra peak memory; PSOR's CPU time over Newton's", "",
                "| problem | n | " + " | ".join(peers + [f"PSOR / {p}" for p in newtons]) + " |",
                "|---|---|" + "---|" * (len(peers) + len(newtons))]
        for case, n in dict.fromkeys((r["case"], r["n"]) for r in obst):
            here = {r["peer"]: r for r in obst if r["case"] == case and r["n"] == n}
            cells = [_one_cell(here[p]) if p in here else "" for p in peers]
            ok = {p: r for p, r in here.items() if r.get("status") == "converged"}
            cells += [f"{ok['psor']['cpu_seconds'] / ok[p]['cpu_seconds']:.1f}×" if "psor" in ok and p in ok else ""
                      for p in newtons]
            out.append(f"| {case} | {n:,} | " + " | ".join(cells) + " |")
        out.append("")
    for sec, title in [("american", "American put, 100 time steps: per time step (mean), Newton steps on the finest "
                                    "level and linear solves on all levels (nrmgs+aa: iterations)")]:
        rs = [r for r in rows if r["section"] == sec]
        if not rs:
            continue
        out += [f"## {title}", "", "| case | n | peer | status | steps | linear solves | seconds | Res | max err | note |",
                "|---|---|---|---|---|---|---|---|---|---|"]
        for r in rs:
            steps = f"{r['steps']:.2f}" if isinstance(r.get("steps"), float) else r.get("steps")
            solves = f"{r['solves']:.2f}" if isinstance(r.get("solves"), float) else r.get("solves", "")
            err = f"{r['err']:.1e}" if r.get("err") is not None else ""
            out.append(f"| {r['case']} | {r['n']:,} | {r['peer']} | {r['status']} | {steps} | "
                       f"{solves} | {r['seconds']:.2f} | {r['res']:.1e} | {err} | {r.get('note', '')} |")
        out.append("")
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--out", default="bench-out/mesh_independent")
    ap.add_argument("--quick", action="store_true", help="small sizes only (minutes)")
    ap.add_argument("--sections", nargs="+", default=["obstacle", "american"], choices=["obstacle", "american"])
    ap.add_argument("--dims", nargs="+", default=["2d", "3d"])
    ap.add_argument("--peers", nargs="+", default=PEERS)
    ap.add_argument("--m", nargs="+", type=int, help="grid sides instead of the defaults "
                    f"(2d: {GRIDS['2d']}, 3d: {GRIDS['3d']})")
    ap.add_argument("--budget", type=float, default=600.0, help="seconds per peer and size (extrapolated)")
    ap.add_argument("--tol", type=float, default=TOL)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(run_peer(*json.loads(args.child))), flush=True)
        return
    log = lambda s: print(s, flush=True)  # noqa: E731
    import nrmicp
    meta = (f"nrmicp {nrmicp.__version__}, {os.cpu_count()} cores, load average at start "
            f"{os.getloadavg()[0]:.1f} (shared machine: compare within the run), {time.strftime('%Y-%m-%d %H:%M')}")
    log(meta)
    rows = []
    sections = {"obstacle": obstacle_section, "american": american_section}
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    for name in args.sections:
        rows += sections[name](args, log)
        with open(args.out + ".csv", "w", newline="") as f:     # after each section: partial results survive
            w = csv.DictWriter(f, fieldnames=FIELDS, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
        with open(args.out + ".md", "w") as f:
            f.write(markdown(rows, meta) + "\n")
    log(f"\nwrote {args.out}.csv and {args.out}.md")


if __name__ == "__main__":
    main()
