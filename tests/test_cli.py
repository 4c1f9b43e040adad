"""The command line: --version, --help naming the command as typed, no arguments -> usage and a
non-zero exit, unknown commands rejected."""
from __future__ import annotations

import subprocess
import sys

import nrmicp
from nrmicp import scenes
from nrmicp.bench.cli import prog_name


def _run(*args, argv0=None):
    """``python -m nrmicp ARGS``, or the installed script simulated by setting sys.argv[0]."""
    if argv0 is None:
        cmd = [sys.executable, "-m", "nrmicp", *args]
    else:
        code = (f"import sys; sys.argv[0] = {argv0!r}; from nrmicp.bench.cli import main; sys.exit(main())")
        cmd = [sys.executable, "-c", code, *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def test_version():
    p = _run("--version")
    assert p.returncode == 0
    assert p.stdout.strip() == f"nrmicp {nrmicp.__version__}"


def test_no_arguments_prints_usage_and_fails():
    p = _run()
    assert p.returncode != 0
    assert p.stderr.startswith("usage: python -m nrmicp")
    assert "demo" in p.stderr and "bench" in p.stderr


def test_help_names_the_installed_command():
    p = _run("--help", argv0="/some/venv/bin/nrmicp")
    assert p.returncode == 0
    assert p.stdout.startswith("usage: nrmicp ")
    assert "python -m" not in p.stdout
    p = _run("bench", "--help", argv0="/some/venv/bin/nrmicp")
    assert p.returncode == 0 and p.stdout.startswith("usage: nrmicp bench ")


def test_help_under_python_m():
    p = _run("--help")
    assert p.returncode == 0 and p.stdout.startswith("usage: python -m nrmicp ")


def test_unknown_command_fails():
    p = _run("nope")
    assert p.returncode == 2 and "invalid choice" in p.stderr


def test_prog_name():
    assert prog_name("/usr/local/bin/nrmicp") == "nrmicp"
    assert prog_name("/x/site-packages/nrmicp/__main__.py") == "python -m nrmicp"


def test_demo_table_headers_say_what_each_column_is_with_units():
    """`nrmicp demo`'s columns: the seconds with their unit and clock, Result.inner named as such
    (the column was 'left solve' and 'seconds', issue 38)."""
    p = _run("demo", "--m", "4")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    headers = [line for line in lines if line.startswith("method ")]
    assert len(headers) == 2   # the LCP and the ICP table
    for header in headers:
        columns = [c.strip() for c in header.split("  ") if c.strip()]
        assert columns == ["method", "status", "iterations (nit)", "wall s", "Res", "max|z-z*|", "inner solver"]
    rows = [r for r in map(str.split, lines) if len(r) == 7 and r[0] in nrmicp.METHODS]
    assert len(rows) == 2 * len(nrmicp.METHODS)
    P = scenes.bai(4, kind="lcp")
    for method, row in zip(nrmicp.METHODS, rows):   # the LCP table's column is Result.inner
        assert row[-1] == nrmicp.solve(P.A, P.q, P.zeta, method=method, tol=1e-8).inner
    assert "left solve" not in p.stdout
