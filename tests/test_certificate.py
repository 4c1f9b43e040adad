"""Tests of nrmicp.certificate.convergence_bound (the paper's sufficient conditions, section 4).

(1) the exact rho(T) agrees with an independent dense brute-force computation written here;
(2) the matrix-free (large-n) value is an upper bound on the exact rho(T);
(3) certified problems do converge, from several random starts, with a plain numpy
    implementation of SPEC.md's loop written here (and with nrmicp.solve when importable);
(4) an uncertified problem says "not certified (sufficient condition only)";
(5) bad input raises errors naming the argument.
"""

import importlib.util
import pathlib
import sys

import numpy as np
import pytest
import scipy.sparse as sp

# Test the module of this checkout (pure numpy/scipy, importable without the compiled core);
# an installed nrmicp may hold an older copy until it is reinstalled.
_path = pathlib.Path(__file__).resolve().parents[1] / "python" / "nrmicp" / "certificate.py"
if _path.exists():
    _spec = importlib.util.spec_from_file_location("_nrmicp_certificate_under_test", _path)
    _mod = importlib.util.module_from_spec(_spec)
    sys.modules[_spec.name] = _mod          # dataclasses need the module registered
    _spec.loader.exec_module(_mod)
    Certificate, convergence_bound = _mod.Certificate, _mod.convergence_bound
else:
    from nrmicp.certificate import Certificate, convergence_bound

from nrmicp.scenes.bai import bai_matrix  # noqa: E402

try:
    import nrmicp as _nrmicp
    _HAVE_SOLVE = callable(getattr(_nrmicp, "solve", None))
except Exception:  # noqa: BLE001 - any failure to import means "not available"
    _nrmicp, _HAVE_SOLVE = None, False



def _openblas_thread_setters():
    """(get, set) pairs of the OpenBLAS builds numpy/scipy wheels bundle, found via ctypes."""
    import ctypes
    import glob
    import os
    pairs = []
    import importlib
    for base in ("numpy", "scipy"):
        top = importlib.import_module(base)
        root = os.path.dirname(os.path.dirname(os.path.abspath(top.__file__)))
        for f in glob.glob(os.path.join(root, base + ".libs", "*openblas*.so*")):
            try:
                lib = ctypes.CDLL(f)
            except OSError:
                continue
            for suffix in ("64_", ""):
                get = getattr(lib, "scipy_openblas_get_num_threads" + suffix, None)
                put = getattr(lib, "scipy_openblas_set_num_threads" + suffix, None)
                if get is not None and put is not None:
                    pairs.append((get, put))
                    break
    return pairs


@pytest.fixture(autouse=True, scope="module")
def _single_threaded_blas():
    """These tests do many small dense eigenproblems; a multi-threaded OpenBLAS on a busy
    machine makes each of them ~100x slower (threads spin on oversubscribed cores)."""
    try:
        pairs = _openblas_thread_setters()
        saved = [(put, get()) for get, put in pairs]
        for _, put in pairs:
            put(1)
    except Exception:  # noqa: BLE001 - best effort only
        saved = []
    yield
    for put, n in saved:
        put(n)


METHODS = ("nrm", "nrmm", "nrmaor", "nrmsor", "nrmgs", "nrmj", "mms", "two_sweep")
NOT_CERTIFIED = "not certified (sufficient condition only)"


# ---------------------------------------------------------------------------------------------
# problems


def bai(m, symmetric=True, mu=4.0):
    """Bai's matrix of the scene (nrmicp.scenes.bai.bai_matrix)."""
    return bai_matrix(m, mu=mu, symmetric=symmetric)


def flipped(A, seed=0):
    """Random signs on the off-diagonal entries: <A> is unchanged (still H+), A is no M-matrix."""
    C = sp.coo_matrix(A)
    rng = np.random.default_rng(seed)
    sign = np.where((C.row != C.col) & (rng.random(C.nnz) < 0.5), -1.0, 1.0)
    return sp.csr_matrix((C.data * sign, (C.row, C.col)), shape=C.shape)


