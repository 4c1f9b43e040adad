#!/usr/bin/env python
"""nrmicp against what a user would otherwise use, measured side by side in one run.

    python benchmarks/run_peers.py --sizes 1e4 1e5 --out bench-out/peers.csv
    python benchmarks/run_peers.py --scale --out bench-out/scale.csv

Scenes (symmetric M-matrix LCPs, so each is also the convex QP min 1/2 z'Az + q'z, z >= 0):

* ``obstacle0`` — the membrane over a paraboloid obstacle (nrmicp.scenes.obstacle_2d) on an
  m x m grid, multiplied through by h^2 and shifted to a pure LCP in y = z - psi:
  A = 5-point Laplacian with entries 4, -1 (mu = 0), q = A psi. Multiplying by h^2 keeps the
  absolute Res targets meaningful (with the 1/h^2 scaling, roundoff in Az alone is ~1e-7 at
  n = 1e6).
* ``bai4`` — Bai's symmetric test LCP, A = blocktridiag(-I, tridiag(-1, 4, -1), -I) + 4 I
  (nrmicp.scenes.bai(m, mu=4)).

The scenes come from nrmicp.scenes, or, when nrmicp is not installed (--allow-no-nrmicp),
from the source tree's python/nrmicp/scenes, which builds its matrices without the compiled
core (the CSV says which).

Every peer is timed wall-clock from the same (A, q) to Res(z) = ||min(Az + q, z)||_2 below the
target; claims are ratios against nrmicp measured in the same run, never absolute timings.
"""
from __future__ import annotations

import argparse
import csv
import importlib
import importlib.util
import json
import math
import os
import resource
import subprocess
import sys
import time

import numpy as np
import scipy.sparse as sp

HERE = os.path.dirname(os.path.abspath(__file__))

import qp_peers  # noqa: E402  (this directory is on sys.path when a script here runs)
import scipy_modulus  # noqa: E402
from peers_impl import peers  # noqa: E402

REPO = os.path.dirname(HERE)


# ----------------------------------------------------------------------------- scenes
def _load_scenes():
    """nrmicp.scenes if importable, else the source tree's scenes package loaded standalone."""
    try:
        return importlib.import_module("nrmicp.scenes"), "nrmicp.scenes"
    except Exception:
        pass
    path = os.path.join(REPO, "python", "nrmicp", "scenes", "__init__.py")
    spec = importlib.util.spec_from_file_location(
        "_nrmicp_scenes_src", path, submodule_search_locations=[os.path.dirname(path)])
    mod = importlib.util.module_from_spec(spec)
    sys.modules["_nrmicp_scenes_src"] = mod
    spec.loader.exec_module(mod)
    return mod, "python/nrmicp/scenes (source tree)"


SCENES_MOD, SCENES_SRC = _load_scenes()


def peer_lcp(name, n):
    """(A csr, q, info) of a peer-table scene, from the scene registry (nrmicp.scenes):
    'obstacle0' is obstacle_2d as the h²-scaled pure LCP (scenes.scaled_lcp), 'bai4' Bai's μ = 4 LCP."""
    m = int(round(math.sqrt(n)))
    if name == "obstacle0":
        A, q = SCENES_MOD.scaled_lcp(SCENES_MOD.obstacle_2d(m, exact=False))
        mu = 0.0
    elif name == "bai4":
        mu = 4.0
        P = SCENES_MOD.bai(m, mu=4.0)
        A, q = sp.csr_matrix(P.A), np.asarray(P.q, dtype=float)
    else:
        raise ValueError(name)
    A.sort_indices()
    s = math.pi / (2 * (m + 1))
    lmin, lmax = mu + 8 * math.sin(s) ** 2, mu + 8 * math.cos(s) ** 2
    rho_j = (4 * math.cos(2 * s)) / (4 + mu)     # Jacobi spectral radius of the grid operator
    return A, q, dict(m=m, n=m * m, mu=mu, lmin=lmin, lmax=lmax,
                      psor_omega=2.0 / (1.0 + math.sqrt(1.0 - rho_j**2)))


# ----------------------------------------------------------------------------- nrmicp
def nrmicp_available():
    try:
        import nrmicp  # noqa: F401
        return hasattr(nrmicp, "solve")
    except Exception:
        return False


