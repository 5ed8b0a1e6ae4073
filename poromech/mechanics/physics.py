"""The contact-mechanics physics behind the time loop (:mod:`poromech.stepping`).

:class:`MechanicsSimulation` owns the :class:`~poromech.mechanics.model.MechanicsModel`, its
semi-smooth Newton and its writers; it is used on its own (``physics: mechanics``) and inside the
coupled poromechanics solver.
"""

from __future__ import annotations

import logging
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
from petsc4py import PETSc

from poromech.io.checkpoint import (
    cell_dof_rows,
    face_dof_rows,
    set_cell_dof_rows,
    set_face_dof_rows,
)
from poromech.io.output import FractureTable, displacement_mesh, fracture_mesh, owned_blocks
from poromech.io.xdmf import XDMFSeries
from poromech.mesh.fractured import FracturedMesh
from poromech.scene.schema import Scene
from poromech.stepping import StepResult, run_steps
from poromech.timing import Timer

__all__ = ["MechanicsSimulation", "formulation_options"]

log = logging.getLogger("poromech")

#: Face fields written to ``fractures.xdmf`` and ``fractures.csv`` (besides ``state``).
WRITTEN_FACE_FIELDS = ("jump_n", "jump_t", "traction_n", "traction_t")
#: Face fields written to ``fractures.xdmf`` only: the fractions of the face in contact and
#: sliding (they differ from 0 and 1 only where pointwise Nitsche switches inside a face).
XDMF_ONLY_FACE_FIELDS = ("contact_fraction", "slip_fraction")


class _Values:
    """A stand-in for a function with other values (same space), for checkpoint rows."""

    def __init__(self, f, values):
        self.function_space, self.name = f.function_space, f.name
        self.x = type("X", (), {"array": values})()


def scalar_row(comm, value: float):
    """A scalar as a keyed checkpoint array (one row, given by rank 0)."""
    ids = np.zeros(1 if comm.rank == 0 else 0, dtype=np.int64)
    return ids, np.full(len(ids), float(value))


def formulation_options(formulation: str) -> dict:
    """PETSc defaults that depend on the formulation.

    The mixed method with P1 displacements is not inf-sup stable: when every face of a fracture
    sticks there are more facewise constraints than jump dofs and the Jacobian is singular (the
    displacement is unique, the multipliers are not). MUMPS null-pivot detection
    (ICNTL(24) = 1) then returns one of the solutions instead of failing.
    """
    return {"mat_mumps_icntl_24": 1} if formulation == "mixed" else {}


