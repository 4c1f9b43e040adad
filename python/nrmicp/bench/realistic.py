"""The default ``nrmicp bench``: what each digit costs on realistic problems at realistic sizes.

    nrmicp bench [--scenes obstacle_2d,obstacle_3d,thermoforming_2d,two_sided_2d,american_put] [--budget 30]
                 [--small] [--out bench-out]

Scenes (nrmicp.scenes): the 2D membrane obstacle at n = 261,121 (m = 511), the 3D obstacle at
n = 103,823 (m = 47), thermoforming 2D (a quasi-variational inequality, ζ a Python callable) at
n = 16,129 (m = 127), the two-sided membrane (a box problem: two obstacles, n = 261,121; the
stationary curves run their box form, PSOR and the QP solver the LCP only), and the American put march (n_space = 3200, 100 Crank–Nicolson steps with
Rannacher start-up: 102 LCPs with one matrix): the scene registry's size "realistic"
(nrmicp.scenes.SIZES). ``--small`` takes its "tiny" sizes, what a test can afford.

Curves: the handful a user chooses between — ``newton`` with the grid's geometric hierarchy and
with ``hierarchy="amg"`` (on the QVI the outer fixed point on ζ, and Newton on the whole ICP with ζ′, the scene's
exact Jacobian as a ``LinearOperator``, the grid's hierarchy: ``newton-jac``), ``nrmgs`` + Anderson, plain ``nrmgs`` (the default stationary member;
``nrmicp bench --family`` compares it with the others), red-black projected SOR (numpy, SOR's optimal ω) and
a QP solver (PIQP, else OSQP, when installed; symmetric LCPs only). x = CPU seconds from the
call (set-up, hierarchy and factorizations included), y = Res. A stationary curve is one solve
whose iterates are timed by a callback (``time.process_time``) until Res < 1e-10 or ``--budget``
CPU seconds; PSOR the same, on its own loop's clock (its red-black colouring and SOR's optimal
ω are found untimed, as a user who knows the grid would); a QP solver is one run per
eps (1e-3, 1e-6, 1e-9), each point its own CPU time. The march: one march per tol (1e-4 … 1e-10),
x = CPU seconds of the whole march, y = the largest Res over its steps.

Outputs in ``--out``: ``realistic.csv`` (scene, curve, seconds, residual per point) and
``work_precision.png`` (the README's figure), each curve labelled at its end.
"""
from __future__ import annotations

import argparse
import csv
import importlib
import os
import time
from typing import Optional

import numpy as np

from .argtypes import positive_float

#: Scene -> (label, builder(small) -> Problem). Sizes: the README's (and --small's for tests).
SCENES = {
    "obstacle_2d": "2D obstacle, n = {n:,}",
    "obstacle_3d": "3D obstacle, n = {n:,}",
    "thermoforming_2d": "thermoforming 2D (QVI), n = {n:,}",
    "two_sided_2d": "two-sided membrane (box), n = {n:,}",
    "american_put": "American put march, n = {n:,}, 102 LCPs",
}
#: Registry sizes (nrmicp.scenes.SIZES): the README's, and --small's for tests.
SIZE = {False: "realistic", True: "tiny"}
TARGET = 1e-10
QP_EPS = (1e-3, 1e-6, 1e-9)
MARCH_TOLS = (1e-4, 1e-6, 1e-8, 1e-10)
N_TIME = 100

#: Curve -> (label, nrmicp.solve options or a peer name).
CURVES = {
    "newton-geo": ("newton, geometric hierarchy", dict(method="newton", hierarchy="geo")),
    "newton-amg": ("newton, hierarchy='amg'", dict(method="newton", hierarchy="amg")),
    "newton-jac": ("newton + ζ′ (LinearOperator)", dict(method="newton", hierarchy="scene", zeta_jacobian="scene")),
    "nrmgs+anderson": ("nrmgs + Anderson", dict(method="nrmgs", accelerate="anderson")),
    "nrmgs": ("nrmgs (stationary)", dict(method="nrmgs")),
    "psor": ("red-black PSOR (numpy)", "psor"),
    "qp": ("QP solver ({solver})", "qp"),
}
#: Scenes whose ζ has a Jacobian (the curve 'newton-jac': Newton on the whole ICP; the others run the
#: outer fixed point on ζ): its maker, problem -> zeta_jacobian.
JACOBIANS = {"thermoforming_2d": "thermoforming.thermoforming_zeta_jacobian"}
COLOURS = {"newton-geo": "#1f77b4", "newton-jac": "#08306b", "newton-amg": "#17becf", "nrmgs+anderson": "#2ca02c",
           "nrmgs": "#98df8a", "psor": "#d62728", "qp": "#9467bd"}