def run_nrmicp(A, q, method, kw, tol, maxiter):
    import nrmicp
    t0 = time.perf_counter()
    r = nrmicp.solve(A, q, method=method, tol=tol, maxiter=maxiter, **kw)
    t1 = time.perf_counter()
    tim = dict(getattr(r, "timings", None) or {})
    return dict(seconds=t1 - t0, nit=int(r.nit), res=float(scipy_modulus.residual(A, q, r.z)),
                res_reported=float(r.residual), status=r.status.name.lower(),
                success=bool(r.success), timings=tim, result=r)


# ----------------------------------------------------------------------------- tuning
def tune_nrmsor(A, q, tol, log):
    """Pick alpha for nrmsor (Omega2 = D, SPEC default) by iteration count with the scipy
    implementation (same iterations as nrmicp) at the smallest size. alpha stays below 2:
    at alpha = 2.2 the scipy loop still converges on obstacle0 (n = 1e4, 4189 iterations)
    but Res rises for a while first and nrmicp stops with STAGNATED after 51. Omega2 = c D
    with c < 1 (violating Theorem 4.2's Omega2 >= D Omega1) diverged in every trial on
    these scenes, so only alpha is tuned."""
    best = None
    for a in (1.0, 1.2, 1.4, 1.6, 1.8, 1.9, 1.95):
        lim = 200_000 if best is None else 2 * best[0] + 10
        o = scipy_modulus.ScipyNRM(A, "nrmsor", alpha=a).solve(q, tol=tol, maxiter=lim)
        nit = o["nit"] if o["success"] else math.inf
        if best is None or nit < best[0]:
            best = (nit, a)
        log(f"    tune nrmsor alpha={a}: nit={nit} ({o['status']})")
    return best


# ----------------------------------------------------------------------------- main run
FIELDS = ["scene", "scenes_source", "mu", "n", "nnz", "target", "peer", "family", "method",
          "setting", "qp_eps", "status", "nit", "nit_nrmicp", "nit_match", "res", "seconds",
          "setup_seconds", "ratio_vs_nrmicp_same", "ratio_vs_best_nrmicp", "note"]


