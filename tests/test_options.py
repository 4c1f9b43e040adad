"""Every option is declared once, in the C++ option table (options.hpp, read by nrmicp._options):
nrmicp.solve's and Solver's signatures, their defaults, the docstring's parameter lines and the
README's option list agree with it, and the checks follow its ranges. A new option added in one
place only fails here."""
from __future__ import annotations

import inspect
import math
import pathlib
import re

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from nrmicp import _options

TABLE = _options.TABLE
#: The problem, not options: solve's positional arguments and the bounds.
PROBLEM = ("A", "q", "zeta", "upper")


def keywords(fn, exclude=()):
    """{name: default} of fn's parameters, without self, **kwargs, private ones and `exclude`."""
    params = inspect.signature(fn).parameters.values()
    return {p.name: p.default for p in params
            if p.kind != p.VAR_KEYWORD and p.name != "self" and not p.name.startswith("_") and p.name not in exclude}


def same(a, b):
    return type(a) is type(b) and a == b


def test_solve_has_every_option_with_the_tables_default():
    kw = keywords(nrmicp.solve, exclude=PROBLEM)
    assert list(kw) == list(TABLE)   # the table is in the order of solve's keywords
    wrong = {n: (v, TABLE[n].default) for n, v in kw.items() if not same(v, TABLE[n].default)}
    assert not wrong, wrong


def test_solver_takes_the_set_up_and_per_solve_options_with_the_tables_defaults():
    kw = keywords(nrmicp.Solver.__init__, exclude=("A",))
    assert set(kw) == set(_options.names("setup", "solve"))
    assert all(same(v, TABLE[n].default) for n, v in kw.items())


def test_solver_solve_takes_the_per_call_options_and_overrides_the_per_solve_ones():
    kw = keywords(nrmicp.Solver.solve, exclude=("q",) + PROBLEM)
    assert set(kw) == set(_options.names("call"))
    assert all(same(v, TABLE[n].default) for n, v in kw.items())
    A = sp.csr_matrix(np.diag([2.0, 3.0]))
    s = nrmicp.Solver(A, method="nrmgs")
    for name in _options.names("solve"):   # each accepted at its default ...
        assert s.solve(np.array([-1.0, 1.0]), **{name: TABLE[name].default}).success, name
    for name in _options.names("setup"):   # ... and each set-up option refused, the call naming it
        with pytest.raises(TypeError, match=name):
            s.solve(np.array([-1.0, 1.0]), **{name: TABLE[name].default})


def docstring_parameters(doc):
    """{name: 'type, default ...'} of the numpydoc lines 'name : ...' (or 'a, b : ...') of Parameters."""
    section = doc.split("Parameters\n    ----------\n", 1)[1].split("Returns\n", 1)[0]
    out = {}
    for names, rest in re.findall(r"^    (\w+(?:, \w+)*) : (.*)$", section, flags=re.M):
        for name in names.split(", "):
            assert name not in out, f"{name} documented twice"
            out[name] = rest
    return out


def test_solve_docstring_documents_each_option_by_the_tables_line():
    documented = docstring_parameters(nrmicp.solve.__doc__)
    assert set(documented) - set(PROBLEM) == set(TABLE)
    wrong = {n: (documented[n], TABLE[n].header().split(" : ", 1)[1]) for n in TABLE
             if f"{n} : {documented[n]}" != TABLE[n].header()}
    assert not wrong, wrong   # (name: (the docstring's, the table's))


def test_solver_docstring_lists_the_set_up_and_per_solve_options():
    doc = " ".join(nrmicp.Solver.__doc__.split())
    setup = re.search(r"the set-up options of :func:`solve` \(([^)]*)\)", doc).group(1).split(", ")
    per_solve = re.search(r"defaults for the iteration options \(([^)]*)\)", doc).group(1).split(", ")
    assert setup == list(_options.names("setup"))
    assert per_solve == list(_options.names("solve"))


def test_readme_options_section_names_every_option():
    readme = (pathlib.Path(__file__).parents[1] / "README.md").read_text()
    section = readme.split("## Options", 1)[1].split("\n## ", 1)[0]
    missing = [n for n in TABLE if f"`{n}`" not in section]
    assert not missing, missing


def outside(opt):
    """A number just outside opt's range (its low bound itself when open)."""
    if opt.high < math.inf:
        return opt.high + 1
    return opt.low if opt.low_open else opt.low - 1


