"""nrmicp.distributed under mpirun: agreement with serial nrmicp, partition independence, bad
input on one rank (the same exception on every rank, no hang), nothing mutated."""
import json
import re

import numpy as np
import pytest

from conftest import mpirun
from nrmicp import _core

AGREE = 1e-10


@pytest.fixture(scope="module", params=[1, 2, 3])
def agreement(request):
    return request.param, mpirun(request.param, "agreement")


def test_every_member_agrees_with_serial_nrmicp(agreement):
    np_, rows = agreement
    assert {r["problem"] for r in rows} == {"obstacle_2d", "obstacle_3d", "convection", "lcp", "affine",
                                             "icp_callable"}
    assert {r["method"] for r in rows} == {"newton", "nrmj", "nrmgs", "nrmsor", "nrmaor"}
    for r in rows:
        where = f"np={np_} {r['problem']} {r['method']}"
        assert r["status"] == "CONVERGED", where
        # an affine ζ on the PETSc engine runs the outer fixed point (no affine system there), another
        # path to the same tol; a callable ζ's outer steps mix iterates by inner products summed in
        # another order on each partition: the answers agree to the tolerance's accuracy there
        outer = r["method"] == "newton" and r["problem"] in ("affine", "icp_callable")
        assert r["err"] < (1e-8 if outer else AGREE), where
        assert r["untouched"], where + ": an input was modified"
        # Res by the numpy oracle: the returned z meets the tolerance it was asked for
        assert r["res"] < (1e-9 if r["method"] == "newton" else 1e-10) * 1.0001, where


def test_newton_nests_finest_steps_few(agreement):
    _, rows = agreement
    for r in rows:
        if r["method"] == "newton" and r["problem"] in ("obstacle_2d", "obstacle_3d", "convection"):
            assert len(r["level_steps"]) > 1, r
            assert r["level_steps"][0] <= 5, r


def test_the_hierarchys_boomeramg_options_reach_it_and_leave_nothing_behind():
    out = mpirun(2, "boomeramg")
    assert out["status"] == "CONVERGED"
    assert out["levels"] > 3 and out["levels_3"] == 3 and out["status_3"] == "CONVERGED", out  # -nrmicp_hierarchy_
    assert out["left_all"] == [], out                    # nothing of ours or the user's stays behind


@pytest.mark.parametrize("np_", [1, 2])
def test_a_first_level_denser_than_1_2_a_is_folded_into_the_next(np_):
    out = mpirun(np_, "dense")
    for name, r in out.items():
        assert r["levels"] > 2, (name, r)
        if r["classical"] > 1.2:       # folded: P0 P1, a coarser first level, no denser than 1.2 A
            assert r["chosen_rows"] < r["classical_rows"] and r["chosen"] <= 1.2, (name, r)
        else:                          # kept: hypre's classical first level itself
            assert r["chosen_rows"] == r["classical_rows"] and r["chosen"] == r["classical"], (name, r)
    assert out["3d"]["classical"] > 1.2 and out["2d"]["classical"] < 1.2 and out["p1"]["classical"] < 1.2, out


def test_newton_stops_at_the_rounding_floor_and_names_it():
    out = mpirun(2, "floor")
    for name in ("obstacle", "affine"):
        r = out[name]
        assert r["status"] == "STAGNATED" == r["serial_status"], r
        assert r["err"] < AGREE, r
    r = out["obstacle"]     # (an affine ζ runs the outer fixed point on the PETSc engine: its own stop)
    assert "rounding level" in r["message"] and "tol 1e-17" in r["message"], r
    floor = float(re.search(r"rounding level [^=]*= ([-+.e0-9]+)", r["message"]).group(1))
    assert 0 < floor and r["res"] <= 100 * floor, r     # stopped at the floor, not before it
    assert r["nit"] <= 5, r                              # and without steps that cannot help