def known_icp(A, c, seed=0):
    """q and zeta(z) = c sin(z) + s with a known solution z* (c = 0: an LCP, zeta = None)."""
    n = A.shape[0]
    rng = np.random.default_rng(seed)
    active = rng.random(n) < 0.5
    g = np.where(active, 0.0, rng.uniform(0.5, 1.5, n))
    w = np.where(active, rng.uniform(0.5, 1.5, n), 0.0)
    if c == 0:
        return w - A @ g, None, g
    z = g + rng.uniform(-1.0, 1.0, n)
    s = z - g - c * np.sin(z)
    return w - A @ z, (lambda y: c * np.sin(y) + s), z


# ---------------------------------------------------------------------------------------------
# independent dense brute force (paper's formulas written out again, nothing shared)


def dense_parts(A, method, alpha=None, beta=None, omega1=None, omega2=None, phi=None):
    Ad = np.asarray(A.todense())
    n = Ad.shape[0]
    D = np.diag(np.diag(Ad))
    L = -np.tril(Ad, -1)
    U = -np.triu(Ad, 1)
    if method in ("nrm", "nrmm"):
        M = Ad.copy()
    else:
        a, b = {"nrmgs": (1.0, 1.0), "nrmj": (1.0, 0.0)}.get(method, (alpha or 1.0, None))
        if method not in ("nrmgs", "nrmj"):
            b = a if beta is None else beta
        M = (D - b * L) / a
    N = M - Ad
    W1 = np.diag(np.broadcast_to(1.0 if omega1 is None else omega1, (n,)).astype(float))
    if omega2 is None:
        omega2 = {"nrm": 1.0, "nrmm": np.mean(np.diag(Ad)) if alpha is None else alpha}.get(method, np.diag(Ad))
    W2 = np.diag(np.broadcast_to(omega2, (n,)).astype(float))
    P = np.diag(np.broadcast_to(0.0 if phi is None else phi, (n,)).astype(float))
    return Ad, D, L, U, M, N, W1, W2, P


def brute_rho(A, method, psi=0.0, z_update="solve", theta=1.0, **kw):
    Ad, D, L, U, M, N, W1, W2, P = dense_parts(A, method, **kw)
    n = Ad.shape[0]
    Psi = psi * np.eye(n)
    K = np.abs(np.linalg.inv(W2 + (M + P) @ W1))
    if method == "two_sweep":
        P1 = np.abs(N) + np.abs(W2 - (D - U))
        top = K @ (P1 + 2 * np.abs(Ad) @ Psi @ np.abs(np.linalg.inv(Ad)) @ W2)
        T = np.block([[theta * top + abs(1 - theta) * np.eye(n), theta * K @ np.abs(L)],
                      [np.eye(n), np.zeros((n, n))]])
    elif z_update == "explicit" and psi > 0:
        P1 = np.abs((N + P) @ W1) + np.abs(W2 - Ad @ W1)
        T = np.block([[K @ (P1 + 2 * np.abs(Ad) @ Psi @ W1), K @ np.abs(Ad) @ Psi @ Psi],
                      [2 * W1, Psi]])
    else:  # Theorem 4.1 as printed
        T = K @ (np.abs((N + P) @ W1) + np.abs(W2 - Ad @ W1)
                 + 2 * np.abs(Ad) @ Psi @ np.abs(np.linalg.inv(Ad)) @ W2)
    return float(np.max(np.abs(np.linalg.eigvals(T))))


# ---------------------------------------------------------------------------------------------
# a tiny numpy Method 3.1 (docs/SPEC.md's loop), started from an arbitrary x0


