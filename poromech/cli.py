"""Command line: ``poromech run|validate|scenes|show|plot`` and ``poromech --version``.

Arguments that start with ``-`` and are not poromech's own are PETSc options, e.g.
``poromech run scene.yaml -mech_snes_monitor -mech_ksp_view``; they override the scene. A scene
is a YAML file or the name of a shipped scene (``poromech run sneddon``; ``poromech scenes``).

Exit status:

* 0 — success;
* 2 — refused before solving: invalid scene or arguments, an unknown PETSc option or type,
  an output directory that is a file, not writable, in use by another run or holding an
  earlier run's outputs (without ``--overwrite``), a mesh estimated not to fit in memory
  (without ``--force``) — all before meshing —, or an expression found not finite or out of
  range at a mesh point (after meshing, before the first solve);
* 3 — a solver did not converge (reason and residual history printed, outputs kept);
* 1 — any other error (one line; the traceback with ``-v``);
* 128 + signal number — stopped by SIGINT (130) or SIGTERM (143) after a completed step.

Under MPI every error is printed once, by rank 0, and every rank ends with the same status.
Errors are found identically on every rank, or on one rank and broadcast to all
(:mod:`poromech.parallel`: the scene is read on rank 0, the output directory checked there). An
error raised on some ranks only (a bug, an I/O error on rank 0 during the run) is printed by
those ranks and ends the run with ``MPI_Abort`` and its status, rather than leaving the other
ranks waiting in a collective call.
"""

from __future__ import annotations

import argparse
import logging
import math
import re
import sys
import time
import traceback
from pathlib import Path

__all__ = ["EXIT_CONFIG", "EXIT_ERROR", "EXIT_SOLVER", "main"]

EXIT_ERROR = 1
EXIT_CONFIG = 2
EXIT_SOLVER = 3

#: Seconds between printing an error on some ranks only and aborting (output forwarding).
ABORT_DRAIN = 0.2

log = logging.getLogger("poromech")


class _Parser(argparse.ArgumentParser):
    """An argument parser that prints (usage, errors, help) on rank 0 only."""

    silent = False

    def _print_message(self, message, file=None):
        if not _Parser.silent:
            super()._print_message(message, file)

    def error(self, message):
        """Refuse bad arguments in one line (status 2)."""
        self.exit(EXIT_CONFIG, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _version() -> str:
    import dolfinx_solver

    import petsc4py

    import poromech

    return (f"poromech {poromech.__version__} (DOLFINx {dolfinx_solver.DOLFINX_VERSION}, "
            f"PETSc {petsc4py.__version__}, Python {sys.version.split()[0]})")


def _parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="poromech",
        description="Frictional contact on fracture networks in (poro)elastic rock.",
        epilog="Unrecognized -options are passed to PETSc (e.g. -mech_snes_monitor). Exit "
               "status: 0 success, 2 refused before solving (invalid scene or arguments), "
               "3 a solver did not converge, 1 any other error.",
    )
    p.add_argument("--version", action="version", version=_version())
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a scene (default: the embedded six-fracture scene)")
    run.add_argument("scene", nargs="?", help="scene YAML file or shipped scene name")
    run.add_argument("-o", "--output", type=_directory,
                     help="output directory (default: results/<scene name>)")
    run.add_argument("--overwrite", action="store_true",
                     help="replace the outputs of an earlier run in the output directory")
    run.add_argument("--force", action="store_true",
                     help="run even if the mesh is estimated not to fit in memory")
    run.add_argument("--restart", metavar="OUTDIR", type=_directory,
                     help="continue the run in OUTDIR from its last completed step (its scene "
                          "is read from OUTDIR/poromech_scene.yaml; no scene or --set)")
    val = sub.add_parser("validate", help="check a scene (file or shipped name) and exit; "
                         "without meshing unless --mesh")
    val.add_argument("scene", help="scene YAML file or shipped scene name")
    val.add_argument("--mesh", action="store_true",
                     help="also mesh the scene and build its solvers, for the checks that need "
                          "the mesh (fields at the mesh points, the initial stress's "
                          "equilibrium, pieces held only by contact); nothing is solved")
    val.add_argument("--force", action="store_true", help="do not refuse a mesh too large "
                     "for this machine's memory")
    for sp in (run, val):
        sp.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene key, e.g. --set contact.formulation=mixed")
        talk = sp.add_mutually_exclusive_group()
        talk.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
        talk.add_argument("-v", "--verbose", action="store_true",
                          help="debug output, and the traceback of an unexpected error")
    sub.add_parser("scenes", help="list the shipped scenes")
    show = sub.add_parser("show", help="print a shipped scene's YAML (to start a scene from)")
    show.add_argument("scene", help="shipped scene name (or a scene file)")
    plot = sub.add_parser("plot", help="draw PNGs of a run's outputs (deformed mesh with fracture "
                          "states, jumps along the fractures, pressure)")
    plot.add_argument("outdir", help="output directory of a run")
    plot.add_argument("--time", type=_finite, help="output time to draw (the nearest written; "
                      "default: the last)")
    plot.add_argument("--scale", type=_positive, help="displacement magnification (default: "
                      "the largest displacement drawn as ~10%% of the domain)")
    plot.add_argument("-o", "--output", type=_directory,
                      help="directory of the PNGs (default: OUTDIR/plots)")
    plot.add_argument("--backend", choices=("auto", "pyvista", "matplotlib"), default="auto",
                      help="auto: pyvista (off-screen VTK) when it can render, else matplotlib")
    plot.add_argument("-v", "--verbose", action="store_true", help="debug output")
    return p


