"""The bench's numbers without its figures: per-digit costs that cannot come out negative (and
say "noise" when the sweep is too short to tell), the CSV and summary written before plotting,
a clean finish without matplotlib, and the environment recorded with the numbers."""
from __future__ import annotations

import csv
import math
import os
import subprocess
import sys

import nrmicp
from nrmicp import bench


def _row(tol, iterations, seconds, iteration_seconds):
    return dict(tol=tol, iterations=iterations, seconds=seconds, iteration_seconds=iteration_seconds,
                converged=1, reused_from_tol="")


def test_per_digit_is_iterations_per_digit_times_seconds_per_iteration():
    # wall times that fall with tol (per-call noise); iterations 10 per digit, 1 ms each except
    # for one run slowed down 5x (another process): the estimate keeps the undisturbed cost
    rows = [_row(1e-2, 20, 0.09, 0.020), _row(1e-4, 40, 0.05, 0.200), _row(1e-6, 60, 0.07, 0.060),
            _row(1e-8, 80, 0.03, 0.080)]
    spd, ipd = bench.per_digit(rows)
    assert ipd == 10.0
    assert math.isclose(spd, 10 * 1e-3)


def test_per_digit_says_noise_when_the_runs_are_too_short_to_time():
    t = bench.MIN_TIMED_SECONDS / 10
    rows = [_row(1e-2, 2, 1e-4, t / 4), _row(1e-4, 4, 0.5e-4, t / 2), _row(1e-6, 8, 0.8e-4, t)]
    spd, ipd = bench.per_digit(rows)
    assert math.isnan(spd) and ipd == 1.5


def _quick(tmp_path, *, without_matplotlib):
    pre = "import sys; sys.modules['matplotlib'] = None; " if without_matplotlib else "import sys; "
    code = pre + "from nrmicp.__main__ import main; sys.exit(main(sys.argv[1:]))"
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-c", code, "bench", "--quick", "--no-progress",
                           "--scenes", "bai_sym_icp,american_put", "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    return out, proc


def test_without_matplotlib_the_numbers_are_written_and_the_run_ends_cleanly(tmp_path):
    out, proc = _quick(tmp_path, without_matplotlib=True)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "pip install nrmicp[plot]" in proc.stdout
    assert {"work_precision.csv", "history.csv", "summary.txt"} <= set(os.listdir(out))
    assert not [f for f in os.listdir(out) if f.endswith(".png")]
    summary = (out / "summary.txt").read_text()
    assert "American put" in summary and "Bai" in summary


def test_summary_has_no_negative_cost_and_records_the_environment(tmp_path):
    out, proc = _quick(tmp_path, without_matplotlib=True)
    assert proc.returncode == 0, proc.stderr
    env = bench.environment()
    lines = (out / "summary.txt").read_text().splitlines()
    assert lines[0] == bench.environment_line(env)
    for word in (f"nrmicp {nrmicp.__version__}", f"numpy {env['numpy']}", f"scipy {env['scipy']}", "cores"):
        assert word in lines[0]
    for line in lines:  # a case line: label, s/digit, it/digit, ...
        parts = line.split()
        if len(parts) > 4 and parts[1] == "/" and parts[0] != "method":
            spd = parts[3]
            assert spd == "noise" or float(spd) >= 0, line
    with open(out / "work_precision.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows
    for r in rows:
        assert {k: r[k] for k in bench.ENV_COLUMNS} == {k: str(v) for k, v in env.items()}
