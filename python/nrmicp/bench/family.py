"""The family sweep (``nrmicp bench --family``; plain ``nrmicp bench`` is the realistic-scene
figure, nrmicp/bench/realistic.py): what each extra digit of accuracy costs in time.

    python -m nrmicp bench --family [--quick] [--scenes ...] [--methods ...] [--peers psor,qp] [--z-updates ...]
                           [--tols ... | --tol-min 1e-12 --tol-max 1e-2] [--size small]
                           [--repeat 1] [--maxiter 10000] [--out bench-out]

For every scene, method and z-update it sweeps ``tol`` (default 1e-2, 1e-3, …, 1e-12). The
methods are nrmicp's members, ``newton`` (its 'iterations' are Newton steps on the finest level;
``hierarchy='auto'``) and any member with ``+polish`` (``polish=True``: Newton steps on the
settled active set, to the rounding floor); next to them, in the same diagrams, the peers a user would otherwise
reach for (nrmicp/bench/peers.py): red-black projected SOR in numpy with SOR's optimal ω, and a QP
solver (PIQP, else OSQP) on min ½zᵀAz + qᵀz, z ≥ 0, its eps tightened from tol by 10× until
Res < tol (the time of that last run). The peers run on the scenes that are LCPs (ζ constant),
the QP solver on the symmetric ones; one that is not installed is skipped with a note. It
records, per tol:

- ``seconds``: wall time of one ``nrmicp.solve`` call (set-up, factorizations and iterations;
  building the scene and its exact reference is excluded), best of ``--repeat`` runs; for
  PSOR the row blocks and the sweeps (the colouring and ω are found once per scene, untimed),
  for a QP solver its matrices, set-up, factorization and solve;
  ``setup_seconds``, ``factorization_seconds`` and ``iteration_seconds`` are the core's own
  ``result.timings`` of the best run, reported separately;
- ``iterations`` (``result.nit``), ``residual`` (Res of the returned z), ``status``;
- ``error`` = max|z − z_exact| when the scene knows its exact discrete solution.

How the numbers are obtained (and why they are not distorted):

- Times come from *separate solves per tol*, with no callback and no history recording, so
  no Python call per iteration is timed.
- Errors come from the *same* solves: the iteration does not depend on tol except where it
  stops, so the z a solve with tol t returns is exactly the first iterate with Res < t —
  the same z a callback would capture in one long run, without the callback's cost.
- When a solve does not converge (stagnated, max_iterations, diverged), every smaller tol
  would run the identical iteration and stop at the same point for the same reason (the
  stopping tests other than ``Res < tol`` do not involve tol), so those rows reuse that
  solve and say so in ``reused_from_tol``; this keeps slow failures from being paid 11 times.
- One extra run per case at the smallest tol with ``record_history=True`` (no callback)
  gives Res at every iterate: drawn as a faint line behind the markers of the
  work–precision diagram (where it flattens is the accuracy floor) and, for one scene, the
  convergence-history figure. Its seconds are the core's clock since the iteration started,
  shifted by the set-up and factorization time of that run.

Outputs in ``--out`` (default ``bench-out/``): ``work_precision.csv``, ``work_precision.png``
(y = Res), ``work_precision_error.png`` (y = max|z − z_exact|), ``convergence_history.png``,
``history.csv`` (the history-scene's iterates) and ``summary.txt`` (also printed): per scene
and case the iterations per extra digit (Theil–Sen slope of the iteration count against
−log10 tol over the converged rows) and the seconds per digit (that times the seconds per
iteration, the least over the converged runs on the core's clock; "noise" when they are all
too short to time; "-" for newton, a polished member and a QP solver, which do not buy digits
one at a time), the seconds to reach the tols nearest 1e-6 and 1e-10, the best Res reached,
and the fastest case at 1e-6 and 1e-10, peers included. The CSV and the
summary are written before any figure, and record nrmicp's version and backends, the numpy,
scipy and Python versions, the CPU model and the cores. Without matplotlib the run ends after
them with a line saying that ``pip install nrmicp[plot]`` draws the figures.

The horizontal line in every panel is the rounding level of the residual,
eps·‖ |A||z*| + |q| ‖₂ (z* the exact or the best solution): w = Az + q cannot be evaluated much
more accurately than that, so Res stops decreasing within a small factor of it (rounding errors
partly cancel, and where the obstacle is active min(w, g) picks g, which is computed more
accurately) — a scale, not a sharp bound. An iteration that reaches it ends STAGNATED; a tol
below it cannot be met by any method.
"""
from __future__ import annotations

import argparse
import csv
import math
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .argtypes import int_at_least, positive_float

# --------------------------------------------------------------------------- scenes

#: Scenes of the default sweep, in plotting order.
DEFAULT_SCENES = ("bai_sym_lcp", "bai_nonsym_lcp", "bai_sym_icp", "bai_nonsym_icp",
                  "obstacle_2d", "thermoforming_2d", "impulse_control", "american_put")
#: Further scenes that may be named with --scenes.
#: The box scenes among them (an upper bound or free unknowns) are run by method newton only.
EXTRA_SCENES = ("bai_sym_affine", "obstacle_1d", "thermoforming_1d", "obstacle_3d", "convection_obstacle",
                "two_sided_1d", "two_sided_2d", "elastic_contact_p1", "elastic_contact_p2", "game_put")
SCENES = DEFAULT_SCENES + EXTRA_SCENES

#: Default methods: nrmaor and nrmsor with their default parameters (α = β = 1) are nrmgs.
#: 'nrmgs+polish' is nrmgs with polish=True (Newton steps on the settled active set, to the rounding floor).
DEFAULT_METHODS = ("nrm", "nrmm", "nrmgs", "nrmj", "mms", "two_sweep", "newton", "nrmgs+polish")
QUICK_METHODS = ("nrmgs", "nrmm", "newton", "nrmgs+polish")
QUICK_TOLS = (1e-2, 1e-4, 1e-6, 1e-8)
#: Target tolerances of the "fastest method" summary.
TARGETS = (1e-6, 1e-10)

