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


def neg_laplacian_3d(m: int) -> sp.csr_matrix:
    """−Δ_h (7-point) on m × m × m interior nodes of (0, 1)³, h = 1/(m + 1), homogeneous
    Dirichlet, lexicographic ordering (x fastest, then y, then z)."""
    t = neg_laplacian_1d(m)
    eye = sp.identity(m, format="csr", dtype=np.float64)
    return as_csr(sp.kron(sp.kron(eye, eye), t) + sp.kron(sp.kron(eye, t), eye)
                  + sp.kron(sp.kron(t, eye), eye))


def grid_3d(m: int) -> tuple:
    """(X, Y, Z) of the m³ interior nodes, each raveled in the lexicographic order above."""
    x = grid_1d(m)
    Z, Y, X = np.meshgrid(x, x, x, indexing="ij")
    return X.ravel(), Y.ravel(), Z.ravel()


def upwind_derivative_1d(n: int, b: float) -> sp.csr_matrix:
    """b·d/dx on n interior nodes of (0, 1), h = 1/(n + 1), first-order upwind (backward
    difference for b > 0, forward for b < 0): b(u_i − u_{i−1})/h or b(u_{i+1} − u_i)/h.
    Its off-diagonal entries are ≤ 0, so adding it to −εΔ_h keeps an M-matrix."""
    h = 1.0 / (n + 1)
    if b >= 0:
        return tridiag(n, -b / h, b / h, 0.0)
    return tridiag(n, 0.0, -b / h, b / h)


def prolongation_1d(m: int) -> sp.csr_matrix:
    """Linear interpolation from the (m − 1)/2 coarse interior nodes (every second fine node,
    H = 2h) to the m fine ones, Dirichlet ends; m odd, ≥ 3. Shape (m, (m − 1)/2)."""
    if m < 3 or m % 2 == 0:
        raise ValueError(f"linear interpolation needs an odd m >= 3, got {m}")
    mc = (m - 1) // 2
    j = np.arange(mc)
    rows = np.concatenate([2 * j + 1, 2 * j, 2 * j + 2])
    cols = np.concatenate([j, j, j])
    vals = np.concatenate([np.ones(mc), np.full(mc, 0.5), np.full(mc, 0.5)])
    return as_csr(sp.coo_matrix((vals, (rows, cols)), shape=(m, mc)))


def grid_prolongations(shape: tuple) -> list:
    """Geometric prolongations of a tensor grid with ``shape`` = nodes per axis (x first,
    the fastest in the ordering): linear (1D), bilinear (2D), trilinear (3D) interpolation,
    finest first, halving every axis while all are odd and ≥ 3 (m = 2^k − 1 coarsens down
    to a single node). P_l maps level l + 1 to level l, shape (n_l, n_{l+1}); ``[]`` when
    the grid cannot be coarsened."""
    shape = tuple(int(s) for s in shape)
    out = []
    while all(s >= 3 and s % 2 == 1 for s in shape):
        P = sp.identity(1, format="csr")
        for s in shape:           # the first axis is the fastest: it is the last kron factor
            P = sp.kron(prolongation_1d(s), P, format="csr")
        out.append(as_csr(P))
        shape = tuple((s - 1) // 2 for s in shape)
    return out


def heat_solve(L: sp.spmatrix, delta: float):
    """The solve of (I + δL) for a symmetric L, factorized once (SuperLU with the minimum-degree
    ordering of Aᵀ + A: half COLAMD's fill and solve time on the 2D grid). Returns v ↦ (I + δL)⁻¹ v."""
    import scipy.sparse.linalg as spla

    return spla.splu(sp.csc_matrix(sp.identity(L.shape[0]) + delta * L), permc_spec="MMD_AT_PLUS_A").solve
