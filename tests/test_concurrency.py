"""Threads and signals: the C++ loop releases the GIL, gives thread-independent answers, and
stops on Ctrl-C (SIGINT -> KeyboardInterrupt). No clock in these tests: how promptly is measured
by benchmarks/gil_latency.py."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp


def laplacian(m):
    T = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
    I = sp.identity(m)
    return sp.csr_matrix(sp.kron(I, T) + sp.kron(T, I))


def problems():
    rng = np.random.default_rng(0)
    out = []
    for m, method, kind in ((20, "nrmgs", "lcp"), (24, "nrm", "icp"), (16, "two_sweep", "obstacle"),
                            (22, "nrmsor", "affine")):
        A = sp.csr_matrix(laplacian(m) + 0.5 * sp.identity(m * m))
        n = m * m
        q = rng.uniform(-1, 1, n)
        c = rng.uniform(-0.5, 0.5, n)
        zeta = {"lcp": None, "icp": (lambda z, c=c: 0.05 * np.sin(z) + c), "obstacle": c,
                "affine": nrmicp.Affine(sp.csr_matrix(0.05 * sp.eye(n, k=1)), c)}[kind]
        opts = dict(method=method, accelerate="anderson" if kind == "icp" else "none")
        if method == "nrmsor":
            opts["alpha"] = 1.2
        out.append((A, q, zeta, opts))
    return out


def test_threads_give_the_serial_answers():
    probs = problems()
    serial = [nrmicp.solve(A, q, zeta, **o) for A, q, zeta, o in probs]
    for workers in (2, 4):
        with ThreadPoolExecutor(workers) as pool:
            futures = [pool.submit(nrmicp.solve, A, q, zeta, **o) for A, q, zeta, o in probs * 2]
            results = [f.result() for f in futures]
        for r, s in zip(results, serial * 2):
            assert r.success and s.success
            np.testing.assert_array_equal(r.z, s.z)
            assert r.nit == s.nit


def test_one_solver_shared_by_threads():
    A, q, zeta, o = problems()[0]
    rng = np.random.default_rng(1)
    qs = [rng.uniform(-1, 1, A.shape[0]) for _ in range(6)]
    serial = [nrmicp.Solver(A, method="nrm").solve(qq, z_update="solve").z for qq in qs]
    # a fresh Solver: the threads race on the lazy factorization of A (z_update="solve")
    s = nrmicp.Solver(A, method="nrm")
    with ThreadPoolExecutor(3) as pool:
        par = list(pool.map(lambda qq: s.solve(qq, z_update="solve").z, qs))
    for a, b in zip(par, serial):
        np.testing.assert_array_equal(a, b)


#: A solve in the main thread of a subprocess that would run for hours (nrmj, unreachable tol, no
#: stall rule), with no callback and a Python ζ-free problem: once past its first iterate it
#: enters Python only at the Ctrl-C poll. Its k = 0 progress line (verbose = 10**6 s: no other
#: line before the end) tells a second thread that the loop is running; that thread then runs
#: Python code, which it can only do if the loop released the GIL, and sends SIGINT, which only
#: the loop's poll can turn into KeyboardInterrupt. No clock decides the outcome: with the GIL
#: held the script never gets past the second thread's first line (the timeout is a hang guard).
_GIL_AND_SIGINT_SCRIPT = """
import logging, os, signal, sys, threading
import numpy as np, scipy.sparse as sp, nrmicp
m = 150
T = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
I = sp.identity(m)
A = sp.csr_matrix(sp.kron(I, T) + sp.kron(T, I))
in_loop = threading.Event()

class FirstIterate(logging.Handler):
    def emit(self, record):
        if "iteration       0" in record.getMessage():
            in_loop.set()

log = logging.getLogger("nrmicp")
log.addHandler(FirstIterate())
log.setLevel(logging.INFO)

def other_thread():
    in_loop.wait()
    # the first iterate's report has returned: the main thread is in the C++ loop from here on
    print("python ran beside the loop:", sum(range(10)), flush=True)
    os.kill(os.getpid(), signal.SIGINT)

threading.Thread(target=other_thread, daemon=True).start()
try:
    nrmicp.solve(A, -np.ones(m * m), method="nrmj", tol=1e-300, maxiter=10**8, stall_iterations=10**6,
                 verbose=10**6)
except KeyboardInterrupt:
    print("KeyboardInterrupt out of the solve", flush=True)
    sys.exit(3)
print("finished", flush=True)
"""


@pytest.fixture(scope="module")
def gil_and_sigint(tmp_path_factory):
    script = tmp_path_factory.mktemp("gil") / "long_solve.py"
    script.write_text(_GIL_AND_SIGINT_SCRIPT)
    # (SIGINT's default action restored in the child: a background job of a non-interactive shell
    # inherits it ignored, and Python then never raises KeyboardInterrupt)
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED="1"),
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:  # ~1 s normally; with the GIL held the script never ends (the hang guard then fails the tests)
        out, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        err += "\n[the script hung: the second thread never ran, so the loop held the GIL]"
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT delivery differs on Windows")
def test_gil_is_released_during_the_solve(gil_and_sigint):
    """Another thread runs Python code while the solve is inside the C++ loop."""
    assert "python ran beside the loop: 45" in gil_and_sigint.stdout, gil_and_sigint.stderr


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT delivery differs on Windows")
def test_sigint_stops_a_long_solve(gil_and_sigint):
    """Ctrl-C reaches the loop's poll: KeyboardInterrupt out of nrmicp.solve, not the end of the solve."""
    proc = gil_and_sigint
    assert proc.returncode == 3, (proc.stdout, proc.stderr)
    assert "KeyboardInterrupt out of the solve" in proc.stdout
    assert "finished" not in proc.stdout
