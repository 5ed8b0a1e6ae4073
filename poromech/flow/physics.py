"""Flow-only runs (``physics: flow``): the Darcy physics behind the time loop.

:class:`FlowPhysics` implements :class:`poromech.physics.Physics` for a steady solve or
implicit Euler steps; it builds no mechanics. Outputs: ``flow.xdmf``, ``fractures_flow.xdmf`` and
``probe_<name>.csv`` (every output time, from ``t = 0`` for transient runs) and
``summary["flow"]``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from poromech.errors import SolverError
from poromech.flow.balance import boundary_fluxes, compute_fluxes, mass_balance
from poromech.flow.hfv import cell_gradients
from poromech.flow.output import FlowWriter
from poromech.flow.problem import DarcyProblem, TimeStep
from poromech.flow.setup import (
    check_pressure_level,
    flow_properties,
    problem_from_scene,
    time_dependent,
)
from poromech.flow.state import FlowState
from poromech.io.probes import LineSampler, fracture_sides, open_probes
from poromech.mesh.entities import fracture_segments
from poromech.physics import Keyed, StepResult
from poromech.scene.schema import Scene

__all__ = ["FlowPhysics", "flow_report", "pressure_columns", "probe_faces", "solve_record"]

log = logging.getLogger("poromech")

#: Relative mass-balance residual (``summary.json`` → ``mass_balance``) above which a flow step
#: fails although its linear solve met its tolerance. Normal steps hold the balance to 1e-10 and
#: below; with fracture permeabilities 1e12 / 1e16 / 1e20 times the matrix's (Flemisch case 2)
#: 5.7e-6 / 2.6e-3 / 1.0 with CG and 1.6e-5 / 0.32 / 0.63 with LU: a contrast beyond what double
#: precision resolves, written as converged before. A fluid at rest is measured against the
#: round-off of its fluxes (:func:`~poromech.flow.balance.mass_balance`), not against its flow.
MASS_BALANCE_FAIL = 1e-3

#: Largest cell or fracture-face balance residual, relative to the flow (``mass_balance`` →
#: ``max_local_residual``), above which a flow run warns (once) that single cells are not
#: resolved. The shipped flow scenes hold 3e-10 to 1e-7; a matrix of 1e-21 m² under fractures
#: of 1e-7 m² (a contrast of 1e14, LU after CG failed) held the global balance to 3e-5 and
#: single cells only to 1.1e-2 of the flow, as much as their own fluxes, and was written
#: without a word.
LOCAL_BALANCE_WARN = 1e-4


def solve_record(problem: DarcyProblem, t: float, step: TimeStep | None) -> dict[str, Any]:
    """Solver statistics and conservation of the last solve (collective)."""
    fluxes = compute_fluxes(problem)
    rec = problem.records[-1]
    return {
        "time": t,
        **rec.as_dict(),
        "mass_balance": mass_balance(problem, fluxes, t, step),
        "boundary_fluxes": boundary_fluxes(problem, fluxes),
    }


def probe_faces(problem: DarcyProblem) -> tuple:
    """The owned fracture faces for probes, and their keys.

    In 2D the segments between their node unknowns, in 3D the triangles.
    """
    fm = problem.fm
    keys = fm.fractures.index.astype(np.float64)
    if problem.dim == 3:
        return fracture_segments(fm.msh, fm.fractures.facets), keys
    return problem.dofs.points[problem.dofs.node], keys


def pressure_columns(problem: DarcyProblem, probe, sampler: LineSampler) -> dict:
    """``p_m`` and ``p_f`` along a probe line, on rank 0 (collective).

    ``probe.interpolation`` linear: ``p_m`` from the HFV cell gradient, ``p_f`` linear between
    face and node values; constant: the cell and face values.
    """
    g = problem.geom
    linear = probe.interpolation == "linear"
    grads = cell_gradients(g.area, g.normal, g.volume, problem.cell_pressure,
                           problem.face_pressure) if linear else None
    return {"p_m": sampler.cells(problem.cell_pressure, grads, g.centroid),
            "p_f": sampler.faces(problem.fracture_pressure,
                                 problem.branch_pressure if linear else None)}


class FlowPhysics:
    """A flow-only scene as a :class:`~poromech.physics.Physics` (collective methods).

    Args:
        scene: The scene (``physics: flow``).
        fm: The fractured mesh.
        timer: Wall-time accounting.
    """

    counters = ("iterations", "seconds", "setup_seconds")
    records_section = "flow"

    def __init__(self, scene: Scene, fm, timer):
        self.scene, self.fm, self.timer = scene, fm, timer
        with timer.phase("flow_setup"):
            self.problem = problem_from_scene(scene, fm)
            check_pressure_level(scene, self.problem)
        solver = self.problem.solver.describe()
        log.info("flow: %d unknowns (%s), solver %s/%s", self.problem.dofs.num_global,
                 ", ".join(f"{v} {k}" for k, v in self.problem.dofs.counts.items()),
                 solver["ksp_type"], solver["pc_type"])
        self.varying = time_dependent(scene)
        self.writer: FlowWriter | None = None
        self.probes: list[tuple] = []
        self.writes_initial_state = scene.time is not None
        self.accepted = FlowState(self.problem)
        self._step: TimeStep | None = None
        self._porosity_fixed = None
        self._warned_local = False  # a step held single cells only to > LOCAL_BALANCE_WARN

    def describe(self) -> dict:
        """Nothing beyond the flow report (``summary["flow"]``)."""
        return {}

    def initialize(self) -> dict | None:
        """Initial pressure and porosity of a transient run (no solve)."""
        if self.scene.time is None:
            return None
        flow, pb = self.scene.flow, self.problem
        pb.set_pressure(flow.initial_pressure, 0.0)
        porosity = np.full(pb.geom.num_cells, flow.porosity)
        self._porosity_fixed = porosity - pb.properties.storage * pb.cell_pressure
        self.accepted.accept(porosity, pb.properties.aperture.copy())
        return None

    def solve(self, t: float, dt: float | None) -> StepResult:
        """One steady solve or one implicit Euler step ending at ``t``."""
        pb = self.problem
        if self.varying and dt is not None:
            pb.set_properties(flow_properties(self.scene, self.fm, pb.geom, t))
        self._step = None if dt is None else TimeStep(dt, self.accepted.porosity,
                                                      self._porosity_fixed,
                                                      self.accepted.aperture)
        try:
            with self.timer.phase("flow_solve"):
                pb.solve(t, self._step)
        except SolverError as err:
            return StepResult(False, {"time": t, **err.record}, str(err), err.reason,
                              err.history)
        record = solve_record(pb, t, self._step)
        balance = record["mass_balance"]["relative_residual"]
        if not balance <= MASS_BALANCE_FAIL:
            return StepResult(False, record, (
                f"the flow solve at t = {t:g} s met its tolerance ({record['reason']}) but holds "
                f"the mass balance only to {balance:.1e} of the flow (more than "
                f"{MASS_BALANCE_FAIL:g}): the conductivities span more decades than double "
                "precision resolves (fracture against matrix permeability?), or the linear "
                "tolerance is too loose for them"), "DIVERGED_MASS_BALANCE", [])
        local = record["mass_balance"]["max_local_residual"]
        if local > LOCAL_BALANCE_WARN and not self._warned_local:
            self._warned_local = True  # the records keep every step's value
            log.warning(
                "the flow solve at t = %g s holds the global mass balance to %.1e but single "
                "cells or fracture faces only to %.1e of the flow (more than %g; summary.json "
                "has every step's max_local_residual): the pressure of the least conductive "
                "cells is not resolved, the conductivities span more decades than double "
                "precision resolves", t, balance, local, LOCAL_BALANCE_WARN)
        return StepResult(True, record)

    def progress(self, k: int, n: int, t: float, result: StepResult) -> str:
        """One line per step: iterations and the mass balance."""
        r = result.record
        return (f"flow step {k + 1}/{n} t={t:g} s: {r['reason']} in {r['iterations']} "
                f"iterations; mass balance residual {r['mass_balance']['relative_residual']:.1e} "
                "(relative)")

    def accept(self, t: float) -> None:
        """The solved porosity and aperture become those of the previous step."""
        pb, step = self.problem, self._step
        if step is None:
            self.accepted.accept(None, None)
        else:
            self.accepted.accept(pb.porosity(step), pb.properties.aperture.copy())

    def reject(self) -> None:
        """Back to the pressures of the last accepted step (the initial guess)."""
        self.accepted.reject()

    # -- output --------------------------------------------------------------------------
    def open_output(self, outdir: Path, resume_until: float | None = None) -> None:
        """Create the XDMF writers (if selected by ``output.xdmf``) and the probe files."""
        with self.timer.phase("flow_output"):
            if self.scene.output.xdmf:
                self.writer = FlowWriter(self.problem, Path(outdir), resume_until=resume_until)
            self.probes = open_probes(self.fm.msh, self.scene.probes, outdir,
                                      probe_faces(self.problem), resume_until,
                                      fracture_sides(self.fm))

    def write(self, t: float) -> None:
        """Write the flow fields and the probes at ``t``."""
        with self.timer.phase("flow_output"):
            if self.writer is not None:
                self.writer.write(t, compute_fluxes(self.problem))
            for probe, table in self.probes:
                table.write(t, pressure_columns(self.problem, probe, table.sampler))

    def finish(self, summary: dict, records: list[dict]) -> None:
        """The flow report (``summary["flow"]``)."""
        summary.setdefault("flow", {}).update(flow_report(self.problem, records))

    # -- checkpoint ----------------------------------------------------------------------
    def state(self) -> dict[str, Keyed]:
        """Pressures, porosity and aperture of the accepted step."""
        return self.accepted.checkpoint()

    def restore(self, arrays: dict, t: float) -> None:
        """Continue after the step ending at ``t`` from checkpoint arrays."""
        self.initialize()
        self.accepted.restore(arrays)

    def close(self) -> None:
        """Free the PETSc objects."""
        self.problem.destroy()


def flow_report(problem: DarcyProblem, records: list, iterations: str = "iterations",
                seconds: str = "seconds") -> dict[str, Any]:
    """The ``summary["flow"]`` entry: sizes, solver, final conservation (records separate).

    ``iterations`` and ``seconds``: the record keys of the linear work (a coupled run's records
    count its Darcy solves as ``darcy_iterations`` and ``darcy_seconds``).
    """
    counts = problem.dofs.counts
    out: dict[str, Any] = {
        "unknowns": {"total": problem.dofs.num_global, **counts},
        "solver": problem.solver.describe(),
        "linear_iterations": int(sum(r.get(iterations, 0) for r in records)),
        "solve_seconds": float(sum(r.get(seconds, 0.0) for r in records)),
        "flux_unit": ("m^3/s (volumetric flux)" if problem.dim == 3
                      else "m^2/s (volumetric flux per unit depth)"),
    }
    done = [r for r in records if "mass_balance" in r]
    if done:
        last = done[-1]
        out["conservation"] = {
            "time": last["time"],
            **last["mass_balance"],
            "max_relative_residual": max(r["mass_balance"]["relative_residual"] for r in done),
        }
        if "boundary_fluxes" in last:  # flow runs (a coupled run has them in its summary)
            out["conservation"]["boundary_fluxes"] = last["boundary_fluxes"]
    return out
