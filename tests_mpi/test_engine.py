"""The one Newton driver (nrmicp::Newton) on the PETSc engine (nrmicp._petsc) takes the serial
member's decisions: given the same prolongations, the same status, finest steps within 1 and z within
1e-8 (relative) on np 1, 2 and 3 — the obstacle cold and nested, a nonsymmetric obstacle, a box
problem (two-sided membrane), a callable ζ (the outer fixed point) and an LCP — and on the golden
master's Newton cases that fit a PETSc matrix (tests/golden/newton.py's obstacle scenes)."""
import pytest

from conftest import mpirun


def check(rows, np_, steps_within=lambda r: 1):
    for r in rows:
        where = f"np={np_} {r['case']}: {r}"
        assert r["status"] == r["serial_status"] == 0, where
        assert len(r["steps"]) == len(r["serial_steps"]), where
        assert abs(r["steps"][0] - r["serial_steps"][0]) <= steps_within(r), where
        assert r["err"] < 1e-8, where
        assert r["res"] < r["tol"] * 1.0001, where


@pytest.mark.parametrize("np_", [1, 2, 3])
def test_the_petsc_engine_takes_the_serial_decisions(np_):
    rows = mpirun(np_, "engine", "engine")
    assert {r["case"] for r in rows} == {"obstacle_2d cold", "obstacle_2d nested", "convection nested",
                                          "two-sided nested", "icp callable", "lcp"}
    check(rows, np_)


def test_one_rank_takes_the_serial_steps_on_the_golden_cases():
    rows = mpirun(1, "engine", "golden")
    assert len(rows) == 66
    check(rows, 1, steps_within=lambda r: 0)


def test_two_ranks_take_the_serial_decisions_on_the_golden_cases():
    """Within 1 finest step, except an outer fixed point's (a callable ζ) within 2: its inexact inner
    solves stop on a Res that the projected sweeps shape, and those are Gauss–Seidel inside a rank,
    Jacobi between ranks (measured: 6 against 8 steps on obstacle_2d_31 at np 3, 4 against 6 on
    obstacle_3d at np 2 and 3; every other case within 1)."""
    rows = mpirun(2, "engine", "golden")
    assert len(rows) == 66
    check(rows, 2, steps_within=lambda r: 2 if "/callable/" in r["case"] else 1)
