"""What CI must have, asserted rather than skipped over: the SuiteSparse backends the README
advertises (a CMake that stops finding SuiteSparse would otherwise drop the CHOLMOD/UMFPACK
tests silently), pyamg (hierarchy='amg'), matplotlib (the bench's figures), a QP peer (the
bench's QP branches), and the example-database-free Hypothesis profile of conftest.py."""
import importlib

import hypothesis
import pytest

import nrmicp
from nrmicp.bench import peers


@pytest.mark.parametrize("backend", ["cholmod", "umfpack", "eigen_llt", "eigen_lu"])
def test_the_build_has_every_backend(backend):
    assert nrmicp.backends()[backend], nrmicp.backends(why=True)


@pytest.mark.parametrize("module", ["pyamg", "matplotlib", "hypothesis"])
def test_required_python_packages_import(module):
    importlib.import_module(module)


def test_a_qp_peer_is_installed():
    assert any(peers.installed(s) for s in peers.QP_SOLVERS), peers.QP_SOLVERS


def test_hypothesis_runs_derandomized_without_a_database():
    import os

    if os.environ.get("NRMICP_HYPOTHESIS", "ci") == "ci":
        assert hypothesis.settings.default.derandomize
    assert hypothesis.settings.default.database is None
