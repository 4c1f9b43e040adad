"""Thermoforming: a membrane pressed onto a mould that expands with its temperature.

A quasi-variational inequality (after Alphonse, Hintermüller & Rautenberg's thermoforming
model, simplified to a linear heat balance and a prescribed heat-transfer law). Dimensionless
units: unit domain, unit membrane tension, temperature measured from ambient.

    membrane:  −Δu ≥ f,  u ≥ Φ(T),  (−Δu − f)(u − Φ(T)) = 0,  u = 0 on ∂Ω,
    mould:     Φ(T) = Φ₀ + κ T                      (linear thermal expansion, coefficient κ)
    heat:      T − δ ΔT = s(u),  T = 0 on ∂Ω         (conduction δ, exchange with ambient)
    transfer:  s(u) = 1 / (1 + ((u − Φ₀)/ℓ)²)        (the hot membrane heats the mould; the
                                                      flux decays with the gap u − Φ₀ over ℓ)

f < 0 is the forming pressure pushing the membrane down onto the mould. Discretized with
the same finite differences as :mod:`.obstacle` (A = −Δ_h, q = −f), the ICP in z = u has

    ζ(z) = Φ₀ + κ (I − δΔ_h)⁻¹ s(z)      — nonlinear and nonlocal: a Python callable.

(I − δΔ_h) is factorized once (scipy ``splu``, minimum-degree ordering) when the scene is built;
each call of ζ is a handful of vectorized numpy operations, one pair of triangular solves, and
writes into a preallocated buffer (overwritten by the next call). Its derivative
ζ′(z) = κ (I − δΔ_h)⁻¹ diag(s′(z)) is dense: :func:`thermoforming_zeta_jacobian` gives it as a
``LinearOperator`` (one pair of triangular solves a product) for ``zeta_jacobian``.

Lipschitz constant (∞-norm): (I − δΔ_h) is an M-matrix with row sums ≥ 1, so
‖(I − δΔ_h)⁻¹‖∞ ≤ 1, and |s'| ≤ 3√3/(8ℓ); hence L = κ·3√3/(8ℓ) (0.162 with the defaults
κ = 0.05, ℓ = 0.2) — a contraction, so the QVI has a unique solution.

Left out: the membrane's own temperature and its temperature-dependent stiffness, heat
transfer through contact (a contact-set-dependent coefficient), time dependence (the real
process is transient), large deflections, the mould's mechanical deformation.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla

from . import Problem
from ._exact import solve_exact_qvi
from ._operators import grid_1d, grid_2d, heat_solve, neg_laplacian_1d, neg_laplacian_2d

_MODELS = ("linear elastic membrane under forming pressure", "unilateral contact with a mould",
           "mould thermal expansion driven by a membrane-heated temperature field (nonlocal)")
_OMITS = ("transient heating (steady state only)", "membrane temperature and thermo-elasticity",
          "contact-dependent heat transfer coefficient", "large deflections", "mould deformation")


def _thermo_zeta(solve, phi0: np.ndarray, kappa: float, ell: float):
    """Build ζ(z) = Φ₀ + κ (I − δL)⁻¹ s(z) from the prefactorized solve, with reused buffers."""
    n = phi0.size
    src = np.empty(n)
    out = np.empty(n)

    def zeta(z, _solve=solve, _src=src, _out=out, _phi0=phi0, _k=kappa, _ell=ell):
        """ζ(z) = Φ₀ + κ (I − δΔ_h)⁻¹ [1 / (1 + ((z − Φ₀)/ℓ)²)]; returns a reused buffer."""
        np.subtract(z, _phi0, out=_src)
        _src *= 1.0 / _ell
        np.multiply(_src, _src, out=_src)
        _src += 1.0
        np.reciprocal(_src, out=_src)
        np.multiply(_solve(_src), _k, out=_out)
        _out += _phi0
        return _out

    return zeta


def thermoforming_zeta_jacobian(problem: Problem):
    """ζ′ of a thermoforming problem's ζ, for ``zeta_jacobian``: at z the ``LinearOperator``
    v ↦ κ (I − δΔ_h)⁻¹ (s′(z) v), s′(z) = −2u/(ℓ(1 + u²)²), u = (z − Φ₀)/ℓ (dense as a matrix;
    each product one pair of triangular solves with the scene's factorization)."""
    ref = problem.reference
    phi0, kappa, ell, solve, n = ref["phi0"], ref["kappa"], ref["ell"], ref["heat_solve"], problem.n

    def jacobian(z):
        u = (np.asarray(z, dtype=float) - phi0) / ell
        ds = kappa * -2.0 * u / ell / (1.0 + u * u) ** 2
        return spla.LinearOperator((n, n), matvec=lambda v: solve(ds * np.ravel(v)), dtype=float)

    return jacobian


def _problem(name, dim, L, phi0, f, kappa, delta, ell, exact, extra_ref, grid):
    if not (kappa >= 0 and delta >= 0 and ell > 0):
        raise ValueError(f"need kappa >= 0, delta >= 0, ell > 0; got {kappa}, {delta}, {ell}")
    lip = kappa * 3.0 * np.sqrt(3.0) / (8.0 * ell)
    solve = heat_solve(L, delta)
    zeta = _thermo_zeta(solve, phi0, kappa, ell)
    q = np.full(phi0.size, -float(f))
    z_exact = None
    if exact and lip < 1.0:
        # the reference solver must not share the scene's buffers
        z_exact = solve_exact_qvi(L, q, _thermo_zeta(solve, phi0, kappa, ell), lip)
    ref = {"phi0": phi0, "kappa": kappa, "delta": delta, "ell": ell, "f": f, "heat_solve": solve}
    ref.update(extra_ref)
    return Problem(
        name=name, A=L, q=q, zeta=zeta, z_exact=z_exact, reference=ref,
        description=f"{dim} thermoforming QVI: membrane on a mould expanding with a membrane-heated temperature",
        models=_MODELS, omits=_OMITS, lipschitz=float(lip), grid=grid)


def thermoforming_1d(n: int, f: float = -10.0, kappa: float = 0.05, delta: float = 0.01,
                     ell: float = 0.2, exact: bool = True) -> Problem:
    """1D thermoforming QVI on n interior nodes, h = 1/(n + 1).

    Mould Φ₀(x) = −0.45 + 0.2 sin²(2πx) (two ribs); pressure f (default −10: the free
    membrane would sag to −1.25, well into the mould). ``z_exact``: exact discrete solution
    (fixed point of exact obstacle solves) unless ``exact=False``.
    """
    L = neg_laplacian_1d(n)
    x = grid_1d(n)
    phi0 = -0.45 + 0.2 * np.sin(2 * np.pi * x) ** 2
    return _problem(f"thermoforming_1d(n={n})", "1D", L, phi0, f, kappa, delta, ell, exact,
                    {"x": x, "h": 1.0 / (n + 1)}, (n,))


def thermoforming_2d(m: int, f: float = -10.0, kappa: float = 0.05, delta: float = 0.01,
                     ell: float = 0.2, exact=None) -> Problem:
    """2D thermoforming QVI on m × m interior nodes of (0, 1)², h = 1/(m + 1).

    Mould Φ₀(x, y) = −0.3 + 0.15 sin²(2πx) sin²(2πy) (a 2 × 2 array of bumps); pressure f
    (default −10: the free membrane sags to about −0.74). ``z_exact`` is computed when
    ``exact`` is True (default: when n ≤ 20 000).
    """
    L = neg_laplacian_2d(m)
    X, Y = grid_2d(m)
    phi0 = -0.3 + 0.15 * np.sin(2 * np.pi * X) ** 2 * np.sin(2 * np.pi * Y) ** 2
    if exact is None:
        exact = m * m <= 20_000
    return _problem(f"thermoforming_2d(m={m})", "2D", L, phi0, f, kappa, delta, ell, exact,
                    {"x": X, "y": Y, "h": 1.0 / (m + 1)}, (m, m))
