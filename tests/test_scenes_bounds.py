"""The box scenes (issue 36): a two-sided membrane with a closed form (1D) and on a grid (2D),
elastic contact with scikit-fem (P1, P2: most unknowns free), a game put (two-sided, one step and
a march). Each answer is checked against what the scene is built to be, computed here: the closed
form at O(h²), a plain numpy primal–dual active-set reference with exact sparse solves (written
below, independent of nrmicp's core and of the scenes' own policy iteration), PIQP on a symmetric
case, the mixed complementarity conditions themselves, and a binomial tree for the game put.
Small sizes (n <= 16,512)."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import nrmicp
import nrmicp.scenes as scenes
import skfem  # noqa: F401  (a test dependency: a missing one fails, not skips)


def reference_box(A, q, lower, upper, maxiter=200):
    """Primal–dual active-set method for lower <= z <= upper, w = Az + q (PATH's signs): from
    x = z − w/diag(A), rows below lower are held there, rows above upper there, the others solve
    w = 0 — eliminated from the system (A_II z_I = −q_I − A_IF z_F), one spsolve per step."""
    A = sp.csr_matrix(A)
    n, d = A.shape[0], A.diagonal()
    lower = np.broadcast_to(np.asarray(lower, float), (n,))
    upper = np.full(n, np.inf) if upper is None else np.broadcast_to(np.asarray(upper, float), (n,))
    z, held = np.zeros(n), None
    for _ in range(maxiter):
        x = z - (A @ z + q) / d
        low, up = x < lower, x > upper
        if held is not None and np.array_equal(low, held[0]) and np.array_equal(up, held[1]):
            return z
        held = (low, up)
        z = np.where(low, lower, np.where(up, upper, 0.0))
        free = ~(low | up)
        rhs = -q[free] - A[free][:, ~free] @ z[~free]
        z[free] = spla.spsolve(sp.csc_matrix(A[free][:, free]), rhs)
    raise AssertionError("reference_box did not settle")


def mcp_violation(problem, z):
    """The largest violation of the box conditions at z, relative to the scale of w: z outside
    [lower, upper], w < 0 at the lower bound, w > 0 at the upper bound, w != 0 strictly between
    (rows within 1e-12 of a bound count as at it)."""
    lower = np.asarray(problem.zeta, float)
    upper = np.full(problem.n, np.inf) if problem.upper is None else problem.upper
    w = problem.A @ z + problem.q
    scale = np.abs(problem.q).max() + np.abs(problem.A @ z).max()
    span = 1e-12 * max(1.0, np.abs(z).max())
    at_low, at_up = z <= lower + span, z >= upper - span
    between = ~(at_low | at_up)
    zscale = max(1.0, np.abs(z).max())
    bad = [np.max(lower - z, initial=0.0) / zscale, np.max(z - upper, initial=0.0) / zscale,
           np.max(-w[at_low], initial=0.0) / scale, np.max(w[at_up], initial=0.0) / scale,
           np.max(np.abs(w[between]), initial=0.0) / scale]
    return max(bad)


def counts(problem, z):
    """(rows at lower, rows at upper, rows between) of z, from the scene's bounds."""
    lower = np.asarray(problem.zeta, float)
    upper = np.full(problem.n, np.inf) if problem.upper is None else problem.upper
    span = 1e-12 * max(1.0, np.abs(z).max())
    lo, up = z <= lower + span, z >= upper - span
    return int(lo.sum()), int(up.sum()), int((~(lo | up)).sum())


# ------------------------------------------------------------------ two-sided membrane, 1D

def test_two_sided_membrane_1d_closed_form_solves_the_continuous_problem():
    x = np.linspace(0.0, 1.0, 2001)
    u = scenes.two_sided.two_sided_membrane_1d_exact(x)
    h = x[1] - x[0]
    upp = (u[2:] - 2 * u[1:-1] + u[:-2]) / h**2            # exact on the quadratic pieces
    f = 16.0 * np.sign(0.5 - x[1:-1])
    assert abs(u[0]) < 1e-15 and abs(u[-1]) < 1e-15 and np.abs(u).max() <= 0.125 + 1e-15
    free = np.abs(np.abs(u[1:-1]) - 0.125) > 1e-9
    away = np.abs(x[1:-1] - 0.5) > 2 * h                    # f jumps at 1/2
    kink = np.min(np.abs(x[1:-1, None] - np.array([0.125, 0.375, 0.625, 0.875])), axis=1) > 2 * h
    assert np.abs(-upp - f)[free & away & kink].max() < 1e-8  # −u'' = f off the plates
    assert np.all(upp[~free & kink] == pytest.approx(0.0, abs=1e-8))
    assert np.abs(np.diff(u)).max() < 16.0 * h               # continuous, |u'| <= load·α = 2


def test_two_sided_membrane_1d_converges_at_second_order_to_the_closed_form():
    # n + 1 = 20·3^j: the free boundaries 1/8, 3/8, 5/8, 7/8 stay cell midpoints on every grid, so
    # the error constant is the same on each and the order is clean (measured ratios 6.9, 8.2, 8.7 -> 9)
    hs, errs = [], []
    for n in (19, 59, 179, 539):
        P = scenes.two_sided_membrane_1d(n, exact=False)
        res = P.solve()
        assert res.success, res.message
        ref = reference_box(P.A, P.q, P.zeta, P.upper)
        assert np.abs(res.z - ref).max() < 1e-10
        hs.append(P.reference["h"])
        errs.append(np.abs(res.z - P.reference["u_exact"]).max())
        x, h = P.reference["x"], P.reference["h"]
        (a, b), (c, d) = P.reference["contact_upper"], P.reference["contact_lower"]

        def inside(lo, hi):   # the nodes more than h inside an interval of the closed form
            return (x > lo + h) & (x < hi - h)
        assert np.all(res.active_mask[inside(a, b)] == 1) and np.all(res.active_mask[inside(c, d)] == -1)
        assert np.all(res.active_mask[inside(0, a) | inside(b, c) | inside(d, 1)] == 0)
    order = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert 1.85 <= order <= 2.15, (order, errs)


def test_two_sided_membrane_1d_rejects_a_gap_no_plate_reaches():
    with pytest.raises(ValueError, match="gap"):
        scenes.two_sided_membrane_1d(31, load=16.0, gap=0.6)


# ------------------------------------------------------------------ two-sided membrane, 2D

def test_two_sided_membrane_2d_touches_both_plates_and_matches_the_references():
    P = scenes.two_sided_membrane_2d(31)
    res = P.solve()
    assert res.success, res.message
    ref = reference_box(P.A, P.q, P.zeta, P.upper)
    assert np.abs(res.z - ref).max() < 1e-10
    assert np.abs(P.z_exact - ref).max() < 1e-10
    assert mcp_violation(P, res.z) < 1e-10
    lo, up, between = counts(P, ref)
    assert lo > 20 and up > 20 and between > P.n // 2, (lo, up, between)
    # upper plate on the left half (load up), lower on the right
    X = P.reference["x"]
    assert np.all(X[ref >= P.upper - 1e-12] < 0.5) and np.all(X[ref <= P.zeta + 1e-12] > 0.5)
    assert np.array_equal(res.active_mask, np.where(ref >= P.upper - 1e-12, 1, np.where(ref <= P.zeta + 1e-12, -1, 0)))


def test_two_sided_membrane_2d_agrees_with_piqp_on_the_box_qp():
    import piqp

    P = scenes.two_sided_membrane_2d(15)
    s = piqp.SparseSolver()
    s.settings.verbose = False
    s.settings.eps_abs = s.settings.eps_rel = 1e-12
    s.setup(sp.triu(P.A, format="csc"), P.q, x_l=P.zeta, x_u=P.upper)
    s.solve()
    res = P.solve()
    assert np.abs(res.z - np.asarray(s.result.x)).max() < 1e-8   # PIQP's interior point ends near the bounds (1.5e-10)


# ------------------------------------------------------------------ elastic contact

@pytest.mark.parametrize("element, r", [("P1", 4), ("P2", 3)])
def test_elastic_contact_matches_the_active_set_reference_with_free_unknowns(element, r):
    P = scenes.elastic_contact(element, r)
    contact = P.reference["contact"]
    assert np.isfinite(P.zeta).sum() == len(contact) and np.all(P.zeta[contact] <= 0)
    assert len(contact) < 0.05 * P.n                        # nearly every unknown is free
    res = P.solve(tol=1e-13)
    ref = reference_box(P.A, P.q, P.zeta, None)
    assert np.abs(res.z - ref).max() < 1e-10 * np.abs(ref).max()
    assert np.abs(P.z_exact - ref).max() < 1e-10 * np.abs(ref).max()
    assert mcp_violation(P, res.z) < 1e-10
    w = P.A @ ref + P.q
    touching = ref[contact] <= P.zeta[contact] + 1e-12
    # a contact patch, not the whole edge; the floor pushes up there and nowhere else
    assert 2 < touching.sum() < 0.5 * len(contact), touching.sum()
    assert w[contact][touching].min() > 0
    free = np.setdiff1d(np.arange(P.n), contact[touching])
    assert np.abs(w[free]).max() < 1e-10 * np.abs(w).max()
    assert np.array_equal(np.flatnonzero(res.active_mask == -1), contact[touching])


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_elastic_contact_mesh_hierarchy_interpolates_each_component_exactly(element):
    P = scenes.elastic_contact(element, 3, exact=False)
    Ps = P.prolongations()
    assert len(Ps) == 3 and Ps[0].shape[0] == P.n
    for fine, coarse in zip(range(3, 0, -1), range(2, -1, -1)):
        Pl = Ps[3 - fine]
        f = scenes.elastic_contact(element, fine, exact=False).reference
        c = scenes.elastic_contact(element, coarse, exact=False).reference
        assert Pl.shape == (len(f["x"]), len(c["x"]))
        # fields that vanish on the pushed top edge (y = 1), each component its own: linear ones for
        # both elements, a quadratic one (x(1 − y)) for P2
        for k, fx, fy in [(1, 1.0, 2.0)] + ([(2, 1.0, 0.0)] if element == "P2" else []):
            def field(ref):
                return (1.0 - ref["y"]) * np.where(ref["component"] == 0, fx, fy) * ref["x"] ** (k - 1)
            assert np.abs(Pl @ field(c) - field(f)).max() < 1e-12


def test_elastic_contact_sizes_are_the_documented_ones():
    for r in (2, 3):
        n1 = scenes.elastic_contact("P1", r, exact=False).n
        assert n1 == 2 * 2**r * (2 ** (r + 1) + 1)
        assert scenes.elastic_contact("P2", r - 1, exact=False).n == n1


# ------------------------------------------------------------------ game put

def test_game_put_step_exercises_below_and_cancels_at_the_strike():
    P = scenes.game_put(n_space=400)
    res = P.solve()
    assert res.success, res.message
    ref = reference_box(P.A, P.q, P.zeta, P.upper)
    assert np.abs(res.z - ref).max() < 1e-10 * P.reference["K"]
    assert np.abs(P.z_exact - ref).max() < 1e-10 * P.reference["K"]
    assert mcp_violation(P, res.z) < 1e-10
    S, K = P.reference["S"], P.reference["K"]
    exercised, cancelled = S[res.active_mask == -1], S[res.active_mask == 1]
    assert exercised.max() < K and np.all(np.diff(np.flatnonzero(res.active_mask == -1)) == 1)
    assert list(cancelled) == [K]        # a constant penalty: the issuer's region is the strike alone


def test_game_put_price_matches_a_binomial_tree_with_the_strike_on_its_lattice():
    # S0 puts K on the tree's lattice (ln(K/S0) = 74 σ√(T/N)): measured tree 11.17924 / 11.17920 /
    # 11.17920 at N = 5,000 / 20,000 / 80,000; the PDE 11.17871 / 11.17905 / 11.17916 at
    # (n_space, n_time) = (600, 100), (1200, 200), (2400, 400)
    S0 = 100.0 * np.exp(-74 * 0.2 * np.sqrt(1.0 / 20000))
    args = dict(S0=S0, K=100.0, r=0.05, sigma=0.2, T=1.0, penalty=5.0)
    tree = scenes.binomial_game_put(steps=20000, **args)
    price, info = scenes.game_put_price(S_max=300.0, n_space=1200, n_time=200, full_output=True, **args)
    assert info["success"]
    assert abs(price - tree) < 5e-4, (price, tree)
    exact = scenes.game_put_price(S_max=300.0, n_space=1200, n_time=200, method="exact", **args)
    assert abs(price - exact) < 1e-6
    american = scenes.american_put_price(S_max=300.0, n_space=1200, n_time=200, method="exact",
                                         **{k: v for k, v in args.items() if k != "penalty"})
    assert price < american - 0.01      # the issuer's option is worth something to the issuer


def test_game_put_rejects_a_non_positive_penalty():
    with pytest.raises(ValueError, match="penalty"):
        scenes.game_put(n_space=50, penalty=0.0)


# ------------------------------------------------------------------ the work-precision bench

def test_bench_sweeps_the_box_scenes_with_newton_and_honest_rows(tmp_path, capsys):
    import csv

    from nrmicp.bench import family

    scenes_ = ("two_sided_2d", "elastic_contact_p2", "game_put")
    assert family.main(["--quick", "--scenes", ",".join(scenes_), "--out", str(tmp_path), "--no-progress"]) == 0
    assert "only newton runs on the box scenes" in capsys.readouterr().out
    with open(tmp_path / "work_precision.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert {(r["scene"], r["method"]) for r in rows} == {(s, "newton") for s in scenes_}   # no peer, no member
    for r in rows:
        assert r["status"] == "converged" and float(r["residual"]) < float(r["tol"]), r
    r = min((r for r in rows if r["scene"] == "game_put"), key=lambda r: float(r["tol"]))
    P = scenes.build("game_put", "tiny")
    z = nrmicp.solve(P.A, P.q, P.zeta, upper=P.upper, tol=float(r["tol"])).z
    mid = np.minimum(z - P.zeta, np.maximum(z - P.upper, P.A @ z + P.q))    # recomputed here, PATH's Res
    assert np.linalg.norm(mid) == pytest.approx(float(r["residual"]), rel=1e-6, abs=1e-15)
    assert float(r["error"]) == pytest.approx(np.abs(z - reference_box(P.A, P.q, P.zeta, P.upper)).max(), abs=1e-14)