def tiny_iteration(A, q, zeta, method, x0, z_update="solve", zprev=None, maxiter=3000, tol=1e-10, **kw):
    Ad, D, L, U, M, N, W1, W2, P = dense_parts(A, method, **kw)
    w1, w2 = np.diag(W1), np.diag(W2)
    n = len(q)
    ze = (lambda z: np.zeros(n)) if zeta is None else zeta
    Lm = W2 + (M + P) @ W1
    x, x_prev = x0.copy(), x0.copy()
    z_prev = np.zeros(n) if zprev is None else zprev
    for k in range(maxiter + 1):
        if z_update == "explicit":
            z = ze(z_prev) + w1 * (np.abs(x) + x)
        else:  # A z = Omega2(|x| - x) - q  (gamma = 1)
            z = np.linalg.solve(Ad, w2 * (np.abs(x) - x) - q)
        res = np.linalg.norm(np.minimum(Ad @ z + q, z - ze(z)))
        if res < tol:
            return z, k
        if not np.isfinite(res):
            break
        if method == "two_sweep":
            rhs = N @ x + (W2 - (D - U)) @ np.abs(x) + L @ np.abs(x_prev) - Ad @ ze(z) - q
            x_new = np.linalg.solve(Lm, rhs)
        else:
            rhs = (N + P) @ (w1 * x) + (W2 - Ad @ W1) @ np.abs(x) - Ad @ ze(z) - q
            x_new = np.linalg.solve(Lm, rhs)
        x_prev, x, z_prev = x, x_new, z
    return z, None


# ---------------------------------------------------------------------------------------------
# (1) exact rho(T) == brute force


@pytest.mark.parametrize("m", [4, 5, 6, 7, 8])
@pytest.mark.parametrize("symmetric", [True, False])
def test_exact_rho_matches_brute_force_on_bai(m, symmetric):
    A = bai(m, symmetric)
    for method in METHODS:
        # the brute force knows the two-sweep recursion with the paper's z-update only
        for psi, zu in ((0.0, "solve"), (0.1, "solve"), (0.1, "explicit"))[:2 if method == "two_sweep" else 3]:
            c = convergence_bound(A, method=method, lipschitz=psi, z_update=zu)
            assert isinstance(c, Certificate)
            assert c.rho_is_exact
            ref = brute_rho(A, method, psi, z_update=zu)
            assert c.rho == pytest.approx(ref, rel=1e-9, abs=1e-12), (method, psi, zu)
            assert c.certified == (ref < 1)
            assert c.conditions["A_is_H_plus"]
            if method != "two_sweep":
                assert c.conditions["H_splitting"] is True   # Bai's matrices are M-matrices


@pytest.mark.parametrize("symmetric", [True, False])
def test_exact_rho_matches_brute_force_nondefault_parameters(symmetric):
    A = flipped(bai(5, symmetric), seed=3)
    n = A.shape[0]
    rng = np.random.default_rng(7)
    w1 = rng.uniform(0.5, 2.0, n)
    ph = rng.uniform(0.0, 1.0, n)
    cases = [
        ("nrmaor", dict(alpha=1.2, beta=0.7, omega1=w1, phi=ph)),
        ("nrmsor", dict(alpha=0.9, phi=0.3)),
        ("nrm", dict(omega2=8.0, omega1=w1)),
        ("nrmm", dict(alpha=5.0, phi=ph)),
        ("nrmgs", dict(omega2=np.full(n, 10.0))),
        ("mms", dict(alpha=1.1, beta=0.5)),
    ]
    for method, kw in cases:
        for psi, zu in ((0.0, "solve"), (0.15, "solve"), (0.15, "explicit")):
            c = convergence_bound(A, method=method, lipschitz=psi, z_update=zu, **kw)
            ref = brute_rho(A, method, psi, z_update=zu, **kw)
            assert c.rho == pytest.approx(ref, rel=1e-9, abs=1e-12), (method, kw, psi, zu)
    for theta in (0.7, 1.0, 1.3):
        c = convergence_bound(A, method="two_sweep", lipschitz=0.1, theta=theta, alpha=1.1, z_update="solve")
        assert c.rho == pytest.approx(brute_rho(A, "two_sweep", 0.1, theta=theta, alpha=1.1), rel=1e-9)


def test_lipschitz_forms_agree():
    A = bai(5, False)
    n = A.shape[0]
    ref = convergence_bound(A, lipschitz=0.2).rho
    assert convergence_bound(A, lipschitz=np.full(n, 0.2)).rho == pytest.approx(ref, rel=1e-12)
    assert convergence_bound(A, lipschitz=0.2 * np.eye(n)).rho == pytest.approx(ref, rel=1e-12)
    assert convergence_bound(A, lipschitz=sp.identity(n) * 0.2).rho == pytest.approx(ref, rel=1e-12)
    assert convergence_bound(A.toarray(), lipschitz=0.2).rho == pytest.approx(ref, rel=1e-12)
    # a full Lipschitz matrix is (correctly) more pessimistic than its diagonal
    full = np.full((n, n), 0.2 / n) + 0.1 * np.eye(n)
    assert convergence_bound(A, lipschitz=full).rho > convergence_bound(A, lipschitz=0.1).rho


