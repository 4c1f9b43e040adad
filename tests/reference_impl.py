"""Plain numpy/scipy reference of Method 3.1 (docs/SPEC.md), written from the paper's form.

This is deliberately slow and simple: it builds the splitting A = M - N explicitly, forms
the left matrix and the right-hand side of the paper's iteration as written,

    Lm x(k+1) = (N + phi) Omega1 x(k) + (Omega2 - A Omega1)|x(k)| - gamma A zeta(z(k)) - gamma q,
    Lm = Omega2 + (M + phi) Omega1,

and solves with scipy.sparse.linalg.spsolve every iteration.  It does NOT use the
defect-correction form of the C++ core, so agreement between the two is evidence for both.

Every numeric parameter is passed explicitly; nothing is defaulted per method except what
SPEC.md's method table fixes (Omega1 = I and phi = 0 for mms and two_sweep; the (alpha, beta)
of nrmsor/nrmgs/nrmj; Omega2 = alpha*I for nrmm).
"""

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

AOR_METHODS = ("nrmaor", "nrmsor", "nrmgs", "nrmj", "mms")
METHODS = ("nrm", "nrmm") + AOR_METHODS + ("two_sweep",)


@dataclass
class ReferenceResult:
    z: np.ndarray                 # z(nit) if converged, else the iterate with the smallest Res
    nit: int                      # number of x-updates made (k of the last z(k) computed)
    converged: bool
    residuals: np.ndarray         # Res(z(0)), Res(z(1)), ..., Res(z(nit))
    x_iterates: list = field(default_factory=list)   # x(0), x(1), ... (first keep_x of them)
    z_iterates: list = field(default_factory=list)   # z(0), z(1), ... (first keep_x of them)


def as_vector(value, n, name):
    """A scalar (times the identity) or a length-n vector, as a float64 vector."""
    if value is None:
        raise ValueError(f"{name} must be given explicitly")
    v = np.asarray(value, dtype=np.float64)
    if v.ndim == 0:
        return np.full(n, float(v))
    if v.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have length {n}")
    return v.copy()


def dlu_parts(A):
    """A = D - L - U: D diagonal, -L the strictly lower, -U the strictly upper part of A."""
    D = sp.diags(A.diagonal())
    L = -sp.tril(A, k=-1)
    U = -sp.triu(A, k=1)
    return D, L, U


def aor_splitting(A, alpha, beta):
    """The paper's AOR splitting: M = (D - beta L)/alpha, N = ((1-alpha)D + (alpha-beta)L + alpha U)/alpha."""
    D, L, U = dlu_parts(A)
    M = (D - beta * L) / alpha
    N = ((1.0 - alpha) * D + (alpha - beta) * L + alpha * U) / alpha
    return sp.csr_matrix(M), sp.csr_matrix(N)


def aor_parameters(method, alpha, beta):
    """(alpha, beta) of an AOR-type method; the SOR/GS/Jacobi members fix some of them."""
    if method == "nrmsor":
        if alpha is None or (beta is not None and beta != alpha):
            raise ValueError("nrmsor needs alpha (and beta, if given, equal to alpha)")
        return alpha, alpha
    if method == "nrmgs":
        if alpha not in (None, 1.0) or beta not in (None, 1.0):
            raise ValueError("nrmgs has alpha = beta = 1")
        return 1.0, 1.0
    if method == "nrmj":
        if alpha not in (None, 1.0) or beta not in (None, 0.0):
            raise ValueError("nrmj has alpha = 1, beta = 0")
        return 1.0, 0.0
    if alpha is None or beta is None:
        raise ValueError(f"{method} needs alpha and beta")
    return alpha, beta


def _g(z, zeta):
    """g = z - zeta(z) for zeta as nrmicp takes it (None, a constant, or a callable)."""
    if zeta is None:
        return z
    if callable(zeta):
        return z - np.asarray(zeta(z), dtype=np.float64)
    return z - np.asarray(zeta, dtype=np.float64)


