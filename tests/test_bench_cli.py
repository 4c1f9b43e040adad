"""The work-precision CLI (``python -m nrmicp bench``): it runs, writes the CSV with a row for
every (scene, method, z-update, tol), valid PNGs, and its 'converged' rows are honest —
checked against the tol of each row and, for one row, by re-solving the same case and
recomputing Res in numpy (``nrmicp.residual``). No timing is asserted."""
import csv
import subprocess
import sys

import numpy as np
import pytest

nrmicp = pytest.importorskip("nrmicp")
pytest.importorskip("matplotlib")
bench = pytest.importorskip("nrmicp.bench")

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EXPECTED_COLUMNS = {"scene", "size", "n", "method", "z_update", "z_update_used", "tol", "status", "converged",
                    "seconds", "setup_seconds", "factorization_seconds", "iteration_seconds", "iterations",
                    "residual", "error", "repeat", "reused_from_tol"}


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    proc = subprocess.run([sys.executable, "-m", "nrmicp", "bench", "--quick", "--out", str(out)],
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
    expected = {(s, m, z, t) for s in bench.DEFAULT_SCENES for m in bench.QUICK_METHODS for z in ("auto",)
                for t in bench.QUICK_TOLS}
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
    rows = [r for r in quick_run[3] if r["scene"] == scene and r["status"] == "converged"]
    assert rows
    r = min(rows, key=lambda r: float(r["tol"]))
    P = bench.build_scene(scene, r["size"])
    assert P.n == int(r["n"])
    res = nrmicp.solve(P.A, P.q, P.zeta, method=r["method"], tol=float(r["tol"]), z_update=r["z_update"])
    assert res.success
    assert int(res.nit) == int(r["iterations"])  # the iteration is deterministic
    res_np = nrmicp.residual(P.A, P.q, res.z, P.zeta)
    assert res_np < float(r["tol"])
    assert res_np == pytest.approx(float(r["residual"]), rel=1e-3, abs=1e-15)
    if P.z_exact is not None and r["error"]:
        assert np.max(np.abs(res.z - P.z_exact)) == pytest.approx(float(r["error"]), rel=1e-3, abs=1e-15)


def test_bad_arguments_exit_nonzero(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "nrmicp", "bench", "--quick", "--methods", "nope",
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert "nope" in proc.stderr
