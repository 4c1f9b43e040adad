"""The API's contract at its edges (found by a review that tried to break it): a re-entrant solve,
data whose Az + q overflows, a fallback that cannot be set up, nrmicp.residual's inputs, option
values that are not numbers, the command line's numeric options. Each test fails on the code
before its fix (a hang, a LinAlgError, a CONVERGED with w = inf, NaN in z, a wrong Res, a
traceback)."""
from __future__ import annotations

import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp


def tridiag(n, d=2.0):
    return sp.diags([-1.0, d, -1.0], [-1, 0, 1], shape=(n, n), format="csr")


def check_certificate(A, q, res, psi=0.0):
    """What a returned iterate must be: finite, its Res the numpy one, success only when it is one."""
    assert np.all(np.isfinite(res.z))
    w = A @ res.z + q
    with np.errstate(over="ignore", invalid="ignore"):
        honest = np.linalg.norm(np.minimum(w, res.z - psi)) if np.all(np.isfinite(w)) else np.inf
    assert res.residual == pytest.approx(honest, rel=1e-6, abs=1e-300)
    assert res.success == (np.isfinite(honest) and honest < 1e-8)


def run(code, timeout=60):
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.parametrize("where", ["callback", "zeta"])
def test_a_newton_solve_from_inside_its_own_solve_is_an_error_not_a_hang(where):
    # the Newton solve holds its levels while it runs: re-entering waited for itself forever
    code = f"""
        import numpy as np, scipy.sparse as sp, nrmicp
        A = sp.diags([-1., 2., -1.], [-1, 0, 1], shape=(50, 50), format="csr"); q = -0.01 * np.ones(50)
        S = nrmicp.Solver(A, method="newton")
        inner = lambda *a: S.solve(2 * q)
        try:
            if "{where}" == "callback":
                S.solve(q, callback=inner)
            else:
                S.solve(q, zeta=lambda z: (inner(), 0 * z)[1])
        except RuntimeError as e:
            assert "re-entrant" in str(e), e
            r = S.solve(q)          # the solver is usable afterwards
            print("ok", r.status.name)
    """
    out = run(code, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "ok CONVERGED" in out.stdout


def test_a_stationary_solve_may_still_be_reentered():
    A, q = tridiag(30), -0.01 * np.ones(30)
    S = nrmicp.Solver(A, method="nrmgs")
    inner = []
    outer = S.solve(q, callback=lambda zk: inner.append(S.solve(2 * q).status) if not inner else None)
    assert outer.success and inner == [nrmicp.Status.CONVERGED]


def test_newton_on_a_row_minus_one_zero_zero_returns_a_status_not_a_linalg_error():
    # a_00 = -1 = -max|a_0j|: the fallback's Omega2 + A had a zero row (LinAlgError from solve)
    A = sp.csr_matrix([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 1.0, 1.0]])
    q = np.array([2.1082884113927522, -0.3488754600926644, -1.1371197204183754])
    for kw in ({}, {"polish": True}, {"hierarchy": None}):
        res = nrmicp.solve(A, q, method="newton", **kw)
        check_certificate(A, q, res)
    z = np.array([q[0], 0.0, q[0] - q[2]])          # a solution: the start x0 = z is accepted at once
    assert nrmicp.solve(A, q, method="newton", x0=z).success


@pytest.mark.parametrize("method", ["nrmgs", "nrm", "newton"])
@pytest.mark.parametrize("kind", ["constant", "callable"])
def test_an_overflowing_w_is_never_a_success(method, kind):
    # zeta = 1e308: w = Az + q overflows; min(w, z - zeta) cannot see w = +inf (newton said CONVERGED)
    n = 5
    A, q = tridiag(n, 4.0), np.ones(n)
    zeta = np.full(n, 1e308) if kind == "constant" else (lambda z: np.full(n, 1e308))
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = nrmicp.solve(A, q, zeta, method=method)
    assert not res.success and res.status == nrmicp.Status.DIVERGED
    assert res.residual == np.inf
    assert not np.isnan(res.z).any()


@pytest.mark.parametrize("scale", [False, "rows", "both"])
@pytest.mark.parametrize("zeta", [None, 0.0, 0.01])
def test_a_solution_beyond_float_range_leaves_a_finite_best_iterate(scale, zeta):
    # a lone subnormal diagonal: z_2 = -q_2 / a_22 is not representable; scale='both' returned NaN in z
    n = 6
    A = tridiag(n).tolil()
    A.rows[2] = [2]
    A.data[2] = [5e-324]
    A = A.tocsr()
    q = np.array([-1.0, 1, -1, 1, -1, -1])
    with np.errstate(all="ignore"):
        res = nrmicp.solve(A, q, zeta, method="newton", scale=scale)
    assert not res.success
    assert np.all(np.isfinite(res.z)) and not np.isnan(res.residual)