def main_run(args):
    log = lambda s: print(s, flush=True)  # noqa: E731
    have = nrmicp_available()
    if not have and not args.allow_no_nrmicp:
        sys.exit("nrmicp is not importable (pass --allow-no-nrmicp to run the peers alone)")
    sizes = sorted(int(float(s)) for s in args.sizes)
    rows = []
    hist = {}         # (scene, target, peer) -> [(n, seconds)]
    skip_note = {}
    seeded_alpha = {}
    if args.seed_csv:
        # continue an earlier run at larger sizes: its timings feed the skip estimates and its
        # tuned nrmsor alpha is reused (a QP solver's eps is always tuned afresh: see below)
        import re
        with open(args.seed_csv) as f:
            for r in csv.DictReader(f):
                fam, peer, meth = r["family"], r["peer"], r["method"]
                name = f"{peer}:{meth}" if fam in ("nrmicp", "scipy") else peer
                key = (r["scene"], float(r["target"]), name)
                if r["status"] in ("converged", "reached") and r["seconds"]:
                    hist.setdefault(key, []).append((int(r["n"]), float(r["seconds"])))
                elif r["status"].startswith("skipped") or r["status"] in (
                        "time_limit", "max_iterations", "diverged"):
                    skip_note[key] = f"skipped (at n={r['n']}: {r['status']})"
                if fam == "nrmicp" and meth == "nrmsor":
                    seeded_alpha[r["scene"]] = float(re.search(r"alpha=([0-9.]+)", r["setting"]).group(1))
        for v in hist.values():
            v.sort()
    t_run = time.perf_counter()
    for scene in args.scenes:
        tuned = dict(alpha_default=seeded_alpha[scene]) if scene in seeded_alpha else None
        for n in sizes:
            A, q, info = peer_lcp(scene, n)
            n = info["n"]
            # mu = 0: iterations grow ~n and time per iteration grows faster than n once the
            # working set leaves cache (measured 1e4 -> 1e5: exponent 2.2-2.5)
            default_p = 2.5 if info["mu"] == 0 else 1.3
            log(f"\n== {scene} n={n} nnz={A.nnz} (scenes: {SCENES_SRC})")
            if tuned is None:
                t0 = time.perf_counter()
                bd = tune_nrmsor(A, q, min(args.targets), log if args.verbose else (lambda s: None))
                tuned = dict(alpha_default=bd[1])
                log(f"  nrmsor tuning at n={n} ({time.perf_counter() - t0:.1f}s): "
                    f"alpha={bd[1]} (nit {bd[0]} at tol {min(args.targets):g})")
            methods = [
                ("nrmgs", "nrmgs", {}, "SPEC defaults"),
                ("nrmsor", "nrmsor", dict(alpha=tuned["alpha_default"]),
                 f"alpha={tuned['alpha_default']} (tuned), Omega2=D"),
                ("nrmgs+aa", "nrmgs", dict(accelerate="anderson"), "accelerate='anderson' (m=5); no scipy twin"),
                ("nrm", "nrm", {}, "SPEC defaults (Omega1=Omega2=I)"),
                ("nrmm", "nrmm", dict(alpha=math.sqrt(info["lmin"] * info["lmax"])),
                 f"alpha=sqrt(lmin*lmax)={math.sqrt(info['lmin'] * info['lmax']):.4g}"),
            ]
            methods = [m for m in methods if m[0] in args.methods]
            for target in args.targets:
                local = []

                def add(peer, family, method, setting, out, nit_nrmicp=None, note=""):
                    row = dict(scene=scene, scenes_source=SCENES_SRC, mu=info["mu"], n=n,
                               nnz=A.nnz, target=target, peer=peer, family=family,
                               method=method, setting=setting, note=note,
                               nit_nrmicp=nit_nrmicp, **out)
                    if nit_nrmicp is not None and out.get("nit") is not None:
                        row["nit_match"] = int(out["nit"]) == int(nit_nrmicp)
                    local.append(row)
                    return row

                def should_skip(key):
                    est = peers.estimate(hist.get(key, []), n, default_p)
                    if key in skip_note:
                        return skip_note[key]
                    if est is not None and est > args.budget:
                        return f"skipped (est. > {est:.0f}s)"
                    return None

                def record(key, out):
                    if out.get("status") in ("converged", "reached") or out.get("ok"):
                        hist.setdefault(key, []).append((n, out["seconds"]))
                    else:
                        skip_note[key] = f"skipped (failed at n={n})"

                nrm_times = {}
                for label, meth, kw, setting in methods:
                    # ---- nrmicp
                    key = (scene, target, "nrmicp:" + label)
                    nit_ref = None
                    sk = should_skip(key)
                    if not have:
                        sk = "nrmicp not importable"
                    if sk:
                        add("nrmicp", "nrmicp", label, setting, dict(status=sk))
                    else:
                        o = run_nrmicp(A, q, meth, kw, target, args.maxiter)
                        ok = o["success"] and o["res"] < target
                        st = "converged" if ok else o["status"]
                        tim = o["timings"]
                        add("nrmicp", "nrmicp", label, setting,
                            dict(status=st, nit=o["nit"], res=o["res"], seconds=o["seconds"],
                                 setup_seconds=tim.get("setup", 0.0)),
                            note=f"timings={json.dumps({k: round(v, 4) for k, v in tim.items()})}")
                        record(key, dict(status=st, seconds=o["seconds"]))
                        if ok:
                            nrm_times[label] = o["seconds"]
                            nit_ref = o["nit"]
                        log(f"  [{target:g}] nrmicp {label:10s} nit={o['nit']:7d} "
                            f"t={o['seconds']:.3f}s res={o['res']:.2e} {st}")
                    # ---- plain scipy, same method (Anderson has no plain-scipy twin)
                    for form in ([] if kw.get("accelerate") else args.scipy_forms):
                        peer = "scipy" if form == "defect" else "scipy-paper"
                        key = (scene, target, f"{peer}:{label}")
                        sk = should_skip(key)
                        if sk:
                            add(peer, "scipy", label, setting, dict(status=sk), nit_ref)
                            continue
                        s = scipy_modulus.ScipyNRM(A, meth, form=form, **kw)
                        o = s.solve(q, tol=target, maxiter=args.maxiter,
                                    time_limit=1.5 * args.budget)
                        o["seconds"] = o["total"]
                        o["setup_seconds"] = o["t_setup"]
                        o["res"] = o["residual"]
                        row = add(peer, "scipy", label, setting,
                                  {k: o[k] for k in ("status", "nit", "res", "seconds",
                                                     "setup_seconds")}, nit_ref,
                                  note=f"factor_nnz={o['factor_nnz']}")
                        record(key, o)
                        log(f"  [{target:g}] {peer:11s} {label:10s} nit={o['nit']:7d} "
                            f"(nrmicp {nit_ref}) t={o['seconds']:.3f}s res={o['res']:.2e} "
                            f"{o['status']}{'' if row.get('nit_match', True) else '  NIT MISMATCH'}")
                # ---- projected SOR (red-black, optimal omega for the grid)
                if "psor" in args.peers:
                    key = (scene, target, "psor")
                    w = info["psor_omega"]
                    setting = f"red-black, omega={w:.4f} (optimal for the grid)"
                    sk = should_skip(key)
                    if sk:
                        add("psor", "psor", "", setting, dict(status=sk))
                    else:
                        o = qp_peers.psor_solve(A, q, target, omega=w,
                                                colors=qp_peers.grid_colors(info["m"]),
                                                maxiter=args.maxiter, time_limit=1.5 * args.budget)
                        add("psor", "psor", "", setting,
                            dict(status=o["status"], nit=o["iters"], res=o["residual"],
                                 seconds=o["seconds"]))
                        record(key, o)
                        log(f"  [{target:g}] psor        sweeps={o['iters']:7d} "
                            f"t={o['seconds']:.3f}s res={o['residual']:.2e} {o['status']}")
                # ---- QP solvers
                for name in qp_peers.QP_SOLVERS:
                    if name not in args.peers:
                        continue
                    key = (scene, target, name)
                    sk = should_skip(key)
                    if sk:
                        add(name, "qp", "", "", dict(status=sk))
                        continue
                    # Tuned from scratch at every size (eps = target, then 10x tighter until Res
                    # reaches it): reusing the previous size's eps pushed PIQP at n = 65,536,
                    # Res < 1e-8 into its iteration limit (500 iterations, 164 s), where a fresh
                    # tuning stalls at 1.1e-8 after about 6 s. The eps used is in column qp_eps.
                    o = qp_peers.solve_to_target(name, A, q, target, eps_start=target,
                                                 time_budget=3 * args.budget)
                    st = "reached" if o["reached"] else f"not reached ({o['status']})"
                    tries = "; ".join(f"{e:g}->{r:.1e}" for e, r, _ in o["attempts"])
                    add(name, "qp", "", o["setting"],
                        dict(status=st, nit=o["iters"], res=o["res"], seconds=o["seconds"], qp_eps=f"{o['eps']:g}"),
                        note=f"solver status {o['status']}; tried eps->Res: {tries}; "
                             f"tuning total {o['tuning_seconds']:.2f}s")
                    if o["reached"]:
                        hist.setdefault(key, []).append((n, o["seconds"]))
                    else:
                        hist.setdefault(key, []).append((n, o["tuning_seconds"]))
                    log(f"  [{target:g}] {name:11s} {o['setting']:55s} t={o['seconds']:.3f}s "
                        f"res={o['res']:.2e} {st}")
                # ---- ratios
                best = min(nrm_times.values()) if nrm_times else None
                for r in local:
                    t = r.get("seconds")
                    if t is None or not isinstance(t, float) or not math.isfinite(t):
                        continue
                    if r["family"] == "scipy" and r["method"] in nrm_times:
                        r["ratio_vs_nrmicp_same"] = t / nrm_times[r["method"]]
                    if best:
                        r["ratio_vs_best_nrmicp"] = t / best
                rows.extend(local)
                write_csv(args.out, rows, quiet=True)   # keep partial results
    log(f"\ntotal run time {time.perf_counter() - t_run:.0f}s")
    write_csv(args.out, rows)
    print_tables(rows)


