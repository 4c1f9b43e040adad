"""``Result.counters``: what a step kind counts beyond the iterations (the core's
Result::counters), e.g. ``anderson_rejections`` — accelerated steps replaced by the plain one."""
from __future__ import annotations

import numpy as np
import pytest

import nrmicp
from nrmicp import scenes


def test_counters_is_an_empty_dict_when_the_step_counts_nothing():
    P = scenes.bai(5)
    res = nrmicp.solve(P.A, P.q)
    assert res.counters == {}
    assert res["counters"] is res.counters  # an OptimizeResult field like the others
    assert "counters: {}" in repr(res)  # scipy's formatter alone fails on an empty dict


@pytest.mark.parametrize("method", ["nrmgs", "nrm", "two_sweep"])
def test_anderson_rejections_bound_the_non_decreasing_steps(method):
    """The safeguard replaces an accelerated step whose Res is not below the last one by the
    plain step, whose Res may or may not be lower; so every k >= 1 where the history's Res did not
    decrease was a rejection (a lower bound), and there are at most as many as iterations."""
    problem = scenes.obstacle_2d(16)
    res = problem.solve(method=method, accelerate="anderson", record_history=True, maxiter=3000, tol=1e-10)
    rejected = res.counters["anderson_rejections"]
    assert isinstance(rejected, int)
    r = res.history["residual"]
    not_decreasing = int(np.count_nonzero(r[1:] >= r[:-1]))
    assert not_decreasing <= rejected <= res.iterations
    assert rejected > 0  # this problem does reject (otherwise the bound above tests nothing)


def test_counters_are_summed_over_scaled_re_solves():
    problem = scenes.obstacle_2d(16)
    res = problem.solve(method="nrmgs", accelerate="anderson", scale="both", maxiter=3000)
    assert set(res.counters) == {"anderson_rejections"}
    assert 0 <= res.counters["anderson_rejections"] <= res.iterations


@pytest.mark.parametrize("scene,method,ratio,max_rejected", [
    ("obstacle_2d", "nrmgs", 0.3, 2),     # measured: 337 plain -> 77 with Anderson, 1 rejected
    ("bai_icp", "nrm", 0.4, 2),           # 173 -> 57, 1 rejected
    ("obstacle_2d", "two_sweep", 0.65, 100),  # 447 -> 257, 78 rejected
])
def test_anderson_accelerates(scene, method, ratio, max_rejected):
    """Iteration counts are deterministic: Anderson's speed-up is asserted, and the safeguard
    rejects few of its steps (a rejection counter equal to the iteration count would fail)."""
    problem = scenes.obstacle_2d(16) if scene == "obstacle_2d" else scenes.bai(16, kind="icp")
    plain = problem.solve(method=method, tol=1e-10, maxiter=3000)
    fast = problem.solve(method=method, accelerate="anderson", tol=1e-10, maxiter=3000)
    assert plain.success and fast.success, (plain.message, fast.message)
    assert fast.iterations <= ratio * plain.iterations, (plain.iterations, fast.iterations)
    assert fast.counters["anderson_rejections"] <= max_rejected


def test_anderson_m_changes_the_acceleration():
    """obstacle_2d(16), nrmgs: memory 2 -> 166 iterations, 5 (the default) -> 77, 10 -> 61."""
    problem = scenes.obstacle_2d(16)
    its = [problem.solve(method="nrmgs", accelerate="anderson", anderson_m=m, tol=1e-10, maxiter=3000).iterations
           for m in (2, 5, 10)]
    default = problem.solve(method="nrmgs", accelerate="anderson", tol=1e-10, maxiter=3000).iterations
    assert its[0] > its[1] > its[2] and default == its[1], its
