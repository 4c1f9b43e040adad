"""Regression tests for what an adversarial run found (issue 9): corrupt sparse structure, failed
factorizations, threads at interpreter exit, a ζ that writes into its input or returns the
wrong thing, dtype checks, int32 limits. Each test names its item."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import nrmicp


def tridiag(n=4):
    return sp.csr_matrix(4.0 * sp.identity(n) - sp.eye(n, k=1) - sp.eye(n, k=-1))


def run_script(code, timeout=60, sigint_after=None):
    """Run `code` in a fresh interpreter -> (returncode, stdout, stderr). With `sigint_after`, send
    SIGINT once the script printed that line."""
    # SIGINT's default action in the child even when this process ignores it (a job started in the
    # background by a non-interactive shell does: Python would then never raise KeyboardInterrupt)
    default_sigint = (lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)) if sigint_after is not None else None
    proc = subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"),
                            preexec_fn=default_sigint)
    try:
        if sigint_after is not None:
            line = proc.stdout.readline().strip()
            assert line == sigint_after, (line, proc.stderr.read() if proc.poll() is not None else "")
            time.sleep(0.3)
            proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, out, err


# ---- item 1: the sparse structure is validated before anything reads it ----------------------


def _corrupt(fmt, part, pos, value, index_dtype=np.int32):
    A = tridiag().asformat(fmt)
    A = type(A)((A.data, A.indices.astype(index_dtype), A.indptr.astype(index_dtype)), shape=A.shape)
    getattr(A, part)[pos] = value
    return A


@pytest.mark.parametrize("fmt", ["csr", "csc"])
@pytest.mark.parametrize("index_dtype", [np.int32, np.int64])
@pytest.mark.parametrize("part,pos,value", [
    ("indices", 1, 4),            # just past the last column: was CONVERGED from memory outside A
    ("indices", 1, 10**8),        # far outside: was a segfault
    ("indices", 3, -1),
    ("indptr", 2, 100),           # was a segfault inside scipy's sort_indices
    ("indptr", 2, 1),             # decreasing
    ("indptr", 0, 1),             # does not start at 0
    ("indptr", -1, 2**31 - 1),    # INT32_MAX: p[r] + 1 overflowed in the canonical check
])
def test_item1_corrupt_structure_is_a_value_error_naming_A(fmt, index_dtype, part, pos, value):
    A = _corrupt(fmt, part, pos, value, index_dtype)
    before = (A.data.copy(), A.indices.copy(), A.indptr.copy())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ValueError, match=r"A is not a valid sparse matrix: A\.(indices|indptr)"):
            nrmicp.solve(A, -np.ones(4))
    for b, a in zip(before, (A.data, A.indices, A.indptr)):
        np.testing.assert_array_equal(b, a)


def test_item1_corrupt_zeta_B_names_zeta_B():
    B = 0.1 * tridiag()
    B.indices[1] = 7
    with pytest.raises(ValueError, match=r"zeta\.B is not a valid sparse matrix"):
        nrmicp.solve(tridiag(), -np.ones(4), nrmicp.Affine(B, np.zeros(4)))


def test_item1_corrupt_coo_names_A():
    A = tridiag().tocoo()
    A.row[2] = 9
    with pytest.raises(ValueError, match=r"A is not a valid sparse matrix: A\.row\[2\] = 9"):
        nrmicp.solve(A, -np.ones(4))


def test_item1_trailing_unused_storage_is_ignored_like_scipy():
    A = tridiag()
    nnz = A.nnz
    A2 = sp.csr_matrix((np.r_[A.data, 7.0], np.r_[A.indices, 99].astype(A.indices.dtype), A.indptr.copy()),
                       shape=A.shape)
    assert A2.indptr[-1] == nnz
    np.testing.assert_allclose(nrmicp.solve(A2, -np.ones(4)).z, nrmicp.solve(A, -np.ones(4)).z)


# ---- items 2, 3, 8: failed factorizations ------------------------------------------------------


@pytest.mark.parametrize("inner", ["auto", "cholmod", "umfpack", "eigen_llt", "eigen_lu"])
def test_item2_3_zero_matrix_is_rejected_before_factorizing(inner):
    # A subprocess: on the old code CHOLMOD segfaulted and Eigen's SparseLU never returned.
    code = f"""
        import numpy as np, scipy.sparse as sp, nrmicp
        try:
            nrmicp.Solver(sp.csr_matrix((30, 30)), method="nrmgs", omega2=1.0, inner={inner!r}, z_update="solve")
        except np.linalg.LinAlgError as e:
            print("LinAlgError:", e)
    """
    rc, out, err = run_script(code, timeout=30)
    assert rc == 0, err
    assert "LinAlgError: InnerSolver: A (for the z-update 'solve') is singular: its row 0 has no nonzero" in out


def test_item2_out_of_memory_in_cholmod_is_a_memory_error():
    if os.environ.get("NRMICP_SANITIZE"):
        pytest.skip("under ASan (make sanitize) an address-space cap cannot work: its shadow memory is reserved")
    # 3D Laplacian, n = 15,625, under an address-space cap 30 MB above what the process uses:
    # CHOLMOD's factor does not fit. The old code ignored CHOLMOD's status (a silent wrong factor).
    code = """
        import resource, numpy as np, scipy.sparse as sp, nrmicp
        m = 25
        T = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
        I = sp.identity(m)
        A = sp.csr_matrix(sp.kron(sp.kron(I, I), T) + sp.kron(sp.kron(I, T), I) + sp.kron(sp.kron(T, I), I))
        used = int(open("/proc/self/statm").read().split()[0]) * resource.getpagesize()
        resource.setrlimit(resource.RLIMIT_AS, (used + 30 * 2**20, resource.RLIM_INFINITY))
        try:
            nrmicp.Solver(A, method="nrm", inner="cholmod")
            print("no error")
        except MemoryError as e:
            print("MemoryError:", e)
    """
    rc, out, err = run_script(code)
    assert rc == 0, err
    assert "MemoryError:" in out, out


def test_item8_singular_A_is_a_linalg_error_at_setup_and_in_a_lazy_factorization():
    A = sp.csr_matrix(np.array([[1.0, 1.0], [1.0, 1.0]]))  # singular, no empty row or column
    with pytest.raises(np.linalg.LinAlgError, match=r"A \(for the z-update 'solve'\)"):
        nrmicp.Solver(A, z_update="solve")
    s = nrmicp.Solver(A, method="nrmgs")  # explicit update: A is not factorized at set-up
    with pytest.raises(np.linalg.LinAlgError, match=r"A \(for the z-update 'solve'\)"):
        s.solve(-np.ones(2), lambda z: 0.1 * z, z_update="solve")


def test_item8_singular_left_matrix_names_the_left_matrix():
    A = sp.csr_matrix(np.array([[0.0, 1.0], [1.0, 0.0]]))  # nrm: Lm = I + A = [[1, 1], [1, 1]]
    with pytest.raises(np.linalg.LinAlgError, match="left matrix"):
        nrmicp.Solver(A, method="nrm")


# ---- item 4: threads at interpreter exit ----------------------------------------------------

_LONG_SOLVE_IN_A_DAEMON_THREAD = textwrap.dedent("""
    import threading, time, numpy as np, scipy.sparse as sp, nrmicp
    m = 120
    T = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
    A = sp.csr_matrix(sp.kron(sp.identity(m), T) + sp.kron(T, sp.identity(m)))
    started = threading.Event()
    def work():
        started.set()
        nrmicp.solve(A, -np.ones(m * m), method="nrmj", tol=1e-300, maxiter=10**8, stall_iterations=10**6)
    th = threading.Thread(target=work, daemon=True)
    th.start()
    started.wait()
    time.sleep(0.3)  # the worker is inside the C++ loop
