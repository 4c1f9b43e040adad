"""What a user would use instead of nrmicp, for the work–precision bench (``python -m nrmicp bench``):
red-black projected SOR in numpy and a QP solver (PIQP or OSQP) on min ½zᵀAz + qᵀz, z ≥ 0.

They live in the package, not in benchmarks/, because the bench must run from an installed
nrmicp (benchmarks/ is not part of the wheel). The peer tables of benchmarks/ (qp_peers.py,
scipy_modulus.py) use these same implementations: PSOR, the QP calls, the eps tuning and the
stopping rule are written once, here.

A peer solves LCP(q', A) in y = z − c: ζ ≡ 0 (c = 0) or a constant ζ ≡ c (the shifted LCP,
q' = q + Ac). A callable ζ is not a peer's problem, and the QP form needs a symmetric A; a peer
says which with :func:`applicable`. Res is the paper's ‖min(Az + q, z − c)‖₂ = ‖min(Ay + q', y)‖₂.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

#: The clock of the time limits and timings (the tests replace it to step time deterministically).
clock = time.perf_counter

#: The QP solvers the bench knows, in order of preference for ``--peers qp``.
QP_SOLVERS = ("piqp", "osqp")


def installed(name: str):
    """The module version of an installed QP solver, or None."""
    try:
        mod = __import__(name)
    except ImportError:
        return None
    return getattr(mod, "__version__", "?")


def shifted_lcp(problem):
    """(A csr, q', c) with y = z − c solving LCP(q', A), or None when ζ is not constant or the
    scene is a box problem (an upper bound, or ζ with -inf: free unknowns)."""
    A = sp.csr_matrix(problem.A, dtype=float)
    q = np.asarray(problem.q, dtype=float)
    zeta = problem.zeta
    if getattr(problem, "upper", None) is not None:
        return None
    if zeta is None:
        return A, q, np.zeros(A.shape[0])
    if callable(zeta) or hasattr(zeta, "B"):
        return None
    c = np.broadcast_to(np.asarray(zeta, dtype=float), q.shape).copy()
    if not np.all(np.isfinite(c)):
        return None
    return A, q + A @ c, c


def applicable(peer: str, problem) -> str:
    """'' when ``peer`` can solve ``problem``, else why not."""
    lcp = shifted_lcp(problem)
    if lcp is None:
        box = getattr(problem, "upper", None) is not None or isinstance(problem.zeta, np.ndarray)
        return "bounds or free unknowns (a box problem, not an LCP)" if box else "ζ is not constant (not an LCP)"
    if peer in QP_SOLVERS:
        A = lcp[0]
        if abs(A - A.T).max() > 1e-14 * abs(A).max():
            return "A is not symmetric (no QP form)"
    return ""


def _res(A, q, y):
    return float(np.linalg.norm(np.minimum(A @ y + q, y)))


def verdict(res, tol, k, maxiter, t0=None, time_limit=None, clock=None):
    """Why an iteration stops at iterate k with Res ``res``, or None to go on: 'converged'
    (Res < tol), 'diverged' (Res not finite), 'max_iterations' (k >= maxiter) or 'time_limit'
    (more than ``time_limit`` seconds of ``clock`` since ``t0``)."""
    if res < tol:
        return "converged"
    if not np.isfinite(res):
        return "diverged"
    if k >= maxiter:
        return "max_iterations"
    if time_limit is not None and (clock or globals()["clock"])() - t0 > time_limit:
        return "time_limit"
    return None


# --------------------------------------------------------------------------- red-black PSOR

def colours(A) -> np.ndarray:
    """Greedy colouring of A's graph in row order: red-black (2 colours) on a 5-point grid or a
    tridiagonal matrix. Rows of one colour do not couple, so each colour is one vectorized update."""
    A = sp.csr_matrix(A)
    S = A + A.T
    ip, ix = S.indptr, S.indices
    col = np.full(A.shape[0], -1, dtype=np.int64)
    for i in range(A.shape[0]):
        used = set(col[ix[ip[i]:ip[i + 1]]].tolist())
        c = 0
        while c in used:
            c += 1
        col[i] = c
    return col


def sor_omega(A) -> float:
    """ω = 2 / (1 + √(1 − ρ_J²)), SOR's optimum for a consistently ordered matrix, with ρ_J the
    spectral radius of the Jacobi matrix I − D⁻¹A. 1 when that fails or ρ_J ≥ 1.

    A symmetric A with a positive diagonal: ρ_J = 1 − λ_min(D^-½ A D^-½) (the Jacobi spectrum of a
    consistently ordered matrix is symmetric about 0; any ω in (0, 2) converges for SPD A), λ_min by
    LOBPCG preconditioned by a pyamg V-cycle: its cost grows like n. ARPACK on I − D⁻¹A, used
    otherwise (and before), converges at the rate of the spectral gap, O(h²): 33 s at P1 n = 130,561
    and more than 200 s at 523,265, where LOBPCG takes 1.3 s and 6.1 s (docs/MEASUREMENTS.md, "The PSOR
    peer's ω")."""
    from scipy.sparse.linalg import eigs

    A = sp.csr_matrix(A, dtype=np.float64)
    d = A.diagonal()
    if not (d > 0).all():
        return 1.0
    try:
        if A.shape[0] < 50:
            J = np.eye(A.shape[0]) - A.toarray() / d[:, None]
            rho = float(np.max(np.abs(np.linalg.eigvals(J))))
        elif abs(A - A.T).max() <= 1e-12 * abs(A).max():
            rho = 1.0 - _lambda_min_scaled(A, d)
        else:
            J = sp.identity(A.shape[0], format="csr") - sp.diags(1.0 / d) @ A
            rho = float(np.abs(eigs(J, k=1, which="LM", return_eigenvectors=False, tol=1e-6)[0]))
    except Exception:
        return 1.0
    return 2.0 / (1.0 + np.sqrt(1.0 - rho * rho)) if 0 <= rho < 1 else 1.0


def _lambda_min_scaled(A, d) -> float:
    """The smallest eigenvalue of D^-½ A D^-½ (A symmetric, d = diag(A) > 0): LOBPCG with a
    smoothed-aggregation V-cycle (pyamg) as preconditioner, or ARPACK's shift-invert without pyamg."""
    from scipy.sparse.linalg import eigsh, lobpcg

    s = 1.0 / np.sqrt(d)
    S = sp.csr_matrix(sp.diags(s) @ A @ sp.diags(s))
    try:
        import pyamg
    except ImportError:
        return float(eigsh(S, k=1, sigma=0, which="LM", return_eigenvectors=False)[0])
    M = pyamg.smoothed_aggregation_solver(S).aspreconditioner()
    X = np.random.default_rng(0).standard_normal((S.shape[0], 1))
    lam = lobpcg(S, X, M=M, largest=False, tol=1e-8, maxiter=200)[0]
    return float(lam[0])


def psor(A, q, c, tol, *, omega, colour, maxiter, history=False, time_limit=None, clock=None):
    """Projected SOR y_i ← max(0, y_i − ω (Ay + q)_i / a_ii) colour by colour, from y = 0, until
    Res < tol (checked every sweep, one SpMV; see :func:`verdict`). Returns z = y + c and the
    outcome; ``setup + iterations`` is the whole time, on ``clock`` (e.g. time.process_time;
    None: the module's :data:`clock`)."""
    clock = clock or globals()["clock"]
    t0 = clock()
    blocks = []
    for k in np.unique(colour):
        rows = np.flatnonzero(colour == k)
        Ak = A[rows]
        blocks.append((rows, Ak, omega / Ak[np.arange(len(rows)), rows].A1, q[rows]))
    setup = clock() - t0
    y = np.zeros(A.shape[0])
    hist = ([], [], []) if history else None
    k = 0
    while True:
        res = _res(A, q, y)
        if hist is not None:
            hist[0].append(k), hist[1].append(clock() - t0), hist[2].append(res)
        status = verdict(res, tol, k, maxiter, t0, time_limit, clock)
        if status:
            break
        for rows, Ak, wd, qk in blocks:
            yk = y[rows] - wd * (Ak @ y + qk)
            np.maximum(yk, 0.0, out=yk)
            y[rows] = yk
        k += 1
    total = clock() - t0
    out = dict(z=y + c, status=status, success=status == "converged", nit=k, residual=res,
               setup=setup, iterations=total - setup)
    if hist is not None:
        out["history"] = dict(iteration=np.array(hist[0]), seconds=np.array(hist[1]), residual=np.array(hist[2]))
    return out


# --------------------------------------------------------------------------- QP solvers

def qp_once(name, A, q, eps, *, max_iter=None):
    """One solve of min ½yᵀAy + qᵀy, y ≥ 0 at accuracy eps: (y, status, iterations). Everything
    the user pays (the upper triangle, the constraint block, set-up, factorization) is inside.
    ``max_iter``: PIQP's iteration limit (None: its default); OSQP gets 10⁶."""
    n = A.shape[0]
    P = sp.triu(A, format="csc")
    if name == "piqp":
        import piqp

        s = piqp.SparseSolver()
        s.settings.verbose = False
        s.settings.eps_abs = s.settings.eps_rel = eps
        s.settings.eps_duality_gap_abs = s.settings.eps_duality_gap_rel = eps
        if max_iter is not None:
            s.settings.max_iter = max_iter
        s.setup(P, q, x_l=np.zeros(n), x_u=np.full(n, np.inf))
        st = s.solve()
        return np.array(s.result.x), getattr(st, "name", str(st)), int(s.result.info.iter)
    if name == "osqp":
        import osqp

        m = osqp.OSQP()
        # polishing (OSQP >= 1.0; 'polish' before): one solve on the guessed active set
        v1 = int(osqp.__version__.split(".")[0]) >= 1
        m.setup(P=P, q=q, A=sp.identity(n, format="csc"), l=np.zeros(n), u=np.full(n, np.inf),
                eps_abs=eps, eps_rel=eps, max_iter=1_000_000, verbose=False,
                **{"polishing" if v1 else "polish": True})
        r = m.solve(raise_error=False) if v1 else m.solve()  # a failed solve is a status, not an error
        return np.array(r.x), str(r.info.status), int(r.info.iter)
    raise ValueError(f"unknown QP solver {name!r}")


def tune_eps(run, A, q, tol, *, eps_start=None, eps_min=1e-14, time_budget=None):
    """A QP solver's eps, from ``eps_start`` (default tol) down by 10× until Res < tol (a user
    has to find it too). ``run(eps)`` -> (y, status, iterations) is one solve; a solve that
    raises is a result too (status 'error: ...', Res inf) and ends the tuning, as do eps_min
    and more than ``time_budget`` seconds spent (status + ' (tuning budget exhausted)').
    Returns the last run: y, status, iterations, residual, seconds (that run alone), eps,
    reached, attempts [(eps, Res, seconds)], tuning_seconds (all runs)."""
    eps = tol if eps_start is None else eps_start
    attempts, spent = [], 0.0
    while True:
        t0 = clock()
        try:
            y, st, it = run(eps)
            secs = clock() - t0
            res = _res(A, q, y)
        except Exception as exc:  # a solver failure is a result too
            y, st, it, res = None, f"error: {exc}", -1, np.inf
            secs = clock() - t0
        attempts.append((eps, res, secs))
        spent += secs
        out = dict(y=y, status=st, iterations=it, residual=res, seconds=secs, eps=eps, reached=bool(res < tol),
                   attempts=attempts, tuning_seconds=spent)
        if out["reached"] or eps / 10 < eps_min * 0.999 or y is None:
            return out
        if time_budget is not None and spent > time_budget:
            out["status"] += " (tuning budget exhausted)"
            return out
        eps /= 10


def qp(name, A, q, c, tol, *, eps_min=1e-14):
    """The QP peer for the bench: :func:`tune_eps` on :func:`qp_once`, the outcome of the last
    run, its own seconds (the tuning runs before it are not counted) and the eps it needed. Not
    converged when even eps_min does not get Res below tol."""
    o = tune_eps(lambda eps: qp_once(name, A, q, eps), A, q, tol, eps_min=eps_min)
    y = np.zeros_like(q) if o["y"] is None else o["y"]
    ok = o["reached"]
    return dict(z=y + c, status="converged" if ok else o["status"].lower().replace(" ", "_"), success=ok,
                nit=max(o["iterations"], 0), residual=o["residual"], seconds=o["seconds"],
                setting=f"eps={o['eps']:.0e}")


# --------------------------------------------------------------------------- budgets

def estimate(history, n, p_default, floor=1e-3):
    """Seconds a peer would take at size n, extrapolated from [(n_i, seconds_i)] at smaller sizes
    (a power law through the last two, its exponent clipped to [1, 2.5]; ``p_default`` with one
    point); the benchmarks skip a peer whose estimate exceeds their budget. Times below ``floor``
    count as ``floor`` (too short to fit). None without history."""
    import math

    if not history:
        return None
    if len(history) >= 2:
        (n1, t1), (n2, t2) = history[-2], history[-1]
        p = min(max(math.log(max(t2, floor) / max(t1, floor)) / math.log(n2 / n1), 1.0), 2.5)
    else:
        p = p_default
    n0, t0 = history[-1]
    return t0 * (n / n0) ** p
