"""Direct (non-iterative in the NRM sense) solvers used to give scenes an exact answer.

Both are Howard's policy iteration (equivalently a semismooth Newton / primal–dual
active-set method). For a nonsingular M-matrix A each step solves one sparse linear
system, the iterates increase monotonically, and the method stops after finitely many
steps at the *exact* solution of the discrete problem (to rounding) — typically a handful
to a few tens of steps. They are references, not competitors: every step refactorizes.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def _policy_matrix(A: sp.csr_matrix, active: np.ndarray) -> sp.csr_matrix:
    """Rows of A where inactive, identity rows where active."""
    keep = sp.diags((~active).astype(np.float64))
    ident = sp.diags(active.astype(np.float64))
    return sp.csr_matrix(keep @ A + ident)


def exact_if_small(A, q, psi, exact, max_n: int = 20_000):
    """A scene's ``z_exact``: :func:`solve_exact_obstacle` when ``exact`` (None: n ≤ ``max_n``)."""
    if exact is None:
        exact = A.shape[0] <= max_n
    return solve_exact_obstacle(A, q, psi) if exact else None


def exact_box_if_small(A, q, lower, upper, exact, max_n: int = 20_000):
    """A box scene's ``z_exact``: :func:`solve_exact_box` (``upper`` None: +inf) when ``exact``
    (None: n ≤ ``max_n``)."""
    if exact is None:
        exact = A.shape[0] <= max_n
    if not exact:
        return None
    return solve_exact_box(A, q, lower, np.full(A.shape[0], np.inf) if upper is None else upper)


