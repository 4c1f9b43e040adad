"""Agreement between the ranks of a PETSc communicator, for nrmicp.distributed: one-float reductions,
exceptions raised on some ranks only re-raised alike on every rank (no rank left waiting in a
collective call the failing ranks never reach), and arguments that must agree refused by name when
they differ."""
from __future__ import annotations

import re
import zlib

import numpy as np
from petsc4py import PETSc

from . import _core, _options
from ._api import Affine
from ._hierarchy import Hierarchy

#: Longest error message exchanged between ranks (bytes, UTF-8).
_MSG_LEN = 1024
#: Exception types re-raised as themselves on every rank; others become DistributedError.
_KNOWN = {e.__name__: e for e in (ValueError, TypeError, ZeroDivisionError, FloatingPointError,
                                  ArithmeticError, RuntimeError, KeyError, IndexError, MemoryError,
                                  KeyboardInterrupt, SystemExit)}


class DistributedError(RuntimeError):
    """An exception of a type this module does not re-create, raised on one rank; every rank
    raises it with the original type's name and message."""


_KNOWN[DistributedError.__name__] = DistributedError


def flag_max(comm, value: float) -> float:
    """max over ranks of one float (a one-entry-per-rank Vec: PETSc's own allreduce)."""
    return _reduce(comm, value, lambda v: v.max()[1])


def flag_sum(comm, value: float) -> float:
    """sum over ranks of one float (as flag_max)."""
    return _reduce(comm, value, lambda v: v.sum())


def _reduce(comm, value: float, op) -> float:
    """op of the Vec holding each rank's `value` in its one entry."""
    v = PETSc.Vec().createMPI((1, PETSc.DECIDE), comm=comm)
    v.setValue(v.getOwnershipRange()[0], value)
    v.assemble()
    out = op(v)
    v.destroy()
    return out


def differing(comm, values: dict) -> list:
    """The keys of `values` (the same keys on every rank) whose values, as text, differ between ranks; every
    rank gets the same sorted list. Collective (one gather of a checksum a key)."""
    keys = sorted(values)
    sums = np.array([zlib.crc32(str(values[k]).encode("utf-8")) for k in keys], dtype=float)
    rows = _all_rows(comm, sums)
    return [k for j, k in enumerate(keys) if np.any(rows[:, j] != rows[0, j])]


def _all_rows(comm, local: np.ndarray) -> np.ndarray:
    """Every rank's `local` (the same length on each) as the rows of one array, on every rank (collective)."""
    v = PETSc.Vec().createMPI((len(local), PETSc.DECIDE), comm=comm)
    v.setArray(local)
    scatter, out = PETSc.Scatter.toAll(v)
    scatter.scatter(v, out, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
    rows = out.getArray().reshape(comm.getSize(), len(local)).copy()
    for obj in (scatter, out, v):   # destroyed here, on every rank together (not by a garbage collector)
        obj.destroy()
    return rows


def agree(comm, exc: BaseException | None) -> None:
    """Every rank calls this after a step that may fail on some ranks only. When any rank
    failed, every rank raises the same exception (type and message of the lowest rank that failed
    first-hand, prefixed 'rank r: ' unless it was agreed before); else returns. Collective: no rank is left waiting."""
    if not flag_max(comm, 0.0 if exc is None else 1.0):
        return
    buf = np.zeros(_MSG_LEN)
    if exc is not None:
        text = f"{type(exc).__name__}\x01{exc}".encode("utf-8")[: _MSG_LEN - 1]
        buf[: len(text)] = np.frombuffer(text, dtype=np.uint8)
    rows = _all_rows(comm, buf)   # (its Vecs destroyed there: the traceback keeps this frame)
    texts = {i: bytes(row[row > 0].astype(np.uint8)).decode("utf-8", "replace") for i, row in enumerate(rows) if row[0]}
    # the lowest rank that failed first-hand (the others' core says only that another rank refused its part)
    r = next((i for i, t in texts.items() if _core.refused_elsewhere not in t), min(texts))
    name, _, msg = texts[r].partition("\x01")
    cls = _KNOWN.get(name)
    if not (cls and re.match(r"rank \d+: ", msg)):   # (an agreed exception raised again keeps its rank)
        msg = f"rank {r}: {msg}" if cls else f"rank {r}: {name}: {msg}"
    # (no local holds the new exception: a frame -> exception -> traceback -> frame cycle would leave this
    # frame, and what it holds, to each rank's cyclic garbage collector, at different times)
    raise (cls or DistributedError)(msg) from exc


def collective(comm, fn, *args):
    """fn(*args) on every rank; an exception on any rank is raised on all (see agree)."""
    try:
        out, exc = fn(*args), None
    except BaseException as e:  # noqa: BLE001 - re-raised on every rank by agree (Ctrl-C, sys.exit on one rank too)
        out, exc = None, e
    try:
        agree(comm, exc)
    finally:
        del exc   # (the caught exception's traceback holds this frame: no cycle through it)
    return out


#: Arguments of each rank's own rows or code: whether they are given must agree between ranks, not their values.
_ROWS = {"x0", "callback", "zeta_jacobian"} | {n for n, o in _options.TABLE.items() if o.kind == "diagonal"}


def agree_arguments(comm, arguments: dict, where: str) -> None:
    """ValueError on every rank naming the arguments that differ between ranks (as _text reads them): every rank
    takes the branches they decide (else some would wait in a collective call the others never make)."""
    names = ", ".join(differing(comm, {k: _text(k, v) for k, v in arguments.items()}))
    _refuse(comm, names and ValueError(f"{where}: {names} must be the same on every rank (a number or string alike; "
                                       "an array, callable, zeta or upper given on every rank or none, of one kind), "
                                       "got different ones"))


def _text(name, value) -> str:
    """What every rank must pass alike of argument `name`: a number's or a string's value; whether a _ROWS one is
    given; what ζ or upper is (none, constant, affine, callable); else (arrays, hierarchies) its kind."""
    if value is None:
        return "none"
    if name in _ROWS:
        return "given"
    if name in ("zeta", "upper"):
        return "affine" if isinstance(value, Affine) else "callable" if callable(value) else "constant"
    if isinstance(value, str):
        return value.lower()
    if isinstance(value, (list, tuple, Hierarchy)):
        return "levels"   # (compared level by level by the caller)
    try:
        return type(value).__name__ if isinstance(value, PETSc.Object) or np.ndim(value) else float(value).hex()
    except (TypeError, ValueError, OverflowError):
        return type(value).__name__


def same(comm, value, error: type, message: str) -> None:
    """error(message) on every rank unless every rank holds this value (a kind of input, or its shapes)."""
    _refuse(comm, differing(comm, {"value": value}) and error(message))


def _refuse(comm, exc) -> None:
    """`exc` (unless falsy) raised on every rank, as any rank's failure is ('rank 0: ...'; collective)."""
    def check():
        if exc:
            raise exc
    collective(comm, check)


def deferred(hook, failed: list):
    """`hook` keeping its first exception in `failed`, not raising it (the core calls it on rank 0 only, between
    collectives; the caller raises it on every rank with agree once the core returns)."""
    def call(*args):
        if not failed:
            try:
                hook(*args)
            except BaseException as exc:  # noqa: BLE001 - raised on every rank once the core returns
                failed.append(exc)
    return call