_OWN_SHORT = {"-o", "-q", "-v", "-h"}


def _split_petsc_options(argv: list[str]) -> tuple[list[str], dict[str, str]]:
    """Separate PETSc options (``-key [value]``, single dash) from poromech's own arguments."""
    own, petsc, i = [], {}, 0
    while i < len(argv):
        arg = argv[i]
        if arg.startswith("-") and not arg.startswith("--") and arg not in _OWN_SHORT \
                and len(arg) > 2 and not _is_number(arg):
            value = ""
            if i + 1 < len(argv) and (not argv[i + 1].startswith("-") or _is_number(argv[i + 1])):
                value, i = argv[i + 1], i + 1
            petsc[arg[1:]] = value
        else:
            own.append(arg)
        i += 1
    return own, petsc


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _setup_logging(rank: int, quiet: bool, verbose: bool) -> None:
    level = logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO
    handler = logging.StreamHandler(sys.stdout if rank == 0 else sys.stderr)
    handler.setFormatter(logging.Formatter("poromech: %(message)s"))
    log.handlers[:] = [handler]
    log.setLevel(level if rank == 0 else logging.ERROR)
    log.propagate = False


def _say(comm, text: str) -> None:
    """Print one line to stderr on rank 0."""
    if comm.rank == 0:
        print(f"poromech: {text}", file=sys.stderr, flush=True)


# -- commands --------------------------------------------------------------------------------
def _load(args, comm):
    """The validated scene and its mapping, read on rank 0 and broadcast.

    A file visible on rank 0 only is fine. A restart reads the scene stored with its run.
    """
    from poromech.errors import ConfigError
    from poromech.parallel import on_root
    from poromech.scene.loading import load_scene_and_raw

    restart = getattr(args, "restart", None)
    if restart is None:
        return on_root(comm, load_scene_and_raw, args.scene, args.set)
    if args.scene is not None or args.set or args.output is not None:
        raise ConfigError("--restart OUTDIR continues that run as it was set up: give no scene, "
                          "--set or -o with it")
    return on_root(comm, _stored_run, Path(restart))


def _stored_run(outdir: Path):
    """The scene and mapping stored with the run in ``outdir``, which must have a checkpoint."""
    from poromech.errors import ConfigError
    from poromech.io.checkpoint import CHECKPOINT, CheckpointError, read_checkpoint_meta
    from poromech.run import SCENE_FILE
    from poromech.scene.loading import load_scene_and_raw

    if not (outdir / SCENE_FILE).is_file():
        raise ConfigError(f"--restart {outdir}: no poromech run there ({SCENE_FILE} is missing)")
    if not (outdir / CHECKPOINT).is_file():
        raise ConfigError(f"--restart {outdir}: the run there wrote no {CHECKPOINT} (a scene "
                          "without time steps, output.checkpoint: false, or a run that stopped "
                          "before its first step): nothing to continue from")
    try:
        read_checkpoint_meta(outdir / CHECKPOINT)
    except CheckpointError as err:
        raise ConfigError(f"--restart {outdir}: {err}") from None
    return load_scene_and_raw(outdir / SCENE_FILE, ())


def _check(args, petsc_opts: dict, comm):
    """Everything that can be refused before meshing; returns scene, mapping and estimate."""
    from poromech.petsc_options import check_petsc_options
    from poromech.scene.geometry import scene_geometry
    from poromech.scene.resources import check_resources

    scene, raw = _load(args, comm)
    check_petsc_options(petsc_opts, scene)
    est = check_resources(scene, scene_geometry(scene), comm, force=args.force)
    return scene, raw, est


