"""Run a scene: the one lifecycle, scene → mesh → physics → time loop → outputs, for every physics.

:class:`Run` is used by the command line (``poromech run``), the Python API
(:func:`run_scene`), the tests and the benchmark scripts alike::

    with Run(scene, outdir) as run:     # outdir None: nothing is written (studies, tests)
        summary = run.execute()
        u = run.physics.model.u         # the solved state stays inspectable until the with ends

The physics of a scene is looked up by name in :data:`PHYSICS` (its class implements
:class:`poromech.physics.Physics`); the lifecycle itself does not know which physics it runs.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
import yaml
from mpi4py import MPI
from petsc4py import PETSc

import poromech
from poromech.errors import ConfigError, SolverError
from poromech.io.checkpoint import (
    CHECKPOINT,
    load_checkpoint,
    read_checkpoint_meta,
    save_checkpoint,
)
from poromech.io.output import write_summary
from poromech.io.xdmf import atomic_write_text, root_write
from poromech.mesh.entities import domain_box
from poromech.mesh.fractured import FracturedMesh, distribute_mesh
from poromech.mesh.generate import generate_mesh
from poromech.parallel import all_ranks_failed, error_comm, on_root
from poromech.petsc_options import check_petsc_options, database_options
from poromech.physics import Physics
from poromech.scene.fields import validate_fields
from poromech.scene.geometry import absolute_geometry_paths, mesh_sizes, scene_geometry
from poromech.scene.schema import Scene, step_times
from poromech.stepping import Interrupted, run_steps, stop_at_once, stop_signals
from poromech.timing import Timer

__all__ = ["PHYSICS", "SCENE_FILE", "Run", "build_mesh", "mesh_summary", "run_scene"]

log = logging.getLogger("poromech")

#: The validated scene (after overrides) is stored next to the outputs, for ``--restart``.
SCENE_FILE = "poromech_scene.yaml"

PhysicsFactory = Callable[[Scene, FracturedMesh, Timer], Physics]


def _mechanics(scene: Scene, fm: FracturedMesh, timer: Timer) -> Physics:
    from poromech.mechanics.physics import MechanicsPhysics

    return MechanicsPhysics(scene, fm, timer)


def _flow(scene: Scene, fm: FracturedMesh, timer: Timer) -> Physics:
    from poromech.flow.physics import FlowPhysics

    return FlowPhysics(scene, fm, timer)


def _poromechanics(scene: Scene, fm: FracturedMesh, timer: Timer) -> Physics:
    from poromech.coupling.poromechanics import Poromechanics

    return Poromechanics(scene, fm, timer)


#: The physics of each value of the scene key ``physics``. The classes are imported when a scene
#: asks for them, so a flow-only run loads no mechanics and compiles no form.
PHYSICS: dict[str, PhysicsFactory] = {
    "mechanics": _mechanics,
    "flow": _flow,
    "poromechanics": _poromechanics,
}


def build_mesh(scene: Scene, comm: MPI.Comm, owner=None) -> FracturedMesh:
    """Generate or read (rank 0) and distribute the fractured mesh of a scene (collective).

    Args:
        scene: The scene.
        comm: Communicator.
        owner: Optional rank of every input cell (an array on rank 0, or a callable of the cell
            centroids), to impose a partition (tests that put a process boundary on a fracture).

    A failure of gmsh or of the mesh file on rank 0 is raised on every rank. A flow-only scene
    gets no cracked topology (it has no displacement space).
    """
    geo = scene_geometry(scene)

    def arrays():
        if scene.geometry.mesh is not None:
            from poromech.mesh.imported import mesh_file_arrays

            return mesh_file_arrays(scene.geometry.mesh, geo, scene.mesh.refinement)
        if geo.dim == 3:
            from poromech.mesh.generate3d import generate_mesh_3d

            return generate_mesh_3d(geo, mesh_sizes(scene))
        return generate_mesh(geo, mesh_sizes(scene))

    return distribute_mesh(comm, geo, arrays, owner, crack=scene.physics != "flow")


#: A 3D fracture meshed with fewer faces than this is said to be under-resolved (a warning): a
#: disc of radius 0.02 m in a mesh of 0.25 m became a heptagon of 7 faces around one node, every
#: face with the same jump.
FEWEST_FACES_3D = 8


def warn_unresolved_fractures(fm: FracturedMesh) -> None:
    """Warn of each 3D fracture with fewer than :data:`FEWEST_FACES_3D` faces (collective)."""
    names = fm.geometry.fracture_names
    if fm.msh.topology.dim != 3 or not names:
        return
    counts = fm.comm.allreduce(np.bincount(fm.fractures.fracture, minlength=len(names)),
                               op=MPI.SUM)
    for name, n in zip(names, counts, strict=True):
        if n < FEWEST_FACES_3D:
            log.warning("fracture %r has only %d face%s: its jumps and tractions are barely "
                        "resolved; a smaller mesh.fracture_size (or a mesh.zones entry around "
                        "it) gives it more", name, n, "" if n == 1 else "s")


def mesh_summary(fm: FracturedMesh) -> dict:
    """Global sizes of a mesh, for the summary (collective-free)."""
    top = fm.msh.topology
    return {
        "cells": top.index_map(top.dim).size_global,
        "vertices": top.index_map(0).size_global,
        "fracture_faces": fm.num_fracture_faces,
    }


def mesh_fingerprint(fm: FracturedMesh) -> list[float]:
    """The bounding box of a mesh's points and their first and second moments (collective).

    Independent of the partition to round-off: a restart compares it with its checkpoint's,
    which accepted a mesh file whose points had all been moved (or a geometry scaled) as long
    as the cell and vertex counts were the same.
    """
    msh = fm.msh
    x = msh.geometry.x[: msh.geometry.index_map().size_local, : msh.geometry.dim]
    lo, hi = domain_box(msh)
    sums = np.concatenate([x.sum(axis=0), (x * x).sum(axis=0)])
    total = np.empty_like(sums)
    fm.comm.Allreduce(sums, total, op=MPI.SUM)
    return [*map(float, lo), *map(float, hi), *map(float, total)]


def _box(values: list[float], d: int) -> str:
    lo, hi = values[:d], values[d: 2 * d]
    return "[" + ", ".join(f"{a:.6g}..{b:.6g}" for a, b in zip(lo, hi, strict=True)) + "]"


class Run:
    """One run of a scene, from its mesh to its outputs (collective).

    Args:
        scene: The validated scene.
        outdir: Output directory (created if needed); None writes nothing (no outputs, no
            ``summary.json``, no checkpoints): the summary is only returned.
        comm: Communicator.
        raw: The scene mapping it was built from; stored as ``poromech_scene.yaml`` for
            ``--restart``.
        restart: Continue the run in ``outdir`` from its checkpoint.
        mesh: A mesh already built from the scene (tests that impose a partition); by default
            :func:`build_mesh`.
        prepare: Called with the physics once it is built, before anything is solved (studies
            and tests that change a solver setting the scene has no key for).

    Attributes:
        summary: The summary, filled as the run goes (also ``outdir/summary.json``).
        records: One record per completed step (in the summary too).
        physics: The physics, once built; it stays alive until :meth:`close`.
        mesh: The fractured mesh, once built.
    """

    def __init__(self, scene: Scene, outdir: str | Path | None = None,
                 comm: MPI.Comm = MPI.COMM_WORLD, *, raw: dict | None = None,
                 restart: bool = False, mesh: FracturedMesh | None = None,
                 prepare: Callable[[Physics], None] | None = None):
        if restart and outdir is None:
            raise ValueError("a restart continues the run of an output directory: give outdir")
        if restart and not (Path(outdir) / CHECKPOINT).is_file():  # as poromech run says it
            raise ConfigError(f"restart of {outdir}: the run there wrote no {CHECKPOINT} (a "
                              "scene without time steps, output.checkpoint: false, or a run "
                              "that stopped before its first step): nothing to continue from")
        # the checks of `poromech run` for a run made from a script: the scene's PETSc options
        # and those set in PETSc's database (ksponly, a second line search, ...), before meshing
        options = database_options()
        check_petsc_options(options, scene)
        # relative file names of a mapping given to scene_from_dict were read from the working
        # directory: stored as absolute paths, a later --restart of outdir finds them again
        raw = None if raw is None else absolute_geometry_paths(raw, Path.cwd())
        self.scene, self.comm, self.raw, self.restart = scene, comm, raw, restart
        error_comm(comm)  # collective: made while every rank passes here
        self.outdir = None if outdir is None else Path(outdir)
        self.mesh, self.prepare = mesh, prepare
        self.physics: Physics | None = None
        self.timer = Timer()
        self.records: list[dict] = []
        self._applied: list[str] = []  # options of the continued run put in PETSc's database
        if restart:
            options = self._continued_options(options)
        #: ``{"from_step", "mpi_ranks"}`` of each part of a restarted run (this one last), and
        #: the PETSc options of poromech's solvers given to it (command line, script).
        self.parts: list[dict] = [{"from_step": 0, "mpi_ranks": comm.size}]
        if options:
            self.parts[0]["petsc_options"] = options
        self._restored = False  # a restart whose checkpoint was accepted
        self._fingerprint: list[float] = []
        self.summary: dict = {
            "scene": scene.name,
            "physics": scene.physics,
            "poromech_version": poromech.__version__,
            "mpi_ranks": comm.size,
            "status": "running",
        }
        if options:
            self.summary["petsc_options"] = options

    def __enter__(self) -> Run:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _continued_options(self, given: dict[str, str]) -> dict[str, str]:
        """The PETSc options a restart runs with: those of the run it continues, and ``given``.

        ``poromech run --restart`` continues a run as it was set up, and the solver options
        given to it on the command line are part of that: they were dropped (a run given
        ``-mech_snes_rtol 1e-3`` went on with the default, 2-6 Newton iterations per step where
        the uninterrupted run took 0-2, and nothing recorded it). Options given again are
        kept; an option given with another value is said.
        """
        meta = on_root(self.comm, read_checkpoint_meta, self.outdir / CHECKPOINT)[0]
        before = (meta.get("parts") or [{}])[-1].get("petsc_options") or {}
        opts = PETSc.Options()
        for k, v in before.items():
            if k not in given:
                opts[k] = v
                self._applied.append(k)
        if self._applied:
            log.info("the restart goes on with the PETSc options of the run it continues: %s",
                     " ".join(f"-{k} {before[k]}".strip() for k in self._applied))
        changed = [k for k in given if before.get(k) != given[k]]
        if changed:
            log.warning("the restart changes PETSc options of the run it continues: %s (the "
                        "summary's parts record each part's)",
                        ", ".join(f"-{k} {before.get(k, '(not given)')} -> {given[k]}"
                                  for k in changed))
        return {**before, **given}

    def close(self) -> None:
        """Free the physics' PETSc objects (collective)."""
        opts = PETSc.Options()
        for k in self._applied:  # the continued run's options leave the database with it
            opts.delValue(k)
        self._applied = []
        if self.physics is not None:
            self.physics.close()
            self.physics = None

    def execute(self) -> dict:
        """Mesh, physics, initial state (or checkpoint), the time steps and the summary.

        Returns:
            The summary (also in ``outdir/summary.json``, rewritten after every step, and
            written with the failure status when a step fails).

        Raises:
            SolverError: A step did not converge (outputs of earlier steps are kept).
            Interrupted: Stopped by SIGINT/SIGTERM at a step boundary.
        """
        self._prepare_outdir()
        summary, timer = self.summary, self.timer
        failed = False
        try:
            with stop_at_once():  # the set-up: a signal stops it at once
                self._set_up()
            self._steps()
            summary["status"] = "converged"
        except SolverError as err:
            failed = True
            summary["status"] = f"failed: {err}"
            if err.record:  # the work of the step that failed, its attempts and cuts included
                summary["failed_step"] = err.record
            raise
        except Interrupted as err:
            failed = True
            summary["status"] = f"interrupted: {err}"
            raise
        except BaseException as err:
            failed = True
            summary["status"] = f"error: {type(err).__name__}: {err}"
            raise
        finally:
            # an error on some ranks only (a bug, a library raising on one rank): the others
            # wait in a collective call and would never join those below; the error goes up
            # at once, and poromech run aborts every rank with it
            if not failed or all_ranks_failed(self.comm):
                if self.physics is not None:
                    self.physics.finish(summary, self.records)
                summary["wall_time"] = timer.report(self.comm)
                if not self.restart or self._restored:  # a refused restart keeps the run's
                    self._write_summary()
        return summary

    # -- pieces of the lifecycle ----------------------------------------------------------------
    def _set_up(self) -> None:
        """The mesh (unless given), the checks on it, the physics and its description."""
        summary, timer = self.summary, self.timer
        if self.mesh is None:
            with timer.phase("mesh"):
                self.mesh = build_mesh(self.scene, self.comm)
        validate_fields(self.scene, self.mesh)  # every expression where it is evaluated
        summary["mesh"] = mesh_summary(self.mesh)
        self._fingerprint = mesh_fingerprint(self.mesh)
        log.info("mesh: %(cells)d cells, %(fracture_faces)d fracture faces", summary["mesh"])
        warn_unresolved_fractures(self.mesh)
        self.physics = PHYSICS[self.scene.physics](self.scene, self.mesh, timer)
        if self.prepare is not None:
            self.prepare(self.physics)
        summary.update(self.physics.describe())

    def _prepare_outdir(self) -> None:
        if self.outdir is None:
            return
        if self.comm.rank == 0:
            self.outdir.mkdir(parents=True, exist_ok=True)
        if not self.restart:  # a restart stores its scene once the checkpoint accepted it
            self._store_scene()
        self.comm.barrier()

    def _store_scene(self) -> None:
        """Write the scene mapping next to the outputs, if the run was given one (collective)."""
        if self.outdir is not None and self.raw is not None:
            root_write(self.comm, atomic_write_text, self.outdir / SCENE_FILE,
                       yaml.safe_dump(self.raw, sort_keys=False))

    def _write_summary(self) -> None:
        if self.outdir is not None:
            write_summary(self.comm, self.outdir, self.summary)

    def _steps(self) -> None:
        """Initial state (or checkpoint), writers, then the time steps with their bookkeeping."""
        scene, physics, summary = self.scene, self.physics, self.summary
        section = physics.records_section
        (summary.setdefault(section, {}) if section else summary)["solves"] = self.records
        start, resume = 0, None
        summary["completed_steps"] = 0  # a run that fails its first step says so
        # a signal during the initial state (an equilibrium under σ⁰ and p⁰ can take minutes)
        # stops the run after it, with the outputs of t = 0 and the summary written
        with stop_signals() as flag:
            if self.restart:
                start, resume = self._restore()
            else:
                initial = physics.initialize()
                if initial is not None:
                    summary["initial"] = initial
            if self.outdir is not None:
                physics.open_output(self.outdir, resume_until=resume)
            self._write_summary()
            run_steps(physics, scene, self.comm, self.records, self._after_step, start=start,
                      write_initial=not self.restart and scene.time is not None
                      and physics.writes_initial_state, stop=flag)

    def _restore(self) -> tuple[int, float]:
        """The state of the last completed step from the checkpoint: (steps done, its time)."""
        meta, arrays = load_checkpoint(self.comm, self.outdir)
        self._check_restart(meta)
        self._restored = True
        # the scene the run goes on with (a run extended by more steps, or continued with
        # other settings through the API): Results.scene and a later --restart read it
        self._store_scene()
        start, resume = meta["steps_done"], meta["time"]
        self.physics.restore(arrays, resume)
        self.records.extend(meta["records"])
        if meta.get("initial"):
            self.summary["initial"] = meta["initial"]
        # the parts before (a checkpoint from before 2026-11-29 does not know its ranks)
        self.parts = [*meta.get("parts", [{"from_step": 0, "mpi_ranks": None}]),
                      {**self.parts[-1], "from_step": start}]
        self.summary["restarted_from"] = {"step": start, "time": resume}
        self.summary["parts"] = self.parts
        self.summary["completed_steps"] = start  # a run restarted after its last step has none
        log.info("restart after step %d (t = %g s)", start, resume)
        return start, resume

    def _check_restart(self, meta: dict) -> None:
        """The checkpoint must come from the same scene on the same mesh and time steps.

        The steps it completed must end where the scene's do (the scene may add steps after
        them, as when a finished run is extended): else the run would go back in time.
        """
        summary = self.summary
        if meta["mesh"] != summary["mesh"]:
            raise ConfigError(f"the checkpoint was written for another mesh ({meta['mesh']}, "
                              f"{meta.get('dofs')} dofs) than this one ({summary['mesh']}, "
                              f"{summary.get('dofs')} dofs)")
        stored = meta.get("fingerprint")  # (none in checkpoints from before 2026-11-29)
        if stored is not None and not np.allclose(stored, self._fingerprint, rtol=1e-9,
                                                   atol=1e-12 * max(map(abs, stored))):
            d = len(stored) // 4  # lowest and highest points, sums of x and of x²
            raise ConfigError(
                "the checkpoint was written for a mesh of as many cells and vertices at other "
                f"places (bounding box {_box(stored, d)} against {_box(self._fingerprint, d)}, "
                "or points moved inside): the geometry or the mesh file changed since, and a "
                "restart continues the same mesh")
        if meta.get("dofs") != summary.get("dofs"):  # the same mesh: degree or formulation
            raise ConfigError(f"the checkpoint was written for {meta.get('dofs')} unknowns on this "
                              f"mesh, the scene has {summary.get('dofs')}: its degree, contact "
                              "formulation or friction changed since (a restart continues the "
                              "same discretization)")
        done, t = int(meta["steps_done"]), float(meta["time"])
        times = step_times(self.scene)
        if done > 0 and (done > len(times)
                         or abs(times[done - 1] - t) > 1e-12 * max(abs(t), abs(times[-1]))):
            there = (f"the scene's step {done} ends at t = {times[done - 1]:g} s"
                     if done <= len(times) else f"the scene has only {len(times)} steps")
            raise ConfigError(f"the checkpoint ends after step {done} at t = {t:g} s, but {there}: "
                             "the time keys changed since it was written (a restart continues "
                             "the same steps, and may add steps after them)")

    def _after_step(self, k: int, t: float) -> None:
        """Summary and checkpoint after step ``k`` (ending at ``t``) was accepted."""
        summary = self.summary
        summary["completed_steps"] = k + 1
        if self.outdir is None:
            return
        summary["wall_time"] = self.timer.report(self.comm)
        self._write_summary()
        if self.scene.time is not None and self.scene.output.checkpoint:
            with self.timer.phase("checkpoint"):
                meta = {"steps_done": k + 1, "time": t, "records": self.records,
                        "initial": summary.get("initial"),
                        "mesh": summary["mesh"], "dofs": summary.get("dofs"),
                        "scene": self.scene.name, "parts": self.parts,
                        "fingerprint": self._fingerprint}
                save_checkpoint(self.comm, self.outdir, meta, self.physics.state())


def run_scene(scene: Scene, outdir: str | Path | None = None, comm: MPI.Comm = MPI.COMM_WORLD,
              *, raw: dict | None = None, restart: bool = False,
              mesh: FracturedMesh | None = None) -> dict:
    """Run a scene and write its outputs to ``outdir`` step by step (collective).

    The arguments are those of :class:`Run`; the physics is freed before returning.

    Returns:
        The summary (also in ``outdir/summary.json``).

    Raises:
        SolverError: A step did not converge (outputs of earlier steps are kept).
        Interrupted: Stopped by SIGINT/SIGTERM at a step boundary.
    """
    with Run(scene, outdir, comm, raw=raw, restart=restart, mesh=mesh) as run:
        return run.execute()
