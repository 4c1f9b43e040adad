"""method="newton": agreement with the scenes' exact discrete solutions (policy iteration),
nesting, the fallback, flat step counts under refinement, honesty on the hard cases, polish,
and its options. Small sizes: seconds in all."""
from __future__ import annotations

import itertools
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from nrmicp.scenes.impulse import impulse_zeta_jacobian as impulse_jacobian  # noqa: F401 (also tests/golden, test_qvi_steps)
from reference_impl import residual as reference_residual, units_residual
from nrmicp import scenes
from nrmicp.scenes import solve_exact_obstacle

WARM_STEPS = nrmicp._core.newton_tuning["warm_steps"]

import test_hard_cases as hard


def err(res, problem):
    return float(np.abs(res.z - problem.z_exact).max())


SCENES = {
    "obstacle_1d": lambda: scenes.obstacle_1d(127),
    "obstacle_2d": lambda: scenes.obstacle_2d(31),
    "thermoforming_1d": lambda: scenes.thermoforming_1d(63),
    "american_put": lambda: scenes.american_put(n_space=256),
}


@pytest.mark.parametrize("hierarchy", [None, "amg", "grid"])
@pytest.mark.parametrize("name", list(SCENES))
def test_newton_agrees_with_the_exact_discrete_solution(name, hierarchy):
    problem = SCENES[name]()
    if hierarchy == "grid":
        hierarchy = problem.prolongations()
        assert hierarchy, f"{name} offers a geometric hierarchy"
    res = problem.solve(method="newton", hierarchy=hierarchy, tol=1e-10)
    assert res.success, res.message
    assert err(res, problem) < 1e-10
    assert res.residual == pytest.approx(problem.residual(res.z), rel=1e-6, abs=1e-13)
    assert len(res.level_steps) == len(res.level_seconds)
    if not isinstance(hierarchy, str):
        assert len(res.level_steps) == 1 + len(hierarchy or [])
    assert res.nit == res.level_steps[0] and res.linear_solves >= sum(res.level_steps)


def test_nesting_needs_fewer_finest_steps_than_a_cold_start():
    problem = scenes.obstacle_2d(63, exact=False)
    cold = problem.solve(method="newton", hierarchy=None)
    nested = problem.solve(method="newton", hierarchy="amg")
    assert cold.success and nested.success
    assert nested.nit <= 3 < cold.nit
    assert len(nested.level_steps) > 2 and nested.linear_solves > nested.nit


def test_the_projected_sweeps_after_each_step_cut_a_cold_starts_peeling():
    # a cold start moves the contact set's boundary about one grid layer per plain Newton step:
    # 12 -> 24 -> 49 steps at m = 31, 63, 127; with kSmoothingSweeps projected Gauss-Seidel sweeps
    # after each step (several layers each) 6 -> 9 -> 15
    steps = [scenes.obstacle_2d(m, exact=False).solve(method="newton", hierarchy=None).nit for m in (31, 63)]
    assert steps[1] <= 12 and steps[1] < 2 * steps[0], steps



@pytest.mark.parametrize("hierarchy", ["amg", "grid"])
def test_a_start_closer_than_a_cold_one_replaces_the_nested_one(hierarchy):
    # time stepping: the previous step's solution is the start and the hierarchy serves the inner
    # solves (no coarse level is solved); a start no closer than a cold one (by Res), or zeros, nests;
    # one whose active set is far off gives way to the nested start after warm_steps
    problem = scenes.obstacle_2d(63, exact=False)
    h = problem.prolongations() if hierarchy == "grid" else "amg"
    solver = nrmicp.Solver(problem.A, method="newton", hierarchy=h, tol=1e-10)
    nested = solver.solve(problem.q, zeta=problem.zeta)
    assert nested.success and any(nested.level_steps[1:])
    q_next = problem.q + 0.5          # the next time step's data: a load; the old solution moves by 0.009
    exact = solve_exact_obstacle(problem.A, q_next, problem.zeta)
    warm = solver.solve(q_next, zeta=problem.zeta, x0=nested.z)
    assert warm.success, warm.message
    assert not any(warm.level_steps[1:]) and 1 <= warm.linear_solves == warm.nit <= WARM_STEPS, warm.level_steps
    assert np.abs(warm.z - exact).max() < 1e-9
    assert warm.inner == nested.inner   # the V-cycle still preconditions
    for cold in (problem.zeta, problem.zeta - 1.0, problem.zeta + 1e-12, np.zeros(problem.n)):
        again = solver.solve(q_next, zeta=problem.zeta, x0=cold)
        assert again.success and any(again.level_steps[1:]) and again.nit <= 4, again.level_steps
        assert np.abs(again.z - exact).max() < 1e-9
    far = solver.solve(q_next, zeta=problem.zeta, x0=np.ones(problem.n))   # Res passes, the set is far off
    assert far.success and any(far.level_steps[1:]) and WARM_STEPS < far.nit <= WARM_STEPS + 4, far.level_steps
    assert np.abs(far.z - exact).max() < 1e-9



