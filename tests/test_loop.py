"""The iteration loop of the C++ core: per-solve options, the stopping rules, Res at extreme
scales, progress output. Each test names the behaviour it checks; oracles are independent
(the numpy reference implementation, numpy residuals, known solutions)."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import nrmicp
from nrmicp import scenes
from problems import make_problem, readme_membrane
from reference_impl import reference_solve


# ---- theta: the two-sweep relaxation, and only that ---------------------------------------

def test_per_solve_theta_is_used():
    """Solver(two_sweep).solve(theta=0.5) iterates with theta = 0.5 (it used the set-up theta)."""
    P = make_problem("lcp", 10, True)
    d = P.A.diagonal()
    ref = reference_solve(P.A, P.q, method="two_sweep", z_update="explicit", gamma=1.0, omega2=d,
                          alpha=1.0, beta=1.0, theta=0.5, tol=1e-8)
    ref_one = reference_solve(P.A, P.q, method="two_sweep", z_update="explicit", gamma=1.0, omega2=d,
                              alpha=1.0, beta=1.0, theta=1.0, tol=1e-8)
    assert ref.nit != ref_one.nit  # theta matters here
    s = nrmicp.Solver(P.A, method="two_sweep", z_update="explicit", tol=1e-8)   # the reference's rule
    res = s.solve(P.q, theta=0.5)
    assert res.success
    assert res.nit == ref.nit


@pytest.mark.parametrize("method", ["nrmgs", "nrm", "nrmaor", "mms"])
def test_theta_rejected_for_other_methods(method):
    P = make_problem("lcp", 4, True)
    with pytest.raises(ValueError, match="theta"):
        nrmicp.solve(P.A, P.q, method=method, theta=0.5)
    with pytest.raises(ValueError, match="theta"):
        nrmicp.Solver(P.A, method=method).solve(P.q, theta=0.5)


# ---- honest stopping: hopeless solves stop early, slow-but-steady ones go on ---------------

def _numpy_res(A, q, z, zeta=None):
    w = A @ z + q
    g = z if zeta is None else (z - (zeta(z) if callable(zeta) else zeta))
    return float(np.linalg.norm(np.minimum(w, g)))


def test_hopeless_solve_stagnates_long_before_maxiter():
    """The paper's nrm on obstacle_2d(64): best Res at iteration 2, then 4x higher and falling too
    slowly to return within maxiter = 10,000. It used to burn all 10,000 iterations."""
    P = scenes.obstacle_2d(64)
    res = nrmicp.solve(P.A, P.q, P.zeta, method="nrm")
    assert res.status == nrmicp.Status.STAGNATED, res.message
    assert res.iterations <= 20 * 100  # a couple of thousand at most, with stall_iterations = 100
    assert np.all(np.isfinite(res.z))
    assert res.residual == pytest.approx(_numpy_res(P.A, P.q, res.z, P.zeta), rel=1e-9)


def test_slow_return_within_budget_is_not_cut():
    """nrm on obstacle_2d(32) needs 965 iterations to get back below its first Res, then keeps
    improving (converging after ~89,000): at maxiter = 3000 it must run to maxiter."""
    P = scenes.obstacle_2d(32)
    res = nrmicp.solve(P.A, P.q, P.zeta, method="nrm", tol=1e-8, maxiter=3000, record_history=True)
    assert res.status == nrmicp.Status.MAX_ITERATIONS, res.message
    r = res.history["residual"]
    assert np.argmin(r) == len(r) - 1 == 3000  # still improving at the end
    # (the start z = 0 has a lower Res than every iterate so far, and is what is returned)
    assert res.residual == pytest.approx(_numpy_res(P.A, P.q, np.zeros(P.n), P.zeta))
    assert res.residual < r.min()


def test_res_jumping_up_then_falling_steadily_is_not_cut():
    """nrmm on the American put: Res jumps from 2 to 759, and takes 127 iterations to fall back."""
    P = scenes.american_put()
    res = nrmicp.solve(P.A, P.q, P.zeta, method="nrmm")
    assert res.success, res.message


def test_plateaus_of_constant_res_are_not_cut():
    """Impulse control: Res stays bit-identical for over a thousand iterations at a time while x
    moves; the default stopping rules must let it converge."""
    P = scenes.impulse_control(101)
    res = P.solve(method="nrmgs", tol=1e-8, maxiter=20_000)
    assert res.success, res.message
    assert _numpy_res(P.A, P.q, res.z, P.zeta) < 1e-8


# ---- divergence of the modulus vector, and ζ's reputation ---------------------------------

def test_runaway_modulus_vector_is_diverged_not_zeta_failure():
    """Issue 9 item 6: Res stays exactly constant while x triples every step; this used to end
    in 'zeta(z) returned non-finite values ... at iteration 649'."""
    calls = []

    def zeta(z):
        calls.append(np.isfinite(z).all())
        return z + 0.5

    A = sp.csr_matrix([[-1.0]])
    res = nrmicp.solve(A, [1.0], zeta, method="nrmj", omega2=2.0, z_update="solve")
    assert res.status == nrmicp.Status.DIVERGED, res.message
    assert "x grew" in res.message
    assert res.iterations < 100
    assert np.all(np.isfinite(res.z)) and np.isfinite(res.residual)
    assert res.residual == pytest.approx(_numpy_res(A, np.array([1.0]), res.z, zeta), rel=1e-12)
    assert all(calls)


def test_overflowing_affine_zeta_in_scaled_variables_is_diverged_not_zeta_failure():
    """Found by the fuzz test: with scale='both' an Affine ζ becomes D_c⁻¹ B D_c y + D_c⁻¹ c, whose
    entries reach 1e150 when A has an entry 2e300; the runaway iterate (q ~ 1e300, no solution: row 1
    of A is empty and q[1] < 0) overflowed it, and the solve raised 'zeta(z) returned non-finite
    values'. ζ = Bz + c with finite B, c is the library's own evaluation: this is divergence."""
    Ad = np.zeros((3, 3))
    Ad[0, 0] = 2e300
    A = sp.csr_matrix(Ad)
    q = np.array([8.66177327e299, -7.90350451e299, 3.32873280e299])
    B = sp.csr_matrix(0.1 * np.array([[0, 1, 0], [1, 0, 1], [0, 0, 1.0]]))
    zeta = nrmicp.Affine(B, np.array([0.6, 0.4, 1.0]))
    res = nrmicp.solve(A, q, zeta, method="nrm", maxiter=50, tol=1e292, z_update="explicit", scale="both")
    assert not res.success
    assert res.status in (nrmicp.Status.DIVERGED, nrmicp.Status.STAGNATED, nrmicp.Status.MAX_ITERATIONS), res.message
    assert np.all(np.isfinite(res.z))
    assert res.residual == pytest.approx(_stable_norm(np.minimum(A @ res.z + q, res.z - (B @ res.z + zeta.c))),
                                         rel=1e-12)


# ---- Res without overflow or underflow ----------------------------------------------------

def _stable_norm(m):
    big = np.abs(m).max()
    return float(big * np.linalg.norm(m / big)) if big > 0 else 0.0


@pytest.mark.parametrize("scale", [2.0 ** 600, 2.0 ** -530, 2.0 ** -660])
def test_res_neither_overflows_nor_underflows(scale):
    """Issue 9 item 7: Res = sqrt(sum m^2) overflowed beyond |m| ~ 1e154 (DIVERGED at iteration 0,
    Res NaN) and underflowed below ~1e-154 (a false CONVERGED). Scaling A and q by a power of two
    leaves the iterates exactly the same; Res becomes ||min(scale w, z)||."""
    A = scenes.bai(4).A
    q = -np.ones(A.shape[0])
    fixed = dict(tol=1e-300, maxiter=12, stall_iterations=1000)
    ref = nrmicp.solve(A, q, **fixed)
    res = nrmicp.solve(scale * A, scale * q, **fixed)
    np.testing.assert_array_equal(res.z, ref.z)
    m = np.minimum(scale * (A @ res.z + q), res.z)
    assert res.residual == pytest.approx(_stable_norm(m), rel=1e-12)
    assert nrmicp.residual(scale * A, scale * q, res.z) == pytest.approx(_stable_norm(m), rel=1e-12)
    conv = nrmicp.solve(scale * A, scale * q, tol=1e-8 * scale)
    assert conv.success, conv.message
    assert np.all(np.isfinite(conv.z))
    assert _stable_norm(np.minimum(scale * (A @ conv.z + q), conv.z)) < 1e-8 * scale


@pytest.mark.parametrize("name, kwargs", [("omega2", dict(omega2=1e-310)), ("gamma", dict(gamma=1e-310)),
                                          ("alpha", dict(method="nrmm", alpha=1e-310)),
                                          ("omega1", dict(omega1=4e-320))])
def test_subnormal_parameters_are_rejected_by_name(name, kwargs):
    A = scenes.bai(4).A
    with pytest.raises(ValueError, match=name):
        nrmicp.solve(A, -np.ones(A.shape[0]), **kwargs)


def test_subnormal_matrix_diagonal_is_rejected_naming_A_under_the_papers_tol():
    """1e-320 * A: the default Omega2 = diag(A) is subnormal (it returned [inf inf ...], Res NaN)."""
    A = scenes.bai(4).A
    with pytest.raises(ValueError, match=r"A\[0,0\]"):
        nrmicp.solve(1e-320 * A, -np.ones(A.shape[0]), tol=1e-8)


def test_a_tiny_matrix_is_a_matrix_in_other_units_under_the_default_rule():
    """1e-300 * A (entries near the bottom of the normal range): the default rule iterates on
    sigma A, sigma q with sigma a power of two, so it solves it as it solves A."""
    A = 1e-300 * scenes.bai(4).A
    q = -1e-300 * np.ones(A.shape[0])
    res = nrmicp.solve(A, q)
    exact = spla.spsolve(sp.csc_matrix(1e300 * A), -1e300 * q)   # an M-matrix and q < 0: z > 0 everywhere
    assert res.success and res.criterion["measure"] == "units"
    assert np.abs(res.z - exact).max() <= 1e-8 * np.abs(exact).max()


# ---- one fact in one place: names, statuses and the 'auto' rule come from the core ---------

def test_python_lists_are_the_cores():
    from nrmicp import _core
    assert nrmicp.METHODS == tuple(_core.Method.__members__)
    assert [s.name for s in nrmicp.Status] == list(_core.Status.__members__)
    assert [int(s) for s in nrmicp.Status] == [int(v) for v in _core.Status.__members__.values()]
    assert _core.status_message(int(nrmicp.Status.CONVERGED)).startswith("converged")
    with pytest.raises(ValueError, match="status"):
        _core.status_message(99)


# newton has no z-update to choose: it recovers z from its linear solves (it rejects z_update).
@pytest.mark.parametrize("method", [m for m in nrmicp.METHODS if m != "newton"])
@pytest.mark.parametrize("kind", ["lcp", "icp"])
def test_resolved_z_update_is_what_auto_does(method, kind):
    """The core answers 'what does auto mean here' (bench/family.py asks it): the same iterates."""
    from nrmicp import _core
    P = make_problem(kind, 6, True)
    used = _core.resolved_z_update(getattr(_core.Method, method), False, P.zeta is not None)
    auto = nrmicp.solve(P.A, P.q, P.zeta, method=method, maxiter=5, tol=1e-300)
    explicit = nrmicp.solve(P.A, P.q, P.zeta, method=method, maxiter=5, tol=1e-300, z_update=used)
    np.testing.assert_array_equal(auto.z, explicit.z)
    other = "solve" if used == "explicit" else "explicit"
    different = nrmicp.solve(P.A, P.q, P.zeta, method=method, maxiter=5, tol=1e-300, z_update=other)
    if kind == "icp":  # for an LCP the z-updates agree on the solution only
        assert not np.array_equal(auto.z, different.z)


# ---- progress: verbose= --------------------------------------------------------------------

def test_silent_by_default(capsys, caplog):
    P = make_problem("lcp", 8, True)
    with caplog.at_level("DEBUG", logger="nrmicp"):
        nrmicp.solve(P.A, P.q)
    assert capsys.readouterr().err == ""
    assert not [r for r in caplog.records if r.name == "nrmicp"]


def test_verbose_logs_first_iterate_and_final_status(caplog):
    P = make_problem("lcp", 8, True)
    with caplog.at_level("INFO", logger="nrmicp"):
        res = nrmicp.Solver(P.A).solve(P.q, verbose=1)
    lines = [r.getMessage() for r in caplog.records if r.name == "nrmicp"]
    assert res.success
    assert "iteration       0" in lines[0] and "Res" in lines[0]
    assert "converged" in lines[-1] and f"(nit = {res.nit}, " in lines[-1]


def _final_line(caplog, **kw):
    """(result, last 'nrmicp' log line) of nrmicp.solve(**kw, verbose=1) on the README's membrane
    at m = 31 (its figures scale, the paths are the same)."""
    m = 31
    A, q, psi = readme_membrane(m)
    zeta = {"psi": psi, "tanh": lambda z: psi + 0.1 * np.tanh(z),
            "affine": nrmicp.Affine(0.1 * sp.identity(m * m, format="csr"), psi)}[kw.pop("zeta")]
    jac = {"zeta_jacobian": lambda z: sp.diags(0.1 / np.cosh(z) ** 2)} if kw.pop("jacobian", False) else {}
    with caplog.at_level("INFO", logger="nrmicp"):
        res = nrmicp.solve(A, q, zeta, verbose=1, **jac, **kw)
    lines = [r.getMessage() for r in caplog.records if r.name == "nrmicp"]
    return res, lines[-1]


@pytest.mark.parametrize("kw", [
    dict(zeta="tanh", method="newton", hierarchy="amg"),          # the README's callable: outer fixed point
    dict(zeta="tanh", method="newton", hierarchy=None, jacobian=True),   # semismooth: said 7 where nit was 18
    dict(zeta="affine", method="newton", hierarchy=None),         # its start's steps count in nit
    dict(zeta="psi", method="nrmgs", maxiter=50, polish=True),    # polished: said max iterations
    dict(zeta="psi", method="nrmgs", maxiter=50, scale=True),
], ids=["callable", "jacobian", "affine", "polish", "scaled"])
def test_verbose_final_line_counts_nit_and_says_the_results_message(kw, caplog):
    """The final verbose line counted the last loop's iterations where nit counts every Newton step
    of the finest level (9 against 13 in issue 38), and told the core's status before polishing."""
    res, last = _final_line(caplog, **kw)
    count = f"nit = {res.nit}" + ("" if res.iterations == res.nit else f" of {res.iterations} iterations")
    assert f"({count}, " in last
    assert last.startswith(f"nrmicp {res.method}: {res.message} (")


