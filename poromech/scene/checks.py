"""What a scene asks of each physics, checked before meshing (one-line ConfigErrors).

Mechanics: material fields, boundary conditions that fix every displacement component, the
contact law's data; flow: permeability, fracture fields, boundary conditions, probes; time
stepping; PETSc option names; names that become file names.
"""

from __future__ import annotations

import logging
import re

import numpy as np

from poromech.errors import ConfigError
from poromech.geometry.plane import PlaneGeometry, segment_meets_polygon
from poromech.scene.builder import field_meta, format_value
from poromech.scene.resources import ITERATIVE_FORMULATIONS
from poromech.scene.schema import (
    Contact,
    Flow,
    FractureFlow,
    Material,
    Scene,
    scene_dimension,
    step_times,
)
from poromech.scene.values import (
    check_expression,
    check_field,
    check_permeability,
    check_times,
    edge_points,
    fracture_points,
    grid_points,
)

__all__ = ["check_boundary_name", "check_name", "check_scene"]

log = logging.getLogger("poromech")


#: Names that become file names (scene name → results/<name>, probe name → probe_<name>.csv).
_FILE_NAME = re.compile(r"[^\W_][\w.-]*")
#: Shortest time step (s), the smallest normal double: a step that rounds below it (0 s, or a
#: subnormal number) divides the storage terms to infinity. (Steps of 1e-300 s run.)
MIN_STEP = float(np.finfo(float).tiny)
#: Longest name (UTF-8 bytes) of a scene or probe, which name files (:func:`check_name`).
NAME_BYTES = 200


def check_boundary_name(key: str, name: str, known: set[str]) -> None:
    """Reject a boundary name that no domain edge has."""
    if name not in known:
        raise ConfigError(f"scene key '{key}' = {name!r} is not a boundary "
                          f"(allowed: {', '.join(sorted(known))})")


def check_components(key: str, value, dim: int) -> None:
    """A vector given per coordinate has ``dim`` components."""
    if value is not None and len(value) != dim:
        names = ", ".join("xyz"[:dim])
        raise ConfigError(f"scene key '{key}' has {len(value)} components: a {dim}D vector has "
                          f"{dim} ({names})")


def _check_3d(scene: Scene) -> None:
    """Every physics runs in 3D (a box domain)."""


def _check_mechanics(scene: Scene, geo: PlaneGeometry) -> None:
    for key in ("geometry", "mesh", "material"):
        if getattr(scene, key) is None:
            raise ConfigError(f"scene key '{key}' is required for physics "
                              f"'{scene.physics}'")
    c = scene.contact
    if c.slip_bound is not None and not c.slip_bound.is_uniform:
        raise ConfigError(f"scene key 'contact.slip_bound' = {format_value(c.slip_bound.source)} "
                          "is not "
                          f"allowed: the Tresca slip bound must not depend on "
                          f"{'x, y or z' if geo.dim == 3 else 'x or y'} (a number, or an "
                          "expression in t)")
    if c.friction == "tresca" and c.slip_bound is None:
        raise ConfigError(
            "scene key 'contact.slip_bound' is required when contact.friction is tresca"
        )
    times = check_times(scene)
    for name in ("young", "poisson"):
        check_field(getattr(scene.material, name), f"material.{name}",
                     field_meta(Material, name), geo, times)
    known = set(geo.boundary_names)
    dim = geo.dim
    fixed = [False] * dim
    for i, bc in enumerate(scene.boundary_conditions):
        path = f"boundary_conditions.{i}"
        check_boundary_name(f"{path}.boundary", bc.boundary, known)
        if (bc.displacement is None) == (bc.traction is None):
            raise ConfigError(f"scene key '{path}' needs exactly one of displacement, traction")
        for kind in ("displacement", "traction"):
            check_components(f"{path}.{kind}", getattr(bc, kind), dim)
        if bc.displacement is not None:
            for k, comp in enumerate(bc.displacement):
                fixed[k] |= comp is not None
    _check_conditions_per_boundary(scene.boundary_conditions)
    check_components("material.body_force", scene.material.body_force, dim)
    if not all(fixed):
        comp = "xyz"[fixed.index(False)]
        raise ConfigError(
            f"scene key 'boundary_conditions': no displacement {comp} is imposed anywhere "
            "(rigid body motion); add a displacement condition"
        )
    _check_mechanics_data(scene, geo, times)
    if (scene.solver.linear_solver == "iterative"
            and scene.contact.formulation not in ITERATIVE_FORMULATIONS):
        raise ConfigError(
            f"scene key 'solver.linear_solver' = 'iterative' is not available for "
            f"contact.formulation {scene.contact.formulation} (its multiplier block is singular "
            f"on faces in contact, a saddle-point system for a direct solve): use direct or "
            f"auto, or formulation {', '.join(ITERATIVE_FORMULATIONS[1:])}")
    if str(scene.solver.petsc.get("pc_type")) == "mg" and scene.degree != 2:
        raise ConfigError(
            f"scene key 'solver.petsc.pc_type' = 'mg' (the p-multigrid, P1 as the coarse level "
            f"of P2) needs degree 2, not {scene.degree}: use gamg, or degree 2")


