"""Convergence certificates for Method 3.1: the paper's sufficient conditions, evaluated.

``convergence_bound(A, method=...)`` evaluates, for a given matrix and method parameters,
the sufficient conditions of section 4 of Kumar, Deepmala & Das ("New relaxation
modulus based iterative method for large and sparse implicit complementarity problem"):

* Theorem 4.1: the iteration converges for every x0 if rho(T) < 1,

      T = |Lm^-1| (|(N + phi) Omega1| + |Omega2 - A Omega1| + 2 |A| Psi |A^-1| Omega2),
      Lm = Omega2 + (M + phi) Omega1,

  where Psi >= 0 is a Lipschitz matrix of zeta: |zeta(x) - zeta(y)| <= Psi |x - y|.
* Theorems 4.2-4.4 (A an H+-matrix): each of them works by showing that
  H - F is a nonsingular M-matrix, with H = <Lm> (comparison matrix) and F the bracket
  above; equivalently rho(<Lm>^-1 F) < 1, and rho(T) <= rho(<Lm>^-1 F) because
  |Lm^-1| <= <Lm>^-1 for an H-matrix Lm.  We evaluate rho(<Lm>^-1 F) directly (with
  |A^-1| <= <A>^-1 as well), which is implied by each of 4.2-4.4; it is also the bound we
  use when n is too large for dense linear algebra.
* Theorem 4.3 (AOR-type methods, Omega2 >= D Omega1): convergence if

      max(alpha, beta) * rho((D Omega1)^-1 (|B Omega1| + |A| Psi |A^-1| Omega2)) < min(1, alpha),

  with B = D - A.  The paper prints D_{Omega1}^-1 |B_{Omega1}| + |A| Psi |A^-1| Omega2
  (the inverse diagonal applied to the first term only) and carries a stray factor 2 in the
  proof; redoing the proof gives the (D Omega1)^-1 (...) form used here, which reduces to the
  printed one when Psi = 0.

All of these conditions are SUFFICIENT, NOT NECESSARY: a problem they do not certify may
well converge (e.g. NRM with the paper's Omega1 = Omega2 = I on Bai's matrices converges but
is not certified).  ``certified=False`` means "no guarantee", never "diverges".

Notes on the theory (derived here, checked numerically in tests/test_certificate.py):

* Theorem 4.1's |A^-1| term comes from the paper's z-update ``A z = Omega2(|x| - x)/gamma - q``
  (z_update="solve"; nrmicp.solve's 'auto' picks it on an ICP only for the paper's nrm, with
  Omega2 = I, and for mms, and 'explicit' otherwise: see _auto_z_update).  For an LCP (Psi = 0) both
  z-updates produce the same x-iterates and the term vanishes.  For z_update="explicit"
  (z = zeta(z_prev) + Omega1(|x| + x)/gamma) with Psi != 0 the error obeys the two-block
  recursion  e' <= K(P + 2|A| Psi Omega1) e + K |A| Psi^2 f,  f' <= 2 Omega1 e + Psi f
  (K = |Lm^-1|, P = |(N+phi)Omega1| + |Omega2 - A Omega1|, f = gamma |z_prev - z*|), and we
  certify with the spectral radius of that 2n x 2n nonnegative matrix.
* Two-sweep (x_tilde from (M1 + Omega2) x_tilde = N1 x + (Omega2 - M2)|x| + N2 |x_prev| - ...,
  x' = theta x_tilde + (1 - theta) x): with e = |x - x*| the error obeys
  e' <= (theta K P1 + |1 - theta| I) e + theta K |N2| e_prev, a 2n x 2n nonnegative block
  recursion; rho < 1 of that block matrix certifies convergence for every x0.
* P-matrix hypothesis: the contraction argument does not need it.  If rho(T) < 1 the map
  x -> x' is a contraction in a monotone weighted max-norm, so the fixed point (hence the
  solution) exists, is unique and is reached from every x0.

Only numpy and scipy are imported: this module is safe to import on its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import numbers
from typing import Any, Optional

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["Certificate", "convergence_bound"]

_AOR_METHODS = ("nrmaor", "nrmsor", "nrmgs", "nrmj", "mms")
_METHODS = ("nrm", "nrmm") + _AOR_METHODS + ("two_sweep",)
_NOT_CERTIFIED = "not certified (sufficient condition only)"


@dataclass
class Certificate:
    """Verdict of :func:`convergence_bound`.

    certified    -- True if a sufficient condition of the paper holds (convergence for every x0).
                    False means only "no guarantee": the conditions are sufficient, not necessary.
    rho          -- the spectral radius of the error-propagation matrix T (Theorem 4.1), exact
                    when rho_is_exact, otherwise a rigorous upper bound (Collatz-Wielandt bound of
                    a comparison-matrix majorant of T, up to floating-point rounding).
                    inf when no bound could be computed.
    rho_is_exact -- whether rho is the exact rho(T) (dense eigenvalues) or an upper bound.
    theorem      -- which condition certified (or, if none did, which was evaluated).
    conditions   -- every evaluated quantity (see convergence_bound's docstring).
    message      -- a sentence for humans.
    """

    certified: bool
    rho: float
    rho_is_exact: bool
    theorem: str
    conditions: dict = field(default_factory=dict)
    message: str = ""


# ---------------------------------------------------------------------------------------------
# validation helpers


def _as_matrix(A):
    if sp.issparse(A):
        if A.ndim != 2:
            raise ValueError(f"A must be 2-D, got shape {A.shape}")
        M = sp.csr_matrix(A, dtype=np.float64)
    else:
        arr = np.asarray(A)
        if arr.ndim != 2:
            raise ValueError(f"A must be a 2-D matrix (scipy sparse or ndarray), got shape {arr.shape}")
        if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
            raise TypeError(f"A must be a real numeric matrix, got dtype {arr.dtype}")
        M = sp.csr_matrix(arr.astype(np.float64))
    if M.shape[0] != M.shape[1]:
        raise ValueError(f"A must be square, got shape {M.shape}")
    if M.shape[0] == 0:
        raise ValueError("A must be non-empty")
    M.sum_duplicates()
    if not np.all(np.isfinite(M.data)):
        raise ValueError("A contains non-finite entries")
    M.eliminate_zeros()
    M.sort_indices()
    return M


def _diag_vector(value, n, name, *, positive):
    """A scalar (times I) or a length-n vector; positive=True: > 0, else >= 0."""
    v = np.asarray(value, dtype=np.float64) if not isinstance(value, np.ndarray) else value.astype(np.float64)
    if v.ndim == 0:
        v = np.full(n, float(v))
    elif v.ndim != 1 or v.shape[0] != n:
        raise ValueError(f"{name} must be a scalar or a vector of length n = {n}, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be finite")
    if positive and not np.all(v > 0):
        i = int(np.argmin(v))
        raise ValueError(f"{name} must be positive: {name}[{i}] = {v[i]}")
    if not positive and not np.all(v >= 0):
        i = int(np.argmin(v))
        raise ValueError(f"{name} must be nonnegative: {name}[{i}] = {v[i]}")
    return v.copy()


def _positive_scalar(value, name, *, allow_zero=False):
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    x = float(value)
    ok = (x >= 0) if allow_zero else (x > 0)
    if not (math.isfinite(x) and ok):
        raise ValueError(f"{name} must be a finite number {'>= 0' if allow_zero else '> 0'}, got {value!r}")
    return x


def _lipschitz_matrix(lipschitz, n):
    """Psi as a CSR matrix (nonnegative), from a scalar, a length-n vector or an n x n matrix."""
    if sp.issparse(lipschitz):
        P = sp.csr_matrix(lipschitz, dtype=np.float64)
        if P.shape != (n, n):
            raise ValueError(f"lipschitz matrix must be {n} x {n}, got shape {P.shape}")
    else:
        arr = np.asarray(lipschitz, dtype=np.float64)
        if arr.ndim == 0:
            x = float(arr)
            if not math.isfinite(x) or x < 0:
                raise ValueError(f"lipschitz must be a finite number >= 0, got {lipschitz!r}")
            return sp.diags(np.full(n, x)).tocsr(), x == 0.0
        if arr.ndim == 1:
            if arr.shape[0] != n:
                raise ValueError(f"lipschitz vector (diagonal Psi) must have length n = {n}, got {arr.shape[0]}")
            P = sp.diags(arr).tocsr()
        elif arr.ndim == 2:
            if arr.shape != (n, n):
                raise ValueError(f"lipschitz matrix must be {n} x {n}, got shape {arr.shape}")
            P = sp.csr_matrix(arr)
        else:
            raise ValueError(f"lipschitz must be a scalar, a length-n vector or an n x n matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(P.data)):
        raise ValueError("lipschitz must be finite")
    if np.any(P.data < 0):
        raise ValueError("lipschitz (the Lipschitz matrix Psi) must be nonnegative")
    P.eliminate_zeros()
    return P, P.nnz == 0


def _comparison(M):
    """<M>: |diagonal|, minus |off-diagonal|."""
    M = sp.csr_matrix(M)
    d = M.diagonal()
    C = sp.csr_matrix(sp.diags(np.abs(d)) - abs(M - sp.diags(d)))
    C.eliminate_zeros()
    return C


# ---------------------------------------------------------------------------------------------
# method set-up: M, N, Lm and the nonnegative pieces of the error recursion


class _Setup:
    pass


def _auto_z_update(method, omega2_given):
    """The z-update that nrmicp.solve's z_update='auto' runs on an ICP (the rule of Solver::iterate
    in cpp/include/nrmicp/solver.hpp; tests/test_certificate.py checks that they agree):
    'solve' for the paper's nrm (Omega2 = I, i.e. omega2 not given) and the baseline mms,
    'explicit' otherwise."""
    return "solve" if method == "mms" or (method == "nrm" and not omega2_given) else "explicit"


def _setup(A, method, omega1, omega2, gamma, phi, alpha, beta, theta, lipschitz, z_update):
    if not isinstance(method, str) or method not in _METHODS:
        raise ValueError(f"method must be one of {', '.join(_METHODS)}; got {method!r}")
    if z_update not in ("auto", "solve", "explicit"):
        raise ValueError(f"z_update must be 'auto', 'solve' or 'explicit', got {z_update!r}")
    if z_update == "auto":
        z_update = _auto_z_update(method, omega2 is not None)
    s = _Setup()
    s.A = A
    n = s.n = A.shape[0]
    s.method = method
    s.gamma = _positive_scalar(gamma, "gamma")
    s.theta = _theta(theta, method)
    d = A.diagonal()
    # --- parameters, as docs/SPEC.md's method table
    if method in ("mms", "two_sweep"):
        for name, val, fixed in (("omega1", omega1, 1.0), ("phi", phi, 0.0)):
            if val is not None and not np.all(np.asarray(val, dtype=np.float64) == fixed):
                raise ValueError(f"method {method!r} fixes {name} = {'I' if fixed else '0'}; got {name}={val!r}")
        omega1, phi = None, None
    s.alpha, s.beta = _alpha_beta(method, alpha, beta)
    s.w1 = np.ones(n) if omega1 is None else _diag_vector(omega1, n, "omega1", positive=True)
    s.phi = np.zeros(n) if phi is None else _diag_vector(phi, n, "phi", positive=False)
    if method == "nrmm" and omega2 is None:     # an explicit omega2 wins over alpha, as in the core
        s.alpha = omega2 = _nrmm_alpha(alpha, d)
    s.w2 = _diag_vector(_default_omega2(method, d) if omega2 is None else omega2, n, "omega2", positive=True)
    s.Psi, s.psi_zero = _lipschitz_matrix(lipschitz, n)
    s.z_update = "any (LCP: Psi = 0)" if s.psi_zero else z_update
    _splitting(s, A, d)
    return s


def _theta(theta, method):
    t = _positive_scalar(theta, "theta")
    if t > 2:
        raise ValueError(f"theta must lie in (0, 2], got {theta!r}")
    if method != "two_sweep" and t != 1.0:
        raise ValueError(f"theta applies to method='two_sweep' only, got theta={theta!r} for {method!r}")
    return t


def _alpha_beta(method, alpha, beta):
    """(alpha, beta) of the method (None for nrm/nrmm, whose M = A), refusing what it fixes."""
    if method in ("nrm", "nrmm"):
        if beta is not None:
            raise ValueError(f"beta does not apply to method {method!r}")
        if method == "nrm" and alpha is not None:
            raise ValueError("alpha does not apply to method 'nrm' (use 'nrmm' for Omega2 = alpha I)")
        return None, None
    a = None if alpha is None else _positive_scalar(alpha, "alpha")
    b = None if beta is None else _positive_scalar(beta, "beta", allow_zero=True)
    if method == "nrmgs":
        if a not in (None, 1.0) or b not in (None, 1.0):
            raise ValueError("method 'nrmgs' fixes alpha = beta = 1 (use 'nrmaor' for other values)")
        return 1.0, 1.0
    if method == "nrmj":
        if a not in (None, 1.0) or b not in (None, 0.0):
            raise ValueError("method 'nrmj' fixes alpha = 1, beta = 0 (use 'nrmaor' for other values)")
        return 1.0, 0.0
    a = 1.0 if a is None else a
    if method == "nrmsor":
        if b is not None and b != a:
            raise ValueError(f"method 'nrmsor' has beta = alpha; got alpha={a}, beta={b}")
        return a, a
    return a, (a if b is None else b)            # nrmaor, mms, two_sweep (as the core)


def _nrmm_alpha(alpha, d):
    """nrmm's Omega2 = alpha I: alpha given, or the mean of diag(A)."""
    if alpha is None:
        alpha = float(np.mean(d))
        if not alpha > 0:
            raise ValueError("nrmm's default alpha (mean of diag A) is not positive; pass alpha")
    return _positive_scalar(alpha, "alpha")


