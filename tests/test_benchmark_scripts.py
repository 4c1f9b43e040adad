"""The README's tables each name the one command that reproduces them: those scripts must run as
shipped. Each runs here on its smallest case (seconds; the tables' sizes belong in benchmarks) and
its output is checked for converged rows, not for timings."""
import json
import os
import re
import subprocess
import sys

import pytest

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def run(script, *args):
    out = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", script), *args], capture_output=True,
                         text=True, timeout=900, env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


def table_rows(text):
    """The markdown table's body rows, as lists of cells."""
    rows = [ln for ln in text.splitlines() if ln.startswith("|") and not ln.startswith("|---")]
    return [[c.strip() for c in ln.strip("|").split("|")] for ln in rows[1:]]


def test_mesh_independent_obstacle_table(tmp_path):
    # README "Mesh-independent solves": the obstacle table's command, on n = 961 (2D) and 29,791 (3D)
    out = tmp_path / "mi"
    run("mesh_independent.py", "--sections", "obstacle", "--dims", "2d", "3d", "--m", "31",
        "--peers", "newton-geo", "newton-amg", "psor", "nrmgs+aa", "--budget", "30", "--out", str(out))
    rows = table_rows(open(f"{out}.md", encoding="utf-8").read())
    assert [r[0] for r in rows] == ["obstacle_2d", "obstacle_3d"]
    for r in rows:
        # newton cells: "s, steps / solves, MB"; the others "s, iterations it, MB"
        assert all(re.match(r"[\d.]+ s, \d+ / \d+, \d+ MB$", c) for c in r[2:4]), r
        assert all(re.match(r"[\d.]+ s, \d+ it, \d+ MB$", c) for c in r[4:6]), r


def test_finite_elements_table():
    # README "Finite-element matrices": the command, on its quick P1 sizes (n = 8,065 and 32,513)
    text = run("finite_elements.py", "--quick", "--cases", "P1", "--budget", "30")
    rows = table_rows(text)
    assert [r[1] for r in rows] == ["8065", "32513"]
    for r in rows:
        assert all("st /" in c and "(" not in c for c in r[2:4]), r     # converged: no status in brackets
        assert all(re.match(r"[\d.]+ s, \d+ it, \d+ MB$", c) for c in r[4:6]), r


def test_other_matrices_table():
    # docs/finite_elements.md "Matrices no scene was tuned on": the command, on its quick sizes
    cases = ["Q1", "Q2", "tetP1", "tetP2", "materials", "aniso", "rotated", "graph", "plate"]
    text = run("finite_elements.py", "--quick", "--cases", *cases, "--peers", "newton-amg", "nrmgs+aa", "--budget", "30")
    rows = table_rows(text)
    assert [r[0].split()[0] for r in rows] == cases
    for r in rows:
        assert re.match(r"[\d.]+ s, \d+ st / \d+ sol, -?\d+ MB$", r[2]), r     # newton converged
        assert re.match(r"[\d.]+ s, \d+ it, -?\d+ MB$", r[3]), r


@pytest.mark.parametrize("scene", ["convection_2d", "convection_3d"])
def test_newton_inner_table(scene):
    # docs/MEASUREMENTS.md "Newton's inner solve": direct and Krylov inner solves reach the same Res target
    lines = [json.loads(ln) for ln in run("newton_inner.py", "--scene", scene, "--m", "15", "--inner",
                                          "umfpack", "cg").splitlines() if ln.startswith("{")]
    assert [ln["inner"] for ln in lines] == ["umfpack", "bicgstab"]
    assert all(ln["status"] == "CONVERGED" and ln["residual"] < 1e-8 for ln in lines), lines


def test_time_stepping_table():
    # README "Time stepping": the two-asset put march at n = 4,225 (hierarchy 'auto' = 'amg' from 1,000);
    # every peer converges and they agree on the value (the march's answer, not a timing)
    rows = table_rows(run("time_stepping.py", "--m", "65"))
    assert [r[1] for r in rows] == ["4,225"]
    values = [float(c.split("value ")[1]) for c in rows[0][2:]]
    assert len(values) == 3 and max(values) - min(values) < 1e-6, rows


