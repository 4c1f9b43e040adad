"""A game (Israeli) put under Black–Scholes: a two-sided obstacle problem per time step.

Model (Kifer's game option): the holder may exercise at any time and receive L(S) = (K − S)⁺; the
issuer may cancel at any time and pay U(S) = (K − S)⁺ + ``penalty``. The value V(S, τ), τ = T − t,
solves the double obstacle problem

    L ≤ V ≤ U,   V_τ − 𝓛V ≥ 0 where V = L (exercise),   ≤ 0 where V = U (cancel),   = 0 between,

𝓛V = ½σ²S²V_SS + rSV_S − rV, V(S, 0) = L(S), V(0, τ) = K, V(S_max, τ) = 0. The issuer cancels
near the strike, where the holder's put is worth more than U.

Discretization: the American put's (nrmicp.scenes.american: the same S grid, operator and
Rannacher/Crank–Nicolson march, A = I − (Δτ/2)𝓛_h). Each step is a box problem in PATH's
convention, ``nrmicp.solve(A, q_k, zeta=L, upper=U)``: w = A V + q_k is the discrete
V_τ − 𝓛V times Δτ (≥ 0 where exercised, ≤ 0 where cancelled).

Left out: dividends, a time-dependent penalty, a finite cancellation window, what the American put
leaves out.
"""
from __future__ import annotations

import numpy as np

from . import Problem
from ._exact import solve_exact_box
from .american import _exact_march, _March, _march_price, _solver_march, crr_lattice

__all__ = ["game_put", "game_put_price", "binomial_game_put"]


def _check_penalty(penalty):
    if not penalty > 0:
        raise ValueError(f"penalty must be > 0 (the issuer pays more than the holder's payoff), got {penalty}")


def game_put(S_max: float = 400.0, K: float = 100.0, r: float = 0.05, sigma: float = 0.2, T: float = 1.0,
             penalty: float = 1.0, n_space: int = 800, n_time: int = 20, rannacher: int = 2,
             exact: bool = True) -> Problem:
    """The *first* box problem of the game-put march (a Rannacher backward-Euler half step from the
    payoff), for benchmarks; :func:`game_put_price` runs the whole march.

    n = n_space − 1 unknowns (the interior S nodes); ζ = L (the holder's payoff), upper = U = L +
    ``penalty``. Both are touched: the holder exercises deep in the money (S below about 0.93 K),
    the issuer cancels at the strike node (with a constant penalty the issuer's region is the
    strike alone: off it −𝓛U = r·U > 0, so V = U cannot hold there). The defaults make the step
    long enough (Δτ/2 = 0.025) for the put's time value at the strike to exceed the penalty.
    ``z_exact``: the exact solution of this step (policy iteration) unless ``exact=False``.
    """
    _check_penalty(penalty)
    m = _March(S_max, K, r, sigma, T, n_space, n_time, rannacher)
    kind = next(m.steps())
    q = m.q(kind, m.payoff)
    lower, upper = m.payoff.copy(), m.payoff + penalty
    return Problem(
        name=f"game_put(n_space={n_space}, n_time={n_time})", A=m.A, q=q, zeta=lower, upper=upper,
        z_exact=solve_exact_box(m.A, q, lower, upper) if exact else None,
        reference={"S": m.S[1:-1], "K": K, "r": r, "sigma": sigma, "T": T, "dt": m.dt, "penalty": penalty,
                   "step": "backward-Euler half step (Rannacher start-up)" if kind == "be" else "Crank-Nicolson"},
        description=f"first time step of a game put (cancellation penalty {penalty}), Black-Scholes, K={K}, "
                    f"sigma={sigma}, r={r} (box problem)",
        models=("Black-Scholes dynamics", "holder's early exercise (lower obstacle)",
                "issuer's cancellation with a penalty (upper obstacle)"),
        omits=("dividends", "time-dependent penalty", "all later time steps (see game_put_price)"),
        lipschitz=0.0, grid=(n_space - 1,))


def game_put_price(S0: float, K: float = 100.0, r: float = 0.05, sigma: float = 0.2, T: float = 1.0,
                   penalty: float = 5.0, S_max=None, n_space: int = 800, n_time: int = 100, rannacher: int = 2,
                   method: str = "newton", tol=None, full_output: bool = False, **solver_options):
    """Price of a game put at S0 by the full Rannacher/Crank–Nicolson march: one
    ``nrmicp.Solver(A, method='newton', **solver_options)`` and ``solver.solve(q_k, zeta=L,
    upper=U, x0=previous)`` per step (the first from the grid's nested start, as
    :func:`american_put_price`); ``method="exact"``: the policy-iteration reference instead (no
    nrmicp needed). The price is read off a cubic spline at S0; ``S_max`` defaults to 4·max(K, S0).
    With ``full_output``, ``(price, info)``: the grid ``S``, values ``V``, per-step ``nit``/``residual``
    (nrmicp only), ``seconds``, ``success`` (every step converged).
    """
    _check_penalty(penalty)
    if method not in ("newton", "exact"):
        raise ValueError(f"method must be 'newton' or 'exact', got {method!r}")

    def run(m):
        lower, upper = m.payoff, m.payoff + penalty
        if method == "exact":
            return _exact_march(m, lambda q, v: solve_exact_box(m.A, q, lower, upper, z0=v))
        return _solver_march(m, "newton", lower, upper, solver_options, tol=tol)

    return _march_price(S0, K, r, sigma, T, S_max, n_space, n_time, rannacher, full_output, run)


def binomial_game_put(S0: float, K: float = 100.0, r: float = 0.05, sigma: float = 0.2, T: float = 1.0,
                      penalty: float = 5.0, steps: int = 20000) -> float:
    """Game put by the Cox–Ross–Rubinstein tree: V = min(U, max(L, discounted continuation)) at
    every node before expiry, V = L at expiry. Independent of the PDE. The issuer cancels at the
    strike only, so the tree converges smoothly (O(1/steps)) only when K is one of its nodes, i.e.
    ln(K/S0)/(σ√(T/steps)) is an integer; elsewhere it jumps by ~1e-2 between step counts."""
    _check_penalty(penalty)
    u, pu, pd, S = crr_lattice(S0, r, sigma, T, steps)
    V = np.maximum(K - S, 0.0)
    for k in range(steps - 1, -1, -1):
        S = S[: k + 1] * u
        L = np.maximum(K - S, 0.0)
        V = np.minimum(L + penalty, np.maximum(L, pu * V[1: k + 2] + pd * V[: k + 1]))
    return float(V[0])