def _default_omega2(method, d):
    if method == "nrm":
        return 1.0
    if not np.all(d > 0):
        raise ValueError(f"the default omega2 = diag(A) of method {method!r} needs a positive "
                         "diagonal of A; pass omega2")
    return d


def _splitting(s, A, d):
    """The splitting's matrices and the blocks of the error-propagation operator, into s."""
    Dm = sp.diags(d)
    Lo = -sp.tril(A, k=-1)
    Up = -sp.triu(A, k=1)
    M = A.copy() if s.method in ("nrm", "nrmm") else (Dm - s.beta * Lo) / s.alpha
    M = sp.csr_matrix(M)
    N = sp.csr_matrix(M - A)
    W1, W2, Ph = sp.diags(s.w1), sp.diags(s.w2), sp.diags(s.phi)
    s.M, s.N, s.Ph = M, N, Ph
    s.two_sweep = s.method == "two_sweep"
    s.Lm = sp.csr_matrix(W2 + (M + Ph) @ W1)
    if s.two_sweep:
        M2 = sp.csr_matrix(Dm - Up)
        s.P = sp.csr_matrix(abs(N) + abs(W2 - M2))
        s.P2 = sp.csr_matrix(abs(Lo))
    else:
        s.P = sp.csr_matrix(abs((N + Ph) @ W1) + abs(W2 - A @ W1))
        s.P2 = None
    s.absA = sp.csr_matrix(abs(A))
    s.explicit_f = (not s.psi_zero) and s.z_update == "explicit"
    s.needs_Ainv = (not s.psi_zero) and s.z_update == "solve"
    s.nblocks = 1 + int(s.two_sweep) + int(s.explicit_f)
    s.lower_triangular = s.method in _AOR_METHODS or s.two_sweep