#: The sizes (--size) are the scene registry's (nrmicp.scenes.SIZES): 'tiny' is what --quick uses.
#: 'small' is chosen so that the default sweep takes about a minute on one core yet every solve
#: takes well over the ~0.1 ms Python overhead of a call: Bai's iteration counts do not grow with
#: n (so n = 4096), while the PDE scenes' grow like h⁻² (so 32 × 32 grids already take ~10³
#: iterations; 'medium' quadruples them).
from ..scenes._registry import SIZES  # noqa: E402

_LABELS = {
    "bai_sym_lcp": "Bai, symmetric, LCP",
    "bai_nonsym_lcp": "Bai, nonsymmetric, LCP",
    "bai_sym_icp": "Bai, symmetric, ICP ζ = ½ sin z + s",
    "bai_nonsym_icp": "Bai, nonsymmetric, ICP ζ = ½ sin z + s",
    "bai_sym_affine": "Bai, symmetric, affine ICP",
    "obstacle_1d": "obstacle 1D (shifted LCP)",
    "obstacle_2d": "obstacle 2D membrane (shifted LCP)",
    "obstacle_3d": "obstacle 3D, 7-point (shifted LCP)",
    "convection_obstacle": "upwind convection–diffusion obstacle (nonsymmetric)",
    "thermoforming_1d": "thermoforming 1D (QVI)",
    "thermoforming_2d": "thermoforming 2D (nonlocal QVI)",
    "impulse_control": "impulse control (QVI, Lipschitz 1)",
    "american_put": "American put, one step (shifted LCP)",
    "two_sided_1d": "two-sided membrane 1D (box)",
    "two_sided_2d": "two-sided membrane 2D (box)",
    "elastic_contact_p1": "elastic contact, P1 (free unknowns)",
    "elastic_contact_p2": "elastic contact, P2 (free unknowns)",
    "game_put": "game put, one step (box)",
}


def scene_label(name: str) -> str:
    return _LABELS.get(name, name)


# --------------------------------------------------------------------------- running

#: Where and with what the numbers were taken: repeated in every row of the CSV (so the file
#: stays one plain table) and on the first line of summary.txt.
ENV_COLUMNS = ("nrmicp", "backends", "numpy", "scipy", "python", "cpu", "cores")
CSV_COLUMNS = ("scene", "size", "n", "method", "z_update", "z_update_used", "tol", "status", "converged",
               "seconds", "setup_seconds", "factorization_seconds", "iteration_seconds", "iterations",
               "linear_solves", "residual", "error", "repeat", "setting", "reused_from_tol") + ENV_COLUMNS


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith(("model name", "hardware", "cpu model")):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def environment() -> dict:
    """nrmicp's version and backends, numpy/scipy/Python versions, CPU model and cores."""
    import scipy

    import nrmicp

    try:
        usable = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        usable = os.cpu_count()
    return dict(nrmicp=nrmicp.__version__,
                backends="+".join(k for k, v in nrmicp.backends().items() if v),
                numpy=np.__version__, scipy=scipy.__version__, python=platform.python_version(),
                cpu=f"{_cpu_model()} ({platform.system()} {platform.machine()})",
                cores=f"{usable} usable of {os.cpu_count()}")


def environment_line(env: dict) -> str:
    return (f"nrmicp {env['nrmicp']} (backends {env['backends']}); numpy {env['numpy']}, scipy {env['scipy']}, "
            f"Python {env['python']}; {env['cpu']}, {env['cores']} cores")


@dataclass
class Case:
    """One (scene, method, z-update) line of the diagram."""
    scene: str
    method: str
    z_update: str
    z_update_used: str = ""
    rows: list = field(default_factory=list)
    history: dict = None          # iteration, seconds (shifted by set-up), residual
    history_status: str = ""
    tool: str = "nrmicp"          # or "peer"
    setting: str = ""             # a peer's tuning (PSOR's omega, the QP solver and its version)
    best: tuple = None            # (Res, z) of the least Res among the rows

    @property
    def label(self) -> str:
        if self.tool == "peer" or not self.z_update_used or self.z_update_used == "-":
            return self.method
        return f"{self.method} / {self.z_update_used}"

    @property
    def linear(self) -> bool:
        """A member that buys digits one at a time (linear convergence): per-digit costs apply.
        Newton (superlinear), a polished member (one Newton step jumps to rounding level) and the
        QP solvers (eps tuned per tol) are compared by their seconds to each tol instead."""
        base, kw = split_method(self.method)
        return (base != "newton" and not kw) if self.tool == "nrmicp" else self.method == "psor"


class Progress:
    """A one-line progress bar on stderr (a line per 10 % when stderr is not a terminal)."""

    def __init__(self, total: int, enabled: bool = True, width: int = 30):
        self.total, self.done, self.width = max(int(total), 1), 0, width
        self.enabled = enabled
        self.tty = enabled and sys.stderr.isatty()
        self.t0 = time.perf_counter()
        self._last_decile = -1

    def step(self, k: int = 1, what: str = "") -> None:
        self.done = min(self.done + k, self.total)
        if not self.enabled:
            return
        frac = self.done / self.total
        elapsed = time.perf_counter() - self.t0
        if self.tty:
            fill = int(round(frac * self.width))
            bar = "#" * fill + "." * (self.width - fill)
            sys.stderr.write(f"\r[{bar}] {self.done}/{self.total} {elapsed:6.1f}s {what[:40]:<40}")
            sys.stderr.flush()
        else:
            decile = int(frac * 10)
            if decile != self._last_decile:
                self._last_decile = decile
                sys.stderr.write(f"bench: {100 * frac:3.0f}% ({self.done}/{self.total}, {elapsed:.1f}s)\n")
                sys.stderr.flush()

    def close(self) -> None:
        if self.tty:
            sys.stderr.write("\n")
            sys.stderr.flush()


