"""The options of nrmicp.solve and nrmicp.Solver, from their one declaration: the C++ option table
(cpp/include/nrmicp/options.hpp, read through ``_core.option_table()``). Each option's name, kind,
scope ('setup': ``Solver(...)`` only; 'solve': a set-up default that each solve may override;
'call': each ``Solver.solve``'s own), default, range or choices and one-line doc come from there.
This module turns them into the Python layer's type checks, defaults and docstring lines;
tests/test_options.py holds the signatures and docstrings of solve and Solver to the table."""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Optional, Union

import numpy as np

from . import _core
from ._inputs import as_diagonal, as_float

#: Integer options are a C++ int.
_INT_MAX = 2**31 - 1
#: True/False mean on/off, as scikit-learn's verbose and scipy's disp: 1 and 0.
_BOOL_IS_INT = {"verbose"}
#: None (or False) means the default (accelerate's type is Optional[str]).
_NONE_IS_DEFAULT = {"accelerate"}
#: The kinds whose values are checked without knowing n.
_SCALAR_KINDS = ("real", "integer", "boolean", "choice")


@dataclass(frozen=True)
class Option:
    """One row of the option table, as nrmicp.solve's keyword sees it."""
    name: str
    kind: str        # 'real', 'integer', 'boolean', 'choice', 'diagonal' or 'python' (the Python layer's own)
    scope: str       # 'setup', 'solve' or 'call'
    default: Any
    core_default: Any   # the C++ field's (None: no field, or NaN: the method's default)
    choices: tuple
    low: float
    high: float
    low_open: bool
    high_open: bool
    finite: bool
    note: Optional[str]
    type: Optional[str]
    doc: str
    distributed: tuple   # the members that take it on PETSc (the C++ table's rule, detail::distributed_takes)
    distributed_why: Optional[str]   # why the others cannot

    def range_text(self) -> str:
        """What a number (or each diagonal entry) may be, as the docs write it: '> 0', 'in [0, 1)'."""
        fmt = (lambda v: str(int(v))) if self.kind == "integer" else (lambda v: f"{v:g}")
        if self.high < math.inf:
            return (f"in {'(' if self.low_open else '['}{fmt(self.low)}, {fmt(self.high)}"
                    f"{')' if self.high_open else ']'}")
        if self.low > -math.inf:
            return f"{'>' if self.low_open else '>='} {fmt(self.low)}"
        return ""

    def type_text(self) -> str:
        """The type as the docstring's parameter line writes it, with the range or the choices."""
        if self.kind == "python":
            return self.type
        if self.kind == "choice":
            return "{" + ", ".join(map(repr, choices(self.name))) + "}"
        word = {"real": "float", "integer": "int", "boolean": "bool", "diagonal": "float or array_like (n,)"}[self.kind]
        return f"{word} {self.range_text()}".rstrip()

    def header(self) -> str:
        """The docstring's parameter line: ``name : type, default value``."""
        return f"{self.name} : {self.type_text()}, default {self.default!r}"


def _read_table() -> dict[str, Option]:
    rows = [r for r in _core.option_table() if r.pop("python")]
    return {r["name"]: Option(**r) for r in rows}


#: The options of nrmicp.solve, in the order of its keywords (the C++-only rows left out).
TABLE = _read_table()


@functools.lru_cache(maxsize=None)   # (every solve asks: a few µs each)
def names(*scopes: str) -> tuple[str, ...]:
    """The options of these scopes (all when none is named), in the table's order."""
    return tuple(n for n, o in TABLE.items() if not scopes or o.scope in scopes)


def distributed_refusals(method: Optional[str] = None) -> dict[str, str]:
    """{name: why} of the options nrmicp.distributed cannot apply to `method` (None: to any member)."""
    return {n: o.distributed_why for n, o in TABLE.items() if (method not in o.distributed if method else not o.distributed)}


def defaults(*scopes: str) -> dict[str, Any]:
    """{name: default} of the options of these scopes (all when none is named)."""
    return {n: TABLE[n].default for n in names(*scopes)}


def pick(values: Mapping[str, Any], *scopes: str) -> dict[str, Any]:
    """{name: values[name]} for the options of these scopes (all when none is named): a function's
    ``locals()`` as its options."""
    return {n: values[n] for n in names(*scopes)}


@functools.lru_cache(maxsize=None)
def choices(name: str) -> tuple[str, ...]:
    """The values a choice option takes. A default outside the core's choices is the Python layer's
    own (method 'auto': _api.choose_method) and comes first."""
    opt = TABLE[name]
    own = (opt.default,) if isinstance(opt.default, str) and opt.default not in opt.choices else ()
    return own + opt.choices


def _choice(value, allowed, name):
    if not isinstance(value, str) or value.lower() not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(map(repr, allowed))}; got {value!r}")
    return value.lower()