def _block_operator(s, K, R):
    """The error-propagation operator T as a function of an (nblocks*n, k) array.

    K applies |Lm^-1| (or its majorant <Lm>^-1), R applies |A^-1| (or <A>^-1); both map
    (n, k) arrays to (n, k) arrays.  Everything else is a sparse nonnegative matrix.
    """
    n, w1, w2 = s.n, s.w1[:, None], s.w2[:, None]
    P, P2, absA, Psi = s.P, s.P2, s.absA, s.Psi

    def T(X):
        e = X[:n]
        idx = n
        if s.two_sweep:
            ep = X[idx:idx + n]
            idx += n
        if s.explicit_f:
            fp = X[idx:idx + n]
        rhs = P @ e
        if s.needs_Ainv:
            rhs = rhs + 2.0 * (absA @ (Psi @ R(w2 * e)))
        if s.explicit_f:
            rhs = rhs + 2.0 * (absA @ (Psi @ (w1 * e))) + absA @ (Psi @ (Psi @ fp))
        if s.two_sweep:
            rhs = rhs + P2 @ ep
        et = K(rhs)
        out = [s.theta * et + abs(1.0 - s.theta) * e if s.two_sweep else et]
        if s.two_sweep:
            out.append(e)
        if s.explicit_f:
            out.append(2.0 * w1 * e + Psi @ fp)
        return np.vstack(out) if len(out) > 1 else out[0]

    return T


