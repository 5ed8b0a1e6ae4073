"""PETSc options given by the user: checked before meshing, unused ones reported after the run.

Options reach PETSc from the command line (``-mech_snes_type newtonls``) and from the scene
(``solver.petsc``, ``flow.petsc``, ``coupling.petsc``, without their prefix). Before meshing,
:func:`check_petsc_options` refuses, in one line:

* a command-line option without a solver prefix (:data:`PREFIXES`), unless it is one of PETSc's
  global options (``-log_view``, ``-options_left``, ...; :data:`GLOBAL_OPTIONS`): it would set
  nothing, since every poromech solver has a prefix;
* a type that this PETSc build does not have (``*snes_type``, ``*ksp_type``, ``*pc_type``,
  ``*snes_linesearch_type``, ``*pc_factor_mat_solver_type``): PETSc is asked by setting the
  type on a throwaway object, so the answer is that of the linked library.

Defaults and scene options of one solver live in a :class:`PrefixedOptions`: they are in the
database only while that solver reads them (its ``setFromOptions`` and its solves, where PETSc
reads the options of set-up: MUMPS' ``mat_mumps_*`` at the first factorization, the ``mat_mffd_*``
of ``-snes_mf`` at ``SNESSetUp``), so that two solvers with the same prefix never see each
other's values.

* a number option (tolerances, iteration counts, thresholds) whose value is not a finite number,
  and a negative tolerance (PETSc takes it as its default, without a word).

After the run, :func:`report_unused_options` warns once about command-line options that no
solver read (a misspelled name, or an option for a solver this scene does not build), as PETSc's
``-options_left`` does, and :func:`report_unused_scene_options` about the scene's: each push of
a :class:`PrefixedOptions` records whether a solver read it.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Mapping

import dolfinx_solver  # noqa: F401  (MPI before petsc4py)

from mpi4py import MPI
from petsc4py import PETSc

from poromech.errors import ConfigError

__all__ = [
    "GLOBAL_OPTIONS",
    "PREFIXES",
    "PetscOptionError",
    "PrefixedOptions",
    "check_petsc_options",
    "database_options",
    "ksp_reason_name",
    "reason_name",
    "forget_read_options",
    "report_unused_options",
    "report_unused_scene_options",
    "scene_options",
    "unused_options",
]

log = logging.getLogger("poromech")

#: Options prefixes of poromech's solvers (sub-prefixes such as ``mech_stale_`` start with one).
PREFIXES = ("mech_", "flow_", "coupling_")

#: Options pushed by :class:`PrefixedOptions` (full name) and whether a solver read any of its
#: pushes: what :func:`report_unused_scene_options` knows of the scene's options.
_READ: dict[str, bool] = {}


class PrefixedOptions:
    """Options of one PETSc object under its prefix, pushed into the database while it reads them.

    Use ``with options:`` around ``setFromOptions`` and around every solve. Options already in
    the database (the command line) win and are left alone; the others are removed on exit.

    Args:
        prefix: Options prefix, ending in ``_``.
        options: Values without the prefix; None values are left out.
    """

    def __init__(self, prefix: str, options: Mapping[str, object]):
        self.prefix = prefix
        self.options = {k: v for k, v in options.items() if v is not None}
        self._pushed: list[str] = []

    def __enter__(self) -> PrefixedOptions:
        db = PETSc.Options()
        self._pushed = [f"{self.prefix}{k}" for k in self.options
                        if not db.hasName(f"{self.prefix}{k}")]
        for key in self._pushed:
            db[key] = self.options[key[len(self.prefix):]]
        return self

    def __exit__(self, *exc) -> None:
        db = PETSc.Options()
        for key in self._pushed:
            _READ[key] = _READ.get(key, False) or db.used(key)
            db.delValue(key)
        self._pushed = []


#: PETSc options that belong to no solver (names, or name prefixes ending in ``_``).
GLOBAL_OPTIONS = (
    "help", "version", "info", "log_", "options_", "malloc", "memory_", "objects_", "on_error_",
    "debugger", "start_in_debugger", "stop_for_debugger", "fp_trap", "no_signal_handler",
    "check_pointer_intensity", "history", "citations", "skip_petscrc", "viewer_", "display",
    "nox", "device_", "use_gpu_aware_mpi", "saws_", "mpiuni_",
)

#: Option name suffixes whose value is a PETSc type, with examples for the message.
_TYPED = {
    "snes_linesearch_type": ("line search", "basic, bt, l2, cp, nleqerr"),
    "pc_factor_mat_solver_type": ("factorization package", "mumps, superlu_dist, petsc"),
    "snes_type": ("SNES type", "newtonls, newtontr, python, ksponly, anderson, ngmres, qn"),
    "ksp_type": ("KSP type", "preonly, cg, gmres, fgmres, bcgs, minres, richardson"),
    "pc_type": ("PC type", "lu, cholesky, gamg, hypre, jacobi, ilu, bjacobi, none"),
}


class PetscOptionError(ConfigError):
    """A PETSc option that cannot be right; the message is one line."""


def database_options() -> dict[str, str]:
    """The options of poromech's solvers (:data:`PREFIXES`) in PETSc's database, without dash.

    Those a script set with ``petsc4py.PETSc.Options()`` (the command line's, under
    ``poromech run``): :class:`poromech.run.Run` checks them with the scene's
    (:func:`check_petsc_options`) before meshing.
    """
    return {k: ("" if v is None else str(v)) for k, v in PETSc.Options().getAll().items()
            if k.startswith(PREFIXES)}


def _has_type(kind: str, value: str) -> bool:
    """Whether this PETSc build registers ``value`` as a type of ``kind`` (local)."""
    cls = {"snes_type": PETSc.SNES, "ksp_type": PETSc.KSP, "pc_type": PETSc.PC,
           "snes_linesearch_type": PETSc.SNESLineSearch}.get(kind)
    if cls is not None:
        obj = cls().create(PETSc.COMM_SELF)
        try:
            obj.setType(value)
        except PETSc.Error:
            return False
        finally:
            obj.destroy()
        return True
    return _has_factor_package(value)


def _has_factor_package(value: str) -> bool:
    """Whether an LU or Cholesky factorization of package ``value`` exists (local)."""
    A = PETSc.Mat().createAIJ([1, 1], nnz=1, comm=PETSc.COMM_SELF)
    A.setValue(0, 0, 1.0)
    A.assemble()
    try:
        for factor in ("lu", "cholesky"):
            ksp = PETSc.KSP().create(PETSc.COMM_SELF)
            try:
                ksp.setOperators(A)
                ksp.setType("preonly")
                ksp.getPC().setType(factor)
                ksp.getPC().setFactorSolverType(value)
                ksp.setUp()
                return True
            except PETSc.Error:
                pass
            finally:
                ksp.destroy()
        return False
    finally:
        A.destroy()


def _check_type(name: str, value, where: str) -> None:
    """Refuse a typed option whose value is not a registered type."""
    for suffix, (what, examples) in _TYPED.items():
        if name == suffix or name.endswith("_" + suffix):
            if isinstance(value, str) and value and _has_type(suffix, value):
                return
            # the examples this build has (hypre is not in every PETSc)
            present = ", ".join(e for e in examples.split(", ") if _has_type(suffix, e))
            if not isinstance(value, str) or not value:
                raise PetscOptionError(f"{where} = {value!r} needs a {what} (e.g. {present})")
            raise PetscOptionError(f"{where} = {value!r} is not a {what} of this PETSc "
                                   f"(e.g. {present})")


#: Options whose value is a number (name endings): PETSc refuses another value only when the
#: solver reads it, after meshing and without naming the option.
_REAL = re.compile(r"(^|_)(rtol|atol|stol|divtol|dtol|threshold|damping)$")
_TOLERANCE = re.compile(r"(^|_)(rtol|atol|stol|divtol|dtol)$")
_INTEGER = re.compile(r"(^|_)(max_it|max_funcs|restart|lag_jacobian|lag_preconditioner)$")


def _check_number(name: str, value, where: str) -> None:
    """Refuse a value that is not a number for an option that takes one."""
    integer = bool(_INTEGER.search(name))
    if not integer and not _REAL.search(name):
        return
    text = str(value).strip()
    try:  # a real option may be a list (pc_gamg_threshold: one value per level)
        values = [int(text)] if integer else [float(v) for v in text.split(",")]
    except ValueError:
        kind = "an integer" if integer else "a number"
        raise PetscOptionError(f"{where} = {value!r} needs {kind}") from None
    if not all(math.isfinite(v) for v in values):
        raise PetscOptionError(f"{where} = {value!r} needs a finite number")
    number = min(values)
    if not integer and number < 0 and _TOLERANCE.search(name):
        raise PetscOptionError(f"{where} = {value!r} needs a number >= 0 (PETSc would take a "
                               "negative one as its default: leave the option out for that)")
    if integer and number < 0 and not name.endswith(("lag_jacobian", "lag_preconditioner")):
        raise PetscOptionError(f"{where} = {value!r} needs a non-negative integer")


def _is_global(name: str) -> bool:
    return any(name.startswith(g) if g.endswith("_") else name == g or name.startswith(g + "_")
               for g in GLOBAL_OPTIONS)


def scene_options(scene) -> dict[str, Mapping]:
    """The scene's PETSc option tables by prefix (those of the sections the scene has)."""
    out: dict[str, Mapping] = {"mech_": scene.solver.petsc}
    if scene.flow is not None:
        out["flow_"] = scene.flow.petsc
    coupling = getattr(scene, "coupling", None)
    if coupling is not None:
        out["coupling_"] = coupling.petsc
    return out


