"""Every expression of a scene checked where the solvers evaluate it, once the mesh exists.

Before meshing, :mod:`poromech.scene` checks fields on a grid and boundary and fracture data
along their lines; a narrow strip of negative Young's modulus can fall between grid points.
:func:`validate_fields` closes the gap after meshing and before the first solve: each expression
is evaluated at the very points the solvers use, at every step time, and checked for finiteness
and for the range of its field (``gt``, ``min``, ... in :mod:`poromech.scene.schema`):

================================  ===========================================================
expression                        points
================================  ===========================================================
``material.young``, ``poisson``   cell centroids (DG0)
``material.body_force``           Lagrange nodes of the cells (vertices; P2: edge midpoints)
``boundary_conditions`` data      Lagrange nodes of the boundary facets of their edges
``fracture_pressure``,            fracture face midpoints (DG0 on the fracture faces)
``contact.slip_bound``
``flow.permeability``, ``source`` cell centroids (HFV cell unknowns)
``flow`` fracture fields          fracture face midpoints, per-fracture values on their faces
``flow.initial_pressure``         every HFV unknown: centroids, facet midpoints, fracture nodes
``flow.boundary_conditions``      boundary facet midpoints, fracture nodes on their edges
================================  ===========================================================

The checks run on the owned entities of each rank; the first failure (in the order of the table,
then by rank) is raised as the same one-line :class:`~poromech.scene.ConfigError` on every rank.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import dolfinx_solver  # noqa: F401  (orders MPI before the bindings)

import dolfinx
import numpy as np
import numpy.typing as npt

from poromech.errors import ConfigError
from poromech.mesh.fractured import FracturedMesh
from poromech.parallel import agree
from poromech.scene.schema import Contact, Flow, FractureFlow, Material, Scene, step_times
from poromech.scene.values import check_expression, check_permeability

__all__ = ["validate_fields"]

Array = npt.NDArray[np.float64]

#: Fracture fields of ``flow`` and the ``flow.fractures`` attribute overriding each.
_FRACTURE_FIELDS = {
    "aperture": "aperture",
    "fracture_permeability": "permeability",
    "fracture_normal_permeability": "normal_permeability",
    "fracture_conductivity": "conductivity",
    "fracture_source": None,
}


#: The two end vertices of each edge of a triangle and of a tetrahedron (local numbering).
_EDGES = {2: ([1, 2, 0], [2, 0, 1]), 3: ([0, 0, 0, 1, 1, 2], [1, 2, 3, 2, 3, 3])}


@dataclass(frozen=True)
class _Points:
    """Evaluation points of this rank's owned entities (m)."""

    centroids: Array
    cell_nodes: Array
    cell_edge_midpoints: Array
    facet_midpoints: Array
    boundary_vertices: tuple[Array, Array]
    boundary_midpoints: tuple[Array, Array]
    face_midpoints: Array
    face_fracture: npt.NDArray[np.int32]
    face_ends: Array

    def boundary(self, edges: list[int], degree: int) -> Array:
        """Lagrange nodes of the boundary facets on ``edges`` (vertices; P2: midpoints too)."""
        (v, ve), (m, me) = self.boundary_vertices, self.boundary_midpoints
        pts = [v[np.isin(ve, edges)]]
        if degree == 2:
            pts.append(m[np.isin(me, edges)])
        return np.concatenate(pts)


def _mesh_points(fm: FracturedMesh) -> _Points:
    """The points of every check on this rank (local)."""
    msh = fm.msh
    tdim, d = msh.topology.dim, msh.geometry.dim
    x = msh.geometry.x[:, :d]
    nc = msh.topology.index_map(tdim).size_local
    cells = x[msh.geometry.dofmaps[0][:nc]]  # (nc, d + 1, d)
    a, b = _EDGES[tdim]
    edges = 0.5 * (cells[:, a] + cells[:, b])
    nf = msh.topology.index_map(tdim - 1).size_local

    def facet_points(facets):
        return x[dolfinx.mesh.entities_to_geometry(msh, tdim - 1, facets)]

    facets = facet_points(np.arange(nf, dtype=np.int32))
    bnd = facet_points(fm.boundary_facets)
    frac = facet_points(fm.fractures.facets)
    if tdim == 3:  # the flow's fracture nodes are the edges: their midpoints
        frac = 0.5 * (frac + frac[:, [1, 2, 0]])
    return _Points(
        centroids=cells.mean(axis=1),
        cell_nodes=cells.reshape(-1, d),
        cell_edge_midpoints=edges.reshape(-1, d),
        facet_midpoints=facets.mean(axis=1),
        boundary_vertices=(bnd.reshape(-1, d), np.repeat(fm.boundary_edge, tdim)),
        boundary_midpoints=(bnd.mean(axis=1), fm.boundary_edge),
        face_midpoints=fm.fractures.midpoint,
        face_fracture=fm.fractures.fracture,
        face_ends=frac.reshape(-1, d),
    )


def _edges(fm: FracturedMesh, name: str) -> list[int]:
    return [i for i, n in enumerate(fm.geometry.boundary_names) if n == name]


def _on_edges(points: Array, geometry, edges: list[int]) -> Array:
    """The points lying on the given boundary parts (polygon edges, box faces)."""
    on = geometry.on_boundary(points, 1e-8 * geometry.diameter)
    return points[on[:, edges].any(axis=1)]


def _meta(cls, name: str) -> dict:
    return dict(cls.__dataclass_fields__[name].metadata)


Check = Callable[[], None]


