"""No scene key is accepted and ignored: keys a scene cannot use are refused or reported.

A key that belongs to a physics the scene does not run (``flow`` in a mechanics scene,
``contact`` in a flow scene) is refused with a one-line :class:`ConfigError`. A key whose effect
depends on another choice of the scene and has none under the current one (``contact.theta``
with ``mixed``, ``flow.biot_modulus`` in a steady scene, ``mesh.tip_size`` without fractures)
is reported by one warning line, and the run goes on: scenes are often varied with ``--set``
(a formulation sweep keeps its Nitsche parameters), so these are not errors.

``tests/test_scene_keys.py`` walks the schema and checks, key by key and physics by physics,
that every key given either changes the results or is refused or reported here.
"""

from __future__ import annotations

import ast
import logging
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from poromech.errors import ConfigError
from poromech.geometry.box import point_segment_distance
from poromech.geometry.plane import PlaneGeometry
from poromech.scene.schema import NITSCHE_FORMULATIONS, Scene

__all__ = ["Unused", "check_keys_used", "given_keys", "unused_keys"]

log = logging.getLogger("poromech")

#: Sections of another physics: refused (scene keys, dotted, and what the physics lacks).
_OTHER_PHYSICS = {
    "mechanics": (("flow", "coupling"),
                  "physics 'mechanics' solves no flow (physics 'poromechanics' couples the "
                  "two)"),
    "flow": (("material", "contact", "solver", "degree", "boundary_conditions",
              "fracture_pressure", "coupling"),
             "physics 'flow' solves no mechanics (flow.boundary_conditions are the flow's; "
             "physics 'poromechanics' couples the two)"),
    "poromechanics": ((), ""),
}

#: Contact keys and the formulations that use them (besides ``formulation`` and ``friction``).
_CONTACT_USE = {
    "theta": NITSCHE_FORMULATIONS,
    "beta_n": NITSCHE_FORMULATIONS,
    "beta_t": NITSCHE_FORMULATIONS,
    "beta_sm_n": ("mixed",),
    "beta_sm_t": ("mixed",),
    "traction_side": NITSCHE_FORMULATIONS,
    "beta_scaling": NITSCHE_FORMULATIONS,
}

#: Solver keys of the contact solve only (``line_search``, ``reuse_jacobian`` and the ``petsc``
#: options also act on the SNES that solves a scene without contact).
_NEWTON_KEYS = ("stale_factorization", "condensation")

#: Flow keys about fractures, of no use in a scene without them.
_FRACTURE_FLOW_KEYS = ("aperture", "fracture_permeability", "fracture_normal_permeability",
                       "fracture_conductivity", "fractures", "fracture_source")

#: Coupling methods whose PETSc solver has a history length (``coupling.memory``).
_WITH_MEMORY = ("anderson", "ngmres", "qn", "composite")


@dataclass(frozen=True)
class Unused:
    """A key given in a scene that cannot act on its results.

    Attributes:
        key: The dotted key as given (``contact.theta``, ``flow.fractures.0.aperture``).
        reason: Why, in words a user can act on.
        refuse: True: a ConfigError (it belongs to another physics); False: a warning.
    """

    key: str
    reason: str
    refuse: bool


def given_keys(raw: Mapping) -> list[str]:
    """Dotted paths of the values given in a raw scene mapping (mappings and lists walked).

    A list of mappings gives one path per entry (``probes.0.name``); any other list is one value.
    A key given as null is not given: null is every optional key's default (``--set flow=null``
    takes a coupled scene's flow section away for a mechanics run, ``--set contact.beta_t=null``
    asks for the default β_t; a required key given as null is refused by the schema).
    """
    def walk(node, prefix: str) -> Iterator[str]:
        if isinstance(node, Mapping) and node:
            for k, v in node.items():
                if v is None:
                    continue
                yield from walk(v, f"{prefix}{k}.")
        elif isinstance(node, list) and node and all(isinstance(v, Mapping) for v in node):
            for i, v in enumerate(node):
                yield from walk(v, f"{prefix}{i}.")
        else:
            yield prefix[:-1]
    return [k for k in walk(dict(raw), "") if k]


def _strip_index(key: str) -> str:
    return re.sub(r"\.\d+(?=\.|$)", "", key)


def _under(key: str, section: str) -> bool:
    return key == section or key.startswith(section + ".")


