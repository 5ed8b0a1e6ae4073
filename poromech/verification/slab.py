"""A 2D scene as a one-layer 3D slab: the plane-strain check of the 3D discretization.

The 2D scene's ``(x, y)`` plane becomes the 3D ``(x, z)`` plane and the slab is one layer of
cells thick in ``y``: every triangle of the 2D mesh is extruded into a prism, split into three
tetrahedra, and every fracture segment into a rectangle made of two triangles. With ``u_y = 0``
on the front and back faces (every vertex lies on one of them) the 3D problem is the
plane-strain problem of the 2D scene, so its fracture jumps must reproduce the 2D ones to the 2D
discretization error (``tests/test_mechanics3d.py``, ``tests/test_slab3d.py``).

Prisms are split by the rule of the sorted vertex numbers: with the triangle's nodes
``a < b < c``, the tetrahedra ``(a₀ b₀ c₀ c₁)``, ``(a₀ b₀ b₁ c₁)`` and ``(a₀ a₁ b₁ c₁)``, where
``₀`` and ``₁`` are the front and back copies of a node. Every quadrilateral side is then cut
along the diagonal from its lower-numbered front node to its higher-numbered back node, the same
from both prisms that share it, so the tetrahedra are conforming.

A fracture polyline with corners becomes one fracture made of planar rectangles, one per
segment (:class:`SlabGeometry` gives each face the frame of its segment); crossings, T-junctions
and fractures that reach the boundary are extruded with the mesh. :func:`slab_scene` turns a 2D
scene (mechanics, flow or coupled: its boundary conditions, contact, material, flow, coupling,
gravity, probes, time steps) into the slab's 3D scene, to run with the mesh of
:func:`slab_mesh`. Flow in the 2D plane is per unit depth and the slab's front and back are
impervious, so the per-volume and per-area quantities (sources, fluxes, apertures) are the 2D
ones and the slab carries the 2D flow over its thickness.
"""

from __future__ import annotations

import copy
import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from mpi4py import MPI

from poromech.geometry.box import BoxGeometry, Fracture3D
from poromech.geometry.plane import PlaneGeometry
from poromech.mesh.fractured import FracturedMesh, distribute_mesh
from poromech.mesh.generate import MeshArrays, generate_mesh
from poromech.scene.geometry import mesh_sizes, scene_geometry
from poromech.scene.loading import scene_from_dict
from poromech.scene.schema import Flow, FlowBoundaryCondition, FractureFlow, Scene

__all__ = ["FLOW_FIELDS", "SLAB_FACES", "SUMMARY_FIELDS", "SlabGeometry", "fracture_summary",
           "slab_arrays", "slab_geometry", "slab_mesh", "slab_scene"]

#: The 3D face of each 2D rectangle edge (the 2D y axis is the 3D z axis).
SLAB_FACES = {"bottom": "bottom", "right": "right", "top": "top", "left": "left"}

#: The name ``y`` in an expression (not part of a longer name or a number).
_Y = re.compile(r"(?<![\w.])y(?!\w)")


def _lift(points: npt.NDArray[np.float64], y: float) -> npt.NDArray[np.float64]:
    """2D points ``(x, y)`` as 3D points ``(x, y3, y)``."""
    return np.column_stack([points[:, 0], np.full(len(points), y), points[:, 1]])