def _thm43_operator(s, R):
    """Y = (D Omega1)^-1 (|B Omega1| + |A| Psi |A^-1| Omega2) (Theorem 4.3), on (n, k) arrays."""
    d = s.A.diagonal()
    DW1 = (d * s.w1)[:, None]
    absB_W1 = sp.csr_matrix(abs(s.A - sp.diags(d)) @ sp.diags(s.w1))
    w2 = s.w2[:, None]

    def Y(X):
        r = absB_W1 @ X
        if not s.psi_zero:
            r = r + s.absA @ (s.Psi @ R(w2 * X))
        return r / DW1

    return Y


# ---------------------------------------------------------------------------------------------
# spectral radius: exact (dense) and Collatz-Wielandt upper bounds (matrix-free)


def _rho_dense(T):
    if T.size == 0:
        return 0.0
    if not np.all(np.isfinite(T)):
        return math.inf
    return float(np.max(np.abs(np.linalg.eigvals(T))))


def _cw_power(apply, v0, maxiter, tol):
    """Shifted power iteration on a nonnegative operator, tracking Collatz-Wielandt bounds.

    For nonnegative T and any positive v:  min_i (Tv)_i/v_i <= rho(T) <= max_i (Tv)_i/v_i.
    The iterate is v <- Tv + sigma v with sigma >= 0 the current lower estimate (a shift makes
    2-cyclic matrices, e.g. Jacobi matrices of grid problems, converge; rho(T + sigma I) =
    rho(T) + sigma for nonnegative T).  A tiny floor keeps v strictly positive; neither affects
    the validity of the bounds, only their tightness.
    Returns (best upper bound, best lower bound, iterations).
    """
    v = np.asarray(v0, dtype=np.float64).copy()
    v /= v.max()
    v = np.maximum(v, 1e-12)
    up, lo = math.inf, 0.0
    it = 0
    for it in range(1, maxiter + 1):
        w = apply(v[:, None])[:, 0]
        if not np.all(np.isfinite(w)):
            return math.inf, lo, it
        ratio = w / v
        rmin = float(ratio.min())
        up = min(up, float(ratio.max()))
        lo = max(lo, rmin)
        if up - lo <= tol * max(up, 1e-300):
            break
        w = w + max(rmin, 0.0) * v
        wmax = float(w.max())
        if wmax <= 0.0:          # T v = 0 with v > 0: T = 0
            return 0.0, 0.0, it
        v = np.maximum(w / wmax, 1e-12)
    return max(up, 0.0), lo, it