def _mechanics_checks(scene: Scene, fm: FracturedMesh, p: _Points, times) -> Iterator[Check]:
    """Checks of the mechanics inputs, in a fixed order."""
    mat = scene.material
    for name in ("young", "poisson"):
        yield lambda name=name: check_expression(
            getattr(mat, name), p.centroids, f"material.{name}", _meta(Material, name), times,
            "a cell centre")
    nodes = p.cell_nodes if scene.degree == 1 else np.concatenate([p.cell_nodes,
                                                                   p.cell_edge_midpoints])
    for k, e in enumerate(mat.body_force or ()):
        yield lambda k=k, e=e: check_expression(e, nodes, f"material.body_force.{k}", None,
                                                times, "a mesh node")
    # interpolated at the nodes of DG of the displacement degree (σ⁰ at least DG1)
    yield lambda: check_expression(mat.density, nodes, "material.density",
                                   _meta(Material, "density"), times, "a mesh node")
    for k, e in enumerate(mat.initial_stress or ()):
        yield lambda k=k, e=e: check_expression(e, nodes, f"material.initial_stress.{k}", None,
                                                [0.0], "a mesh node")
    for i, bc in enumerate(scene.boundary_conditions):
        pts = p.boundary(_edges(fm, bc.boundary), scene.degree)
        for kind in ("displacement", "traction"):
            for k, e in enumerate(getattr(bc, kind) or ()):
                yield lambda kind=kind, k=k, e=e, pts=pts, i=i: check_expression(
                    e, pts, f"boundary_conditions.{i}.{kind}.{k}", None, times,
                    f"a node of boundary '{scene.boundary_conditions[i].boundary}'")
    yield lambda: check_expression(scene.fracture_pressure, p.face_midpoints,
                                   "fracture_pressure", None, times, "a fracture face")
    yield lambda: check_expression(scene.contact.slip_bound, p.face_midpoints,
                                   "contact.slip_bound", _meta(Contact, "slip_bound"), times,
                                   "a fracture face")


def _flow_checks(scene: Scene, fm: FracturedMesh, p: _Points, times) -> Iterator[Check]:
    """Checks of the flow inputs, in a fixed order."""
    flow = scene.flow
    yield lambda: check_permeability(flow.permeability, p.centroids, times, "a cell centre")
    yield lambda: check_expression(flow.source, p.centroids, "flow.source", None, times,
                                   "a cell centre")
    names = fm.geometry.fracture_names
    for name, override in _FRACTURE_FIELDS.items():
        taken = {ff.fracture for ff in flow.fractures
                 if override and getattr(ff, override) is not None}
        sel = ~np.isin(p.face_fracture, [names.index(n) for n in taken])
        yield lambda name=name, sel=sel: check_expression(
            getattr(flow, name), p.face_midpoints[sel], f"flow.{name}", _meta(Flow, name),
            times, "a fracture face")
    for i, ff in enumerate(flow.fractures):
        sel = p.face_fracture == names.index(ff.fracture)
        for name in ("aperture", "permeability", "normal_permeability", "conductivity"):
            yield lambda i=i, ff=ff, name=name, sel=sel: check_expression(
                getattr(ff, name), p.face_midpoints[sel], f"flow.fractures.{i}.{name}",
                _meta(FractureFlow, name), times, f"a face of fracture '{ff.fracture}'")
    if scene.time is not None:
        unknowns = np.concatenate([p.centroids, p.facet_midpoints, p.face_ends])
        yield lambda: check_expression(flow.initial_pressure, unknowns, "flow.initial_pressure",
                                       None, [0.0], "a flow unknown")
    for i, bc in enumerate(flow.boundary_conditions):
        edges = _edges(fm, bc.boundary)
        pts = [p.boundary_midpoints[0][np.isin(p.boundary_midpoints[1], edges)]]
        if bc.fracture_ends == "inherit":
            pts.append(_on_edges(p.face_ends, fm.geometry, edges))
        pts = np.concatenate(pts)
        if bc.where is not None:
            yield lambda i=i, pts=pts, bc=bc: check_expression(
                bc.where, pts, f"flow.boundary_conditions.{i}.where", None, [0.0],
                f"a point of boundary '{bc.boundary}'")  # before a nan selects its face
            pts = pts[np.asarray(bc.where(pts, 0.0)) != 0]
        for kind in ("pressure", "flux"):
            yield lambda i=i, kind=kind, pts=pts, bc=bc: check_expression(
                getattr(bc, kind), pts, f"flow.boundary_conditions.{i}.{kind}", None, times,
                f"a point of boundary '{bc.boundary}'")


def validate_fields(scene: Scene, fm: FracturedMesh) -> None:
    """Check every expression of a scene at the points where it is evaluated (collective).

    Call it after meshing and before the first solve. Finiteness and the range of each field are
    checked at every step time (:func:`~poromech.scene.schema.step_times`; the initial
    pressure at t = 0).

    Raises:
        ConfigError: On every rank, one line naming the key, the expression, the value and the
            point (the first failure in a partition-independent order).
    """
    times = step_times(scene)
    if scene.time is not None and (scene.physics == "poromechanics"
                                   or scene.material is not None
                                   and scene.material.initial_stress is not None):
        times = [0.0, *times]  # the initial equilibrium (and the σ⁰ check) use the loads at 0
    p = _mesh_points(fm)
    checks: list[Check] = []
    if scene.physics in ("mechanics", "poromechanics"):
        checks += _mechanics_checks(scene, fm, p, times)
    if scene.physics in ("flow", "poromechanics") and scene.flow is not None:
        checks += _flow_checks(scene, fm, p, times)
    error, failed = None, len(checks)
    for index, check in enumerate(checks):
        try:
            check()
        except ConfigError as err:
            error, failed = err, index
            break
    agree(fm.comm, error, failed)