def _check_conditions_per_boundary(conditions) -> None:
    """One displacement value per component and boundary, and no traction that could not act.

    A displacement component given twice on one boundary kept the last one; a traction
    component on a boundary whose displacement component is imposed had no effect. Tractions
    on one boundary add up; a displacement and a traction may share a boundary on different
    components (a roller loaded along its free direction).
    """
    imposed: dict[tuple[str, int], int] = {}
    for i, bc in enumerate(conditions):
        for k, comp in enumerate(bc.displacement or ()):
            if comp is None:
                continue
            if (bc.boundary, k) in imposed:
                raise ConfigError(
                    f"scene key 'boundary_conditions.{i}' imposes u_{'xyz'[k]} (displacement."
                    f"{k}) on boundary {bc.boundary!r}, which boundary_conditions."
                    f"{imposed[bc.boundary, k]} already imposes (allowed: one value per "
                    "component; null leaves a component free)")
            imposed[bc.boundary, k] = i
    for i, bc in enumerate(conditions):
        for k, comp in enumerate(bc.traction or ()):
            if (bc.boundary, k) in imposed and not (comp.is_constant and comp.value() == 0.0):
                raise ConfigError(
                    f"scene key 'boundary_conditions.{i}' gives traction.{k} = "
                    f"{format_value(comp.source)} on boundary {bc.boundary!r}, where "
                    f"boundary_conditions.{imposed[bc.boundary, k]} imposes u_{'xyz'[k]}: it "
                    "would have no effect (allowed: 0, or null in that displacement)")


def _check_mechanics_data(scene: Scene, geo: PlaneGeometry, times) -> None:
    """Check the mechanical data where the solver will evaluate them (before meshing).

    Body force on the domain grid, boundary data along their edges (vertices included), fracture
    pressure and slip bound along the fractures.
    """
    grid = grid_points(geo)
    for k, e in enumerate(scene.material.body_force or ()):
        check_expression(e, grid, f"material.body_force.{k}", None, times)
    for i, bc in enumerate(scene.boundary_conditions):
        points = edge_points(geo, bc.boundary)
        for kind in ("displacement", "traction"):
            for k, e in enumerate(getattr(bc, kind) or ()):
                check_expression(e, points, f"boundary_conditions.{i}.{kind}.{k}", None, times)
    points = fracture_points(geo)
    check_expression(scene.fracture_pressure, points, "fracture_pressure", None, times)
    check_expression(scene.contact.slip_bound, points, "contact.slip_bound",
                field_meta(Contact, "slip_bound"), times)
    _check_weight_and_stress(scene, geo, times)


#: Components of ``material.initial_stress`` by dimension (Voigt order).
STRESS_COMPONENTS = {2: ("xx", "yy", "xy"), 3: ("xx", "yy", "zz", "yz", "xz", "xy")}


def _check_gravity(scene: Scene, geo: PlaneGeometry) -> None:
    """``gravity``: one finite component per coordinate."""
    g = scene.gravity
    if g is None:
        return
    if len(g) != geo.dim:
        raise ConfigError(f"scene key 'gravity' = {list(g)} must have {geo.dim} components "
                          f"(one per coordinate)")
    if not all(np.isfinite(g)):
        raise ConfigError(f"scene key 'gravity' = {list(g)} must be finite")