def test_theorem_4_3():
    """nrmj (alpha=1, beta=0, Omega2=D): Theorem 4.3's matrix is T itself; and whenever
    Theorem 4.3 holds for an AOR pair, rho(T) < 1 (it is a consequence of Theorem 4.1)."""
    A = bai(6, False)
    for psi in (0.0, 0.1, 0.3):  # Theorem 4.3 is stated for the paper's z-update
        c = convergence_bound(A, method="nrmj", lipschitz=psi, z_update="solve")
        assert c.conditions["thm43_rho"] == pytest.approx(c.rho, rel=1e-9)
    held = 0
    for alpha in (0.5, 0.8, 1.0, 1.3, 1.8):
        for beta in (0.0, 0.5, 1.0, 1.5):
            for psi in (0.0, 0.1):
                c = convergence_bound(A, method="nrmaor", alpha=alpha, beta=beta, lipschitz=psi, z_update="solve")
                cond = c.conditions
                assert cond["omega2_ge_D_omega1"]
                assert cond["thm43_lhs"] == pytest.approx(max(alpha, beta) * cond["thm43_rho"])
                assert cond["thm43_rhs"] == min(1.0, alpha)
                if cond["thm43_holds"]:
                    held += 1
                    assert c.rho < 1 and c.certified
    assert held > 5


# ---------------------------------------------------------------------------------------------
# (2) the matrix-free value is an upper bound


@pytest.mark.parametrize("m,symmetric,flip", [(8, True, False), (9, False, True), (10, True, True)])
def test_large_n_bound_is_upper_bound(m, symmetric, flip):
    A = bai(m, symmetric)
    if flip:
        A = flipped(A, seed=m)
    methods = ("nrm", "nrmsor", "nrmj", "two_sweep") if m >= 10 else ("nrmm", "nrmgs", "nrmj", "two_sweep")
    for method in methods:
        kw = dict(alpha=1.2) if method == "nrmsor" else {}
        for psi, zu in ((0.0, "auto"), (0.1, "solve"), (0.1, "explicit")):
            exact = convergence_bound(A, method=method, lipschitz=psi, z_update=zu, **kw)
            bound = convergence_bound(A, method=method, lipschitz=psi, z_update=zu, exact_max_n=0,
                                      maxiter=200, **kw)
            assert exact.rho_is_exact and not bound.rho_is_exact
            assert bound.rho >= exact.rho * (1 - 1e-12), (method, psi, zu)
            # ... and it is the comparison-matrix majorant of Theorems 4.2-4.4, not far above it
            assert bound.rho >= exact.conditions["rho_comparison"] * (1 - 1e-9)
            assert bound.rho <= exact.conditions["rho_comparison"] * 1.2 + 1e-12
            assert bound.conditions["rho_T_cw_lower"] <= exact.conditions["rho_comparison"] * (1 + 1e-9)
            if flip and psi == 0 and method != "nrmj":
                assert bound.rho > exact.rho * (1 + 1e-6)   # strictly pessimistic for a non-M-matrix


def test_large_n_path_certifies_bigger_problem():
    A = bai(40, False)                                     # n = 1600, matrix-free
    c = convergence_bound(A, method="nrmgs", lipschitz=0.1, exact_max_n=1000)
    assert c.certified and not c.rho_is_exact and c.rho < 1
    assert "upper bound" in c.message and "comparison" in c.theorem
    assert c.conditions["A_is_H_plus"] and c.conditions["rho_jacobi_abs"] < 1


# ---------------------------------------------------------------------------------------------
# (3) certified problems converge


