"""Conforming tetrahedral meshes of fractured boxes with gmsh (serial, on one rank).

The fractures (plane polygons and discs) are embedded in the box with the OpenCASCADE
``fragment`` operation, which splits them along their intersection lines (X and T junctions)
and where they reach the box, so the tetrahedra conform to the whole network; the conforming
surfaces of the geometry (polygons that are not fractures) are fragmented in the same way, so
that no tetrahedron and no boundary triangle straddles them. Sizes: the
``fracture_size`` on the fractures grows linearly to ``size`` over ``transition`` (gmsh
``Threshold`` of the ``Distance`` to the fracture surfaces), and ``tip_size`` on the tip curves
(fracture edges that are neither on the box nor on another fracture) grows the same way, and so
does the size of each zone (a ball, :class:`~poromech.mesh.generate.SizeZone`); the minimum
applies. Each ``refinement`` level then splits every tetrahedron into 8.

Finally the mesh is repaired for the cracked topology: edges that vertex cracking cannot
duplicate (see :mod:`poromech.cracking`) are bisected.

The result is a :class:`~poromech.meshing.MeshArrays` with 3D shapes: ``x (n, 3)``,
``cells (m, 4)`` (positively oriented), ``fracture_facets (k, 3)`` and ``boundary_facets (l, 3)``.
``fracture_segment`` is 0 (every fracture is one planar piece) and ``fracture_s`` is NaN (there
is no arc length in 3D). ``boundary_edge`` indexes ``BoxGeometry.boundary_names``. Fracture faces
are numbered by fracture, then lexicographically by the in-plane coordinates ``(t1·c, t2·c)``
of their centroid ``c`` (``Fracture3D.tangents``); boundary faces by face, then by the two
in-face coordinates of their centroid in axis order.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from poromech.geometry.box import BoxGeometry, Fracture3D
from poromech.mesh.cracking import (
    bisect_edges,
    crack_vertices,
    deficient_edges,
    facet_table,
    unique_rows,
)
from poromech.mesh.generate import (
    SAMPLING_EXCESS_3D,
    MeshArrays,
    MeshSizes,
    gmsh_session,
    threshold_field,
    zone_fields,
)

__all__ = [
    "ALGORITHM_2D",
    "ALGORITHM_3D",
    "MeshReport3D",
    "build_mesh_3d",
    "generate_mesh_3d",
]

log = logging.getLogger("poromech")

#: gmsh surface algorithm (Frontal-Delaunay: no deficient edges in the prototype's cases).
ALGORITHM_2D = 6

#: Default gmsh volume algorithm: 1 (Delaunay). 10 (HXT) also conforms to the fractures and is
#: 2-6 times faster, but follows steep size gradings less closely (fewer, flatter tets); 4
#: (Frontal) and 7 (MMG3D) ignore embedded surfaces and are refused.
ALGORITHM_3D = 1

#: Steepest size grading ``(size - fracture_size) / transition`` that gives good tets; steeper
#: is logged as a warning (penny, slope 2.4: 56 % of the tets had quality < 0.2; 0.6: none).
MAX_GRADING = 1.0

#: Rounds of deficient-edge bisection before giving up (one always sufficed in tests).
_MAX_BISECTION_ROUNDS = 5

#: Geometric tolerance for classifying gmsh entities, as a fraction of the box diameter.
_CLASSIFY_TOL = 1e-7
#: The least of that tolerance, in the model's units. OpenCASCADE enlarges every bounding box by
#: its absolute precision, 1e-7, whatever the model's size: modelled in metres, a 2 mm box's
#: faces reached 1e-7 m beyond them, about 300 times its tolerance, and were not found.
_OCC_MARGIN = 1e-6

_TETRA, _TRIANGLE = 4, 2  # gmsh element types


@dataclass(frozen=True)
class MeshReport3D:
    """What :func:`build_mesh_3d` did.

    Attributes:
        num_nodes: Nodes of the returned mesh.
        num_cells: Tetrahedra of the returned mesh.
        num_fracture_faces: Fracture triangles.
        num_boundary_faces: Box boundary triangles.
        gmsh_cells: Tetrahedra produced by gmsh (after refinement, before bisection).
        bisected_edges: Deficient edges bisected.
        tip_curves: Number of gmsh curves classified as fracture tips.
        seconds: Wall time per phase (s): ``model``, ``generate``, ``refine``, ``extract``,
            ``repair``.
    """

    num_nodes: int
    num_cells: int
    num_fracture_faces: int
    num_boundary_faces: int
    gmsh_cells: int
    bisected_edges: int
    tip_curves: int
    seconds: dict[str, float] = field(default_factory=dict)


def model_scale(geo: BoxGeometry) -> float:
    """The length (m) that is gmsh's unit of length for ``geo``.

    1, or for a box of diameter below 1 m the power of ten that brings it between 1 and 10.
    OpenCASCADE's absolute precision, 1e-7 in the model's units (see :data:`_OCC_MARGIN`), is
    then at most 1e-7 of the box's diameter; boxes of a metre and more are meshed in metres, as
    they were.
    """
    d = geo.diameter
    return 1.0 if d >= 1.0 else 10.0 ** np.floor(np.log10(d))


def _scaled(geo: BoxGeometry, sizes: MeshSizes, scale: float) -> tuple[BoxGeometry, MeshSizes]:
    """``geo`` and ``sizes`` in units of ``scale`` (m)."""
    if scale == 1.0:
        return geo, sizes

    def fracture(f: Fracture3D) -> Fracture3D:
        if f.is_disc:
            return Fracture3D.disc(f.name, f.center / scale, f.normal, f.radius / scale)
        return Fracture3D.polygon(f.name, f.points / scale)

    box = BoxGeometry(tuple(v / scale for v in geo.box), tuple(map(fracture, geo.fractures)),
                      tuple(map(fracture, geo.surfaces)))
    zones = tuple(replace(z, center=tuple(c / scale for c in z.center), radius=z.radius / scale,
                          size=z.size / scale, transition=z.transition / scale)
                  for z in sizes.zones)
    return box, replace(sizes, size=sizes.size / scale, fracture_size=sizes.fracture_size / scale,
                        tip_size=sizes.tip_size / scale, transition=sizes.transition / scale,
                        zones=zones)


def _add_fracture(occ, fr: Fracture3D) -> int:
    """Create the OCC surface of a fracture; return its tag."""
    if fr.is_disc:
        t1, _ = fr.tangents
        return occ.addDisk(*fr.center, fr.radius, fr.radius, zAxis=list(fr.normal),
                           xAxis=list(t1))
    pts = [occ.addPoint(*p) for p in fr.points]
    lines = [occ.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
    return occ.addPlaneSurface([occ.addCurveLoop(lines)])


def _build_model(gmsh, geo: BoxGeometry) -> list[list[int]]:
    """Box, fractures and conforming surfaces, fragmented; the surface tags of each fracture."""
    occ = gmsh.model.occ
    box = occ.addBox(*geo.lower, *(geo.upper - geo.lower))
    tools = [(2, _add_fracture(occ, fr)) for fr in (*geo.fractures, *geo.surfaces)]
    _, out_map = occ.fragment([(3, box)], tools)
    occ.synchronize()
    return [sorted(t for d, t in out_map[1 + j] if d == 2) for j in range(len(geo.fractures))]


def _face_of(geo: BoxGeometry, bbox, tol: float) -> int:
    """Box face on which an entity with bounding box ``bbox`` lies, or -1."""
    lo, hi = np.asarray(bbox[:3]), np.asarray(bbox[3:])
    for face in range(6):
        axis, value = geo.face_plane(face)
        if abs(lo[axis] - value) <= tol and abs(hi[axis] - value) <= tol:
            return face
    return -1


def _boundary_surfaces(gmsh, geo: BoxGeometry, tol: float) -> dict[int, list[int]]:
    """Box face index -> model surfaces on it."""
    volumes = gmsh.model.getEntities(3)
    surfaces = sorted({abs(t) for _, t in gmsh.model.getBoundary(volumes, combined=True,
                                                                  oriented=False)})
    out: dict[int, list[int]] = {k: [] for k in range(6)}
    for s in surfaces:
        face = _face_of(geo, gmsh.model.getBoundingBox(2, s), tol)
        if face < 0:
            raise RuntimeError(f"gmsh boundary surface {s} is not on a box face")
        out[face].append(s)
    return out


def _curve_samples(gmsh, curve: int) -> npt.NDArray[np.float64]:
    """Three points on a model curve (at 1/4, 1/2, 3/4 of its parameter range)."""
    lo, hi = gmsh.model.getParametrizationBounds(1, curve)
    t = [lo[0] + f * (hi[0] - lo[0]) for f in (0.25, 0.5, 0.75)]
    return np.asarray(gmsh.model.getValue(1, curve, t)).reshape(-1, 3)


def _tip_curves(gmsh, geo: BoxGeometry, surfaces: list[list[int]], tol: float) -> list[int]:
    """Boundary curves of fracture surfaces that are neither on the box nor on another fracture.

    Nor on a conforming surface: one that crosses a fracture cuts its mesh along a line inside it.
    """
    tips = set()
    for j, ss in enumerate(surfaces):
        bnd = gmsh.model.getBoundary([(2, s) for s in ss], combined=False, oriented=False)
        for c in sorted({abs(t) for _, t in bnd}):
            x = _curve_samples(gmsh, c)
            on_box = _face_of(geo, np.concatenate([x.min(axis=0), x.max(axis=0)]), tol) >= 0
            on_other = any(np.all(f.contains(x, tol))
                           for i, f in enumerate(geo.fractures) if i != j)
            on_surface = any(np.all(s.contains(x, tol)) for s in geo.surfaces)
            if not (on_box or on_other or on_surface):
                tips.add(c)
    return sorted(tips)


def _sampling(length: float, size: float, lo: int, hi: int) -> int:
    """Sampling of a gmsh Distance field: about 2 points per ``size`` along ``length``."""
    return int(np.clip(np.ceil(2 * length / size), lo, hi))


def _size_fields(gmsh, geo: BoxGeometry, surfaces: list[list[int]], tips: list[int],
                 sizes: MeshSizes) -> None:
    """Background size: Min of thresholds on the distances to fractures and to tip curves."""
    fld = gmsh.model.mesh.field
    extent = max((float(np.ptp(f.outline(), axis=0).max()) for f in geo.fractures), default=1.0)

    fields = []
    all_surfaces = sorted({s for ss in surfaces for s in ss})
    # the samples' largest gaps: a grid of n × n on a surface (its bounding box's largest side
    # in each direction), n along a curve
    side = max((float(np.ptp(np.reshape(gmsh.model.getBoundingBox(2, s), (2, 3)), axis=0).max())
                for s in all_surfaces), default=0.0)
    longest = max((gmsh.model.occ.getMass(1, c) for c in tips), default=0.0)
    if all_surfaces:
        n = _sampling(extent, sizes.fracture_size, 20, 400)
        fields.append(threshold_field(fld, "SurfacesList", all_surfaces, sizes.fracture_size,
                                      sizes, n, side / (np.sqrt(2.0) * (n - 1)),
                                      SAMPLING_EXCESS_3D))
    if tips:
        n = _sampling(extent, sizes.tip_size, 20, 2000)
        fields.append(threshold_field(fld, "CurvesList", tips, sizes.tip_size, sizes, n,
                                      longest / (2 * (n - 1)), SAMPLING_EXCESS_3D))
    finest = min((z.size for z in sizes.zones), default=sizes.fracture_size)
    n = _sampling(extent, finest, 20, 400)
    fields += zone_fields(fld, sizes, "SurfacesList", all_surfaces, n,
                          side / (np.sqrt(2.0) * (n - 1)), SAMPLING_EXCESS_3D)
    const = fld.add("MathEval")
    fld.setString(const, "F", repr(float(sizes.size)))
    fields.append(const)
    fmin = fld.add("Min")
    fld.setNumbers(fmin, "FieldsList", fields)
    fld.setAsBackgroundMesh(fmin)
    for opt in ("MeshSizeExtendFromBoundary", "MeshSizeFromPoints", "MeshSizeFromCurvature"):
        gmsh.option.setNumber(f"Mesh.{opt}", 0)


def _elements(gmsh, dim: int, tag: int, etype: int, nv: int) -> npt.NDArray[np.int64]:
    """Node tags of the elements of one type on an entity (all entities of ``dim`` if tag < 0)."""
    types, _, nodes = gmsh.model.mesh.getElements(dim, tag)
    out = [np.asarray(n, dtype=np.int64).reshape(-1, nv)
           for t, n in zip(types, nodes, strict=True) if t == etype]
    return np.concatenate(out) if out else np.empty((0, nv), dtype=np.int64)


def _extract(gmsh, surfaces: list[list[int]], faces: dict[int, list[int]]):
    """Nodes, tets and classified triangles from the gmsh model (gmsh node numbering mapped)."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    x = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    index = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
    index[tags] = np.arange(len(tags))
    cells = index[_elements(gmsh, 3, -1, _TETRA, 4)]

    def collect(groups) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int32]]:
        tri, ids = [np.empty((0, 3), dtype=np.int64)], [np.empty(0, dtype=np.int32)]
        for k, ss in groups:
            for s in ss:
                e = index[_elements(gmsh, 2, s, _TRIANGLE, 3)]
                tri.append(e)
                ids.append(np.full(len(e), k, dtype=np.int32))
        return np.concatenate(tri), np.concatenate(ids)

    ff, fid = collect(enumerate(surfaces))
    bf, bid = collect(sorted(faces.items()))
    return x, cells, (ff, fid), (bf, bid)