def _z_update_used(problem, z_update: str, method: str = "") -> str:
    method = split_method(method)[0]
    if method == "newton":
        return "-"  # Newton recovers z from its linear solves: no z-update to choose
    if z_update != "auto":
        return z_update
    # A scene may say it needs a z-update (impulse control: Lipschitz-1 ζ, only 'solve'
    # converges; Problem.solver_options). Otherwise SPEC's 'auto': explicit, except 'solve' on an
    # ICP with a non-constant ζ for nrm (paper's Omega2 = I) and the baseline mms.
    needed = getattr(problem, "solver_options", {}).get("z_update")
    if needed:
        return needed
    from .. import _core
    icp = problem.zeta is not None and not isinstance(problem.zeta, np.ndarray)
    omega2_given = "omega2" in getattr(problem, "solver_options", {})
    if method not in _core.Method.__members__:
        return "explicit"  # no method named (callers always name one)
    return _core.resolved_z_update(getattr(_core.Method, method), omega2_given, icp)


def _status_name(status) -> str:
    return getattr(status, "name", str(status)).lower()


# --- cases: an nrmicp member ('nrmgs'), a member with polish ('nrmgs+polish'), or a peer

#: Peers (not nrmicp) the bench can run next to nrmicp: red-black projected SOR (numpy) and the QP
#: solvers of nrmicp.bench.peers. 'qp' means the first installed of nrmicp.bench.peers.QP_SOLVERS.
PEERS = ("psor", "qp", "piqp", "osqp")
DEFAULT_PEERS = ("psor", "qp")


def split_method(method: str):
    """'nrmgs+polish' -> ('nrmgs', {'polish': True}); 'newton' -> ('newton', {})."""
    base, _, extra = method.partition("+")
    if extra not in ("", "polish"):
        raise ValueError(f"unknown method {method!r}: a method name, optionally with '+polish'")
    return base, ({"polish": True} if extra else {})


def is_peer(method: str) -> bool:
    return method in PEERS


def is_box(problem) -> bool:
    """A scene with an upper bound or free unknowns (ζ with -inf): method newton's only."""
    zeta = problem.zeta
    free = isinstance(zeta, np.ndarray) and not np.all(np.isfinite(zeta))
    return getattr(problem, "upper", None) is not None or free


def _run_nrmicp(problem, method, z_update_used, maxiter):
    """solve(tol, history) for an nrmicp case: the outcome dict run_case records."""
    import nrmicp

    base, kw = split_method(method)
    if getattr(problem, "upper", None) is not None:
        kw = dict(kw, upper=problem.upper)
    if "components" in getattr(problem, "solver_options", {}):   # a vector scene's unknowns, for 'amg'
        kw = dict(kw, components=problem.solver_options["components"])

    def solve(tol, history=False):
        res = nrmicp.solve(problem.A, problem.q, problem.zeta, method=base, tol=tol, maxiter=maxiter,
                           z_update="auto" if z_update_used == "-" else z_update_used, record_history=history, **kw)
        tm = res.timings or {}
        out = dict(z=np.asarray(res.z), status=_status_name(res.status), success=bool(res.success),
                   nit=int(res.nit), residual=float(res.residual), setup=tm.get("setup", ""),
                   factorization=tm.get("factorization", ""), iterations=tm.get("iterations", ""),
                   linear_solves=getattr(res, "linear_solves", ""))
        if history and res.history is not None:
            h = {k: np.asarray(v, dtype=float) for k, v in res.history.items()}
            if getattr(res, "polished", False):  # the polishing step is not in the member's history
                h = {k: np.append(v, x) for (k, v), x in
                     zip(h.items(), (h["iteration"][-1] + 1, out["iterations"] or h["seconds"][-1],
                                     out["residual"]))}
            out["history"] = h
        return out

    return solve


def _run_peer(problem, peer, maxiter):
    """solve(tol, history) for a peer, after its one-off tuning (colouring and ω for PSOR; done
    once per scene outside the timings, as a user who knows the grid would), and its setting."""
    from . import peers

    A, q, c = peers.shifted_lcp(problem)
    if peer == "psor":
        colour, omega = peers.colours(A), peers.sor_omega(A)
        setting = f"omega={omega:.4g}, {colour.max() + 1} colours"

        def solve(tol, history=False):
            return dict(peers.psor(A, q, c, tol, omega=omega, colour=colour, maxiter=maxiter, history=history),
                        setting=setting)
        return solve, setting

    def solve(tol, history=False):
        return peers.qp(peer, A, q, c, tol)
    return solve, f"{peer} {peers.installed(peer)}"


def resolve_peers(names, problems):
    """The peers to run per scene and the notes to print for those that cannot run."""
    from . import peers

    notes, out = [], []
    for p in names:
        if p == "qp":
            have = [s for s in peers.QP_SOLVERS if peers.installed(s)]
            if not have:
                notes.append(f"peer qp skipped: none of {', '.join(peers.QP_SOLVERS)} is installed "
                             "(pip install piqp)")
                continue
            p = have[0]
        elif p != "psor" and not peers.installed(p):
            notes.append(f"peer {p} skipped: not installed (pip install {p})")
            continue
        if p not in out:
            out.append(p)
    per_scene, skipped = {s: [] for s in problems}, {}
    for p in out:
        for s, P in problems.items():
            why = peers.applicable(p, P)
            if why:
                skipped.setdefault((p, why), []).append(s)
            else:
                per_scene[s].append(p)
    notes += [f"peer {p} not run on {', '.join(ss)}: {why}" for (p, why), ss in skipped.items()]
    return per_scene, notes


def _timed(solve, tol, repeat):
    """Best of ``repeat``: (outcome, seconds). A peer that times itself (a QP solver, whose eps
    tuning is not counted) reports its own seconds."""
    best, best_t = None, math.inf
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        out = solve(tol)
        dt = out.pop("seconds", time.perf_counter() - t0)
        if dt < best_t:
            best, best_t = out, dt
    return best, best_t