def _mmatrix_solver(C, name, triangular):
    """For a Z-matrix C: (solve, u) if C is a nonsingular M-matrix (u = C^-1 e > 0), else (None, why)."""
    n = C.shape[0]
    try:
        if triangular:      # no fill, no pivoting: the LU of a triangular matrix is itself
            lu = spla.splu(sp.csc_matrix(C), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                           options={"SymmetricMode": True})
        else:
            lu = spla.splu(sp.csc_matrix(C))

        def solve(X):
            return lu.solve(np.ascontiguousarray(X))
        u = solve(np.ones((n, 1)))[:, 0]
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        return None, f"{name} is singular ({exc})"
    if not (np.all(np.isfinite(u)) and np.all(u > 0)):
        return None, f"{name} is not a nonsingular M-matrix (<.>^-1 e has nonpositive entries)"
    resid = C @ u
    if not np.all(resid > 0):
        return None, f"{name} is not a nonsingular M-matrix (numerically)"
    return solve, u


# ---------------------------------------------------------------------------------------------


def convergence_bound(A: Any, *, method: str = "nrmgs", lipschitz: Any = 0.0, omega1: Any = None,
                      omega2: Any = None, gamma: float = 1.0, phi: Any = None, alpha: Optional[float] = None,
                      beta: Optional[float] = None, theta: float = 1.0, z_update: str = "auto",
                      exact_max_n: int = 2000, tol: float = 1e-10, maxiter: int = 1000) -> Certificate:
    """Evaluate the paper's sufficient conditions for convergence of Method 3.1 from any x0.

    The conditions are SUFFICIENT, NOT NECESSARY: a problem that is not certified may still
    converge (certified=False means "no guarantee", not "diverges").

    Parameters (same meaning and defaults as nrmicp.solve, docs/SPEC.md's method table)
    ----------
    A : (n, n) scipy sparse matrix or ndarray.
    method : 'nrm', 'nrmm', 'nrmaor', 'nrmsor', 'nrmgs', 'nrmj', 'mms' or 'two_sweep'.
    lipschitz : Lipschitz matrix Psi of zeta, |zeta(x) - zeta(y)| <= Psi |x - y| componentwise:
        a scalar psi >= 0 (Psi = psi I; 0 for an LCP or a constant obstacle), a length-n vector
        (diagonal Psi) or an n x n nonnegative matrix (dense or sparse); for an affine
        zeta(z) = B z + c (nrmicp.Affine) pass abs(B).
    omega1, omega2, phi : scalar or length-n vector (defaults per method: Omega1 = I;
        Omega2 = I for nrm, alpha I for nrmm, diag(A) for the AOR types; phi = 0).
    gamma : > 0.  It only rescales x and does not enter any condition.
    alpha, beta : AOR parameters (nrmaor/mms/two_sweep: alpha = 1, beta = alpha by default;
        nrmsor: beta = alpha (default 1); nrmgs: 1, 1; nrmj: 1, 0); for nrmm alpha sets
        Omega2 = alpha I (default: mean of diag A; an explicit omega2 takes precedence).
    theta : two-sweep relaxation in (0, 2].
    z_update : 'auto' (the z-update nrmicp.solve's 'auto' runs: 'solve' for nrm with the paper's
        Omega2 = I and for mms, 'explicit' otherwise), 'solve' (the paper's Step 1, Theorem 4.1
        as printed) or 'explicit' (block recursion, see the module docstring).  Irrelevant for
        an LCP.
    exact_max_n : when the error-propagation matrix has order <= exact_max_n (n, or 2n for
        two_sweep and for the explicit z-update of an ICP), rho(T) is computed exactly with dense
        numpy (inverses, eigenvalues).  Otherwise an upper bound is computed matrix-free.
    tol, maxiter : stopping rule of the power iteration of the matrix-free bound (relative gap
        between the Collatz-Wielandt upper and lower bounds).

    The matrix-free bound replaces |Lm^-1| by <Lm>^-1 (valid when Lm is an H-matrix; always
    for the lower-triangular AOR-type left matrices) and |A^-1| by <A>^-1 (valid for an
    H-matrix A), applied by sparse solves; this majorant is exactly the matrix of Theorems
    4.2-4.4.  Its spectral radius is bounded above by the Collatz-Wielandt quotient
    max_i (T v)_i / v_i along a power iteration, which is a rigorous upper bound on rho(T).

    Returns a :class:`Certificate`.  ``conditions`` holds:
      method, n, alpha, beta, z_update;
      rho_T (exact) or rho_T_upper (bound) and rho_T_cw_lower (lower CW bound of the majorant),
      power_iterations; rho_comparison (exact spectral radius of the comparison majorant, small n);
      A_is_H_plus, rho_jacobi_abs (rho(D^-1 |B|), exact or an upper bound);
      Lm_is_H; H_splitting (<M + phi> - |N + phi| an M-matrix, hypothesis of Theorems 4.2/4.4);
      omega2_ge_D_omega1, thm43_rho, thm43_lhs, thm43_rhs, thm43_holds
      (AOR-type methods with the paper's z-update).
    """
    A = _as_matrix(A)
    if isinstance(exact_max_n, bool) or not isinstance(exact_max_n, numbers.Integral) or exact_max_n < 0:
        raise ValueError(f"exact_max_n must be an integer >= 0, got {exact_max_n!r}")
    tol = _positive_scalar(tol, "tol")
    if isinstance(maxiter, bool) or not isinstance(maxiter, numbers.Integral) or maxiter < 1:
        raise ValueError(f"maxiter must be an integer >= 1, got {maxiter!r}")
    s = _setup(A, method, omega1, omega2, gamma, phi, alpha, beta, theta, lipschitz, z_update)
    n = s.n
    order = s.nblocks * n
    exact = order <= exact_max_n
    cond = {"method": method, "n": n, "alpha": s.alpha, "beta": s.beta, "z_update": s.z_update,
            "theta": s.theta if s.two_sweep else None, "order_of_T": order}
    d = A.diagonal()

    if s.two_sweep:
        form = "Theorem 4.1 (two-sweep block form)"
    elif s.explicit_f:
        form = "Theorem 4.1 (block form for the explicit z-update)"
    else:
        form = "Theorem 4.1"

    aor_thm43 = method in _AOR_METHODS and not s.explicit_f
    Cmp_A = _comparison(A)

    # Theorems 4.2/4.4 hypothesis: A = (M + phi) - (N + phi) is an H-splitting,
    # i.e. <M + phi> - |N + phi| is a nonsingular M-matrix
    if not s.two_sweep:
        MP = s.M + s.Ph
        Zs = sp.csr_matrix(_comparison(MP) - abs(s.N + s.Ph))
        cond["H_splitting"] = _mmatrix_solver(Zs, "<M + phi> - |N + phi|", triangular=False)[0] is not None

    if exact:
        rho, is_exact, theorem, certified, note = _exact_path(s, A, cond, d, Cmp_A, form, aor_thm43)
    else:
        rho, is_exact, theorem, certified, note = _bound_path(s, A, cond, d, Cmp_A, form, aor_thm43,
                                                              tol, maxiter)

    what = "rho(T)" if is_exact else "upper bound on rho(T)"
    if certified:
        if theorem.startswith("Theorem 4.3") and not (rho < 1):
            msg = (f"certified by Theorem 4.3: max(alpha, beta) rho = {cond['thm43_lhs']:.6g} < "
                   f"min(1, alpha) = {cond['thm43_rhs']:.6g}; converges for every x0")
        else:
            msg = f"certified by {theorem}: {what} = {rho:.6g} < 1; converges for every x0"
    else:
        msg = f"{_NOT_CERTIFIED}: {what} = {rho:.6g} >= 1; the iteration may still converge"
    if note:
        msg += f" ({note})"
    return Certificate(certified=bool(certified), rho=float(rho), rho_is_exact=bool(is_exact),
                       theorem=theorem, conditions=cond, message=msg)