def build(scene: str, small: bool = False):
    from .. import scenes

    if scene not in SCENES:
        raise ValueError(f"unknown scene {scene!r}; choose from {', '.join(SCENES)}")
    return scenes.build(scene, SIZE[small], exact=False)


def _options(problem, options, scene):
    """nrmicp.solve's options of a curve on this scene's problem; None: the curve does not apply (no grid)."""
    opts = dict(options)
    if opts.get("zeta_jacobian") == "scene":   # (run() skips the scenes without one)
        module, name = JACOBIANS[scene].rsplit(".", 1)
        opts["zeta_jacobian"] = getattr(importlib.import_module(f"nrmicp.scenes.{module}"), name)(problem)
    if opts.get("hierarchy") in ("geo", "scene"):   # 'scene': the grid's where it has one, else the default
        P = problem.prolongations()
        if P is None and opts["hierarchy"] == "geo":
            return None
        opts["hierarchy"] = "auto" if P is None else P
    return opts


def _solve_curve(problem, options, budget):
    """One nrmicp solve, its iterates timed in CPU seconds by a callback: [(seconds, Res)]."""
    import nrmicp

    points = []
    t0 = time.process_time()

    def callback(intermediate_result):
        points.append((time.process_time() - t0, float(intermediate_result.residual)))
        if points[-1][0] > budget:
            raise StopIteration

    nrmicp.solve(problem.A, problem.q, problem.zeta, upper=getattr(problem, "upper", None), tol=TARGET,
                 maxiter=10**6, callback=callback, **{**problem.solver_options, **options})
    return points  # the iterates (not the returned best one: a solve cut by the budget may return its start)


def _psor_curve(problem, budget):
    from . import peers

    A, q, c = peers.shifted_lcp(problem)
    colour, omega = peers.colours(A), peers.sor_omega(A)  # untimed: a user who knows the grid knows them
    out = peers.psor(A, q, c, TARGET, omega=omega, colour=colour, maxiter=10**7, history=True,
                      time_limit=budget, clock=time.process_time)
    h = out["history"]
    return list(zip(h["seconds"], h["residual"]))


def _qp_solver():
    from . import peers

    have = [s for s in peers.QP_SOLVERS if peers.installed(s)]
    return have[0] if have else None


def _qp_point(solver, A, q, eps, queue):
    from . import peers

    t0 = time.process_time()
    y, _, _ = peers.qp_once(solver, A, q, eps)
    queue.put((time.process_time() - t0, peers._res(A, q, y)))


def _qp_curve(problem, budget):
    """One QP run per eps, each in a child process that is stopped after 4 × ``budget`` seconds of
    wall time (an interior-point factorization in 3D can take many minutes); a stopped run is no
    point of the curve."""
    import multiprocessing as mp

    from . import peers

    solver = _qp_solver()
    A, q, _ = peers.shifted_lcp(problem)
    ctx = mp.get_context("fork")
    points, spent = [], 0.0
    for eps in QP_EPS:
        queue = ctx.Queue()
        child = ctx.Process(target=_qp_point, args=(solver, A, q, eps, queue))
        child.start()
        child.join(4 * budget)  # wall seconds: a loaded machine stretches CPU seconds
        if child.is_alive():
            child.kill()
            child.join()
            break
        if queue.empty():
            break
        points.append(queue.get())
        spent += points[-1][0]
        if spent > budget:
            break
    return points


def _march_curve(problem, curve, small):
    """The American put march per tol: [(CPU seconds of the march, max Res over its steps)]."""
    from . import peers
    from ..scenes.american import _March, _nested_first_step

    import nrmicp

    from ..scenes import parameter

    n_space = parameter("american_put", SIZE[small])
    m = _March(400.0, 100.0, 0.05, 0.2, 1.0, n_space, N_TIME, 2)
    points = []
    if curve == "psor":  # untimed, as on the other scenes
        colour, omega = peers.colours(m.A), peers.sor_omega(m.A)
    for tol in MARCH_TOLS:
        t0 = time.process_time()
        v, worst = m.payoff.copy(), 0.0
        if curve not in ("psor", "qp"):
            label, options = CURVES[curve]
            options = dict(options)
            if options.get("hierarchy") == "geo":
                options.pop("hierarchy")  # the scene's own rule: nested first step, then warm starts
            method = options.pop("method")
            options["tol"] = tol   # set up for the rule the march solves by
            solver = nrmicp.Solver(m.A, method=method, **options)
            first = _nested_first_step(solver, m.A, method, options)
        for step, kind in enumerate(m.steps()):
            q = m.q(kind, v)
            if curve == "psor":
                qs = q + m.A @ m.payoff
                out = peers.psor(m.A, qs, m.payoff, tol, omega=omega, colour=colour, maxiter=10**6)
                v, r = out["z"], out["residual"]
            elif curve == "qp":
                qs = q + m.A @ m.payoff
                o = peers.tune_eps(lambda eps: peers.qp_once(_qp_solver(), m.A, qs, eps), m.A, qs, tol)
                v, r = o["y"] + m.payoff, o["residual"]
            else:
                res = (first if step == 0 else solver).solve(q, zeta=m.payoff, x0=v, tol=tol, maxiter=10**6)
                v, r = np.array(res.z), res.residual
            worst = max(worst, r)
        points.append((time.process_time() - t0, worst))
    return points