def _record_history(case, solve, tol, repeat):
    """One recorded run at `tol` (best wall time of `repeat`) into case.history."""
    try:
        out, wall = None, math.inf
        for _ in range(max(1, repeat)):  # best of repeat, like the timed solves
            t0 = time.perf_counter()
            o = solve(tol, history=True)
            dt = time.perf_counter() - t0
            if dt < wall:
                out, wall = o, dt
        h = out["history"]
        # the clock of a history starts with the iteration: shift it by everything else in
        # the call (Python checks, set-up, factorizations, result conversion) so that the
        # last iterate sits at the run's wall time, on the same axis as the timed solves
        last = out["iterations"] if out.get("iterations") not in ("", None) else h["seconds"][-1]
        offset = max(wall - max(last, h["seconds"][-1]), 0.0)
        case.history = dict(iteration=h["iteration"], seconds=h["seconds"] + offset, residual=h["residual"])
        case.history_status = out["status"]
    except Exception as exc:  # already recorded in the rows
        case.history_status = f"error: {exc}"


def run_case(problem, scene, method, z_update, tols, *, size, maxiter, repeat, history, progress):
    """All tols of one case, then (if ``history``) one recorded run at the smallest tol."""
    peer = is_peer(method)
    if peer:
        case = Case(scene, method, "", "", tool="peer")
        solve, case.setting = _run_peer(problem, method, maxiter)
    else:
        case = Case(scene, method, z_update, _z_update_used(problem, z_update, method))
        solve = _run_nrmicp(problem, method, case.z_update_used, maxiter)
    base = dict(scene=scene, size=size, n=problem.n, method=method, z_update=case.z_update,
                z_update_used=case.z_update_used, repeat=repeat)
    failed = None  # (tol, row) of the first solve that did not converge
    try:  # one untimed warm-up solve (first-call allocations, library initialisation, imports)
        solve(max(tols))
    except Exception:
        pass  # the timed solves record it
    for tol in tols:
        what = f"{scene} {method} {z_update} tol={tol:.0e}"
        if failed is not None:
            row = dict(failed[1], tol=tol, reused_from_tol=failed[0])
            case.rows.append(row)
            progress.step(repeat, what)
            continue
        try:
            out, secs = _timed(solve, tol, repeat)
        except Exception as exc:  # a property of the case (e.g. a factorization failed): record it
            row = dict(base, tol=tol, status=f"error: {type(exc).__name__}: {exc}"[:200], converged=0,
                       seconds="", setup_seconds="", factorization_seconds="", iteration_seconds="",
                       iterations="", linear_solves="", residual="", error="", setting=case.setting,
                       reused_from_tol="")
            case.rows.append(row)
            failed = (tol, row)
            progress.step(repeat, what)
            continue
        err = ""
        if problem.z_exact is not None:
            err = float(np.max(np.abs(out["z"] - problem.z_exact)))
        row = dict(base, tol=tol, status=out["status"], converged=int(out["success"]), seconds=secs,
                   setup_seconds=out.get("setup", ""), factorization_seconds=out.get("factorization", ""),
                   iteration_seconds=out.get("iterations", ""), iterations=out["nit"],
                   linear_solves=out.get("linear_solves", ""), residual=out["residual"], error=err,
                   setting=out.get("setting", case.setting), reused_from_tol="")
        case.rows.append(row)
        if np.isfinite(out["residual"]) and (case.best is None or out["residual"] < case.best[0]):
            case.best = (out["residual"], out["z"])
        if not out["success"]:
            failed = (tol, row)
        progress.step(repeat, what)
    if history and method not in _peers_without_history():
        _record_history(case, solve, min(tols), repeat)
    progress.step(repeat, f"{scene} {method} {z_update} history")
    return case


def _peers_without_history():
    """Peers whose solvers report no per-iteration Res (the QP solvers): no history line."""
    from . import peers

    return peers.QP_SOLVERS


def rounding_floor(problem, cases) -> float:
    """eps·‖|A||z*| + |q|‖₂ with z* = z_exact, else the z of least Res seen (the residual's rounding level)."""
    z = problem.z_exact
    if z is None:
        best = min((c.best for c in cases if c.best is not None), key=lambda b: b[0], default=None)
        if best is None:
            return math.nan
        z = best[1]
    absA = abs(problem.A)
    return float(np.finfo(float).eps * np.linalg.norm(absA @ np.abs(z) + np.abs(problem.q)))


# --------------------------------------------------------------------------- analysis

def _fresh_converged(rows):
    return [r for r in rows if r["converged"] == 1 and r["reused_from_tol"] == ""]


#: Converged runs whose iterations took less than this (core clock) are too short to time; when
#: a case has none longer, its seconds per digit are reported as noise.
MIN_TIMED_SECONDS = 5e-5


def per_digit(rows):
    """(seconds per digit, iterations per digit), or NaN where they cannot be told.

    Iterations per digit: Theil–Sen slope of the iteration count against −log10 tol over the
    converged rows (deterministic numbers). Seconds per digit: iterations per digit times the
    seconds per iteration, the least ``iteration_seconds / iterations`` (core clock) over the
    converged runs that iterated at least MIN_TIMED_SECONDS (timing noise only ever adds time,
    so the least is the least disturbed). Fitting wall times of separate solves instead lets the
    per-call overhead and a stray slow solve decide the slope: on the --quick sizes it came out
    negative. Seconds per digit are NaN ("noise") when no run iterated that long."""
    ok = _fresh_converged(rows)
    if len(ok) < 2:
        return math.nan, math.nan
    d = np.array([-math.log10(r["tol"]) for r in ok])
    if np.ptp(d) == 0:
        return math.nan, math.nan
    ipd = _theil_sen(d, np.array([r["iterations"] for r in ok], dtype=float))
    per_iteration = [r["iteration_seconds"] / r["iterations"] for r in ok
                     if r["iterations"] >= 1 and r["iteration_seconds"] != ""
                     and r["iteration_seconds"] >= MIN_TIMED_SECONDS]
    if not per_iteration:
        return math.nan, ipd
    return ipd * min(per_iteration), ipd


def _theil_sen(x, y) -> float:
    """Median of the pairwise slopes: a straight-line fit that one noisy timing cannot swing."""
    i, j = np.triu_indices(len(x), 1)
    keep = x[j] != x[i]
    return float(np.median((y[j] - y[i])[keep] / (x[j] - x[i])[keep]))


