"""Command line: ``poromech run [SCENE] [-o OUTDIR] [--set k=v ...]`` and ``poromech validate``.

Arguments that start with ``-`` and are not poromech's own are PETSc options, e.g.
``poromech run scene.yaml -mech_snes_monitor -mech_ksp_view``; they override the scene.

Exit status: 0 success, 2 invalid scene or arguments, 3 a solver did not converge, 1 any other
error (on one rank this aborts all ranks rather than leaving them waiting).
"""

from __future__ import annotations

import argparse
import logging
import sys
import traceback
from pathlib import Path

__all__ = ["main"]

EXIT_CONFIG = 2
EXIT_SOLVER = 3


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="poromech",
        description="Frictional contact on fracture networks in (poro)elastic rock.",
        epilog="Unrecognized -options are passed to PETSc (e.g. -mech_snes_monitor).",
    )
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a scene (default: the embedded six-fracture scene)")
    run.add_argument("scene", nargs="?", help="scene YAML file")
    run.add_argument("-o", "--output", help="output directory (default: results/<scene name>)")
    val = sub.add_parser("validate", help="check a scene file and exit")
    val.add_argument("scene", help="scene YAML file")
    for sp in (run, val):
        sp.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene key, e.g. --set contact.formulation=mixed")
        sp.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
        sp.add_argument("-v", "--verbose", action="store_true", help="debug output")
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
    log = logging.getLogger("poromech")
    log.handlers[:] = [handler]
    log.setLevel(level if rank == 0 else logging.ERROR)
    log.propagate = False


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``poromech`` command."""
    own, petsc_opts = _split_petsc_options(list(sys.argv[1:] if argv is None else argv))
    args = _parser().parse_args(own)

    import dolfinx_solver  # noqa: F401  (MPI first)

    from mpi4py import MPI

    from poromech.config import ConfigError, load_scene

    comm = MPI.COMM_WORLD
    _setup_logging(comm.rank, args.quiet, args.verbose)
    log = logging.getLogger("poromech")
    try:
        scene = load_scene(args.scene, args.set)
    except ConfigError as err:
        if comm.rank == 0:
            print(f"poromech: invalid scene: {err}", file=sys.stderr)
        return EXIT_CONFIG
    if args.command == "validate":
        log.info("%s: valid (%s, physics %s)", args.scene, scene.name, scene.physics)
        return 0

    from petsc4py import PETSc

    from poromech.errors import SolverError
    from poromech.run import run_scene

    opts = PETSc.Options()
    for k, v in petsc_opts.items():
        opts[k] = v
    outdir = Path(args.output) if args.output else Path("results") / scene.name
    try:
        summary = run_scene(scene, outdir, comm)
    except SolverError as err:
        if comm.rank == 0:
            print(f"poromech: {err}", file=sys.stderr)
            print(f"poromech: results up to the failure are in {outdir}", file=sys.stderr)
        return EXIT_SOLVER
    except Exception:
        traceback.print_exc()
        sys.stderr.flush()
        if comm.size > 1:
            comm.Abort(1)
        return 1
    log.info("done in %.1f s; results in %s", summary["wall_time"]["total"], outdir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