def _scene_key(prefix: str) -> str:
    return {"mech_": "solver.petsc", "flow_": "flow.petsc", "coupling_": "coupling.petsc"}[prefix]


def check_petsc_options(cli_options: Mapping[str, str], scene=None) -> None:
    """Check command-line and scene PETSc options before meshing (local, identical on all ranks).

    Args:
        cli_options: Command-line options, names without the dash.
        scene: The validated scene, or None.

    Raises:
        PetscOptionError: With a one-line message naming the option, its value and what is
            allowed.
    """
    for name, value in cli_options.items():
        if not name.startswith(PREFIXES) and not _is_global(name):
            raise PetscOptionError(
                f"PETSc option '-{name}' has no solver prefix and sets nothing: give it to a "
                f"solver (prefixes {', '.join(PREFIXES)}; e.g. -mech_{name}) or use a global "
                "option such as -log_view"
            )
        _check_type(name, value, f"PETSc option '-{name}'")
        _check_number(name, value, f"PETSc option '-{name}'")
    if scene is None:
        return
    for prefix, table in scene_options(scene).items():
        key = _scene_key(prefix)
        for name, value in table.items():  # names were checked by the scene loader
            if value is not None:
                _check_type(name, value, f"scene key '{key}.{name}'")
                _check_number(name, value, f"scene key '{key}.{name}'")
    _check_coupling_jacobian(cli_options, scene)
    _check_contact_newton(cli_options, scene)


