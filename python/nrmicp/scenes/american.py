"""American put under Black–Scholes: one linear complementarity problem per time step.

Model: V(S, τ), τ = T − t time to expiry, with

    min( V_τ − ½σ²S²V_SS − rSV_S + rV,  V − (K − S)⁺ ) = 0,   V(S, 0) = (K − S)⁺,

on S ∈ [0, S_max] with V(0, τ) = K (exercise at once) and V(S_max, τ) = 0 (truncation).
Units: S and K in currency, r and σ per year, T in years.

Discretization: uniform S grid S_i = i ΔS, ΔS = S_max/n_space, unknowns at the interior
nodes i = 1..n_space−1; central differences (the drift term falls back to a forward,
upwind difference at the few nodes where central differencing would break the M-matrix
sign pattern, i.e. i < r/σ²). Time: Crank–Nicolson with Rannacher start-up — the first
``rannacher`` steps are each replaced by two backward-Euler half steps, which damps the
payoff kink. Both use the *same* matrix

    A = I − (Δτ/2) 𝓛_h          (an M-matrix),

so one ``nrmicp.Solver`` serves the whole march. Each step is ICP(q_k, A, ζ) with
q_k = −(right-hand side) and ζ = the payoff vector: a constant obstacle, passed as an ndarray
(a shifted LCP, no callback).

Left out: dividends, discrete monitoring, transaction costs, stochastic volatility or
rates, the S_max truncation error (small for S_max ≥ 4K), nonuniform grids.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from . import Problem
from ._exact import solve_exact_obstacle
from ._operators import as_csr


def _bs_operator(S_max: float, r: float, sigma: float, n_space: int):
    """(L_h, a1, S): interior Black–Scholes operator 𝓛_h V = ½σ²S²V_SS + rSV_S − rV,
    the coefficient a1 of the boundary value V_0 in row 1, and the full grid S."""
    if n_space < 4:
        raise ValueError(f"n_space must be >= 4, got {n_space}")
    i = np.arange(1, n_space, dtype=float)
    alpha = 0.5 * sigma**2 * i**2   # ½σ²S²/ΔS²
    beta = 0.5 * r * i              # rS/(2ΔS)
    lower = alpha - beta
    upper = alpha + beta
    diag = -(2.0 * alpha + r)
    fwd = lower < 0                 # upwind (forward) drift where central would be positive-off-diagonal
    lower = np.where(fwd, alpha, lower)
    upper = np.where(fwd, alpha + r * i, upper)
    diag = np.where(fwd, -(2.0 * alpha + r * i + r), diag)
    L = sp.diags([lower[1:], diag, upper[:-1]], [-1, 0, 1], shape=(n_space - 1, n_space - 1))
    S = np.linspace(0.0, S_max, n_space + 1)
    return as_csr(L), float(lower[0]), S


class _March:
    """The fixed parts of a Rannacher/Crank–Nicolson march (matrix, payoff, boundary terms)."""

    def __init__(self, S_max, K, r, sigma, T, n_space, n_time, rannacher):
        if not (K > 0 and sigma > 0 and T > 0 and S_max > K):
            raise ValueError(f"need K > 0, sigma > 0, T > 0, S_max > K; got K={K}, sigma={sigma}, T={T}, S_max={S_max}")
        if not 0 <= rannacher <= n_time:
            raise ValueError(f"rannacher must be in [0, n_time], got {rannacher}")
        self.L, self.a1, self.S = _bs_operator(S_max, r, sigma, n_space)
        self.K, self.n_time, self.rannacher = K, n_time, rannacher
        self.dt = T / n_time
        n = n_space - 1
        self.A = as_csr(sp.identity(n) - 0.5 * self.dt * self.L)
        self.B = as_csr(sp.identity(n) + 0.5 * self.dt * self.L)   # CN explicit half
        self.payoff = np.maximum(K - self.S[1:-1], 0.0)
        self.e1K = np.zeros(n)
        self.e1K[0] = self.a1 * K

    def steps(self):
        """Yield the kind of each LCP solve: 'be' (half step) or 'cn' (full step)."""
        for k in range(self.n_time):
            if k < self.rannacher:
                yield "be"
                yield "be"
            else:
                yield "cn"

    def q(self, kind, v):
        """q for the next LCP from the current interior values v."""
        if kind == "be":   # (I − Δτ/2 𝓛) v⁺ = v + Δτ/2·a1 K e1
            return -(v + 0.5 * self.dt * self.e1K)
        return -(self.B @ v + self.dt * self.e1K)  # CN

    def full(self, v):
        """Values on the whole grid including V(0) = K and V(S_max) = 0."""
        return np.concatenate(([self.K], v, [0.0]))


def american_put(S_max: float = 400.0, K: float = 100.0, r: float = 0.05, sigma: float = 0.2,
                 T: float = 1.0, n_space: int = 800, n_time: int = 100, rannacher: int = 2,
                 exact: bool = True) -> Problem:
    """The *first* LCP of the American-put march (a Rannacher backward-Euler half step from
    the payoff), for benchmarks; :func:`american_put_price` runs the whole march.

    n = n_space − 1 unknowns (the interior S nodes). ζ is the payoff vector (ndarray).
    ``z_exact`` is the exact solution of this LCP (policy iteration) unless ``exact=False``.
    """
    m = _March(S_max, K, r, sigma, T, n_space, n_time, rannacher)
    kind = next(m.steps())
    q = m.q(kind, m.payoff)
    return Problem(
        name=f"american_put(n_space={n_space}, n_time={n_time})", A=m.A, q=q, zeta=m.payoff.copy(),
        z_exact=solve_exact_obstacle(m.A, q, m.payoff) if exact else None,
        reference={"S": m.S[1:-1], "K": K, "r": r, "sigma": sigma, "T": T, "dt": m.dt,
                   "step": "backward-Euler half step (Rannacher start-up)" if kind == "be" else "Crank-Nicolson"},
        description=f"first time step of an American put, Black-Scholes, K={K}, sigma={sigma}, r={r} (shifted LCP)",
        models=("Black-Scholes dynamics", "early exercise (payoff obstacle)"),
        omits=("dividends", "transaction costs", "stochastic volatility or rates",
               "all later time steps (see american_put_price)"),
        lipschitz=0.0, grid=(n_space - 1,))


def _nested_first_step(solver, A, method, solver_options):
    """The Solver for the march's first step. Started from the payoff, Newton without a hierarchy
    moves the exercise boundary about one node per step: unless the caller chose a hierarchy, a
    Newton march without one takes its first step from the nested start (the grid's geometric
    prolongations, else 'amg'; README "Which method for which problem")."""
    if method != "newton" or solver.levels > 1 or "hierarchy" in solver_options:
        return solver
    import nrmicp

    from ._operators import grid_prolongations

    hierarchy = grid_prolongations((A.shape[0],)) or "amg"
    return nrmicp.Solver(A, method=method, **dict(solver_options, hierarchy=hierarchy))


def american_put_price(S0: float, K: float = 100.0, r: float = 0.05, sigma: float = 0.2,
                       T: float = 1.0, S_max=None, n_space: int = 800, n_time: int = 100,
                       rannacher: int = 2, method: str = "nrmgs", tol: float = 1e-9,
                       maxiter: int = 100_000, full_output: bool = False, **solver_options):
    """Price of an American put at S0 by the full Rannacher/Crank–Nicolson march.

    ``method`` is an nrmicp method name: ``nrmicp.Solver(A, method=method, **solver_options)``
    is built once and ``solver.solve(q_k, zeta=payoff, x0=previous, tol=tol,
    maxiter=maxiter)`` is called at each step (warm start). With ``method="newton"`` and no
    ``hierarchy`` given, the first step (whose start, the payoff, is far from its solution) is
    solved from the nested start of a second Solver with the grid's prolongations ('amg' when
    the grid does not coarsen). ``method="exact"`` uses the
    policy-iteration reference solver instead (no nrmicp needed). The price is read off a
    cubic spline through the grid values at S0. ``S_max`` defaults to 4·max(K, S0).

    Returns the price, or ``(price, info)`` with ``full_output=True``; info holds the grid
    ``S``, the values ``V``, per-step ``nit`` and ``residual`` (nrmicp only), ``seconds``
    and whether every step converged (``success``).
    """
    if method == "exact":
        run = lambda m: _exact_march(m, lambda q, v: solve_exact_obstacle(m.A, q, m.payoff, z0=v))  # noqa: E731
    else:   # set up for the rule the march solves by
        run = lambda m: _solver_march(m, method, m.payoff, None, dict(solver_options, tol=tol),  # noqa: E731
                                      tol=tol, maxiter=maxiter)
    return _march_price(S0, K, r, sigma, T, S_max, n_space, n_time, rannacher, full_output, run)


def _march_price(S0, K, r, sigma, T, S_max, n_space, n_time, rannacher, full_output, run):
    """A put's price by the march (the American and the game put's): the grid (S_max defaults to
    4·max(K, S0)), ``run(march)`` -> (last values, per-step nit, per-step Res, every step converged),
    the price read off a cubic spline at S0; with ``full_output`` also the info dict."""
    from scipy.interpolate import CubicSpline

    if S_max is None:
        S_max = 4.0 * max(K, S0)
    if not 0 < S0 < S_max:
        raise ValueError(f"need 0 < S0 < S_max, got S0={S0}, S_max={S_max}")
    m = _March(S_max, K, r, sigma, T, n_space, n_time, rannacher)
    t0 = time.perf_counter()
    v, nits, ress, ok = run(m)
    seconds = time.perf_counter() - t0
    V = m.full(v)
    price = float(CubicSpline(m.S, V)(S0))
    if not full_output:
        return price
    return price, {"S": m.S, "V": V, "nit": np.array(nits), "residual": np.array(ress),
                   "seconds": seconds, "success": ok}


def _exact_march(m, step):
    """The march by the reference solver: v ← step(q_k, v) from the payoff."""
    v = m.payoff.copy()
    for kind in m.steps():
        v = step(m.q(kind, v), v)
    return v, [], [], True


def _solver_march(m, method, lower, upper, setup_options, **solve_options):
    """The march with one nrmicp Solver (the first step from the nested start: _nested_first_step),
    lower ≤ v ≤ upper (None: no upper bound): (last values, per-step nit, per-step Res, all converged)."""
    import nrmicp

    solver = nrmicp.Solver(m.A, method=method, **setup_options)
    first = _nested_first_step(solver, m.A, method, setup_options)
    v, nits, ress, ok = lower.copy(), [], [], True
    for step, kind in enumerate(m.steps()):
        res = (first if step == 0 else solver).solve(m.q(kind, v), zeta=lower, upper=upper, x0=v, **solve_options)
        v = np.asarray(res.z, dtype=float).copy()
        nits.append(res.nit)
        ress.append(res.residual)
        ok = ok and bool(res.success)
    return v, nits, ress, ok


def crr_lattice(S0: float, r: float, sigma: float, T: float, steps: int) -> tuple:
    """The Cox–Ross–Rubinstein tree of `steps` steps: (u, discounted up and down probabilities, the
    prices at expiry S0 u^(2j − steps), j up-moves out of `steps`)."""
    dt = T / steps
    u = np.exp(sigma * np.sqrt(dt))
    d = 1.0 / u
    disc = np.exp(-r * dt)
    p = (np.exp(r * dt) - d) / (u - d)
    if not 0 < p < 1:
        raise ValueError(f"CRR probability {p} outside (0, 1): increase steps")
    return u, disc * p, disc * (1.0 - p), S0 * u ** (2.0 * np.arange(steps + 1) - steps)


def binomial_american_put(S0: float, K: float = 100.0, r: float = 0.05, sigma: float = 0.2,
                          T: float = 1.0, steps: int = 20000) -> float:
    """American put by the Cox–Ross–Rubinstein binomial tree (vectorized over each level).

    Independent of the PDE: an O(steps²) reference whose error decays like O(1/steps)
    (with an even/odd oscillation; average ``steps`` and ``steps + 1`` to damp it).
    """
    u, pu, pd, S = crr_lattice(S0, r, sigma, T, steps)
    V = np.maximum(K - S, 0.0)
    for k in range(steps - 1, -1, -1):
        S = S[: k + 1] * u                              # S_{k,j} = S_{k+1,j} / d
        V = pu * V[1 : k + 2] + pd * V[: k + 1]
        np.maximum(V, K - S, out=V)
    return float(V[0])