def _h_plus(Ad, d, cond):
    """Is A an H+-matrix? rho(D^-1 |B|) < 1 with D > 0 (into cond)."""
    if np.all(d > 0):
        J = np.abs(Ad - np.diag(d)) / d[:, None]
        rj = _rho_dense(J)
        cond["rho_jacobi_abs"] = rj
        cond["A_is_H_plus"] = bool(rj < 1)
    else:
        cond["rho_jacobi_abs"] = None
        cond["A_is_H_plus"] = False


def _comparison_rho(s, A, Lmd, Cmp_A, rho, I, cond):
    """The spectral radius of the comparison majorant of Theorems 4.2-4.4 (exactly, for
    reference), None where it is not defined; cond["Lm_is_H"] on the way."""
    Hd = _comparison(s.Lm).toarray()
    try:
        Hinv = np.linalg.inv(Hd)
        H_ok = bool(np.all(Hinv >= -1e-14 * np.abs(Hinv).max()))
    except np.linalg.LinAlgError:
        H_ok = False
    cond["Lm_is_H"] = H_ok
    same = bool(np.array_equal(Hd, Lmd)) and (not s.needs_Ainv or abs(Cmp_A - A).max() == 0)
    if H_ok and same:            # Lm (and A) are M-matrices: the majorant is T itself
        return rho
    if H_ok and (not s.needs_Ainv or cond["A_is_H_plus"] or _is_M(Cmp_A)):
        Rc = np.linalg.inv(Cmp_A.toarray()) if s.needs_Ainv else None
        Tc = _block_operator(s, lambda X: np.abs(Hinv) @ X, (lambda X: Rc @ X) if Rc is not None else None)(I)
        return _rho_dense(Tc)
    return None