class MechanicsSimulation:
    """The contact problem of a scene as a :class:`~poromech.stepping.Physics` (collective).

    Args:
        scene: The scene.
        fm: The fractured mesh.
        timer: Wall-time accounting.

    Attributes:
        model: The :class:`~poromech.mechanics.model.MechanicsModel` (holds the current unknowns).
        solver: The :class:`~poromech.mechanics.newton.SemiSmoothNewton`.
        records: One JSON-ready record per completed step (filled by :meth:`run`).
    """

    counters = ("iterations", "face_iterations", "linear_iterations", "factorizations",
                "stale_solves", "jacobian_reuses", "residual_evaluations", "time_assembly",
                "time_linear")

    def __init__(self, scene: Scene, fm: FracturedMesh, timer: Timer):
        from poromech.mechanics.model import MechanicsModel
        from poromech.mechanics.newton import SemiSmoothNewton

        self.scene, self.timer, self.fm = scene, timer, fm
        singular = scene.contact.formulation == "mixed" and scene.degree == 1
        if singular:
            log.warning("mixed with P1 displacements is not inf-sup stable: multipliers are not "
                        "unique and Newton may not converge; prefer degree 2 or stabilized_mixed")
        with timer.phase("setup"):
            self.model = model = MechanicsModel(fm, scene)
            states = model.active_set if model.faces else None
            self.solver = SemiSmoothNewton(
                model.F, model.J, model.unknowns, model.bcs, prefix="mech_",
                options={**formulation_options(model.params.formulation), **scene.solver.petsc},
                line_search=scene.solver.line_search,
                reuse_jacobian=scene.solver.reuse_jacobian,
                # a stale factorization of a singular Jacobian is no preconditioner
                stale_factorization=scene.solver.stale_factorization and not singular,
                states=states,
            )
        # only Young's modulus and Poisson's ratio enter the Jacobian besides the contact
        # branches: while they are constant in time, an unchanged active set reuses it
        material = scene.material
        self.solver.states_determine_jacobian = not (
            material.young.depends_on_time or material.poisson.depends_on_time)
        self.solver.condensed = self._condensed()
        self.records: list[dict] = []
        self.has_initial_output = False
        self._saved = [f.x.array.copy() for f in model.unknowns]
        self._series: dict[str, XDMFSeries] = {}
        self._table: FractureTable | None = None

    def _condensed(self):
        """A :class:`~poromech.mechanics.condensed.CondensedContact` where it applies, else None."""
        from poromech.mechanics.condensed import MAX_FACE_UNKNOWNS, CondensedContact, applicable
        from poromech.mechanics.newton import _is_direct

        m, scene, ksp = self.model, self.scene, self.solver.snes.getKSP()
        if not (scene.solver.condensation and m.lam is not None
                and applicable(m.params.formulation, scene.degree, scene.contact.friction)
                and self.solver.states_determine_jacobian and _is_direct(ksp)
                and ksp.getPC().getFactorSolverType() == "mumps"):
            return None
        V = m.lam.function_space
        n = V.dofmap.index_map.size_global * V.dofmap.index_map_bs
        if n > MAX_FACE_UNKNOWNS:
            log.info("%d multiplier unknowns: more than %d, the contact problem is not condensed",
                     n, MAX_FACE_UNKNOWNS)
            return None
        try:
            with self.timer.phase("setup"):
                return CondensedContact(m, self.solver)
        except (RuntimeError, PETSc.Error) as err:
            log.warning("the contact problem is not condensed: %s", err)
            return None

    def describe(self) -> dict:
        """Formulation, degree and size, for the summary."""
        out = {
            "formulation": self.model.params.formulation,
            "friction": self.scene.contact.friction,
            "theta": self.scene.contact.theta,
            "degree": self.scene.degree,
            "dofs": self.model.dof_count(),
            "beta_n": self.model.beta0[0],
            "beta_t": self.model.beta0[1],
        }
        if self.model.beta_sm0 is not None:
            out["beta_sm_n"], out["beta_sm_t"] = self.model.beta_sm0
        c = self.solver.condensed
        out["condensed"] = None if c is None else c.describe()
        if self.model.coercivity_ratio is not None:
            out["coercivity_ratio"] = self.model.coercivity_ratio
        if self.model.warnings:
            out["warnings"] = list(self.model.warnings)
        return out

    # -- Physics interface -----------------------------------------------------------------
    def initialize(self) -> dict | None:
        """Nothing to solve: the displacement starts at zero."""
        return None

    def solve(self, t: float, dt: float | None) -> StepResult:
        """Semi-smooth Newton at time ``t`` from the current unknowns."""
        self.model.set_time(t)
        rec = self.solver.solve()
        self.timer.add("assembly", rec.time_assembly)
        self.timer.add("linear_solve", rec.time_linear)
        message = ""
        if not rec.converged:
            message = (f"Newton did not converge at t = {t:g} s: {rec.reason} after "
                       f"{rec.iterations} iterations; residual history "
                       + ", ".join(f"{r:.3e}" for r in rec.residuals))
        return StepResult(rec.converged, rec.as_dict(), message, rec.reason, rec.residuals)

    def accept(self, t: float) -> None:
        """The solved displacement becomes the reference of the next slip increment."""
        self.model.accept_step()
        for saved, f in zip(self._saved, self.model.unknowns, strict=True):
            saved[:] = f.x.array

    def reject(self) -> None:
        """Back to the unknowns of the last accepted step."""
        for saved, f in zip(self._saved, self.model.unknowns, strict=True):
            f.x.array[:] = saved

    def progress(self, k: int, n: int, t: float, result: StepResult) -> str:
        """One line per step: Newton iterations, residuals, active-set changes."""
        rec = result.record
        changes = ",".join(str(c) for c in rec["active_set_changes"]) or "-"
        res = rec["residuals"] or [float("nan")]
        face = f" (+{rec['face_iterations']} face Newton)" if rec.get("face_iterations") else ""
        return (f"step {k + 1}/{n} t={t:g} s: {rec['reason']} in {rec['iterations']} Newton "
                f"it{face} "
                f"(|F| {res[0]:.2e} -> {res[-1]:.2e}), active-set changes {changes}, "
                f"{rec['factorizations']} factorizations")

    # -- output ------------------------------------------------------------------------------
    def open_output(self, outdir: Path, resume_until: float | None = None,
                    fracture_columns: tuple[str, ...] = ()) -> None:
        """Create the writers selected by ``scene.output`` (collective).

        Args:
            outdir: Output directory.
            resume_until: Continue the series of an earlier run up to this time.
            fracture_columns: Extra face fields (written by a coupled run).
        """
        out = self.scene.output
        comm = self.fm.comm
        with self.timer.phase("output"):
            if out.xdmf:
                self._series["u"] = XDMFSeries(comm, outdir, "displacement",
                                               displacement_mesh(self.model.V), "u",
                                               resume_until)
                if self.model.faces is not None:
                    self._series["fractures"] = XDMFSeries(comm, outdir, "fractures",
                                                           fracture_mesh(self.fm), "fractures",
                                                           resume_until)
            if out.fractures_csv and self.model.faces is not None:
                columns = (*WRITTEN_FACE_FIELDS, "state", *fracture_columns)
                self._table = FractureTable(self.fm, Path(outdir) / "fractures.csv", columns,
                                            resume_until)

    def face_output(self) -> dict[str, np.ndarray]:
        """The written face fields and states of the owned fracture faces."""
        from poromech.mechanics.model import FACE_FIELDS

        values = self.model.face_fields()
        out = {name: values[:, FACE_FIELDS.index(name)]
               for name in (*WRITTEN_FACE_FIELDS, *XDMF_ONLY_FACE_FIELDS)}
        out["state"] = self.model.states(values)
        return out

    def write(self, t: float, extra_faces: dict[str, np.ndarray] | None = None) -> None:
        """Write the displacement, the fracture fields and the fracture table at ``t``."""
        with self.timer.phase("output"):
            faces = None
            if "u" in self._series:
                self._series["u"].write(t, point_data={"u": owned_blocks(self.model.u)})
            if self.model.faces is not None and (self._table or "fractures" in self._series):
                faces = {**self.face_output(), **(extra_faces or {})}
            if "fractures" in self._series:
                self._series["fractures"].write(t, cell_data=faces)
            if self._table is not None:
                self._table.write(t, {k: v for k, v in faces.items()
                                      if k not in XDMF_ONLY_FACE_FIELDS})

    # -- checkpoint ----------------------------------------------------------------------
    def _rows(self, f, values=None):
        """A function's values (or ``values`` in its layout), keyed independently of the partition.

        By input cell (displacements) or by fracture face (multipliers, averages).
        """
        m = self.model
        if values is not None:
            f = _Values(f, values)
        if f.function_space.mesh is m.submesh and m.submesh is not None:
            return face_dof_rows(self.fm, f, m.emap)
        return cell_dof_rows(self.fm, f)

    def _set_rows(self, f, rows) -> None:
        m = self.model
        if f.function_space.mesh is m.submesh and m.submesh is not None:
            set_face_dof_rows(self.fm, f, m.emap, rows)
        else:
            set_cell_dof_rows(self.fm, f, rows)

    def state(self) -> dict:
        """Unknowns, slip reference and the predictor's previous step, partition-independent."""
        m = self.model
        out = {f.name: self._rows(f) for f in m.unknowns}
        if m.u_prev is not None:
            out["u_prev"] = cell_dof_rows(self.fm, m.u_prev)
        out["reference_norm"] = scalar_row(self.fm.comm, self.solver.reference_norm)
        history = getattr(m, "_history", [])
        if len(history) == 2:
            t0, arrays = history[0]
            for f, a in zip(m.unknowns, arrays, strict=True):
                out[f"previous_{f.name}"] = self._rows(f, a)
            out["previous_time"] = scalar_row(self.fm.comm, t0)
        return out

    def restore(self, arrays: dict, t: float) -> None:
        """Set the unknowns of the step ending at ``t`` from checkpoint arrays; accept them."""
        m = self.model
        previous = []
        if "previous_time" in arrays:
            for f in m.unknowns:
                self._set_rows(f, arrays[f"previous_{f.name}"])
                previous.append(f.x.array.copy())
        for f in m.unknowns:
            self._set_rows(f, arrays[f.name])
        if m.u_prev is not None:
            set_cell_dof_rows(self.fm, m.u_prev, arrays["u_prev"])
        self.solver.reference_norm = float(arrays["reference_norm"][0])
        m._t = t
        m._history = [(float(arrays["previous_time"][0]), previous)] if previous else []
        m._history.append((t, [f.x.array.copy() for f in m.unknowns]))
        for saved, f in zip(self._saved, m.unknowns, strict=True):
            saved[:] = f.x.array

    def finish(self, summary: dict) -> None:
        """The work of the condensed solve, if any."""
        if self.solver.condensed is not None:
            summary["condensed"] = self.solver.condensed.describe()

    def run(self) -> list[dict]:
        """Solve every time step of the scene without writing anything (for studies, tests).

        Raises:
            SolverError: A step failed after the allowed step cuts.
        """
        run_steps(self, self.scene, self.fm.comm, self.records, lambda k, t: None)
        return self.records

    def close(self) -> None:
        """Free the PETSc objects."""
        self.solver.destroy()

