"""nrmicp.backends(): which inner solvers the build has, and with why=True why one is missing."""
from __future__ import annotations

import sys
import types

import nrmicp
from nrmicp import _api


def test_backends_is_a_dict_of_bools_with_eigens_always_there():
    b = nrmicp.backends()
    assert set(b) == {"cholmod", "umfpack", "eigen_llt", "eigen_lu"}
    assert all(isinstance(v, bool) for v in b.values())
    assert b["eigen_llt"] and b["eigen_lu"]


def test_why_agrees_with_the_bools():
    have, why = nrmicp.backends(), nrmicp.backends(why=True)
    assert set(have) == set(why)
    for name, ok in have.items():
        assert (why[name] == "compiled in") == ok, (name, why[name])


def _fake_build(monkeypatch, have_cholmod, recorded):
    core = types.SimpleNamespace(backends=lambda: {"cholmod": have_cholmod, "umfpack": True,
                                                   "eigen_llt": True, "eigen_lu": True})
    monkeypatch.setattr(_api, "_core", core)
    info = types.ModuleType("nrmicp._build_info")
    info.BACKENDS = recorded
    monkeypatch.setitem(sys.modules, "nrmicp._build_info", info)


def test_a_backend_switched_off_says_disabled(monkeypatch):
    _fake_build(monkeypatch, False, {"cholmod": "disabled", "umfpack": "found"})
    why = nrmicp.backends(why=True)
    assert why["cholmod"] == "disabled at build time (NRMICP_USE_SUITESPARSE=OFF)"
    assert why["umfpack"] == "compiled in"
    assert nrmicp.backends()["cholmod"] is False


def test_a_backend_not_found_says_not_found(monkeypatch):
    _fake_build(monkeypatch, False, {"cholmod": "not found", "umfpack": "found"})
    assert nrmicp.backends(why=True)["cholmod"].startswith("not found at build time")
