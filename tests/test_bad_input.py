"""Bad input: a clear exception naming the argument, or the documented status; the caller's
arrays are never modified. Property-based (hypothesis) over shapes, dtypes, formats, index types."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import nrmicp
from nrmicp import scenes
from reference_impl import residual as reference_residual
from snapshots import assert_unchanged, snapshot

SETTINGS = settings(max_examples=25)  # derandomized, no database: the profile of tests/conftest.py


def bai_like(n, rng):
    """Strictly diagonally dominant (an H+-matrix, hence P): every method converges."""
    R = sp.random(n, n, density=min(1.0, 3.0 / n), random_state=rng, data_rvs=lambda k: rng.uniform(-1, 1, k))
    R = sp.csr_matrix(R)
    R.setdiag(0)
    R.eliminate_zeros()
    return sp.csr_matrix(R + sp.diags(abs(R).sum(axis=1).A1 + 1.0))


def in_format(A, fmt, index_dtype):
    if fmt == "dense":
        return A.toarray()
    M = A.asformat(fmt)
    if fmt in ("csr", "csc"):
        M = type(M)((M.data, M.indices.astype(index_dtype), M.indptr.astype(index_dtype)), shape=M.shape)
    else:
        M = sp.coo_matrix((M.data, (M.row.astype(index_dtype), M.col.astype(index_dtype))), shape=M.shape)
    return M


# ---- valid inputs in every format / dtype / index type give the same answer ----------------


@SETTINGS
@given(n=st.integers(1, 12), seed=st.integers(0, 10_000),
       fmt=st.sampled_from(["csr", "csc", "coo", "dense"]),
       index_dtype=st.sampled_from([np.int32, np.int64]),
       dtype=st.sampled_from([np.float64, np.float32, np.int64]),
       qdtype=st.sampled_from([np.float64, np.float32, np.int32]),
       scale=st.sampled_from([False, "rows", "both"]))
def test_formats_dtypes_agree(n, seed, fmt, index_dtype, dtype, qdtype, scale):
    rng = np.random.default_rng(seed)
    A64 = bai_like(n, rng)
    if dtype != np.float64:
        A64 = sp.csr_matrix(np.round(A64.toarray() * 4))  # exactly representable in float32 / int
    A = in_format(A64, fmt, index_dtype).astype(dtype)
    q = np.round(rng.uniform(-5, 5, n)).astype(qdtype)
    zc = rng.uniform(-1, 1, n)
    before = snapshot(A, q, zc)
    ref = nrmicp.solve(sp.csr_matrix(A64.astype(np.float64)), q.astype(np.float64), zc)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = nrmicp.solve(A, q, zc, scale=scale)
    if fmt == "dense" or fmt in ("csc", "coo"):
        assert any(issubclass(w.category, nrmicp.ConversionWarning) for w in caught)
    assert_unchanged(before, [A, q, zc])
    assert res.success and ref.success
    np.testing.assert_allclose(res.z, ref.z, atol=1e-6 * (1 + np.abs(ref.z).max()))
    assert reference_residual(A64, q.astype(float), res.z, zc) < 1e-8


def test_bool_matrix_is_accepted():
    with pytest.warns(nrmicp.ConversionWarning):
        res = nrmicp.solve(np.eye(3, dtype=bool), -np.ones(3))
    assert res.success
    np.testing.assert_allclose(res.z, 1.0)


@pytest.mark.parametrize("bad", [np.eye(3, dtype=complex), sp.csr_matrix(np.eye(3, dtype=complex)),
                                 np.array([["a"] * 3] * 3), np.array([[1, 0], [0, 1]], dtype=object)])
def test_complex_or_nonnumeric_A_is_a_type_error(bad):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(TypeError, match="A"):
            nrmicp.solve(bad, -np.ones(bad.shape[0]))


@pytest.mark.parametrize("arg", ["q", "x0", "zeta"])
def test_complex_vectors_are_type_errors(arg):
    A = sp.identity(3, format="csr") * 2.0
    kw = dict(q=-np.ones(3), x0=None, zeta=None)
    kw[arg] = np.ones(3, dtype=complex)
    with pytest.raises(TypeError, match=arg):
        nrmicp.solve(A, kw["q"], kw["zeta"], x0=kw["x0"])


# ---- NaN / Inf, shapes ----------------------------------------------------------------------


@SETTINGS
@given(n=st.integers(1, 8), where=st.sampled_from(["A", "q", "x0", "zeta", "zeta.B", "zeta.c", "omega1", "phi"]),
       bad=st.sampled_from([np.nan, np.inf, -np.inf]), seed=st.integers(0, 1000), i=st.integers(0, 100))
def test_nonfinite_input_names_the_argument(n, where, bad, seed, i):
    if where == "zeta" and bad == -np.inf:
        return   # a valid lower bound: z free below there, for every method (tests/test_bounds_family.py)
    rng = np.random.default_rng(seed)
    A = bai_like(n, rng)
    q = rng.uniform(-1, 1, n)
    x0 = np.zeros(n)
    B = sp.csr_matrix(0.1 * sp.identity(n))
    c = np.zeros(n)
    om = np.ones(n)
    phi = np.zeros(n)
    k = i % n
    target = {"A": A.data, "q": q, "x0": x0, "zeta": c, "zeta.B": B.data, "zeta.c": c, "omega1": om,
              "phi": phi}[where]
    target[k % len(target)] = bad
    zeta = nrmicp.Affine(B, c) if where in ("zeta.B", "zeta.c") else (c if where == "zeta" else None)
    before = snapshot(A, q, x0, B, c)
    with pytest.raises(ValueError, match=where.replace(".", r"\.")):
        nrmicp.solve(A, q, zeta, x0=x0, omega1=om if where == "omega1" else None,
                     phi=phi if where == "phi" else None, method="nrmgs")
    assert_unchanged(before, [A, q, x0, B, c])


@SETTINGS
@given(rows=st.integers(1, 6), cols=st.integers(1, 6))
def test_non_square_A(rows, cols):
    if rows == cols:
        return
    with pytest.raises(ValueError, match="square"):
        nrmicp.solve(sp.csr_matrix(np.ones((rows, cols))), np.zeros(rows))


@SETTINGS
@given(n=st.integers(1, 6), m=st.integers(0, 8), arg=st.sampled_from(["q", "x0", "phi", "omega1", "omega2", "zeta"]))
def test_wrong_length_vectors(n, m, arg):
    if m == n:
        return
    A = sp.csr_matrix(2.0 * sp.identity(n))
    kw = {}
    q = -np.ones(n)
    zeta = None
    if arg == "q":
        q = np.ones(m)
    elif arg == "zeta":
        zeta = np.ones(m)
    else:
        kw[arg] = np.ones(m)
    with pytest.raises(ValueError, match=arg):
        nrmicp.solve(A, q, zeta, **kw)


def test_a_one_dimensional_sparse_array_is_not_a_matrix():
    with pytest.raises(ValueError, match="A must be 2-D"):
        nrmicp.solve(sp.coo_array(np.ones(5)), np.ones(5))


def test_empty_A():
    with pytest.raises(ValueError, match="A"):
        nrmicp.solve(sp.csr_matrix((0, 0)), np.zeros(0))


# ---- parameters -----------------------------------------------------------------------------


@pytest.mark.parametrize("name,value", [("omega1", 0.0), ("omega1", -1.0), ("omega2", 0.0), ("omega2", -2.0),
                                        ("gamma", 0.0), ("gamma", -1.0), ("phi", -1.0), ("alpha", 0.0),
                                        ("alpha", -1.0), ("beta", -0.5), ("tol", 0.0), ("tol", -1.0),
                                        ("tol", np.nan), ("maxiter", -1), ("anderson_m", 0), ("theta", 0.0),
                                        ("theta", 2.5), ("stall_iterations", 0)])
def test_nonpositive_parameters_name_themselves(name, value):
    A = sp.csr_matrix(2.0 * sp.identity(3))
    method = "nrmaor" if name in ("alpha", "beta") else ("two_sweep" if name == "theta" else "nrmgs")
    with pytest.raises(ValueError, match=name):
        nrmicp.solve(A, -np.ones(3), method=method, **{name: value})


@pytest.mark.parametrize("name,value", [("gamma", True), ("gamma", "1"), ("omega1", 1j), ("maxiter", 1.5),
                                        ("method", None), ("scale", "cols"), ("scale", 2)])
def test_wrong_type_parameters(name, value):
    A = sp.csr_matrix(2.0 * sp.identity(3))
    with pytest.raises((TypeError, ValueError), match=name):
        nrmicp.solve(A, -np.ones(3), **{name: value})


@pytest.mark.parametrize("method", ["nrmaor", "nrmsor", "nrmgs", "nrmj", "mms", "two_sweep"])
@pytest.mark.parametrize("d", [0.0, -1.0])
def test_nonpositive_diagonal_for_aor_methods(method, d):
    A = sp.csr_matrix(np.array([[d, 1.0], [1.0, 2.0]]))
    with pytest.raises(ValueError, match="omega2|diagonal"):
        nrmicp.solve(A, -np.ones(2), method=method)


@pytest.mark.parametrize("method", ["nrm", "nrmm"])
def test_nonpositive_diagonal_for_nrm_is_an_error_or_an_honest_status(method):
    A = sp.csr_matrix(np.array([[-1.0, 0.0], [0.0, -1.0]]))
    try:
        res = nrmicp.solve(A, -np.ones(2), method=method, maxiter=200)
    except (ValueError, np.linalg.LinAlgError) as exc:
        assert any(s in str(exc) for s in ("omega2", "alpha", "singular", "left matrix"))
    else:  # LCP(-1, -I) has no solution
        assert not res.success and np.all(np.isfinite(res.z))


# ---- ζ misbehaving ---------------------------------------------------------------------------


def _problem(n=4):
    A = sp.csr_matrix(4.0 * sp.identity(n) - sp.eye(n, k=1) - sp.eye(n, k=-1))
    return A, -np.ones(n)


@pytest.mark.parametrize("scale", [False, "both"])
@pytest.mark.parametrize("ret,exc,match", [
    (lambda z: np.zeros(3), ValueError, r"shape \(4,\)"),
    (lambda z: np.zeros((4, 2)), ValueError, r"shape \(4,\)"),   # a column (4, 1) is a vector: accepted
    (lambda z: None, (TypeError, ValueError), "zeta"),
    (lambda z: z.astype(complex), TypeError, "dtype"),
    (lambda z: z > 0, TypeError, "dtype"),
    (lambda z: "abcd", TypeError, "zeta"),
    (lambda z: z * np.nan, ValueError, "non-finite"),
    (lambda z: np.full(4, np.inf), ValueError, "non-finite"),
])
def test_zeta_bad_return(ret, exc, match, scale):
    A, q = _problem()
    with pytest.raises(exc, match=match):
        nrmicp.solve(A, q, ret, scale=scale)


@pytest.mark.parametrize("scale", [False, "both"])
@pytest.mark.parametrize("exc_type", [KeyError, RuntimeError, ZeroDivisionError, ValueError, StopIteration])
def test_zeta_exception_reaches_the_caller_unchanged(exc_type, scale):
    A, q = _problem()
    err = exc_type("from zeta")
    calls = []

    def zeta(z):
        calls.append(1)
        if len(calls) > 3:
            raise err
        return 0.1 * np.sin(z)

    with pytest.raises(exc_type) as info:
        nrmicp.solve(A, q, zeta, scale=scale, tol=1e-300, maxiter=50)
    assert info.value is err


def test_zeta_receives_read_only_array():
    A, q = _problem()

    def zeta(z):
        with pytest.raises(ValueError):
            z[0] = 1.0
        return np.zeros_like(z)

    assert nrmicp.solve(A, q, zeta).success


# ---- callbacks -------------------------------------------------------------------------------


@pytest.mark.parametrize("scale", [False, "both"])
def test_callback_stop_iteration(scale):
    A, q = _problem(20)
    seen = []

    def cb(intermediate_result):
        seen.append(intermediate_result.nit)
        if intermediate_result.nit >= 2:
            raise StopIteration

    res = nrmicp.solve(A, q, callback=cb, scale=scale, tol=1e-300)
    assert res.status == nrmicp.Status.CALLBACK_STOP and not res.success
    assert seen == [0, 1, 2]
    assert np.all(np.isfinite(res.z))


@pytest.mark.parametrize("scale", [False, "both"])
def test_callback_exception_reaches_the_caller(scale):
    A, q = _problem(20)
    err = RuntimeError("from callback")

    def cb(r):
        raise err

    with pytest.raises(RuntimeError) as info:
        nrmicp.solve(A, q, callback=cb, scale=scale, tol=1e-300)
    assert info.value is err


def test_callback_not_callable():
    A, q = _problem()
    with pytest.raises(TypeError, match="callback"):
        nrmicp.solve(A, q, callback=3)


# ---- the caller's arrays are unchanged (every ζ kind, scaling, Solver reuse) ----------------


@SETTINGS
@given(n=st.integers(1, 10), seed=st.integers(0, 10_000),
       kind=st.sampled_from(["none", "constant", "affine", "callable"]),
       scale=st.sampled_from([False, True, "rows", "both"]),
       method=st.sampled_from(["nrmgs", "nrm", "two_sweep"]),
       index_dtype=st.sampled_from([np.int32, np.int64]))
def test_inputs_not_mutated(n, seed, kind, scale, method, index_dtype):
    rng = np.random.default_rng(seed)
    A = bai_like(n, rng)
    A = sp.csr_matrix(sp.diags(10.0 ** rng.uniform(-3, 3, n)) @ A @ sp.diags(10.0 ** rng.uniform(-3, 3, n)))
    A = sp.csr_matrix((A.data, A.indices.astype(index_dtype), A.indptr.astype(index_dtype)), shape=A.shape)
    q = rng.uniform(-1, 1, n)
    x0 = rng.uniform(0, 1, n)
    B = sp.csr_matrix(0.05 * sp.random(n, n, density=0.5, random_state=seed))
    c = rng.uniform(-1, 1, n)
    zeta = {"none": None, "constant": c, "affine": nrmicp.Affine(B, c),
            "callable": (lambda z: 0.05 * np.sin(z) + c)}[kind]
    before = snapshot(A, q, x0, B, c)
    s = nrmicp.Solver(A, method=method, scale=scale)
    res = s.solve(q, zeta, x0=x0, maxiter=2000)
    res2 = s.solve(q, zeta, x0=x0, maxiter=2000)
    assert_unchanged(before, [A, q, x0, B, c])
    np.testing.assert_array_equal(res.z, res2.z)
    assert np.all(np.isfinite(res.z))
    assert res.residual == pytest.approx(reference_residual(A, q, res.z, zeta), rel=1e-6, abs=1e-14)
    if res.success and res.criterion["measure"] == "paper":
        assert reference_residual(A, q, res.z, zeta) < 1e-8
    elif res.success:   # the default rule, judged on the equilibration the solve iterated on
        assert res.criterion["value"] < res.criterion["target"]
    # z returned is not a view of the caller's data
    assert not np.shares_memory(res.z, x0) and not np.shares_memory(res.z, q)


def test_scaled_affine_and_callable_agree():
    rng = np.random.default_rng(0)
    n = 30
    A = bai_like(n, rng)
    dr, dc = 10.0 ** rng.uniform(-4, 4, n), 10.0 ** rng.uniform(-4, 4, n)
    A = sp.csr_matrix(sp.diags(dr) @ A @ sp.diags(dc))
    B = sp.csr_matrix(sp.diags(dc ** -1) @ (0.1 * sp.eye(n, k=1)) @ sp.diags(dc))
    c = rng.uniform(-1, 1, n) / dc
    q = rng.uniform(-1, 1, n) * dr
    r1 = nrmicp.solve(A, q, nrmicp.Affine(B, c), scale=True)
    r2 = nrmicp.solve(A, q, lambda z: B @ z + c, scale=True)
    assert r1.success and r2.success
    np.testing.assert_allclose(r1.z, r2.z, rtol=1e-6, atol=1e-12)


# ---- one shape rule for vectors: (n,) and the column (n, 1) alike, in and out ---------------

def _column_paths(n, rng):
    """Every vector input and output of a solve: name -> (solve keywords with a flat vector, the same
    with that vector a column (n, 1), and with it of shape (n, 2))."""
    c = rng.uniform(-0.5, 0.5, n)
    B = sp.csr_matrix(sp.diags(np.full(n, 0.1)))
    out = {}
    for name in ("q", "x0", "zeta", "omega1", "omega2", "phi"):
        v = {"q": rng.uniform(-2, 2, n), "x0": rng.uniform(0, 1, n), "zeta": c, "omega1": np.full(n, 1.5),
             "omega2": np.full(n, 0.8), "phi": np.full(n, 0.2)}[name]
        out[name] = tuple({name: w} for w in (v, v[:, None], np.column_stack([v, v])))
    out["zeta.c"] = tuple({"zeta": nrmicp.Affine(B, w)} for w in (c, c[:, None], np.column_stack([c, c])))
    for method in ("nrmgs", "newton"):
        out[f"zeta(z) ({method})"] = tuple(
            {"zeta": fn, "method": method} for fn in (lambda z: 0.1 * np.tanh(z) + c,
                                                      lambda z: (0.1 * np.tanh(z) + c)[:, None],
                                                      lambda z: np.column_stack([z, z])))
    return out


@pytest.mark.parametrize("path", ["q", "x0", "zeta", "omega1", "omega2", "phi", "zeta.c", "zeta(z) (nrmgs)",
                                  "zeta(z) (newton)"])
def test_a_column_vector_is_accepted_wherever_a_vector_is(path):
    """MATLAB-style code passes columns: q of shape (n, 1) was accepted while ζ returning (n, 1)
    raised (issue 38). Each path: the column gives the flat vector's answer, (n, 2) is refused by name."""
    n, rng = 12, np.random.default_rng(5)
    A = bai_like(n, rng)
    flat, column, wide = _column_paths(n, rng)[path]
    base = {"q": rng.uniform(-2, 2, n), "zeta": None}
    ref = nrmicp.solve(A, **dict(base, **flat))
    res = nrmicp.solve(A, **dict(base, **column))
    assert ref.success and res.success and res.status == ref.status
    np.testing.assert_array_equal(res.z, ref.z)
    zeta = dict(base, **flat)["zeta"]
    zeta_fn = (lambda z: zeta.B @ z + zeta.c) if isinstance(zeta, nrmicp.Affine) else zeta
    assert reference_residual(A, dict(base, **flat)["q"], res.z, zeta_fn) < 1e-8
    name = path.split(" ")[0].replace("(", r"\(").replace(")", r"\)")
    with pytest.raises(ValueError, match=f"{name}.*shape \\(12, 2\\)"):
        nrmicp.solve(A, **dict(base, **wide))


