"""scipy.optimize's conventions, which users of nrmicp already know: ``res.x``, readable
status names, warnings attributed to the caller's line, and the callback rule
(``callback(intermediate_result)`` or ``callback(xk)``; StopIteration stops)."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from reference_impl import residual as reference_residual, units_residual
from nrmicp import scenes


def _lcp(m=6):
    P = scenes.bai(m)
    return P.A, P.q


def test_x_is_an_alias_of_z():
    A, q = _lcp()
    res = nrmicp.solve(A, q)
    assert res.x is res.z
    assert reference_residual(A, q, res.x) < 1e-8


@pytest.mark.parametrize("status", list(nrmicp.Status))
def test_status_prints_its_name(status):
    assert str(status) == status.name
    assert f"{status}" == status.name
    assert f"{status:>20}" == status.name.rjust(20)
    assert repr(status) == f"Status.{status.name}"
    assert f"{status:d}" == str(int(status)) and "%d" % status == str(int(status))
    assert status == int(status) and isinstance(status, int)  # still an IntEnum


def test_status_of_a_result_prints_converged():
    A, q = _lcp()
    assert str(nrmicp.solve(A, q).status) == "CONVERGED"


def test_conversion_warning_points_at_the_callers_line():
    A, q = _lcp()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        nrmicp.solve(A.tocsc(), q); line = _line()  # noqa: E702  (the warning's line)
    conv = [w for w in caught if issubclass(w.category, nrmicp.ConversionWarning)]
    assert conv, [str(w.message) for w in caught]
    for w in conv:
        assert w.filename == __file__, w.filename
        assert w.lineno == line


def test_conversion_warning_from_solver_points_at_the_callers_line():
    A, q = _lcp()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        nrmicp.Solver(A.toarray()); line = _line()  # noqa: E702
    conv = [w for w in caught if issubclass(w.category, nrmicp.ConversionWarning)]
    assert conv and all((w.filename, w.lineno) == (__file__, line) for w in conv)


def _line():
    """The line number of the caller's line."""
    import sys
    return sys._getframe(1).f_lineno


def test_callback_named_intermediate_result_gets_the_result():
    A, q = _lcp()
    seen = []

    def cb(intermediate_result):
        seen.append((intermediate_result.nit, intermediate_result.residual, intermediate_result.x.copy()))

    res = nrmicp.solve(A, q, callback=cb)
    assert [k for k, _, _ in seen] == list(range(len(seen)))
    assert res.success and len(seen) == res.nit + 1  # k = 0 .. nit, each once
    assert np.array_equal(seen[-1][2], res.z)  # the last call has result.z
    for _, r, x in seen:  # each is the iterate with its Res_E (the default rule's), recomputed in numpy
        assert units_residual(A, q, x) == pytest.approx(r, rel=1e-9, abs=1e-13)


@pytest.mark.parametrize("scale", [False, "both"])
def test_other_callbacks_get_the_iterate(scale):
    A, q = _lcp()
    iterates = []
    res = nrmicp.solve(A, q, callback=lambda xk: iterates.append(np.array(xk)), scale=scale)
    assert all(isinstance(x, np.ndarray) and x.shape == (A.shape[0],) for x in iterates)
    assert res.success and np.array_equal(iterates[-1], res.z)  # the last call has result.z
    if not scale:
        assert len(iterates) == res.nit + 1


def test_callback_with_another_parameter_name_gets_the_iterate():
    A, q = _lcp()
    got = []

    def cb(res):  # named 'res', not 'intermediate_result': scipy calls it with xk
        got.append(type(res))

    nrmicp.solve(A, q, callback=cb)
    assert got and all(t is np.ndarray for t in got)


@pytest.mark.parametrize("form", ["xk", "intermediate_result"])
def test_stop_iteration_stops(form):
    A, q = _lcp()
    calls = []

    def plain(xk):
        calls.append(1)
        if len(calls) == 3:
            raise StopIteration

    def named(intermediate_result):
        plain(intermediate_result.x)

    res = nrmicp.solve(A, q, tol=1e-300, callback=plain if form == "xk" else named)
    assert res.status == nrmicp.Status.CALLBACK_STOP and not res.success
    assert len(calls) == 3


def _path_with_a_decoupled_row(n=20):
    """The 1D path Laplacian with row 0 replaced by 3 e_0 (its column kept): the Newton member
    solves row 0 in closed form, z_0 = max(0, −q_0 / 3), and Newton on the other rows."""
    A = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="lil")
    A[0, :] = 0
    A[0, 0] = 3.0
    return sp.csr_matrix(A), -np.ones(n)


def test_intermediate_result_callback_gets_the_whole_iterate_with_decoupled_rows():
    A, q = _path_with_a_decoupled_row()
    seen = []
    res = nrmicp.solve(A, q, method="newton", callback=lambda intermediate_result: seen.append(intermediate_result))
    assert res.success and seen
    assert all(isinstance(r, nrmicp.Result) and r.x.shape == (A.shape[0],) for r in seen)
    assert all(r.z[0] == pytest.approx(1 / 3) for r in seen)   # the closed-form row, put back


def test_result_survives_pickling():
    import pickle
    A, q = _lcp()
    res = nrmicp.solve(A, q)
    back = pickle.loads(pickle.dumps(res))
    assert type(back) is nrmicp.Result and back.status is nrmicp.Status.CONVERGED
    assert np.array_equal(back.z, res.z) and repr(back) == repr(res)


def test_result_pickled_under_its_former_module_loads():
    import pickle
    A, q = _lcp()
    data = pickle.dumps(nrmicp.solve(A, q), protocol=0)
    assert b"cnrmicp\nResult\n" in data   # pickles name the public path
    old = data.replace(b"cnrmicp\nResult\n", b"cnrmicp._api\nResult\n")
    assert type(pickle.loads(old)) is nrmicp.Result
