"""Type hints on the public API, and the py.typed marker that makes type checkers read them."""
from __future__ import annotations

import inspect
import typing
from importlib import resources

import pytest

import nrmicp

PUBLIC = [nrmicp.solve, nrmicp.Solver.__init__, nrmicp.Solver.solve, nrmicp.residual, nrmicp.backends,
          nrmicp.convergence_bound, nrmicp.Affine.__call__]


@pytest.mark.parametrize("fn", PUBLIC, ids=lambda f: f.__qualname__)
def test_every_parameter_and_return_is_annotated(fn):
    hints = typing.get_type_hints(fn)  # also checks that the annotations evaluate
    params = [p for p in inspect.signature(fn).parameters.values() if p.name != "self"]
    missing = [p.name for p in params if p.name not in hints]
    assert not missing, f"{fn.__qualname__}: no annotation for {missing}"
    assert "return" in hints


def test_py_typed_marker_ships_with_the_package():
    assert resources.files("nrmicp").joinpath("py.typed").is_file()