def _check_contact_newton(cli_options: Mapping[str, str], scene) -> None:
    """Refuse a SNES of one linear step, or a second line search, for the contact Newton.

    ``ksponly`` solves one Newton direction and reports ``CONVERGED_ITS`` whatever the residual:
    a contact problem stopped there was written as converged with its active set still changing.
    A PETSc line search type given with poromech's search (``solver.line_search: contact``)
    ran after it on its already searched step (``bt``: other iterations than either search
    alone), and was not reported.
    """
    if getattr(scene, "physics", None) not in ("mechanics", "poromechanics") \
            or scene.contact.formulation == "none":
        return
    given = "mech_snes_type" in cli_options
    snes_type = cli_options.get("mech_snes_type", scene.solver.petsc.get("snes_type"))
    if snes_type in ("ksponly", "ksptransposeonly"):
        where = "PETSc option '-mech_snes_type'" if given else "scene key 'solver.petsc.snes_type'"
        raise PetscOptionError(
            f"{where} = {snes_type!r} takes one linear step and does not check the contact "
            f"conditions of contact.formulation {scene.contact.formulation}: use the default "
            "(poromech's semi-smooth Newton) or newtonls")
    search = cli_options.get("mech_snes_linesearch_type",
                             scene.solver.petsc.get("snes_linesearch_type"))
    if search is not None and snes_type in (None, "python") \
            and scene.solver.line_search == "contact":
        # PETSc's search would run on the step poromech's search has already taken
        where = ("PETSc option '-mech_snes_linesearch_type'"
                 if "mech_snes_linesearch_type" in cli_options
                 else "scene key 'solver.petsc.snes_linesearch_type'")
        raise PetscOptionError(
            f"{where} = {search!r} would search again along the step of the contact Newton's "
            "own line search: choose the search with solver.line_search (contact, basic, bt, "
            "l2 or cp; e.g. --set solver.line_search=bt)")