CONVERGENCE_CASES = [
    (bai(6, True), "nrmgs", 0.0, "solve", {}),
    (bai(6, False), "nrmj", 0.1, "solve", {}),
    (bai(6, False), "nrmm", 0.1, "explicit", {}),
    (flipped(bai(6, False), 1), "nrmsor", 0.1, "solve", dict(alpha=1.1)),
    (flipped(bai(6, True), 2), "nrmaor", 0.2, "explicit", dict(alpha=0.9, beta=0.6, phi=0.5)),
    (bai(6, False), "mms", 0.1, "solve", {}),
    (bai(6, False), "two_sweep", 0.1, "solve", {}),
    (flipped(bai(6, False), 4), "nrm", 0.1, "solve", dict(omega2=8.0)),
]


@pytest.mark.parametrize("A,method,c,z_update,kw", CONVERGENCE_CASES)
def test_certified_problems_converge(A, method, c, z_update, kw):
    cert = convergence_bound(A, method=method, lipschitz=c, z_update=z_update, **kw)
    assert cert.certified, cert.message
    q, zeta, z_star = known_icp(A, c, seed=5)
    rng = np.random.default_rng(11)
    n = A.shape[0]
    for trial in range(3):
        x0 = rng.normal(scale=10.0, size=n)
        zprev = rng.normal(scale=10.0, size=n)
        z, nit = tiny_iteration(A, q, zeta, method, x0, z_update=z_update, zprev=zprev, **kw)
        assert nit is not None, (method, trial)
        assert np.linalg.norm(z - z_star) < 1e-8


@pytest.mark.skipif(not _HAVE_SOLVE, reason="nrmicp (compiled) is not importable")
@pytest.mark.parametrize("A,method,c,z_update,kw", CONVERGENCE_CASES)
def test_certified_problems_converge_with_nrmicp_solve(A, method, c, z_update, kw):
    assert convergence_bound(A, method=method, lipschitz=c, z_update=z_update, **kw).certified
    q, zeta, z_star = known_icp(A, c, seed=5)
    rng = np.random.default_rng(13)
    for trial in range(3):
        z0 = rng.normal(scale=10.0, size=A.shape[0])
        r = _nrmicp.solve(A, q, zeta, method=method, z_update=z_update, tol=1e-9, x0=z0, **kw)
        assert r.success, r.message
        assert r.residual < 1e-8
        assert np.linalg.norm(r.z - z_star) < 1e-6


# ---------------------------------------------------------------------------------------------
# (4) not certified: sufficient only


def test_not_certified_message_and_still_converges():
    A = bai(6, True)
    c = convergence_bound(A, method="nrm")          # the paper's Omega1 = Omega2 = I
    assert not c.certified and c.rho >= 1 and c.rho_is_exact
    assert NOT_CERTIFIED in c.message
    assert "Theorem 4.1" in c.theorem
    # ... yet the iteration converges: the condition is sufficient, not necessary
    q, zeta, z_star = known_icp(A, 0.0, seed=2)
    z, nit = tiny_iteration(A, q, zeta, "nrm", np.zeros(A.shape[0]), maxiter=2000)
    assert nit is not None and np.linalg.norm(z - z_star) < 1e-8

    cb = convergence_bound(A, method="nrm", exact_max_n=0)
    assert not cb.certified and cb.rho >= c.rho * (1 - 1e-12) and NOT_CERTIFIED in cb.message


def test_not_certified_when_no_matrix_free_bound():
    # A with a zero-free but not H diagonal: the comparison bound is unavailable
    rng = np.random.default_rng(0)
    A = sp.csr_matrix(rng.uniform(-1, 1, (30, 30)) + 3 * np.eye(30))
    c = convergence_bound(A, method="nrm", omega2=10.0, lipschitz=0.1, exact_max_n=0)
    assert not c.certified and c.rho == np.inf and NOT_CERTIFIED in c.message


# ---------------------------------------------------------------------------------------------
# (5) bad input