def test_residual_takes_a_zeta_returning_a_column():
    A, rng = bai_like(8, np.random.default_rng(2)), np.random.default_rng(3)
    q, z, c = rng.uniform(-1, 1, 8), rng.uniform(0, 1, 8), rng.uniform(-1, 1, 8)
    assert nrmicp.residual(A, q, z, lambda v: c[:, None]) == nrmicp.residual(A, q, z, c) \
        == pytest.approx(reference_residual(A, q, z, c), rel=1e-14)


# ---- a Jacobian in any scipy sparse format, converted without a warning per step -----------

@pytest.mark.parametrize("fmt", ["dia", "coo", "csc", "lil", "bsr", "dok", "dense"])
def test_a_zeta_jacobian_in_any_format_gives_the_csr_answer_without_warnings(fmt):
    """sp.diags builds DIA: every Newton step warned 'converting DIA to CSR' (9 warnings in one
    solve, issue 38); the conversion is nrmicp's business."""
    problem = scenes.obstacle_2d(15, exact=False)
    psi = problem.zeta

    def jacobian(form):
        def J(z):
            D = sp.diags(0.1 / np.cosh(z) ** 2, format="csr")
            return D.toarray() if form == "dense" else D.asformat(form)
        return J
    zeta = lambda z: psi + 0.1 * np.tanh(z)   # noqa: E731
    ref = nrmicp.solve(problem.A, problem.q, zeta, method="newton", hierarchy=None, zeta_jacobian=jacobian("csr"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = nrmicp.solve(problem.A, problem.q, zeta, method="newton", hierarchy=None, zeta_jacobian=jacobian(fmt))
    assert ref.success and res.success and res.nit == ref.nit >= 2
    np.testing.assert_array_equal(res.z, ref.z)
    assert reference_residual(problem.A, problem.q, res.z, zeta) < 1e-8
