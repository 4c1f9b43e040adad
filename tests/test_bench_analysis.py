"""The bench's numbers without its figures: per-digit costs that cannot come out negative (and
say "noise" when the sweep is too short to tell), the CSV and summary written before plotting,
a clean finish without matplotlib, and the environment recorded with the numbers."""
from __future__ import annotations

import csv
import math
import os
import subprocess
import sys

import pytest

import nrmicp
from reference_impl import residual as reference_residual
from nrmicp.bench import family


def _row(tol, iterations, seconds, iteration_seconds):
    return dict(tol=tol, iterations=iterations, seconds=seconds, iteration_seconds=iteration_seconds,
                converged=1, reused_from_tol="")


def test_per_digit_is_iterations_per_digit_times_seconds_per_iteration():
    # wall times that fall with tol (per-call noise); iterations 10 per digit, 1 ms each except
    # for one run slowed down 5x (another process): the estimate keeps the undisturbed cost
    rows = [_row(1e-2, 20, 0.09, 0.020), _row(1e-4, 40, 0.05, 0.200), _row(1e-6, 60, 0.07, 0.060),
            _row(1e-8, 80, 0.03, 0.080)]
    spd, ipd = family.per_digit(rows)
    assert ipd == 10.0
    assert math.isclose(spd, 10 * 1e-3)


def test_per_digit_says_noise_when_the_runs_are_too_short_to_time():
    t = family.MIN_TIMED_SECONDS / 10
    rows = [_row(1e-2, 2, 1e-4, t / 4), _row(1e-4, 4, 0.5e-4, t / 2), _row(1e-6, 8, 0.8e-4, t)]
    spd, ipd = family.per_digit(rows)
    assert math.isnan(spd) and ipd == 1.5


@pytest.fixture(scope="module")
def quick_without_matplotlib(tmp_path_factory):
    """One `bench --quick` run without matplotlib, shared by the tests that read it."""
    code = "import sys; sys.modules['matplotlib'] = None; from nrmicp.bench.cli import main; sys.exit(main(sys.argv[1:]))"
    out = tmp_path_factory.mktemp("bench") / "out"
    proc = subprocess.run([sys.executable, "-c", code, "bench", "--family", "--quick", "--no-progress",
                           "--scenes", "bai_sym_icp,american_put", "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    return out, proc


def test_without_matplotlib_the_numbers_are_written_and_the_run_ends_cleanly(quick_without_matplotlib):
    out, proc = quick_without_matplotlib
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "pip install nrmicp[plot]" in proc.stdout
    assert {"work_precision.csv", "history.csv", "summary.txt"} <= set(os.listdir(out))
    assert not [f for f in os.listdir(out) if f.endswith(".png")]
    summary = (out / "summary.txt").read_text()
    assert "American put" in summary and "Bai" in summary


def test_summary_has_no_negative_cost_and_records_the_environment(quick_without_matplotlib):
    out, proc = quick_without_matplotlib
    assert proc.returncode == 0, proc.stderr
    env = family.environment()
    lines = (out / "summary.txt").read_text().splitlines()
    assert lines[0] == family.environment_line(env)
    for word in (f"nrmicp {nrmicp.__version__}", f"numpy {env['numpy']}", f"scipy {env['scipy']}", "cores"):
        assert word in lines[0]
    for line in lines:  # a case line: label, s/digit, it/digit, ...
        parts = line.split()
        if len(parts) > 4 and parts[1] == "/" and parts[0] != "method":
            spd = parts[3]
            assert spd in ("noise", "-") or float(spd) >= 0, line
            if parts[0] in ("newton", "nrmgs+polish"):  # not linear: no cost per digit
                assert spd == "-", line
    with open(out / "work_precision.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows
    for r in rows:
        assert {k: r[k] for k in family.ENV_COLUMNS} == {k: str(v) for k, v in env.items()}


def _known_lcp(n=40, seed=0):
    """A symmetric M-matrix LCP with a known solution: z* with zeros, w* = Az* + q complementary."""
    import numpy as np
    import scipy.sparse as sp

    rng = np.random.default_rng(seed)
    A = sp.diags([-np.ones(n - 1), 2.5 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr")
    z = np.where(rng.random(n) < 0.5, 0.0, rng.random(n) + 0.1)
    w = np.where(z > 0, 0.0, rng.random(n) + 0.1)
    return A, w - A @ z, z


def test_peers_solve_a_known_lcp_and_its_shifted_form():
    """Red-black PSOR and the QP solver against a known solution, through the shifted LCP
    y = z − c that the bench hands them (ζ ≡ c constant)."""
    import numpy as np

    from nrmicp.bench import peers
    from nrmicp.scenes import Problem

    A, q0, y_star = _known_lcp()
    c = np.linspace(-1.0, 1.0, A.shape[0])
    P = Problem(name="known", A=A, q=q0 - A @ c, zeta=c, z_exact=y_star + c)  # z = y + c
    assert peers.applicable("psor", P) == ""
    Ash, qsh, csh = peers.shifted_lcp(P)
    assert np.allclose(qsh, q0) and np.allclose(csh, c)
    colour = peers.colours(Ash)
    assert colour.max() == 1  # tridiagonal: red-black
    omega = peers.sor_omega(Ash)
    assert 1.0 <= omega < 2.0
    out = peers.psor(Ash, qsh, csh, 1e-10, omega=omega, colour=colour, maxiter=10_000, history=True)
    assert out["success"] and out["residual"] < 1e-10
    assert np.max(np.abs(out["z"] - P.z_exact)) < 1e-9
    assert reference_residual(P.A, P.q, out["z"], P.zeta) < 1e-10
    assert len(out["history"]["residual"]) == out["nit"] + 1
    installed = [name for name in peers.QP_SOLVERS if peers.installed(name)]
    assert installed, f"none of the QP peers {peers.QP_SOLVERS} is installed (make deps installs piqp)"
    for name in installed:
        o = peers.qp(name, Ash, qsh, csh, 1e-8)
        assert o["success"] and reference_residual(P.A, P.q, o["z"], P.zeta) < 1e-8, (name, o["status"])
        assert np.max(np.abs(o["z"] - P.z_exact)) < 1e-6


def test_peers_say_where_they_do_not_apply():
    from nrmicp import scenes
    from nrmicp.bench import peers

    assert "not constant" in peers.applicable("psor", scenes.bai(4, kind="icp"))
    assert "not symmetric" in peers.applicable("piqp", scenes.bai(4, symmetric=False, kind="lcp"))
    assert peers.applicable("piqp", scenes.bai(4, kind="lcp")) == ""


def test_a_missing_qp_solver_is_a_note_not_an_error(tmp_path):
    code = ("import sys; sys.modules['matplotlib'] = None; sys.modules['piqp'] = None; "
            "sys.modules['osqp'] = None; from nrmicp.bench.cli import main; sys.exit(main(sys.argv[1:]))")
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-c", code, "bench", "--family", "--quick", "--no-progress", "--scenes",
                           "obstacle_2d", "--methods", "nrmgs", "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "peer qp skipped: none of piqp, osqp is installed" in proc.stdout
    with open(out / "work_precision.csv", newline="") as f:
        methods = {r["method"] for r in csv.DictReader(f)}
    assert methods == {"nrmgs", "psor"}