def unused_keys(scene: Scene, given: list[str], geo: PlaneGeometry) -> list[Unused]:
    """The keys of ``given`` that ``scene`` (on geometry ``geo``) cannot use, in given order."""
    has_fractures = bool(geo.fracture_names)
    out: list[Unused] = []
    sections, why = _OTHER_PHYSICS[scene.physics]
    for key in given:
        plain = _strip_index(key)
        refused = next((s for s in sections if _under(plain, s)), None)
        if refused is not None:
            if not any(u.key == refused for u in out):
                out.append(Unused(refused, why, True))
            continue
        reason = (_conditional(scene, plain, has_fractures, geo.dim)
                  or _by_entry(scene, key, geo))
        if reason:
            out.append(Unused(key, reason, False))
    return out


def _conditional(scene: Scene, key: str, has_fractures: bool, dim: int = 2) -> str | None:
    """Why ``key`` (indices stripped) has no effect under the scene's other choices, or None."""
    head, _, rest = key.partition(".")
    mechanics = scene.physics in ("mechanics", "poromechanics")
    c = scene.contact
    contact = mechanics and has_fractures and c.formulation != "none"
    transient = scene.time is not None
    if head == "contact" and mechanics:
        if not has_fractures:
            return "the scene has no fractures"
        if rest != "formulation" and c.formulation == "none":
            return "contact.formulation is none (open fractures, no contact conditions)"
        if rest in _CONTACT_USE and c.formulation not in _CONTACT_USE[rest]:
            return (f"contact.formulation {c.formulation} does not use it (only "
                    f"{', '.join(_CONTACT_USE[rest])})")
        if rest in ("beta_t", "beta_sm_t") and c.friction == "frictionless":
            return "contact.friction is frictionless (no tangential terms)"
        if rest == "friction_coefficient" and c.friction != "coulomb":
            return f"contact.friction is {c.friction} (the coefficient is Coulomb's)"
        if rest == "slip_bound" and c.friction != "tresca":
            return f"contact.friction is {c.friction} (the slip bound is Tresca's)"
        if rest == "beta_scaling" and scene.material is not None \
                and scene.material.young.is_uniform:
            return "material.young is uniform (every face already has the largest modulus)"
    if head == "solver" and mechanics and rest in _NEWTON_KEYS:
        if not contact:
            return "no contact conditions: the mechanics is one linear solve per step"
        if rest == "condensation" and (c.formulation != "mixed" or scene.degree < 2):
            return "the condensed solve is that of contact.formulation mixed with degree 2"
        if rest == "condensation" and dim == 3:
            return ("the condensed solve is 2D only (in 3D its dense face problem on one rank "
                    "grows as the square of the fracture faces)")
    if key == "solver.predictor" and mechanics and not transient:
        return "the scene has no time steps (one solve)"
    if key == "material.biot" and scene.physics == "mechanics":
        return "physics 'mechanics' has no matrix pressure (Biot acts in 'poromechanics')"
    if key == "fracture_pressure" and not has_fractures:
        return "the scene has no fractures"
    if head == "mesh" and rest in ("fracture_size", "tip_size", "transition") \
            and not has_fractures:
        return "the scene has no fractures"
    if head == "flow":
        sub = rest.partition(".")[0]
        if sub in _FRACTURE_FLOW_KEYS and not has_fractures:
            return "the scene has no fractures"
        if sub in ("initial_pressure", "porosity", "biot_modulus") and not transient:
            return "the flow is steady (no time section)"
        if sub == "porosity" and scene.physics == "flow":
            return ("physics 'flow' has no porosity change to add it to (storage is 1/M; "
                    "the porosity is an output of 'poromechanics')")
    if head == "coupling" and scene.physics == "poromechanics":
        methods = {scene.coupling.method, scene.coupling.fallback}
        if rest == "memory" and not methods & set(_WITH_MEMORY):
            return f"coupling.method {scene.coupling.method} keeps no history"
        if rest == "fracture_stabilization" and not has_fractures:
            return "the scene has no fractures"
        if rest in ("stabilization", "fracture_stabilization", "extrapolate") and not transient:
            return ("the scene has no time steps (one solve: no storage term to stabilize, no "
                    "earlier step to extrapolate from)")
        if rest == "stabilization" and scene.material is not None and scene.material.biot == 0:
            return "material.biot is 0 (the fixed-stress term is b²/K_dr)"
    if head == "output" and rest in ("every", "checkpoint") and not transient:
        return "the scene has no time steps (one solve)"
    if head == "output" and rest == "fractures_csv" and not (has_fractures and mechanics):
        return ("the scene has no fractures" if has_fractures is False else
                "physics 'flow' writes no fractures.csv (fracture pressures are in the XDMF "
                "and probe files)")
    if head == "probes" and rest == "interpolation" and scene.physics == "mechanics":
        return "interpolation applies to pressures (flow and poromechanics)"
    return None


