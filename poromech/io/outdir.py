"""The output directory of a run: checked before meshing, locked for the run, no stale outputs.

:func:`output_directory` is the context manager around a run (collective; the file system is
touched on rank 0 only and its errors reach every rank through :func:`poromech.parallel.on_root`):

1. the path is checked (not a file, not below a file) and created, and a file is written in it,
   so that a read-only or full directory is reported before meshing;
2. a lock (``fcntl.flock`` on :data:`LOCK_NAME`) is taken and held by rank 0 until the run ends:
   a second run into the same directory is refused with one line naming the first (its pid and
   host), instead of failing on an HDF5 lock after meshing and overwriting ``summary.json``;
3. files of an earlier run (those matching :data:`OWNED_OUTPUTS`) are refused unless
   ``overwrite`` is set, in which case they are removed first, so that no stale file (an old
   ``displacement_steps/`` of a longer run, ...) mixes with the new ones. Nothing else in the
   directory is touched. A restart that continues a run in its own directory passes
   ``clear=False`` (lock only).

Every refusal is an :class:`OutputDirError` (exit status 2, like an invalid argument: nothing has
been run).
"""

from __future__ import annotations

import contextlib
import fcntl
import fnmatch
import os
import shutil
import socket
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from mpi4py import MPI

from poromech.parallel import on_root
from poromech.scene.checks import check_name

__all__ = [
    "LOCK_NAME",
    "OWNED_OUTPUTS",
    "OutputDirError",
    "check_output_path",
    "clear_outputs",
    "default_output_dir",
    "output_directory",
    "owned_outputs",
]

#: Names (glob patterns) of the files and directories a run writes: these, and only these, are
#: removed by ``--overwrite`` (with their temporary ``.<name>.part``). Patterns carry their
#: extension, so that a user's ``fractures_paper.pdf`` next to the outputs survives. Writers of
#: new outputs add their pattern here.
OWNED_OUTPUTS: tuple[str, ...] = (
    "displacement*.xdmf", "displacement*.h5", "displacement*.bp", "displacement*_steps",
    "fractures*.xdmf", "fractures*.h5", "fractures*.csv", "fractures*_steps",
    "flow*.xdmf", "flow*.h5", "flow*_steps",
    "probe_*.csv",
    "summary.json",
    "checkpoint*",
    "poromech_scene.yaml",
    "plots",
)

#: The lock file held by the running process (never removed, never an output).
LOCK_NAME = ".poromech.lock"

#: Directory under which runs without ``-o`` write, as ``results/<scene name>``.
RESULTS = Path("results")

class OutputDirError(RuntimeError):
    """An output directory that cannot be used; the message is one line."""


def default_output_dir(scene_name: str, root: Path = RESULTS) -> Path:
    """``results/<scene name>``, refused when the name would lead elsewhere.

    Raises:
        ConfigError: The name is empty, ``..``, absolute or has a path separator (the scene
            loader refuses such names already; scenes built in code are checked here).
    """
    check_name("name", scene_name)
    return root / scene_name


def _is_owned(name: str) -> bool:
    """True for a run output, or the temporary ``.<name>.part`` of one."""
    if name.startswith(".") and name.endswith(".part"):
        name = name[1:-5]
    return any(fnmatch.fnmatchcase(name, p) for p in OWNED_OUTPUTS)


#: Outputs whose name a user's own folder may have too: a run's only next to its ``summary.json``.
_GENERIC_OUTPUTS = ("plots",)


def owned_outputs(path: Path) -> list[Path]:
    """The entries of ``path`` that a run writes (sorted; empty when ``path`` does not exist).

    ``plots`` (written by ``poromech plot``) counts only in the folder of a run, one with a
    ``summary.json``: a user's own ``plots`` folder elsewhere is not poromech's to remove.
    """
    path = Path(path)
    if not path.is_dir():
        return []
    run = (path / "summary.json").is_file()
    return sorted(p for p in path.iterdir() if _is_owned(p.name)
                  and (run or p.name not in _GENERIC_OUTPUTS))


