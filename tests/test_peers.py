"""nrmicp.bench.peers's shared pieces, which the bench and benchmarks/ (qp_peers.py, scipy_modulus.py)
use alike: the stopping rule, the QP eps tuning and PSOR's time limit. Time limits run on a fake
clock (peers.clock replaced), so no test depends on how fast the machine is."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from nrmicp.bench import peers


@pytest.mark.parametrize("res, k, expected", [
    (1e-9, 0, "converged"), (1e-9, 50, "converged"),  # converged wins over maxiter
    (np.inf, 3, "diverged"), (np.nan, 3, "diverged"),
    (1.0, 10, "max_iterations"), (1.0, 3, None)])
def test_verdict(res, k, expected):
    assert peers.verdict(res, 1e-8, k, 10) == expected


class FakeClock:
    """Each reading is `step` seconds after the previous one."""

    def __init__(self, step):
        self.now, self.step = 0.0, step

    def __call__(self):
        self.now += self.step
        return self.now


@pytest.fixture
def fake_clock(monkeypatch):
    def install(step):
        clock = FakeClock(step)
        monkeypatch.setattr(peers, "clock", clock)
        return clock
    return install


def test_verdict_time_limit(fake_clock):
    fake_clock(1.0)  # the verdict's reading is 1 s after t0 = 0
    assert peers.verdict(1.0, 1e-8, 0, 10, 0.0, time_limit=0.5) == "time_limit"
    assert peers.verdict(1.0, 1e-8, 0, 10, 0.0, time_limit=100.0) is None


def _lcp(n=6):
    """LCP(q, I) with solution y* = max(−q, 0)."""
    q = np.linspace(-1.0, 1.0, n)
    return sp.identity(n, format="csr"), q, np.maximum(-q, 0.0)


def test_tune_eps_tightens_until_res_below_tol():
    A, q, y_star = _lcp()
    # a "solver" whose error is eps itself: min(y* + eps + q, y* + eps) = eps, so Res = √6 eps
    run = lambda eps: (y_star + eps, "ok", 1)  # noqa: E731
    o = peers.tune_eps(run, A, q, 1e-6)
    assert o["reached"] and o["residual"] < 1e-6
    assert [e for e, _, _ in o["attempts"]] == pytest.approx([1e-6, 1e-7])  # √6·1e-6 > tol, √6·1e-7 < tol
    assert o["eps"] == pytest.approx(1e-7) and o["tuning_seconds"] >= o["seconds"]


def test_tune_eps_stops_at_eps_min_and_on_an_error():
    A, q, y_star = _lcp()
    o = peers.tune_eps(lambda eps: (y_star + 1.0, "stuck", 1), A, q, 1e-6, eps_min=1e-8)
    assert not o["reached"] and [e for e, _, _ in o["attempts"]] == pytest.approx([1e-6, 1e-7, 1e-8])

    def fails(eps):
        raise RuntimeError("boom")

    o = peers.tune_eps(fails, A, q, 1e-6)
    assert not o["reached"] and o["y"] is None and o["status"] == "error: boom" and len(o["attempts"]) == 1


def test_tune_eps_budget(fake_clock):
    A, q, y_star = _lcp()
    fake_clock(1.0)  # every attempt takes 1 s on this clock
    stuck = lambda eps: (y_star + 1.0, "stuck", 1)  # noqa: E731
    o = peers.tune_eps(stuck, A, q, 1e-6, time_budget=2.5)
    assert o["status"] == "stuck (tuning budget exhausted)" and len(o["attempts"]) == 3


def test_psor_time_limit_and_max_iterations(fake_clock):
    n = 400
    A = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr")  # slow
    q = -np.ones(n)
    colour = peers.colours(A)
    fake_clock(1.0)
    o = peers.psor(A, q, np.zeros(n), 1e-14, omega=1.0, colour=colour, maxiter=10**9, time_limit=20.0)
    assert o["status"] == "time_limit" and not o["success"] and 0 < o["nit"] < 20
    o = peers.psor(A, q, np.zeros(n), 1e-14, omega=1.0, colour=colour, maxiter=5)
    assert o["status"] == "max_iterations" and o["nit"] == 5


@pytest.mark.parametrize("m", [15, 40])
def test_sor_omega_is_the_closed_form_optimum_on_the_5_point_grid(m):
    # Jacobi on the 5-point Laplacian (consistently ordered): ρ_J = cos(π h), h = 1/(m + 1), so
    # ω_opt = 2 / (1 + sin(π h)) (Young). m = 40: n = 1,600, the LOBPCG + AMG path.
    from nrmicp.scenes._operators import neg_laplacian_2d
    A = neg_laplacian_2d(m)
    assert peers.sor_omega(A) == pytest.approx(2.0 / (1.0 + np.sin(np.pi / (m + 1))), rel=1e-7)
    assert peers.sor_omega(4.0 * A) == pytest.approx(peers.sor_omega(A), rel=1e-7)  # scale-free


def test_sor_omega_nonsymmetric_and_degenerate():
    n = 60  # an upwind tridiagonal: ARPACK's path; Jacobi's ρ = 2 √(ab) / d cos(π / (n + 1))
    A = sp.diags([np.full(n - 1, -1.5), np.full(n, 4.0), np.full(n - 1, -0.5)], [-1, 0, 1], format="csr")
    rho = 2 * np.sqrt(1.5 * 0.5) / 4.0 * np.cos(np.pi / (n + 1))
    # ARPACK on this non-normal J finds ρ to about 2% (random start; 0.4325-0.4408 against 0.4324 in
    # 10 runs), ω to about 0.3%
    assert peers.sor_omega(A) == pytest.approx(2.0 / (1.0 + np.sqrt(1.0 - rho ** 2)), rel=5e-3)
    assert peers.sor_omega(sp.diags(np.r_[np.ones(n - 1), 0.0], format="csr")) == 1.0  # a zero diagonal