def test_a_warm_try_and_the_nested_run_that_spend_maxiter_return_the_better_iterate():
    # the start: the solution under an obstacle moved from x = 0.3 to 0.6 (its active set far off):
    # the warm try spends WARM_STEPS steps, the nested run the rest; the best of both is returned
    m = 127
    A = scenes.obstacle_2d(m, exact=False).A
    x = np.linspace(1, m, m) / (m + 1)
    X, Y = np.meshgrid(x, x)
    psi = [(0.2 - 4 * ((X - cx) ** 2 + (Y - 0.5) ** 2)).ravel() for cx in (0.3, 0.6)]
    q = 2.0 * np.ones(m * m)
    start = solve_exact_obstacle(A, q, psi[0])
    res = nrmicp.solve(A, q, zeta=psi[1], x0=start, method="newton", tol=1e-8, maxiter=WARM_STEPS + 1,
                       record_history=True)
    assert res.status == nrmicp.Status.MAX_ITERATIONS and res.nit == WARM_STEPS + 1
    best = min(res.history["residual"])
    assert res.residual == pytest.approx(best, rel=1e-9) and best < res.history["residual"][-1], res.history["residual"]
    assert reference_residual(A, q, res.z, psi[1]) == pytest.approx(res.residual, rel=1e-6)

@pytest.mark.parametrize("hierarchy", ["amg", "grid"])
def test_finest_step_count_is_flat_under_refinement(hierarchy):
    steps = []
    for m in (15, 31, 63):  # odd: the geometric hierarchy halves down to one node
        problem = scenes.obstacle_2d(m, exact=False)
        h = problem.prolongations() if hierarchy == "grid" else "amg"
        res = problem.solve(method="newton", hierarchy=h, tol=1e-10)
        assert res.success, res.message
        steps.append(res.nit)
    # flat: no size takes more than 1 step beyond the fewest of the smaller sizes (a cold start
    # grows, 3 -> 6 -> 9 here); fewer steps on a finer grid are no growth
    assert all(steps[i] <= min(steps[:i]) + 1 for i in range(1, len(steps))), steps
    assert max(steps) <= 3, steps


def test_thermoforming_outer_iteration_and_impulse_control_with_its_jacobian():
    problem = scenes.thermoforming_1d(63)
    res = problem.solve(method="newton", hierarchy="amg", tol=1e-10)
    assert res.success and err(res, problem) < 1e-10
    assert res.outer_iterations >= 2 and res.linear_solves <= 30
    problem = scenes.impulse_control(101)
    jacobian, calls = impulse_jacobian(problem), []
    res = nrmicp.solve(problem.A, problem.q, problem.zeta, method="newton", tol=1e-10,
                       zeta_jacobian=lambda z: calls.append(1) or jacobian(z))
    assert res.success, res.message
    assert err(res, problem) < 1e-10
    # policy iteration: a handful of linearizations (each step's outer obstacle solve has Newton
    # steps of its own, in nit), not the outer fixed point's hundreds
    assert len(calls) <= 8 and res.nit <= 30