def test_an_overshooting_step_is_damped_as_in_the_serial_member():
    # P3, n = 18,241, np 2: 15 finest steps before the damping (Globalized::overshoots), 8 with it
    out = mpirun(2, "overshoot")
    assert out["status"] == "CONVERGED" and out["err"] < 1e-8, out
    assert out["levels"][0] <= 10, out


@pytest.mark.parametrize("np_", [1, 2])
def test_projected_sweeps_after_each_step_cut_a_cold_starts_peeling(np_):
    # the serial member's kSmoothingSweeps, on each rank's rows: 24 steps without them (the serial
    # member's count before the sweeps; the distributed member took as many)
    out = mpirun(np_, "sweeps")
    assert out["status"] == "CONVERGED" and out["err"] < 1e-8 and out["res"] < 1e-9, out
    assert out["levels"] == [out["levels"][0]] and out["levels"][0] <= 12, out



@pytest.mark.parametrize("np_", [1, 2])
def test_a_start_closer_than_a_cold_one_replaces_the_nested_one(np_):
    out = mpirun(np_, "warm")
    warm_steps = _core.newton_tuning["warm_steps"]
    assert len(out["first_levels"]) > 1, out
    for name in ("warm", "zeros", "ones"):
        assert out[name]["status"] == "CONVERGED" and out[name]["err"] < 1e-8, out
    # level_steps has an entry per level (0: the level was not solved)
    assert not any(out["warm"]["levels"][1:]) and 1 <= out["warm"]["nit"] <= warm_steps, out
    assert all(out["zeros"]["levels"][1:]) and out["zeros"]["nit"] <= 5, out
    assert all(out["ones"]["levels"][1:]) and warm_steps < out["ones"]["nit"] <= warm_steps + 5, out

@pytest.fixture(scope="module")
def partition_run():
    return mpirun(3, "partition")


def test_answer_does_not_depend_on_the_partition(partition_run):
    diffs = partition_run
    assert diffs["newton"] < AGREE
    assert diffs["nrmgs"] < AGREE


def test_a_p_matrix_where_active_sets_may_cycle_takes_the_serial_path(partition_run):
    fb = partition_run["fallback"]
    assert fb["status"] == "CONVERGED" and fb["path"] == fb["serial_path"], fb
    assert fb["err"] < AGREE, fb


BAD = {
    "layout": ("ValueError", "does not match A's rows"),
    "nonsquare": ("ValueError", "must together be square"),
    "dense_A": ("ValueError", "A must be an AIJ (sparse) PETSc matrix, got type 'mpidense'"),
    "sbaij_A": ("ValueError", "A must be an AIJ (sparse) PETSc matrix, got type 'mpisbaij'"),
    "inf_in_A": ("ValueError", "A has a non-finite entry inf at"),
    "callback_not_callable": ("TypeError", "callback must be callable, got int"),
    "layout_A": ("ValueError", "create A with the same row and column layout"),
    "zero_diagonal": ("ValueError", "diagonal must be positive"),
    "nan_q": ("ValueError", "q has a non-finite entry"),
    "complex_A": ("TypeError", "A must be real"),
    "corrupt_A": ("ValueError", "A is not a valid sparse matrix"),
    "zeta_raises": ("RuntimeError", "zeta failed here"),
    "callback_raises": ("RuntimeError", "callback failed here"),
    "zeta_nan": ("ValueError", "NaN or Inf"),
    "bad_option": ("ValueError", "tol"),
    "bad_method": ("ValueError", "method must be one of"),
    "z_update_solve": ("ValueError", "z_update"),
    "mms_icp": ("ValueError", "z_update 'solve'"),
    "array_hierarchy": ("TypeError", "hierarchy"),   # (a wrong type for any member, as nrmicp.solve says)
    "mixed_kinds": ("TypeError", "not both"),
    "mat_as_zeta": ("TypeError", "nrmicp.Affine"),
    "B_columns": ("ValueError", "zeta.B must be"),
    "subnormal_diagonal": ("ValueError", "not subnormal"),
    "nonfinite_A": ("ValueError", "this rank's block of rows"),
    "crossing_bounds": ("ValueError", "which start at global row"),   # (the index is the rank's row)
    "q_length_affine": ("ValueError", "q must have length"),
}