def best_residual(case) -> float:
    vals = [r["residual"] for r in case.rows if r["residual"] != ""]
    if case.history is not None and len(case.history["residual"]):
        vals.append(float(np.min(case.history["residual"])))
    vals = [v for v in vals if np.isfinite(v)]
    return min(vals) if vals else math.nan


def _same_iterates(a, b) -> bool:
    """Two cases whose every row stopped at the same iteration with the same Res."""
    key = lambda c: [(r["status"], r["iterations"], r["residual"]) for r in c.rows]
    return bool(a.rows) and key(a) == key(b)


def near_ties(cases, row, tol, within=0.10):
    """Other cases converged at ``tol`` within ``within`` (relative) of ``row``'s seconds."""
    out = []
    for c in cases:
        for r in c.rows:
            if (r is not row and r["tol"] == tol and r["converged"] == 1
                    and r["seconds"] <= row["seconds"] * (1 + within)):
                out.append(c.label)
    return out


def fastest_at(cases, target, tols):
    """(case, row) converged at the tol closest to ``target`` in log scale with the least seconds."""
    tols = sorted(set(tols))
    if not tols:
        return None, None, None
    tol = min(tols, key=lambda t: abs(math.log10(t) - math.log10(target)))
    best = None
    for c in cases:
        for r in c.rows:
            if r["tol"] == tol and r["converged"] == 1 and (best is None or r["seconds"] < best[1]["seconds"]):
                best = (c, r)
    return (best[0], best[1], tol) if best else (None, None, tol)


def _closest(tols, target):
    """The tol closest to ``target`` in log scale (the smaller one on a tie)."""
    return min(sorted(set(tols)), key=lambda t: abs(math.log10(t) - math.log10(target)))


def seconds_to(case, target, tols):
    """The converged, freshly timed row of ``case`` at the tol closest to ``target`` (log scale), or None."""
    if not tols:
        return None
    tol = _closest(tols, target)
    return next((r for r in case.rows if r["tol"] == tol and r["converged"] == 1 and r["reused_from_tol"] == ""),
                None)


def summarize(scene_results, tols, env=None) -> str:
    lines = []
    if env:
        lines.append(environment_line(env))
        lines.append("s/digit = it/digit x least seconds per iteration of the converged runs (core clock); "
                     f"'noise': none iterated {MIN_TIMED_SECONDS * 1e6:.0f} us, too short to tell; "
                     "'-': not linear (newton, +polish, a QP solver), see 's to tol'")
    for scene, (problem, cases, floor) in scene_results.items():
        lines.append(f"\n== {scene_label(scene)}: {problem.name}, n = {problem.n}; "
                     f"rounding level eps*|| |A||z*|+|q| || = {floor:.1e}")
        lines.append(f"   {'method / z-update':<24} {'s/digit':>9} {'it/digit':>9} "
                     + " ".join(f"{'s to ' + f'{_closest(tols, t):.0e}':>10}" for t in TARGETS)
                     + f" {'best Res':>9} {'smallest tol met':>16}  stopped (first failing tol)")
        for c in cases:
            spd, ipd = per_digit(c.rows) if c.linear else (math.nan, math.nan)
            met = [r["tol"] for r in c.rows if r["converged"] == 1]
            stop = next((r for r in c.rows if r["converged"] != 1), None)
            stop_s = "-" if stop is None else (f"{stop['status']} at tol {stop['tol']:.0e}"
                                               + (f" (Res {stop['residual']:.1e}, {stop['iterations']} it)"
                                                  if stop["residual"] != "" else ""))
            twin = next((o.label for o in cases[:cases.index(c)] if _same_iterates(o, c)), None)
            spd_s = "noise" if math.isnan(spd) and not math.isnan(ipd) else f"{spd:.2e}"
            ipd_s = f"{ipd:.1f}"
            if not c.linear:  # superlinear, or one jump to rounding level: no cost per digit
                spd_s = ipd_s = "-"
            at = []
            for t in TARGETS:
                r = seconds_to(c, t, tols)
                at.append("-" if r is None else f"{r['seconds']:.2e}")
            lines.append(f"   {c.label:<24} {spd_s:>9} {ipd_s:>9} " + " ".join(f"{a:>10}" for a in at)
                         + f" {best_residual(c):9.1e} "
                         f"{(f'{min(met):.0e}' if met else 'none'):>16}  {stop_s}"
                         + (f"  [same iterates as {twin}]" if twin else ""))
        for target in TARGETS:
            c, r, tol = fastest_at(cases, target, tols)
            if tol is None:
                continue
            if c is None:
                lines.append(f"   fastest at tol {tol:.0e}: no case converged")
            else:
                ties = near_ties(cases, r, tol)
                lines.append(f"   fastest at tol {tol:.0e}: {c.label} ({r['seconds'] * 1e3:.2f} ms, "
                             f"{r['iterations']} it)"
                             + (f"; within 10 %: {', '.join(ties)}" if ties else ""))
    return "\n".join(lines).lstrip("\n")


# --------------------------------------------------------------------------- plots

_COLORS = {"nrm": "tab:blue", "nrmm": "tab:orange", "nrmaor": "tab:brown", "nrmsor": "tab:pink",
           "nrmgs": "tab:green", "nrmj": "tab:red", "mms": "tab:purple", "two_sweep": "tab:gray",
           "newton": "tab:cyan", "psor": "black", "piqp": "tab:olive", "osqp": "gold"}
_POLISH_COLOR = "darkgreen"
_MARKERS = {"nrm": "o", "nrmm": "s", "nrmaor": "P", "nrmsor": "X", "nrmgs": "^", "nrmj": "v",
            "mms": "D", "two_sweep": "*", "newton": "p", "psor": "x", "piqp": "h", "osqp": "d"}
_LINESTYLES = {"explicit": "-", "solve": "--"}
_PEER_LINESTYLE = "-."


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path, dpi):
    """Save as PNG, palette-quantized when Pillow is there (a quarter of the bytes, same look)."""
    fig.savefig(path, dpi=dpi)
    try:
        from PIL import Image

        with Image.open(path) as im:
            small = im.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
        small.save(path, optimize=True)
    except Exception:  # pragma: no cover - keep the full-colour PNG
        pass


