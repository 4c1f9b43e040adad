"""nrmicp.distributed.solve takes nrmicp.solve's options from the one table (nrmicp._options): each
either reaches the PETSc engine or, where it cannot apply there, is refused naming it (one rank, under
mpirun: this process itself never initializes MPI, so that it can launch mpirun). The stationary
members run the serial loop, so its options (accelerate, phi, theta, inner, verbose, ...) apply."""
import pytest

from conftest import mpirun


@pytest.fixture(scope="module")
def out():
    return mpirun(1, "options")


def test_the_refused_options_are_options_of_the_table(out):
    assert out["unsupported"] == out["other"]
    assert out["unsupported_stationary"] == out["other_stationary"]
    assert set(out["other"]) | set(out["other_stationary"]) <= set(out["table"])


@pytest.mark.parametrize("member", ["refused", "refused_stationary"])
def test_an_option_that_cannot_apply_on_petsc_is_refused_naming_it(out, member):
    for name, (kind, message) in out[member].items():
        assert kind == "ValueError" and f"option {name}=" in message, (member, name, kind, message)


def test_the_stationary_members_options_are_refused_for_newton_by_the_core_naming_them(out):
    for name, (kind, message) in out["checked"].items():
        assert kind == "ValueError" and name in message, (name, kind, message)


def test_zeta_jacobian_of_a_stationary_member_is_refused_naming_it(out):
    kind, message = out["jacobian_stationary"]
    assert kind == "ValueError" and "zeta_jacobian" in message and "newton" in message, out["jacobian_stationary"]


@pytest.mark.parametrize("case", ["auto_solve", "solve_stationary"])
def test_z_update_solve_or_auto_that_means_it_is_refused_naming_it(out, case):
    kind, message = out[case]
    assert kind == "ValueError" and "z_update" in message and "explicit" in message, out[case]


def test_an_unknown_option_is_a_type_error_naming_it(out):
    kind, message = out["unknown"]
    assert kind == "TypeError" and "tolerance" in message


def _holds(s):
    assert s["success"] and s["res"] < 1e-12, s
    assert s["history"] == s["calls"] > 0, s
    assert s["min_z"] >= -1e-14 and s["min_w"] >= -1e-12 and s["zw"] < 1e-10, s   # the LCP's conditions


def test_the_supported_options_reach_the_solve(out):
    _holds(out["supported"])
    assert out["supported"]["polished"]


@pytest.mark.parametrize("name", ["nrmgs anderson", "nrmaor phi", "two_sweep theta", "nrm inner", "nrmm verbose",
                                  "mms", "nrmj explicit"])
def test_the_serial_loops_options_reach_the_stationary_members(out, name):
    _holds(out["supported_stationary"][name])


def test_the_defaults_are_nrmicp_solves(out):
    # method 'auto': rows dominant by half their diagonal, so nrmgs, as nrmicp.solve picks
    assert out["auto"] == ["nrmgs", "nrmgs"]
    # on a Laplacian newton, but nrmgs when an option only the stationary members read is given (per solve)
    assert out["auto_laplacian"] == {"{}": ["newton", "newton"], "{'accelerate': 'anderson'}": ["nrmgs", "nrmgs"],
                                     "{'z_update': 'explicit'}": ["nrmgs", "nrmgs"]}, out["auto_laplacian"]
