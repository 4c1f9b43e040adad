"""Test problems with a known solution: Bai's matrices, as LCP and as ICP.

Bai's matrices (n = m*m) are the scene's, nrmicp.scenes.bai.bai_matrix (its docstring gives
them). With mu = 4 the diagonal of A is 8 and A is strictly diagonally dominant (a P-matrix),
so every problem below has exactly one solution. The known solutions here are random (the
scene's are periodic), so the tests see other active sets than the scene.

Known solution.  Pick z*, and a split of the indices into an "active" set, where
g*_i = z*_i - zeta(z*)_i = 0 and w*_i > 0, and an "inactive" set, where g*_i > 0 and w*_i = 0.
Then q = w* - A z* makes z* the solution:  w* = A z* + q >= 0,  g* >= 0,  g*^T w* = 0.

Three kinds of ICP, each with its shift s chosen so that z* - zeta(z*) = g*:
  'icp'       zeta(z) = c*sin(z) + s   (componentwise, Lipschitz constant c; a Python callable)
  'affine'    zeta(z) = B z + s        (B sparse, ||B||_inf = c; nrmicp evaluates it in C++)
  'obstacle'  zeta(z) = s              (a constant obstacle; nrmicp solves the shifted LCP)
"""

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import scipy.sparse as sp

from nrmicp.scenes.bai import bai_matrix


def tridiag(m, sub, diag, sup):
    """m x m tridiagonal matrix with constant sub-, main and super-diagonal."""
    return sp.diags([np.full(m - 1, sub), np.full(m, diag), np.full(m - 1, sup)], [-1, 0, 1])


def readme_membrane(m):
    """The README's worked example on an m x m grid: (A = 5-point -Delta_h / h^2, q = 8, the
    paraboloid obstacle psi)."""
    h = 1.0 / (m + 1)
    T = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m))
    A = ((sp.kron(sp.identity(m), T) + sp.kron(T, sp.identity(m))) / h**2).tocsr()
    x = np.linspace(h, 1 - h, m)
    X, Y = np.meshgrid(x, x)
    psi = (0.3 - 2 * ((X - .5) ** 2 + (Y - .5) ** 2)).ravel()
    return A, np.full(m * m, 8.0), psi


@dataclass
class Problem:
    """ICP(q, A, zeta) with its known solution z_star.  zeta is None for an LCP."""
    name: str
    A: sp.csr_matrix
    q: np.ndarray
    zeta: Optional[Callable[[np.ndarray], np.ndarray]]
    z_star: np.ndarray
    w_star: np.ndarray
    g_star: np.ndarray


def known_solution_parts(n, seed=0):
    """z*, g*, w* with a deterministic mixed active set.

    About half of the indices are active (g_i = 0, w_i > 0), the others inactive
    (g_i > 0, w_i = 0).  Values are bounded away from 0 (in [0.5, 1.5]) so that the
    strict complementarity of the solution is clear-cut.
    """
    rng = np.random.default_rng(seed)
    active = rng.random(n) < 0.5
    g_star = np.where(active, 0.0, rng.uniform(0.5, 1.5, n))
    w_star = np.where(active, rng.uniform(0.5, 1.5, n), 0.0)
    return active, g_star, w_star


def make_lcp(m, symmetric=True, seed=0):
    """LCP(q, A) (zeta = 0): z* = g*."""
    A = bai_matrix(m, symmetric=symmetric)
    n = A.shape[0]
    _, g_star, w_star = known_solution_parts(n, seed)
    z_star = g_star.copy()
    q = w_star - A @ z_star
    name = f"lcp-{'sym' if symmetric else 'nonsym'}-m{m}"
    return Problem(name, A, q, None, z_star, w_star, g_star)


def make_icp(m, symmetric=True, c=0.1, seed=0):
    """ICP(q, A, zeta) with zeta(z) = c*sin(z) + s and a known solution z*."""
    A = bai_matrix(m, symmetric=symmetric)
    n = A.shape[0]
    _, g_star, w_star = known_solution_parts(n, seed)
    rng = np.random.default_rng(seed + 1)
    z_star = g_star + rng.uniform(-1.0, 1.0, n)   # z* is no longer g*: the obstacle is nonzero
    s = z_star - g_star - c * np.sin(z_star)

    def zeta(z):
        return c * np.sin(z) + s

    assert np.allclose(z_star - zeta(z_star), g_star, atol=1e-14)
    q = w_star - A @ z_star
    name = f"icp-{'sym' if symmetric else 'nonsym'}-m{m}"
    return Problem(name, A, q, zeta, z_star, w_star, g_star)


class AffineZeta:
    """zeta(z) = B z + c."""
    def __init__(self, B, c):
        self.B, self.c = B, c

    def __call__(self, z):
        return self.B @ z + self.c


class ConstantZeta:
    """zeta(z) = c."""
    def __init__(self, c):
        self.c = c

    def __call__(self, z):
        return self.c.copy()


def make_affine_icp(m, symmetric=True, c=0.1, seed=0):
    """ICP with zeta(z) = B z + s, B = c * tridiag(0.5, 0, 0.5) (so ||B||_inf <= c)."""
    A = bai_matrix(m, symmetric=symmetric)
    n = A.shape[0]
    _, g_star, w_star = known_solution_parts(n, seed)
    rng = np.random.default_rng(seed + 2)
    z_star = g_star + rng.uniform(-1.0, 1.0, n)
    B = sp.csr_matrix(c * tridiag(n, 0.5, 0.0, 0.5))
    zeta = AffineZeta(B, z_star - g_star - B @ z_star)
    assert np.allclose(z_star - zeta(z_star), g_star, atol=1e-14)
    q = w_star - A @ z_star
    name = f"affine-{'sym' if symmetric else 'nonsym'}-m{m}"
    return Problem(name, A, q, zeta, z_star, w_star, g_star)


def make_obstacle_icp(m, symmetric=True, seed=0):
    """ICP with a constant obstacle zeta(z) = s."""
    A = bai_matrix(m, symmetric=symmetric)
    n = A.shape[0]
    _, g_star, w_star = known_solution_parts(n, seed)
    rng = np.random.default_rng(seed + 3)
    z_star = g_star + rng.uniform(-1.0, 1.0, n)
    zeta = ConstantZeta(z_star - g_star)
    q = w_star - A @ z_star
    name = f"obstacle-{'sym' if symmetric else 'nonsym'}-m{m}"
    return Problem(name, A, q, zeta, z_star, w_star, g_star)


PROBLEM_KINDS = {"lcp": make_lcp, "icp": make_icp, "affine": make_affine_icp,
                 "obstacle": make_obstacle_icp}


def make_problem(kind, m, symmetric=True):
    """kind is 'lcp', 'icp', 'affine' or 'obstacle'."""
    if kind not in PROBLEM_KINDS:
        raise ValueError(f"unknown problem kind {kind!r}")
    return PROBLEM_KINDS[kind](m, symmetric)