def test_impulse_control_without_jacobian_converges_by_the_outer_iteration():
    # A regression: the outer fixed point warm-starts each inner obstacle solve with the previous
    # active set; on impulse control its steps were rejected and the solve ended STAGNATED at
    # Res 3.2 after 6 outer steps. A rejected guess must give way to the start's own active set.
    problem = scenes.impulse_control(101)
    res = nrmicp.solve(problem.A, problem.q, problem.zeta, method="newton", tol=1e-10)
    assert res.success, res.message
    assert err(res, problem) < 1e-9
    assert res.path == "newton" and res.outer_iterations >= 2


def test_affine_zeta_is_solved_on_the_full_system():
    import problems
    p = problems.make_affine_icp(8, symmetric=False)
    res = nrmicp.solve(p.A, p.q, nrmicp.Affine(p.zeta.B, p.zeta.c), method="newton", tol=1e-12)
    assert res.success and np.abs(res.z - p.z_star).max() < 1e-12
    assert res.path == "newton"



def test_affine_zeta_steps_are_swept_as_the_lcps_are():
    # From a start whose active set is 3 points off (the obstacle solution with psi = zeta(z1)), the
    # plain affine Newton path goes Res 0.12 -> 344 -> 560 -> ... -> 4e-11 in 8 steps: its second step
    # left the non-monotone window and the solve stagnated at 0.124 after 10 fallback sweeps. The
    # projected sweeps after each step (z_i >= (Bz)_i + c_i) keep the path inside it.
    m = 127
    A = scenes.obstacle_2d(m, exact=False).A
    n, x = m * m, np.linspace(1, m, m) / (m + 1)
    X, Y = np.meshgrid(x, x)
    psi1 = (0.2 - 4 * ((X - 0.4) ** 2 + (Y - 0.5) ** 2)).ravel()
    psi2 = (0.2 - 4 * ((X - 0.45) ** 2 + (Y - 0.5) ** 2)).ravel()
    q, B = 2.0 * np.ones(n), sp.csr_matrix(0.1 * sp.eye(n, k=1))
    z1 = solve_exact_obstacle(A, q, psi1)
    start = solve_exact_obstacle(A, q, B @ z1 + psi2)
    res = nrmicp.solve(A, q, zeta=nrmicp.Affine(B, psi2), x0=start, method="newton", hierarchy=None, tol=1e-8)
    assert res.success and res.path == "newton" and res.fallback_sweeps == 0, (res.message, res.nit)
    w, g = A @ res.z + q, res.z - (B @ res.z + psi2)   # the complementarity conditions themselves
    assert w.min() > -1e-8 and g.min() > -1e-12 and np.abs(np.minimum(w, g)).max() < 1e-8
    assert reference_residual(A, q, res.z, B @ res.z + psi2) < 1e-8

def test_nonsymmetric_m_matrix_upwind_convection_diffusion():
    problem = scenes.convection_diffusion_obstacle(31)
    for hierarchy in (None, "amg"):
        res = problem.solve(method="newton", hierarchy=hierarchy, tol=1e-10)
        assert res.success and err(res, problem) < 1e-10
        assert res.inner == "umfpack"  # nonsymmetric, n = 961: LU


# A P-matrix (not M, not H+) on which Newton's steps, each followed by its projected Gauss-Seidel
# sweeps, return to an active set seen before (found by search); its solution by enumeration.
CYCLING_3 = np.array([[1.0, -1.5, -2.5], [0.0, 1.5, -0.5], [3.0, -0.5, 1.5]])
CYCLING_3_Q = np.array([1.3, -0.1, -0.9])


def _lcp_by_enumeration(M, q):
    n = len(q)
    for pattern in itertools.product([False, True], repeat=n):
        free = np.array(pattern)
        z = np.zeros(n)
        z[free] = np.linalg.solve(M[np.ix_(free, free)], -q[free])
        if z.min() >= -1e-12 and (M @ z + q).min() >= -1e-12:
            return z
    raise AssertionError("no complementary point")


def test_p_matrix_where_the_newton_steps_cycle_takes_the_fallback():
    res = nrmicp.solve(sp.csr_matrix(CYCLING_3), CYCLING_3_Q, method="newton", hierarchy=None, tol=1e-12)
    assert res.success, res.message
    assert res.fallback_sweeps > 0 and res.path in ("newton+fallback", "fallback")
    assert np.abs(res.z - _lcp_by_enumeration(CYCLING_3, CYCLING_3_Q)).max() < 1e-10


