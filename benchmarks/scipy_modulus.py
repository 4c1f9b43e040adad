"""Plain scipy/numpy implementation of the NRM family for an LCP — the peer a user
would write from the paper, following docs/SPEC.md exactly:

* same start  x0 = gamma/2 * (Omega1^-1 z0 - Omega2^-1 (A z0 + q))   (z0 = 0 by default)
* same explicit z-update  z(k) = Omega1 (|x(k)| + x(k)) / gamma       (LCP: zeta == 0)
* same stop  Res(z(k)) = ||min(A z(k) + q, z(k))||_2 < tol  ->  nit = k
* step 2 either in the paper's form (``form="paper"``)
      Lm x(k+1) = (N + phi) Omega1 x(k) + (Omega2 - A Omega1)|x(k)| - gamma q
  or in SPEC's defect-correction form (``form="defect"``, what nrmicp's core evaluates)
      x(k+1) = x(k) + Lm^-1 [Omega2 (|x(k)| - x(k)) - gamma (A z(k) + q)]
  The defect form reuses A z(k) + q from the residual check: one SpMV per iteration
  instead of three.

Left-matrix solves:
* AOR family (nrmaor / nrmsor / nrmgs / nrmj): Lm is lower triangular.
  ``tri="splu"`` (default) factorizes Lm once with SuperLU in natural order and no
  pivoting — no fill, L is Lm with unit diagonal — and then every solve is SuperLU's C
  triangular solve. ``tri="spsolve_triangular"`` calls scipy.sparse.linalg.spsolve_triangular
  every iteration, which re-validates and rescales the matrix each call (~5x slower per
  solve at n = 1e6 on this machine).
* nrm / nrmm: Lm = Omega2 + (A + phi) Omega1 is factorized once with scipy.sparse.linalg.splu
  (exactly what scipy.sparse.linalg.factorized does when scikit-umfpack is absent; calling
  splu directly lets us report nnz(L) + nnz(U)).
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from peers_impl import peers

AOR_METHODS = ("nrmaor", "nrmsor", "nrmgs", "nrmj")
FACTOR_METHODS = ("nrm", "nrmm")


def residual(A, q, z):
    """Res(z) = ||min(Az + q, z)||_2 for an LCP."""
    return float(np.linalg.norm(np.minimum(A @ z + q, z)))


def _diag(v, n, default):
    if v is None:
        v = default
    v = np.asarray(v, dtype=float)
    if v.ndim == 0:
        v = np.full(n, float(v))
    if v.shape != (n,):
        raise ValueError("diagonal parameter must be a scalar or a length-n vector")
    return v


def _resolve(method, A, omega1, omega2, phi, alpha, beta):
    """Return (M, omega1, omega2, phi) for `method` per SPEC.md's method table."""
    n = A.shape[0]
    d = A.diagonal()
    if method in AOR_METHODS:
        if method == "nrmgs":
            alpha, beta = 1.0, 1.0
        elif method == "nrmj":
            alpha, beta = 1.0, 0.0
        elif method == "nrmsor":
            alpha = 1.0 if alpha is None else float(alpha)
            beta = alpha
        else:  # nrmaor
            alpha = 1.0 if alpha is None else float(alpha)
            beta = alpha if beta is None else float(beta)
        # A = D - L - U with -L the strictly lower part:  D - beta L = D + beta tril(A, -1)
        M = ((sp.diags(d) + beta * sp.tril(A, -1)) / alpha).tocsr()
        o1 = _diag(omega1, n, 1.0)
        o2 = _diag(omega2, n, d)
    elif method in FACTOR_METHODS:
        M = A
        o1 = _diag(omega1, n, 1.0)
        if method == "nrm":
            o2 = _diag(omega2, n, 1.0)
        else:
            a = float(np.mean(d)) if alpha is None else float(alpha)
            o2 = _diag(omega2, n, a) if omega2 is not None else np.full(n, a)
    else:
        raise ValueError(f"unknown method {method!r}")
    ph = _diag(phi, n, 0.0)
    return M, o1, o2, ph