def run(scenes=tuple(SCENES), curves=tuple(CURVES), budget=30.0, small=False, progress=print, csv_path=None):
    """-> {scene: (label, {curve: [(seconds, Res)]})}; each curve is appended to ``csv_path`` as
    soon as it is measured."""
    out = {}
    if csv_path:
        write_csv({}, csv_path)
    for scene in scenes:
        problem = build(scene, small)
        label = SCENES[scene].format(n=problem.n)
        found = {}
        for curve in curves:
            name, options = CURVES[curve]
            if curve == "qp":
                solver = _qp_solver()
                sym = abs(problem.A - problem.A.T).max() == 0
                if solver is None or not sym or callable(problem.zeta) or getattr(problem, "upper", None) is not None:
                    continue
            if curve == "psor" and (callable(problem.zeta) or getattr(problem, "upper", None) is not None):
                continue   # (the peers solve the LCP only)
            if "zeta_jacobian" in options and scene not in JACOBIANS:
                continue
            t0 = time.perf_counter()
            if scene == "american_put":
                pts = _march_curve(problem, curve, small)
            elif curve == "psor":
                pts = _psor_curve(problem, budget)
            elif curve == "qp":
                pts = _qp_curve(problem, budget)
            else:
                opts = _options(problem, options, scene)
                if opts is None:
                    continue
                pts = _solve_curve(problem, opts, budget)
            if not pts:  # a QP solver whose first run did not end within its time
                progress(f"{scene} {curve}: no point within the budget")
                continue
            found[curve] = pts
            if csv_path:
                write_csv({scene: (label, {curve: pts})}, csv_path, append=True)
            progress(f"{scene} {curve}: {len(pts)} points, last Res {pts[-1][1]:.2e} at {pts[-1][0]:.2f} CPU s "
                     f"({time.perf_counter() - t0:.1f} s wall)")
        out[scene] = (label, found)
    return out


def curve_label(curve: str, scene: str) -> str:
    label = CURVES[curve][0]
    if curve == "qp":
        label = label.format(solver=_qp_solver())
    if scene == "american_put" and curve == "newton-amg":
        label = "newton, hierarchy='amg' (warm starts, V-cycle inner solves)"
    if scene in JACOBIANS and curve in ("newton-geo", "newton-amg"):
        label += ", no ζ′"   # (the outer fixed point on ζ)
    if scene == "american_put" and curve == "newton-geo":
        label = "newton (nested first step, warm starts, direct solves)"
    return label


CSV_COLUMNS = ("scene", "label", "curve", "point", "cpu_seconds", "residual")


def write_csv(results, path, append=False):
    with open(path, "a" if append else "w", newline="") as f:
        w = csv.writer(f)
        if not append:
            w.writerow(CSV_COLUMNS)
        for scene, (label, found) in results.items():
            for curve, pts in found.items():
                for i, (s, r) in enumerate(pts):
                    w.writerow((scene, label, curve, i, f"{s:.6g}", f"{r:.6g}"))


def read_csv(paths):
    """The results of one or more realistic.csv files (later files replace a scene's curves)."""
    out = {}
    for path in paths:
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                label, found = out.setdefault(row["scene"], (row["label"], {}))
                pts = found.setdefault(row["curve"], [])
                if row["point"] == "0":
                    pts.clear()
                pts.append((float(row["cpu_seconds"]), float(row["residual"])))
    return out


def _spread(ys, gap):
    """Label heights (log10) pushed apart by at least `gap`, keeping their order."""
    order = np.argsort(ys)
    out = np.array(ys, dtype=float)
    for a, b in zip(order[:-1], order[1:]):
        if out[b] - out[a] < gap:
            out[b] = out[a] + gap
    return out