def clear_outputs(path: Path) -> list[Path]:
    """Remove the run outputs of ``path`` (files and step directories); return them (local)."""
    removed = owned_outputs(path)
    for p in removed:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink()
    return removed


def check_output_path(path: Path) -> None:
    """Check that ``path`` is, or can become, a directory (local, no side effect).

    Raises:
        OutputDirError: ``path`` is a file, or lies below one.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputDirError(f"output directory '{path}' is a file, not a directory")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputDirError(f"output directory '{path}' lies below the file '{parent}'")
            break


def _create_writable(path: Path) -> None:
    """Create ``path`` and prove it writable by writing a file in it."""
    check_output_path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputDirError(f"output directory '{path}' cannot be created: "
                             f"{err.strerror or err}") from None
    try:
        with tempfile.TemporaryFile(dir=path) as fh:
            fh.write(b"poromech")
    except OSError as err:
        raise OutputDirError(f"output directory '{path}' is not writable: "
                             f"{err.strerror or err}") from None


def _lock(path: Path):
    """Open and lock ``path/LOCK_NAME`` (non-blocking); return the open file."""
    try:
        fh = open(path / LOCK_NAME, "a+")
    except OSError as err:
        raise OutputDirError(f"output directory '{path}' is not writable: "
                             f"{err.strerror or err}") from None
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.seek(0)
        holder = fh.read().strip() or "unknown process"
        fh.close()
        raise OutputDirError(f"output directory '{path}' is in use by another poromech run "
                             f"({holder}): wait for it to end or choose another -o") from None
    try:
        fh.seek(0)
        fh.truncate()
        fh.write(f"pid {os.getpid()} on {socket.gethostname()}, since "
                 f"{time.strftime('%Y-%m-%d %H:%M:%S')}\n")
        fh.flush()
    except OSError as err:
        fh.close()
        raise OutputDirError(f"output directory '{path}' is not writable: "
                             f"{err.strerror or err}") from None
    return fh


def _stale_message(path: Path, stale: list[Path]) -> str:
    names = ", ".join(p.name + ("/" if p.is_dir() else "") for p in stale[:4])
    more = f" and {len(stale) - 4} more" if len(stale) > 4 else ""
    return (f"output directory '{path}' holds outputs of an earlier run ({names}{more}): "
            "pass --overwrite to replace them, or choose another -o")


def _prepare(path: Path, overwrite: bool, clear: bool, held: list) -> None:
    """Rank 0: create, check, lock, and clear or refuse earlier outputs."""
    _create_writable(path)
    fh = _lock(path)
    try:
        stale = owned_outputs(path) if clear else []
        if stale and not overwrite:
            raise OutputDirError(_stale_message(path, stale))
        if stale:
            try:
                clear_outputs(path)
            except OSError as err:
                raise OutputDirError(f"output directory '{path}': cannot remove "
                                     f"'{err.filename}' of an earlier run: "
                                     f"{err.strerror or err}") from None
    except BaseException:
        fh.close()
        raise
    held.append(fh)


@contextlib.contextmanager
def output_directory(path: Path, comm: MPI.Comm = MPI.COMM_WORLD, overwrite: bool = False,
                     clear: bool = True) -> Iterator[Path]:
    """Check, create and lock an output directory for the duration of a run (collective).

    Args:
        path: The output directory.
        comm: Communicator of the run; rank 0 touches the file system and holds the lock.
        overwrite: Remove the outputs of an earlier run (:data:`OWNED_OUTPUTS`) instead of
            refusing the directory.
        clear: False to keep earlier outputs without asking (a restart continuing its run).

    Yields:
        The path.

    Raises:
        OutputDirError: On every rank, before anything is written, when the path is a file or
            below one, cannot be created or written, is locked by another run, or holds
            earlier outputs and neither ``overwrite`` nor ``clear=False`` was given.
    """
    path = Path(path)
    held: list = []
    on_root(comm, _prepare, path, overwrite, clear, held)
    try:
        yield path
    finally:
        for fh in held:
            fh.close()  # releases the lock