def _log_ticks(ax):
    """Decade labels only (minor-tick labels collide on short log axes)."""
    from matplotlib.ticker import LogLocator, NullFormatter

    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(LogLocator(base=10, numticks=8))
        axis.set_minor_formatter(NullFormatter())


def _case_style(c):
    base, kw = split_method(c.method)
    if c.tool == "peer":
        linestyle = _PEER_LINESTYLE
    else:
        linestyle = _LINESTYLES.get(c.z_update_used, "-")
    return dict(color=_POLISH_COLOR if kw else _COLORS.get(base, "k"),
                marker="*" if kw else _MARKERS.get(base, "o"), linestyle=linestyle,
                lw=2.0 if base == "newton" or kw else 1.3)


def _plot_case(ax, c, st, y):
    """One case in a work-precision panel: its history (faint), converged points, early stops."""
    if y == "residual" and c.history is not None:
        hs, hr = c.history["seconds"], c.history["residual"]
        keep = (hs > 0) & (hr > 0) & np.isfinite(hr)
        ax.plot(hs[keep], hr[keep], color=st["color"], linestyle=st["linestyle"], lw=0.8, alpha=0.3)
    fresh = [r for r in c.rows if r["reused_from_tol"] == "" and r["seconds"] != ""]
    vals = [(r["seconds"], r[y], r["converged"]) for r in fresh
            if r[y] != "" and np.isfinite(r[y]) and r[y] > 0]
    ok = [(s, v) for s, v, conv in vals if conv == 1]
    bad = [(s, v) for s, v, conv in vals if conv != 1]
    if ok:
        xs, ys = zip(*ok)
        ax.plot(xs, ys, color=st["color"], linestyle=st["linestyle"], marker=st["marker"], ms=5, lw=st["lw"])
    if bad:  # the point reached when the solve stopped early: hollow marker
        xs, ys = zip(*bad)
        ax.plot(xs, ys, linestyle="none", marker=st["marker"], ms=9, mfc="none", mec=st["color"], mew=1.6)
        if ok:  # connect the last converged point to where it stopped
            ax.plot([ok[-1][0], xs[0]], [ok[-1][1], ys[0]], color=st["color"], lw=0.8, linestyle=":")


def _legend(Line2D, seen_methods, seen_z, scene_results, y):
    """The work-precision figure's legend entries."""
    handles = [Line2D([], [], color=st["color"], marker=st["marker"], linestyle=st["linestyle"], label=m)
               for m, st in seen_methods.items()]
    handles += [Line2D([], [], color="k", linestyle=_LINESTYLES[z], label=f"z-update '{z}'")
                for z in _LINESTYLES if z in seen_z]
    if any(c.tool == "peer" for _, cs, _ in scene_results.values() for c in cs):
        handles.append(Line2D([], [], color="k", linestyle=_PEER_LINESTYLE, label="peer (not nrmicp)"))
    handles += [Line2D([], [], color="k", marker="o", linestyle="none", label="converged (Res < tol)"),
                Line2D([], [], color="k", marker="o", mfc="none", ms=9, linestyle="none",
                       label="stopped early: point reached")]
    if y == "residual":
        handles += [Line2D([], [], color="k", lw=0.8, alpha=0.4, label="history of one run (every iterate)"),
                    Line2D([], [], color="k", lw=0.9, linestyle=":", label="rounding level eps·‖|A||z*|+|q|‖₂")]
    return handles


def _res_label(problem) -> str:
    """The y label of a Res axis: PATH's mid for a box scene, the paper's min otherwise."""
    return "Res = ‖mid(z−ζ, z−u, Az+q)‖₂" if is_box(problem) else "Res = ‖min(Az+q, z−ζ(z))‖₂"


def plot_work_precision(scene_results, path, *, y="residual", tols=(), dpi=110):
    """One panel per scene: x = seconds (log), y = Res or max|z − z*| (log)."""
    plt = _pyplot()
    from matplotlib.lines import Line2D

    names = list(scene_results)
    ncols = min(4, len(names))
    nrows = math.ceil(len(names) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.3 * ncols, 3.6 * nrows + 1.2), squeeze=False)
    seen_methods, seen_z = {}, set()
    for ax, scene in zip(axes.flat, names):
        problem, cases, floor = scene_results[scene]
        for c in cases:
            st = _case_style(c)
            seen_methods.setdefault(c.method, dict(st, linestyle=_PEER_LINESTYLE if c.tool == "peer" else "-"))
            seen_z.add(c.z_update_used)
            _plot_case(ax, c, st, y)
        if y == "residual":
            if np.isfinite(floor) and floor > 0:
                ax.axhline(floor, color="k", lw=0.9, linestyle=":")
                ax.annotate("rounding level", xy=(0.02, floor), xycoords=("axes fraction", "data"),
                            xytext=(0, 2), textcoords="offset points", fontsize=7, va="bottom")
        ax.set_xscale("log")
        ax.set_yscale("log")
        _log_ticks(ax)
        ax.grid(True, which="major", alpha=0.3)
        ax.set_title(f"{scene_label(scene)}\nn = {problem.n}", fontsize=9)
        ax.set_xlabel("seconds per solve (incl. set-up)", fontsize=8)
        ax.set_ylabel(_res_label(problem) if y == "residual" else "max |z − z_exact|", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(names):]:
        ax.set_visible(False)
    handles = _legend(Line2D, seen_methods, seen_z, scene_results, y)
    fig.legend(handles=handles, loc="lower center", ncol=math.ceil(len(handles) / 2), fontsize=8, frameon=False)
    tl = f"tol = {max(tols):.0e} … {min(tols):.0e}" if tols else ""
    what = "residual Res reached" if y == "residual" else "true error max|z − z_exact| reached"
    fig.suptitle(f"nrmicp work–precision: {what} against solve time, {tl} (one marker per tol; "
                 f"colour: method or peer, line style: z-update)", fontsize=11)
    fig.tight_layout(rect=(0, 0.75 / (3.6 * nrows + 1.2), 1, 1 - 0.45 / (3.6 * nrows + 1.2)))
    _save(fig, path, dpi)
    plt.close(fig)