def plot(results, path, dpi=100):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    k = len(results)
    cols = 2 if k > 1 else 1
    rows = (k + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(11, 4.2 * rows), squeeze=False)
    for ax, (scene, (label, found)) in zip(axes.flat, results.items()):
        ends = []
        for curve, pts in found.items():
            s = np.maximum([p[0] for p in pts], 1e-4)
            r = np.maximum([p[1] for p in pts], 1e-16)
            style = dict(marker="o", ms=4) if scene == "american_put" or curve == "qp" or len(pts) < 8 else {}
            ax.loglog(s, r, color=COLOURS.get(curve, "k"), lw=2, **style)
            ends.append((curve, s[-1], r[-1]))
        ax.axhline(TARGET, color="0.6", lw=0.8, ls=":")
        ax.annotate("target", (1, TARGET), xycoords=("axes fraction", "data"), xytext=(-4, 3),
                    textcoords="offset points", ha="right", fontsize=8, color="0.5")
        lo, hi = ax.get_xlim()
        ax.set_xlim(lo, hi * 12)  # room for the labels
        ylo, yhi = ax.get_ylim()
        span = np.log10(yhi) - np.log10(ylo)
        heights = np.asarray(_spread([np.log10(e[2]) for e in ends], 0.09 * span), dtype=float)
        if len(heights):   # labels spread above the top would run into the title
            heights -= max(0.0, heights.max() - (np.log10(yhi) - 0.05 * span))
        for (curve, x, y), hy in zip(ends, heights):
            ax.annotate(curve_label(curve, scene), (x, y), xytext=(x * 1.25, 10 ** hy), fontsize=9,
                        color=COLOURS.get(curve, "k"), va="center",
                        arrowprops=dict(arrowstyle="-", color="0.75", lw=0.5))
        ax.set_title(label, fontsize=11)
        ax.set_xlabel("CPU seconds" + (" (whole march)" if scene == "american_put" else ""), fontsize=9)
        ax.set_ylabel("Res" + (" (worst step)" if scene == "american_put" else ""), fontsize=9)
        ax.tick_params(labelsize=8)
        ax.grid(True, which="major", lw=0.3, color="0.85")
    for ax in list(axes.flat)[k:]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def _parser(prog):
    p = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0],
                                epilog="'--family' runs the family sweep on Bai's matrices instead (see --family --help).")
    p.add_argument("--scenes", default=",".join(SCENES), help=f"comma-separated from {', '.join(SCENES)}")
    p.add_argument("--curves", default=",".join(CURVES), help=f"comma-separated from {', '.join(CURVES)}")
    p.add_argument("--budget", type=positive_float, default=30.0, help="CPU seconds per curve (default 30)")
    p.add_argument("--small", action="store_true", help="small sizes (seconds; for tests)")
    p.add_argument("--out", default="bench-out", help="output directory (default bench-out/)")
    p.add_argument("--plot", nargs="+", metavar="CSV", help="only draw the figure from these realistic.csv files")
    return p


def main(argv: Optional[list] = None, prog: str = "nrmicp bench") -> int:
    a = _parser(prog).parse_args(argv)
    scenes = [s for s in a.scenes.split(",") if s]
    curves = [c for c in a.curves.split(",") if c]
    for s in scenes:
        if s not in SCENES:
            raise SystemExit(f"{prog}: unknown scene {s!r}; choose from {', '.join(SCENES)}")
    for c in curves:
        if c not in CURVES:
            raise SystemExit(f"{prog}: unknown curve {c!r}; choose from {', '.join(CURVES)}")
    os.makedirs(a.out, exist_ok=True)
    if a.plot:
        try:
            results = read_csv(a.plot)
        except (OSError, KeyError, ValueError, csv.Error) as exc:
            raise SystemExit(f"{prog}: --plot: cannot read a realistic.csv from {' '.join(a.plot)}: "
                             f"{type(exc).__name__}: {exc}") from None
        if not results:
            raise SystemExit(f"{prog}: --plot: no rows of a realistic.csv in {' '.join(a.plot)}")
        results = {s: results[s] for s in SCENES if s in results}
    else:
        results = run(scenes, curves, a.budget, a.small, csv_path=os.path.join(a.out, "realistic.csv"))
    try:
        plot(results, os.path.join(a.out, "work_precision.png"))
    except ImportError:
        print("matplotlib is not installed: pip install nrmicp[plot] draws work_precision.png")
    print(f"wrote {a.out}/realistic.csv and {a.out}/work_precision.png")
    return 0