@pytest.mark.parametrize("kind", sorted(BAD))
@pytest.mark.parametrize("method", ["newton", "nrmgs"])
def test_bad_input_raises_the_same_exception_on_every_rank(kind, method):
    outcomes = mpirun(2, "bad", kind, method, timeout=120)
    kind_name, text = BAD[kind]
    assert len(outcomes) == 2
    assert outcomes[0] == outcomes[1], outcomes  # the same type and message on both ranks
    name, message, untouched = outcomes[0]
    assert name == kind_name, outcomes
    assert text in message, outcomes
    assert message.startswith("rank "), outcomes
    assert untouched, "an input was modified"


@pytest.mark.parametrize("ranks", [1, 2])
def test_rows_far_apart_in_size_factorize_as_serially(ranks):
    # (z itself is not compared: Res, unweighted, leaves the small rows' entries loose on both engines alike)
    for scale, r in mpirun(ranks, "rows_apart", timeout=120).items():
        assert r["status"] == r["serial"] == "CONVERGED", (ranks, scale, r)


def test_an_argument_that_differs_between_ranks_is_refused_naming_it_on_every_rank():
    out = mpirun(2, "differing", timeout=180)   # (a hang before: the ranks took different branches)
    for name, outcomes in out["refused"].items():
        assert len(outcomes) == 2 and outcomes[0] == outcomes[1], (name, outcomes)
        kind, message = outcomes[0]
        assert kind == "ValueError" and name in message and "must be the same on every rank" in message, (name, kind, message)
    for name, outcomes in out["solved"].items():   # a rank's own rows' data may differ
        assert outcomes == [["no exception", "CONVERGED"]] * 2, (name, outcomes)
    kinds = {tuple(o) for o in out["callback_return"]}   # one rank's callback returned an array
    assert len(kinds) == 1 and "callback must return None or a bool" in out["callback_return"][0][1], kinds


def test_a_rank_without_rows_newton_refuses_on_every_rank_the_stationary_members_solve():
    out = mpirun(2, "no_rows", timeout=120)
    for method in ("newton", "newton_amg"):
        assert len(out[method]) == 2 and out[method][0] == out[method][1], out[method]   # the same on both ranks
        name, message = out[method][0]
        assert name == "ValueError" and message.startswith("rank 1: A has no rows on this rank"), out[method]
    for method in ("nrmgs", "nrmgs_default", "nrm_omega2", "nrm_omega2_icp"):
        for status, err in out[method]:
            assert status == "CONVERGED" and err < 1e-6, (method, out[method])
    assert out["nrmgs_short"] == [["MAX_ITERATIONS", True]] * 2, out["nrmgs_short"]   # the member's advice
    assert out["auto"][0] == out["auto"][1] and out["auto"][0][1].startswith("rank 1: A has no rows"), out["auto"]


