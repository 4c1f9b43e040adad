"""nrmicp.distributed.solve takes nrmicp.solve's options from the one table (nrmicp._options): each
either reaches the PETSc engine or, where it cannot apply there, is refused naming it. One process
(petsc4py without mpirun)."""
import numpy as np
import pytest
import scipy.sparse as sp

from nrmicp import _options
from nrmicp import distributed as dist

#: A valid value other than the default for each option the PETSc side refuses.
OTHER = {"scale": True, "accelerate": "anderson", "anderson_m": 3, "phi": 0.5, "theta": 0.5, "z_update": "solve",
         "inner": "cg", "verbose": 1, "components": 2, "zeta_jacobian": lambda z: sp.eye(len(z))}


def problem(n=8):
    A = sp.diags([-1.0, 4.0, -1.0], [-1, 0, 1], shape=(n, n), format="csr")
    return A, np.linspace(-1.0, 1.0, n)


def test_the_refused_options_are_the_table_minus_what_reaches_petsc():
    assert set(dist._UNSUPPORTED) == set(OTHER)
    assert set(OTHER) <= set(_options.names())


@pytest.mark.parametrize("name", sorted(OTHER))
def test_an_option_that_cannot_apply_on_petsc_is_refused_naming_it(name):
    A, q = problem()
    with pytest.raises(ValueError, match=f"option {name}="):
        dist.solve(A, q, method="newton", **{name: OTHER[name]})


def test_an_unknown_option_is_a_type_error_naming_it():
    A, q = problem()
    with pytest.raises(TypeError, match="tolerance"):
        dist.solve(A, q, tolerance=1e-8)


def test_the_supported_options_reach_the_solve():
    A, q = problem()
    seen = []
    r = dist.solve(A, q, method="newton", tol=1e-12, maxiter=50, stall_iterations=7, record_history=True,
                   callback=lambda k, z, res: seen.append(k) and False, polish=True, gamma=2.0)
    assert r.success and r.residual < 1e-12
    assert r.history is not None and len(r.history["residual"]) == len(seen) > 0
    assert "polished" in r
    z = dist.gather(r.z)
    w = A @ z + q
    assert np.all(z >= -1e-14) and np.all(w >= -1e-12) and abs(z @ w) < 1e-10   # the LCP's conditions


def test_the_defaults_are_nrmicp_solves():
    A, q = problem()
    import nrmicp
    r = dist.solve(A, q)   # method 'auto': rows dominant by half their diagonal, so nrmgs, as nrmicp.solve picks
    assert r.method == "nrmgs" == nrmicp.solve(A, q).method and r.success
    assert dist.solve(A, q, method="newton").method == "newton"
