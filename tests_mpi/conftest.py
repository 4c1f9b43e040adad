"""Runs tests_mpi/cases.py under mpirun. MPI missing is a failure here, never a skip: these tests
exist to check the distributed part (make test installs it; README "Beyond one machine")."""
import json
import os
import shutil
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
#: The Python that runs under mpirun (make test points it at the environment holding petsc4py).
PYTHON = os.environ.get("NRMICP_MPI_PYTHON", sys.executable)
#: A deadlock fails the test instead of hanging the suite.
TIMEOUT = float(os.environ.get("NRMICP_MPI_TIMEOUT", "300"))


def mpirun(np_, *args, timeout=TIMEOUT):
    """Rank 0's JSON result of ``cases.py *args`` on np_ ranks; pytest.fail on a non-zero exit,
    a missing mpirun/petsc4py or a timeout."""
    launcher = shutil.which("mpirun") or shutil.which("mpiexec")
    if launcher is None:
        pytest.fail("mpirun not found: install Open MPI (make test does: README 'Beyond one machine')")
    cmd = [launcher, "-n", str(np_), "--oversubscribe"]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        cmd.append("--allow-run-as-root")
    env = dict(os.environ, OMPI_MCA_rmaps_base_oversubscribe="1", OPENBLAS_NUM_THREADS="1")
    cmd += ["-x", "OPENBLAS_NUM_THREADS", PYTHON, os.path.join(HERE, "cases.py"), *map(str, args)]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"{' '.join(cmd)} did not finish in {timeout} s (a deadlock?)\n{exc.stdout}\n{exc.stderr}")
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("RESULT ")]
    if out.returncode != 0 or not lines:
        pytest.fail(f"{' '.join(cmd)} failed (exit {out.returncode}):\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}")
    return json.loads(lines[-1][len("RESULT "):])