def solve_exact_obstacle(A, q, psi, z0=None, maxiter: int | None = None) -> np.ndarray:
    """Exact solution of min(A z + q, z − ψ) = 0 (constant obstacle ψ), A an M-matrix.

    Policy iteration: with z the current iterate, the active set is where z − ψ < A z + q
    (the obstacle row gives the smaller value); solve z = ψ there and (A z + q) = 0 elsewhere.
    ``z0`` warm-starts the active set. Raises RuntimeError if it has not settled in
    ``maxiter`` steps (default n + 1: for an M-matrix it cannot cycle, and in 1D its free boundary may move a
    node a step).
    """
    A = sp.csr_matrix(A, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    psi = np.asarray(psi, dtype=np.float64)
    normA = spla.norm(A, np.inf)
    maxiter = A.shape[0] + 1 if maxiter is None else maxiter
    if z0 is None:
        z = spla.spsolve(A.tocsc(), -q)
        active = z < psi
    else:
        z = np.asarray(z0, dtype=np.float64)
        active = (z - psi) < (A @ z + q)
    for _ in range(maxiter):
        M = _policy_matrix(A, active)
        rhs = np.where(active, psi, -q)
        z = spla.spsolve(M.tocsc(), rhs)
        w = A @ z + q
        new_active = (z - psi) < w
        # Stop when the active set repeats or min(w, z − ψ) vanishes to rounding (ties,
        # where both are ~0, may flip sides without changing z).
        scale = normA * np.max(np.abs(z)) + np.max(np.abs(q)) + np.max(np.abs(psi))
        if np.array_equal(new_active, active) or \
                np.max(np.abs(np.minimum(w, z - psi))) <= 100 * np.finfo(float).eps * scale:
            return z
        active = new_active
    raise RuntimeError(f"solve_exact_obstacle: policy iteration did not settle in {maxiter} steps")


def solve_exact_box(A, q, lower, upper, z0=None, maxiter: int = 500) -> np.ndarray:
    """Exact solution of the box problem lower ≤ z ≤ upper, w = A z + q ≥ 0 where z = lower,
    ≤ 0 where z = upper, = 0 between (±inf entries: no bound there), i.e. mid(z − lower,
    z − upper, w) = 0.

    Policy iteration (the primal–dual active-set method) with three states from x = z − w/diag(A):
    at the lower bound where x < lower, at the upper one where x > upper, else w = 0; one sparse
    solve per step. Weighting w by 1/diag(A) matters with two bounds: comparing z − bound with w
    itself (solve_exact_obstacle's rule) flips rows between the bounds forever when A ~ 1/h².
    Settled on every scene measured (M-matrices, and the SPD elastic-contact matrices).
    Raises RuntimeError if it has not settled in ``maxiter`` steps.
    """
    A = sp.csr_matrix(A, dtype=np.float64)
    q, lower, upper = (np.asarray(v, dtype=np.float64) for v in (q, lower, upper))
    z = spla.spsolve(A.tocsc(), -q) if z0 is None else np.asarray(z0, dtype=np.float64)
    normA, d, state = spla.norm(A, np.inf), A.diagonal(), None
    for _ in range(maxiter):
        w = A @ z + q
        x = z - w / d
        at_lower, at_upper = x < lower, x > upper     # ±inf bounds: False there
        with np.errstate(invalid="ignore"):
            mid = np.minimum(z - lower, np.maximum(z - upper, w))
        new = at_lower.astype(np.int8) - at_upper.astype(np.int8)
        # settled: the states repeat, or mid vanishes to rounding (ties may flip without changing z)
        floor = 100 * np.finfo(float).eps * (normA * np.max(np.abs(z)) + np.max(np.abs(q)))
        if state is not None and (np.array_equal(new, state) or np.max(np.abs(mid)) <= floor):
            return z
        state = new
        rhs = np.where(at_lower, lower, np.where(at_upper, upper, -q))
        z = spla.spsolve(_policy_matrix(A, state != 0).tocsc(), rhs)
    raise RuntimeError(f"solve_exact_box: policy iteration did not settle in {maxiter} steps")


def solve_exact_qvi(A, q, zeta_fn, lipschitz: float, z0=None, tol: float = 1e-13,
                    maxiter: int = 200) -> np.ndarray:
    """Exact solution of min(A z + q, z − ζ(z)) = 0 for a contraction ζ (lipschitz < 1).

    Fixed point of z ↦ S(ζ(z)), S(ψ) = solution of the obstacle problem with obstacle ψ.
    For an M-matrix A, S is 1-Lipschitz in the ∞-norm, so the map contracts with factor
    ``lipschitz``; each obstacle problem is solved exactly by :func:`solve_exact_obstacle`.
    Stops as :func:`exact_fixed_point` does.
    """
    if not lipschitz < 1.0:
        raise ValueError(f"solve_exact_qvi needs a contraction, got lipschitz={lipschitz}")
    A = sp.csr_matrix(A, dtype=np.float64)
    z = solve_exact_obstacle(A, q, np.array(zeta_fn(np.zeros(A.shape[0])))) if z0 is None else np.asarray(z0, float)
    return exact_fixed_point(lambda v: solve_exact_obstacle(A, q, np.array(zeta_fn(v)), z0=v), z, lipschitz, tol,
                             maxiter, "solve_exact_qvi")


def exact_fixed_point(step_map, z: np.ndarray, lipschitz: float, tol: float, maxiter: int, who: str) -> np.ndarray:
    """The fixed point of ``step_map`` (an outer step of exact inner solves, a contraction with constant
    ``lipschitz``) from z. Stops when the ∞-norm step is below tol · max(1, ‖z‖∞), or below 1e-9 of that
    scale and no longer contracting at the map's rate (a step above max(0.5, lipschitz) × the one before
    it, which a contraction with that constant cannot take: the rounding floor of the inner solves,
    ~1e-13 for h⁻²-scaled A). RuntimeError naming ``who`` after maxiter steps."""
    prev = np.inf
    for _ in range(maxiter):
        z_new = step_map(z)
        step = np.max(np.abs(z_new - z))
        z = z_new
        scale = max(1.0, np.max(np.abs(z)))
        if step <= tol * scale or (step <= 1e-9 * scale and step > max(0.5, lipschitz) * prev):
            return z
        prev = step
    raise RuntimeError(f"{who}: no convergence in {maxiter} outer steps")
