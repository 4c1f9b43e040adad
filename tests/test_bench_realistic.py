"""`nrmicp bench` (the realistic-scene figure, run here at the registry's tiny sizes) and the
dispatch to the family sweep (`nrmicp bench --family`)."""
import csv
import subprocess
import sys

import numpy as np
import pytest

import nrmicp
import matplotlib  # noqa: F401  (required: a missing one fails, not skips)
import pyamg  # noqa: F401  (required: a missing one fails, not skips)
from nrmicp import scenes  # noqa: E402
from nrmicp.bench import realistic  # noqa: E402


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("realistic")
    proc = subprocess.run([sys.executable, "-m", "nrmicp", "bench", "--small", "--budget", "2", "--out", str(out)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"stdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    with open(out / "realistic.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    curves = {}
    for r in rows:
        curves.setdefault((r["scene"], r["curve"]), []).append((float(r["cpu_seconds"]), float(r["residual"])))
    return out, curves


def test_every_scene_has_the_curves_a_user_chooses_between(small_run):
    _, curves = small_run
    for scene in realistic.SCENES:
        for curve in ("newton-amg", "nrmgs+anderson", "nrmgs"):
            assert (scene, curve) in curves, (scene, curve)
        # the geometric hierarchy where the scene's grid has one (the march: its own default rule)
        has_geo = scene == "american_put" or realistic.build(scene, small=True).prolongations() is not None
        assert ((scene, "newton-geo") in curves) == has_geo, scene
    for scene in ("obstacle_2d", "obstacle_3d", "american_put"):  # LCPs: PSOR runs; not on the QVI
        assert (scene, "psor") in curves
    assert ("thermoforming_2d", "psor") not in curves
    # Newton on the whole ICP with ζ′ where the scene's ζ has one (the QVI), nowhere else
    assert [s for s in realistic.SCENES if (s, "newton-jac") in curves] == ["thermoforming_2d"]
    assert curves[("thermoforming_2d", "newton-jac")][-1][1] < 1e-8


def test_newton_curves_reach_the_target_and_the_times_are_cpu_seconds_from_the_call(small_run):
    _, curves = small_run
    for scene in realistic.SCENES:
        pts = curves[(scene, "newton-amg")]
        assert pts[-1][1] < 1e-8, (scene, pts)
        seconds = [s for s, _ in pts]
        assert all(s >= 0 for s in seconds)
        if scene != "american_put":  # one solve's iterates (the march: one march per tol)
            assert seconds == sorted(seconds)


def test_the_curves_match_an_independent_solve(small_run):
    """The last point of the nrmgs + Anderson curve on the 2D obstacle is Res of what nrmicp.solve
    returns for the same options, recomputed in numpy."""
    _, curves = small_run
    P = scenes.build("obstacle_2d", "tiny", exact=False)
    res = nrmicp.solve(P.A, P.q, P.zeta, method="nrmgs", accelerate="anderson", tol=realistic.TARGET,
                       maxiter=10**6)
    mine = float(np.linalg.norm(np.minimum(P.A @ res.z + P.q, res.z - P.zeta)))
    assert curves[("obstacle_2d", "nrmgs+anderson")][-1][1] == pytest.approx(mine, rel=1e-6, abs=1e-14)


def test_png_is_written(small_run):
    out, _ = small_run
    with open(out / "work_precision.png", "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"


def test_bench_help_names_the_realistic_scenes_and_family_the_sweep():
    plain = subprocess.run([sys.executable, "-m", "nrmicp", "bench", "--help"], capture_output=True, text=True,
                           timeout=60)
    family = subprocess.run([sys.executable, "-m", "nrmicp", "bench", "--family", "--help"], capture_output=True,
                            text=True, timeout=60)
    assert plain.returncode == family.returncode == 0
    assert "--budget" in plain.stdout and "--family" in plain.stdout
    assert "--methods" in family.stdout and "bench --family" in family.stdout


def test_unknown_scene_exits_nonzero(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "nrmicp", "bench", "--scenes", "nope", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and "nope" in proc.stderr


def test_plot_only_redraws_the_figure_from_the_csv(small_run, tmp_path):
    out, curves = small_run
    again = realistic.read_csv([str(out / "realistic.csv")])
    assert {(s, c) for s, (_, found) in again.items() for c in found} == set(curves)
    proc = subprocess.run([sys.executable, "-m", "nrmicp", "bench", "--plot", str(out / "realistic.csv"),
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "work_precision.png").stat().st_size > 10_000