""")


class KnownAsanThreadExitReport(Exception):
    """ASan's report from its own sigaltstack interceptor (__asan_handle_no_return) while
    pthread_exit's forced unwind destroys the solving thread's frames."""


def _no_sanitizer_report(err):
    """Fails on a sanitizer report in a child's stderr; the known ASan one raises
    KnownAsanThreadExitReport (expected under make sanitize only), any other an AssertionError.
    Known: a stack-buffer-overflow whose frame #0 is the sigaltstack interceptor, or whose frames
    were never written (after Ctrl-C the process dies while ASan is still printing)."""
    at = err.find("ERROR: AddressSanitizer: stack-buffer-overflow")
    if at >= 0:
        report = err[at:].splitlines()
        frame0 = next((line for line in report if line.strip().startswith("#0 ")), None)
        if frame0 is None or "sigaltstack" in frame0:
            raise KnownAsanThreadExitReport(report[0])
    assert "Sanitizer" not in err, err


#: make sanitize (NRMICP_SANITIZE=1): the two thread-exit tests below end in ASan's report from its
#: own interceptor, every run (its exit code only sometimes shows it: the report races the exit).
#: Only that report is expected (raises=); any other failure still fails. Not strict: if the
#: process exits before the dying thread is unwound, there is no report and the test passes.
_ASAN_THREAD_EXIT = pytest.mark.xfail(
    bool(os.environ.get("NRMICP_SANITIZE")), raises=KnownAsanThreadExitReport, strict=False,
    reason="under ASan only: a stack-buffer-overflow reported by ASan's sigaltstack interceptor "
           "(__asan_handle_no_return) during pthread_exit's forced unwind of the solving thread, a "
           "known ASan false positive; the test passes without ASan")


@_ASAN_THREAD_EXIT
@pytest.mark.skipif(sys.platform == "win32", reason="POSIX threads and signals")
def test_item4_interpreter_exit_while_a_thread_solves_is_clean():
    rc, out, err = run_script(_LONG_SOLVE_IN_A_DAEMON_THREAD + "print('exiting')\n")
    _no_sanitizer_report(err)
    assert "terminate called" not in err
    assert rc == 0, f"exit code {rc}: {err}"
    assert out.strip() == "exiting"


@_ASAN_THREAD_EXIT
@pytest.mark.skipif(sys.platform == "win32", reason="POSIX threads and signals")
def test_item4_ctrl_c_in_join_while_a_thread_solves_is_clean():
    rc, out, err = run_script(_LONG_SOLVE_IN_A_DAEMON_THREAD + "print('joining')\nth.join()\n",
                              sigint_after="joining")
    _no_sanitizer_report(err)
    assert "terminate called" not in err
    assert "KeyboardInterrupt" in err
    assert rc in (-signal.SIGINT, 1, 130), f"exit code {rc} (SIGABRT is {-signal.SIGABRT}): {err}"


# ---- item 5: ζ gets a read-only array that is never the result --------------------------------


@pytest.mark.parametrize("scale", [False, "rows", "both"])
@pytest.mark.parametrize("kind", ["plain", "anderson", "solve"])
def test_item5_zeta_input_is_read_only_and_never_the_result(scale, kind):
    A = sp.csr_matrix(sp.diags(2.0 ** np.arange(-3, 3)) @ tridiag(6).toarray())
    q = -np.ones(6)
    seen = []

    def zeta(z):
        seen.append(z)
        assert not z.flags.writeable
        return 0.1 * np.sin(z)

    opts = {"plain": {}, "anderson": dict(accelerate="anderson"), "solve": dict(z_update="solve")}[kind]
    res = nrmicp.solve(A, q, zeta, scale=scale, **opts)
    assert res.success
    assert seen and not any(np.shares_memory(z, res.z) for z in seen)


@pytest.mark.parametrize("scale", [False, "both"])
def test_item5_in_place_zeta_is_an_error_naming_zeta_not_a_false_success(scale):
    # was: success=True with reported residual 3.4e-9 and true Res 0.947 (scale='both')
    A = sp.csr_matrix(sp.diags(2.0 ** np.arange(-2, 2)) @ tridiag().toarray())

    def zeta(z):
        z += 0.1
        return np.zeros_like(z)

    with pytest.raises(ValueError, match=r"zeta\(z\) tried to modify its input z, which is read-only"):
        nrmicp.solve(A, -np.ones(4), zeta, scale=scale)


@pytest.mark.parametrize("scale", [False, "both"])
def test_item5_a_zeta_that_forces_its_input_writable_cannot_fake_success(scale):
    A = sp.csr_matrix(sp.diags(2.0 ** np.arange(-2, 2)) @ tridiag().toarray())
    q = -np.ones(4)

    def zeta(z):
        try:
            z.flags.writeable = True
            z[:] = 5.0  # scribble over its input, then return a legitimate value
        except ValueError:
            pass
        return np.zeros(4)

    res = nrmicp.solve(A, q, zeta, scale=scale)
    w = A @ res.z + q
    true_res = np.linalg.norm(np.minimum(w, res.z))
    assert not res.success or true_res < 1e-8, (res.residual, true_res)


# ---- item 9: dtypes by kind and size; every argument and ζ named --------------------------------


def test_item9_longlong_indices_are_int64():
    A = tridiag()
    A.indices = A.indices.astype(np.longlong)
    A.indptr = A.indptr.astype(np.longlong)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # zero-copy: no ConversionWarning
        res = nrmicp.solve(A, -np.ones(4))
    assert res.success


def test_item9_float64_with_metadata_is_float64():
    A = tridiag()
    A.data = A.data.astype(np.dtype(np.float64, metadata={"unit": "m"}))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert nrmicp.solve(A, -np.ones(4)).success


@pytest.mark.parametrize("name", ["maxiter", "stall_iterations"])
def test_item9_int_options_beyond_int32_name_themselves(name):
    with pytest.raises(ValueError, match=name):
        nrmicp.solve(tridiag(), -np.ones(4), **{name: 2**31})


@pytest.mark.parametrize("ret", [
    lambda z: [1 + 0j] * 4,
    lambda z: z.astype(np.complex128),
    lambda z: ["0.1"] * 4,
    lambda z: np.array(["0.1"] * 4),
    lambda z: None,
    lambda z: b"abcd",
    lambda z: [[0.0, 1.0], [0.0]],
    lambda z: np.array([None] * 4),
])
@pytest.mark.parametrize("scale", [False, "both"])
def test_item9_zeta_returning_a_non_real_thing_is_a_type_error_naming_zeta(ret, scale):
    with pytest.raises(TypeError, match=r"zeta\(z\)"):
        nrmicp.solve(tridiag(), -np.ones(4), ret, scale=scale)


@pytest.mark.parametrize("dtype", [np.float32, np.int64, np.float16])
def test_item9_zeta_of_another_real_dtype_is_converted_with_one_warning_per_solve(dtype):
    A, q = tridiag(), -np.ones(4)
    for _ in range(2):  # once per solve, not once per process or per iteration
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = nrmicp.solve(A, q, lambda z: np.zeros(4, dtype=dtype))
        msgs = [str(w.message) for w in caught if issubclass(w.category, nrmicp.ConversionWarning)]
        assert len(msgs) == 1 and "zeta(z) returned dtype" in msgs[0], msgs
        assert res.success


def test_item9_float64_zeta_output_needs_no_conversion():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert nrmicp.solve(tridiag(), -np.ones(4), lambda z: 0.1 * np.sin(z)).success


def test_item9_zeta_failed_message_says_it_once():
    with pytest.raises(ValueError) as info:
        nrmicp.solve(tridiag(), -np.ones(4), lambda z: np.full(4, np.nan))
    msg = str(info.value)
    assert msg.startswith("zeta(z)") and msg.count("non-finite") == 1, msg


@pytest.mark.parametrize("member", ["newton", "newton+jacobian", "newton+hierarchy", "nrmgs"])
@pytest.mark.parametrize("call", [1, 4])
def test_a_zeta_returning_nan_at_any_call_raises_naming_it(member, call):
    """Found by review: the Newton member's outer and semismooth paths took a NaN of zeta's later calls for a
    failed step (DIVERGED "overflowed", STAGNATED, or CONVERGED past a single NaN entry); README: a ζ returning
    NaN/Inf raises ValueError, in every member and at whichever call."""
    n = 1200 if member == "newton+hierarchy" else 200
    A = sp.csr_matrix(sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n)) * (n + 1) ** 2)
    x = np.linspace(0, 1, n + 2)[1:-1]
    psi, calls = -2 + 2 * (x - 0.5) ** 2, []

    def zeta(z):
        calls.append(1)
        out = psi + 0.2 * np.sin(z)
        if len(calls) == call:
            out[7] = np.nan
        return out
    options = {"method": member.split("+")[0],
               "zeta_jacobian": (lambda z: sp.diags(0.2 * np.cos(z))) if member == "newton+jacobian" else None,
               "hierarchy": "amg" if member == "newton+hierarchy" else None}
    with pytest.raises(ValueError, match=r"^zeta\(z\) returned non-finite values \(NaN or Inf\): zeta\(z\)\[7\] = nan$"):
        nrmicp.solve(A, 50 * np.ones(n), zeta, **options)
    assert len(calls) == call   # (raised at that call)


def test_a_nan_of_zeta_at_a_non_finite_z_is_the_iterations_not_zetas():
    """Found by review of the rule above: the Newton member may hand ζ a non-finite trial z (here a Jacobian 4x
    ζ′ overshoots into overflow, z in units of 6e307), whose NaN the rule blamed on ζ; the solve converges when
    the core judges that trial."""
    m, t = 300, 6e307
    A = sp.csr_matrix(sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m)) * (m + 1) ** 2)
    x = np.linspace(0, 1, m + 2)[1:-1]
    psi = 0.3 - 2 * (x - 0.5) ** 2
    inputs = []

    def zeta(z):
        inputs.append(bool(np.all(np.isfinite(z))))
        return t * (psi + 0.05 * np.sin(z / t * 10))

    def jacobian(z):
        c = 2.0 * np.cos(z / t * 10)
        return spla.LinearOperator((m, m), matvec=lambda v: c * np.ravel(v), dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # (sin of the non-finite trial)
        res = nrmicp.solve(A / t, 8.0 * np.ones(m), zeta, method="newton", zeta_jacobian=jacobian)
    assert res.success, res.message
    assert not all(inputs)   # (else this test no longer reaches the case)
    z = res.z
    d = t / (2 * (m + 1) ** 2)   # (w in z's units: 1 / max_j |a_ij|; max, not a 2-norm: squares of 1e199 overflow)
    assert np.abs(np.minimum(d * (A / t @ z + 8.0), z - zeta(z))).max() < 1e-8 * np.abs(z).max()


def test_item9_small_values_are_shown_as_g():
    A = sp.csr_matrix(np.diag([-1e-7, 1.0]))
    with pytest.raises(ValueError, match=r"A\[0,0\] = -1e-07"):
        nrmicp.solve(A, -np.ones(2), method="nrmgs")