RANGED = [n for n, o in TABLE.items() if o.kind in ("real", "integer") and o.low > -math.inf and n != "theta"]


@pytest.mark.parametrize("name", RANGED)
def test_a_number_outside_its_range_is_refused_naming_the_option_and_the_range(name):
    opt = TABLE[name]
    A, q = sp.csr_matrix(np.diag([2.0, 3.0])), np.array([-1.0, 1.0])
    kw = {name: outside(opt)}
    with pytest.raises(ValueError, match=rf"{name} must (be|lie in) .*{re.escape(opt.range_text().split()[-1])}"):
        nrmicp.solve(A, q, method="nrmgs", **kw)


def test_theta_range_and_its_member():
    A, q = sp.csr_matrix(np.diag([2.0, 3.0])), np.array([-1.0, 1.0])
    with pytest.raises(ValueError, match=r"theta must lie in \(0, 2\]"):
        nrmicp.solve(A, q, method="two_sweep", theta=2.5)
    assert nrmicp.solve(A, q, method="two_sweep", theta=2.0).success


@pytest.mark.parametrize("name", [n for n, o in TABLE.items() if o.kind == "choice"])
def test_a_choice_outside_the_table_is_refused_listing_the_choices(name):
    with pytest.raises(ValueError, match=rf"{name} must be one of {re.escape(repr(_options.choices(name)[0]))}"):
        nrmicp.solve(sp.identity(2, format="csr"), -np.ones(2), **{name: "no-such-choice"})


def test_validate_names_an_option_that_cannot_apply():
    why = {"accelerate": "the distributed members take no Anderson steps", "callback": "no per-iterate hook"}
    _options.validate({"tol": 1e-8, "accelerate": "none", "callback": None}, where="distributed.solve",
                      unsupported=why)   # defaults pass
    with pytest.raises(ValueError, match=r"distributed.solve cannot apply option accelerate='anderson' "
                                         r"\(the distributed members take no Anderson steps\)"):
        _options.validate({"accelerate": "anderson"}, where="distributed.solve", unsupported=why)
    with pytest.raises(ValueError, match="callback"):
        _options.validate({"callback": print}, where="distributed.solve", unsupported=why)
    with pytest.raises(ValueError, match="verbose=True"):   # True == 1, not the default 0
        _options.validate({"verbose": True}, where="distributed.solve", unsupported={"verbose"})


def test_validate_refuses_unknown_names_and_wrong_types():
    with pytest.raises(TypeError, match=r"distributed.solve\(\) got unexpected keyword argument\(s\) \['tolerance'\]"):
        _options.validate({"tolerance": 1e-8}, where="distributed.solve")
    with pytest.raises(TypeError, match="maxiter must be a whole number"):
        _options.validate({"maxiter": 2.5}, where="distributed.solve")
    with pytest.raises(ValueError, match="z_update must be one of"):
        _options.validate({"z_update": "implicit"}, where="distributed.solve")


def test_validate_takes_an_option_given_as_its_default_none():
    # tol=None and rtol=None are nrmicp.solve's defaults (the default rule), not numbers to check
    _options.validate({"tol": None, "rtol": None, "accelerate": None}, where="distributed.solve")
    with pytest.raises(TypeError, match="tol must be a number"):
        _options.validate({"tol": "1e-8"}, where="distributed.solve")


def test_the_distributed_refusals_are_the_tables_and_the_core_applies_them_on_a_distributed_engine():
    # the table's column (OptionSpec::distributed): what nrmicp.distributed refuses for each kind of member
    assert set(_options.distributed_refusals("newton")) == {"scale", "components", "inner"}
    assert set(_options.distributed_refusals("nrmgs")) == {"scale", "components", "polish"}
    assert set(_options.distributed_refusals()) == {"scale", "components"}
    assert all(_options.distributed_refusals("newton").values())   # each says why
    o = nrmicp._core.Options()
    o.method, o.inner = nrmicp._core.Method.newton, nrmicp._core.Inner.cg
    o.check(4)   # the serial engine takes it
    with pytest.raises(ValueError, match="inner cannot apply to method 'newton' on a distributed engine"):
        o.check(4, serial_engine=False)
    o.method = nrmicp._core.Method.nrm   # the stationary members take it on every engine
    o.check(4, serial_engine=False)