def write_csv(path, rows, quiet=False):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=FIELDS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(r)
    if not quiet:
        print(f"wrote {path}")


def _fmt(x, spec):
    if x is None or x == "":
        return ""
    try:
        return format(float(x), spec)
    except (TypeError, ValueError):
        return str(x)


def print_tables(rows):
    groups = {}
    for r in rows:
        groups.setdefault((r["scene"], r["target"]), []).append(r)
    for (scene, target), rs in groups.items():
        print(f"\n### {scene} (mu={rs[0]['mu']:g}), Res target {target:g}\n")
        print("| n | peer | method / setting | time s | × nrmicp (same method) | × best nrmicp "
              "| nit (nrmicp) | Res | status |")
        print("|---|---|---|---|---|---|---|---|---|")
        for r in rs:
            ms = r["method"] if r["family"] in ("nrmicp", "scipy") else r["setting"]
            if r["family"] == "nrmicp" or r["peer"] == "psor":
                ms = f"{r['method']} {r['setting']}".strip()
            nit = "" if r.get("nit") is None else str(r["nit"])
            if r.get("nit_nrmicp") is not None and r.get("nit") is not None:
                nit += f" ({r['nit_nrmicp']})" + ("" if r.get("nit_match") else " MISMATCH")
            print(f"| {r['n']} | {r['peer']} | {ms} | {_fmt(r.get('seconds'), '.3f')} | "
                  f"{_fmt(r.get('ratio_vs_nrmicp_same'), '.1f')} | "
                  f"{_fmt(r.get('ratio_vs_best_nrmicp'), '.1f')} | {nit} | "
                  f"{_fmt(r.get('res'), '.1e')} | {r.get('status', '')} |")