def test_readme_example_runs_on_two_ranks():
    import os
    import subprocess
    import shutil
    from conftest import PYTHON, TIMEOUT
    here = os.path.dirname(os.path.abspath(__file__))
    cmd = [shutil.which("mpirun"), "-n", "2", "--oversubscribe"] + (["--allow-run-as-root"] if os.geteuid() == 0 else [])
    out = subprocess.run(cmd + [PYTHON, os.path.join(here, "..", "examples", "distributed_obstacle.py")],
                         capture_output=True, text=True, timeout=TIMEOUT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("CONVERGED finest steps"), out.stdout
    assert "on 2 ranks" in out.stdout


def test_the_documented_example_is_the_one_the_tests_run():
    import os
    import re
    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    doc = open(os.path.join(root, "docs", "DISTRIBUTED.md"), encoding="utf-8").read()
    block = re.findall(r"^```py\n(.*?)^```", doc, flags=re.S | re.M)[0]
    assert block == open(os.path.join(root, "examples", "distributed_obstacle.py"), encoding="utf-8").read()


@pytest.mark.parametrize("np_", [1, 2])
def test_the_default_rule_does_not_depend_on_units(np_):
    out = mpirun(np_, "units")
    for key, r in out.items():
        assert r["status"] == "CONVERGED" and r["criterion"] == "units", (np_, key, r)
        assert r["err"] < 1e-6, (np_, key, r)
        assert r["res_is_papers"], (np_, key, r)


@pytest.mark.parametrize("np_", [1, 2])
def test_z_in_extreme_units_takes_the_same_steps(np_):
    out = mpirun(np_, "z_units")
    for name, runs in out.items():
        for s, r in runs.items():
            assert r["status"] == "CONVERGED" and r["nit"] == r["nit_1"] and r["err"] < 1e-12, (np_, name, s, r)


@pytest.mark.parametrize("np_", [2, 3])
def test_rows_at_a_nonzero_bound_on_one_rank_only_do_not_deadlock(np_):
    out = mpirun(np_, "one_sided_contact", timeout=120)
    for h, r in out.items():
        assert r["status"] == "CONVERGED", (np_, h, r)
        assert r["at_upper"] == 6, (np_, h, r)   # the six pushed rows, and no other
        assert r["violation"] <= 1e-12 and r["sign"] <= 1e-9, (np_, h, r)


@pytest.mark.parametrize("np_", [1, 2])
def test_an_implicit_upper_bound_runs_the_serial_outer_fixed_point(np_):
    out = mpirun(np_, "implicit_upper")
    for name in ("callable", "affine"):
        r = out[name]
        assert r["status"] == r["serial_status"] == "CONVERGED", (np_, name, r)
        assert r["err"] < 1e-8 and r["res"] < 1e-10, (np_, name, r)
        assert r["at_upper"] > 100 and r["above"] <= 1e-12, (np_, name, r)   # the ceiling is met, never crossed
    assert "solved by method 'newton'" in out["nrmgs"] and "upper" in out["nrmgs"]
    assert out["auto"] == ["newton", "newton"], out


@pytest.mark.parametrize("np_", [1, 2])
def test_zeta_jacobian_runs_semismooth_newton_on_petsc_with_the_serial_decisions(np_):
    """ζ′ as a LinearOperator of this rank's rows (its products communicating, for a nonlocal ζ) or a
    diagonal matrix: the one driver's semismooth Newton on the whole ICP. Cold, the serial member's
    decisions (ζ′ calls, steps) and z; nested (BoomerAMG against pyamg) the same answer; the ICP's own
    conditions checked in numpy. A sparse ζ′ the engine has no system for acts by its product. Bad
    Jacobians (wrong shape on one rank, complex, not callable, ...) are refused on every rank naming
    zeta_jacobian."""
    out = mpirun(np_, "jacobian")
    for name, r in out.items():
        if name == "refused":
            continue
        assert r["status"] == r["serial_status"] == "CONVERGED" and r["path"] == "newton", (name, r)
        assert r["gw"] < 1e-9 and r["min_w"] > -1e-9 and r["min_g"] > -1e-9, (name, r)
        assert abs(r["oracle_res"] - r["res"]) <= 1e-6 * r["res"] + 1e-13, (name, r)
        assert 1 <= r["calls"] <= 3, (name, r)
        assert r["err"] < 1e-9, (name, r)
        # the engine solves a sparse ζ′ it has no system for (one that couples rows, or a diagonal with an entry
        # 1) by its product, where the serial member assembles it: the same answer, its own steps
        by_product = name.startswith(("local coupling matrix", "sin diagonal at 1"))
        if name.endswith(" None") and not by_product:
            assert (r["calls"], r["nit"]) == (r["serial_calls"], r["serial_nit"]), (name, r)
        assert (r["matrix_free"] > 0) == ("operator" in name or by_product), (name, r)
    for rank in out["refused"]:
        refused = json.loads(rank)
        kind, message = refused["wrong shape on the last rank"]
        assert kind == "ValueError" and "zeta_jacobian(z) must return" in message, refused
        for name, expected in (("complex operator", "TypeError"), ("a string", "TypeError"),
                               ("matvec of the wrong length on the last rank", "ValueError"),
                               ("matvec NaN on the last rank", "ValueError"), ("not callable", "TypeError")):
            kind, message = refused[name]
            assert kind == expected and "zeta_jacobian" in message, (name, refused)


@pytest.mark.parametrize("np_", [1, 2])
def test_a_solver_is_set_up_once_for_a_march_of_solves(np_):
    """distributed.Solver: three loads with x0 the last answer, newton ('amg') and nrmgs, each against
    serial nrmicp and the numpy oracle; the set-up is reported by the first solve of each scaling only
    (the default rule's σA, then the paper's tol on A); misplaced options and a closed Solver refused."""
    out = mpirun(np_, "solver")
    for method, rows in (("newton", out["newton"]), ("nrmgs", out["nrmgs"])):
        assert [r["status"] for r in rows] == ["CONVERGED"] * 3, rows
        assert rows[0]["setup"] > 0 and rows[1]["setup"] == 0 and rows[2]["setup"] > 0, rows
        for r in rows:   # the default rule is relative (Res_E 1e-10 of Res_E(0)); the last row is tol 1e-9
            assert r["err"] < (1e-10 if method == "newton" else 1e-6), (method, rows)
        assert rows[2]["res"] < 1e-9 * 1.0001, rows
    kind, message = out["x0 at set-up"]
    assert kind == "TypeError" and "x0" in message and "solve()" in message, out
    kind, message = out["method per solve"]
    assert kind == "TypeError" and "method" in message and "distributed.Solver()" in message, out
    assert out["closed"][0] == "ValueError" and "closed" in out["closed"][1], out


@pytest.mark.parametrize("np_", [1, 2])
def test_zeta_jacobian_where_one_ranks_rows_stand_still_does_not_hang(np_):
    """The semismooth loop's tests are taken on every rank alike (a rank whose rows stood still skipped
    a collective obstacle solve the other entered: a hang before); the answer's ICP conditions in numpy."""
    out = mpirun(np_, "jacobian_still_rows", timeout=120)
    for form, r in out.items():
        assert r["status"] == r["serial_status"] == "CONVERGED", (form, r)
        assert r["numpy"] < 1e-7 and r["serial_numpy"] < 1e-7, (form, r)


@pytest.mark.parametrize("np_", [1, 2])
def test_the_serial_rounds_decide_as_in_nrmicp_solve(np_):
    out = mpirun(np_, "rounds")
    for m in ("newton", "nrmgs"):   # w = A z + q in the user's units, though σ(Az + q) overflows
        r = out[f"w_{m}"]
        assert np.all(np.isfinite(r["w"])), r
        assert np.allclose(r["w"], r["numpy"], rtol=1e-14, atol=0) and np.allclose(r["w"], r["serial"], rtol=1e-14, atol=0), r
    r = out["free"]   # free rows are bounds: polish runs within them, as in nrmicp.solve
    assert r["status"] == r["serial_status"] and r["err"] < 1e-12, r
    assert ("polish:" in r["message"]) == ("polish:" in r["serial_message"]) and "polish:" in r["message"], r
    r = out["callback"]   # k counts on over re-solves, as the history does
    assert r["ks"] == r["history"] == sorted(r["ks"]) and len(r["ks"]) > 0, r
    r = out["verbose"]   # the Newton member's progress lines: rank 0's, one set
    assert r["status"] == "CONVERGED" and len(r["lines"]) >= 2 and r["others"] == 0, r
    assert any("newton" in line for line in r["lines"]), r
    if np_ == 1:   # a Jacobian given up: the note under the default rule too
        r = out["jacobian"]
        assert r["path"] == r["serial_path"] == "newton+outer", r
        assert "looks wrong" in r["message"] and "looks wrong" in r["serial_message"], r


@pytest.mark.parametrize("np_", [1, 2, 3])
def test_one_hierarchy_object_serves_both_engines_with_the_same_decisions(np_):
    out = mpirun(np_, "shared_hierarchy")
    refused = out["another A"]   # a Hierarchy of another A: refused on every rank, as nrmicp.solve refuses it
    assert len(set(refused)) == 1 and "hierarchy was built on another matrix than A" in refused[0], refused
    out = out["levels"]
    assert len(out) == 4
    for name, r in out.items():
        assert r["status"] == r["serial_status"] == "CONVERGED" and r["steps"] == r["serial_steps"], (name, r)
        assert r["err"] < AGREE, (name, r)


def test_a_failure_on_one_rank_only_raises_on_every_rank_without_a_hang():
    ranks = mpirun(2, "hazards", timeout=120)
    assert len(ranks) == 2 and ranks[0] == ranks[1], ranks
    out = ranks[0]
    for name in ("levels differ", "values differ"):
        assert out[name][0] == "ValueError" and "same on every rank" in out[name][1], (name, out[name])
    for name in ("verbose progress", "verbose final"):
        assert out[name][0] == "RuntimeError" and "the logger failed on rank 0" in out[name][1], (name, out[name])
    assert out["after"] == ["ok", "CONVERGED"], out
    kind, message = out["block refused"]   # the failing rank's own message, on every rank
    assert message.startswith("rank 1: ") and "cholmod factorization" in message and "another process" not in message, out


@pytest.mark.parametrize("ranks", [1, 2])
def test_a_nonpositive_diagonal_is_refused_and_gives_the_amg_set_up_up(ranks):
    out = mpirun(ranks, "nonpositive_diagonal", timeout=120)
    for case in ("newton amg", "newton None", "nrm auto"):
        assert out[case] is not None and "diagonal must be positive" in out[case] and out[case].endswith("A[3, 3] = 0"), out
    assert out["nrmgs amg"].endswith(out["serial_stationary"]), out
    assert out["levels"] == {"zero": [], "nan": []}, out


@pytest.mark.parametrize("ranks", [1, 2])
def test_an_upper_of_plus_infinity_everywhere_is_no_bound(ranks):
    out = mpirun(ranks, "upper_all_inf", timeout=120)
    assert out == {"status": "CONVERGED", "polished": True}, out


def test_a_base_exception_on_one_rank_is_raised_on_every_rank():
    out = mpirun(2, "base_exception", timeout=120)   # (they hung: collective caught Exception only)
    assert out["KeyboardInterrupt"] == ["KeyboardInterrupt: rank 1: "] * 2, out
    assert out["SystemExit"] == ["SystemExit: rank 1: 3"] * 2, out


@pytest.mark.parametrize("ranks", [2, 3])
def test_bounds_on_one_ranks_rows_only_are_every_ranks_problem(ranks):
    out = mpirun(ranks, "bounds_on_rank_0", timeout=120)   # (the core gives the other ranks +inf upper bounds)
    assert out["status"] == out["serial_status"] == "CONVERGED", out
    assert out["res"] < 1.0001e-10 and out["err"] < 1e-8, out


def test_a_hierarchy_given_up_on_one_rank_gives_every_rank_the_same_reason():
    out = mpirun(2, "reason_alike", timeout=120)
    assert out[0] == out[1] and out[0]["used"] == 1 and "a_ii <= 0" in out[0]["reason"], out


@pytest.mark.parametrize("ranks", [1, 2])
def test_a_solve_that_does_not_converge_gives_the_serial_hints(ranks):
    out = mpirun(ranks, "hints", timeout=120)
    for name, (serial, ours, serial_hints, our_hints) in out.items():
        assert serial == ours and serial != "CONVERGED" and serial_hints and our_hints == serial_hints, (name, out)
