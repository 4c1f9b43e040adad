"""A zeta_jacobian returning a linear operator (issue 37): method 'newton' takes matrix-free Newton
steps on the whole ICP (FGMRES preconditioned by the LCP piece; docs/SPEC.md, the Newton member).
Its answers agree with the same Jacobian given as a matrix and with the outer fixed point (no
Jacobian), and satisfy the complementarity conditions checked here in numpy; its Newton steps do not
grow with the mesh; a bad operator is a clear error naming zeta_jacobian."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import nrmicp
from nrmicp import scenes


def sin_problem(m):
    """(A, q, ζ, ∂ζ as a sparse matrix): the 2D obstacle scene with ζ(z) = ψ + 0.2 sin z."""
    pb = scenes.obstacle_2d(m, exact=False)
    psi = np.asarray(pb.zeta, dtype=float)
    return pb.A, pb.q, (lambda z: psi + 0.2 * np.sin(z)), (lambda z: sp.diags(0.2 * np.cos(z), format="csr"))


def nonlocal_problem(m, k=1.0):
    """(A, q, ζ, ∂ζ as a dense array): the 2D obstacle scene under a load with the obstacle lowered where the
    membrane is, ζ(z) = ψ − φ T z, T = (kI − Δ_h)⁻¹ (as thermoforming's mould): ∂ζ = −diag(φ) T is dense."""
    pb = scenes.obstacle_2d(m, load=-8.0, exact=False)
    A, n = pb.A, pb.n
    x, y = pb.reference["x"], pb.reference["y"]
    phi = 0.5 * np.sin(np.pi * x) * np.sin(np.pi * y)
    lu = spla.splu(sp.csc_matrix(k * sp.identity(n) + A))
    psi = np.asarray(pb.zeta, dtype=float)
    T = lu.solve(np.eye(n))
    return A, pb.q, (lambda z: psi - phi * lu.solve(z)), (lambda z: -phi[:, None] * T)


def as_operator(jacobian):
    """The same ∂ζ(z), known only by its products."""
    def op(z):
        J = jacobian(z)
        return spla.LinearOperator(J.shape, matvec=lambda v: J @ v, dtype=float)
    return op


def complementarity(A, q, zeta, z):
    """max |min(Az + q, z − ζ(z))| in numpy."""
    return float(np.max(np.abs(np.minimum(A @ z + q, z - zeta(z)))))


PROBLEMS = {"sin": sin_problem, "nonlocal": nonlocal_problem}


@pytest.mark.parametrize("name", sorted(PROBLEMS))
@pytest.mark.parametrize("scale", [False, "both"])
def test_an_operator_jacobian_agrees_with_the_matrix_and_with_the_outer_fixed_point(name, scale):
    A, q, zeta, jacobian = PROBLEMS[name](15)
    kw = dict(method="newton", tol=1e-11, scale=scale)
    by_operator = nrmicp.solve(A, q, zeta, zeta_jacobian=as_operator(jacobian), **kw)
    by_matrix = nrmicp.solve(A, q, zeta, zeta_jacobian=jacobian, **kw)
    outer = nrmicp.solve(A, q, zeta, **kw)
    for res in (by_operator, by_matrix, outer):
        assert res.success, res.message
        assert complementarity(A, q, zeta, res.z) < 1e-10
    assert by_operator.path == "newton" and by_operator.counters["matrix_free_iterations"] > 0
    assert by_matrix.counters.get("matrix_free_iterations", 0) == 0
    assert np.max(np.abs(by_operator.z - by_matrix.z)) < 1e-10
    assert np.max(np.abs(by_operator.z - outer.z)) < 1e-10
    assert by_operator.inner_iterations >= by_operator.counters["matrix_free_iterations"]


def thermoforming(m):
    """scenes.thermoforming_2d (κ = 2, δ = 1) with its exact ∂ζ = κ (I + δ A)⁻¹ diag(s'(z)) as an operator."""
    kappa, delta = 2.0, 1.0
    pb = scenes.thermoforming_2d(m, kappa=kappa, delta=delta, exact=False)
    phi0, ell, n = pb.reference["phi0"], pb.reference["ell"], pb.n
    lu = spla.splu(sp.csc_matrix(sp.identity(n) + delta * pb.A))

    def jacobian(z):
        u = (z - phi0) / ell
        ds = -2.0 * kappa * u / ell / (1.0 + u * u) ** 2
        return spla.LinearOperator((n, n), matvec=lambda v: lu.solve(ds * v), dtype=float)
    return pb, jacobian


def test_newton_steps_with_an_operator_jacobian_do_not_grow_with_the_mesh():
    steps = []
    for m in (15, 31, 63):   # odd: the geometric hierarchy halves down to one node
        pb, jacobian = thermoforming(m)
        calls = []
        res = nrmicp.solve(pb.A, pb.q, pb.zeta, method="newton", tol=1e-10, hierarchy=pb.prolongations(),
                           zeta_jacobian=lambda z: calls.append(1) or jacobian(z))
        assert res.success and res.path == "newton", res.message
        zeta = lambda z: pb.zeta(z).copy()  # noqa: E731 (the scene's ζ returns a reused buffer)
        assert complementarity(pb.A, pb.q, zeta, res.z) < 1e-9
        steps.append(len(calls))
    # measured 3, 3, 3 (the outer fixed point: 6-7 outer steps; benchmarks/qvi_operator.py)
    assert max(steps) <= 6 and all(s <= min(steps[:i]) + 1 for i, s in enumerate(steps) if i), steps


def test_a_wrong_operator_jacobian_is_given_up_for_the_outer_fixed_point():
    pb, jacobian = thermoforming(31)
    negated = lambda z: -jacobian(z)  # noqa: E731
    res = nrmicp.solve(pb.A, pb.q, pb.zeta, method="newton", tol=1e-10, hierarchy=None, zeta_jacobian=negated)
    assert res.path == "newton+outer" and "zeta_jacobian looks wrong" in res.message
    assert res.success, res.message
    zeta = lambda z: pb.zeta(z).copy()  # noqa: E731
    assert complementarity(pb.A, pb.q, zeta, res.z) < 1e-9


def bad(n, how):
    """A zeta_jacobian returning a bad operator of the kind `how`."""
    return {
        "wrong shape": lambda z: spla.aslinearoperator(sp.identity(n + 1)),
        "complex": lambda z: spla.LinearOperator((n, n), matvec=lambda v: (1 + 1j) * v, dtype=complex),
        "matvec of wrong length": lambda z: spla.LinearOperator((n, n), matvec=lambda v: np.ones(n + 1), dtype=float),
        "matvec returns nan": lambda z: spla.LinearOperator((n, n), matvec=lambda v: np.full(n, np.nan), dtype=float),
        "matvec returns a string": lambda z: spla.LinearOperator((n, n), matvec=lambda v: "Jv", dtype=float),
        "not an operator": lambda z: object(),
    }[how]


@pytest.mark.parametrize("how, error, says", [
    ("wrong shape", ValueError, "(226, 226)"),
    ("complex", TypeError, "real operator"),
    ("matvec of wrong length", ValueError, "matvec(v)"),
    ("matvec returns nan", ValueError, "returned non-finite values (NaN or Inf): zeta_jacobian(z).matvec(v)[0] = nan"),
    ("matvec returns a string", ValueError, "matvec(v)"),
    ("not an operator", TypeError, "linear operator"),
])
def test_a_bad_operator_is_an_error_naming_zeta_jacobian(how, error, says):
    A, q, zeta, _ = sin_problem(15)
    with pytest.raises(error, match="zeta_jacobian") as info:
        nrmicp.solve(A, q, zeta, method="newton", zeta_jacobian=bad(A.shape[0], how))
    assert says in str(info.value)


def test_a_matvec_writing_into_its_input_is_named():
    A, q, zeta, jacobian = sin_problem(15)

    def writes(z):
        def matvec(v):
            v[0] = 0.0
            return v
        return spla.LinearOperator(A.shape, matvec=matvec, dtype=float)
    # (unscaled, tol given: scaled, as under the default stopping rule, v reaches the matvec as D_c v,
    # a fresh array)
    with pytest.raises(ValueError, match=r"zeta_jacobian\(z\)\.matvec\(v\) tried to modify its input v"):
        nrmicp.solve(A, q, zeta, method="newton", zeta_jacobian=writes, scale=False, tol=1e-10)


@pytest.mark.parametrize("form", ["operator", "none"])
def test_zeta_is_not_called_again_at_the_z_of_its_last_call(form):
    # A costly ζ (here a sparse solve) is asked at one z by the step's Res, the outer step after it, the stop
    # rules and the next linearization: the Newton member keeps its last value instead of calling again.
    pb, jacobian = thermoforming(31)
    seen = []

    def zeta(z):
        seen.append(np.array(z, copy=True))
        return pb.zeta(z).copy()
    # tol below Res's rounding floor: the floor's stop rules ask for ζ at the z they judge, too
    res = nrmicp.solve(pb.A, pb.q, zeta, method="newton", tol=1e-14, hierarchy=pb.prolongations(),
                       zeta_jacobian=jacobian if form == "operator" else None)
    assert res.status in (nrmicp.Status.CONVERGED, nrmicp.Status.STAGNATED), res.message
    # the last call is the result's Res, computed in numpy in the user's variables (an independent check)
    assert len(seen) > 3 and np.array_equal(seen[-1], res.z)
    core = seen[:-1]
    repeats = [k for k in range(1, len(core)) if np.array_equal(core[k], core[k - 1])]
    assert not repeats, f"zeta called again at the same z at calls {repeats} of {len(core)}"
    assert complementarity(pb.A, pb.q, lambda z: pb.zeta(z).copy(), res.z) < 1e-9


@pytest.mark.parametrize("m, s", [(63, 0.004), (127, 0.001)])
def test_a_failing_operator_solve_returns_no_iterate_worse_than_its_start(m, s):
    """ζ = Bz + ψ with B = s·A strong (ζ′ ≈ s·h⁻²-scaled Laplacian): the operator path's first outer step
    S(ζ(0)) lies far from the answer and its iterates never get below the start's Res; the solve says it
    did not converge and returns the start (it returned Res 8.7e9 from Res(0) = 2.1)."""
    pb = scenes.obstacle_2d(m, exact=False)
    A = sp.csr_matrix(pb.A)
    B = sp.csr_matrix(s * A)
    psi = np.asarray(pb.zeta, dtype=float)
    zeta = lambda z: B @ z + psi   # noqa: E731
    start = float(np.linalg.norm(np.minimum(pb.q, -zeta(np.zeros(A.shape[0])))))   # Res(0), in numpy
    r = nrmicp.solve(A, pb.q, zeta, method="newton", tol=1e-8, zeta_jacobian=lambda z: spla.aslinearoperator(B))
    res = float(np.linalg.norm(np.minimum(A @ r.z + pb.q, r.z - zeta(r.z))))
    if r.status != nrmicp.Status.CONVERGED:
        assert res <= start * (1 + 1e-12), (r.status, r.nit, res, start)
        assert res < start or "returning the start" in r.message, r.message
        assert abs(r.residual - res) <= 1e-9 * max(res, 1.0), (r.residual, res)
    else:
        assert res < 1e-8