def _exact_path(s, A, cond, d, Cmp_A, form, aor_thm43):
    n = s.n
    note = ""
    Ad = A.toarray()
    Lmd = s.Lm.toarray()
    try:
        Kd = np.abs(np.linalg.inv(Lmd))
    except np.linalg.LinAlgError:
        raise ValueError(f"the left matrix Omega2 + (M + phi) Omega1 of method {s.method!r} is "
                         "singular: the iteration is not defined") from None
    Rd = None
    if s.needs_Ainv or (aor_thm43 and not s.psi_zero):
        try:
            Rd = np.abs(np.linalg.inv(Ad))
        except np.linalg.LinAlgError:
            Rd = None
    I = np.eye(s.nblocks * n)

    _h_plus(Ad, d, cond)
    if s.needs_Ainv and Rd is None:
        cond["rho_T"] = math.inf
        return math.inf, True, form, False, "A is singular, so Theorem 4.1 (|A^-1|) does not apply"

    T = _block_operator(s, lambda X: Kd @ X, (lambda X: Rd @ X) if Rd is not None else None)(I)
    rho = _rho_dense(T)
    cond["rho_T"] = rho

    cond["rho_comparison"] = _comparison_rho(s, A, Lmd, Cmp_A, rho, I, cond)
    if aor_thm43:
        _thm43(s, cond, d, (lambda X: Rd @ X) if Rd is not None else None,
               exact_rho=lambda Y: _rho_dense(Y(np.eye(n))))

    certified = rho < 1
    theorem = form
    if not certified and cond.get("thm43_holds"):
        certified, theorem = True, "Theorem 4.3"      # cannot happen when the algebra is right
    return rho, True, theorem, certified, note


