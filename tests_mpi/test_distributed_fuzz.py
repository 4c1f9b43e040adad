"""Random small problems through the distributed entry points (np = 2, uneven partitions):
every member against serial nrmicp and a plain numpy Res (bounds: ‖mid(z − ζ, z − u, Az + q)‖);
bounds (an implicit upper too, on newton), a callable ζ with zeta_jacobian (newton), scipy prolongations or a
nrmicp.Hierarchy (newton) and a callback on every member, the stationary members with Anderson, phi, theta, the
history and the stall window drawn at random."""
import os

from conftest import mpirun

EXAMPLES = int(os.environ.get("NRMICP_MPI_FUZZ_EXAMPLES", "40"))


def test_distributed_fuzz():
    rows = mpirun(2, "fuzz", EXAMPLES)
    assert len(rows) == EXAMPLES
    for r in rows:
        assert r["status"] == "CONVERGED", r
        assert r["res"] < 1e-9 * 1.0001, r
        # a P-matrix ICP has one solution; z's error is bounded by ||A^-1|| Res (A is diagonally dominant)
        assert r["err"] < 1e-8, r
        assert r["called"], r   # the callback saw the iterates
    assert any(r["bounded"] and r["method"] != "newton" for r in rows)
    assert any("accelerate" in r["options"] for r in rows)
    assert any("zeta_jacobian" in r["options"] for r in rows)   # a callable ζ with ζ′ (operator or diagonal)
    assert {"list", "Hierarchy"} <= {r["hierarchy"] for r in rows if r["method"] == "newton"}   # scipy P's, a Hierarchy