def test_units_table():
    # docs/MEASUREMENTS.md "The default rule in three units": its command, on its quick sizes (n <= 2,000)
    text = run("units.py", "--quick")
    rows = table_rows(text.split("\n\n")[0])
    assert {r[0] for r in rows} >= {"README membrane", "Bai (mu = 4)"}
    for r in rows:
        if r[2].startswith("auto"):   # the defaults succeed in every unit, with the exact contact set
            assert r[3] == "ok / ok / ok" and r[5] == "same" and float(r[4]) < 1e-6, r
        if "ok" in r[3]:
            assert float(r[4]) < 1e-6 and r[5] == "same", r   # every success, in any unit, is one


def test_qvi_operator_table():
    # README "Quasi-variational inequalities": issue 37's table (benchmarks/qvi_operator.py) on its smallest sizes:
    # each scene with zeta' and without it converges to an answer numpy's complementarity check accepts
    rows = table_rows(run("qvi_operator.py", "--achp", "63", "--thermo2d", "15", "--impulse", "101", "--sin", "15"))
    assert [r[0] for r in rows] == ["ACHP 1D", "thermoforming_2d κ=2 δ=1", "impulse control", "ψ + 0.2 sin z"]
    for r in rows:
        assert 1 <= int(r[2]) <= 6 and 1 <= int(r[5]) <= 20, r   # Newton steps with zeta', outer steps without
        assert r[4].startswith("CONVERGED") and r[7].startswith("CONVERGED"), r
        assert float(r[8]) < 1e-8, r                              # numpy's check of both answers
        assert float(r[11]) >= 0 and float(r[12]) > 0 and float(r[13]) > 0, r   # obstacle CPU s, the ratios


def test_qvi_outer_table():
    # the thermoforming QVIs without a Jacobian (benchmarks/qvi_outer.py), on its smallest sizes
    rows = table_rows(run("qvi_outer.py", "--achp", "63", "--thermo2d", "15", "--obstacle"))
    assert [r[0] for r in rows] == ["ACHP-style 1D", "thermoforming_2d", "thermoforming_2d κ=2 δ=1",
                                    "thermoforming_2d κ=2 δ=1, hierarchy 'auto'"]
    for r in rows:
        assert r[5] == "CONVERGED" and float(r[7]) < 1e-8, r  # the numpy complementarity check
        assert float(r[9]) >= 0 and float(r[10]) > 0, r       # the frozen obstacle's CPU s, the ratio


def test_qvi_units_table():
    # a change of units on QVIs (benchmarks/qvi_units.py): every rule converges to numpy's reference
    rows = table_rows(run("qvi_units.py", "--thermo", "63", "--achp", "63", "--scales", "1e4"))
    assert [(r[0], r[2]) for r in rows] == [(p, rule) for p in ("thermoforming_1d", "ACHP-style 1D")
                                            for rule in ("default", "tol 1e-8", "default, s = 10000")]
    for r in rows:
        assert r[3] == "CONVERGED" and float(r[8]) < 1e-6, r  # the relative error against the reference


def test_bounds_table():
    # README "Bounds and free unknowns": the command, on its quick sizes (n <= 3,969) with the PIQP peer (vinewtonrsls needs
    # petsc4py's interpreter, --petsc-python); every solver meets the target, the box scenes converge
    text = run("bounds.py", "--quick", "--scenes", "membrane", "contact_p2", "--peers", "piqp")
    scaling, peers, contact = (table_rows(part) for part in text.split("\n\n")[1:6:2])
    assert [(r[0], r[1]) for r in scaling] == [("membrane", "961"), ("membrane", "3,969"), ("contact_p2", "272"),
                                              ("contact_p2", "1,056")]
    for r in scaling:
        assert re.match(r"\d+$", r[2]) and float(r[5]) < 1e-8, r        # converged: no status in brackets
    assert [r[0] for r in peers] == ["membrane", "contact_p2"]
    for r in peers:
        assert all(re.match(r"[\d.]+ s, \d+ (st|it)$", c) for c in r[2:4]) and r[4].endswith("x"), r
    assert [r[1] for r in contact] == ["272", "1,056"]
    for r in contact:
        assert all(re.match(r"[\d.]+ s, \d+ st$", r[k]) for k in (2, 3, 5, 7)) and r[4].endswith("x"), r


def test_hierarchy_reuse_table():
    # README's options ("a Hierarchy ... set-up"): the command on n = 961, both sides converged
    rows = table_rows(run("hierarchy_reuse.py", "--m", "31", "--repeat", "1"))
    assert [r[0] for r in rows] == ["961"] and "CONVERGED" in rows[0][-1], rows