def _orient(x: npt.NDArray[np.float64], cells: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """Reorder tets to positive volume (swap the last two vertices of negative ones)."""
    d = x[cells[:, 1:]] - x[cells[:, :1]]
    neg = np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2])) < 0
    cells = cells.copy()
    cells[neg] = cells[neg][:, [0, 1, 3, 2]]
    return cells


def _drop_unused(x, cells, ff, bf):
    """Keep only the nodes used by tets (gmsh keeps geometry points) and renumber."""
    used = np.unique(cells)
    renum = np.full(len(x), -1, dtype=np.int64)
    renum[used] = np.arange(len(used))
    return x[used], renum[cells], renum[ff], renum[bf]


def _check_conforming(cells, ff, bf, algorithm: int) -> None:
    """Every fracture and boundary triangle must be a face of the tets."""
    faces = np.sort(cells[:, facet_table(4)], axis=2).reshape(-1, 3)
    ids, _ = unique_rows(np.concatenate([faces, np.sort(ff, axis=1), np.sort(bf, axis=1)]))
    if not np.all(np.isin(ids[len(faces):], ids[: len(faces)])):
        raise RuntimeError(f"gmsh's 3D algorithm {algorithm} did not conform to the fracture or "
                           f"box surfaces (use {ALGORITHM_3D} or 10)")