def test_verbose_reports_by_time_not_per_iteration(caplog):
    """verbose = k reports every k seconds: with k = 10**6 a 2000-iteration solve reports its
    first iterate and its end, nothing per iteration (no clock decides it)."""
    P = scenes.obstacle_2d(32)
    with caplog.at_level("INFO", logger="nrmicp"):
        res = nrmicp.solve(P.A, P.q, P.zeta, method="nrmgs", maxiter=2000, tol=1e-300, stall_iterations=10**6,
                           verbose=10**6)
    lines = [r.getMessage() for r in caplog.records if r.name == "nrmicp"]
    assert res.iterations == 2000
    assert len(lines) == 2, lines
    assert "iteration       0" in lines[0]
    assert f"(nit = {res.nit}{'' if res.nit == 2000 else ' of 2000 iterations'}, " in lines[1]


def test_verbose_prints_to_stderr_when_logging_is_not_configured(capsys):
    from nrmicp import _api
    P = make_problem("lcp", 8, True)
    saved = _api.logger.propagate
    _api.logger.propagate = False  # as if no handler were configured anywhere
    try:
        nrmicp.solve(P.A, P.q, verbose=1)
    finally:
        _api.logger.propagate = saved
    err = capsys.readouterr().err
    assert "nrmicp nrmgs: iteration       0" in err and "converged" in err


def test_verbose_must_be_a_nonnegative_whole_number():
    P = make_problem("lcp", 4, True)
    with pytest.raises(ValueError, match="verbose"):
        nrmicp.solve(P.A, P.q, verbose=-1)
    with pytest.raises(TypeError, match="verbose"):
        nrmicp.solve(P.A, P.q, verbose=0.5)