def _scalar(value, name, *, low=None, low_inclusive=False, high=None, allow_none=False, integer=False):
    if value is None and allow_none:
        return None
    if integer and high is None:
        high = _INT_MAX
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a {'whole ' if integer else ''}number, got {value!r}")
    if not math.isfinite(as_float(value)):   # before int(): int(nan) and int(inf) raise unnamed
        raise ValueError(f"{name} must be finite, got {value!r}")
    if integer and int(value) != value:
        raise TypeError(f"{name} must be a whole number, got {value!r}")
    v = int(value) if integer else float(value)
    if low is not None and (v < low or (v == low and not low_inclusive)):
        raise ValueError(f"{name} must be {'>=' if low_inclusive else '>'} {low}, got {value!r}")
    if high is not None and v > high:
        raise ValueError(f"{name} must be <= {high}, got {value!r}")
    return v


def _boolean(value, name):
    if not (isinstance(value, (bool, np.bool_)) or (isinstance(value, (int, np.integer)) and value in (0, 1))):
        raise TypeError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def _converter(opt: Option):
    """convert(value, n) for one option of the core: what its field takes, type-checked."""
    name = opt.name
    if opt.kind == "real":
        none_is_nan = opt.core_default is None   # NaN: the method's default (alpha, beta)
        return lambda v, n: math.nan if v is None and none_is_nan else _scalar(v, name)
    if opt.kind == "integer":
        bool_ok = name in _BOOL_IS_INT
        return lambda v, n: _scalar(int(v) if bool_ok and isinstance(v, (bool, np.bool_)) else v, name, integer=True)
    if opt.kind == "boolean":
        return lambda v, n: _boolean(v, name)
    if opt.kind == "choice":
        enum, allowed = type(getattr(_core.Options(), name)), choices(name)
        if name in _NONE_IS_DEFAULT:   # (None, or False: the default)
            return lambda v, n: getattr(enum, _choice(v or opt.default, allowed, name))
        return lambda v, n: getattr(enum, _choice(v, allowed, name))
    return lambda v, n: as_diagonal(v, n, name, positive=opt.low_open)


#: The converter of each option of the core (the Python layer's own options have none).
_CONVERTERS = {n: _converter(o) for n, o in TABLE.items() if o.kind != "python"}


def convert(name: str, value: Any, n: Optional[int] = None) -> Any:
    """A value of an option of the core -> what its field takes, type-checked (TypeError/ValueError
    naming the option); the ranges are the core's to check (Options.check). Diagonals need n."""
    if name not in _CONVERTERS:
        raise TypeError(f"{name} is an option of the Python layer; the core has no field for it")
    return _CONVERTERS[name](value, n)


def fill(opts, values: Mapping[str, Any], n: Optional[int] = None):
    """Set the core options `opts` (Options or SolveOptions) from `values`, each converted; a diagonal
    given as None keeps its default (the method's)."""
    for name, value in values.items():
        v = _CONVERTERS[name](value, n)
        if v is not None:
            setattr(opts, name, v)
    return opts


def _is_default(opt: Option, value: Any) -> bool:
    if value is None or opt.default is None:
        return value is opt.default or (value is None and opt.name in _NONE_IS_DEFAULT)
    if isinstance(value, (bool, np.bool_)) != isinstance(opt.default, bool):
        return False   # True == 1, but verbose=True is not the default 0
    try:
        return bool(value == opt.default)
    except (TypeError, ValueError):   # an array compares entry by entry
        return False


def validate(values: Mapping[str, Any], *, where: str,
             unsupported: Union[Mapping[str, str], Iterable[str]] = ()) -> None:
    """Check the options that an entry point other than nrmicp.solve received (its name `where`, as
    ``'distributed.solve'``): each name is an option of the table (else TypeError naming it), each
    scalar value is of its option's type (as nrmicp.solve checks it), and none of `unsupported`
    (a set of names, or {name: why}) differs from its default: ValueError naming the option that
    cannot apply there, and why."""
    unknown = sorted(set(values) - set(TABLE))
    if unknown:
        raise TypeError(f"{where}() got unexpected keyword argument(s) {unknown}; its options are among "
                        f"nrmicp.solve's")
    why = unsupported if isinstance(unsupported, Mapping) else dict.fromkeys(unsupported, "")
    for name, value in values.items():
        opt = TABLE[name]
        if name in why and not _is_default(opt, value):
            reason = f" ({why[name]})" if why[name] else ""
            raise ValueError(f"{where} cannot apply option {name}={value!r}{reason}; leave it at its default "
                             f"{opt.default!r}, or use nrmicp.solve")
        if opt.kind in _SCALAR_KINDS and not _is_default(opt, value):   # (tol=None: the default, no number)
            convert(name, value)