def _check_weight_and_stress(scene: Scene, geo: PlaneGeometry, times) -> None:
    """Density with gravity (each needs the other), and the initial stress's shape and data."""
    m = scene.material
    if m.density is not None and scene.gravity is None:
        example = "[0, 0, -9.81]" if scene_dimension(scene) == 3 else "[0, -9.81]"
        raise ConfigError("scene key 'material.density' has no effect without gravity: give "
                          f"gravity (e.g. {example}) or remove the density")
    if scene.gravity is not None and m.density is None:
        raise ConfigError("scene key 'material.density' is required with gravity (the weight of "
                          "the rock): give the bulk density in kg/m³")
    check_field(m.density, "material.density", field_meta(Material, "density"), geo, times[:1])
    if m.initial_stress is None:
        return
    names = STRESS_COMPONENTS[geo.dim]
    if len(m.initial_stress) != len(names):
        raise ConfigError(
            f"scene key 'material.initial_stress' has {len(m.initial_stress)} components: "
            f"a {geo.dim}D stress has {len(names)}, [{', '.join('σ_' + c for c in names)}]")
    for k, e in enumerate(m.initial_stress):
        path = f"material.initial_stress.{k}"
        if e.depends_on_time:
            raise ConfigError(f"scene key '{path}' = {format_value(e.source)} depends on t: the "
                              "initial stress is the state at t = 0")
        check_field(e, path, {}, geo, [0.0])


def _check_flow(scene: Scene, geo: PlaneGeometry) -> None:
    """Validate a flow scene (physics ``flow``): every failure is a one-line ConfigError."""
    flow = scene.flow
    if flow is None:
        raise ConfigError(f"scene key 'flow' is required for physics '{scene.physics}'")
    if scene.mesh is None:
        raise ConfigError(f"scene key 'mesh' is required for physics '{scene.physics}'")
    times = check_times(scene)
    if scene.gravity is not None and flow.fluid_density is None:
        raise ConfigError("scene key 'flow.fluid_density' is required with gravity (the weight "
                          "of the fluid): give it in kg/m³, e.g. 1000")
    if scene.gravity is None and flow.fluid_density is not None:
        raise ConfigError("scene key 'flow.fluid_density' has no effect without gravity: give "
                          "gravity or remove the fluid density")
    _check_flow_permeability(flow.permeability, geo, times)
    check_field(flow.source, "flow.source", field_meta(Flow, "source"), geo, times)
    if scene.time is not None:  # the initial state of a transient run
        check_field(flow.initial_pressure, "flow.initial_pressure",
                     field_meta(Flow, "initial_pressure"), geo, [0.0])
    for name, override in _FRACTURE_DEFAULTS.items():
        kept = {ff.fracture for ff in flow.fractures if getattr(ff, override, None) is not None}
        which = [k for k, n in enumerate(geo.fracture_names) if n not in kept]
        check_expression(getattr(flow, name), fracture_points(geo, which), f"flow.{name}",
                    field_meta(Flow, name), times)
    if flow.fracture_permeability is not None and flow.fracture_conductivity is not None:
        raise ConfigError("scene key 'flow': give fracture_permeability or fracture_conductivity, "
                          "not both")
    seen: set[str] = set()
    for i, ff in enumerate(flow.fractures):
        path = f"flow.fractures.{i}"
        if ff.fracture not in geo.fracture_names or ff.fracture in seen:
            what = "repeats" if ff.fracture in seen else "is not a fracture"
            raise ConfigError(f"scene key '{path}.fracture' = {ff.fracture!r} {what} "
                              f"(allowed: {', '.join(geo.fracture_names)})")
        seen.add(ff.fracture)
        if ff.permeability is not None and ff.conductivity is not None:
            raise ConfigError(f"scene key '{path}': give permeability or conductivity, not both")
        points = fracture_points(geo, [geo.fracture_names.index(ff.fracture)])
        for name in ("aperture", "permeability", "normal_permeability", "conductivity"):
            check_expression(getattr(ff, name), points, f"{path}.{name}",
                        field_meta(FractureFlow, name), times)
    _check_flow_boundaries(scene, geo)


#: Fracture fields of ``flow`` and the ``flow.fractures`` entry overriding each on one fracture.
_FRACTURE_DEFAULTS = {
    "aperture": "aperture",
    "fracture_permeability": "permeability",
    "fracture_normal_permeability": "normal_permeability",
    "fracture_conductivity": "conductivity",
    "fracture_source": "",
}


def _check_flow_permeability(perm, geo: PlaneGeometry, times) -> None:
    """Permeability: 1, 2 or 3 components (3D: 1, 3 or 6) forming an SPD tensor everywhere."""
    allowed, counts = "[k], [k_xx, k_yy] or [k_xx, k_xy, k_yy]", (1, 2, 3)
    if geo.dim == 3:
        allowed = "[k], [k_xx, k_yy, k_zz] or [k_xx, k_xy, k_xz, k_yy, k_yz, k_zz] in 3D"
        counts = (1, 3, 6)
    if len(perm) not in counts:
        raise ConfigError(f"scene key 'flow.permeability' has {len(perm)} entries "
                          f"(allowed: {allowed})")
    check_permeability(perm, grid_points(geo), times)