def _repair(x, cells, fracture, boundary):
    """Bisect deficient edges until vertex cracking realizes the rule for every edge."""
    (ff, fid), (bf, bid) = fracture, boundary
    total = 0
    for _ in range(_MAX_BISECTION_ROUNDS):
        cracked, _ = crack_vertices(cells, ff, len(x))
        bad = deficient_edges(cells, ff, len(x), cracked)
        if len(bad) == 0:
            return x, cells, (ff, fid), (bf, bid), total
        x, cells, ff, fpar, bf, bpar = bisect_edges(x, cells, ff, bf, bad)
        fid, bid = fid[fpar], bid[bpar]
        total += len(bad)
    raise RuntimeError(f"deficient edges remain after {_MAX_BISECTION_ROUNDS} bisection rounds")


def _ordered(geo: BoxGeometry, x, ff, fid, bf, bid):
    """Fracture faces by (fracture, t1·c, t2·c); boundary faces by (face, in-face coordinates)."""
    c = x[ff].mean(axis=1)
    u = np.zeros((len(ff), 2))
    for j, fr in enumerate(geo.fractures):
        sel = fid == j
        t1, t2 = fr.tangents
        u[sel] = np.column_stack([c[sel] @ t1, c[sel] @ t2])
    fo = np.lexsort((u[:, 1], u[:, 0], fid))
    cb = x[bf].mean(axis=1)
    axes = np.array([[1, 2], [0, 2], [0, 1]])[bid // 2]
    ub = np.take_along_axis(cb, axes, axis=1)
    bo = np.lexsort((ub[:, 1], ub[:, 0], bid))
    return ff[fo], fid[fo], bf[bo], bid[bo]


def build_mesh_3d(geo: BoxGeometry, sizes: MeshSizes, repair: bool = True,
                  algorithm_3d: int = ALGORITHM_3D) -> tuple[MeshArrays, MeshReport3D]:
    """Mesh a fractured box with gmsh and repair it for cracking (call on one rank only).

    Args:
        geo: A geometry that passed :func:`~poromech.box_geometry.check_box_geometry`.
        sizes: Size control (m) and number of uniform refinements (each: 8 times the cells).
        repair: Bisect deficient edges (False only to inspect the raw gmsh mesh).
        algorithm_3d: gmsh ``Mesh.Algorithm3D`` (see :data:`ALGORITHM_3D`).

    Raises:
        RuntimeError: The tetrahedra do not conform to the fractures or the box faces.

    Returns:
        The mesh arrays (see the module docstring for the 3D conventions) and a report.
    """
    grading = max([(sizes.size - min(sizes.fracture_size, sizes.tip_size)) / sizes.transition]
                  + [(sizes.size - z.size) / z.transition for z in sizes.zones])
    if grading > MAX_GRADING:
        log.warning("3D mesh size grading %.3g > %g: expect flat tetrahedra (raise transition)",
                    grading, MAX_GRADING)
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    scale = model_scale(geo)  # gmsh works in units of scale (m)
    model, model_sizes = _scaled(geo, sizes, scale)
    tol = max(_CLASSIFY_TOL * model.diameter, _OCC_MARGIN)
    with gmsh_session() as gmsh:
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add("poromech3d")
        surfaces = _build_model(gmsh, model)
        faces = _boundary_surfaces(gmsh, model, tol)
        tips = _tip_curves(gmsh, model, surfaces, tol)
        _size_fields(gmsh, model, surfaces, tips, model_sizes)
        gmsh.option.setNumber("Mesh.Algorithm", ALGORITHM_2D)
        gmsh.option.setNumber("Mesh.Algorithm3D", algorithm_3d)
        seconds["model"] = time.perf_counter() - t0
        t = time.perf_counter()
        gmsh.model.mesh.generate(3)
        seconds["generate"] = time.perf_counter() - t
        t = time.perf_counter()
        for _ in range(sizes.refinement):
            gmsh.model.mesh.refine()
        seconds["refine"] = time.perf_counter() - t
        t = time.perf_counter()
        x, cells, fracture, boundary = _extract(gmsh, surfaces, faces)
        if scale != 1.0:
            x = x * scale
    gmsh_cells = len(cells)
    _check_conforming(cells, fracture[0], boundary[0], algorithm_3d)
    x, cells, ff, bf = _drop_unused(x, _orient(x, cells), fracture[0], boundary[0])
    seconds["extract"] = time.perf_counter() - t
    t = time.perf_counter()
    fracture, boundary = (ff, fracture[1]), (bf, boundary[1])
    if repair:
        x, cells, fracture, boundary, nbis = _repair(x, cells, fracture, boundary)
    else:
        nbis = 0
    (ff, fid), (bf, bid) = fracture, boundary
    ff, fid, bf, bid = _ordered(geo, x, ff, fid, bf, bid)
    seconds["repair"] = time.perf_counter() - t
    arrays = MeshArrays(x, cells, ff, fid, np.zeros(len(ff), dtype=np.int32),
                        np.full(len(ff), np.nan), bf, bid)
    report = MeshReport3D(len(x), len(cells), len(ff), len(bf), gmsh_cells, nbis, len(tips),
                          {k: round(v, 4) for k, v in seconds.items()})
    return arrays, report


def generate_mesh_3d(geo: BoxGeometry, sizes: MeshSizes) -> MeshArrays:
    """Mesh a fractured box (rank 0 only); logs the cell count and bisected edges.

    Args:
        geo: A geometry that passed :func:`~poromech.box_geometry.check_box_geometry`.
        sizes: Size control (m) and number of uniform refinements.

    Returns:
        The mesh arrays (3D shapes; see the module docstring).
    """
    arrays, report = build_mesh_3d(geo, sizes)
    log.info("3D mesh: %d tets, %d nodes, %d fracture faces, %d deficient edges bisected",
             report.num_cells, report.num_nodes, report.num_fracture_faces,
             report.bisected_edges)
    return arrays
