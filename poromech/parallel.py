"""Errors under MPI: the same exception on every rank, so that every rank ends the same way.

A run under ``mpirun`` must print each error once and end every rank with the documented exit
status, without leaving a rank waiting in a collective call for a partner that has given up.
Two helpers cover the two ways an error can arise:

* :func:`on_root` runs a function on rank 0 only (file system, gmsh, ...) and broadcasts its
  result *or its exception*, so every rank returns the same value or raises the same error;
* :func:`agree` ends a step in which every rank checked its own data (e.g. its own cells): the
  first error found (lowest check index, then lowest rank) is raised on every rank.

An error that escapes both (a bug, a library raising on one rank) is raised on some ranks only;
:func:`all_ranks_failed` tells the ranks that hit it whether the others did too, so that they
skip the collective calls of their clean-up (which the others would never join) and abort.

Errors that every rank detects identically by itself (a scene file read on every rank) need
neither. Both helpers are collective.
"""

from __future__ import annotations

import pickle
import time
from collections.abc import Callable
from typing import Any

from mpi4py import MPI

__all__ = ["AGREE_TIMEOUT", "agree", "all_ranks_failed", "error_comm", "on_root"]

#: Seconds the ranks that hit an unexpected error wait for the others to report the same (an
#: error on all ranks ends cleanly; on some ranks only, the others never arrive).
AGREE_TIMEOUT = 5.0
_ERROR_COMMS: dict = {}


def error_comm(comm: MPI.Comm) -> MPI.Comm:
    """A duplicate of ``comm`` used only to find out whether an error hit every rank.

    Collective the first time for a communicator: create it where every rank passes (the start
    of a run), not when an error is already on some ranks only.
    """
    key = comm.py2f()
    if key not in _ERROR_COMMS:
        _ERROR_COMMS[key] = comm.Dup()
    return _ERROR_COMMS[key]


def all_ranks_failed(comm: MPI.Comm) -> bool:
    """Whether every rank reaches this point within :data:`AGREE_TIMEOUT` seconds.

    Called by the ranks an exception reached; True at once on one rank.
    """
    if comm.size == 1:
        return True
    request = error_comm(comm).Ibarrier()
    deadline = time.monotonic() + AGREE_TIMEOUT
    while time.monotonic() < deadline:
        if request.Test():
            return True
        time.sleep(0.01)
    return False


def _portable(err: BaseException) -> BaseException:
    """The exception itself if it survives pickling, else a RuntimeError with its message."""
    try:
        pickle.loads(pickle.dumps(err))
    except Exception:
        return RuntimeError(f"{type(err).__name__}: {err}")
    return err


def on_root[T](comm: MPI.Comm, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """Call ``fn(*args, **kwargs)`` on rank 0 and give every rank its result (collective).

    Returns:
        The value returned on rank 0 (broadcast; it must be picklable).

    Raises:
        Exception: The exception ``fn`` raised on rank 0, raised on every rank (a RuntimeError
            with the same message when it cannot be pickled).
    """
    outcome: tuple[bool, Any] | None = None
    if comm.rank == 0:
        try:
            outcome = (True, fn(*args, **kwargs))
        except Exception as err:
            outcome = (False, _portable(err))
        except SystemExit as stop:  # a library that exits must not leave the other ranks waiting
            outcome = (False, RuntimeError(f"{fn.__name__} exited (status {stop.code})"))
        try:
            pickle.dumps(outcome)
        except Exception as err:
            outcome = (False, RuntimeError(f"result of {fn.__name__} cannot be sent: {err}"))
    ok, value = comm.bcast(outcome, root=0)
    if not ok:
        raise value
    return value


def agree(comm: MPI.Comm, error: Exception | None, index: int = 0) -> None:
    """Raise on every rank the first error any rank found, or return when none did (collective).

    Args:
        comm: Communicator.
        error: The error this rank found, or None.
        index: Order of the failed check on this rank (a lower index wins, then a lower rank), so
            that the error reported does not depend on the partition when several ranks fail.

    Raises:
        Exception: The chosen error, on every rank.
    """
    mine = None if error is None else (index, comm.rank, _portable(error))
    found = [e for e in comm.allgather(mine) if e is not None]
    if found:
        raise min(found, key=lambda e: (e[0], e[1]))[2]