def _check_flow_boundaries(scene: Scene, geo: PlaneGeometry) -> None:
    """Boundary names, one of pressure/flux each, and a pressure condition when needed."""
    flow = scene.flow
    known = set(geo.boundary_names)
    used: set[str] = set()
    whole: set[str] = set()
    for i, bc in enumerate(flow.boundary_conditions):
        path = f"flow.boundary_conditions.{i}"
        check_boundary_name(f"{path}.boundary", bc.boundary, known)
        if bc.boundary in used and (bc.where is None or bc.boundary in whole):
            raise ConfigError(f"scene key '{path}.boundary' = {bc.boundary!r} already has a "
                              "flow condition (one per boundary, or several each with a where)")
        used.add(bc.boundary)
        if bc.where is None:
            whole.add(bc.boundary)
        if (bc.pressure is None) == (bc.flux is None):
            raise ConfigError(f"scene key '{path}' needs exactly one of pressure, flux")
        points, times = edge_points(geo, bc.boundary), check_times(scene)
        if bc.where is not None:
            if bc.where.depends_on_time:
                raise ConfigError(f"scene key '{path}.where' = {format_value(bc.where.source)} "
                                  "depends on t (allowed: an expression in x, y, z)")
            # nan != 0 would select a face without a word
            check_expression(bc.where, points, f"{path}.where", None, [0.0],
                             f"a point of boundary '{bc.boundary}'")
            selected = np.broadcast_to(bc.where(points, 0.0) != 0, points.shape[:1])
            if not np.any(selected):
                raise ConfigError(f"scene key '{path}.where' = {format_value(bc.where.source)} "
                                  f"is zero everywhere on boundary {bc.boundary!r} (allowed: "
                                  "an expression nonzero on part of it)")
            points = points[selected]  # the value is used only where the condition acts
        for kind in ("pressure", "flux"):
            check_expression(getattr(bc, kind), points, f"{path}.{kind}", None, times)
    transient_storage = scene.time is not None and flow.biot_modulus is not None
    if not transient_storage and all(bc.pressure is None for bc in flow.boundary_conditions):
        raise ConfigError(
            "scene key 'flow.boundary_conditions' has no pressure condition: the pressure is not "
            "unique without one (allowed: add a pressure condition, or time with biot_modulus)"
        )


def _check_petsc_keys(scene: Scene) -> None:
    """Scene PETSc options are given without the dash and without their solver's prefix."""
    tables = {"solver.petsc": ("mech_", scene.solver.petsc),
              "coupling.petsc": ("coupling_", scene.coupling.petsc)}
    if scene.flow is not None:
        tables["flow.petsc"] = ("flow_", scene.flow.petsc)
    for key, (prefix, options) in tables.items():
        for name in options:
            if name.startswith(("-", "mech_", "flow_", "coupling_")):
                raise ConfigError(f"scene key '{key}.{name}' is not allowed: give the option "
                                  f"without '-' and without the {prefix} prefix (e.g. ksp_rtol)")


def check_name(key: str, name: str) -> None:
    """Refuse a name that becomes part of a file name unless it is a plain name.

    At most :data:`NAME_BYTES` bytes in UTF-8: with its prefix and suffix (``.probe_<name>
    .csv.part``) a file name must stay within the 255 bytes of common file systems (a probe
    of 260 letters failed only when its file was first written, after the solve).
    """
    if not _FILE_NAME.fullmatch(name):
        raise ConfigError(f"scene key '{key}' = {name!r} is not allowed: use letters, digits, "
                          "'_', '-' or '.' (starting with a letter or digit); it names files")
    size = len(name.encode())
    if size > NAME_BYTES:
        raise ConfigError(f"scene key '{key}' = {name[:40]!r}... is {size} bytes long (allowed: "
                          f"at most {NAME_BYTES}; it names files)")


