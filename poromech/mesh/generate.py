"""Conforming triangle meshes of fractured polygons with gmsh (serial, on one rank).

The fractures are embedded in the domain with the OpenCASCADE ``fragment`` operation, which
splits curves at their crossings (T and X junctions) and where they touch the boundary, so the
mesh is conforming to the whole network. Sizes are controlled near the fractures, near their
end points and in zones (balls, :class:`SizeZone`); a refinement level ``m`` then splits every
triangle into four, ``m`` times, so that a family ``m = 0, 1, 2, ...`` has ``4^m`` times the
cells and ``2^m`` times the fracture faces.
"""

from __future__ import annotations

import contextlib
import signal
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from poromech.errors import ConfigError
from poromech.geometry.plane import PlaneGeometry, arc_length_positions

__all__ = ["CELLS_PER_AREA", "SAMPLING_EXCESS", "SAMPLING_EXCESS_3D", "MeshArrays", "MeshSizes",
           "SizeZone", "generate_mesh", "gmsh_session",
           "threshold_field", "zone_fields"]


#: Largest excess of the size asked on a fracture, relative to its ``fracture_size`` (or zone
#: size), that the sampling of gmsh's Distance field may leave between its samples
#: (:func:`threshold_field`). With a ``transition`` short against the samples' spacing the
#: fractures were meshed up to 10 times coarser than asked, without a word (a 2 m crack at
#: ``fracture_size`` 1e-2 and ``transition`` 1e-3: 30 faces instead of 200). The shipped
#: scenes stay below 3 % and are meshed as before.
SAMPLING_EXCESS = 0.05
#: The same bound for the fracture surfaces and tip curves of 3D meshes, looser: the shipped
#: 3D scenes and every 3D study in docs/ were meshed with excesses of up to 66 % (penny.yaml's
#: tips 52 %, injection3d.yaml's 66 %), and the 5 % bound would mesh them anew (penny.yaml 594
#: fracture faces instead of 557). A disc of radius 1 m at ``fracture_size`` 0.1 and
#: ``transition`` 0.005 got 23 faces instead of about 725 (516 with a transition of 1 m).
SAMPLING_EXCESS_3D = 1.0

#: Triangles per unit of ``∫ h⁻²`` (``1/(√3/4) ≈ 2.31`` for equilateral triangles; gmsh's
#: frontal-Delaunay meshes of the shipped scenes give 2.4-2.5).
CELLS_PER_AREA = 2.45


@dataclass(frozen=True)
class SizeZone:
    """A ball of finer mesh.

    Attributes:
        center: Centre ``(x, y, z)`` (``z = 0`` in 2D).
        radius: Radius of the ball.
        size: Element size in it: on the fractures (``on_fractures``), or everywhere.
        transition: Distance over which the size grows from ``size`` (beyond the ball, and
            away from the fractures).
        on_fractures: Whether only the fractures (and the rock around them) are refined.
    """

    center: tuple[float, float, float]
    radius: float
    size: float
    transition: float
    on_fractures: bool = True


@dataclass(frozen=True)
class MeshSizes:
    """Target element sizes (m).

    Attributes:
        size: Size away from the fractures.
        fracture_size: Size along the fractures.
        tip_size: Size at fracture end points.
        transition: Distance over which the sizes blend into ``size``.
        refinement: Number of uniform refinements after generation.
        zones: Balls of finer mesh.
    """

    size: float
    fracture_size: float
    tip_size: float
    transition: float
    refinement: int = 0
    zones: tuple[SizeZone, ...] = ()


@dataclass(frozen=True)
class MeshArrays:
    """A mesh as plain arrays (input numbering).

    Attributes:
        x: Node coordinates, ``(num_nodes, 2)``.
        cells: Triangle nodes, ``(num_cells, 3)``.
        fracture_facets: Nodes of fracture faces, ``(num_faces, 2)``.
        fracture_id: Fracture index of each fracture face.
        fracture_segment: Polyline segment of each fracture face.
        fracture_s: Arc length of each fracture face midpoint from the polyline start (m).
        boundary_facets: Nodes of boundary faces, ``(num_bfaces, 2)``.
        boundary_edge: Domain polygon edge index of each boundary face.
    """

    x: npt.NDArray[np.float64]
    cells: npt.NDArray[np.int64]
    fracture_facets: npt.NDArray[np.int64]
    fracture_id: npt.NDArray[np.int32]
    fracture_segment: npt.NDArray[np.int32]
    fracture_s: npt.NDArray[np.float64]
    boundary_facets: npt.NDArray[np.int64]
    boundary_edge: npt.NDArray[np.int32]


