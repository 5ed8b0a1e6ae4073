"""Run a scene: mesh → models → (coupling) → time loop → output. Dispatches on ``physics``."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
import yaml
from mpi4py import MPI

import poromech
from poromech.errors import SolverError
from poromech.io.checkpoint import load_checkpoint, save_checkpoint
from poromech.io.output import write_summary
from poromech.mechanics.physics import MechanicsSimulation, formulation_options
from poromech.mesh.fractured import FracturedMesh, create_fractured_mesh
from poromech.mesh.generate import generate_mesh
from poromech.parallel import agree
from poromech.scene.fields import validate_fields
from poromech.scene.geometry import mesh_sizes, plane_geometry
from poromech.scene.schema import Scene, step_times
from poromech.stepping import Interrupted, run_steps, stop_signals
from poromech.timing import Timer

__all__ = [
    "MechanicsSimulation",
    "RunContext",
    "SCENE_FILE",
    "build_mesh",
    "formulation_options",
    "make_simulation",
    "mesh_sizes",
    "run_scene",
    "time_points",
]

log = logging.getLogger("poromech")

#: The validated scene (after overrides) is stored next to the outputs, for ``--restart``.
SCENE_FILE = "poromech_scene.yaml"


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


def build_mesh(scene: Scene, comm: MPI.Comm, owner=None) -> FracturedMesh:
    """Generate or read (rank 0) and distribute the fractured mesh of a scene (collective).

    A failure of gmsh or of the mesh file on rank 0 is raised on every rank.
    """
    geo = plane_geometry(scene)
    arrays, err = None, None
    if comm.rank == 0:
        try:
            if scene.geometry.mesh is not None:
                from poromech.mesh.imported import mesh_file_arrays

                arrays = mesh_file_arrays(scene.geometry.mesh, geo, scene.mesh.refinement)
            else:
                arrays = generate_mesh(geo, mesh_sizes(scene))
        except Exception as e:  # noqa: BLE001  (re-raised on every rank by agree)
            err = e
    agree(comm, err)
    return create_fractured_mesh(comm, geo, arrays, owner=owner)


def time_points(scene: Scene) -> list[float]:
    """Times of the solves: ``[0]`` for a static scene, else the step end times."""
    return step_times(scene)


def _mesh_summary(fm: FracturedMesh) -> dict:
    msh = fm.msh
    return {
        "cells": msh.topology.index_map(2).size_global,
        "vertices": msh.topology.index_map(0).size_global,
        "fracture_faces": fm.num_fracture_faces,
    }


def make_simulation(scene: Scene, fm: FracturedMesh, timer: Timer):
    """The physics object of a scene (collective)."""
    if scene.physics == "flow":
        from poromech.flow.physics import FlowSimulation

        return FlowSimulation(scene, fm, timer)
    if scene.physics == "poromechanics":
        from poromech.coupling.poromechanics import PoromechanicsSimulation

        return PoromechanicsSimulation(scene, fm, timer)
    return MechanicsSimulation(scene, fm, timer)


def run_scene(scene: Scene, outdir: Path, comm: MPI.Comm = MPI.COMM_WORLD, *,
              raw: dict | None = None, restart: bool = False) -> dict:
    """Run a scene and write its outputs to ``outdir`` step by step (collective).

    Args:
        scene: The validated scene.
        outdir: Output directory (created if needed).
        comm: Communicator.
        raw: The scene mapping it was built from; stored as ``scene.yaml`` for ``--restart``.
        restart: Continue the run in ``outdir`` from its checkpoint.

    Returns:
        The summary (also in ``outdir/summary.json``, rewritten after every step, and written
        with the failure status when a step fails).

    Raises:
        SolverError: A step did not converge (outputs of earlier steps are kept).
        Interrupted: Stopped by SIGINT/SIGTERM at a step boundary.
    """
    outdir = Path(outdir)
    if comm.rank == 0:
        outdir.mkdir(parents=True, exist_ok=True)
        if raw is not None and not restart:
            (outdir / SCENE_FILE).write_text(yaml.safe_dump(raw, sort_keys=False))
    comm.barrier()
    timer = Timer()
    summary: dict = {
        "scene": scene.name,
        "physics": scene.physics,
        "poromech_version": poromech.__version__,
        "mpi_ranks": comm.size,
        "status": "running",
    }
    sim = None
    try:
        with timer.phase("mesh"):
            fm = build_mesh(scene, comm)
        validate_fields(scene, fm)  # every expression where it is evaluated, every step time
        summary["mesh"] = _mesh_summary(fm)
        log.info("mesh: %(cells)d cells, %(fracture_faces)d fracture faces", summary["mesh"])
        sim = make_simulation(scene, fm, timer)
        summary.update(sim.describe())
        _loop(sim, RunContext(scene, fm, outdir, timer, summary), restart)
        summary["status"] = "converged"
    except SolverError as err:
        summary["status"] = f"failed: {err}"
        raise
    except Interrupted as err:
        summary["status"] = f"interrupted: {err}"
        raise
    except BaseException as err:
        summary["status"] = f"error: {type(err).__name__}: {err}"
        raise
    finally:
        if sim is not None:
            sim.finish(summary)
            sim.close()
        summary["wall_time"] = timer.report(comm)
        write_summary(comm, outdir, summary)
    return summary


def _loop(sim, ctx: RunContext, restart: bool) -> None:
    """Initial state (or checkpoint), writers, then the time steps with per-step bookkeeping."""
    scene, comm, summary, outdir = ctx.scene, ctx.comm, ctx.summary, ctx.outdir
    key = "flow" if scene.physics == "flow" else None
    records: list[dict] = sim.records
    (summary.setdefault("flow", {}) if key else summary)["solves"] = records
    start, resume = 0, None
    if restart:
        meta, arrays = load_checkpoint(comm, outdir)
        _check_restart(meta, summary)
        start, resume = meta["steps_done"], meta["time"]
        sim.restore(arrays, resume)
        records.extend(meta["records"])
        if meta.get("initial"):
            summary["initial"] = meta["initial"]
        summary["restarted_from"] = {"step": start, "time": resume}
        log.info("restart after step %d (t = %g s)", start, resume)
    else:
        initial = sim.initialize()
        if initial is not None:
            summary["initial"] = initial
    sim.open_output(outdir, resume_until=resume)
    checkpoints = scene.time is not None and scene.output.checkpoint

    def on_step(k: int, t: float) -> None:
        summary["completed_steps"] = k + 1
        summary["wall_time"] = ctx.timer.report(comm)
        write_summary(comm, outdir, summary)
        if checkpoints:
            with ctx.timer.phase("checkpoint"):
                meta = {"steps_done": k + 1, "time": t, "records": records,
                        "initial": summary.get("initial"),
                        "mesh": summary["mesh"], "dofs": summary.get("dofs"),
                        "scene": scene.name}
                save_checkpoint(comm, outdir, meta, sim.state())

    write_summary(comm, outdir, summary)
    with stop_signals() as flag:
        run_steps(sim, scene, comm, records, on_step, start=start,
                  write_initial=not restart and scene.time is not None
                  and getattr(sim, "has_initial_output", False), stop=flag)


def _check_restart(meta: dict, summary: dict) -> None:
    """The checkpoint must come from the same scene on the same mesh."""
    if meta["mesh"] != summary["mesh"] or meta.get("dofs") != summary.get("dofs"):
        raise ValueError(f"the checkpoint was written for another mesh ({meta['mesh']}, "
                         f"{meta.get('dofs')} dofs) than this one ({summary['mesh']}, "
                         f"{summary.get('dofs')} dofs)")


def final_time(scene: Scene) -> float:
    """Time of the last step (0 for a static scene)."""
    return float(np.max(step_times(scene)))