def test_the_sweeps_after_each_step_break_the_plain_iterations_cycle():
    # the plain active-set iteration cycles on this scene (tests/test_scenes_newton.py); the
    # projected sweeps after the first step land on the solution's active set
    problem = scenes.p_matrix_cycling(4)
    res = problem.solve(method="newton", hierarchy=None, tol=1e-12)
    assert res.success, res.message
    assert err(res, problem) < 1e-10


def test_time_stepping_with_one_solver_american_put():
    price_exact, exact = scenes.american_put_price(100.0, n_space=256, n_time=20, method="exact", full_output=True)
    price, info = scenes.american_put_price(100.0, n_space=256, n_time=20, method="newton", full_output=True,
                                            tol=1e-10, hierarchy="amg")
    assert info["success"]
    assert np.abs(info["V"] - exact["V"]).max() < 1e-8
    assert info["nit"].mean() <= 3


HARD_CONFIGS = {"newton": dict(method="newton"), "newton+scale": dict(method="newton", scale="both")}


@pytest.mark.parametrize("config", list(HARD_CONFIGS))
@pytest.mark.parametrize("case", hard.CASES, ids=hard.CASE_IDS)
def test_hard_cases_end_in_success_or_an_honest_status(case, config):
    opts = dict(HARD_CONFIGS[config], **case.setup)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", nrmicp.ConversionWarning)
            res = nrmicp.solve(case.A, case.q, case.zeta, tol=hard.TOL, maxiter=3000, **opts)
    except (ValueError, np.linalg.LinAlgError) as exc:
        assert case.may_refuse, f"{case.name}/{config}: unexpected {type(exc).__name__}: {exc}"
        assert "omega2" in str(exc) or "singular" in str(exc)
        return
    hard.check_honest(case, config, res)
    assert res.path in ("newton", "newton+fallback", "fallback")
    if case.name in ("laplacian-cond1e+07-lcp", "convection-upwind-p10", "hplus-nonsym", "degenerate-lcp",
                     "badly-scaled-lcp", "near-singular", "explicit-zeros", "duplicate-entries"):
        assert res.success, f"{case.name}/{config}: {res.message}"


@pytest.mark.parametrize("zeta_kind", ["obstacle", "lcp", "callable"])
def test_polish_takes_a_member_stopped_at_1e6_to_rounding_level(zeta_kind):
    problem = scenes.obstacle_2d(31)
    zeta = {"obstacle": problem.zeta, "lcp": None, "callable": lambda z: problem.zeta}[zeta_kind]
    q = problem.q if zeta_kind != "lcp" else problem.q + problem.A @ problem.zeta  # the shifted LCP
    plain = nrmicp.solve(problem.A, q, zeta, method="nrmgs", accelerate="anderson", tol=1e-6)
    polished = nrmicp.solve(problem.A, q, zeta, method="nrmgs", accelerate="anderson", tol=1e-6, polish=True)
    assert plain.success and not hasattr(plain, "polished")
    assert polished.polished and polished.success
    assert plain.residual > 1e-8 and polished.residual < 1e-10  # from ~1e-6 to rounding level
    assert polished.residual == pytest.approx(reference_residual(problem.A, q, polished.z, zeta), rel=1e-6, abs=1e-14)


@pytest.mark.parametrize("rule", [{"rtol": 1e-4}, {"tol": 1e-3}])
def test_newton_polish_steps_under_any_target(rule):
    """Found by review: Newton::polish kept the set-up's rtol, a target its start already met, so polish=True
    took no step under rtol (or the default rule). Rows scaled apart, every row free at the answer: the
    first Newton step leaves z[2] 2% off within these targets; the polish takes it to rounding."""
    A = sp.csr_matrix([[3.847e4, 4.448e3, -1.297e4], [5.756e-4, 3.233e-3, 7.759e-4], [-1.770e-3, 8.182e-4, 7.021e-3]])
    q = np.array([-5.078e4, -4.652e-3, 1.064e-3])
    exact = np.linalg.solve(A.toarray(), -q)
    res = nrmicp.solve(A, q, method="newton", polish=True, **rule)
    assert res.success and res.polished, res.message
    np.testing.assert_allclose(res.z, exact, rtol=1e-12)


