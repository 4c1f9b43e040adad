"""The work-precision CLI (``python -m nrmicp bench``): it runs, writes the CSV with a row for
every (scene, method, z-update, tol), valid PNGs, and its 'converged' rows are honest —
checked against the tol of each row and, for one row, by re-solving the same case and
recomputing Res in numpy (tests/reference_impl.residual). No timing is asserted."""
import csv
import subprocess
import sys

import numpy as np
import pytest

import matplotlib  # noqa: F401  (required for the PNGs: a missing one fails, not skips)

import nrmicp
from reference_impl import residual as reference_residual
from nrmicp import scenes
from nrmicp.bench import family

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EXPECTED_COLUMNS = {"scene", "size", "n", "method", "z_update", "z_update_used", "tol", "status", "converged",
                    "seconds", "setup_seconds", "factorization_seconds", "iteration_seconds", "iterations",
                    "residual", "error", "repeat", "reused_from_tol"}


def _installed_qp():
    """The QP peer of this machine: CI installs one (Makefile), so its branches always run."""
    from nrmicp.bench import peers

    qp = next((s for s in peers.QP_SOLVERS if peers.installed(s)), None)
    assert qp, f"none of the QP peers {peers.QP_SOLVERS} is installed (make deps installs piqp)"
    return qp


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    proc = subprocess.run([sys.executable, "-m", "nrmicp", "bench", "--family", "--quick", "--out", str(out)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"stdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    with open(out / "work_precision.csv", newline="") as f:
        reader = csv.DictReader(f)
        columns = set(reader.fieldnames)
        rows = list(reader)
    return out, proc, columns, rows


def test_csv_columns_and_one_row_per_case_and_tol(quick_run):
    _, _, columns, rows = quick_run
    assert EXPECTED_COLUMNS <= columns
    keys = [(r["scene"], r["method"], r["z_update"], float(r["tol"])) for r in rows]
    assert len(keys) == len(set(keys)), "duplicate (scene, method, z-update, tol) rows"
    expected = {(s, m, z, t) for s in family.DEFAULT_SCENES for m in family.QUICK_METHODS for z in ("auto",)
                for t in family.QUICK_TOLS}
    # the peers, on the scenes that are LCPs (ζ constant); the QP solver on the symmetric ones
    lcp = ("bai_sym_lcp", "bai_nonsym_lcp", "obstacle_2d", "american_put")
    expected |= {(s, "psor", "", t) for s in lcp for t in family.QUICK_TOLS}
    qp = _installed_qp()
    if qp:  # (always: _installed_qp asserts one)
        expected |= {(s, qp, "", t) for s in ("bai_sym_lcp", "obstacle_2d") for t in family.QUICK_TOLS}
    assert set(keys) == expected
    for r in rows:
        assert r["size"] == "tiny"
        assert r["status"] in {s.name.lower() for s in nrmicp.Status} or r["status"].startswith("error")


def test_pngs_exist_and_are_png(quick_run):
    out = quick_run[0]
    for name in ("work_precision.png", "work_precision_error.png", "convergence_history.png"):
        data = (out / name).read_bytes()
        assert len(data) > 1000, name
        assert data[:8] == PNG_SIGNATURE, name
    assert (out / "summary.txt").read_text().strip()


def test_converged_rows_meet_their_tol(quick_run):
    rows = quick_run[3]
    converged = [r for r in rows if r["status"] == "converged"]
    assert converged, "the quick sweep should converge somewhere"
    for r in converged:
        assert r["converged"] == "1"
        assert float(r["residual"]) < float(r["tol"]), r
    for r in rows:  # a row that did not converge is never reported as converged
        if r["status"] != "converged":
            assert r["converged"] == "0", r


@pytest.mark.parametrize("scene", ["bai_sym_icp", "obstacle_2d"])
def test_converged_row_reproduced_independently(quick_run, scene):
    """Re-solve one converged row's case and recompute Res in numpy."""
    rows = [r for r in quick_run[3] if r["scene"] == scene and r["status"] == "converged"
            and r["method"] in ("nrmgs", "nrmm")]
    assert rows
    r = min(rows, key=lambda r: float(r["tol"]))
    P = scenes.build(scene, r["size"])
    assert P.n == int(r["n"])
    res = nrmicp.solve(P.A, P.q, P.zeta, method=r["method"], tol=float(r["tol"]), z_update=r["z_update"])
    assert res.success
    assert int(res.nit) == int(r["iterations"])  # the iteration is deterministic
    res_np = reference_residual(P.A, P.q, res.z, P.zeta)
    assert res_np < float(r["tol"])
    assert res_np == pytest.approx(float(r["residual"]), rel=1e-3, abs=1e-15)
    if P.z_exact is not None and r["error"]:
        assert np.max(np.abs(res.z - P.z_exact)) == pytest.approx(float(r["error"]), rel=1e-3, abs=1e-15)


def test_bad_arguments_exit_nonzero(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "nrmicp", "bench", "--family", "--quick", "--methods", "nope",
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert "nope" in proc.stderr


def _rows(rows, scene, method):
    return sorted((r for r in rows if r["scene"] == scene and r["method"] == method), key=lambda r: -float(r["tol"]))


def test_newton_polish_and_the_peers_are_in_the_same_sweep(quick_run):
    """newton, nrmgs+polish, red-black PSOR and the QP solver each reach Res < 1e-8 on the obstacle,
    and their answers agree with the scene's exact discrete solution (policy iteration)."""
    _, proc, _, rows = quick_run
    methods = ["newton", "nrmgs+polish", "psor", _installed_qp()]
    for m in methods:
        rs = _rows(rows, "obstacle_2d", m)
        assert [float(r["tol"]) for r in rs] == list(family.QUICK_TOLS), m
        last = rs[-1]
        assert last["converged"] == "1" and float(last["residual"]) < 1e-8, last
        # Res < 1e-8 on this 8 x 8 grid bounds the error by ||A^-1|| Res < 1e-9
        assert float(last["error"]) < 1e-6, last
    assert "peer qp skipped" not in proc.stdout


def test_polish_reaches_rounding_level_where_its_member_stops_at_tol(quick_run):
    rows = quick_run[3]
    for scene in ("obstacle_2d", "bai_sym_lcp"):
        plain, polished = _rows(rows, scene, "nrmgs")[0], _rows(rows, scene, "nrmgs+polish")[0]
        assert float(plain["tol"]) == float(polished["tol"]) == 1e-2
        assert plain["iterations"] == polished["iterations"]  # the same member, then one Newton step
        assert float(plain["residual"]) > 1e-6
        assert float(polished["residual"]) < 1e-10


def test_newton_counts_newton_steps(quick_run):
    """For newton 'iterations' are Newton steps: few, and the same at every tol once the active set
    is found (Res then drops to rounding level in one step), and its history has those steps."""
    out, _, _, rows = quick_run
    rs = [r for r in _rows(rows, "obstacle_2d", "newton") if r["reused_from_tol"] == ""]
    its = [int(r["iterations"]) for r in rs]
    assert 1 <= max(its) <= 5 and len(set(its)) == 1, its  # measured: 3 steps at every tol on 8 x 8
    assert all(float(r["residual"]) < 1e-11 for r in rs)
    assert int(rs[-1]["linear_solves"]) >= its[-1]


@pytest.mark.parametrize("method", ["newton", "nrmgs+polish"])
def test_newton_and_polish_rows_reproduced_independently(quick_run, method):
    r = _rows(quick_run[3], "obstacle_2d", method)[-1]
    P = scenes.build("obstacle_2d", "tiny")
    base, kw = family.split_method(method)
    res = nrmicp.solve(P.A, P.q, P.zeta, method=base, tol=float(r["tol"]), **kw)
    assert int(res.nit) == int(r["iterations"])
    res_np = reference_residual(P.A, P.q, res.z, P.zeta)
    assert res_np < float(r["tol"])
    assert res_np == pytest.approx(float(r["residual"]), rel=1e-2, abs=1e-13)