def test_bad_inputs():
    A = bai(4)
    n = A.shape[0]
    bad = [
        (dict(A=np.ones((3, 4))), ValueError, "square"),
        (dict(A=np.ones(5)), ValueError, "2-D"),
        (dict(A=sp.csr_matrix((0, 0))), ValueError, "non-empty"),
        (dict(method="sor"), ValueError, "method"),
        (dict(lipschitz=-0.1), ValueError, "lipschitz"),
        (dict(lipschitz=np.full(n + 1, 0.1)), ValueError, "lipschitz"),
        (dict(lipschitz=-np.eye(n)), ValueError, "lipschitz"),
        (dict(lipschitz=np.full((n, n + 1), 0.1)), ValueError, "lipschitz"),
        (dict(omega1=np.ones(n - 1)), ValueError, "omega1"),
        (dict(omega1=0.0), ValueError, "omega1"),
        (dict(omega2=-1.0), ValueError, "omega2"),
        (dict(phi=-0.5), ValueError, "phi"),
        (dict(gamma=0.0), ValueError, "gamma"),
        (dict(method="nrmaor", alpha=-1.0), ValueError, "alpha"),
        (dict(method="nrmaor", beta=-1.0), ValueError, "beta"),
        (dict(method="nrmgs", alpha=1.5), ValueError, "nrmgs"),
        (dict(method="nrmj", beta=1.0), ValueError, "nrmj"),
        (dict(method="nrmsor", alpha=1.2, beta=0.5), ValueError, "nrmsor"),
        (dict(method="mms", omega1=2.0), ValueError, "omega1"),
        (dict(method="two_sweep", phi=1.0), ValueError, "phi"),
        (dict(method="nrm", alpha=2.0), ValueError, "alpha"),
        (dict(method="nrmgs", theta=0.5), ValueError, "theta"),
        (dict(method="two_sweep", theta=2.5), ValueError, "theta"),
        (dict(z_update="implicit"), ValueError, "z_update"),
        (dict(exact_max_n=-1), ValueError, "exact_max_n"),
        (dict(maxiter=0), ValueError, "maxiter"),
        (dict(tol=0.0), ValueError, "tol"),
        (dict(A=sp.csr_matrix(np.array([[0.0, 1.0], [1.0, 2.0]]))), ValueError, "omega2"),
        (dict(A=np.array([[1.0, np.nan], [0.0, 1.0]])), ValueError, "non-finite"),
    ]
    for kw, exc, word in bad:
        kw = dict(kw)
        mat = kw.pop("A", A)
        with pytest.raises(exc, match=word):
            convergence_bound(mat, **kw)
    with pytest.raises(TypeError, match="gamma"):
        convergence_bound(A, gamma="1")
    # a singular left matrix: the iteration itself is undefined
    with pytest.raises(ValueError, match="singular"):
        convergence_bound(sp.csr_matrix(np.array([[-1.0, 0.0], [0.0, 1.0]])), method="nrm")


def test_docstring_says_sufficient_not_necessary():
    assert "SUFFICIENT, NOT NECESSARY" in convergence_bound.__doc__


@pytest.mark.skipif(not _HAVE_SOLVE, reason="nrmicp (compiled) is not importable")
def test_package_exports_certificate():
    assert callable(_nrmicp.convergence_bound)
    c = _nrmicp.convergence_bound(bai(4), method="nrmgs")
    assert c.certified and c.rho < 1


@pytest.mark.skipif(not _HAVE_SOLVE, reason="nrmicp.solve (the compiled core) is not importable")
@pytest.mark.parametrize("method,kw", [("nrm", {}), ("nrm", dict(omega2=8.0)), ("nrmm", {}), ("nrmaor", {}),
                                       ("nrmsor", {}), ("nrmgs", {}), ("nrmj", {}), ("mms", {}),
                                       ("two_sweep", {})])
def test_auto_z_update_is_the_one_solve_runs(method, kw):
    """The certificate checks the iteration the solver runs: with z_update='auto', solve's
    iterates are bit for bit those of the z-update the certificate names, and not the other's."""
    from nrmicp import scenes

    P = scenes.bai(4, kind="icp", c=0.1)
    zu = convergence_bound(P.A, method=method, lipschitz=0.1, **kw).conditions["z_update"]
    assert zu in ("solve", "explicit")
    other = {"solve": "explicit", "explicit": "solve"}[zu]
    run = {z: _nrmicp.solve(P.A, P.q, P.zeta, method=method, z_update=z, tol=1e-12, maxiter=8, **kw)
           for z in ("auto", zu, other)}
    assert np.array_equal(run["auto"].z, run[zu].z) and run["auto"].nit == run[zu].nit
    assert not np.array_equal(run["auto"].z, run[other].z)