def plot_history(problem, scene, cases, floor, path, tol, dpi=110):
    """Res against iteration and against seconds for every case of one scene."""
    plt = _pyplot()
    from matplotlib.ticker import NullFormatter

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 5.0))
    for c in cases:
        if c.history is None:
            continue
        st = _case_style(c)
        h = c.history
        keep = np.isfinite(h["residual"]) & (h["residual"] > 0)
        lab = f"{c.label} ({c.history_status})"
        a1.plot(h["iteration"][keep], h["residual"][keep], color=st["color"], linestyle=st["linestyle"], lw=1.2,
                label=lab)
        a2.plot(h["seconds"][keep], h["residual"][keep], color=st["color"], linestyle=st["linestyle"], lw=1.2,
                label=lab)
    for ax in (a1, a2):
        ax.set_yscale("log")
        if np.isfinite(floor) and floor > 0:
            ax.axhline(floor, color="k", lw=0.9, linestyle=":", label="rounding level eps·‖|A||z*|+|q|‖₂")
        ax.axhline(tol, color="0.5", lw=0.8, linestyle="-.", label=f"tol = {tol:.0e}")
        ax.grid(True, which="major", alpha=0.3)
        ax.set_ylabel(_res_label(problem))
    a1.set_xscale("symlog", linthresh=10, linscale=0.5)
    a1.set_xlim(left=0)
    a1.yaxis.set_minor_formatter(NullFormatter())
    a1.set_xlabel("iteration (linear up to 10, then log)")
    a2.set_xscale("log")
    _log_ticks(a2)
    a2.set_xlabel("seconds (set-up + iterations)")
    a1.set_title("Res against iteration", fontsize=10)
    a2.set_title("Res against time", fontsize=10)
    handles, labels = a2.get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(f"nrmicp convergence history: {scene_label(scene)}, {problem.name}, n = {problem.n}",
                 fontsize=11)
    fig.tight_layout(rect=(0, 0.13, 1, 0.95))
    _save(fig, path, dpi)
    plt.close(fig)


# --------------------------------------------------------------------------- CLI

def _split(s):
    return [t.strip() for t in s.replace(";", ",").split(",") if t.strip()]


def _tols(args):
    if args.tols:
        tols = [float(t) for t in _split(args.tols)]
    elif args.quick and args.tol_min is None and args.tol_max is None:
        tols = list(QUICK_TOLS)
    else:
        hi = 1e-2 if args.tol_max is None else args.tol_max
        lo = 1e-12 if args.tol_min is None else args.tol_min
        if not (0 < lo <= hi):
            raise SystemExit(f"need 0 < --tol-min <= --tol-max, got {lo}, {hi}")
        k = int(round(math.log10(hi / lo)))
        tols = list(np.logspace(math.log10(hi), math.log10(lo), k + 1)) if k > 0 else [hi]
    if any(not (t > 0) for t in tols):
        raise SystemExit("every tol must be > 0")
    return sorted(set(float(f"{t:.6g}") for t in tols), reverse=True)