def _validate(args, petsc_opts: dict, comm) -> int:
    scene, _, est = _check(args, petsc_opts, comm)
    if not args.mesh:
        log.info("%s: valid (%s, physics %s; ~%.2g cells, ~%.2g GB estimated; not meshed: "
                 "--mesh also runs the checks on the mesh)", args.scene, scene.name,
                 scene.physics, est.cells, est.memory / 1e9)
        return 0
    from poromech.run import Run

    class _Built(Exception):
        """The physics is built: stop before anything is solved."""

    def stop(physics) -> None:
        raise _Built

    with Run(scene, comm=comm, prepare=stop) as run:
        try:
            run.execute()
        except _Built:
            pass
    mesh = run.summary["mesh"]
    log.info("%s: valid (%s, physics %s; meshed: %d cells, %d fracture faces; nothing solved)",
             args.scene, scene.name, scene.physics, mesh["cells"], mesh["fracture_faces"])
    return 0


def _run(args, petsc_opts: dict, comm) -> int:
    from petsc4py import PETSc

    from poromech.errors import OutputError, SolverError
    from poromech.io.outdir import default_output_dir, output_directory
    from poromech.petsc_options import (
        forget_read_options,
        report_unused_options,
        report_unused_scene_options,
    )
    from poromech.run import run_scene
    from poromech.stepping import Interrupted

    scene, raw, _ = _check(args, petsc_opts, comm)
    restart = args.restart is not None
    if restart:
        outdir = Path(args.restart)
    else:
        outdir = Path(args.output) if args.output else default_output_dir(scene.name)
    opts = PETSc.Options()
    for k, v in petsc_opts.items():
        opts[k] = v
    forget_read_options()
    if "log_view" in petsc_opts:
        PETSc.Log.begin()  # options given after PetscInitialize do not start the log
    try:
        with output_directory(outdir, comm, overwrite=args.overwrite, clear=not restart):
            try:
                summary = run_scene(scene, outdir, comm, raw=raw, restart=restart)
            except SolverError as err:
                _say(comm, str(err))
                _say(comm, f"results up to the failure are in {outdir}")
                return EXIT_SOLVER
            except OutputError as err:  # disk full, quota, permissions: earlier steps kept
                _say(comm, f"{err}; the steps completed before are readable in {outdir}")
                return EXIT_ERROR
            except Interrupted as err:  # SIGINT/SIGTERM at a step boundary: 128 + signal
                _say(comm, f"{err}; results are in {outdir}")
                return 128 + err.signum
            finally:
                report_unused_options(comm, petsc_opts)
                report_unused_scene_options(comm, scene, petsc_opts)
    finally:
        for k in petsc_opts:
            if k != "log_view":
                opts.delValue(k)
    log.info("done in %.1f s; results in %s", summary["wall_time"]["total"], outdir)
    return 0


def _scene_list() -> str:
    """One line per shipped scene: its name and description."""
    import yaml

    from poromech.scene.loading import shipped_scenes

    scenes = shipped_scenes()
    width = max(map(len, scenes))
    return "".join(f"{name:<{width}}  {yaml.safe_load(path.read_text()).get('description', '')}\n"
                   for name, path in scenes.items())


def _scenes(args, petsc_opts: dict, comm) -> int:
    from poromech.parallel import on_root

    text = on_root(comm, _scene_list)
    if comm.rank == 0:
        sys.stdout.write(text)
        sys.stdout.flush()
    return 0


def _show(args, petsc_opts: dict, comm) -> int:
    from poromech.parallel import on_root
    from poromech.scene.loading import scene_text

    text = on_root(comm, scene_text, args.scene)
    if comm.rank == 0:
        sys.stdout.write(text)
        sys.stdout.flush()
    return 0


def _plot(args, petsc_opts: dict, comm) -> int:
    """Draw the pictures of a run on rank 0 (serial); status 2 if OUTDIR is not a run's."""
    from poromech.io.plot import PlotError, plot_run
    from poromech.parallel import on_root

    try:
        paths = on_root(comm, plot_run, args.outdir, time=args.time, scale=args.scale,
                        out=args.output, backend=args.backend)
    except FileNotFoundError as err:
        return _end(comm, EXIT_CONFIG, str(err))
    except PlotError as err:
        return _end(comm, EXIT_ERROR, str(err))
    except (OSError, ValueError) as err:  # a file of the run cut short or edited by hand
        return _end(comm, EXIT_CONFIG, f"cannot plot {args.outdir}: {' '.join(str(err).split())}")
    for path in paths:
        log.info("wrote %s", path)
    return 0


_COMMANDS = {"run": _run, "validate": _validate, "scenes": _scenes, "show": _show,
             "plot": _plot}


