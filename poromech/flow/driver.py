"""Flow-only runs (``physics: flow``): steady or implicit Euler, output, probes, report.

``run_flow(ctx)`` is called by ``poromech run`` with a context holding the scene, the fractured
mesh, the output directory, a timer, the summary dictionary and the communicator. It builds no
mechanics. Outputs: ``flow.xdmf`` and ``fractures_flow.xdmf`` (every output time),
``probe_<name>.csv`` (final time) and ``summary["flow"]``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from poromech.flow.balance import boundary_fluxes, compute_fluxes, mass_balance
from poromech.flow.hfv import cell_gradients
from poromech.flow.output import FlowWriter
from poromech.flow.problem import DarcyProblem, TimeStep
from poromech.flow.setup import flow_properties, problem_from_scene, time_dependent
from poromech.probes import LineSampler, write_csv
from poromech.scene import Scene

__all__ = ["run_flow", "write_probes"]

log = logging.getLogger("poromech")


def _solve_record(problem: DarcyProblem, t: float, step: TimeStep | None) -> dict[str, Any]:
    """Solver statistics and conservation of the last solve (collective)."""
    fluxes = compute_fluxes(problem)
    rec = problem.records[-1]
    balance = mass_balance(problem, fluxes, t, step)
    log.info("flow t=%g s: %s in %d iterations, %.3f s; mass balance residual %.1e (relative)",
             t, rec.reason, rec.iterations, rec.seconds, balance["relative_residual"])
    return {
        "time": t,
        **rec.as_dict(),
        "mass_balance": balance,
        "boundary_fluxes": boundary_fluxes(problem, fluxes),
    }


def write_probes(scene: Scene, problem: DarcyProblem, outdir: Path) -> None:
    """Sample ``p_m`` and ``p_f`` along every probe line to ``probe_<name>.csv`` (collective)."""
    fm, g = problem.fm, problem.geom
    ends = problem.dofs.points[problem.dofs.node]
    faces = (ends, fm.fractures.index.astype(np.float64))
    grads = cell_gradients(g.area, g.normal, g.volume, problem.cell_pressure,
                           problem.face_pressure)
    for probe in scene.probes:
        sampler = LineSampler(fm.msh, probe.start, probe.end, probe.samples, faces)
        linear = probe.interpolation == "linear"
        p_m = sampler.cells(problem.cell_pressure, grads if linear else None, g.centroid)
        p_f = sampler.faces(problem.fracture_pressure, problem.node_pressure if linear else None)
        if problem.comm.rank == 0:
            x = sampler.points
            write_csv(Path(outdir) / f"probe_{probe.name}.csv", {
                "arc_length": sampler.arc_length, "x": x[:, 0], "y": x[:, 1],
                "p_m": p_m, "p_f": p_f,
            })


def _initial_step_data(scene: Scene, problem: DarcyProblem):
    """Porosity bookkeeping of a flow-only transient run from ``p⁰`` (owned cells)."""
    flow = scene.flow
    problem.set_pressure(flow.initial_pressure, 0.0)
    s = problem.properties.storage
    phi_prev = np.full(problem.geom.num_cells, flow.porosity)
    phi_fixed = phi_prev - s * problem.cell_pressure
    return phi_prev, phi_fixed


def _transient(ctx, problem: DarcyProblem, writer: FlowWriter | None, records: list) -> None:
    """Implicit Euler steps with output every ``output.every`` steps."""
    scene, timer = ctx.scene, ctx.timer
    dt = scene.time.final / scene.time.steps
    phi_prev, phi_fixed = _initial_step_data(scene, problem)
    varying = time_dependent(scene)
    geom = problem.geom
    if writer is not None:
        with timer.phase("flow_output"):
            writer.write(0.0, compute_fluxes(problem))
    aperture_prev = problem.properties.aperture.copy()
    for n in range(1, scene.time.steps + 1):
        t = n * dt
        if varying:
            problem.set_properties(flow_properties(scene, ctx.fm, geom, t))
        step = TimeStep(dt, phi_prev, phi_fixed, aperture_prev)
        with timer.phase("flow_solve"):
            problem.solve(t, step)
        records.append(_solve_record(problem, t, step))
        aperture_prev = problem.properties.aperture.copy()
        phi_prev = problem.porosity(step)
        last = n == scene.time.steps
        if writer is not None and (n % scene.output.every == 0 or last):
            with timer.phase("flow_output"):
                writer.write(t, compute_fluxes(problem))


def _summary(problem: DarcyProblem, records: list) -> dict[str, Any]:
    """The ``summary["flow"]`` entry: sizes, solver, per-solve records, final conservation."""
    counts = problem.dofs.counts
    out: dict[str, Any] = {
        "unknowns": {"total": problem.dofs.num_global, **counts},
        "solver": problem.solver.describe(),
        "solves": records,
        "linear_iterations": int(sum(r["iterations"] for r in records)),
        "solve_seconds": float(sum(r["seconds"] for r in records)),
        "flux_unit": "m^2/s (volumetric flux per unit depth)",
    }
    if records:
        last = records[-1]
        out["conservation"] = {
            "time": last["time"],
            **last["mass_balance"],
            "max_relative_residual": max(r["mass_balance"]["relative_residual"] for r in records),
            "boundary_fluxes": last["boundary_fluxes"],
        }
    return out


def run_flow(ctx) -> None:
    """Run a flow-only scene (collective).

    Args:
        ctx: Run context with attributes ``scene`` (:class:`Scene`), ``fm``
            (:class:`~poromech.mesh.FracturedMesh`), ``outdir`` (existing directory),
            ``timer`` (:class:`~poromech.timing.Timer`), ``summary`` (dict, filled here) and
            ``comm``.

    Raises:
        poromech.errors.SolverError: A linear solve did not converge (the summary then holds
            the solves done so far).
    """
    scene, timer = ctx.scene, ctx.timer
    with timer.phase("flow_setup"):
        problem = problem_from_scene(scene, ctx.fm)
        solver = problem.solver.describe()
        log.info("flow: %d unknowns (%s), solver %s/%s", problem.dofs.num_global,
                 ", ".join(f"{v} {k}" for k, v in problem.dofs.counts.items()),
                 solver["ksp_type"], solver["pc_type"])
        writer = FlowWriter(problem, Path(ctx.outdir)) if scene.output.xdmf else None
    records: list[dict[str, Any]] = []
    try:
        if scene.time is None:
            with timer.phase("flow_solve"):
                problem.solve(0.0)
            records.append(_solve_record(problem, 0.0, None))
            if writer is not None:
                with timer.phase("flow_output"):
                    writer.write(0.0, compute_fluxes(problem))
        else:
            _transient(ctx, problem, writer, records)
        with timer.phase("flow_output"):
            write_probes(scene, problem, Path(ctx.outdir))
    finally:
        ctx.summary["flow"] = _summary(problem, records)
        if writer is not None:
            writer.close()
        problem.destroy()