# ----------------------------------------------------------------------------- scale mode
def run_case(spec):
    """Child process: one case, prints one JSON line with its own peak RSS."""
    A, q, info = peer_lcp(spec["scene"], spec["n"])
    out = dict(spec, n=info["n"], nnz=A.nnz)
    meth, kw = spec["method"], dict(spec.get("kw", {}))
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    if spec["peer"] == "baseline":
        out.update(seconds=0.0, nit=0)
    elif spec["peer"] == "nrmicp":
        o = run_nrmicp(A, q, meth, kw, spec["tol"], spec["maxiter"])
        r = o.pop("result")
        tim = o["timings"]
        nnz = None
        for attr in ("factor_nnz", "nnz_factor", "nnz_L"):
            nnz = nnz or getattr(r, attr, None) or tim.get(attr)
        out.update(seconds=o["seconds"], nit=o["nit"], res=o["res"], status=o["status"],
                   t_setup=tim.get("setup", 0.0),
                   t_iter=tim.get("iterations", o["seconds"]), timings=tim, factor_nnz=nnz)
    else:
        s = scipy_modulus.ScipyNRM(A, meth, **kw)
        o = s.solve(q, tol=spec["tol"], maxiter=spec["maxiter"])
        out.update(seconds=o["total"], nit=o["nit"], res=o["residual"], status=o["status"],
                   t_setup=o["t_setup"], t_iter=o["t_iter"], factor_nnz=o["factor_nnz"])
    out["rss_before_mb"] = rss0 / 1024
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print("CASE_JSON " + json.dumps(out, default=str), flush=True)


