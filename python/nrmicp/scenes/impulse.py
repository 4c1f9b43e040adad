"""Impulse control of a decaying diffusion: a 1D quasi-variational inequality.

Model (dimensionless). A level X_t ∈ [0, 1] (a stock, a machine's condition, a reservoir)
drifts down and diffuses, reflected at both ends:

    dX = b dt + σ dW,  b < 0 by default.

It earns the running reward f(x) = x per unit time, discounted at rate ρ. At any time the
controller may raise the level from x to any x' ≥ x, paying a fixed cost K plus a
proportional cost c·(x' − x). The value V solves the QVI

    min(ρV − 𝓛V − f,  V − 𝓜V) = 0,   𝓜V(x) = max_{x' ≥ x} [V(x') − c (x' − x)] − K,

with 𝓛 = ½σ² d²/dx² + b d/dx. Discretization on nodes x_i = i h, i = 0..n−1, h = 1/(n−1):
a Markov-chain (upwind) approximation of 𝓛 — central diffusion, upwinded drift, reflection
by mirroring the rate that would leave the grid — so A = ρI − 𝓛_h is a strictly diagonally
dominant M-matrix (margin ρ). As ICP(q, A, ζ) in z = V:

    A = ρI − 𝓛_h,   q = −f,   ζ(z)_i = max_{j ≥ i} (z_j − c x_j) + c x_i − K.

ζ is nonsmooth, nonlocal and Lipschitz 1 in the ∞-norm (not a contraction: well-posedness
comes from K > 0 and the discounting in A). It is evaluated with one suffix maximum
(``numpy.maximum.accumulate`` on the reversed array) into a preallocated buffer (overwritten
by the next call). Allowing j = i is harmless (it gives g_i = K > 0) and keeps ζ finite at
the right end, where no jump is possible.

Discretization artifact: the reflecting condition V'(0) = 0 is incompatible with the slope
V' = c of the value in the jump region, so a boundary layer of a few nodes at x = 0 is
(discretely) a continuation region; it shrinks with h and does not affect the policy.

Left out: downward jumps (selling, scrapping), delays or capacity limits on
interventions, state-dependent costs other than linear, jumps in the dynamics.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import Problem
from ._operators import as_csr


def generator_1d(n: int, sigma: float, b: float) -> sp.csr_matrix:
    """Upwind Markov-chain generator 𝓛_h of dX = b dt + σ dW on [0, 1], reflecting ends.

    Rates to the right ½σ²/h² + max(b, 0)/h, to the left ½σ²/h² + max(−b, 0)/h; a rate that
    would leave the grid is mirrored to the neighbour inside. Rows sum to zero.
    """
    if n < 3:
        raise ValueError(f"need n >= 3 nodes, got {n}")
    h = 1.0 / (n - 1)
    right = np.full(n, 0.5 * sigma**2 / h**2 + max(b, 0.0) / h)
    left = np.full(n, 0.5 * sigma**2 / h**2 + max(-b, 0.0) / h)
    up = right.copy()
    lo = left.copy()
    up[0] += left[0]       # node 0: the left move is reflected to node 1
    lo[-1] += right[-1]    # node n−1: the right move is reflected to node n−2
    L = sp.diags([lo[1:], -(right + left), up[:-1]], [-1, 0, 1], shape=(n, n))  # rows sum to 0
    return as_csr(L)


def _impulse_zeta(x: np.ndarray, cost: float, prop: float):
    """ζ(z)_i = max_{j ≥ i}(z_j − c x_j) + c x_i − K, with reused buffers."""
    cx = prop * x
    shift = cx - cost
    buf = np.empty_like(x)
    out = np.empty_like(x)
    rbuf = buf[::-1]

    def zeta(z, _buf=buf, _rbuf=rbuf, _out=out, _cx=cx, _shift=shift):
        """Best jump to the right minus its cost (suffix maximum); returns a reused buffer."""
        np.subtract(z, _cx, out=_buf)
        np.maximum.accumulate(_rbuf, out=_rbuf)
        np.add(_buf, _shift, out=_out)
        return _out

    return zeta


def solve_exact_impulse(A, q, x, cost: float, prop: float, maxiter: int = 500) -> np.ndarray:
    """Exact discrete solution of the impulse-control QVI by Howard's policy iteration.

    A policy chooses, at each node, to continue ((A z + q)_i = 0) or to jump to the best
    target j*(i) > i (z_i − z_{j*} = c(x_i − x_{j*}) − K). Jumps go strictly right, so every
    policy matrix is nonsingular; values increase monotonically and the iteration ends
    after finitely many steps.
    """
    n = x.size
    idx = np.arange(n)
    A = sp.csr_matrix(A)
    z = spla.spsolve(A.tocsc(), -q)
    jump = np.zeros(n, dtype=bool)
    target = idx.copy()
    for _ in range(maxiter):
        v = z - prop * x
        sufmax = np.maximum.accumulate(v[::-1])[::-1]
        record = np.where(v == sufmax, idx, n)
        new_target = np.minimum.accumulate(record[::-1])[::-1]  # first maximizer at or right of i
        g = z - (sufmax + prop * x - cost)
        w = A @ z + q
        new_jump = (g < w) & (new_target > idx)
        scale = np.max(np.abs(z)) * spla.norm(A, np.inf) + np.max(np.abs(q)) + cost
        settled = np.max(np.abs(np.minimum(w, g))) <= 100 * np.finfo(float).eps * scale
        if settled or (np.array_equal(new_jump, jump) and np.array_equal(new_target[jump], target[jump])):
            return z
        jump, target = new_jump, new_target
        rows_c = sp.diags((~jump).astype(float)) @ A
        ji = idx[jump]
        J = sp.csr_matrix((np.r_[np.ones(ji.size), -np.ones(ji.size)],
                           (np.r_[ji, ji], np.r_[ji, target[jump]])), shape=(n, n))
        M = sp.csc_matrix(rows_c + J)
        rhs = np.where(jump, prop * (x - x[target]) - cost, -q)
        z = spla.spsolve(M, rhs)
    raise RuntimeError(f"solve_exact_impulse: policy iteration did not settle in {maxiter} steps")


def impulse_zeta_jacobian(problem: Problem):
    """∂ζ of an :func:`impulse_control` problem's ζ(z)_i = max_{j≥i}(z_j − c x_j) + c x_i − K, for
    ``zeta_jacobian``: row i picks the first maximizer j*(i) (a selection matrix, an element of the
    generalized Jacobian)."""
    x, c = problem.reference["x"], problem.reference["prop"]
    n, idx = x.size, np.arange(x.size)

    def jacobian(z):
        v = z - c * x
        best = np.maximum.accumulate(v[::-1])[::-1]
        first = np.minimum.accumulate(np.where(v == best, idx, n)[::-1])[::-1]
        return sp.csr_matrix((np.ones(n), (idx, first)), shape=(n, n))

    return jacobian


def impulse_control(n: int, cost: float = 0.1, prop: float = 0.2, rho: float = 0.1,
                    sigma: float = 0.3, b: float = -0.5, exact: bool = True) -> Problem:
    """Impulse-control QVI (see the module docstring) on n nodes of [0, 1].

    Parameters: fixed cost K = ``cost``, proportional cost c = ``prop``, discount ρ, volatility
    σ, drift b. ``z_exact`` is the exact discrete solution by policy iteration unless
    ``exact=False``; ``reference`` holds the grid and, from z_exact, the intervention
    threshold (largest node where jumping is optimal) and the target level.
    """
    if cost <= 0:
        raise ValueError(f"the fixed cost must be positive (else the QVI degenerates), got {cost}")
    x = np.linspace(0.0, 1.0, n)
    A = as_csr(rho * sp.identity(n) - generator_1d(n, sigma, b))
    q = -x.copy()  # −f, f(x) = x
    zeta = _impulse_zeta(x, cost, prop)
    ref = {"x": x, "h": 1.0 / (n - 1), "rho": rho, "sigma": sigma, "b": b, "cost": cost, "prop": prop}
    z_exact = None
    if exact:
        z_exact = solve_exact_impulse(A, q, x, cost, prop)
        g = z_exact - _impulse_zeta(x, cost, prop)(z_exact)
        w = A @ z_exact + q
        act = np.flatnonzero(g <= w)
        if act.size:
            ref["threshold"] = float(x[act.max()])
            ref["target"] = float(x[np.argmax(z_exact - prop * x)])
    return Problem(
        name=f"impulse_control(n={n}, K={cost})", A=A, q=q, zeta=zeta, z_exact=z_exact,
        reference=ref,
        description=f"1D impulse-control QVI, upward jumps at cost {cost} + {prop}*size, n={n}",
        models=("discounted reward of a reflected diffusion", "fixed + proportional intervention cost",
                "optimal timing and size of upward jumps (nonsmooth, nonlocal obstacle)"),
        omits=("downward jumps", "intervention delays and capacity limits",
               "jumps in the uncontrolled dynamics", "finite horizon (stationary problem)"),
        lipschitz=1.0,
        # ζ has Lipschitz constant 1: the explicit z-update (the default) does not converge in
        # 20,000 iterations here, the paper's 'solve' update does (measured, n = 201).
        solver_options={"z_update": "solve"})