def test_polish_is_refused_when_it_does_not_help():
    A = sp.csr_matrix(np.array([[2.0]]))
    res = nrmicp.solve(A, np.array([-4.0]), method="nrmgs", polish=True)
    assert res.success and res.residual == 0 and res.polished is False


@pytest.mark.parametrize("kwargs, error, words", [
    (dict(method="newton", hierarchy="geometric"), ValueError, "hierarchy"),
    (dict(method="newton", hierarchy=42), TypeError, "hierarchy"),
    (dict(method="nrmgs", hierarchy="amg"), ValueError, "hierarchy"),
    (dict(method="newton", accelerate="anderson"), ValueError, "accelerate"),
    (dict(method="newton", phi=1.0), ValueError, "phi"),
    (dict(method="newton", z_update="solve"), ValueError, "z_update"),
    (dict(method="newton", alpha=1.2), ValueError, "alpha"),
    (dict(method="nrmgs", polish="yes"), TypeError, "polish"),
])
def test_bad_newton_options_are_refused_naming_them(kwargs, error, words):
    A = hard.lap2d(4)
    with pytest.raises(error, match=words):
        nrmicp.solve(A, -np.ones(16), **kwargs)


def test_zeta_jacobian_needs_newton_and_a_callable_zeta():
    A = hard.lap2d(4)
    with pytest.raises(ValueError, match="zeta_jacobian"):
        nrmicp.solve(A, -np.ones(16), None, method="newton", zeta_jacobian=lambda z: sp.identity(16))
    with pytest.raises(ValueError, match="zeta_jacobian"):
        nrmicp.solve(A, -np.ones(16), lambda z: 0 * z, method="nrmgs", zeta_jacobian=lambda z: sp.identity(16))


def test_newton_does_not_mutate_its_inputs():
    problem = scenes.obstacle_2d(15, exact=False)
    A, q, psi = problem.A.copy(), problem.q.copy(), problem.zeta.copy()
    Ps = problem.prolongations()
    Ps_copy = [P.copy() for P in Ps]
    nrmicp.solve(problem.A, problem.q, problem.zeta, method="newton", hierarchy=Ps)
    assert (abs(problem.A - A)).nnz == 0 and np.array_equal(problem.q, q) and np.array_equal(problem.zeta, psi)
    assert all((abs(P - Pc)).nnz == 0 for P, Pc in zip(Ps, Ps_copy))


def test_callback_sees_z_in_the_original_variables_and_can_stop_newton():
    problem = scenes.obstacle_2d(15)
    seen = []

    def callback(intermediate_result):
        # the default rule's measure, Res_E, recomputed in numpy
        seen.append((intermediate_result.nit, intermediate_result.residual,
                     units_residual(problem.A, problem.q, intermediate_result.z, problem.zeta)))
        if len(seen) == 3:
            raise StopIteration

    res = problem.solve(method="newton", hierarchy=None, callback=callback, record_history=True)
    assert res.status == nrmicp.Status.CALLBACK_STOP and not res.success
    assert len(seen) == 3
    for _, reported, recomputed in seen:  # the callback's z is z = y + ψ, with the Res it reports
        assert reported == pytest.approx(recomputed, rel=1e-8, abs=1e-12)
    assert len(res.history["residual"]) == 3