# -- errors ----------------------------------------------------------------------------------
def _end(comm, code: int, line: str, err: BaseException | None = None) -> int:
    """Print an error once and return its status on every rank (collective when all failed).

    An error raised on every rank (the designed case: scene errors are found identically or
    broadcast) is printed by rank 0. An error on some ranks only would leave the others waiting
    in a collective call: the ranks that failed print it and abort the run with the same status.

    Args:
        comm: The communicator of the run.
        code: Exit status.
        line: The message.
        err: An unexpected exception whose traceback to print (``-v``).
    """
    from poromech.parallel import all_ranks_failed

    if all_ranks_failed(comm):
        if comm.rank == 0:
            if err is not None:
                traceback.print_exception(err)
            _say(comm, line)
        return code
    if err is not None:
        traceback.print_exception(err)
    print(f"poromech: {line} (on rank {comm.rank} only; aborting all ranks)", file=sys.stderr,
          flush=True)
    # the abort tears down mpirun's forwarding of this rank's output: give the line time to
    # get through first (without the pause it was occasionally lost: empty stderr)
    time.sleep(ABORT_DRAIN)
    comm.Abort(code)
    return code  # pragma: no cover


def _finite(text: str) -> float:
    """A finite number (argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def _directory(text: str) -> str:
    """A directory path that is not empty or blank (argparse type)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is not a directory path")
    return text


def _positive(text: str) -> float:
    """A finite number > 0 (argparse type)."""
    value = _finite(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not > 0")
    return value


def _petsc_error(err: BaseException) -> str:
    """A PETSc error as one line: the innermost routine and PETSc's messages.

    petsc4py's message is ``error code N`` followed by PETSc's trace, one ``[rank] routine() at
    file:line`` per frame, then the error class and the detail. A Python exception raised
    inside a PETSc callback (poromech's Newton step, a line search) reaches here as PETSc's
    error 101 whose cause is that exception.
    """
    from petsc4py import PETSc

    while isinstance(err, PETSc.Error) and isinstance(err.__cause__, BaseException):
        err = err.__cause__
    if not isinstance(err, PETSc.Error):
        return f"{type(err).__name__}: {str(err).strip()}"
    frames, messages = [], []
    for line in str(err).strip().splitlines()[1:]:
        text = re.sub(r"^\[\d+\]\s*", "", line).strip()
        (frames if re.search(r"\(\) at \S", text) else messages).append(text)
    where = f" in {frames[-1].split(' at ')[0]}" if frames else ""
    return f"PETSc error {err.ierr}{where}" + "".join(f": {m}" for m in messages if m)


def _unexpected(err: BaseException, comm, verbose: bool) -> int:
    """One line (the traceback with -v), status 1."""
    from petsc4py import PETSc

    first = str(err).strip().splitlines()[0] if str(err).strip() else ""
    line = f"error: {type(err).__name__}" + (f": {first}" if first else "")
    if isinstance(err, PETSc.Error):
        line = f"error: {_petsc_error(err)}".splitlines()[0]
    if not verbose:
        line += " (run with -v for the traceback)"
    return _end(comm, EXIT_ERROR, line, err if verbose else None)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``poromech`` command (collective under MPI)."""
    import dolfinx_solver  # noqa: F401  (MPI first)

    from mpi4py import MPI

    from poromech.errors import ConfigError, SolverError
    from poromech.io.outdir import OutputDirError
    from poromech.parallel import error_comm
    from poromech.petsc_options import PetscOptionError
    from poromech.scene.resources import ResourceError

    comm = MPI.COMM_WORLD
    error_comm(comm)
    own, petsc_opts = _split_petsc_options(list(sys.argv[1:] if argv is None else argv))
    _Parser.silent = comm.rank != 0
    try:
        args = _parser().parse_args(own)
    except SystemExit as stop:  # --help, --version, usage errors (printed by rank 0)
        return stop.code if isinstance(stop.code, int) else EXIT_CONFIG
    verbose = getattr(args, "verbose", False)
    _setup_logging(comm.rank, getattr(args, "quiet", False), verbose)
    try:
        return _COMMANDS[args.command](args, petsc_opts, comm)
    except (PetscOptionError, OutputDirError, ResourceError) as err:  # before ConfigError
        return _end(comm, EXIT_CONFIG, str(err))
    except ConfigError as err:
        return _end(comm, EXIT_CONFIG, f"invalid scene: {err}")
    except SolverError as err:  # raised outside a run (e.g. by a restart)
        return _end(comm, EXIT_SOLVER, str(err))
    except Exception as err:
        return _unexpected(err, comm, verbose)


if __name__ == "__main__":
    sys.exit(main())
