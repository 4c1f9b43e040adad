"""Finite-difference operators shared by the scenes (all returned as CSR float64)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def tridiag(n: int, lower: float, diag: float, upper: float) -> sp.csr_matrix:
    """n × n tridiagonal matrix with constant bands."""
    return sp.diags([lower, diag, upper], [-1, 0, 1], shape=(n, n), format="csr", dtype=np.float64)


def neg_laplacian_1d(n: int) -> sp.csr_matrix:
    """−Δ_h on n interior nodes of (0, 1), h = 1/(n + 1), homogeneous Dirichlet:
    (−u_{i−1} + 2u_i − u_{i+1}) / h²."""
    h = 1.0 / (n + 1)
    return tridiag(n, -1.0, 2.0, -1.0) * (1.0 / h**2)


def neg_laplacian_2d(m: int) -> sp.csr_matrix:
    """−Δ_h (5-point) on m × m interior nodes of (0, 1)², h = 1/(m + 1), homogeneous
    Dirichlet, lexicographic ordering (x fastest): (4u_P − u_E − u_W − u_N − u_S) / h²."""
    t = neg_laplacian_1d(m)
    eye = sp.identity(m, format="csr", dtype=np.float64)
    return sp.csr_matrix(sp.kron(eye, t) + sp.kron(t, eye))


def grid_1d(n: int) -> np.ndarray:
    """Interior nodes x_i = i h, i = 1..n, h = 1/(n + 1)."""
    return np.arange(1, n + 1) / (n + 1.0)


def grid_2d(m: int) -> tuple:
    """(X, Y) of the m × m interior nodes, each raveled in the lexicographic order above."""
    x = grid_1d(m)
    X, Y = np.meshgrid(x, x, indexing="xy")
    return X.ravel(), Y.ravel()


def as_csr(A) -> sp.csr_matrix:
    """CSR, float64, sorted indices, no explicit zeros."""
    A = sp.csr_matrix(A, dtype=np.float64)
    A.eliminate_zeros()
    A.sort_indices()
    return A