@dataclass(frozen=True, eq=False)
class SlabGeometry(BoxGeometry):
    """The box and extruded fractures of a slab, with the 2D geometry it comes from.

    A fracture with corners is not planar: its faces take the frame of their polyline segment,
    ``n⁺ = (n_x, 0, n_y)`` and ``τ_1 = (τ_x, 0, τ_y)`` from the 2D ``n⁺`` and ``τ``, and
    ``τ_2 = n⁺ × τ_1 = e_y`` (the slip out of the plane).

    Attributes:
        plane: The 2D geometry.
    """

    plane: PlaneGeometry | None = None

    def face_frames(self, fracture: npt.NDArray[np.int32], segment: npt.NDArray[np.int32]
                    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """``n⁺`` ``(n, 3)`` and the tangents ``(n, 2, 3)`` of faces (fracture, 2D segment)."""
        n2, t2 = self.plane.face_frames(np.asarray(fracture), np.asarray(segment))
        normal, t1 = _lift(n2, 0.0), _lift(t2[:, 0], 0.0)
        return normal, np.stack([t1, np.cross(normal, t1)], axis=1)


def slab_geometry(geo: PlaneGeometry, thickness: float) -> SlabGeometry:
    """The box and fractures of a rectangle with fracture polylines, extruded.

    A fracture ``P_0 … P_k`` becomes the polygon ``P_0⁰ … P_k⁰ P_k¹ … P_0¹`` (front points, then
    the back points in reverse); a straight one is the rectangle whose right-hand normal is the
    2D left normal ``n⁺`` in the ``(x, z)`` plane.

    Raises:
        ValueError: The domain is not a rectangle with edges bottom, right, top, left.
    """
    lo, hi = geo.boundary.min(axis=0), geo.boundary.max(axis=0)
    if len(geo.boundary) != 4 or set(geo.boundary_names) != set(SLAB_FACES):
        raise ValueError("a slab extrudes a rectangle (edges bottom, right, top, left)")
    fractures = tuple(
        Fracture3D.polygon(name, np.concatenate([_lift(pts, 0.0), _lift(pts[::-1], thickness)]))
        for pts, name in zip(geo.fractures, geo.fracture_names, strict=True))
    box = (float(lo[0]), 0.0, float(lo[1]), float(hi[0]), float(thickness), float(hi[1]))
    return SlabGeometry(box, fractures, plane=geo)


def _quads(edges: npt.NDArray[np.int64], n: int) -> npt.NDArray[np.int64]:
    """The two triangles of the extruded side of each edge, cut as the prisms cut it."""
    p, q = edges.min(axis=1), edges.max(axis=1)
    first = np.column_stack([p, q, q + n])
    second = np.column_stack([p, p + n, q + n])
    return np.stack([first, second], axis=1).reshape(-1, 3)


def slab_arrays(arrays: MeshArrays, geo: PlaneGeometry, slab: BoxGeometry) -> MeshArrays:
    """The one-layer tetrahedral mesh of a 2D triangle mesh (input numbering, 3D shapes).

    Node ``i`` of the 2D mesh gives nodes ``i`` (front, ``y = 0``) and ``i + n`` (back).
    Fracture and boundary faces are numbered after the 2D faces they come from (two each, with
    the fracture and polyline segment of their 2D face); the front and back faces of the box are
    the 2D triangles on either side.
    """
    n = len(arrays.x)
    thickness = slab.upper[1]
    x = np.concatenate([_lift(arrays.x, 0.0), _lift(arrays.x, thickness)])
    a, b, c = np.sort(arrays.cells, axis=1).T
    cells = np.concatenate([np.column_stack([a, b, c, c + n]),
                            np.column_stack([a, b, b + n, c + n]),
                            np.column_stack([a, a + n, b + n, c + n])])
    d = x[cells[:, 1:]] - x[cells[:, :1]]
    negative = np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2])) < 0
    cells[negative] = cells[negative][:, [0, 1, 3, 2]]
    faces = list(slab.boundary_names)
    edge_face = np.array([faces.index(SLAB_FACES[geo.boundary_names[e]])
                          for e in arrays.boundary_edge], dtype=np.int32)
    boundary = np.concatenate([_quads(arrays.boundary_facets, n), arrays.cells,
                               arrays.cells + n])
    boundary_face = np.concatenate([np.repeat(edge_face, 2),
                                    np.full(len(arrays.cells), faces.index("front")),
                                    np.full(len(arrays.cells), faces.index("back"))])
    nf = len(arrays.fracture_facets)
    return MeshArrays(
        x=x, cells=cells.astype(np.int64),
        fracture_facets=_quads(arrays.fracture_facets, n),
        fracture_id=np.repeat(arrays.fracture_id, 2).astype(np.int32),
        fracture_segment=np.repeat(arrays.fracture_segment, 2).astype(np.int32),
        fracture_s=np.full(2 * nf, np.nan),
        boundary_facets=boundary.astype(np.int64),
        boundary_edge=boundary_face.astype(np.int32),
    )


def slab_mesh(scene: Scene, thickness: float, comm: MPI.Comm = MPI.COMM_WORLD
              ) -> FracturedMesh:
    """The slab mesh of a 2D scene meshed by gmsh (its sizes and refinement) (collective)."""
    geo = scene_geometry(scene)
    slab = slab_geometry(geo, thickness)
    return distribute_mesh(comm, slab,
                           lambda: slab_arrays(generate_mesh(geo, mesh_sizes(scene)), geo, slab))


def _in_xz(value):
    """A 2D expression in ``(x, y)`` as one in the slab's ``(x, z)`` (numbers unchanged)."""
    return _Y.sub("z", value) if isinstance(value, str) else value


def _vector(value, middle):
    """A 2D vector ``[v_x, v_y]`` as the 3D ``[v_x, middle, v_z]``, expressions in ``(x, z)``."""
    if value is None:
        return None
    vx, vy = (_in_xz(v) for v in value)
    return [vx, middle, vy]


def _expressions(cls) -> tuple[str, ...]:
    """The keys of a scene section that hold one expression (``Expr`` or ``Expr | None``)."""
    return tuple(f.name for f in dataclasses.fields(cls) if re.fullmatch(r"Expr( \| None)?",
                                                                           str(f.type)))


