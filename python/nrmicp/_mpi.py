"""Agreement between the ranks of a PETSc communicator, for nrmicp.distributed: one-float reductions,
and exceptions raised on some ranks only re-raised alike on every rank (no rank left waiting in a
collective call the failing ranks never reach)."""
from __future__ import annotations

import zlib

import numpy as np
from petsc4py import PETSc

from . import _core

#: Longest error message exchanged between ranks (bytes, UTF-8).
_MSG_LEN = 1024
#: Exception types re-raised as themselves on every rank; others become DistributedError.
_KNOWN = {e.__name__: e for e in (ValueError, TypeError, ZeroDivisionError, FloatingPointError,
                                  ArithmeticError, RuntimeError, KeyError, IndexError, MemoryError)}


class DistributedError(RuntimeError):
    """An exception of a type this module does not re-create, raised on one rank; every rank
    raises it with the original type's name and message."""


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
    first-hand, prefixed 'rank r: '); else returns. Collective: no rank is left waiting."""
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
    # (no local holds the new exception: a frame -> exception -> traceback -> frame cycle would leave this
    # frame, and what it holds, to each rank's cyclic garbage collector, at different times)
    raise (cls(f"rank {r}: {msg}") if cls else DistributedError(f"rank {r}: {name}: {msg}")) from exc


def collective(comm, fn, *args):
    """fn(*args) on every rank; an exception on any rank is raised on all (see agree)."""
    try:
        out, exc = fn(*args), None
    except Exception as e:  # noqa: BLE001 - re-raised on every rank by agree
        out, exc = None, e
    try:
        agree(comm, exc)
    finally:
        del exc   # (the caught exception's traceback holds this frame: no cycle through it)
    return out