#: Fracture defaults of ``flow`` and the ``flow.fractures`` value that overrides each.
_OVERRIDDEN_BY = {"aperture": "aperture", "fracture_permeability": "permeability",
                  "fracture_normal_permeability": "normal_permeability",
                  "fracture_conductivity": "conductivity"}


def _by_entry(scene: Scene, key: str, geo: PlaneGeometry) -> str | None:
    """Why a key of a list entry (or a fracture default) has no effect, or None.

    Flow conditions on edges that no fracture ends on, per-fracture entries without values,
    fracture defaults of ``flow`` that every fracture overrides, and mesh zones that refine
    nothing.
    """
    parts = key.split(".")
    if parts[:2] == ["mesh", "zones"] and len(parts) >= 4:
        return _zone_unused(scene, int(parts[2]), geo)
    if scene.flow is None or parts[0] != "flow":
        return None
    if len(parts) == 2 and parts[1] in _OVERRIDDEN_BY and geo.fracture_names:
        own = {ff.fracture for ff in scene.flow.fractures
               if getattr(ff, _OVERRIDDEN_BY[parts[1]]) is not None}
        if own >= set(geo.fracture_names):
            return (f"every fracture has its own {_OVERRIDDEN_BY[parts[1]]} in flow.fractures")
    if len(parts) < 4:
        return None
    entry = int(parts[2])
    if parts[1] == "boundary_conditions" and parts[3] == "fracture_ends":
        name = scene.flow.boundary_conditions[entry].boundary
        if not _fracture_ends_on(geo, name):
            return f"no fracture ends on boundary {name!r}"
    if parts[1] == "fractures" and parts[3] == "fracture":
        ff = scene.flow.fractures[entry]
        if all(getattr(ff, k) is None for k in ("aperture", "permeability",
                                                "normal_permeability", "conductivity")):
            return "the entry gives no value for its fracture"
    return None


def _zone_unused(scene: Scene, index: int, geo: PlaneGeometry) -> str | None:
    """Why the ``mesh.zones`` entry ``index`` does not change the mesh, or None."""
    zone = scene.mesh.zones[index]
    if scene.geometry is not None and scene.geometry.mesh is not None:
        return "the mesh is read from geometry.mesh.file (zones size the meshes gmsh makes)"
    if zone.region == "fractures" and not geo.fracture_names:
        return "the scene has no fractures for the zone to refine (region: ball refines the ball)"
    m = scene.mesh
    if zone.region == "fractures":
        around = m.fracture_size or m.size
        if zone.size >= around:
            return (f"its size {zone.size:g} m is not finer than the {around:g} m the fractures "
                    "have (mesh.fracture_size, else mesh.size)")
        # the zone's field is the larger of its ball's (finer than mesh.size within radius +
        # transition of the centre) and a band's (within transition of a fracture): it is
        # finer somewhere only within radius + 2 transitions of a fracture
        reach = zone.radius + 2 * (zone.transition or m.transition or 4 * m.size)
        if _distance_to_fractures(geo, np.asarray(zone.center, dtype=float)) >= reach:
            return (f"no fracture is within its radius and twice its transition ({reach:g} m) "
                    "of its centre, and region fractures refines only the fractures there and "
                    "the rock within a transition of them (region: ball refines the rock)")
    elif zone.size >= m.size:
        return f"its size {zone.size:g} m is not finer than mesh.size {m.size:g} m"
    for other in range(len(m.zones)):
        # of two equal zones the later one is reported
        if other != index and _zone_covers(scene, other, index) and not (
                other > index and _zone_covers(scene, index, other)):
            return (f"mesh.zones.{other} asks for a size at most its own wherever its ball "
                    "and transition reach (the mesh takes the finest size asked)")
    return None


def _zone_covers(scene: Scene, a: int, b: int) -> bool:
    """Whether the size field of zone ``a`` is at most zone ``b``'s everywhere.

    A zone's ball field (poromech.mesh.generate.zone_fields) is ``s`` within ``R`` of its
    centre, growing linearly to ``mesh.size`` over ``t``; ``a``'s at distance ``r + δ`` from
    its centre (``δ`` between the centres) bounds it on the points at ``r`` from ``b``'s centre,
    with equality along the ray from ``a``'s centre through ``b``'s, so comparing the two
    piecewise-linear profiles at their kinks decides. On the fractures a zone is the larger of
    its ball and a size growing from ``s`` over ``t`` away from the fractures: ``a`` on the
    fractures covers only such a zone, of a size not finer and a transition not longer.
    """
    m = scene.mesh
    za, zb = m.zones[a], m.zones[b]
    ta, tb = (z.transition or m.transition or 4 * m.size for z in (za, zb))
    if za.region == "fractures" and (zb.region != "fractures" or za.size > zb.size
                                     or ta < tb):
        return False
    delta = float(np.linalg.norm(np.subtract(za.center, zb.center, dtype=float)))

    def field(z, t: float, r: float) -> float:
        return z.size + (m.size - z.size) * min(max((r - z.radius) / t, 0.0), 1.0)

    kinks = (0.0, zb.radius, zb.radius + tb, za.radius - delta, za.radius + ta - delta)
    return all(field(za, ta, r + delta) <= field(zb, tb, r) * (1 + 1e-12)
               for r in kinks if r >= 0.0)