def residual(A, q, z, zeta=None):
    """Res(z) = || min(Az + q, z - zeta(z)) ||_2, in numpy from the original data; zeta as nrmicp
    takes it (None, a constant, or a callable such as nrmicp.Affine). The tests' check of the
    product: it shares no code with nrmicp.residual."""
    return float(np.linalg.norm(np.minimum(sp.csr_matrix(A) @ z + q, _g(z, zeta))))


def units_residual(A, q, z, zeta=None):
    """nrmicp's default stopping measure Res_E(z) = || min(sigma (Az + q), z - zeta(z)) ||_2 with
    sigma = 2^-round(mean log2 |a_ii|) over the nonzero diagonal (README "What you get back"), from
    the original data, sharing no code with nrmicp."""
    d = np.abs(sp.csr_matrix(A).diagonal())
    sigma = 2.0 ** -round(float(np.mean(np.log2(d[d > 0]))))
    return float(np.linalg.norm(np.minimum(sigma * (sp.csr_matrix(A) @ z + q), _g(z, zeta))))


def reference_solve(A, q, zeta=None, *, method, z_update, gamma, omega1=None, omega2=None,
                    phi=None, alpha=None, beta=None, theta=1.0, tol=1e-8, maxiter=10000,
                    z0=None, keep_x=10):
    """Method 3.1 (or the two-sweep baseline) exactly as SPEC.md states it.

    z_update: 'explicit' (z(k) = zeta(z(k-1)) + Omega1(|x(k)| + x(k))/gamma, z(-1) = z0)
              or 'solve' (A z(k) = Omega2(|x(k)| - x(k))/gamma - q).
    maxiter: the largest number of x-updates; z(0), ..., z(maxiter) are checked.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}")
    if z_update not in ("explicit", "solve"):
        raise ValueError("z_update must be 'explicit' or 'solve'")
    A = sp.csr_matrix(A, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    n = A.shape[0]

    def zeta_of(z):
        return np.zeros(n) if zeta is None else np.asarray(zeta(z), dtype=np.float64)

    # ---- parameters --------------------------------------------------------------------
    if method in ("mms", "two_sweep"):
        if omega1 not in (None, 1.0) or phi not in (None, 0.0):
            raise ValueError(f"{method} fixes omega1 = I and phi = 0")
        omega1, phi = 1.0, 0.0
    if method == "nrmm":
        if alpha is None or omega2 is not None:
            raise ValueError("nrmm takes alpha (Omega2 = alpha I), not omega2")
        omega2 = alpha
    w1 = as_vector(omega1, n, "omega1")
    w2 = as_vector(omega2, n, "omega2")
    ph = as_vector(phi, n, "phi")
    Om1, Om2, Phi = sp.diags(w1), sp.diags(w2), sp.diags(ph)

    # ---- splitting A = M - N and the left matrix -----------------------------------------
    if method in ("nrm", "nrmm"):
        M, N = A.copy(), sp.csr_matrix((n, n))
    else:
        a, b = aor_parameters(method, alpha, beta)
        M, N = aor_splitting(A, a, b)
    assert abs(M - N - A).max() < 1e-12 * max(1.0, abs(A).max())

    if method == "two_sweep":
        # M1 = M, N1 = N (the AOR splitting); M2 = D - U, N2 = M2 - A = L.
        D, L, U = dlu_parts(A)
        M2 = sp.csr_matrix(D - U)
        N2 = sp.csr_matrix(L)
        Lm = sp.csc_matrix(M + Om2)
    else:
        Lm = sp.csc_matrix(Om2 + (M + Phi) @ Om1)

    # ---- start ------------------------------------------------------------------------
    z_init = np.zeros(n) if z0 is None else np.asarray(z0, dtype=np.float64).copy()
    x = gamma / 2.0 * ((z_init - zeta_of(z_init)) / w1 - (A @ z_init + q) / w2)
    x_prev = x.copy()          # two-sweep: x(-1) = x(0)
    z_prev = z_init            # explicit update: z(-1) = z0

    def z_of(x, z_prev):
        if z_update == "explicit":
            return zeta_of(z_prev) + w1 * (np.abs(x) + x) / gamma
        return spla.spsolve(sp.csc_matrix(A), w2 * (np.abs(x) - x) / gamma - q)

    residuals, x_iterates, z_iterates = [], [], []
    best_z, best_res = None, np.inf
    converged = False
    k = 0
    while True:
        z = z_of(x, z_prev)
        res = residual(A, q, z, zeta)
        residuals.append(res)
        if len(x_iterates) < keep_x:
            x_iterates.append(x.copy())
            z_iterates.append(z.copy())
        if res < best_res:
            best_z, best_res = z.copy(), res
        if res < tol:
            converged = True
            break
        if k == maxiter or not np.isfinite(res):
            break

        zeta_z = zeta_of(z)
        if method == "two_sweep":
            rhs = (N @ x + (Om2 - M2) @ np.abs(x) + N2 @ np.abs(x_prev)
                   - gamma * (A @ zeta_z) - gamma * q)
            x_tilde = spla.spsolve(Lm, rhs)
            x_new = theta * x_tilde + (1.0 - theta) * x
        else:
            rhs = ((N + Phi) @ (w1 * x) + np.abs(x) * w2 - A @ (w1 * np.abs(x))
                   - gamma * (A @ zeta_z) - gamma * q)
            x_new = spla.spsolve(Lm, rhs)
        x_prev, x = x, x_new
        z_prev = z
        k += 1

    z_out = z if converged else best_z
    if not converged and residual(A, q, z_init, zeta) < best_res:
        z_out = z_init  # the start itself, when no iterate had a lower Res (SPEC: the best iterate)
    return ReferenceResult(z=z_out, nit=k, converged=converged,
                           residuals=np.array(residuals), x_iterates=x_iterates,
                           z_iterates=z_iterates)


# ---- bounds: lower <= z <= upper (the mixed complementarity problem, PATH's convention) ------


@dataclass
class BoxReferenceResult:
    z: np.ndarray
    state: np.ndarray        # per row: -1 at lower, +1 at upper, 0 between (w = 0)
    steps: int               # active-set (Newton) steps taken
    pgs_sweeps: int          # projected Gauss-Seidel sweeps of the safeguard (0: none needed)


def box_residual(A, q, z, lower, upper):
    """Res(z) = || mid(z - lower, z - upper, Az + q) ||_2 = || min(z - l, max(z - u, w)) ||_2 (l <= u),
    in numpy; infinite bounds are bounds that are not there (lower None: 0, upper None: +inf)."""
    w = sp.csr_matrix(A) @ z + q
    lower, upper = _bounds(len(z), lower, upper)
    with np.errstate(invalid="ignore"):
        return float(np.linalg.norm(np.minimum(z - lower, np.maximum(z - upper, w))))


def _bounds(n, lower, upper):
    """(lower, upper) as float64 vectors of length n (None: 0 below, +inf above; numbers broadcast)."""
    lower = np.zeros(n) if lower is None else np.broadcast_to(np.asarray(lower, dtype=np.float64), (n,)).copy()
    upper = np.full(n, np.inf) if upper is None else np.broadcast_to(np.asarray(upper, dtype=np.float64), (n,)).copy()
    return lower, upper


def _box_state(z, w, d, lower, upper, fixed):
    """The primal-dual active set at (z, w): x = z - w / a_ii below lower -> -1, above upper -> +1,
    else 0; rows with lower = upper are always at their (one) value."""
    x = z - w / d
    state = np.where(x < lower, -1, np.where(x > upper, 1, 0)).astype(np.int8)
    state[fixed] = -1
    return state


def _box_solve(A, q, state, lower, upper):
    """z with z = lower on state -1, z = upper on +1, and (Az + q)_I = 0 on the rest I (an exact
    sparse solve of A_II)."""
    z = np.where(state < 0, lower, np.where(state > 0, upper, 0.0))
    inactive = np.flatnonzero(state == 0)
    if inactive.size:
        active = np.flatnonzero(state != 0)
        rhs = -q[inactive] - A[inactive][:, active] @ z[active]
        z[inactive] = np.atleast_1d(spla.spsolve(sp.csc_matrix(A[inactive][:, inactive]), rhs))
    return z


def _projected_gauss_seidel(A, q, z, lower, upper, sweeps):
    """`sweeps` sweeps of projected Gauss-Seidel on the box (converges for A symmetric positive
    definite: it is coordinate descent on the box QP)."""
    A = sp.csr_matrix(A)
    d = A.diagonal()
    for _ in range(sweeps):
        for i in range(A.shape[0]):
            lo, hi = A.indptr[i], A.indptr[i + 1]
            wi = A.data[lo:hi] @ z[A.indices[lo:hi]] + q[i]
            z[i] = min(upper[i], max(lower[i], z[i] - wi / d[i]))
    return z


def reference_box_solve(A, q, lower=None, upper=None, *, z0=None, maxsteps=200, pgs_sweeps=50):
    """The box problem lower <= z <= upper, w = Az + q >= 0 at lower, <= 0 at upper, = 0 between,
    by the primal-dual active-set (semismooth Newton) method with exact sparse solves.

    Each step takes the active set of the current (z, w) (_box_state) and solves for the z it
    fixes (_box_solve); the method ends when the set repeats its predecessor. It converges in
    finitely many steps for an M-matrix (Hintermueller, Ito & Kunisch 2002). For other symmetric
    positive definite A the steps may cycle: a repeated older set is the cycle check, and then
    `pgs_sweeps` projected Gauss-Seidel sweeps (convergent there) move z before the steps go on.
    The result is checked against the conditions before it is returned (AssertionError if not).
    """
    A = sp.csr_matrix(A, dtype=np.float64)
    n = A.shape[0]
    q = np.asarray(q, dtype=np.float64)
    lower, upper = _bounds(n, lower, upper)
    assert np.all(lower <= upper)
    d = A.diagonal()
    assert np.all(d > 0), "the reference needs a positive diagonal"
    fixed = lower == upper
    z = np.clip(np.zeros(n) if z0 is None else np.asarray(z0, dtype=np.float64), lower, upper)
    seen, sweeps = set(), 0
    state = _box_state(z, A @ z + q, d, lower, upper, fixed)
    for step in range(1, maxsteps + 1):
        z = _box_solve(A, q, state, lower, upper)
        new = _box_state(z, A @ z + q, d, lower, upper, fixed)
        if np.array_equal(new, state):
            _check_box_solution(A, q, z, lower, upper)
            return BoxReferenceResult(z=z, state=state, steps=step, pgs_sweeps=sweeps)
        seen.add(state.tobytes())
        if new.tobytes() in seen:   # a cycle: the safeguard moves z, then the steps go on from there
            z = _projected_gauss_seidel(A, q, np.clip(z, lower, upper), lower, upper, pgs_sweeps)
            sweeps += pgs_sweeps
            new = _box_state(z, A @ z + q, d, lower, upper, fixed)
            seen.clear()
        state = new
    raise AssertionError(f"the reference active-set method did not end in {maxsteps} steps")


def _check_box_solution(A, q, z, lower, upper):
    """The conditions at the reference's answer (relative to the data's size)."""
    w = A @ z + q
    scale = abs(A) @ np.abs(z) + np.abs(q) + 1.0
    tol = 1e-9 * scale
    assert np.all(z >= lower) and np.all(z <= upper)
    at_lower, at_upper = z == lower, z == upper
    between = ~(at_lower | at_upper)
    assert np.all(np.abs(w[between]) <= tol[between])
    assert np.all(w[at_lower & ~at_upper] >= -tol[at_lower & ~at_upper])
    assert np.all(w[at_upper & ~at_lower] <= tol[at_upper & ~at_lower])