def _in_xz_keys(section: Mapping, keys: tuple[str, ...]) -> dict:
    """A scene section with the expressions of ``keys`` in ``(x, z)``."""
    return {k: _in_xz(v) if k in keys else v for k, v in section.items()}


def _permeability(value) -> list:
    """2D permeability components as 3D ones, with ``k_yy = k_xx`` across the slab.

    ``[k]`` stays isotropic, ``[k_xx, k_yy]`` becomes ``[k_xx, k_xx, k_yy]`` and
    ``[k_xx, k_xy, k_yy]`` the six components ``[k_xx, 0, k_xy, k_xx, 0, k_yy]``. No flow
    crosses the slab (impervious front and back, no gradient in ``y``), so any positive
    ``k_yy`` would do; ``k_xx`` keeps an isotropic tensor isotropic.
    """
    k = [_in_xz(c) for c in (value if isinstance(value, list | tuple) else [value])]
    if len(k) == 2:
        return [k[0], k[0], k[1]]
    if len(k) == 3:
        return [k[0], 0.0, k[1], k[0], 0.0, k[2]]
    return k


def _slab_flow(flow: Mapping) -> dict:
    """The ``flow`` section of the slab: boundaries to box faces, expressions in ``(x, z)``."""
    out = _in_xz_keys(flow, _expressions(Flow))
    if "permeability" in flow:
        out["permeability"] = _permeability(flow["permeability"])
    out["fractures"] = [_in_xz_keys(f, _expressions(FractureFlow))
                        for f in flow.get("fractures") or ()]
    out["boundary_conditions"] = [
        {**_in_xz_keys(bc, _expressions(FlowBoundaryCondition)),
         "boundary": SLAB_FACES[bc["boundary"]]} for bc in flow.get("boundary_conditions") or ()]
    return out


def _initial_stress(stress) -> list | None:
    """2D ``[σ_xx, σ_yy, σ_xy]`` as the slab's ``[σ_xx, σ_yy, σ_zz, σ_yz, σ_xz, σ_xy]``.

    The out-of-plane ``σ_yy`` of the slab is 0: the 2D scene does not give it and it acts on
    nothing (``n⁺`` has no ``y`` component, ``u_y = 0`` on front and back).
    """
    if stress is None:
        return None
    sxx, syy, sxy = (_in_xz(s) for s in stress)
    return [sxx, 0.0, syy, 0.0, sxy, 0.0]


def _slab_mechanics(raw: dict) -> None:
    """Material, contact, fracture pressure and boundary conditions of the slab, in place."""
    material = dict(raw.get("material") or {})
    raw["material"] = {k: _vector(v, 0.0) if k == "body_force" else _in_xz(v)
                       for k, v in material.items() if k != "initial_stress"}
    if material.get("initial_stress") is not None:
        raw["material"]["initial_stress"] = _initial_stress(material["initial_stress"])
    raw["contact"] = {k: _in_xz(v) for k, v in (raw.get("contact") or {}).items()}
    if "fracture_pressure" in raw:
        raw["fracture_pressure"] = _in_xz(raw["fracture_pressure"])
    bcs = []
    for bc in raw.get("boundary_conditions") or ():
        face = SLAB_FACES[bc["boundary"]]
        if bc.get("displacement") is not None:
            bcs.append({"boundary": face, "displacement": _vector(bc["displacement"], None)})
        else:
            bcs.append({"boundary": face, "traction": _vector(bc["traction"], 0.0)})
    raw["boundary_conditions"] = bcs + [{"boundary": b, "displacement": [None, 0.0, None]}
                                        for b in ("front", "back")]
    solver = dict(raw.get("solver") or {})
    if solver.get("linear_solver", "auto") == "auto":
        # the 2D scene's solver: direct (faster at slab sizes; on this one layer of cells GMRES
        # + GAMG fails on the contact Jacobians with either level smoother, SOR or Jacobi)
        solver["linear_solver"] = "direct"
    raw["solver"] = solver


def _slab_raw(raw: Mapping, slab: SlabGeometry, fractures: list[list[list[float]]]) -> dict:
    """The raw 3D scene of the slab (with the given fracture polygons)."""
    raw = copy.deepcopy(dict(raw))
    if raw.get("physics", "mechanics") != "flow":
        _slab_mechanics(raw)
    if raw.get("flow") is not None:
        raw["flow"] = _slab_flow(raw["flow"])
    if raw.get("gravity") is not None:
        raw["gravity"] = _vector(raw["gravity"], 0.0)
    middle = 0.5 * (slab.lower[1] + slab.upper[1])
    raw["probes"] = [{**p, "start": _vector(p["start"], middle), "end": _vector(p["end"], middle)}
                     for p in raw.get("probes") or ()]
    raw["geometry"] = {"domain": {"box": list(slab.box)},
                       "fractures": [{"name": f.name, "polygon": p}
                                     for f, p in zip(slab.fractures, fractures, strict=True)]}
    raw["mesh"] = {"size": slab.upper[1] - slab.lower[1]}
    return raw