def _check_coupling_jacobian(cli_options: Mapping[str, str], scene) -> None:
    """Refuse a Newton-type SNES for the coupled fixed point without a matrix-free Jacobian.

    ``p - g(p)`` has no assembled Jacobian: PETSc would difference ``g`` once per pressure
    unknown for each Jacobian (measured: 19,595 ``g`` for the first step of the injected disc).
    ``coupling.method: newtonkrylov`` is the Newton method of the coupling (``-snes_mf``).
    """
    coupling = getattr(scene, "coupling", None)
    if coupling is None or getattr(scene, "physics", None) != "poromechanics":
        return
    for prefix in ("coupling_", "coupling_fallback_"):
        given = {n[len(prefix):]: v for n, v in cli_options.items() if n.startswith(prefix)
                 and (prefix != "coupling_" or not n.startswith("coupling_fallback_"))}
        table = coupling.petsc if prefix == "coupling_" else {}
        snes_type = given.get("snes_type", table.get("snes_type"))
        method = coupling.method if prefix == "coupling_" else coupling.fallback
        free = method == "newtonkrylov" or any(k in given or k in table
                                               for k in ("snes_mf", "snes_mf_operator"))
        if snes_type in NEEDS_JACOBIAN and not free:
            where = (f"PETSc option '-{prefix}snes_type'" if "snes_type" in given
                     else "scene key 'coupling.petsc.snes_type'")
            raise PetscOptionError(
                f"{where} = {snes_type!r} needs the Jacobian of p - g(p), which the coupled "
                "fixed point has only matrix-free: use coupling.method: newtonkrylov (or add "
                f"-{prefix}snes_mf); PETSc would difference g once per pressure unknown")


#: SNES types that solve with the Jacobian (``-snes_mf`` gives it matrix-free).
NEEDS_JACOBIAN = frozenset({"newtonls", "newtontr", "newtontrdc", "vinewtonrsls",
                            "vinewtonssls", "ksponly", "ksptransposeonly", "aspin"})


def unused_options(names: Mapping[str, str] | None = None) -> list[str]:
    """Options in PETSc's database (or only ``names``) that no object has read (local).

    Global options (``-log_view``, read at the end) are left out.
    """
    opts = PETSc.Options()
    present = opts.getAll()
    keys = present if names is None else [k for k in names if k in present]
    return sorted(k for k in keys if not _is_global(k) and not opts.used(k))


def report_unused_options(comm: MPI.Comm, names: Mapping[str, str] | None = None) -> list[str]:
    """Warn once (rank 0) about options no solver used; return them (collective-safe, local).

    Args:
        comm: Communicator (rank 0 logs).
        names: The options to consider (e.g. those of the command line); all when None.
    """
    unused = unused_options(names)
    if unused and comm.rank == 0:
        listed = ", ".join(f"-{k}" for k in unused)
        log.warning("PETSc option(s) %s were not used (misspelled, or for a solver this scene "
                    "does not build)", listed)
    return unused


def forget_read_options() -> None:
    """Start a new record of the pushed options that were read (at the start of a run)."""
    _READ.clear()


def report_unused_scene_options(comm: MPI.Comm, scene,
                                cli_options: Mapping[str, str] | None = None) -> list[str]:
    """Warn once (rank 0) about scene PETSc options no solver read; return their scene keys.

    An option is unused when every push of it went unread, or when it was never pushed because
    no solver of its prefix was built (a command-line option of the same name wins and is
    reported by :func:`report_unused_options` instead).
    """
    unused: list[str] = []
    if not _READ:  # no solver was built (the run stopped before): nothing to tell
        return unused
    for prefix, table in scene_options(scene).items():
        for name, value in table.items():
            full = prefix + name
            if value is None or (cli_options and full in cli_options):
                continue
            if not _READ.get(full, False):
                unused.append(f"{_scene_key(prefix)}.{name}")
    if unused and comm.rank == 0:
        log.warning("scene key(s) %s were not used by any solver (misspelled, or for a solver "
                    "this scene does not build)", ", ".join(unused))
    return unused


_SNES_REASONS = {v: k for k, v in vars(PETSc.SNES.ConvergedReason).items()
                 if not k.startswith("_")}


def reason_name(reason: int) -> str:
    """The name of a SNES converged reason (``CONVERGED_FNORM_RELATIVE``), or its number."""
    return _SNES_REASONS.get(reason, str(reason))


_KSP_REASONS = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items()
                if not k.startswith("_")}


def ksp_reason_name(reason: int) -> str:
    """The name of a KSP converged reason (``DIVERGED_ITS``), or its number."""
    return _KSP_REASONS.get(reason, str(reason))