def _parser(prog: str = "python -m nrmicp bench --family"):
    import nrmicp

    p = argparse.ArgumentParser(
        prog=prog,
        description="Work-precision sweep: seconds, iterations, Res and true error against tol for each "
                    "scene, method and z-update; writes a CSV, PNG diagrams and a text summary.")
    p.add_argument("--scenes", help=f"comma-separated; default: {','.join(DEFAULT_SCENES)} "
                                    f"(also: {','.join(EXTRA_SCENES)})")
    p.add_argument("--methods", help=f"comma-separated from {','.join(nrmicp.METHODS)}, each optionally "
                                     f"with '+polish'; default: {','.join(DEFAULT_METHODS)}")
    p.add_argument("--peers", default=",".join(DEFAULT_PEERS),
                   help=f"comma-separated from {','.join(PEERS)} or 'none' (default {','.join(DEFAULT_PEERS)}: "
                        "red-black PSOR and the first installed of piqp, osqp); run on the LCP scenes "
                        "(a QP solver on the symmetric ones); one not installed is skipped with a note")
    p.add_argument("--z-updates", default="auto",
                   help="comma-separated from auto,explicit,solve (default auto, which is explicit; "
                        "use explicit,solve to compare the two)")
    p.add_argument("--tols", help="comma-separated tolerances (overrides --tol-min/--tol-max)")
    p.add_argument("--tol-min", type=positive_float, help="smallest tol (default 1e-12); one tol per decade")
    p.add_argument("--tol-max", type=positive_float, help="largest tol (default 1e-2)")
    p.add_argument("--size", default=None, choices=tuple(SIZES),
                   help="problem sizes (default small; --quick: tiny)")
    p.add_argument("--quick", action="store_true",
                   help=f"tiny sizes, tols 1e-2..1e-8 (4), methods {','.join(QUICK_METHODS)} and the peers: "
                        "a smoke run of seconds")
    p.add_argument("--repeat", type=int_at_least(1), default=1, help="time each solve r times and keep the best (default 1)")
    p.add_argument("--maxiter", type=int_at_least(1), default=10000, help="iteration cap per solve (default 10000)")
    p.add_argument("--history-scene", help="scene of the convergence-history figure "
                                           "(default obstacle_2d if swept, where newton and the peers all run; else the first scene)")
    p.add_argument("--out", default="bench-out", help="output directory (default bench-out/)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    return p


def main(argv: Optional[list[str]] = None, prog: str = "python -m nrmicp bench --family") -> int:
    import nrmicp

    args = _parser(prog).parse_args(argv)
    try:
        sel = _selection(args, nrmicp.METHODS)
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    os.makedirs(args.out, exist_ok=True)
    t_start = time.perf_counter()
    print(f"nrmicp {nrmicp.__version__} bench: scenes {','.join(sel.scenes)}; methods {','.join(sel.methods)}; "
          f"peers {','.join(sel.peers) or 'none'}; z-updates {','.join(sel.z_updates)}; size {sel.size}; "
          f"{len(sel.tols)} tols {sel.tols[0]:.0e}..{sel.tols[-1]:.0e}; repeat {args.repeat}; maxiter {args.maxiter}",
          flush=True)
    scene_results = _sweep(sel, args)
    env = environment()
    written = _write_tables(scene_results, sel, env, args.out)
    # The numbers first: a missing or failing matplotlib must not cost the sweep.
    try:
        _pyplot()
    except ImportError:
        print(f"\nwrote {', '.join(written)} in {time.perf_counter() - t_start:.1f} s. No figures: matplotlib "
              "is not installed; pip install nrmicp[plot] (or matplotlib) draws them.")
        return 0
    pngs = _plot_all(scene_results, sel, args.out)
    print(f"\nwrote {', '.join(written + pngs)} in {time.perf_counter() - t_start:.1f} s")
    return 0


@dataclass
class _Selection:
    """What one bench invocation sweeps."""
    scenes: list
    methods: list
    z_updates: list
    peers: list
    size: str
    tols: list
    hist_scene: str


def _selection(args, known_methods) -> _Selection:
    """The sweep the arguments ask for; ValueError naming the first unknown choice."""
    scenes = _split(args.scenes) if args.scenes else list(DEFAULT_SCENES)
    methods = [m.lower() for m in _split(args.methods)] if args.methods else \
        list(QUICK_METHODS if args.quick else DEFAULT_METHODS)
    z_updates = [z.lower() for z in _split(args.z_updates)]
    peers = [p.lower() for p in _split(args.peers) if p.lower() != "none"]
    for s in scenes:
        if s not in SCENES:
            raise ValueError(f"unknown scene {s!r}; choose from {', '.join(SCENES)}")
    for m in methods:
        base, _, extra = m.partition("+")
        if base not in known_methods or extra not in ("", "polish"):
            raise ValueError(f"unknown method {m!r}; choose from {', '.join(known_methods)} (each optionally "
                             "with '+polish')")
    for p in peers:
        if p not in PEERS:
            raise ValueError(f"unknown peer {p!r}; choose from {', '.join(PEERS)} or none")
    for z in z_updates:
        if z not in ("auto", "explicit", "solve"):
            raise ValueError(f"unknown z-update {z!r}; choose from auto, explicit, solve")
    if args.repeat < 1 or args.maxiter < 1:
        raise ValueError("--repeat and --maxiter must be >= 1")
    tols = _tols(args)
    hist_scene = args.history_scene or ("obstacle_2d" if "obstacle_2d" in scenes else scenes[0])
    if hist_scene not in scenes:
        raise ValueError(f"--history-scene {hist_scene!r} is not among the swept scenes")
    return _Selection(scenes, methods, z_updates, peers, args.size or ("tiny" if args.quick else "small"), tols,
                      hist_scene)


def _sweep(sel, args) -> dict:
    """Every (scene, method, z-update) and peer case: scene -> (problem, cases, rounding floor)."""
    from .. import scenes

    problems = {s: scenes.build(s, sel.size) for s in sel.scenes}  # exact references are not timed
    peers, notes = resolve_peers(sel.peers, problems)
    for note in notes:
        print(note, flush=True)
    plan = {s: [(m, z) for m in sel.methods if m == "newton" or not is_box(problems[s])
                for z in (sel.z_updates if split_method(m)[0] != "newton" else sel.z_updates[:1])]
            + [(p, "") for p in peers[s]] for s in sel.scenes}
    boxes = [s for s in sel.scenes if is_box(problems[s])]
    if boxes and any(m != "newton" for m in sel.methods):
        print(f"only newton runs on the box scenes {', '.join(boxes)} (the other members have no box form)",
              flush=True)
    n_cases = sum(len(v) for v in plan.values())
    progress = Progress(n_cases * (len(sel.tols) + 1) * args.repeat, enabled=not args.no_progress)
    scene_results = {}
    for s in sel.scenes:
        P = problems[s]
        cases = [run_case(P, s, m, z, sel.tols, size=sel.size, maxiter=args.maxiter, repeat=args.repeat,
                          history=True, progress=progress) for m, z in plan[s]]
        scene_results[s] = (P, cases, rounding_floor(P, cases))
    progress.close()
    return scene_results


def _write_tables(scene_results, sel, env, out) -> list:
    """work_precision.csv, history.csv (the history scene) and summary.txt; their paths."""
    csv_path = os.path.join(out, "work_precision.csv")
    with open(csv_path, "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        wr.writeheader()
        for _, cases, _ in scene_results.values():
            for c in cases:
                for r in c.rows:
                    wr.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in dict(r, **env).items()})
    _, hcases, _ = scene_results[sel.hist_scene]
    hist_path = os.path.join(out, "history.csv")
    with open(hist_path, "w", newline="") as f:
        wr = csv.writer(f)
        wr.writerow(("scene", "method", "z_update_used", "iteration", "seconds", "residual"))
        for c in hcases:
            if c.history is not None:
                for k, t, r in zip(c.history["iteration"], c.history["seconds"], c.history["residual"]):
                    wr.writerow((sel.hist_scene, c.method, c.z_update_used, int(k), f"{t:.6g}", f"{r:.6g}"))
    summary_path = os.path.join(out, "summary.txt")
    text = summarize(scene_results, sel.tols, env)
    with open(summary_path, "w") as f:
        f.write(text + "\n")
    print(text)
    return [csv_path, hist_path, summary_path]


def _plot_all(scene_results, sel, out) -> list:
    """The work-precision figures (residual; error where exact solutions exist) and the history."""
    pngs = [os.path.join(out, "work_precision.png"), os.path.join(out, "work_precision_error.png"),
            os.path.join(out, "convergence_history.png")]
    plot_work_precision(scene_results, pngs[0], y="residual", tols=sel.tols)
    with_exact = {s: v for s, v in scene_results.items() if v[0].z_exact is not None}
    if with_exact:
        plot_work_precision(with_exact, pngs[1], y="error", tols=sel.tols)
    else:
        pngs.pop(1)
    P, hcases, hfloor = scene_results[sel.hist_scene]
    plot_history(P, sel.hist_scene, hcases, hfloor, pngs[-1], tol=min(sel.tols))
    return pngs


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