def main_scale(args):
    sizes = [int(float(s)) for s in (args.scale_sizes or ["1e6", "4e6"])]
    have = nrmicp_available()
    cases = []
    for n in sizes:
        base = dict(scene=args.scale_scene, n=n, tol=args.scale_tol, maxiter=args.maxiter)
        cases.append(dict(base, peer="baseline", method="-"))
        for meth, kw in (("nrmgs", {}), ("nrm", {}), ("nrmm", {})):
            if have:
                cases.append(dict(base, peer="nrmicp", method=meth, kw=kw))
            cases.append(dict(base, peer="scipy", method=meth, kw=kw))
    rows = []
    hist = {}
    for c in cases:
        key = (c["peer"], c["method"])
        est = peers.estimate(hist.get(key, []), c["n"], 1.3)
        if c["peer"] != "baseline" and est is not None and est > args.scale_budget:
            r = dict(c, status=f"skipped (est. > {est:.0f}s)")
            rows.append(r)
            print(f"  {c['peer']:8s} {c['method']:7s} n={c['n']:>8d} {r['status']}", flush=True)
            continue
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, os.path.abspath(__file__), "--_case", json.dumps(c)],
                           capture_output=True, text=True, timeout=args.case_timeout)
        line = [ln for ln in p.stdout.splitlines() if ln.startswith("CASE_JSON ")]
        if p.returncode != 0 or not line:
            r = dict(c, status=f"failed rc={p.returncode}: {p.stderr.strip()[-300:]}")
        else:
            r = json.loads(line[0][len("CASE_JSON "):])
        r["wall_incl_build"] = time.perf_counter() - t0
        if r.get("seconds"):
            hist.setdefault(key, []).append((c["n"], r["seconds"]))
        rows.append(r)
        print(f"  {r['peer']:8s} {r['method']:7s} n={r['n']:>8d} nit={r.get('nit')} "
              f"t={_fmt(r.get('seconds'), '.2f')}s peak={_fmt(r.get('peak_rss_mb'), '.0f')}MB "
              f"{r.get('status', '')}", flush=True)
    base = {r["n"]: r.get("peak_rss_mb", 0.0) for r in rows if r["peer"] == "baseline"}
    fields = ["peer", "method", "n", "nnz", "nit", "seconds", "t_setup", "t_iter",
              "us_per_iter", "ns_per_iter_per_nnzA", "factor_nnz", "ns_per_iter_per_nnz_factor",
              "peak_rss_mb", "extra_rss_mb", "res", "status"]
    for r in rows:
        if r["peer"] == "baseline" or not r.get("nit"):
            continue
        per = r["t_iter"] / r["nit"]
        r["us_per_iter"] = per * 1e6
        r["ns_per_iter_per_nnzA"] = per * 1e9 / r["nnz"]
        if r.get("factor_nnz"):
            r["ns_per_iter_per_nnz_factor"] = per * 1e9 / (r["nnz"] + int(r["factor_nnz"]))
        r["extra_rss_mb"] = r["peak_rss_mb"] - base.get(r["n"], 0.0)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {args.out}")
    print(f"\n### scale: {args.scale_scene}, tol {args.scale_tol:g} "
          f"(peak RSS per subprocess; baseline = scene build only: "
          f"{', '.join(f'n={k}: {v:.0f} MB' for k, v in base.items())})\n")
    print("| peer | method | n | nnz(A) | nit | total s | setup+factor s | µs/iter | "
          "ns/iter/nnz(A) | factor nnz | ns/iter/(nnz(A)+nnz(factor)) | peak RSS MB | "
          "RSS over baseline MB | status |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if r["peer"] == "baseline":
            continue
        print(f"| {r['peer']} | {r['method']} | {r['n']} | {r.get('nnz', '')} | {r.get('nit', '')} | "
              f"{_fmt(r.get('seconds'), '.2f')} | {_fmt(r.get('t_setup'), '.2f')} | "
              f"{_fmt(r.get('us_per_iter'), '.0f')} | {_fmt(r.get('ns_per_iter_per_nnzA'), '.2f')} | "
              f"{r.get('factor_nnz') or ''} | {_fmt(r.get('ns_per_iter_per_nnz_factor'), '.2f')} | "
              f"{_fmt(r.get('peak_rss_mb'), '.0f')} | {_fmt(r.get('extra_rss_mb'), '.0f')} | "
              f"{r.get('status', '')} |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", nargs="+", default=["1e4", "1e5"])
    ap.add_argument("--targets", nargs="+", type=float, default=[1e-6, 1e-8])
    ap.add_argument("--scenes", nargs="+", default=["obstacle0", "bai4"],
                    choices=["obstacle0", "bai4"])
    ap.add_argument("--methods", nargs="+",
                    default=["nrmgs", "nrmsor", "nrmgs+aa", "nrm", "nrmm"])
    ap.add_argument("--peers", nargs="+",
                    default=["psor", "osqp", "clarabel", "piqp", "proxsuite"])
    ap.add_argument("--scipy-forms", nargs="+", default=["defect"],
                    choices=["defect", "paper"])
    ap.add_argument("--budget", type=float, default=120.0,
                    help="skip a peer whose estimated time exceeds this (s)")
    ap.add_argument("--maxiter", type=int, default=1_000_000)
    ap.add_argument("--out", default="bench-out/peers.csv")
    ap.add_argument("--allow-no-nrmicp", action="store_true")
    ap.add_argument("--seed-csv", help="CSV of an earlier run at smaller sizes: seeds the skip "
                    "estimates, the nrmsor alpha and the QP eps")
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--scale", action="store_true")
    ap.add_argument("--scale-sizes", nargs="+")
    ap.add_argument("--scale-scene", default="bai4", choices=["obstacle0", "bai4"])
    ap.add_argument("--scale-tol", type=float, default=1e-8)
    ap.add_argument("--case-timeout", type=float, default=1800)
    ap.add_argument("--scale-budget", type=float, default=300.0,
                    help="--scale: skip a case whose estimated time exceeds this (s)")
    ap.add_argument("--_case", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args._case:
        return run_case(json.loads(args._case))
    if args.scale:
        if args.out == "bench-out/peers.csv":
            args.out = "bench-out/scale.csv"
        return main_scale(args)
    return main_run(args)


if __name__ == "__main__":
    main()
