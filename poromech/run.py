"""Run a scene: mesh → spaces/forms → solves over time → output. Dispatches on ``physics``."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
from mpi4py import MPI

import poromech
from poromech.config import plane_geometry
from poromech.errors import SolverError
from poromech.mesh import FracturedMesh, create_fractured_mesh
from poromech.meshing import MeshSizes, generate_mesh
from poromech.output import write_summary
from poromech.scene import Scene
from poromech.timing import Timer

__all__ = [
    "MechanicsSimulation",
    "formulation_options",
    "RunContext",
    "build_mesh",
    "mesh_sizes",
    "run_scene",
    "time_points",
]

log = logging.getLogger("poromech")


@dataclass
class RunContext:
    """What a physics driver needs: the scene, the mesh, where to write, and the bookkeeping."""

    scene: Scene
    fm: FracturedMesh
    outdir: Path
    timer: Timer
    summary: dict = field(default_factory=dict)

    @property
    def comm(self) -> MPI.Comm:
        """The communicator of the run."""
        return self.fm.comm


def mesh_sizes(scene: Scene) -> MeshSizes:
    """Mesh sizes with the documented defaults filled in."""
    m = scene.mesh
    fracture = m.fracture_size or m.size
    return MeshSizes(
        size=m.size,
        fracture_size=fracture,
        tip_size=m.tip_size or fracture,
        transition=m.transition or 4 * m.size,
        refinement=m.refinement,
    )


def build_mesh(scene: Scene, comm: MPI.Comm, owner=None) -> FracturedMesh:
    """Generate (rank 0) and distribute the fractured mesh of a scene (collective)."""
    geo = plane_geometry(scene)
    arrays = generate_mesh(geo, mesh_sizes(scene)) if comm.rank == 0 else None
    return create_fractured_mesh(comm, geo, arrays, owner=owner)


def time_points(scene: Scene) -> list[float]:
    """Times of the solves: ``[0]`` for a static scene, else the uniform step ends."""
    if scene.time is None:
        return [0.0]
    return list(np.linspace(0.0, scene.time.final, scene.time.steps + 1)[1:])


def _mesh_summary(fm: FracturedMesh) -> dict:
    msh = fm.msh
    return {
        "cells": msh.topology.index_map(2).size_global,
        "vertices": msh.topology.index_map(0).size_global,
        "fracture_faces": fm.num_fracture_faces,
    }


def run_scene(scene: Scene, outdir: Path, comm: MPI.Comm = MPI.COMM_WORLD) -> dict:
    """Run a scene and write its outputs to ``outdir`` (collective).

    Returns:
        The summary (also written to ``outdir/summary.json``, even when a solve fails).

    Raises:
        SolverError: A solve did not converge (outputs of earlier steps are kept).
    """
    outdir = Path(outdir)
    if comm.rank == 0:
        outdir.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    timer = Timer()
    summary: dict = {
        "scene": scene.name,
        "physics": scene.physics,
        "poromech_version": poromech.__version__,
        "mpi_ranks": comm.size,
    }
    try:
        with timer.phase("mesh"):
            fm = build_mesh(scene, comm)
        summary["mesh"] = _mesh_summary(fm)
        log.info("mesh: %(cells)d cells, %(fracture_faces)d fracture faces", summary["mesh"])
        ctx = RunContext(scene, fm, outdir, timer, summary)
        if scene.physics == "flow":
            from poromech.flow.driver import run_flow

            run_flow(ctx)
        else:
            _run_mechanics(ctx)
        summary["status"] = "converged"
    except SolverError as err:
        summary["status"] = f"failed: {err}"
        raise
    finally:
        summary["wall_time"] = timer.report(comm)
        write_summary(comm, outdir, summary)
    return summary


def formulation_options(formulation: str) -> dict:
    """PETSc defaults that depend on the formulation.

    The mixed method with P1 displacements is not inf-sup stable: when every face of a fracture
    sticks there are more facewise constraints than jump dofs and the Jacobian is singular (the
    displacement is unique, the multipliers are not). MUMPS null-pivot detection
    (ICNTL(24) = 1) then returns one of the solutions instead of failing.
    """
    return {"mat_mumps_icntl_24": 1} if formulation == "mixed" else {}


class MechanicsSimulation:
    """The contact problem of a scene and its time loop (collective methods).

    Attributes:
        model: The :class:`~poromech.mechanics.MechanicsModel` (holds the current unknowns).
        solver: The :class:`~poromech.newton.SemiSmoothNewton`.
        records: One JSON-ready record per attempted step, appended as the run goes.
    """

    def __init__(self, scene: Scene, fm: FracturedMesh, timer: Timer):
        from poromech.mechanics import MechanicsModel
        from poromech.newton import SemiSmoothNewton

        self.scene, self.timer = scene, timer
        singular = scene.contact.formulation == "mixed" and scene.degree == 1
        if singular:
            log.warning("mixed with P1 displacements is not inf-sup stable: multipliers are not "
                        "unique and Newton may not converge; prefer degree 2 or stabilized_mixed")
        with timer.phase("setup"):
            self.model = model = MechanicsModel(fm, scene)
            states = (lambda: model.states(model.face_fields())) if model.faces else None
            self.solver = SemiSmoothNewton(
                model.F, model.J, model.unknowns, model.bcs, prefix="mech_",
                options={**formulation_options(model.params.formulation), **scene.solver.petsc},
                line_search=scene.solver.line_search,
                reuse_jacobian=scene.solver.reuse_jacobian,
                # a stale factorization of a singular Jacobian is no preconditioner
                stale_factorization=scene.solver.stale_factorization and not singular,
                states=states,
            )
        self.records: list[dict] = []

    def describe(self) -> dict:
        """Formulation, degree and size, for the summary."""
        return {
            "formulation": self.model.params.formulation,
            "friction": self.scene.contact.friction,
            "theta": self.scene.contact.theta,
            "degree": self.scene.degree,
            "dofs": self.model.dof_count(),
        }

    def run(self, on_step=None) -> list[dict]:
        """Solve every time step; call ``on_step(k, t, model)`` after each converged one.

        Raises:
            SolverError: A step did not converge (its record is the last of ``records``).
        """
        times = time_points(self.scene)
        for k, t in enumerate(times):
            t0 = time.perf_counter()
            self.model.set_time(t)
            rec = self.solver.solve()
            self.timer.add("assembly", rec.time_assembly)
            self.timer.add("linear_solve", rec.time_linear)
            wall = self.model.fm.comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
            entry = {"step": k + 1, "time": t, "wall_time": wall, **rec.as_dict()}
            self.records.append(entry)
            _progress(k, len(times), t, rec, wall)
            if not rec.converged:
                raise SolverError(
                    f"Newton did not converge at t = {t:g} s (step {k + 1}): {rec.reason} after "
                    f"{rec.iterations} iterations; residual history "
                    + ", ".join(f"{r:.3e}" for r in rec.residuals),
                    rec.reason, rec.residuals, entry,
                )
            self.model.accept_step()
            if on_step is not None:
                on_step(k, t, self.model)
        return self.records

    def close(self) -> None:
        """Free the PETSc objects."""
        self.solver.destroy()


def _run_mechanics(ctx: RunContext) -> None:
    from poromech.output import MechanicsOutput

    scene, timer, summary = ctx.scene, ctx.timer, ctx.summary
    sim = MechanicsSimulation(scene, ctx.fm, timer)
    summary.update(sim.describe())
    summary["solves"] = sim.records
    log.info("%s, P%d, %d dofs on %d rank(s)", summary["formulation"], scene.degree,
             summary["dofs"], ctx.comm.size)
    nsteps = len(time_points(scene))
    with timer.phase("output"):
        out = MechanicsOutput(sim.model, ctx.outdir, xdmf=scene.output.xdmf, vtx=scene.output.vtx,
                              csv_file=scene.output.fractures_csv)

    def write(k, t, model):
        if (k + 1) % scene.output.every == 0 or k + 1 == nsteps:
            with timer.phase("output"):
                values = model.face_fields()
                out.write(t, values, model.states(values))

    try:
        sim.run(on_step=write)
    finally:
        with timer.phase("output"):
            out.close()
        sim.close()


def _progress(k: int, n: int, t: float, rec, seconds: float) -> None:
    changes = ",".join(str(c) for c in rec.active_set_changes) or "-"
    first = rec.residuals[0] if rec.residuals else float("nan")
    last = rec.residuals[-1] if rec.residuals else float("nan")
    log.info(
        "step %d/%d t=%g s: %s in %d Newton it (|F| %.2e -> %.2e), active-set changes %s, "
        "%d factorizations, %.2f s",
        k + 1, n, t, rec.reason, rec.iterations, first, last, changes, rec.factorizations, seconds,
    )
