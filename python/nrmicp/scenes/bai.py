"""Bai's test matrices (Z.-Z. Bai, 2010, modulus-based matrix splitting methods for LCPs).

A = Â + μ I with Â = blocktridiag(−I, S, −I), S = tridiag(−1, 4, −1) (symmetric) or
Â = blocktridiag(−1.5 I, S, −0.5 I), S = tridiag(−1.5, 4, −0.5) (nonsymmetric); the first
argument is the sub-diagonal (block). n = m². Both are M-matrices for μ ≥ 0.

The solution is known by construction: choose z* and a strictly complementary pair
(w*, g*), then set q = w* − A z* and (for an ICP) the shift s of ζ so that
g* = z* − ζ(z*). Pure linear algebra: no physical units.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from . import Problem
from ._operators import as_csr, tridiag


def bai_matrix(m: int, mu: float = 4.0, symmetric: bool = True) -> sp.csr_matrix:
    """A = Â + μI of size m² (see the module docstring)."""
    if m < 1:
        raise ValueError(f"m must be >= 1, got {m}")
    lo, up = (-1.0, -1.0) if symmetric else (-1.5, -0.5)
    S = tridiag(m, lo, 4.0, up)
    T = tridiag(m, lo, 0.0, up)  # block pattern: sub-diagonal block lo*I, super-diagonal up*I
    eye = sp.identity(m, format="csr")
    A = sp.kron(eye, S) + sp.kron(T, eye) + mu * sp.identity(m * m)
    return as_csr(A)


def bai(m: int, mu: float = 4.0, symmetric: bool = True, kind: str = "lcp",
        c: float = 0.5) -> Problem:
    """Bai's LCP, or an ICP built on the same matrix, with a known solution.

    Parameters
    ----------
    m : grid side; n = m².
    mu : diagonal shift μ (Bai uses 4; μ = 0 exposes the h⁻²-like iteration growth).
    symmetric : symmetric or nonsymmetric Â (see the module docstring).
    kind : ``"lcp"`` (ζ ≡ 0, passed as None), ``"icp"`` (ζ(z) = c·sin(z) + s, a nonlinear
        callable, Lipschitz |c|) or ``"affine"`` (ζ(z) = (c/2)·tridiag(1, 0, 1) z + s,
        passed as ``nrmicp.Affine``, Lipschitz |c|; needs nrmicp importable).
    c : strength of the ζ coupling (ignored for ``"lcp"``).

    Construction: alternate components are active. With i = 0, 1, …:
    even i: g*_i = 0, w*_i = 1;  odd i: g*_i = 1 + (i mod 3)/2, w*_i = 0.
    LCP: z* = g*. ICP/affine: z*_i = 1 + ½ cos(i) (all positive, varied), s chosen so that
    z* − ζ(z*) = g*. q = w* − A z*.
    """
    if kind not in ("lcp", "icp", "affine"):
        raise ValueError(f"kind must be 'lcp', 'icp' or 'affine', got {kind!r}")
    A = bai_matrix(m, mu, symmetric)
    n = m * m
    i = np.arange(n)
    even = (i % 2) == 0
    w_star = np.where(even, 1.0, 0.0)
    g_star = np.where(even, 0.0, 1.0 + 0.5 * (i % 3))
    tag = f"bai(m={m}, mu={mu}, {'sym' if symmetric else 'nonsym'}, {kind})"
    common = dict(omits=("any physical model: a synthetic matrix test",))

    if kind == "lcp":
        z_star = g_star.copy()
        return Problem(
            name=tag, A=A, q=w_star - A @ z_star, zeta=None, z_exact=z_star, reference={},
            description=f"Bai's {'symmetric' if symmetric else 'nonsymmetric'} block-tridiagonal LCP, n={n}, mu={mu}",
            models=("M-matrix LCP with a strictly complementary known solution",),
            lipschitz=0.0, **common)

    z_star = 1.0 + 0.5 * np.cos(i)
    if kind == "icp":
        s = z_star - c * np.sin(z_star) - g_star
        buf = np.empty(n)

        def zeta(z, _buf=buf, _c=c, _s=s):
            """ζ(z) = c·sin(z) + s, written into a reused buffer."""
            np.sin(z, out=_buf)
            _buf *= _c
            _buf += _s
            return _buf

        return Problem(
            name=tag, A=A, q=w_star - A @ z_star, zeta=zeta, z_exact=z_star, reference={"c": c},
            description=f"Bai's matrix with the nonlinear implicit obstacle zeta(z) = {c} sin(z) + s, n={n}",
            models=("M-matrix ICP", "componentwise nonlinear obstacle, Lipschitz |c|"),
            lipschitz=abs(c), **common)

    import nrmicp  # affine: evaluated in C++

    B = as_csr(tridiag(n, 0.5 * c, 0.0, 0.5 * c))
    s = z_star - B @ z_star - g_star
    return Problem(
        name=tag, A=A, q=w_star - A @ z_star, zeta=nrmicp.Affine(B, s), z_exact=z_star,
        reference={"c": c},
        description=f"Bai's matrix with the affine obstacle zeta(z) = B z + s, B = {c}/2 tridiag(1,0,1), n={n}",
        models=("M-matrix ICP", "affine coupled obstacle, Lipschitz |c|"),
        lipschitz=abs(c), **common)