def slab_scene(raw: Mapping, slab: SlabGeometry) -> Scene:
    """The 3D scene of the slab of a 2D scene (validated).

    ``raw`` is the 2D scene's mapping (after overrides; :func:`load_scene_and_raw`). Boundary
    conditions, mechanical and flow, go to the box faces of their edges (a 2D vector
    ``[v_x, v_y]`` becomes ``[v_x, ·, v_y]``, the name ``y`` in expressions becomes ``z``);
    ``u_y = 0`` is imposed on front and back, which are impervious. Gravity ``[g_x, g_y]``
    becomes ``[g_x, 0, g_y]``, probes run at mid-thickness (a point ``[x, y]`` becomes
    ``[x, H/2, y]``), the initial stress gets ``σ_yy = 0`` out of the plane, the matrix
    permeability ``k_yy = k_xx`` across the slab (:func:`_permeability`). Contact, material, flow
    coefficients, coupling, time stepping, solver and output are kept, except that an ``auto``
    linear solver is direct, as in 2D (faster at these sizes). The scene's ``mesh`` key only
    holds the slab thickness (the mesh is :func:`slab_mesh`'s).

    The 3D checks of a box geometry are made for gmsh and require planar fractures: they are
    run on each fracture's chord (the rectangle from its first to its last point), and the
    scene then holds the extruded polylines of ``slab``.

    Raises:
        ConfigError: The 3D scene is invalid.
    """
    chords = [np.concatenate([f.points[[0, n // 2 - 1]], f.points[[n // 2, n - 1]]]).tolist()
              for f in slab.fractures for n in [len(f.points)]]
    scene = scene_from_dict(_slab_raw(raw, slab, chords))
    specs = tuple(dataclasses.replace(s, polygon=tuple(map(tuple, f.points.tolist())))
                  for s, f in zip(scene.geometry.fractures, slab.fractures, strict=True))
    return dataclasses.replace(
        scene, geometry=dataclasses.replace(scene.geometry, fractures=specs))


#: The per-fracture quantities of :func:`fracture_summary`, and those it adds with a flow.
SUMMARY_FIELDS = ("jump_n", "jump_t", "jump_y", "open", "stick", "slip")
FLOW_FIELDS = ("aperture", "p_f")


def fracture_summary(model, fm: FracturedMesh, flow=None) -> dict[str, npt.NDArray[np.float64]]:
    """Per fracture, the current state of a 2D run or of its slab (collective).

    ``jump_n`` and ``jump_t``: means over the fracture (weighted by face length or area) of the
    normal jump and of the tangential jump along the 2D tangent ``τ`` (in 3D its component on
    ``τ_1 = (τ_x, 0, τ_y)``); ``jump_y``: the largest ``|[[u]]_y|`` of a face (0 in 2D), the
    slip out of the plane; ``open``, ``stick``, ``slip``: the fractions of the fracture's length
    or area in each contact state (:meth:`MechanicsModel.states`). With the Darcy problem
    ``flow`` of a coupled run, also the means of the aperture (m) and of the fracture pressure
    ``p_f`` (Pa). Each is an array over the fractures, reduced over the ranks.
    """
    values, faces = model.face_fields(), fm.fractures
    if "jump_tx" in values:
        jump = np.column_stack([values[f"jump_t{c}"] for c in "xyz"])
        jt = np.einsum("ij,ij->i", jump, faces.tangents[:, 0])
        jy = np.abs(values["jump_ty"])
    else:
        jt, jy = values["jump_t"], np.zeros(len(faces.measure))
    states = model.states(values)
    comm, k = fm.msh.comm, len(fm.geometry.fracture_names)
    w = faces.measure

    def total(q):
        return comm.allreduce(np.bincount(faces.fracture, weights=q, minlength=k), op=MPI.SUM)

    def largest(q):  # elementwise (the pickling allreduce compares whole arrays)
        out = np.empty_like(q)
        comm.Allreduce(q, out, op=MPI.MAX)
        return out

    length = total(w)
    out = {"jump_n": total(w * values["jump_n"]) / length, "jump_t": total(w * jt) / length,
           "jump_y": largest(np.array([jy[faces.fracture == j].max(initial=0.0)
                                       for j in range(k)]))}
    for code, name in enumerate(("open", "stick", "slip")):
        out[name] = total(w * (states == code)) / length
    if flow is not None:
        out["aperture"] = total(w * flow.properties.aperture) / length
        out["p_f"] = total(w * flow.fracture_pressure) / length
    return out
