"""From a validated scene to the inputs of :class:`DarcyProblem` (local evaluation).

Coefficients are evaluated at cell centres (matrix) and face midpoints (fractures); per-fracture
entries of ``flow.fractures`` override the fracture defaults on that fracture's faces. A
fracture value left unset becomes ``NaN``, which selects the default law of
:class:`~poromech.flow.problem.FlowProperties`.
"""

from __future__ import annotations

import numpy as np

from poromech.flow.boundary import FlowBoundary
from poromech.flow.hfv import permeability_tensors
from poromech.flow.problem import DarcyProblem, FlowProperties
from poromech.geometry.box import BoxGeometry
from poromech.geometry.plane import PlaneGeometry
from poromech.mesh.entities import CellGeometry, cell_geometry
from poromech.mesh.fractured import FracturedMesh
from poromech.scene.expressions import Expression
from poromech.scene.schema import Flow, Scene, step_times

__all__ = ["check_pressure_level", "flow_boundaries", "flow_properties", "problem_from_scene",
           "time_dependent"]

#: Fracture coefficient fields: (Flow default, FractureFlow override) attribute names.
_FRACTURE_FIELDS = {
    "aperture": ("aperture", "aperture"),
    "fracture_permeability": ("fracture_permeability", "permeability"),
    "normal_permeability": ("fracture_normal_permeability", "normal_permeability"),
    "conductivity": ("fracture_conductivity", "conductivity"),
}


def _at(expr: Expression | None, x: np.ndarray, t: float) -> np.ndarray:
    """Values at points ``x`` (NaN for an unset expression)."""
    if expr is None:
        return np.full(len(x), np.nan)
    return expr(x, t)


def _fracture_values(flow: Flow, fm: FracturedMesh, name: str, t: float) -> np.ndarray:
    """One fracture coefficient on the owned fracture faces, with per-fracture overrides."""
    default, override = _FRACTURE_FIELDS[name]
    faces = fm.fractures
    values = _at(getattr(flow, default), faces.midpoint, t)
    names = fm.geometry.fracture_names
    for ff in flow.fractures:
        expr = getattr(ff, override)
        sel = faces.fracture == names.index(ff.fracture)
        if expr is not None and sel.any():
            values[sel] = _at(expr, faces.midpoint[sel], t)
    return values


def flow_properties(scene: Scene, fm: FracturedMesh, geom: CellGeometry,
                    t: float = 0.0) -> FlowProperties:
    """Coefficients of the scene at time ``t`` on the owned entities."""
    flow = scene.flow
    x = geom.centroid
    perm = permeability_tensors([_at(e, x, t) for e in flow.permeability], x.shape[1])
    storage = 0.0
    if flow.biot_modulus is not None and scene.time is not None:
        storage = 1.0 / flow.biot_modulus
    frac = {k: _fracture_values(flow, fm, k, t) for k in _FRACTURE_FIELDS}
    return FlowProperties(
        permeability=perm, viscosity=flow.viscosity, storage=np.full(len(x), storage), **frac
    )


def time_dependent(scene: Scene) -> bool:
    """True when a coefficient (not a source or boundary value) depends on time."""
    flow = scene.flow
    exprs = list(flow.permeability) + [getattr(flow, d) for d, _ in _FRACTURE_FIELDS.values()]
    exprs += [getattr(ff, o) for ff in flow.fractures for _, o in _FRACTURE_FIELDS.values()]
    return any(e is not None and e.depends_on_time for e in exprs)


def flow_boundaries(scene: Scene, geometry: PlaneGeometry | BoxGeometry) -> list[FlowBoundary]:
    """The boundary conditions of the scene, with their domain polygon edges."""
    out = []
    for bc in scene.flow.boundary_conditions:
        edges = tuple(i for i, n in enumerate(geometry.boundary_names) if n == bc.boundary)
        kind = "pressure" if bc.pressure is not None else "flux"
        value = bc.pressure if bc.pressure is not None else bc.flux
        out.append(FlowBoundary(bc.boundary, edges, kind, value, bc.fracture_ends, bc.where))
    return out


def problem_from_scene(scene: Scene, fm: FracturedMesh, prefix: str = "flow_") -> DarcyProblem:
    """Build the flow problem of a scene, with coefficients at ``t = 0`` (collective)."""
    flow = scene.flow
    geom = cell_geometry(fm.msh)
    return DarcyProblem(
        fm,
        flow_properties(scene, fm, geom),
        flow_boundaries(scene, fm.geometry),
        source=None if _is_zero(flow.source) else flow.source,
        fracture_source=None if _is_zero(flow.fracture_source) else flow.fracture_source,
        prefix=prefix,
        solver=flow.linear_solver,
        options=flow.petsc,
        beta=flow.stabilization,
        geom=geom,
        gravity=None if scene.gravity is None else flow.fluid_density * np.asarray(scene.gravity),
    )


def check_pressure_level(scene: Scene, problem: DarcyProblem) -> None:
    """Refuse a transient scene whose longest step loses the pressure level (collective).

    :meth:`~poromech.flow.problem.DarcyProblem.check_pressure_level` with the scene's longest
    time step, before anything is solved; nothing for a steady scene.
    """
    if scene.time is None:
        return
    times = step_times(scene)
    problem.check_pressure_level(float(np.max(np.diff([0.0, *times]))))


def _is_zero(expr: Expression) -> bool:
    return expr.is_constant and not expr.depends_on_time and expr.value() == 0.0
