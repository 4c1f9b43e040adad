"""nrmicp.distributed.solve takes nrmicp.solve's options from the one table (nrmicp._options): each
either reaches the PETSc engine or, where it cannot apply there, is refused naming it (one rank, under
mpirun: this process itself never initializes MPI, so that it can launch mpirun)."""
import pytest

from conftest import mpirun


@pytest.fixture(scope="module")
def out():
    return mpirun(1, "options")


def test_the_refused_options_are_options_of_the_table(out):
    assert out["unsupported"] == out["other"]
    assert set(out["other"]) <= set(out["table"])


def test_an_option_that_cannot_apply_on_petsc_is_refused_naming_it(out):
    for name, (kind, message) in out["refused"].items():
        assert kind == "ValueError" and f"option {name}=" in message, (name, kind, message)


def test_an_unknown_option_is_a_type_error_naming_it(out):
    kind, message = out["unknown"]
    assert kind == "TypeError" and "tolerance" in message


def test_the_supported_options_reach_the_solve(out):
    s = out["supported"]
    assert s["success"] and s["res"] < 1e-12
    assert s["history"] == s["calls"] > 0 and s["polished"]
    assert s["min_z"] >= -1e-14 and s["min_w"] >= -1e-12 and s["zw"] < 1e-10   # the LCP's conditions


def test_the_defaults_are_nrmicp_solves(out):
    # method 'auto': rows dominant by half their diagonal, so nrmgs, as nrmicp.solve picks
    assert out["auto"] == ["nrmgs", "nrmgs"]
