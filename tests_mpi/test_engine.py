"""The one Newton driver (nrmicp::Newton) on the PETSc engine (nrmicp._petsc) takes the serial
member's decisions: given the same prolongations, the same status, finest steps within 1 and z within
1e-8 (relative) on np 1, 2 and 3 — the obstacle cold and nested, a nonsymmetric obstacle, a box
problem (two-sided membrane), a callable ζ (the outer fixed point) and an LCP."""
import pytest

from conftest import mpirun


@pytest.mark.parametrize("np_", [1, 2, 3])
def test_the_petsc_engine_takes_the_serial_decisions(np_):
    rows = mpirun(np_, "engine")
    assert {r["case"] for r in rows} == {"obstacle_2d cold", "obstacle_2d nested", "convection nested",
                                          "two-sided nested", "icp callable", "lcp"}
    for r in rows:
        where = f"np={np_} {r['case']}: {r}"
        assert r["status"] == r["serial_status"] == 0, where
        assert len(r["steps"]) == len(r["serial_steps"]), where
        assert abs(r["steps"][0] - r["serial_steps"][0]) <= 1, where
        assert r["err"] < 1e-8, where
        assert r["res"] < 1e-9 * 1.0001, where