def _distance_to_fractures(geo, point: np.ndarray) -> float:
    """The distance from ``point`` to the nearest fracture (m); inf without fractures."""
    if hasattr(geo, "face_plane"):  # a box (3D): planar polygons and discs
        out = np.inf
        for fr in geo.fractures:
            h = float(fr.height(point)[0])
            r = 0.0 if fr.projects_inside(point)[0] else float(fr.rim_distance(point)[0])
            out = min(out, float(np.hypot(h, r)))
        return out
    p = np.atleast_2d(point[:2])
    return min((float(np.min(point_segment_distance(p, f[:-1], f[1:]))) for f in geo.fractures),
               default=np.inf)


def _fracture_ends_on(geo: PlaneGeometry, name: str) -> bool:
    """True when a fracture ends on the boundary called ``name``.

    2D: an end point on one of its edges; 3D: a point of a fracture's outline on the box face.
    """
    if hasattr(geo, "face_plane"):  # a box (3D): the outlines against the face planes
        tol = 1e-9 * geo.diameter
        faces = [i for i, n in enumerate(geo.boundary_names) if n == name]
        return any(bool(geo.on_boundary(fr.outline(), tol)[:, faces].any())
                   for fr in geo.fractures)
    ends = [p[i] for p in geo.fractures for i in (0, -1)]
    poly = geo.boundary
    tol = 1e-9 * geo.diameter
    for e, edge in enumerate(geo.boundary_names):
        if edge != name:
            continue
        a, b = poly[e], poly[(e + 1) % len(poly)]
        for x in ends:
            s = np.clip(np.dot(x - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
            if np.linalg.norm(a + s * (b - a) - x) <= tol:
                return True
    return False


def unused_parameters(raw: Mapping) -> list[str]:
    """Names of ``parameters`` that no expression or value of the scene uses."""
    params = raw.get("parameters") or {}
    if not isinstance(params, Mapping):
        return []
    names: set[str] = set()

    def walk(node) -> None:
        if isinstance(node, Mapping):
            for v in node.values():
                walk(v)
        elif isinstance(node, list | tuple):
            for v in node:
                walk(v)
        elif isinstance(node, str):
            try:
                tree = ast.parse(node, mode="eval")
            except SyntaxError:
                return
            names.update(n.id for n in ast.walk(tree) if isinstance(n, ast.Name))
    walk({k: v for k, v in raw.items() if k != "parameters"})
    walk(list(params.values()))  # a parameter used by another one is used
    return [str(p) for p in params if str(p) not in names]


def check_keys_used(scene: Scene, raw: Mapping, geo: PlaneGeometry) -> list[Unused]:
    """Refuse the first key of another physics; warn (one line each) for the other unused keys.

    Raises:
        ConfigError: ``scene key 'flow' is not used by physics 'mechanics' ...``.

    Returns:
        The keys reported by a warning (parameters included, as ``parameters.<name>``).
    """
    unused = unused_keys(scene, given_keys(raw), geo)
    for u in unused:
        if u.refuse:
            raise ConfigError(f"scene key '{u.key}' is not allowed: {u.reason}; remove it")
    warned = [u for u in unused if not u.refuse]
    warned += [Unused(f"parameters.{p}", "no expression of the scene uses it", False)
               for p in unused_parameters(raw)]
    for u in warned:
        log.warning("scene key '%s' has no effect: %s", u.key, u.reason)
    if (scene.physics == "flow" and scene.time is not None and scene.flow.biot_modulus is None
            and "flow.initial_pressure" in given_keys(raw)):
        # not "no effect": it is the written state at t = 0
        log.warning("scene key 'flow.initial_pressure' sets only the state written at t = 0: "
                    "without flow.biot_modulus physics 'flow' has no storage, and each time "
                    "step solves the steady problem of its time")
    return warned
