"""The stationary members on PETSc are the serial loop (nrmicp::Solver on the PETSc engine) as
synchronous multisplitting: on one rank the serial member's iterates; on two and three ranks the
serial solution (Res by numpy, bounds included), nrmj in the serial number of iterations (Jacobi does
not depend on the partition); and the loop's options — Anderson, history, callback, theta, phi,
verbose, rtol, stall_iterations — reach it."""
import pytest

from conftest import mpirun

MEMBERS = {"nrm", "nrmm", "nrmaor", "nrmsor", "nrmgs", "nrmj"}
PROBLEMS = {"lcp", "constant", "callable", "bounds", "bounds_on_rank_0"}
TOL = 1e-10


@pytest.fixture(scope="module", params=[1, 2, 3])
def family(request):
    return request.param, mpirun(request.param, "family")


def test_every_member_and_problem_ran(family):
    _, rows = family
    assert {r["method"] for r in rows} == MEMBERS
    assert {r["problem"] for r in rows} == PROBLEMS
    assert len(rows) == len(MEMBERS) * len(PROBLEMS)


def test_each_member_converges_to_the_serial_solution(family):
    np_, rows = family
    for r in rows:
        where = f"np={np_} {r}"
        assert r["status"] == r["serial_status"] == "CONVERGED", where
        assert r["res"] < TOL * 1.0001, where            # complementarity (and the bounds), by numpy
        assert abs(r["reported"] - r["res"]) <= 1e-6 * r["res"] + 1e-15, where
        assert r["err"] < 1e-8, where                    # unique solution: Bai's matrices are P-matrices


def test_one_rank_takes_the_serial_iterates_more_ranks_a_few_more_sweeps(family):
    np_, rows = family
    for r in rows:
        if np_ == 1:   # the diagonal block is A: the serial splitting, the serial loop
            assert r["nit"] == r["serial_nit"] and r["err"] < 1e-12, r
        else:          # Jacobi between the blocks: measured 0 to 3 more on these n = 64 problems
            assert r["serial_nit"] <= r["nit"] + 1 and r["nit"] <= r["serial_nit"] + 5, (np_, r)


def test_jacobi_takes_the_serial_iterations_on_any_partition(family):
    np_, rows = family
    for r in rows:
        if r["method"] == "nrmj":
            assert r["nit"] == r["serial_nit"] and r["err"] < 1e-12, (np_, r)


@pytest.fixture(scope="module")
def hooks():
    return mpirun(2, "hooks")


def test_anderson_accelerates_on_two_ranks_with_history_and_callback(hooks):
    a, plain = hooks["anderson"], hooks["plain"]
    assert a["status"] == "CONVERGED" and a["res"] < TOL * 1.0001, a
    assert a["nit"] < plain["nit"], (a, plain)
    assert "anderson_rejections" in a["counters"], a
    # every iterate k = 0..nit seen once by the callback and recorded in the history, with the same Res
    assert a["calls"] == a["history"][1] == a["iterations"] + 1 and a["last_call"] == a["history"][0], a
    assert a["history_res"] == a["call_res"], a


def test_a_callback_that_stops_on_one_rank_stops_every_rank(hooks):
    r = hooks["stop_on_one_rank"]
    assert r["status"] == "CALLBACK_STOP" and r["iterations"] == 3, r
    r = hooks["stop_iteration_on_one_rank"]   # StopIteration stops as True does (nrmicp.solve's rule)
    assert r["status"] == "CALLBACK_STOP" and r["iterations"] == 3, r


@pytest.mark.parametrize("name", ["two_sweep_theta", "phi", "verbose"])
def test_the_loops_parameters_apply(hooks, name):
    r = hooks[name]
    assert r["status"] == "CONVERGED" and r["res"] < TOL * 1.0001, (name, r)
    assert r["calls"] == r["iterations"] + 1, (name, r)


def test_rtol_is_relative_to_res_at_zero_as_serially(hooks):
    r = hooks["rtol"]
    assert r["status"] == "CONVERGED", r
    assert abs(r["target"] - hooks["serial_rtol_tol"]) <= 1e-12 * r["target"], r
    assert r["res"] < r["target"], r


def test_stall_iterations_sets_the_no_progress_window(hooks):
    r = hooks["stall"]   # nrm with omega2 = 0.1 on diag 8: no progress; windows of 5
    assert r["status"] == "STAGNATED" and r["iterations"] < 1000, r