class ScipyNRM:
    """Set-up once (left matrix + its solver), then `solve(q)`."""

    def __init__(self, A, method="nrmgs", *, omega1=None, omega2=None, gamma=1.0, phi=None,
                 alpha=None, beta=None, form="defect", tri="splu", permc_spec="COLAMD"):
        t0 = time.perf_counter()
        A = sp.csr_matrix(A, dtype=float)
        A.sort_indices()
        n = A.shape[0]
        self.A, self.n, self.method, self.gamma, self.form = A, n, method, float(gamma), form
        M, o1, o2, ph = _resolve(method, A, omega1, omega2, phi, alpha, beta)
        self.o1, self.o2, self.ph = o1, o2, ph
        D1 = sp.diags(o1)
        # Lm = Omega2 + (M + phi) Omega1
        Lm = (sp.diags(o2) + (M + sp.diags(ph)) @ D1).tocsc()
        Lm.sort_indices()
        self.Lm = Lm
        if form == "paper":
            N = (M - A).tocsr()
            self.Nphi = ((N + sp.diags(ph)) @ D1).tocsr()       # (N + phi) Omega1
            self.B = (sp.diags(o2) - A @ D1).tocsr()             # Omega2 - A Omega1
        elif form != "defect":
            raise ValueError("form must be 'defect' or 'paper'")
        self.factor_nnz = None
        tf = time.perf_counter()
        if method in AOR_METHODS:
            if tri == "splu":
                lu = spla.splu(Lm, permc_spec="NATURAL", diag_pivot_thresh=0.0,
                               options=dict(SymmetricMode=True))
                if not np.array_equal(lu.perm_r, np.arange(n)):
                    raise RuntimeError("SuperLU pivoted a triangular matrix")
                self._solve = lu.solve
                self.factor_nnz = int(lu.L.nnz + lu.U.nnz)
            elif tri == "spsolve_triangular":
                Lcsr = Lm.tocsr()
                self._solve = lambda b: spla.spsolve_triangular(Lcsr, b, lower=True)
            else:
                raise ValueError("tri must be 'splu' or 'spsolve_triangular'")
        else:
            # == scipy.sparse.linalg.factorized(Lm) without scikit-umfpack
            lu = spla.splu(Lm, permc_spec=permc_spec)
            self._solve = lu.solve
            self.factor_nnz = int(lu.L.nnz + lu.U.nnz)
        t1 = time.perf_counter()
        self.t_factor = t1 - tf
        self.t_setup = t1 - t0

    def solve(self, q, *, x0=None, tol=1e-8, maxiter=10000, time_limit=None):
        t0 = time.perf_counter()
        A, g, o1, o2 = self.A, self.gamma, self.o1, self.o2
        q = np.asarray(q, dtype=float)
        n = self.n
        z0 = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
        # x(0) = gamma/2 (Omega1^-1 z0 - Omega2^-1 (A z0 + q))       (zeta == 0)
        x = 0.5 * g * (z0 / o1 - (A @ z0 + q) / o2)
        gq = g * q
        best_res, best_z = np.inf, None
        k = 0
        while True:
            ax = np.abs(x)
            z = o1 * (ax + x) / g
            r = A @ z
            r += q
            res = float(np.linalg.norm(np.minimum(r, z)))
            if res < best_res:
                best_res, best_z = res, z
            status = peers.verdict(res, tol, k, maxiter, t0, time_limit)  # the peers' one stopping rule
            if status:
                break
            if self.form == "defect":
                rhs = o2 * (ax - x)
                rhs -= g * r
                x = x + self._solve(rhs)
            else:
                rhs = self.Nphi @ x + self.B @ ax - gq
                x = self._solve(rhs)
            k += 1
        t1 = time.perf_counter()
        return dict(z=best_z, nit=k, residual=best_res, status=status,
                    success=status == "converged", t_iter=t1 - t0,
                    t_setup=self.t_setup, t_factor=self.t_factor,
                    total=t1 - t0 + self.t_setup, factor_nnz=self.factor_nnz)


def solve(A, q, method="nrmgs", *, tol=1e-8, maxiter=10000, x0=None, time_limit=None, **kw):
    """One-shot: set-up + solve; times include the set-up."""
    return ScipyNRM(A, method, **kw).solve(q, x0=x0, tol=tol, maxiter=maxiter,
                                           time_limit=time_limit)


if __name__ == "__main__":  # tiny self-check
    from nrmicp.scenes.bai import bai_matrix  # Bai's matrix, mu = 4

    m = 30
    A = bai_matrix(m)
    rng = np.random.default_rng(0)
    q = rng.standard_normal(m * m)
    for meth in ("nrmgs", "nrmsor", "nrmj", "nrm", "nrmm"):
        for form in ("defect", "paper"):
            out = solve(A, q, meth, form=form, alpha=1.2 if meth == "nrmsor" else None)
            print(meth, form, out["status"], out["nit"], out["residual"],
                  residual(A.tocsr(), q, out["z"]))