def _check_probes(scene: Scene, geo: PlaneGeometry) -> None:
    """Probe names are unique and usable in file names; lines have a length.

    A line entirely outside the domain is only warned about (its file will have no values).
    """
    names: set[str] = set()
    for i, probe in enumerate(scene.probes):
        path = f"probes.{i}"
        check_name(f"{path}.name", probe.name)
        if probe.name in names:
            raise ConfigError(f"scene key '{path}.name' = {probe.name!r} repeats")
        names.add(probe.name)
        check_components(f"{path}.start", probe.start, geo.dim)
        check_components(f"{path}.end", probe.end, geo.dim)
        if np.allclose(probe.start, probe.end, rtol=0.0, atol=0.0):
            raise ConfigError(f"scene key '{path}.end' = {list(probe.end)} equals start: "
                              "a probe line needs two distinct points")
        a, b = np.array(probe.start), np.array(probe.end)
        meets = (segment_meets_box(a, b, geo.lower, geo.upper) if geo.dim == 3
                 else segment_meets_polygon(a, b, geo.boundary))
        if not meets:
            log.warning("probe '%s' (scene key '%s') lies entirely outside the domain: "
                        "probe_%s.csv will have no values", probe.name, path, probe.name)


def _check_mesh_zones(scene: Scene, geo: PlaneGeometry) -> None:
    """A zone's centre has a component per coordinate, and its ball reaches the domain."""
    if scene.mesh is None:
        return
    if geo.dim == 3:
        lo, hi = geo.lower, geo.upper
    else:
        lo, hi = geo.boundary.min(axis=0), geo.boundary.max(axis=0)
    for i, zone in enumerate(scene.mesh.zones):
        key = f"mesh.zones.{i}"
        check_components(f"{key}.center", zone.center, geo.dim)
        c = np.asarray(zone.center, dtype=float)
        if np.linalg.norm(c - np.clip(c, lo, hi)) >= zone.radius:
            raise ConfigError(f"scene key '{key}.center' = {list(zone.center)} is farther than "
                              f"its radius {zone.radius:g} m from the domain: the zone refines "
                              "nothing")


def segment_meets_box(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether the segment ``[a, b]`` meets the closed box ``[lo, hi]`` (slab clipping)."""
    t0, t1 = 0.0, 1.0
    d = b - a
    for k in range(len(a)):
        if d[k] == 0.0:
            if not lo[k] <= a[k] <= hi[k]:
                return False
            continue
        ta, tb = sorted(((lo[k] - a[k]) / d[k], (hi[k] - a[k]) / d[k]))
        t0, t1 = max(t0, ta), min(t1, tb)
    return t0 <= t1


def _check_time(scene: Scene) -> None:
    """Uniform steps (final and steps) or listed times, increasing and positive."""
    spec = scene.time
    if spec is None:
        return
    uniform = spec.final is not None or spec.steps is not None
    if uniform == (spec.times is not None):
        raise ConfigError("scene key 'time' needs either final and steps, or times")
    if uniform and (spec.final is None or spec.steps is None):
        missing = "final" if spec.final is None else "steps"
        raise ConfigError(f"scene key 'time.{missing}' is required with uniform steps")
    if spec.times is not None:
        t = np.asarray(spec.times, dtype=float)
        if len(t) == 0 or np.any(np.diff(t) <= 0):
            raise ConfigError(f"scene key 'time.times' = {[float(v) for v in t]} is not allowed: "
                              "must be a non-empty list of increasing times > 0")
    # steps that round to nothing (final = 5e-324 over 2 steps: a step of 0 s, 1/dt = inf)
    dt = float(np.min(np.diff([0.0, *step_times(scene)])))
    if not dt >= MIN_STEP:
        key, value = (("time.times", list(spec.times)) if spec.times is not None
                      else ("time.final", spec.final))
        raise ConfigError(f"scene key '{key}' = {value} gives a step of {dt:g} s (allowed: "
                          f"steps of at least {MIN_STEP:.3g} s)")


def _check_poromechanics(scene: Scene) -> None:
    """What a coupled scene needs beyond a mechanics and a flow scene."""
    if scene.fracture_pressure is not None:
        raise ConfigError("scene key 'fracture_pressure' is not allowed for physics "
                          "'poromechanics': the fracture pressure is computed by the flow")


def check_scene(scene: Scene, geo: PlaneGeometry) -> None:
    """Everything the scene's physics needs, checked before meshing.

    Raises:
        ConfigError: The first defect, in one line naming the key.
    """
    _check_petsc_keys(scene)
    if geo.dim == 3:
        _check_3d(scene)
    _check_time(scene)
    _check_gravity(scene, geo)
    _check_probes(scene, geo)
    _check_mesh_zones(scene, geo)
    if scene.physics in ("mechanics", "poromechanics"):
        _check_mechanics(scene, geo)
    if scene.physics in ("flow", "poromechanics"):
        _check_flow(scene, geo)
    if scene.physics == "poromechanics":
        _check_poromechanics(scene)