@contextlib.contextmanager
def gmsh_session():
    """Initialize gmsh quietly and finalize it whatever happens.

    ``gmsh.initialize`` resets the SIGINT and SIGTERM handlers to the system's: those of the
    run (a stop at once while setting up) are put back.
    """
    import gmsh

    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    gmsh.initialize(interruptible=False)
    with contextlib.suppress(ValueError, TypeError):  # not the main thread; a C handler
        for s, h in handlers.items():
            signal.signal(s, h)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.Verbosity", 1)
    try:
        yield gmsh
    finally:
        gmsh.finalize()


def _classify_boundary(gmsh, geo: PlaneGeometry) -> dict[int, list[int]]:
    """Map each domain polygon edge to the model curves lying on it."""
    surfaces = gmsh.model.getEntities(2)
    curves = {abs(t) for _, t in gmsh.model.getBoundary(surfaces, combined=True, oriented=False)}
    n = len(geo.boundary)
    a, b = geo.boundary, np.roll(geo.boundary, -1, axis=0)
    out: dict[int, list[int]] = {i: [] for i in range(n)}
    tol = 1e-7 * geo.diameter
    for c in sorted(curves):
        lo, hi = gmsh.model.getParametrizationBounds(1, c)
        mid = np.asarray(gmsh.model.getValue(1, c, [0.5 * (lo[0] + hi[0])]))[:2]
        ab = b - a
        s = np.clip(np.einsum("ij,ij->i", mid - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
        dist = np.linalg.norm(a + s[:, None] * ab - mid, axis=1)
        i = int(np.argmin(dist))
        if dist[i] > tol:
            raise RuntimeError(f"boundary curve {c} is not on the domain polygon")
        out[i].append(c)
    return out


def _build_model(gmsh, geo: PlaneGeometry):
    """Create the OCC model; return the boundary curves, fracture curves and their owners."""
    occ = gmsh.model.occ
    n = len(geo.boundary)
    bpts = [occ.addPoint(*p, 0.0) for p in geo.boundary]
    blines = [occ.addLine(bpts[i], bpts[(i + 1) % n]) for i in range(n)]
    surf = occ.addPlaneSurface([occ.addCurveLoop(blines)])
    flines, owners = [], []
    for k, pts in enumerate(geo.fractures):
        fpts = [occ.addPoint(*p, 0.0) for p in pts]
        for i in range(len(pts) - 1):
            flines.append(occ.addLine(fpts[i], fpts[i + 1]))
            owners.append((k, i))
    _, out_map = occ.fragment([(2, surf)], [(1, f) for f in flines])
    occ.synchronize()
    fracture_curves = {j: [t for d, t in out_map[1 + j] if d == 1] for j in range(len(flines))}
    return _classify_boundary(gmsh, geo), fracture_curves, owners


def threshold_field(field, kind: str, entities: list[int], size_min: float, sizes: MeshSizes,
                    sampling: int | None = None, gap: float = 0.0,
                    excess: float = SAMPLING_EXCESS) -> int:
    """A gmsh size field: ``size_min`` at the entities, ``sizes.size`` beyond ``transition``.

    ``field`` is ``gmsh.model.mesh.field``; ``sampling``: points per curve or surface of the
    distance (gmsh's default when None); ``gap``: the largest distance of a point of the
    entities from the nearest of those samples. gmsh measures the distance to the samples, so
    that between them the threshold asks for more than ``size_min`` on the entities
    themselves; where that excess reaches ``excess`` of ``size_min``
    (:data:`SAMPLING_EXCESS`), a ``Constant`` field holds ``size_min`` on the entities (the
    ``Min`` of both is returned).
    """
    d = field.add("Distance")
    field.setNumbers(d, kind, entities)
    if sampling is not None:
        field.setNumber(d, "Sampling", sampling)
    th = field.add("Threshold")
    field.setNumber(th, "InField", d)
    field.setNumber(th, "SizeMin", size_min)
    field.setNumber(th, "SizeMax", sizes.size)
    field.setNumber(th, "DistMin", 0.0)
    field.setNumber(th, "DistMax", sizes.transition)
    if (sizes.size - size_min) * gap / sizes.transition < excess * size_min:
        return th
    on = field.add("Constant")
    field.setNumbers(on, kind, entities)
    field.setNumber(on, "VIn", size_min)
    field.setNumber(on, "VOut", sizes.size)
    field.setNumber(on, "IncludeBoundary", 1)
    both = field.add("Min")
    field.setNumbers(both, "FieldsList", [th, on])
    return both


def zone_fields(field, sizes: MeshSizes, kind: str, fractures: list[int],
                sampling: int | None = None, gap: float = 0.0,
                excess: float = SAMPLING_EXCESS) -> list[int]:
    """The gmsh size fields of ``sizes.zones`` (the Min of the background takes them).

    A zone is a ``Ball`` field (``size`` inside, growing to ``sizes.size`` over ``transition``
    outside); on the fractures only, it is the ``Max`` of the ball and of a ``Threshold`` of the
    distance to the fracture entities ``fractures`` (of gmsh type ``kind``), so that the size is
    small only where both are: near a fracture and in the ball.
    """
    out = []
    for z in sizes.zones:
        if z.on_fractures and not fractures:
            continue
        ball = field.add("Ball")
        for name, value in zip(("XCenter", "YCenter", "ZCenter"), z.center, strict=True):
            field.setNumber(ball, name, float(value))
        field.setNumber(ball, "Radius", z.radius)
        field.setNumber(ball, "Thickness", z.transition)
        field.setNumber(ball, "VIn", z.size)
        field.setNumber(ball, "VOut", sizes.size)
        if not z.on_fractures:
            out.append(ball)
            continue
        zone = MeshSizes(sizes.size, z.size, z.size, z.transition)
        near = threshold_field(field, kind, fractures, z.size, zone, sampling, gap, excess)
        both = field.add("Max")
        field.setNumbers(both, "FieldsList", [ball, near])
        out.append(both)
    return out


def _size_fields(gmsh, fracture_curves, sizes: MeshSizes) -> None:
    """Background size field: min of thresholds on fracture and fracture-end distances."""
    field = gmsh.model.mesh.field
    curves = sorted({c for cs in fracture_curves.values() for c in cs})
    fields = []
    longest = max((gmsh.model.occ.getMass(1, c) for c in curves), default=0.0)
    if curves:
        ends = gmsh.model.getBoundary([(1, c) for c in curves], combined=False, oriented=False)
        fields.append(threshold_field(field, "CurvesList", curves, sizes.fracture_size, sizes,
                                      sampling=200, gap=longest / (2 * 199)))
        fields.append(threshold_field(field, "PointsList", sorted({abs(t) for _, t in ends}),
                                      sizes.tip_size, sizes))
    if sizes.zones:  # about 2 distance samples per zone size along the longest curve
        finest = min(z.size for z in sizes.zones)
        n = int(np.clip(np.ceil(2 * longest / finest), 200, 20000))
        fields += zone_fields(field, sizes, "CurvesList", curves, n, longest / (2 * (n - 1)))
    const = field.add("MathEval")
    field.setString(const, "F", repr(float(sizes.size)))
    fields.append(const)
    fmin = field.add("Min")
    field.setNumbers(fmin, "FieldsList", fields)
    field.setAsBackgroundMesh(fmin)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)


def _line_elements(gmsh, curve: int) -> npt.NDArray[np.int64]:
    """Node tags of the 2-node line elements on a curve, shape ``(k, 2)``."""
    types, _, nodes = gmsh.model.mesh.getElements(1, curve)
    out = [np.asarray(nd, dtype=np.int64).reshape(-1, 2)
           for ty, nd in zip(types, nodes, strict=True) if ty == 1]
    return np.concatenate(out) if out else np.empty((0, 2), dtype=np.int64)


def generate_mesh(geo: PlaneGeometry, sizes: MeshSizes) -> MeshArrays:
    """Mesh a fractured polygon with gmsh (call on one rank only).

    Args:
        geo: The checked geometry.
        sizes: Size control and refinement level.

    Returns:
        The mesh as arrays with fracture faces classified by fracture, segment and arc length.
    """
    with gmsh_session() as gmsh:
        gmsh.model.add("poromech")
        bcurves, fcurves, owners = _build_model(gmsh, geo)
        _size_fields(gmsh, fcurves, sizes)
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        gmsh.model.mesh.generate(2)
        for _ in range(sizes.refinement):
            gmsh.model.mesh.refine()
        tags, coords, _ = gmsh.model.mesh.getNodes()
        x = np.asarray(coords).reshape(-1, 3)[:, :2]
        index = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
        index[tags] = np.arange(len(tags))
        types, _, nodes = gmsh.model.mesh.getElements(2)
        tri = [np.asarray(nd, dtype=np.int64).reshape(-1, 3)
               for ty, nd in zip(types, nodes, strict=True) if ty == 2]
        cells = index[np.concatenate(tri)]
        ffacets, fid, fseg = [], [], []
        for j, curves in fcurves.items():
            for c in curves:
                e = index[_line_elements(gmsh, c)]
                ffacets.append(e)
                fid.append(np.full(len(e), owners[j][0], dtype=np.int32))
                fseg.append(np.full(len(e), owners[j][1], dtype=np.int32))
        bfacets, bedge = [], []
        for i, curves in bcurves.items():
            for c in curves:
                e = index[_line_elements(gmsh, c)]
                bfacets.append(e)
                bedge.append(np.full(len(e), i, dtype=np.int32))
    empty2 = np.empty((0, 2), dtype=np.int64)
    ff = np.concatenate(ffacets) if ffacets else empty2
    fid = np.concatenate(fid) if fid else np.empty(0, dtype=np.int32)
    fseg = np.concatenate(fseg) if fseg else np.empty(0, dtype=np.int32)
    bf = np.concatenate(bfacets) if bfacets else empty2
    be = np.concatenate(bedge) if bedge else np.empty(0, dtype=np.int32)
    _check_fracture_faces(geo, ff, fid, bf, be)
    return mesh_arrays(geo, x, cells, (ff, fid, fseg), (bf, be))


def _check_fracture_faces(geo: PlaneGeometry, facets: npt.NDArray[np.int64],
                          fracture: npt.NDArray[np.int32],
                          boundary: npt.NDArray[np.int64] | None = None,
                          edge: npt.NDArray[np.int32] | None = None) -> None:
    """Every fracture has mesh faces, and no face belongs to two fractures or to the boundary.

    gmsh merges curves closer than its tolerance: two fractures crossing at a tiny angle
    (1e-7 rad) shared their faces, and one of them vanished from the results without a word;
    a fracture parallel to a domain edge 1e-8 of the domain's size inside it shared that
    edge's faces, and the run stopped after meshing with an internal error.

    Raises:
        ConfigError: Naming the fractures (and the domain edge).
    """
    names = geo.fracture_names
    key = np.sort(facets, axis=1)
    if boundary is not None and len(boundary) and len(key):
        bkey = np.sort(boundary, axis=1)
        both, in_f, in_b = np.intersect1d(
            key.view([("a", key.dtype), ("b", key.dtype)]).ravel(),
            bkey.view([("a", bkey.dtype), ("b", bkey.dtype)]).ravel(), return_indices=True)
        if len(both):
            name, e = names[int(fracture[in_f[0]])], int(edge[in_b[0]])
            raise ConfigError(
                f"fracture '{name}' and domain edge {e} share mesh faces: it runs along the "
                "edge at a distance the mesh cannot resolve (allowed: move it away from the "
                "edge, by more than about 1e-6 of the domain's size)")
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    for f in first[counts > 1]:
        same = np.flatnonzero(np.all(key == key[f], axis=1))
        owners = sorted({names[int(k)] for k in fracture[same]})
        if len(owners) > 1:
            raise ConfigError(
                f"fractures {' and '.join(repr(n) for n in owners)} share mesh faces: they "
                "meet at an angle or a distance the mesh cannot resolve (merge them, or move "
                "them apart)")
    for k, name in enumerate(names):
        if not np.any(fracture == k):
            raise ConfigError(f"fracture '{name}' has no faces in the mesh")


def mesh_arrays(geo: PlaneGeometry, x: npt.NDArray[np.float64], cells: npt.NDArray[np.int64],
                fracture: tuple, boundary: tuple) -> MeshArrays:
    """Assemble :class:`MeshArrays` from a triangle mesh and its classified facets.

    Drops the nodes no triangle uses, orients the triangles counter-clockwise, computes the arc
    length of every fracture face and numbers the fracture faces by (fracture, arc length).

    Args:
        geo: The plane geometry the facets refer to.
        x: Node coordinates, ``(n, 2)``.
        cells: Triangle nodes, ``(m, 3)``.
        fracture: Fracture facets ``(k, 2)``, their fracture index and polyline segment.
        boundary: Boundary facets ``(l, 2)`` and their domain polygon edge.
    """
    ff, fid, fseg = fracture
    bf, be = boundary
    # Keep only the nodes used by triangles (gmsh may keep geometry points)
    used = np.unique(cells)
    renum = np.full(len(x), -1, dtype=np.int64)
    renum[used] = np.arange(len(used))
    x, cells, ff, bf = x[used], renum[cells], renum[ff], renum[bf]
    # Counter-clockwise triangles
    d1, d2 = x[cells[:, 1]] - x[cells[:, 0]], x[cells[:, 2]] - x[cells[:, 0]]
    cw = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0] < 0
    cells[cw] = cells[cw][:, [0, 2, 1]]
    s = np.empty(len(ff))
    mid = 0.5 * (x[ff[:, 0]] + x[ff[:, 1]])
    for k, pts in enumerate(geo.fractures):
        sel = fid == k
        s[sel] = arc_length_positions(pts, fseg[sel], mid[sel])
    # Sort fracture faces by (fracture, arc length): the global fracture face numbering
    order = np.lexsort((s, fid))
    return MeshArrays(x, cells, ff[order], fid[order], fseg[order], s[order], bf, be)
