"""The scene: a frozen, validated description of one simulation.

Every field carries its unit, default and meaning in its metadata; :mod:`poromech.scene.builder`
builds these classes from YAML (rejecting unknown keys and wrong types) and
``docs/scene_schema.md`` is generated from them. Expressions (``Expr``) are numbers or strings in
``x``, ``y``, ``z``, ``t`` and the scene ``parameters``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np

from poromech.scene.expressions import Expression

__all__ = [
    "BoundaryCondition",
    "Contact",
    "Coupling",
    "Disc",
    "Domain",
    "FlowBoundaryCondition",
    "Flow",
    "FractureFlow",
    "FractureSpec",
    "Geometry",
    "Material",
    "MeshFile",
    "MeshSpec",
    "MeshZone",
    "Output",
    "Probe",
    "Scene",
    "Solver",
    "Surface",
    "TimeSpec",
    "scene_dimension",
    "step_times",
]

Expr = Expression
Formulation = Literal["none", "mixed", "stabilized_mixed", "mean_nitsche", "nitsche"]
Friction = Literal["coulomb", "tresca", "frictionless"]
#: The formulations with Nitsche terms (θ, β_n, β_τ): the others are ``mixed`` and ``none``.
NITSCHE_FORMULATIONS = ("nitsche", "mean_nitsche", "stabilized_mixed")


def doc(text: str, unit: str = "", **checks) -> dict:
    """Field metadata: description, SI unit and value checks (``min``, ``max``, ``gt``, ...)."""
    return {"doc": text, "unit": unit, **checks}


@dataclass(frozen=True)
class Domain:
    """The matrix domain: a rectangle or a polygon (2D), or a box (3D)."""

    rectangle: tuple[float, float, float, float] | None = field(
        default=None,
        metadata=doc("[x0, y0, x1, y1]; edges are named bottom, right, top, left", "m"),
    )
    box: tuple[float, float, float, float, float, float] | None = field(
        default=None,
        metadata=doc("[x0, y0, z0, x1, y1, z1] (3D); faces are named left, right (x = x0, x1), "
                     "front, back (y = y0, y1), bottom, top (z = z0, z1)", "m"),
    )
    polygon: tuple[tuple[float, float], ...] | None = field(
        default=None, metadata=doc("vertices [[x, y], ...]; edge i joins vertex i and i+1", "m")
    )
    boundary_names: dict[str, tuple[int, ...]] = field(
        default_factory=dict,
        metadata=doc("names of polygon edges, {name: [edge indices]}; unnamed edges are edge<i>"),
    )


@dataclass(frozen=True)
class Disc:
    """A circular planar fracture (3D)."""

    center: tuple[float, float, float] = field(metadata=doc("centre [x, y, z]", "m"))
    normal: tuple[float, float, float] = field(
        metadata=doc("normal n⁺ [n_x, n_y, n_z] (any length but 0): the + side is the side it "
                     "points out of"))
    radius: float = field(metadata=doc("radius", "m", gt=0))


@dataclass(frozen=True)
class FractureSpec:
    """One fracture: a polyline (2D; a corner does not split it), a planar polygon or a disc."""

    points: tuple[tuple[float, float], ...] | None = field(
        default=None,
        metadata=doc("2D: polyline points [[x, y], ...]; their order fixes n⁺ (left normal)", "m")
    )
    polygon: tuple[tuple[float, float, float], ...] | None = field(
        default=None,
        metadata=doc("3D: vertices [[x, y, z], ...] of a planar polygon; n⁺ by the right-hand "
                     "rule (counter-clockwise seen from the side n⁺ points to)", "m")
    )
    disc: Disc | None = field(default=None, metadata=doc("3D: a disc (below)"))
    name: str | None = field(default=None,
                             metadata=doc("fracture name (default: its 1-based number)"))


@dataclass(frozen=True)
class Surface:
    """A planar polygon the 3D mesh conforms to without being a fracture (no unknowns, no jump).

    Where data change across a plane that is no fracture: a material interface (a permeability
    that jumps, given with ``where``), or, lying in a box face, the outline of the part of the
    face on which a boundary condition acts (its ``where`` selects faces by their centre).
    It may cross fractures, not overlap one in its plane nor pass within half the fracture size
    of one it does not meet.
    """

    polygon: tuple[tuple[float, float, float], ...] = field(
        metadata=doc("vertices [[x, y, z], ...] of a planar polygon in the box or in a box face",
                     "m")
    )
    name: str | None = field(default=None, metadata=doc("name, for messages (default: its "
                                                        "1-based number)"))


@dataclass(frozen=True)
class MeshFile:
    """A mesh from a file, with named groups of line elements as fractures and boundaries.

    A gmsh .geo (meshed by gmsh, with its own sizes) or .msh file, or any mesh meshio reads
    (groups: its cell sets or gmsh physical names). The mesh must be 3-node triangles in z = 0,
    one piece with no holes. The scene's ``mesh`` key then only gives ``refinement``
    (docs/meshes.md).
    """

    file: str = field(
        metadata=doc("the file: a path relative to the scene file's folder, or the name of a "
                     "shipped file (six_fractures.msh)")
    )
    fractures: tuple[str, ...] = field(
        default=(),
        metadata=doc("groups that are fractures: one chain of triangle edges each, named as the "
                     "group; its polyline runs the way its line elements do in the file"),
    )
    boundaries: dict[str, tuple[str, ...]] | None = field(
        default=None,
        metadata=doc("boundary names, {name: [groups]}, covering the whole boundary (default: "
                     "every group on the boundary, under its own name)"),
    )
    starts: dict[str, tuple[float, float]] = field(
        default_factory=dict,
        metadata=doc("start point of fractures, {fracture: [x, y]} (one of its ends): fixes n⁺ "
                     "instead of the direction of its line elements", "m"),
    )


@dataclass(frozen=True)
class Geometry:
    """Domain and fracture network: given in the scene, from a CSV file, or a mesh file.

    With ``fracture_file`` or ``mesh``, the loader fills ``domain`` and ``fractures`` from the
    file (a mesh file's polygon has one edge per straight run of same-named boundary edges).
    """

    domain: Domain | None = field(
        default=None, metadata=doc("the matrix domain (required unless mesh is given)")
    )
    fractures: tuple[FractureSpec, ...] = field(default=(), metadata=doc("the fracture network"))
    surfaces: tuple[Surface, ...] = field(
        default=(),
        metadata=doc("3D: polygons the mesh conforms to besides the fractures (below)"),
    )
    fracture_file: str | None = field(
        default=None,
        metadata=doc("CSV file of fractures instead of fractures: header fracture,x0,y0,x1,y1 "
                     "(a row per segment) or fracture,x,y (a row per point); path as for "
                     "mesh.file (docs/meshes.md)"),
    )
    mesh: MeshFile | None = field(
        default=None,
        metadata=doc("a mesh file instead of domain, fractures and gmsh generation; the scene's "
                     "mesh key then only gives refinement"),
    )


@dataclass(frozen=True)
class MeshZone:
    """A ball of finer mesh, e.g. around an injection point or a well (docs/meshes.md).

    Within ``radius`` of ``center`` the element size is at most ``size``: on the fractures, from
    which it grows to the size around over ``transition`` (``region: fractures``, the default: a
    thin refined layer, where the jumps and the fracture flow are), or in the whole ball
    (``region: ball``). Beyond the ball the size grows to ``mesh.size`` over ``transition``.
    gmsh meshes only (not a ``geometry.mesh`` file).
    """

    center: tuple[float, ...] = field(metadata=doc("centre [x, y] (3D: [x, y, z])", "m"))
    radius: float = field(metadata=doc("radius of the ball", "m", gt=0))
    size: float = field(metadata=doc("element size in the ball", "m", gt=0))
    transition: float | None = field(
        default=None, metadata=doc("distance over which the size grows from size (default: "
                                   "mesh.transition)", "m", gt=0)
    )
    region: Literal["fractures", "ball"] = field(
        default="fractures",
        metadata=doc("fractures: size on the fractures in the ball; ball: the whole ball"),
    )


@dataclass(frozen=True)
class MeshSpec:
    """gmsh size control and uniform refinement."""

    size: float = field(metadata=doc("element size away from fractures", "m", gt=0))
    fracture_size: float | None = field(
        default=None, metadata=doc("element size along fractures (default: size)", "m", gt=0)
    )
    tip_size: float | None = field(
        default=None, metadata=doc("element size at fracture ends (default: fracture_size)", "m",
                                   gt=0)
    )
    transition: float | None = field(
        default=None, metadata=doc("distance over which sizes grow to size (default: 4 size)", "m",
                                   gt=0)
    )
    refinement: int = field(
        default=0, metadata=doc("uniform refinement level m (each level: cells x4 and fracture "
                                "faces x2 in 2D, x8 and x4 in 3D)", "", min=0, max=7)
    )
    zones: tuple[MeshZone, ...] = field(
        default=(), metadata=doc("balls of finer mesh (below)")
    )


@dataclass(frozen=True)
class Material:
    """Linear elastic matrix (plane strain in 2D)."""

    young: Expr = field(metadata=doc("Young's modulus E (may vary in space and time)", "Pa",
                                     gt=0))
    poisson: Expr = field(metadata=doc("Poisson's ratio ν", "", gt=-1, lt=0.5))
    body_force: tuple[Expr, ...] | None = field(
        default=None, metadata=doc("body force f, one component per coordinate", "N/m³")
    )
    biot: float = field(
        default=1.0,
        metadata=doc("Biot coefficient b: total stress σ(u) - b p_m I (poromechanics)", "", min=0,
                     max=1),
    )
    density: Expr | None = field(
        default=None,
        metadata=doc("bulk density ρ of the (fluid-saturated) rock: with gravity, the body force "
                     "ρ g is added to body_force", "kg/m³", min=0),
    )
    initial_stress: tuple[Expr, ...] | None = field(
        default=None,
        metadata=doc("in-situ total stress σ⁰ at t = 0, tension positive: [σ_xx, σ_yy, σ_xy] "
                     "(2D) or [σ_xx, σ_yy, σ_zz, σ_yz, σ_xz, σ_xy] (3D). Total, as field "
                     "measurements and the overburden give it: the stress is σ⁰ + σ(u) - b (p_m "
                     "- p⁰) I, displacements are measured from the initial state, and a fracture "
                     "carries σ⁰n⁺ + p_f n⁺ at rest. It must be in equilibrium with the body force "
                     "and the boundary tractions at t = 0 (checked before the first solve); not "
                     "a function of t", "Pa"),
    )


@dataclass(frozen=True)
class Contact:
    """Contact on the fractures: formulation, friction law and Nitsche parameters."""

    formulation: Formulation = field(
        default="nitsche",
        metadata=doc("mixed | stabilized_mixed | mean_nitsche | nitsche | none (open fractures)"),
    )
    friction: Friction = field(default="coulomb", metadata=doc("coulomb | tresca | frictionless"))
    friction_coefficient: float = field(
        default=0.5, metadata=doc("Coulomb friction coefficient F", "", min=0)
    )
    slip_bound: Expr | None = field(
        default=None, metadata=doc("Tresca slip bound s (required for tresca): a number or an "
                                 "expression in t, uniform in space", "Pa", min=0)
    )
    theta: float = field(
        default=-1.0,
        metadata=doc("Nitsche symmetry parameter θ: -1, 0 or 1", "", choices=(-1, 0, 1)),
    )
    beta_n: float | None = field(
        default=None,
        metadata=doc("β_n⁰; β_n = β_n⁰/h_σ (default 250 E_max, E_max the largest Young's "
                     "modulus of the scene: the paper's 1000 GPa for E = 4 GPa)", "Pa", gt=0),
    )
    beta_t: float | None = field(
        default=None,
        metadata=doc("β_τ⁰; β_τ = β_τ⁰/h_σ (default 10 E_max: the paper's 40 GPa for "
                     "E = 4 GPa); with theta 1 both must exceed a mesh-dependent bound "
                     "(docs/mechanics.md)", "Pa", gt=0),
    )
    beta_sm_n: float | None = field(
        default=None,
        metadata=doc("β_n^sm⁰ of the mixed formulation's complementarity functions, "
                     "β_n^sm = β_n^sm⁰/h_σ (Beaude et al. 2023, eq. (4)); a solver parameter, the "
                     "solution does not depend on it (default E_max: Newton converges in about "
                     "half the iterations it needs with beta_n, docs/poromechanics.md)", "Pa",
                     gt=0),
    )
    beta_sm_t: float | None = field(
        default=None,
        metadata=doc("β_τ^sm⁰ of the mixed formulation, β_τ^sm = β_τ^sm⁰/h_σ; a solver "
                     "parameter (default 0.04 E_max, the ratio β_τ⁰/β_n⁰ of the defaults)", "Pa",
                     gt=0),
    )
    #: Default ``β_n⁰ / E_max`` and ``β_τ⁰ / E_max`` (Beaude et al. 2023, §3).
    BETA_N_PER_E: ClassVar[float] = 250.0
    BETA_T_PER_E: ClassVar[float] = 10.0
    #: Default ``β_n^sm⁰ / E_max`` and ``β_τ^sm⁰ / E_max`` of ``mixed``: on the coupled
    #: six-fracture scene (E = 4 GPa) β_n^sm⁰ from 0.1 to 2.5 E_max gave the fewest Newton
    #: iterations; 250 E_max (Nitsche's β_n⁰) about twice as many.
    BETA_SM_N_PER_E: ClassVar[float] = 1.0
    BETA_SM_T_PER_E: ClassVar[float] = 0.04
    traction_side: Literal["plus", "mean"] = field(
        default="plus",
        metadata=doc("side whose stress defines T(u): plus (as in the paper) or mean of both"),
    )
    beta_scaling: Literal["largest", "local"] = field(
        default="largest",
        metadata=doc("largest: β_n⁰ and β_τ⁰ act on every face, as in the paper; local: they "
                     "are the values at the largest Young's modulus E_max and each face takes "
                     "β⁰ E_σ/E_max, E_σ the larger modulus of its two cells, so that a fracture "
                     "in soft rock is penalized as much relative to its rock as one in the "
                     "stiffest (docs/mechanics.md)"),
    )


@dataclass(frozen=True)
class BoundaryCondition:
    """A mechanical condition on named boundary edges or faces (default: traction free)."""

    boundary: str = field(metadata=doc("boundary name (rectangle: bottom, right, top, left; "
                                       "box: left, right, front, back, bottom, top)"))
    displacement: tuple[Expr | None, ...] | None = field(
        default=None, metadata=doc("imposed [u_x, u_y] (3D: [u_x, u_y, u_z]); null leaves a "
                                   "component free; each component at most once per boundary; "
                                   "where two boundaries meet the one listed later holds "
                                   "(different values there are reported)", "m")
    )
    traction: tuple[Expr, ...] | None = field(
        default=None, metadata=doc("imposed traction [t_x, t_y] (3D: [t_x, t_y, t_z]); the "
                                   "tractions on one boundary add up; a component whose "
                                   "displacement is imposed there must be 0", "Pa")
    )


@dataclass(frozen=True)
class TimeSpec:
    """Time stepping (implicit Euler, quasi-static): uniform steps or listed step end times.

    Friction then acts on slip increments. A step whose solve fails is retried as halves,
    quarters, ... up to ``max_cuts`` times before the run stops (exit status 3).
    """

    final: float | None = field(default=None, metadata=doc("final time T (uniform steps)", "s",
                                                             gt=0))
    steps: int | None = field(default=None,
                              metadata=doc("number of uniform steps", "", min=1, max=1_000_000))
    times: tuple[float, ...] | None = field(
        default=None,
        metadata=doc("listed step end times t_1 < t_2 < ... (instead of final/steps)", "s", gt=0),
    )
    max_cuts: int = field(
        default=4, metadata=doc("halvings of a failed step before the run stops (fewer when "
                                "a halved step starts from the failed one's residual: loads "
                                "constant in t, the same problem)", "", min=0, max=20)
    )

    @property
    def end(self) -> float:
        """The final time (s)."""
        return float(self.times[-1]) if self.times else float(self.final)


#: ``solver.linear_solver: auto`` solves a 3D system (every formulation but ``mixed``) of more
#: unknowns than this with a Krylov method + GAMG (:mod:`poromech.scene.resources` has the
#: measurements behind it).
ITERATIVE_FROM_UNKNOWNS_3D = 20_000


@dataclass(frozen=True)
class Solver:
    """Semi-smooth Newton (mechanics) and its linear solver."""

    linear_solver: Literal["auto", "direct", "iterative"] = field(
        default="auto",
        metadata=doc("linear solver of the mechanics: direct (MUMPS LU), iterative (CG + GAMG "
                     "with the rigid-body modes of the cracked space as near-nullspace; GMRES "
                     "with an inexact Newton for contact, on the displacement Schur complement "
                     "for mean_nitsche and stabilized_mixed; not for mixed), or auto: direct "
                     "in 2D and for mixed, iterative in 3D above "
                     f"{ITERATIVE_FROM_UNKNOWNS_3D:,} unknowns (counted after meshing), "
                     "switching to MUMPS LU for the rest of the run after a failed Krylov "
                     "solve where the factorization fits in memory; "
                     "solver.petsc options override either's defaults"),
    )
    line_search: Literal["contact", "basic", "bt", "l2", "cp"] = field(
        default="contact",
        metadata=doc("contact (poromech's active-set aware search) or a PETSc line search"),
    )
    predictor: Literal["auto", "extrapolate", "last", "lower_residual"] = field(
        default="auto",
        metadata=doc("start of each step's contact Newton: extrapolate (the unknowns of the "
                     "last two accepted steps, linearly in time), last (the last accepted "
                     "unknowns), lower_residual (whichever of the two has the lower residual; "
                     "one more residual assembly per step), or auto: in a mechanics-only 3D "
                     "scene lower_residual for nitsche, last for mean_nitsche and "
                     "stabilized_mixed; extrapolate otherwise"),
    )
    reuse_jacobian: bool = field(
        default=True, metadata=doc("skip refactorization when the Jacobian did not change")
    )
    stale_factorization: bool = field(
        default=True,
        metadata=doc("after few contact-state changes, try GMRES preconditioned by the last "
                     "factorization before refactorizing"),
    )
    condensation: bool = field(
        default=True,
        metadata=doc("mixed, degree >= 2: solve each contact problem condensed onto the face "
                     "unknowns (one factorization of the elastic operator for the run), then "
                     "check it with the regular Newton"),
    )
    petsc: dict[str, str | float | int | bool | None] = field(
        default_factory=dict,
        metadata=doc("PETSc options for the mechanics solver, without the mech_ prefix"),
    )


@dataclass(frozen=True)
class FlowBoundaryCondition:
    """A flow condition on named boundary edges (unlisted boundaries are impervious)."""

    boundary: str = field(metadata=doc("boundary name"))
    pressure: Expr | None = field(default=None, metadata=doc("imposed pressure", "Pa"))
    flux: Expr | None = field(
        default=None,
        metadata=doc("imposed outward volumetric flux per area (negative: inflow)", "m/s"),
    )
    where: Expr | None = field(
        default=None,
        metadata=doc("restrict the condition to the boundary faces whose centre makes this "
                     "expression nonzero (e.g. \"z > 90\"); the rest of the boundary is "
                     "impervious unless another condition with a where covers it. Where two "
                     "conditions of a boundary cover a face, the one listed last applies"),
    )
    fracture_ends: Literal["inherit", "no_flow"] = field(
        default="inherit",
        metadata=doc("fracture ends on this boundary: inherit its condition (pressure, or the "
                     "flux through the fracture cross-section d_f) or no_flow"),
    )


@dataclass(frozen=True)
class FractureFlow:
    """Flow properties of one named fracture, overriding the fracture defaults of ``flow``."""

    fracture: str = field(metadata=doc("fracture name"))
    aperture: Expr | None = field(default=None, metadata=doc("aperture d_f", "m", gt=0))
    permeability: Expr | None = field(
        default=None, metadata=doc("tangential permeability K_f,τ", "m²", gt=0)
    )
    normal_permeability: Expr | None = field(
        default=None, metadata=doc("normal permeability Λ_f,n", "m²", gt=0)
    )
    conductivity: Expr | None = field(
        default=None, metadata=doc("conductivity C_f (replaces K_f,τ d_f)", "m³", gt=0)
    )


@dataclass(frozen=True)
class Flow:
    """Single-phase Darcy flow in matrix and fractures (HFV, DESIGN §5)."""

    permeability: tuple[Expr, ...] = field(
        metadata=doc("matrix permeability: [k] (or k), [k_xx, k_yy] or [k_xx, k_xy, k_yy] "
                     "in 2D; [k], [k_xx, k_yy, k_zz] or [k_xx, k_xy, k_xz, k_yy, k_yz, k_zz] "
                     "in 3D", "m²")
    )
    viscosity: float = field(default=1e-3, metadata=doc("fluid viscosity η", "Pa·s", gt=0))
    fluid_density: float | None = field(
        default=None,
        metadata=doc("fluid density ρ_f (required with gravity): Darcy's law acts on the "
                     "potential p - ρ_f g·x, so that a hydrostatic pressure is at rest",
                     "kg/m³", gt=0),
    )
    aperture: Expr = field(
        default=Expression(1e-4),
        metadata=doc("fracture aperture d_f; for poromechanics the aperture at contact d₀, and "
                     "d_f = d₀ - [[u]]_n", "m", gt=0),
    )
    fracture_permeability: Expr | None = field(
        default=None,
        metadata=doc("tangential fracture permeability K_f,τ (default d_f²/12)", "m²", gt=0),
    )
    fracture_normal_permeability: Expr | None = field(
        default=None, metadata=doc("normal fracture permeability Λ_f,n (default d_f²/12); "
                                   "T_f = 2 Λ_f,n / d_f", "m²", gt=0)
    )
    fracture_conductivity: Expr | None = field(
        default=None,
        metadata=doc("fracture conductivity C_f (default K_f,τ d_f, i.e. d_f³/12)", "m³", gt=0),
    )
    fractures: tuple[FractureFlow, ...] = field(
        default=(), metadata=doc("per-fracture values overriding the fracture defaults")
    )
    source: Expr = field(default=Expression(0.0), metadata=doc("matrix volumetric source", "1/s"))
    fracture_source: Expr = field(
        default=Expression(0.0), metadata=doc("fracture source per fracture area", "m/s")
    )
    boundary_conditions: tuple[FlowBoundaryCondition, ...] = field(
        default=(), metadata=doc("pressure / flux conditions; other boundaries are impervious")
    )
    initial_pressure: Expr = field(
        default=Expression(0.0),
        metadata=doc("initial pressure p⁰ (transient; physics flow without biot_modulus: only "
                     "the state at t = 0)", "Pa"),
    )
    porosity: float = field(default=0.0, metadata=doc("initial matrix porosity φ⁰ (transient)", "",
                                                      min=0, max=1))
    biot_modulus: float | None = field(
        default=None,
        metadata=doc("Biot modulus M, matrix storage 1/M (transient; absent: no storage)", "Pa",
                     gt=0),
    )
    stabilization: float | None = field(
        default=None, metadata=doc("HFV stabilization β (default √d)", "", gt=0)
    )
    linear_solver: Literal["auto", "iterative", "direct"] = field(
        default="auto",
        metadata=doc("defaults of the flow_ solver: iterative (CG + GAMG), direct (MUMPS), or "
                     "auto: iterative, and MUMPS for the rest of the run after a failed "
                     "Krylov solve where it fits in memory"),
    )
    petsc: dict[str, str | float | int | bool | None] = field(
        default_factory=dict,
        metadata=doc("PETSc options for the flow solver, without the flow_ prefix; null removes "
                     "a default"),
    )


@dataclass(frozen=True)
class Probe:
    """A straight line along which fields are sampled to probe_<name>.csv at every output time.

    Columns: ``time, arc_length, x, y``, then the fields of the physics: displacement ``u_x,
    u_y`` (mechanics; on a fracture, that of one side), and where the line runs along a fracture
    its ``jump_n, jump_t, traction_n, traction_t``; ``p_m, p_f`` (flow); all of these and
    ``porosity`` (poromechanics). Empty where the line leaves the domain or a fracture.
    """

    name: str = field(metadata=doc("probe name (file probe_<name>.csv)"))
    start: tuple[float, ...] = field(metadata=doc("start point [x, y] (3D: [x, y, z])", "m"))
    end: tuple[float, ...] = field(metadata=doc("end point", "m"))
    samples: int = field(default=201, metadata=doc("number of sample points", "", min=2,
                                                    max=100_000))
    interpolation: Literal["linear", "constant"] = field(
        default="linear",
        metadata=doc("linear: p_m from the HFV cell gradient, p_f linear between face and node "
                     "values in 2D (in 3D the face value on the whole triangle: the fracture "
                     "unknowns are on its edges); constant: the cell / face value (flow and "
                     "poromechanics)"),
    )


@dataclass(frozen=True)
class Coupling:
    """The fixed point ``p = g(p)`` of a poromechanics step, solved by a PETSc SNES (``coupling_``).

    ``g`` solves the contact mechanics at the given matrix and fracture pressures, then Darcy at
    the resulting porosity and aperture (Beaude et al. 2023, §3).
    """

    method: Literal["anderson", "ngmres", "qn", "composite", "newtonkrylov", "picard"] = field(
        default="anderson",
        metadata=doc("anderson | ngmres | qn | composite (Anderson on Picard sweeps) | "
                     "newtonkrylov (matrix-free Newton-GMRES) | picard (plain fixed point)"),
    )
    fallback: Literal["none", "anderson", "ngmres", "qn", "composite", "newtonkrylov",
                      "picard"] = field(
        default="ngmres",
        metadata=doc("method a step is solved again with, from the same start, when `method` "
                     "fails on it, before the step is cut (NGMRES chooses between the "
                     "accelerated and the plain fixed-point iterate and restarts when they "
                     "stagnate; Anderson does neither); none, or the method itself: cut at "
                     "once. Not after a failed contact or Darcy solve inside g; once per "
                     "accepted state (the sub-steps of a cut go without it until one "
                     "converges)"),
    )
    rtol: float = field(
        default=1e-5, metadata=doc("stop when |p - g(p)| <= rtol |p0 - g(p0)| (the paper's 1e-5)",
                                   "", gt=0, lt=1)
    )
    atol: float = field(
        default=1e-6,
        metadata=doc("or when |p - g(p)| / sqrt(N) <= atol (a step that barely changes p)", "Pa",
                     min=0),
    )
    max_it: int = field(
        default=300,
        metadata=doc("largest number of iterations of an attempt (the paper's scene needs at most "
                     "9 per step; slow steps of extreme cases up to 190, e.g. a sealed fracture "
                     "network; divergence is detected earlier, and an attempt whose best "
                     "|p - g(p)| has not been halved for 150 iterations ends as stalled)", "",
                     min=1),
    )
    memory: int = field(
        default=15,
        metadata=doc("Anderson/NGMRES history (snes_anderson_m, snes_ngmres_m); the paper's scene"
                     " converges within 5 iterations per step, slow steps gain from more",
                     "", min=1, max=50),
    )
    stabilization: float = field(
        default=0.5,
        metadata=doc("fixed-stress term β (p - p_in) in the Darcy solve of g, β = factor · b²/K_dr,"
                     " K_dr = λ + μ; 0 is the paper's g, 0.5 the smallest factor with a proof of "
                     "convergence for linear Biot (Both et al. 2017); the fixed point is the same",
                     "", min=0, max=10),
    )
    fracture_stabilization: float | None = field(
        default=None,
        metadata=doc("fixed-stress term β_f (p_f - p_in) in the fracture volume balance of the "
                     "Darcy solve of g, β_f = factor · π(1 - ν²) a / E (mean opening per unit "
                     "pressure of a crack of half-length a); for fractures sealed by a nearly "
                     "impervious matrix; the fixed point is the same. null: off until a step "
                     "fails with a Darcy solve in g that is not to be trusted (estimated error "
                     "above 1e-4 |p|) or by divergence (|p - g(p)| grown 1e3-fold, as in a "
                     "very short step), then 1 for the rest of the run", "", min=0, max=10),
    )
    extrapolate: bool = field(
        default=True,
        metadata=doc("start each step from p extrapolated linearly from the two previous steps"),
    )
    petsc: dict[str, str | float | int | bool | None] = field(
        default_factory=dict,
        metadata=doc("PETSc options of the fixed point, without the coupling_ prefix"),
    )


@dataclass(frozen=True)
class Output:
    """What is written to the output directory."""

    xdmf: bool = field(default=True, metadata=doc("XDMF files for ParaView"))
    checkpoint: bool = field(
        default=True,
        metadata=doc("checkpoint.h5 after every step of a time-dependent run (for --restart)"),
    )
    fractures_csv: bool = field(default=True, metadata=doc("fractures.csv, one row per face/time "
                                                           "(not written without fractures)"))
    every: int = field(default=1, metadata=doc("write every n-th time step", "", min=1))


@dataclass(frozen=True)
class Scene:
    """A complete simulation description."""

    name: str = field(metadata=doc("scene name"))
    physics: Literal["mechanics", "flow", "poromechanics"] = field(
        default="mechanics",
        metadata=doc("mechanics (contact), flow (Darcy only) or poromechanics (both, coupled)"),
    )
    description: str = field(default="", metadata=doc("free text"))
    parameters: dict[str, float] = field(
        default_factory=dict, metadata=doc("named constants usable in every expression")
    )
    geometry: Geometry | None = field(
        default=None, metadata=doc("domain and fractures, or the name of a file in meshes/")
    )
    mesh: MeshSpec | None = field(default=None, metadata=doc("mesh size control"))
    degree: int = field(default=2, metadata=doc("displacement degree (1 or 2)", "",
                                                choices=(1, 2)))
    material: Material | None = field(default=None, metadata=doc("elastic matrix"))
    contact: Contact = field(default_factory=Contact, metadata=doc("contact on the fractures"))
    fracture_pressure: Expr | None = field(
        default=None, metadata=doc("fluid pressure p_f acting on both fracture faces", "Pa")
    )
    gravity: tuple[float, ...] | None = field(
        default=None,
        metadata=doc("gravitational acceleration g, one component per coordinate, e.g. [0, -9.81] "
                     "(2D, y up): the body force ρ g (material.density) and, with flow, Darcy's "
                     "law on p - ρ_f g·x (flow.fluid_density)", "m/s²"),
    )
    boundary_conditions: tuple[BoundaryCondition, ...] = field(
        default=(), metadata=doc("mechanical boundary conditions")
    )
    time: TimeSpec | None = field(default=None, metadata=doc("time stepping (absent: one solve)"))
    solver: Solver = field(default_factory=Solver, metadata=doc("nonlinear solver"))
    flow: Flow | None = field(
        default=None, metadata=doc("Darcy flow (physics: flow and poromechanics)")
    )
    coupling: Coupling = field(
        default_factory=lambda: Coupling(),
        metadata=doc("fixed point of the coupled solve (physics: poromechanics)"),
    )
    probes: tuple[Probe, ...] = field(default=(), metadata=doc("sampling lines"))
    output: Output = field(default_factory=Output, metadata=doc("output selection"))


def scene_dimension(scene: Scene) -> int:
    """2, or 3 for a box domain."""
    return 3 if scene.geometry.domain is not None and scene.geometry.domain.box is not None else 2


def step_times(scene: Scene) -> list[float]:
    """End times of the steps: ``[0]`` for a static scene, else the uniform or listed times."""
    spec = scene.time
    if spec is None:
        return [0.0]
    if spec.times:
        return [float(t) for t in spec.times]
    return [float(t) for t in np.linspace(0.0, spec.final, spec.steps + 1)[1:]]