def _is_M(C):
    solve, _ = _mmatrix_solver(C, "<A>", triangular=False)
    return solve is not None


def _thm43(s, cond, d, R, exact_rho=None, bound_rho=None):
    """Theorem 4.3 for the AOR-type methods (with its hypotheses recorded)."""
    ge = bool(np.all(s.w2 >= d * s.w1 * (1 - 1e-14)))
    cond["omega2_ge_D_omega1"] = ge
    rhs = min(1.0, s.alpha)
    cond["thm43_rhs"] = rhs
    if not np.all(d > 0) or (not s.psi_zero and R is None):
        cond.update(thm43_rho=None, thm43_lhs=None, thm43_holds=False)
        return
    Y = _thm43_operator(s, R)
    r = exact_rho(Y) if exact_rho is not None else bound_rho(Y)
    lhs = max(s.alpha, s.beta) * r
    cond["thm43_rho"] = r
    cond["thm43_lhs"] = lhs
    cond["thm43_holds"] = bool(ge and lhs < rhs)


def _bound_path(s, A, cond, d, Cmp_A, form, aor_thm43, tol, maxiter):
    n = s.n
    theorem = form + " via comparison matrices (the Theorem 4.2-4.4 majorant)"

    # A is H+ ?  <A> an M-matrix (u = <A>^-1 e > 0); then rho(D^-1|B|) <= 1 - min 1/(d_i u_i)
    solveA, uA = (None, "diag(A) is not positive")
    if np.all(d > 0):
        solveA, uA = _mmatrix_solver(Cmp_A, "<A>", triangular=False)
    cond["A_is_H_plus"] = solveA is not None
    cond["rho_jacobi_abs"] = (float(max(0.0, 1.0 - np.min(1.0 / (d * uA)))) if solveA is not None else None)
    cond["rho_jacobi_abs_is_upper_bound"] = True
    R = solveA

    H = _comparison(s.Lm)
    solveH, uH = _mmatrix_solver(H, "<Lm>", triangular=s.lower_triangular)
    cond["Lm_is_H"] = solveH is not None
    if solveH is None:
        cond["rho_T_upper"] = math.inf
        return math.inf, False, theorem, False, (f"no matrix-free bound: {uH}; |Lm^-1| <= <Lm>^-1 is "
                                                 "unavailable. Use exact_max_n >= n for the exact test")
    if s.needs_Ainv and R is None:
        cond["rho_T_upper"] = math.inf
        return math.inf, False, theorem, False, ("no matrix-free bound: A is not an H-matrix, so "
                                                 "|A^-1| <= <A>^-1 is unavailable. Use exact_max_n >= n")

    T = _block_operator(s, solveH, R)

    # a good positive start: u = (<Lm> - P_total)^-1 e when that is positive
    v0 = np.ones(s.nblocks * n)
    Ptot = s.P if s.P2 is None else s.P + s.P2
    try:
        u = spla.splu(sp.csc_matrix(H - Ptot)).solve(np.ones(n))
        if np.all(np.isfinite(u)) and np.all(u > 0):
            blocks = [u]
            if s.two_sweep:
                blocks.append(u)
            if s.explicit_f:
                blocks.append(2.0 * s.w1 * u)
            v0 = np.concatenate(blocks)
    except (RuntimeError, ValueError):
        pass
    up, lo, it = _cw_power(T, v0, maxiter, tol)
    cond["rho_T_upper"] = up
    cond["rho_T_cw_lower"] = lo
    cond["power_iterations"] = it

    if aor_thm43:
        start = uA if solveA is not None else np.ones(n)
        _thm43(s, cond, d, R, bound_rho=lambda Y: _cw_power(Y, start, maxiter, tol)[0])
    certified = up < 1
    if not certified and cond.get("thm43_holds"):
        certified, theorem = True, "Theorem 4.3 (with |A^-1| <= <A>^-1)"
    return up, False, theorem, certified, ""