@pytest.mark.parametrize("zkind", ["none", "affine", "callable", "callable+jacobian"])
@pytest.mark.parametrize("scale", [2.0 ** 600, 2.0 ** -600])
def test_newton_res_neither_overflows_nor_underflows(zkind, scale):
    """Found by the fuzz test: Newton computed Res as a plain sqrt(sum m^2), which overflowed for
    |m| > ~1e154 — with a callable ζ this ended as 'zeta(z) returned non-finite values' though ζ
    only ever saw finite input and returned finite values — and underflowed to 0 below ~1e-154
    (a false success). Scaling A and q by a power of two leaves the solution exactly the same."""
    A = sp.csr_matrix(scenes.bai(3).A)
    n = A.shape[0]
    q = -np.ones(n)
    c = np.full(n, 0.1)
    B = sp.csr_matrix(0.1 * sp.eye(n))
    seen = []

    def zeta(z):
        seen.append(bool(np.isfinite(z).all()))
        return 0.05 * np.sin(z) + c

    extra = {}
    if zkind == "affine":
        zarg, zref = nrmicp.Affine(B, c), (lambda z: B @ z + c)
    elif zkind == "none":
        zarg, zref = None, (lambda z: 0 * z)
    else:
        zarg, zref = zeta, zeta
        if zkind == "callable+jacobian":
            extra["zeta_jacobian"] = lambda z: sp.diags(0.05 * np.cos(z), format="csr")
    ref = nrmicp.solve(A, q, zarg, method="newton", hierarchy=None, **extra)
    assert ref.success, ref.message
    res = nrmicp.solve(scale * A, scale * q, zarg, method="newton", hierarchy=None, tol=1e-8 * scale, **extra)
    assert res.success, res.message
    assert np.all(np.isfinite(res.z))
    m = np.minimum(scale * (A @ res.z + q), res.z - zref(res.z))
    big = np.abs(m).max()
    true_res = float(big * np.linalg.norm(m / big)) if big > 0 else 0.0
    assert true_res < 1e-8 * scale
    np.testing.assert_allclose(res.z, ref.z, rtol=1e-10, atol=1e-12)
    assert all(seen)


@pytest.mark.parametrize("zkind", ["obstacle", "affine", "callable+jacobian"])
def test_verbose_reports_every_newton_path_ending_with_the_result_message(zkind, caplog):
    """Every Newton path runs in the family's loop with its Monitor: progress lines from iterate 0
    on, the last one with the result's own message (before, the semismooth path printed nothing,
    and a settled active set printed the Monitor's generic 'stagnated' text)."""
    problem = scenes.obstacle_2d(15, exact=False)
    n, psi = problem.n, problem.zeta
    zero = sp.csr_matrix((n, n))
    zeta, extra = {"obstacle": (psi, {}), "affine": (nrmicp.Affine(zero, psi), {}),
                   "callable+jacobian": (lambda z: psi, {"zeta_jacobian": lambda z: zero})}[zkind]
    with caplog.at_level("INFO", logger="nrmicp"):
        res = nrmicp.solve(problem.A, problem.q, zeta, method="newton", hierarchy=None, tol=1e-300, verbose=1,
                           record_history=True, **extra)
    lines = [r.getMessage() for r in caplog.records if r.name == "nrmicp"]
    assert res.status == nrmicp.Status.STAGNATED and res.nit >= 2
    # (its first iterate: 0, or the semismooth loop's, numbered on from its start's steps as nit counts them)
    assert f"iteration {int(res.history['iteration'][0]):7d}" in lines[0]
    assert res.message.split(";")[0] in lines[-1]
    if zkind != "callable+jacobian":  # a repeated active set ends only the fixed-system paths
        assert "the active set has settled" in lines[-1]


def test_a_step_rejected_at_the_rounding_floor_ends_there_without_sweeps():
    # A constant ζ with its (zero) Jacobian, tol below what double precision resolves: the start, an
    # exact obstacle solve, is at the floor; its Newton step lost to rounding and was rejected, and the
    # fallback's sweeps ended STAGNATED "Res stopped decreasing" instead of at the floor
    problem = scenes.american_put(n_space=256, exact=False)
    psi, n = np.asarray(problem.zeta), problem.n
    res = nrmicp.solve(problem.A, problem.q, lambda z: psi, method="newton", tol=1e-16, hierarchy=None,
                       zeta_jacobian=lambda z: sp.csr_matrix((n, n)))
    assert res.status == nrmicp.Status.STAGNATED and "rounding floor" in res.message, res.message
    assert res.fallback_sweeps == 0
    w = problem.A @ res.z + problem.q
    assert np.linalg.norm(np.minimum(w, res.z - psi)) < 1e-9 * np.linalg.norm(problem.q)
