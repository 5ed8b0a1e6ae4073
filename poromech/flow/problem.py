"""The mixed-dimensional HFV Darcy problem: unknowns, coefficients, PETSc system and solves.

This is the entry point a coupled (poromechanical) problem uses. Per time step it passes the
porosity increments coming from the displacement and the current face apertures, and calls
:meth:`DarcyProblem.solve`; only values change, never the matrix pattern (DESIGN §5 "Time"):

* matrix cells: ``|K| (φ_Kⁿ - φ_Kⁿ⁻¹)/Δt + (1/η) Σ_σ F_{K,σ} = |K| q_K`` with
  ``φ_Kⁿ = φ̂_Kⁿ + s_K p_Kⁿ`` (``s_K = 1/M``, ``φ̂_Kⁿ = φ⁰ + b((div uⁿ)_K - (div u⁰)_K) - p⁰/M``);
* fracture faces: ``|σ| (d_σⁿ - d_σⁿ⁻¹)/Δt + (1/η)(Σ_e F_{σ,e} - Σ_K F^{mf}_{K,σ}) = |σ| q_σ``.

Units are SI: pressure Pa, permeability m², viscosity Pa·s, apertures m, sources 1/s (matrix)
and m/s (fracture, per fracture area), fluxes per unit depth in 2D.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import dolfinx_solver  # noqa: F401  (orders MPI before the bindings)

import numpy as np
import numpy.typing as npt
from mpi4py import MPI
from petsc4py import PETSc

from poromech.errors import ConfigError, SolverError
from poromech.flow import hfv
from poromech.flow.boundary import FlowBoundary, boundary_dofs
from poromech.flow.dofs import FlowDofs, number_dofs
from poromech.flow.intersections import (
    FractureCrossings,
    crossing_resistance,
    series_transmissibilities,
)
from poromech.flow.shift import TraceShift
from poromech.flow.solver import LinearRecord, LinearSolver
from poromech.flow.system import (
    ElementValues,
    SystemPattern,
    cell_elements,
    pair_elements,
    shifted_cell_elements,
)
from poromech.mesh.entities import CellGeometry, cell_geometry, ridge_coordinates
from poromech.mesh.fractured import FracturedMesh

__all__ = [
    "DarcyProblem",
    "FlowBoundary",
    "FlowProperties",
    "TimeStep",
    "fracture_conductivity",
    "normal_transmissibility",
]

Array = npt.NDArray[np.float64]
#: Largest estimated condition number ``‖A‖∞ N / Σ storage`` of a flow system without a
#: pressure condition. Its pressure level is set by the storage term alone, and round-off
#: moves it by about ``0.05 ε κ``. A closed 1 m box with two fractures fed through one face
#: (time steps of 2 s, 1/M = 1e-9 1/Pa), 1 rank and 2 ranks: at 2e13 (permeability 1e-4 m²)
#: the storage took up the inflow to 2e-5 on both and they agreed to 2e-5; at 2e14 (1e-3 m²)
#: to 1e-3 and 1.4e-3, 2e-3 apart; at 2e15 (1e-2 m²) 1.3e-2 apart; at 2e16 (1e-1 m²) 27 % off;
#: at 2e18 (10 m², a unit error) the pressure was uniform and negative under injection with
#: flows through impervious faces, and each step's balance looked closed (the round-off of the
#: fluxes is its floor). 1e14 keeps that error near the mass balance's tolerance of 1e-3
#: (``MASS_BALANCE_FAIL``). A coupled closed box: 2e13 (1e-6 m²) ran, 1e16 (1e-3 m²) failed
#: its fixed point, 2e19 (1 m²) "converged" to such pressures.
CLOSED_CONDITION_MAX = 1e14
#: HFV stabilization of the triangular fracture faces in 3D (``√d`` in the fracture's dimension).
FRACTURE_BETA_3D = float(np.sqrt(2.0))
#: A space-time field ``f(points, t)``: values at points ``(n, d)`` (m) and time ``t`` (s).
Field = Callable[[Array, float], Array]


@dataclass(frozen=True)
class FlowProperties:
    """Coefficients on the owned cells and owned fracture faces (SI units).

    ``NaN`` in the fracture arrays selects the default law: ``K_f,τ = d_f²/12``,
    ``Λ_f,n = d_f²/12``, ``C_f = K_f,τ d_f`` (cubic law, DESIGN §1).

    Attributes:
        permeability: Matrix permeability tensors ``(nc, 2, 2)`` (m²).
        viscosity: Fluid viscosity ``η`` (Pa·s).
        aperture: Fracture aperture ``d_f`` per face ``(nf,)`` (m).
        fracture_permeability: Tangential permeability ``K_f,τ`` ``(nf,)`` (m²).
        normal_permeability: Normal permeability ``Λ_f,n`` ``(nf,)`` (m²).
        conductivity: Fracture conductivity ``C_f`` ``(nf,)`` (m³), overrides ``K_f,τ d_f``.
        storage: Matrix storage ``s_K = 1/M`` ``(nc,)`` (1/Pa); zero for an incompressible
            fluid and rigid matrix.
        fracture_storage: Fracture storage ``s_f`` ``(nf,)`` (m/Pa), the change of the fracture
            volume per unit length and unit fracture pressure in the fracture balance
            ``|σ| (d̂ⁿ + s_f p_fⁿ - dⁿ⁻¹)/Δt``; None: none (the volume is the aperture).
    """

    permeability: Array
    viscosity: float
    aperture: Array
    fracture_permeability: Array
    normal_permeability: Array
    conductivity: Array
    storage: Array
    fracture_storage: Array | None = None


@dataclass(frozen=True)
class TimeStep:
    """Accumulation data of one implicit Euler step (DESIGN §5 "Time").

    Attributes:
        dt: Step ``Δt`` (s).
        porosity_prev: ``φ_Kⁿ⁻¹`` on the owned cells.
        porosity_fixed: ``φ̂_Kⁿ = φ_Kⁿ - s_K p_Kⁿ``, the pressure-independent part of the new
            porosity (for a coupled problem ``φ⁰ + b((div uⁿ)_K - (div u⁰)_K) - p⁰/M``).
        aperture_prev: ``d_σⁿ⁻¹`` on the owned fracture faces (``dⁿ`` is the current aperture
            of the problem's properties).
        aperture_fixed: ``d̂_σⁿ``, the pressure-independent part of the new fracture volume
            ``d̂_σⁿ + s_f p_fⁿ`` (with a fracture storage ``s_f``); None: the current aperture.
    """

    dt: float
    porosity_prev: Array
    porosity_fixed: Array
    aperture_prev: Array
    aperture_fixed: Array | None = None


def fracture_conductivity(props: FlowProperties) -> Array:
    """``C_f = K_f,τ d_f`` with ``K_f,τ = d_f²/12`` by default, or the given ``C_f`` (m³)."""
    d = props.aperture
    kt = np.where(np.isnan(props.fracture_permeability), d**2 / 12.0, props.fracture_permeability)
    return np.where(np.isnan(props.conductivity), kt * d, props.conductivity)


def normal_transmissibility(props: FlowProperties) -> Array:
    """``T_f = 2 Λ_f,n / d_f`` with ``Λ_f,n = d_f²/12`` by default (DESIGN §5) (m)."""
    d = props.aperture
    kn = np.where(np.isnan(props.normal_permeability), d**2 / 12.0, props.normal_permeability)
    return 2.0 * kn / d


class DarcyProblem:
    """Mixed-dimensional HFV Darcy flow on a fractured mesh (DESIGN §5); owns its PETSc objects.

    Args:
        fm: The fractured mesh (the mechanics' partition).
        properties: Coefficients on the owned entities.
        boundary: Boundary conditions; unlisted domain edges are impervious.
        source: Matrix source ``q(x, t)`` (1/s), or None.
        fracture_source: Fracture source ``q_f(x, t)`` per fracture area (m/s), or None.
        prefix: PETSc options prefix.
        solver: ``iterative`` (CG + GAMG) or ``direct`` (MUMPS) defaults.
        options: PETSc options merged over the defaults (without the prefix).
        beta: HFV stabilization ``β`` (default ``√d``).
        geom: The cell geometry if already computed (else computed here).
        gravity: ``ρ_f g`` (Pa/m), the fluid's weight per volume, or None: Darcy's law then acts
            on the potential ``ψ = p - ρ_f g·x`` (the system is solved for ``ψ``; storage terms
            and outputs stay in ``p``), so that a hydrostatic pressure is at rest.

    Attributes:
        geom: Geometry of the owned cells.
        dofs: The distributed numbering of the unknowns.
        faces: The owned fracture faces, ``fm.fractures``.
        face_direction: 2D: unit vector from the first to the second node unknown of each face
            (the direction of positive flux along it), ``(nf, 2)``; None in 3D.
        bdofs: Where the boundary conditions act.
        A_cell: Cell matrices ``A_K / η`` of the owned cells, ``(nc, d + 1, d + 1)``
            (m^{d-1}/(Pa·s)).
        t_pair: ``|σ| T_f / η`` of the owned fracture faces (m²/(Pa·s)).
        A_fracture: Fracture-face matrices ``(nf, d, d)``: the fluxes from each owned
            fracture face to its nodes are ``A_fracture (p_f - p_e)``. In 2D the diagonal
            ``T*_{σ,e} / η`` (``T_fracture``); in 3D the HFV matrices of the triangles
            (:func:`~poromech.flow.hfv.fracture_face_matrices`) times ``C_f / η``, in series
            with the resistance of the overlap with the fractures crossed at a node
            (:mod:`poromech.flow.intersections`).
        A_half: ``A_fracture`` without the crossing resistances.
        T_fracture: 2D: ``T*_{σ,e} / η`` to both nodes of the owned fracture faces,
            ``(nf, 2)``: the half-face transmissibility, in series with the resistance of the
            overlap with the fractures crossed at that node; None in 3D.
        T_half: 2D: ``T_{σ,e} / η``, the half-face part of ``T_fracture``, ``(nf, 2)``.
        crossings: Which face ends cross another fracture at their node.
        p: Current solution on the local (owned, then ghost) dofs (Pa).
        head: ``ρ_f g·x`` at every local dof (Pa), or None without gravity.
        records: One :class:`LinearRecord` per solve.
    """

    def __init__(
        self,
        fm: FracturedMesh,
        properties: FlowProperties,
        boundary: Sequence[FlowBoundary] = (),
        source: Field | None = None,
        fracture_source: Field | None = None,
        *,
        prefix: str = "flow_",
        solver: str = "iterative",
        options: dict | None = None,
        beta: float | None = None,
        geom: CellGeometry | None = None,
        gravity: Array | None = None,
    ):
        self.fm, self.comm = fm, fm.comm
        self.geom: CellGeometry = cell_geometry(fm.msh) if geom is None else geom
        self.dofs: FlowDofs = number_dofs(fm, self.geom)
        self.faces = fm.fractures
        self.dim = fm.msh.topology.dim
        self.face_direction = _node_directions(self.dofs) if self.dim == 2 else None
        self._unit_fracture, node_length = None, None
        if self.dim == 3:
            edges = ridge_coordinates(fm.msh, self.dofs.node_entity.ravel()).reshape(-1, 3, 2, 3)
            self._unit_fracture = hfv.fracture_face_matrices(edges, fm.fractures.tangents,
                                                             FRACTURE_BETA_3D)
            node_length = np.linalg.norm(edges[:, :, 1] - edges[:, :, 0], axis=2)
        self.node_length = node_length
        self.crossings = FractureCrossings(self.comm, self.dofs, fm.fractures.fracture)
        self.boundary = tuple(boundary)
        self.bdofs = boundary_dofs(self.dofs, self.geom, fm.geometry, self.boundary, node_length)
        #: No pressure condition anywhere: the storage alone sets the pressure level.
        self.closed = not self.comm.allreduce(len(self.bdofs.dirichlet[0]) > 0, op=MPI.LOR)
        self._check_conditions_act()
        self.source, self.fracture_source = source, fracture_source
        self.beta = float(np.sqrt(float(self.dim))) if beta is None else float(beta)
        self.pattern = SystemPattern(self.dofs, self.bdofs.mask)
        self.A = self.pattern.create_matrix(self.comm)
        d = self.dofs
        self.b = PETSc.Vec().createMPI((d.num_owned, d.num_global), comm=self.comm)
        self.x = PETSc.Vec().createGhost(d.ghosts.astype(PETSc.IntType),
                                         (d.num_owned, d.num_global), comm=self.comm)
        self._global = d.local_to_global(np.arange(d.num_local)).astype(PETSc.IntType)
        self.solver = LinearSolver(self.A, prefix, solver, options, self.dim)
        self.p = np.zeros(d.num_local)
        self.head = None if gravity is None else d.points @ np.asarray(gravity, dtype=float)
        self.shift = TraceShift(fm, d, self.geom.facets)
        self.records: list[LinearRecord] = []
        self._storage_dt: float | None = None
        self._guess_set = False
        self._error: PETSc.Vec | None = None
        self.set_properties(properties)

    # -- coefficients (values only) ---------------------------------------------------------
    def _check_conditions_act(self) -> None:
        """Refuse a ``where`` condition that selects no boundary face or fracture end (collective).

        ``where`` is evaluated at face midpoints and nodes of the mesh: a predicate narrower than
        the boundary faces selected nothing, and the condition was dropped without a word (a
        flux: no inflow at all; a pressure: a singular system).
        """
        b, n = self.bdofs, len(self.boundary)
        local = sum(np.bincount(np.asarray(c, dtype=np.int64), minlength=n)[:n]
                    for c in (b.dirichlet[1], b.flux_faces[1], b.flux_nodes[1]))
        counts = self.comm.allreduce(np.asarray(local), op=MPI.SUM)
        for i, bc in enumerate(self.boundary):
            if bc.where is not None and counts[i] == 0:
                raise ConfigError(
                    f"'flow.boundary_conditions.{i}' (boundary {bc.name}, restricted by where) "
                    "selects no boundary face or fracture end of the mesh (where is tested at "
                    "face midpoints and nodes), or a condition listed after it covers all it "
                    "selects (the last listed applies): widen where, refine the mesh there, or "
                    "remove the overlap")

    def set_properties(self, properties: FlowProperties) -> None:
        """Replace all coefficients (collective); matrix values are recomputed at the next solve."""
        self.properties = properties
        mob = properties.permeability / properties.viscosity
        g = self.geom
        self.A_cell = hfv.cell_matrices(g.area, g.normal, g.offset, g.volume, mob, self.beta)
        self._update_fracture()

    def set_permeability(self, permeability: Array) -> None:
        """New matrix permeability tensors ``(nc, 2, 2)`` (m²), values-only update (collective)."""
        self.set_properties(replace(self.properties, permeability=permeability))

    def set_aperture(self, aperture: Array) -> None:
        """New fracture apertures ``dⁿ`` on the owned faces (m), values-only update (collective).

        The conductivity (cubic law unless given) and the normal transmissibility follow.
        """
        self.properties = replace(self.properties, aperture=np.asarray(aperture, dtype=float))
        self._update_fracture()

    def _update_fracture(self) -> None:
        """Fracture transmissibilities from the current properties (collective)."""
        props, eta = self.properties, self.properties.viscosity
        T_f = normal_transmissibility(props)
        self.t_pair = self.faces.measure * T_f / eta
        C_f = fracture_conductivity(props)
        with np.errstate(divide="ignore"):
            crossed = self.crossings.averages(np.column_stack([0.5 / T_f, props.aperture]))
        # ΔR is a geometric resistance (1/m²); in series with T/η it counts η times
        added = eta * crossing_resistance(crossed, C_f, props.aperture)
        if self.dim == 2:
            half = hfv.fracture_half_transmissibilities(self.faces.measure, C_f)
            self.T_half = np.column_stack([half, half]) / eta
            self.T_fracture = series_transmissibilities(self.T_half, added)
            self.A_half = _diagonal(self.T_half)
            self.A_fracture = _diagonal(self.T_fracture)
        else:
            self.T_half = self.T_fracture = None
            self.A_half = (C_f / eta)[:, None, None] * self._unit_fracture
            self.A_fracture = hfv.series_matrices(self.A_half, added / self.node_length)
        self._values = None
        if self.shift.update(self.A_cell, self.t_pair):
            self._write_guess()

    def _storage_diagonals(self, dt: float | None) -> tuple[Array, Array]:
        """``|K| s_K / Δt`` of the cells and ``|σ| s_f / Δt`` of the fracture faces."""
        storage = np.zeros(self.geom.num_cells)
        fracture_storage = np.zeros(len(self.faces.measure))
        if dt is not None:
            storage = self.geom.volume * self.properties.storage / dt
            if self.properties.fracture_storage is not None:
                fracture_storage = self.faces.measure * self.properties.fracture_storage / dt
        return storage, fracture_storage

    def element_values(self, dt: float | None) -> ElementValues:
        """Element matrices for a steady (``dt`` None) or implicit Euler solve."""
        storage, fracture_storage = self._storage_diagonals(dt)
        E = cell_elements(self.A_cell)
        plain, touching = self.pattern.plain_cells, self.pattern.fracture_cells
        return ElementValues(
            E[plain],
            shifted_cell_elements(E[touching], self.shift.cell[touching]),
            pair_elements(np.concatenate([self.t_pair, self.t_pair]),
                          np.concatenate([self.shift.pair, self.shift.pair])),
            cell_elements(self.A_fracture),
            storage,
            fracture_storage,
        )

    # -- solves ---------------------------------------------------------------------------
    def solve(self, t: float = 0.0, step: TimeStep | None = None) -> LinearRecord:
        """Solve the steady problem (``step`` None) or one implicit Euler step at time ``t``.

        Collective. Raises :class:`poromech.errors.SolverError` when the solver fails.
        """
        if not self._guess_set:
            self._initial_guess(t)
        self.assemble_matrix(None if step is None else step.dt)
        b = self.rhs(t, step)
        self.b.zeroEntries()
        self.b.setValues(self._global, b, addv=PETSc.InsertMode.ADD_VALUES)
        self.b.assemblyBegin()
        self.b.assemblyEnd()
        record = self.solver.solve(self.b, self.x)
        self._read_solution()
        self.records.append(record)
        return record

    def solve_error(self) -> tuple[Array, Array]:
        """Estimated error of the last solve on the owned cells and fracture faces (Pa).

        One step of iterative refinement (:meth:`LinearSolver.correction`): what round-off in
        the solve leaves in the pressures, the accuracy to which they are known at all when the
        system is ill-conditioned (large permeability contrasts). Collective; one solve with
        the current factorization or one AMG cycle.
        """
        if self._error is None:
            self._error = self.x.duplicate()
        self.solver.correction(self.b, self.x, self._error)
        self._error.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        with self._error.localForm() as loc:
            e = loc.getArray(readonly=True)
            return e[self.dofs.cell].copy(), e[self.dofs.fracture].copy()

    def assemble_matrix(self, dt: float | None = None) -> None:
        """Push new matrix values if coefficients or the storage term changed (collective).

        Called by :meth:`solve`; a values-only ``MatSetValuesCOO`` on the fixed pattern.
        """
        key = dt if self._has_storage else None
        if self._values is not None and key == self._storage_dt:
            return
        values = self._set_values(dt, key)
        problem = None if dt is None else self._pressure_level_problem(values, dt)
        if problem is not None:
            raise SolverError(f"the Darcy system of time steps of {dt:.3g} s is singular in "
                              f"double precision: {problem}", "DIVERGED_PRESSURE_LEVEL")

    def _set_values(self, dt: float | None, key: float | None) -> ElementValues:
        """Push the matrix values of a steady solve or of steps of ``dt`` (collective).

        ``key``: ``dt`` where the problem has storage, else None (the values do not depend on
        it).
        """
        values = self.element_values(dt)
        self._values = values.flat()
        self.A.setValuesCOO(self._values, addv=PETSc.InsertMode.INSERT_VALUES)
        self.solver.operator_changed()
        self._storage_dt = key
        return values

    def check_pressure_level(self, dt: float) -> None:
        """Refuse steps of ``dt`` that would lose the pressure level to round-off (collective).

        Raises ConfigError (:meth:`_pressure_level_problem`). Called at set-up with the longest
        step; after it each assembly makes the same test and raises SolverError (a step cut
        shortens the step; the conductances grow with the apertures).
        """
        problem = self._pressure_level_problem(
            self._set_values(dt, dt if self._has_storage else None), dt)
        if problem is not None:
            k = float(np.max(self.comm.allgather(float(np.max(self.properties.permeability,
                                                                  initial=0.0)))))
            raise ConfigError(f"scene key 'flow.permeability' (up to {k:.3g} m²) with time "
                              f"steps of {dt:.3g} s: {problem}")

    def _pressure_level_problem(self, values: ElementValues, dt: float) -> str | None:
        """Why a closed system's pressure level is lost to round-off, or None (collective).

        Without a pressure condition the conductances leave the pressure level free and only
        the storage term ``Σ |K| s_K/Δt`` fixes it; the constant pressure's Rayleigh quotient,
        ``Σ storage / N``, bounds the smallest eigenvalue, so that ``‖A‖∞ N / Σ storage``
        estimates the condition number (:data:`CLOSED_CONDITION_MAX`).
        """
        if not self.closed:
            return None
        storage = self.comm.allreduce(float(values.storage.sum() + values.fracture_storage.sum()))
        kappa = self.A.norm(PETSc.NormType.INFINITY) * self.A.getSize()[0] / max(
            storage, np.finfo(float).tiny)
        if kappa <= CLOSED_CONDITION_MAX:
            return None
        return (f"with no pressure condition only the storage term sets the pressure level, and "
                f"it is {1 / kappa:.1e} of the conductances, lost to round-off (allowed: "
                f"a condition estimate ‖A‖∞ N/storage up to {CLOSED_CONDITION_MAX:.1e}, here "
                f"{kappa:.1e}: check the permeability's units, or add a pressure condition, more "
                "storage (flow.biot_modulus) or shorter steps)")

    @property
    def _has_storage(self) -> bool:
        s_f = self.properties.fracture_storage
        local = bool(np.any(self.properties.storage > 0) or (s_f is not None and np.any(s_f > 0)))
        return bool(self.comm.allreduce(local, op=MPI.LOR))

    def rhs(self, t: float, step: TimeStep | None) -> Array:
        """Local right-hand side (owned and ghost rows) at time ``t``."""
        d, g, f = self.dofs, self.geom, self.faces
        b = np.zeros(d.num_local)
        if self.source is not None:
            b[d.cell] += g.volume * self.source(g.centroid, t)
        if self.fracture_source is not None:
            b[d.fracture] += f.measure * self.fracture_source(f.midpoint, t)
        dof, bc, area = self.bdofs.flux_faces
        b -= np.bincount(dof, area * self._boundary_values(dof, bc, t), minlength=d.num_local)
        dof, bc, face, length = self.bdofs.flux_nodes
        section = self.properties.aperture[face] * length
        b -= np.bincount(dof, section * self._boundary_values(dof, bc, t), minlength=d.num_local)
        if step is not None:
            b[d.cell] += g.volume * (step.porosity_prev - step.porosity_fixed) / step.dt
            b[d.fracture] -= f.measure * (self._volume_fixed(step) - step.aperture_prev) / step.dt
            if self.head is not None:  # storage acts on p = ψ + ρ_f g·x, the unknown is ψ
                storage, fracture_storage = self._storage_diagonals(step.dt)
                b[d.cell] -= storage * self.head[d.cell]
                b[d.fracture] -= fracture_storage * self.head[d.fracture]
        values = self._values if self._values is not None else self.element_values(None).flat()
        return b + self.pattern.dirichlet_rhs(values, self.dirichlet_values(t))

    def _boundary_values(self, dof, bc, t: float) -> Array:
        """Values of the conditions ``bc`` at the locations of ``dof``."""
        out = np.zeros(len(dof))
        x = self.dofs.points[dof]
        for i, cond in enumerate(self.boundary):
            sel = bc == i
            if sel.any():
                out[sel] = cond.value(x[sel], t)
        return out

    def dirichlet_values(self, t: float) -> Array:
        """Dirichlet values of the unknowns (potentials) over the local dofs at ``t`` (else 0)."""
        g = np.zeros(self.dofs.num_local)
        dof, bc = self.bdofs.dirichlet
        g[dof] = self._boundary_values(dof, bc, t)
        if self.head is not None:
            g[dof] -= self.head[dof]
        return g

    def _initial_guess(self, t: float) -> None:
        """First guess: the mean Dirichlet value (the pressure level), zero without any."""
        dof, _ = self.bdofs.dirichlet
        owned = dof < self.dofs.num_owned
        g = self.dirichlet_values(t)[dof[owned]]
        total, count = self.comm.allreduce(np.array([g.sum(), float(len(g))]), op=MPI.SUM)
        level = total / count if count else 0.0
        self.set_pressure(lambda x, t: np.full(len(x), level), t)

    def _read_solution(self) -> None:
        """Pressures from the solved variables: traces are ``δ + p_f`` (see ``system``)."""
        self.x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        with self.x.localForm() as loc:
            self.p[:] = loc.getArray(readonly=True)
        self.shift.to_pressure(self.p)
        if self.head is not None:
            self.p += self.head

    def set_pressure(self, p: Field, t: float = 0.0) -> None:
        """Set every unknown from ``p(x, t)``: initial state or initial guess (collective)."""
        self.p[:] = p(self.dofs.points, t)
        self._write_guess()
        self._guess_set = True

    def set_unknowns(self, p: Array) -> None:
        """Set every local unknown (Pa) and make it the initial guess of the next solve.

        Collective. Restores an accepted state (a rejected step, a checkpoint).
        """
        self.p[:] = p
        self._write_guess()

    def _write_guess(self) -> None:
        """Put the current pressures into the solution vector (the next initial guess)."""
        values = self.potential.copy()
        self.shift.to_variables(values)
        n = self.dofs.num_owned
        self.x.setValues(self._global[:n], values[:n])
        self.x.assemble()
        self._read_solution()

    # -- solution views (owned entities) --------------------------------------------------
    @property
    def potential(self) -> Array:
        """``ψ = p - ρ_f g·x`` on the local dofs (Pa): what drives the Darcy fluxes."""
        return self.p if self.head is None else self.p - self.head

    @property
    def cell_pressure(self) -> Array:
        """``p_K`` on the owned cells (Pa)."""
        return self.p[self.dofs.cell]

    @property
    def face_pressure(self) -> Array:
        """Face values seen by each owned cell ``(nc, 3)`` (``p_σ`` or the cell's trace)."""
        return self.p[self.dofs.cell_faces]

    @property
    def trace_pressure(self) -> Array:
        """``(p_{K+,σ}, p_{K-,σ})`` on the owned fracture faces ``(nf, 2)``."""
        return self.p[self.dofs.trace]

    @property
    def fracture_pressure(self) -> Array:
        """``p_{f,σ}`` on the owned fracture faces."""
        return self.p[self.dofs.fracture]

    @property
    def node_pressure(self) -> Array:
        """``p_e`` at the nodes of the owned fracture faces ``(nf, d)``."""
        return self.p[self.dofs.node]

    @property
    def branch_pressure(self) -> Array:
        """Pressure at both ends of the owned fracture faces, on the face's side ``(nf, 2)`` (Pa).

        ``p_e`` where the face crosses no fracture at that end; where it does, the value before
        the crossed fracture's resistance, ``p_f - (T*_{σ,e}/T_{σ,e}) (p_f - p_e)`` (the flux
        ``T*(p_f - p_e)`` divided by the half-face transmissibility). For fracture profiles:
        behind a blocking intersection the branch keeps its own pressure up to the crossing.
        """
        p_f = self.fracture_pressure[:, None]
        if self.dim == 3:  # q = p_f - A_half⁻¹ F, F = A_fracture (p_f - p_e)
            flux = np.einsum("nij,nj->ni", self.A_fracture, p_f - self.node_pressure)
            return p_f - np.linalg.solve(self.A_half, flux[..., None])[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(self.T_half > 0, self.T_fracture / self.T_half, 1.0)
        return p_f - ratio * (p_f - self.node_pressure)

    def porosity(self, step: TimeStep) -> Array:
        """``φ_Kⁿ = φ̂_Kⁿ + s_K p_Kⁿ`` after a step (owned cells)."""
        return step.porosity_fixed + self.properties.storage * self.cell_pressure

    def _volume_fixed(self, step: TimeStep) -> Array:
        """``d̂_σⁿ``: the given pressure-independent fracture volume, or the current aperture."""
        return self.properties.aperture if step.aperture_fixed is None else step.aperture_fixed

    def fracture_volume(self, step: TimeStep) -> Array:
        """``d̂_σⁿ + s_f p_fⁿ`` after a step (owned fracture faces), as in the balance solved."""
        s_f = self.properties.fracture_storage
        if s_f is None:
            return self._volume_fixed(step)
        return self._volume_fixed(step) + s_f * self.fracture_pressure

    def destroy(self) -> None:
        """Free the PETSc objects."""
        self.solver.destroy()
        for obj in (self.A, self.b, self.x):
            obj.destroy()


def _diagonal(T: Array) -> Array:
    """``(n, k, k)`` diagonal matrices from ``(n, k)`` diagonals."""
    out = np.zeros(T.shape + T.shape[-1:])
    idx = np.arange(T.shape[1])
    out[:, idx, idx] = T
    return out


def _node_directions(dofs: FlowDofs) -> Array:
    """Unit vectors from the first to the second node unknown of each owned fracture face."""
    ends = dofs.points[dofs.node].reshape(-1, 2, 2)
    t = ends[:, 1] - ends[:, 0]
    length = np.linalg.norm(t, axis=1)
    return t / np.where(length > 0, length, 1.0)[:, None]