def test_residual_checks_its_arguments_as_solve_does():
    A, q = tridiag(5, 4.0), np.array([-1.0, 2, -3, 4, -5])
    z = nrmicp.solve(A, q).z
    assert nrmicp.residual(A, q.reshape(-1, 1), z) == nrmicp.residual(A, q, z) < 1e-8   # was 13.1
    with pytest.raises(ValueError, match="zeta"):
        nrmicp.residual(A, q, z, np.nan)
    with pytest.raises(ValueError, match="z must have length"):
        nrmicp.residual(A, q, z[:-1])
    with pytest.raises(ValueError, match="q must have length"):
        nrmicp.residual(A, q[:-1], z)
    assert nrmicp.residual(A, q, z, nrmicp.Affine(sp.csr_matrix((5, 5)), np.zeros(5))) == nrmicp.residual(A, q, z)
    assert nrmicp.residual(A, q, z, lambda v: np.full(5, 1e308)) == np.inf    # Az + q overflows: no Res


@pytest.mark.parametrize("name,value,error", [
    ("maxiter", float("nan"), ValueError), ("maxiter", float("inf"), ValueError),
    ("stall_iterations", float("inf"), ValueError), ("verbose", float("nan"), ValueError),
    ("anderson_m", float("-inf"), ValueError), ("record_history", "yes", TypeError),
    ("omega1", 10**400, ValueError),
])
def test_option_values_that_are_no_numbers_name_the_option(name, value, error):
    A, q = tridiag(5, 4.0), -np.ones(5)
    extra = {"accelerate": "anderson"} if name == "anderson_m" else {}
    with pytest.raises(error, match=name):
        nrmicp.solve(A, q, **{name: value}, **extra)


def test_a_huge_python_int_diagonal_option_is_taken_as_its_float():
    A, q = tridiag(5, 4.0), -np.ones(5)
    res = nrmicp.solve(A, q, omega1=10**30)    # numpy's isfinite refused the int (a TypeError naming nothing)
    assert res.status in set(nrmicp.Status)


@pytest.mark.parametrize("args,option", [
    (["demo", "--m", "0"], "--m"), (["demo", "--tol", "-1"], "--tol"),
    (["bench", "--budget", "nan"], "--budget"),
])
def test_cli_numeric_options_are_usage_errors(args, option):
    out = subprocess.run([sys.executable, "-m", "nrmicp", *args], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and option in out.stderr and "Traceback" not in out.stderr


def test_cli_bench_plot_of_a_missing_or_foreign_file_says_so(tmp_path):
    foreign = tmp_path / "notes.txt"
    foreign.write_text("hello\n")
    for path, says in ((tmp_path / "missing.csv", "cannot read"), (foreign, "no rows")):
        out = subprocess.run([sys.executable, "-m", "nrmicp", "bench", "--plot", str(path), "--out", str(tmp_path)],
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 1 and says in out.stderr and "Traceback" not in out.stderr


def test_newton_solves_positive_definite_nonsymmetric_lcps_and_blames_no_floor_it_is_above():
    # A = BᵀB + 0.05 I + 2 (K − Kᵀ), n = 200 (monotone LCPs): newton stopped STAGNATED on 5 of 6 seeds
    # (Res 7e-8 .. 5e-4), its message calling that the rounding floor (level 9.5e-11): the projected
    # Gauss–Seidel sweeps after each step took the exact step on the right set from Res 3e-14 back up
    import re
    for seed in range(6):
        rng = np.random.default_rng(seed)
        n, dens = 200, 4 / 200
        B = sp.random(n, n, density=dens, random_state=rng, data_rvs=rng.standard_normal)
        K = sp.random(n, n, density=dens, random_state=rng, data_rvs=rng.standard_normal)
        A = sp.csr_matrix(B.T @ B + 0.05 * sp.identity(n) + 2.0 * (K - K.T))
        A.sum_duplicates()
        A.sort_indices()
        q = 5 * rng.standard_normal(n)
        res = nrmicp.solve(A, q, method="newton")
        check_certificate(A, q, res)
        if not res.success and "rounding floor" in res.message:
            level = float(re.search(r"= ([0-9.e+-]+); returning", res.message).group(1))
            assert res.residual <= 100 * level, res.message
        assert res.success, (seed, res.message)
        other = nrmicp.solve(A, q, method="nrmm", tol=1e-10, maxiter=20000)   # an independent member
        assert other.success and np.abs(res.z - other.z).max() < 1e-7


def test_durations_masked_arrays_and_array_valued_callbacks_are_refused_by_name():
    A, q = tridiag(5, 4.0), -np.ones(5)
    with pytest.raises(TypeError, match="q must be a real numeric array"):
        nrmicp.solve(A, np.arange(5).astype("timedelta64[s]"))
    with pytest.raises(TypeError, match="x0 is a masked array"):
        nrmicp.solve(A, q, x0=np.ma.masked_array(np.zeros(5), mask=[0, 1, 0, 0, 0]))
    assert nrmicp.solve(A, np.ma.masked_array(q, mask=False)).success    # nothing masked: its values
    with pytest.raises(TypeError, match="callback must return None or a bool"):
        nrmicp.solve(A, q, callback=lambda zk: zk)
    assert nrmicp.solve(A, q, callback=lambda zk: 0).success              # a falsy int: go on
