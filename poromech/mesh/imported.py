"""Meshes from files: a gmsh ``.geo`` or ``.msh`` file, or any mesh meshio reads, with named groups.

A mesh file gives the triangles of the domain and named groups of line elements (in gmsh, 1D
physical groups). The scene says which groups are fractures and which groups make up each named
boundary; this module turns them into what a generated mesh gives
(:func:`poromech.mesh.generate.generate_mesh`): the plane geometry (boundary polygon with named
edges,
fracture polylines; :class:`poromech.geometry.plane.PlaneGeometry`) and the mesh arrays
(:class:`poromech.mesh.generate.MeshArrays`) consistent with it. The rules (docs/meshes.md):

* cells: 3-node triangles in the plane ``z = 0``, forming one conforming piece with a single
  boundary loop (no holes);
* a fracture group: line elements that are edges of the triangles, inside the domain, forming a
  single chain (one polyline, corners allowed; no branch, gap or loop). Its polyline runs the way
  its line elements run in the file (in gmsh, the way its curves run), or from the end given as
  its start point in the scene; ``n⁺`` is the left normal of that direction;
* the boundary: every boundary edge belongs to exactly one named boundary;
* consecutive edges that are collinear (within :data:`COLLINEAR_TOL` of the domain size) are one
  polyline segment or one polygon edge, so a straight fracture or side is one segment, as in a
  YAML geometry.

Serial, no MPI: call on one rank.
"""

from __future__ import annotations

import contextlib
import io
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from poromech.geometry.plane import PlaneGeometry
from poromech.mesh.generate import MeshArrays, gmsh_session, mesh_arrays

__all__ = [
    "COLLINEAR_TOL",
    "GMSH_SUFFIXES",
    "ImportedMesh",
    "MeshFileError",
    "RawMesh",
    "import_mesh",
    "mesh_file_arrays",
    "mesh_from_groups",
    "read_mesh_file",
    "refine_uniformly",
]

log = logging.getLogger("poromech")

#: Files read with gmsh (a ``.geo`` script is meshed by gmsh first); others go through meshio.
GMSH_SUFFIXES = (".geo", ".msh")
#: Nodes within this fraction of the domain diameter of a straight line are on it: collinear
#: edges are merged into one segment (far below the 1e-8 used to find nodes on the boundary).
COLLINEAR_TOL = 1e-10
#: Largest ``|z|`` (fraction of the domain diameter) of a node of a plane mesh.
PLANAR_TOL = 1e-9

IntArray = npt.NDArray[np.int64]


class MeshFileError(ValueError):
    """A mesh file or group that cannot be used.

    Attributes:
        key: The scene key under ``geometry.mesh`` the error is about (``file``, ``fractures.0``,
            ``boundaries.top``, ``starts.F1``).
    """

    def __init__(self, key: str, message: str):
        super().__init__(message)
        self.key = key


@dataclass(frozen=True)
class RawMesh:
    """A mesh as read from a file.

    Attributes:
        x: Node coordinates, ``(n, 3)``.
        triangles: Triangle nodes, ``(m, 3)``.
        groups: Line elements ``(k, 2)`` of every named 1D group, in file order and orientation.
        unnamed: Tags of the 1D physical groups without a name (they cannot be referenced).
    """

    x: npt.NDArray[np.float64]
    triangles: IntArray
    groups: dict[str, IntArray]
    unnamed: tuple[int, ...] = ()


@dataclass(frozen=True)
class ImportedMesh:
    """A mesh file turned into a plane geometry and the mesh arrays that go with it."""

    geometry: PlaneGeometry
    arrays: MeshArrays


def _point(p) -> str:
    return f"({float(p[0]):g}, {float(p[1]):g})"


# ---------------------------------------------------------------------------------------------
# Reading


def read_mesh_file(path: Path) -> RawMesh:
    """Read triangles and named 1D groups: gmsh for ``.geo``/``.msh``, meshio otherwise.

    Raises:
        MeshFileError: Unreadable file, or cells other than 3-node triangles and 2-node lines.
    """
    if path.suffix.lower() in GMSH_SUFFIXES:
        return _read_gmsh(path)
    return _read_meshio(path)


def _gmsh_failure(gmsh, err: Exception, path: Path) -> str:
    """The last error gmsh logged (its exceptions only say 'Error'), with the file's name."""
    lines = [m for m in gmsh.logger.get() if m.lower().startswith("error")]
    text = lines[-1].split(":", 1)[-1].strip() if lines else str(err)
    return " ".join(text.replace(str(path), path.name).split())


def _read_gmsh(path: Path) -> RawMesh:
    """Open a ``.msh`` (or mesh a ``.geo`` in 2D) with gmsh and read its mesh and 1D groups."""
    with gmsh_session() as gmsh:
        gmsh.logger.start()
        try:
            gmsh.open(str(path))
            if path.suffix.lower() == ".geo":
                gmsh.model.mesh.generate(2)
        except Exception as err:  # noqa: BLE001  (gmsh raises plain Exceptions)
            why = _gmsh_failure(gmsh, err, path)
            raise MeshFileError("file", f"gmsh cannot read it: {why}") from None
        tags, coords, _ = gmsh.model.mesh.getNodes()
        if not len(tags):
            raise MeshFileError("file", "the file has no mesh nodes (allowed: a 2D triangle mesh)")
        index = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
        index[tags] = np.arange(len(tags))
        x = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
        _reject_gmsh_elements(gmsh, 3, ())
        _reject_gmsh_elements(gmsh, 2, (2,))
        types, _, nodes = gmsh.model.mesh.getElements(2)
        tri = [index[np.asarray(nd, dtype=np.int64)].reshape(-1, 3)
               for ty, nd in zip(types, nodes, strict=True) if ty == 2]
        groups: dict[str, list[IntArray]] = {}
        unnamed = []
        for _, tag in gmsh.model.getPhysicalGroups(1):
            name = gmsh.model.getPhysicalName(1, tag)
            if not name:
                unnamed.append(int(tag))
                continue
            for ent in gmsh.model.getEntitiesForPhysicalGroup(1, tag):
                etypes, _, enodes = gmsh.model.mesh.getElements(1, int(ent))
                for ty, nd in zip(etypes, enodes, strict=True):
                    if ty != 1:
                        kind = gmsh.model.mesh.getElementProperties(ty)[0]
                        raise MeshFileError("file", f"group '{name}' has '{kind}' elements "
                                            "(allowed: 2-node lines; export a first-order mesh)")
                    groups.setdefault(name, []).append(
                        index[np.asarray(nd, dtype=np.int64)].reshape(-1, 2))
    cells = np.concatenate(tri) if tri else np.empty((0, 3), dtype=np.int64)
    return RawMesh(x, cells, {k: np.concatenate(v) for k, v in groups.items()}, tuple(unnamed))


def _reject_gmsh_elements(gmsh, dim: int, allowed: Sequence[int]) -> None:
    """Refuse elements of dimension ``dim`` whose gmsh type is not in ``allowed``."""
    types, tags, _ = gmsh.model.mesh.getElements(dim)
    for ty, t in zip(types, tags, strict=True):
        if ty not in allowed and len(t):
            kind, edim = gmsh.model.mesh.getElementProperties(ty)[:2]
            why = (": mesh files are read for 2D scenes only (a 3D scene meshes its box from "
                   "geometry.domain.box and geometry.fractures)" if edim == 3 else "")
            raise MeshFileError("file", f"the mesh has {len(t)} '{kind}' elements (allowed: "
                                f"3-node triangles and 2-node lines of a first-order 2D mesh){why}")


def _read_meshio(path: Path) -> RawMesh:
    """Read a mesh with meshio; named groups from its cell sets or gmsh physical names."""
    import meshio

    said = io.StringIO()
    try:
        # meshio prints why a reader failed and then calls sys.exit: keep both in the error
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            mesh = meshio.read(str(path))
    except (Exception, SystemExit) as err:  # noqa: BLE001  (meshio raises many kinds)
        printed = [line.strip() for line in said.getvalue().splitlines() if line.strip()]
        text = printed[0] if printed and isinstance(err, SystemExit) else str(err)
        text = " ".join(text.replace(str(path), path.name).split()) or type(err).__name__
        raise MeshFileError("file", f"meshio cannot read it: {text} (allowed: .geo, .msh, or a "
                            "format meshio reads, with named line groups)") from None
    x = np.asarray(mesh.points, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] not in (2, 3):
        raise MeshFileError("file", f"its points have shape {x.shape} (allowed: 2D or 3D points)")
    if x.shape[1] == 2:
        x = np.column_stack([x, np.zeros(len(x))])
    tri = []
    for block in mesh.cells:
        if block.type == "triangle":
            tri.append(np.asarray(block.data, dtype=np.int64))
        elif block.type not in ("line", "vertex") and len(block.data):
            raise MeshFileError("file", f"the mesh has {len(block.data)} '{block.type}' cells "
                                "(allowed: 'triangle', and 'line' for groups)")
    groups: dict[str, list[IntArray]] = {}
    for name, per_block in mesh.cell_sets.items():
        for block, idx in zip(mesh.cells, per_block, strict=False):
            if block.type == "line" and idx is not None and len(idx):
                groups.setdefault(str(name), []).append(np.asarray(block.data)[np.asarray(idx)])
    physical = mesh.cell_data.get("gmsh:physical")
    named = set()
    for name, value in (mesh.field_data or {}).items():
        tag, dim = (int(v) for v in np.asarray(value).ravel()[:2])
        if dim != 1 or physical is None:
            continue
        named.add(tag)
        for block, tags in zip(mesh.cells, physical, strict=True):
            if block.type == "line" and name not in mesh.cell_sets:
                groups.setdefault(str(name), []).append(np.asarray(block.data)[tags == tag])
    tags = {int(t) for block, ts in zip(mesh.cells, physical or (), strict=False)
            if block.type == "line" for t in np.unique(ts)}
    cells = np.concatenate(tri) if tri else np.empty((0, 3), dtype=np.int64)
    return RawMesh(x, cells, {k: np.concatenate(v).astype(np.int64) for k, v in groups.items()},
                   tuple(sorted(tags - named)))


# ---------------------------------------------------------------------------------------------
# Mesh topology


def _keys(edges: IntArray, n: int) -> IntArray:
    """A key per undirected edge."""
    return np.minimum(edges[:, 0], edges[:, 1]) * n + np.maximum(edges[:, 0], edges[:, 1])


@dataclass(frozen=True)
class _Edges:
    """The edges of a triangle mesh: unique keys, triangle counts, directed boundary edges."""

    n: int
    keys: IntArray
    count: IntArray
    boundary: IntArray

    @classmethod
    def of(cls, cells: IntArray, n: int) -> _Edges:
        directed = cells[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)  # counter-clockwise cells
        keys, inverse, count = np.unique(_keys(directed, n), return_inverse=True,
                                         return_counts=True)
        return cls(n, keys, count, directed[count[inverse] == 1])

    def count_of(self, edges: IntArray) -> IntArray:
        """Number of triangles sharing each edge (0: not an edge of the mesh; -1 nodes: none)."""
        k = _keys(np.maximum(edges, 0), self.n)
        i = np.minimum(np.searchsorted(self.keys, k), len(self.keys) - 1)
        return np.where(np.all(edges >= 0, axis=1) & (self.keys[i] == k), self.count[i], 0)


def _plane_triangles(raw: RawMesh) -> tuple[npt.NDArray[np.float64], IntArray, IntArray]:
    """Nodes used by triangles (2D), counter-clockwise triangles, and the old→new node map."""
    if not len(raw.triangles):
        raise MeshFileError("file", "the mesh has no triangles (allowed: a 2D triangle mesh; a "
                            "gmsh file with physical groups keeps only their elements: add a "
                            "Physical Surface)")
    used = np.unique(raw.triangles)
    renum = np.full(len(raw.x), -1, dtype=np.int64)
    renum[used] = np.arange(len(used))
    x3 = raw.x[used]
    size = float(np.linalg.norm(x3[:, :2].max(axis=0) - x3[:, :2].min(axis=0)))
    z = np.abs(x3[:, 2])
    if z.max() > PLANAR_TOL * size:
        i = int(np.argmax(z))
        raise MeshFileError("file", f"node {_point(x3[i])} has z = {x3[i, 2]:g} (allowed: a plane "
                            "mesh in z = 0)")
    x, cells = x3[:, :2].copy(), renum[raw.triangles]
    d1, d2 = x[cells[:, 1]] - x[cells[:, 0]], x[cells[:, 2]] - x[cells[:, 0]]
    area = 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    flat = np.abs(area) <= 1e-14 * size**2
    if flat.any():
        c = x[cells[np.argmax(flat)]].mean(axis=0)
        raise MeshFileError("file", f"the triangle at {_point(c)} has zero area (allowed: "
                            "non-degenerate triangles)")
    cells[area < 0] = cells[area < 0][:, [0, 2, 1]]
    return x, cells, renum


def _boundary_loop(x, edges: _Edges) -> IntArray:
    """Directed boundary edges in loop order (interior on the left), from the lowest-left node.

    Raises:
        MeshFileError: The mesh is not one piece bounded by one loop.
    """
    b = edges.boundary
    if np.any(edges.count > 2):
        k = edges.keys[np.argmax(edges.count > 2)]
        p = 0.5 * (x[k // edges.n] + x[k % edges.n])
        raise MeshFileError("file", f"the edge at {_point(p)} is shared by more than two "
                            "triangles (allowed: a conforming 2D mesh)")
    starts, counts = np.unique(b[:, 0], return_counts=True)
    if np.any(counts > 1):
        raise MeshFileError("file", f"the boundary touches itself at "
                            f"{_point(x[starts[np.argmax(counts > 1)]])} (allowed: one boundary "
                            "loop without pinched points)")
    nxt = np.full(edges.n, -1, dtype=np.int64)
    nxt[b[:, 0]] = np.arange(len(b))
    first = int(np.lexsort((x[b[:, 0], 1], x[b[:, 0], 0]))[0])
    order = [first]
    e = nxt[b[first, 1]]
    while e != first and len(order) <= len(b):
        order.append(int(e))
        e = nxt[b[e, 1]]
    if len(order) != len(b):
        rest = np.setdiff1d(np.arange(len(b)), order)
        raise MeshFileError("file", f"the mesh boundary has more than one loop (another one "
                            f"passes through {_point(x[b[rest[0], 0]])}): holes, separate pieces "
                            "and hanging nodes are not supported (allowed: one conforming piece "
                            "with one boundary loop)")
    return b[np.array(order)]


def _runs(p: npt.NDArray[np.float64], tol: float) -> list[int]:
    """Indices of the points that end straight runs of the path ``p`` (first and last included).

    A run ``p[a..b]`` is straight when its inner points lie within ``tol`` of the segment
    ``[p[a], p[b]]`` and progress along it.
    """
    keep, a = [0], 0
    for b in range(2, len(p)):
        d = p[b] - p[a]
        length = float(np.hypot(*d))
        q = p[a + 1:b] - p[a]
        dist = np.abs(d[0] * q[:, 1] - d[1] * q[:, 0]) / length
        along = np.concatenate([[0.0], q @ d / length, [length]])
        if dist.max() > tol or np.any(np.diff(along) <= 0.0):
            keep.append(b - 1)
            a = b - 1
    keep.append(len(p) - 1)
    return keep


# ---------------------------------------------------------------------------------------------
# Groups


@dataclass(frozen=True)
class _Groups:
    """The named groups of a mesh, mapped to its cleaned nodes and edges."""

    x: npt.NDArray[np.float64]
    edges: _Edges
    raw: Mapping[str, IntArray]
    renum: IntArray
    unnamed: tuple[int, ...]

    def mapped(self, name: str) -> IntArray:
        """A group's line elements in the mesh's node numbering (-1: a node of no triangle)."""
        e = self.raw[name].reshape(-1, 2)
        return np.where(e >= 0, self.renum[np.maximum(e, 0)], -1)

    def counts(self, name: str) -> IntArray:
        """Triangles sharing each line element of a group (0: not a triangle edge)."""
        return self.edges.count_of(self.mapped(name))

    def mid(self, e) -> str:
        """The midpoint of an edge, for a message."""
        return _point(0.5 * (self.x[e[0]] + self.x[e[1]]))

    def require(self, name: str, key: str, fractures: Sequence[str] = ()) -> None:
        """Refuse a group the file does not have (or a boundary group that is a fracture)."""
        if name in fractures and not key.startswith("fractures"):
            raise MeshFileError(key, f"group '{name}' is also a fracture (allowed: a group is a "
                                "fracture or part of a boundary)")
        if name not in self.raw:
            known = ", ".join(sorted(self.raw)) or "none"
            hint = (f"; its unnamed 1D physical groups (tags {', '.join(map(str, self.unnamed))})"
                    " cannot be referenced: give them names" if self.unnamed else "")
            raise MeshFileError(key, f"'{name}' is not a named group of line elements of the "
                                f"file (allowed: {known}){hint}")

    def edges_of(self, name: str, key: str) -> IntArray:
        """The line elements of a group (unique, file orientation), checked to be mesh edges.

        Raises:
            MeshFileError: A line element that is not an edge of the triangles.
        """
        e = self.mapped(name)
        count = self.edges.count_of(e)
        if np.any(count == 0):
            i = int(np.argmax(count == 0))
            where = "" if np.any(e[i] < 0) else f" at {self.mid(e[i])}"
            raise MeshFileError(key, f"group '{name}' has a line element{where} that is not an "
                                "edge of the triangles: the mesh is not conforming to it "
                                "(allowed: line elements that are triangle edges)")
        _, first = np.unique(_keys(e, self.edges.n), return_index=True)
        return e[np.sort(first)]


def _chain(x, e: IntArray, name: str, key: str) -> tuple[IntArray, bool]:
    """Order the edges of a fracture group into a path; also whether all edges run along it.

    Raises:
        MeshFileError: The group branches, has several pieces or is a closed loop.
    """
    nodes, degree = np.unique(e, return_counts=True)
    if np.any(degree > 2):
        p = x[nodes[np.argmax(degree > 2)]]
        raise MeshFileError(key, f"group '{name}' branches at {_point(p)} (allowed: one chain of "
                            "edges per fracture; make one group per branch)")
    ends = nodes[degree == 1]
    if not len(ends):
        raise MeshFileError(key, f"group '{name}' is a closed loop (allowed: a chain with two "
                            "ends)")
    incident: dict[int, list[int]] = {}
    for i, (a, b) in enumerate(e):
        incident.setdefault(int(a), []).append(i)
        incident.setdefault(int(b), []).append(i)
    path, used, forward = [int(ends[0])], np.zeros(len(e), dtype=bool), []
    while True:
        nxt = [i for i in incident[path[-1]] if not used[i]]
        if not nxt:
            break
        i = nxt[0]
        used[i] = True
        forward.append(int(e[i, 0]) == path[-1])
        path.append(int(e[i, 1] if forward[-1] else e[i, 0]))
    if not used.all():
        raise MeshFileError(key, f"group '{name}' is not one piece (one piece ends at "
                            f"{_point(x[ends[0]])}, another passes through "
                            f"{_point(x[e[~used][0, 0]])}) "
                            "(allowed: one chain of edges per fracture; make one group per "
                            "piece)")
    return np.array(path, dtype=np.int64), all(forward) or not any(forward)


def _orient(x, path: IntArray, consistent: bool, first_forward: bool, start, name: str,
            key: str, tol: float) -> IntArray:
    """The path of a fracture from its start: the given start point, else the file's direction."""
    ends = f"{_point(x[path[0]])} or {_point(x[path[-1]])}"
    if start is not None:
        d = [np.linalg.norm(x[path[0]] - start), np.linalg.norm(x[path[-1]] - start)]
        if min(d) > tol:
            raise MeshFileError(f"starts.{name}", f"{_point(start)} is not an end of group "
                                f"'{name}' (allowed: {ends})")
        return path if d[0] <= d[1] else path[::-1]
    if not consistent:
        raise MeshFileError(key, f"group '{name}' has line elements running both ways, so its "
                            f"orientation (n⁺) is undefined (allowed: give its start point, "
                            f"geometry.mesh.starts.{name}: {ends})")
    return path if first_forward else path[::-1]


@dataclass(frozen=True)
class _Fracture:
    name: str
    points: npt.NDArray[np.float64]  # polyline corners
    facets: IntArray  # mesh edges along the polyline, oriented along it
    segment: npt.NDArray[np.int32]


def _fracture(groups: _Groups, name: str, key: str, start, tol: float) -> _Fracture:
    """A fracture group as a polyline and its edges (checked to be inside the domain)."""
    x = groups.x
    e = groups.edges_of(name, key)
    if not len(e):
        raise MeshFileError(key, f"group '{name}' has no line elements (allowed: a group of "
                            "line elements)")
    inside = groups.edges.count_of(e) == 2
    if not inside.all():
        raise MeshFileError(key, f"group '{name}' runs along the domain boundary at "
                            f"{groups.mid(e[~inside][0])} (allowed: fractures inside the domain; "
                            "they may end on the boundary)")
    path, consistent = _chain(x, e, name, key)
    first_forward = bool(np.any((e[:, 0] == path[0]) & (e[:, 1] == path[1])))
    path = _orient(x, path, consistent, first_forward, start, name, key, 1e3 * tol)
    corners = _runs(x[path], tol)
    segment = np.repeat(np.arange(len(corners) - 1, dtype=np.int32), np.diff(corners))
    return _Fracture(name, x[path[corners]], np.column_stack([path[:-1], path[1:]]), segment)


def _default_boundaries(groups: _Groups, fractures: Sequence[str]) -> dict[str, tuple[str]]:
    """Every named group lying on the boundary (and not a fracture), under its own name."""
    return {name: (name,) for name in groups.raw if name not in fractures
            and len(groups.raw[name]) and np.all(groups.counts(name) == 1)}


def _boundary_names(groups: _Groups, loop: IntArray,
                    boundaries: Mapping[str, Sequence[str]], fractures: Sequence[str]) -> list[str]:
    """The boundary name of each edge of the boundary loop.

    Raises:
        MeshFileError: Missing or misplaced groups, an edge in two boundaries or in none.
    """
    edges = groups.edges
    keys = _keys(loop, edges.n)
    sorter = np.argsort(keys)
    owner = np.full(len(loop), -1, dtype=np.int64)
    names = list(boundaries)
    for j, (bname, members) in enumerate(boundaries.items()):
        key = f"boundaries.{bname}"
        for g in members:
            groups.require(g, key, fractures)
            e = groups.edges_of(g, key)
            on = edges.count_of(e) == 1
            if not on.all():
                raise MeshFileError(key, f"group '{g}' has an edge inside the domain at "
                                    f"{groups.mid(e[~on][0])} (allowed: edges on the domain "
                                    "boundary)")
            i = sorter[np.searchsorted(keys, _keys(e, edges.n), sorter=sorter)]
            clash = (owner[i] >= 0) & (owner[i] != j)
            if clash.any():
                k = i[np.argmax(clash)]
                raise MeshFileError(key, f"the boundary edge at {groups.mid(loop[k])} is in "
                                    f"boundaries '{names[owner[k]]}' and '{bname}' (allowed: "
                                    "each boundary edge in one boundary)")
            owner[i] = j
    if np.any(owner < 0):
        k = int(np.argmax(owner < 0))
        raise MeshFileError("boundaries", f"the boundary edge at {groups.mid(loop[k])} is in no "
                            "named boundary (allowed: every boundary edge in a named group, "
                            "listed in geometry.mesh.boundaries when that is given)")
    return [names[j] for j in owner]


def _polygon(x, loop: IntArray, names: list[str], tol: float):
    """Boundary polygon vertices, the name of each polygon edge, the polygon edge of each facet."""
    cut = [0] + [i for i in range(1, len(loop)) if names[i] != names[i - 1]] + [len(loop)]
    vertices, edge_names, facet_edge = [], [], np.empty(len(loop), dtype=np.int32)
    for a, b in zip(cut[:-1], cut[1:], strict=True):
        p = x[np.concatenate([loop[a:b, 0], loop[b - 1:b, 1]])]
        corners = _runs(p, tol)
        for k in range(len(corners) - 1):
            facet_edge[a + corners[k]:a + corners[k + 1]] = len(vertices)
            vertices.append(p[corners[k]])
            edge_names.append(names[a])
    return np.array(vertices), tuple(edge_names), facet_edge


# ---------------------------------------------------------------------------------------------
# Public


def mesh_from_groups(raw: RawMesh, fractures: Sequence[str],
                     boundaries: Mapping[str, Sequence[str]] | None = None,
                     starts: Mapping[str, Sequence[float]] | None = None,
                     refinement: int = 0, warn: bool = True) -> ImportedMesh:
    """Plane geometry and mesh arrays of a mesh with named groups.

    Args:
        raw: The mesh as read.
        fractures: Groups that are fractures (one fracture each, named as the group).
        boundaries: ``{boundary name: [groups]}``; None: every named group lying on the boundary
            (and not a fracture) is a boundary of the same name.
        starts: Start point of fractures whose orientation is given explicitly, by name.
        refinement: Uniform refinements (each splits every triangle into four).
        warn: Warn about the groups that are ignored (once per run: the file is read when the
            scene is checked and again when it is meshed).

    Raises:
        MeshFileError: One line naming the scene key and the group.
    """
    starts = dict(starts or {})
    x, cells, renum = _plane_triangles(raw)
    diameter = float(np.linalg.norm(x.max(axis=0) - x.min(axis=0)))
    tol = COLLINEAR_TOL * diameter
    groups = _Groups(x, _Edges.of(cells, len(x)), raw.groups, renum, raw.unnamed)
    loop = _boundary_loop(x, groups.edges)
    for name in starts:
        if name not in fractures:
            raise MeshFileError(f"starts.{name}", f"'{name}' is not a fracture (allowed: "
                                f"{', '.join(fractures) or 'none'})")
    fracs = []
    for i, name in enumerate(fractures):
        key = f"fractures.{i}"
        if name in fractures[:i]:
            raise MeshFileError(key, f"group '{name}' is listed twice")
        groups.require(name, key)
        start = np.asarray(starts[name], dtype=np.float64) if name in starts else None
        fracs.append(_fracture(groups, name, key, start, tol))
    if boundaries is None:
        boundaries = _default_boundaries(groups, fractures)
    names = _boundary_names(groups, loop, boundaries, fractures)
    polygon, edge_names, facet_edge = _polygon(x, loop, names, tol)
    if warn:
        _warn_unused(groups, set(fractures) | {g for gs in boundaries.values() for g in gs})
    geo = PlaneGeometry(polygon, edge_names, tuple(f.points for f in fracs),
                        tuple(f.name for f in fracs))
    empty = np.empty(0, dtype=np.int32)
    ff = np.concatenate([f.facets for f in fracs]) if fracs else np.empty((0, 2), np.int64)
    fid = np.concatenate([np.full(len(f.facets), k, np.int32) for k, f in enumerate(fracs)]
                         + [empty])
    fseg = np.concatenate([f.segment for f in fracs] + [empty])
    fracture, boundary = (ff, fid, fseg), (loop, facet_edge)
    for _ in range(refinement):
        x, cells, fracture, boundary = refine_uniformly(x, cells, fracture, boundary)
    return ImportedMesh(geo, mesh_arrays(geo, x, cells, fracture, boundary))


def _warn_unused(groups: _Groups, listed: set[str]) -> None:
    """Warn about named groups inside the domain that are not fractures, and unnamed groups.

    Both are ignored. An unnamed group was dropped without a word: a file whose two fracture
    groups were both named "f" kept the name on one of them, and half the network was gone.
    """
    for name in sorted(set(groups.raw) - listed):
        if np.any(groups.counts(name) == 2):
            log.warning("group '%s' of the mesh file lies inside the domain but is not in "
                        "geometry.mesh.fractures: it is not a fracture", name)
    if groups.unnamed:  # gmsh keeps one name per tag: two groups named alike lose one name
        log.warning("the mesh file's 1D physical groups without a name (tags %s) are ignored: "
                    "name them to use them as fractures or boundaries",
                    ", ".join(map(str, groups.unnamed)))


def refine_uniformly(x, cells, fracture: tuple, boundary: tuple):
    """Split every triangle into four and every facet into two at edge midpoints.

    Args:
        x: Node coordinates ``(n, 2)``.
        cells: Triangles ``(m, 3)``.
        fracture: Fracture facets ``(k, 2)`` with their fracture index and segment.
        boundary: Boundary facets ``(l, 2)`` with their polygon edge.

    Returns:
        The refined ``x``, ``cells``, ``fracture`` and ``boundary`` (facet data repeated).
    """
    n = len(x)
    keys, inverse = np.unique(_keys(cells[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), n),
                              return_inverse=True)
    mid = n + inverse.reshape(-1, 3)  # midpoints of edges 01, 12, 20
    x = np.vstack([x, 0.5 * (x[keys // n] + x[keys % n])])
    a, b, c = cells.T
    m01, m12, m20 = mid.T
    cells = np.concatenate([np.column_stack(t) for t in (
        (a, m01, m20), (m01, b, m12), (m20, m12, c), (m01, m12, m20))])

    def split(facets, *data):
        m = n + np.searchsorted(keys, _keys(facets, n))
        halves = np.stack([np.column_stack([facets[:, 0], m]), np.column_stack([m, facets[:, 1]])],
                          axis=1).reshape(-1, 2)
        return (halves, *(np.repeat(d, 2) for d in data))

    return x, cells, split(*fracture), split(*boundary)


def import_mesh(path: Path, fractures: Sequence[str],
                boundaries: Mapping[str, Sequence[str]] | None = None,
                starts: Mapping[str, Sequence[float]] | None = None,
                refinement: int = 0, warn: bool = True) -> ImportedMesh:
    """Read a mesh file and build its plane geometry and mesh arrays (one rank).

    See :func:`mesh_from_groups` for the arguments.

    Raises:
        MeshFileError: One line naming the scene key and the group.
    """
    return mesh_from_groups(read_mesh_file(Path(path)), fractures, boundaries, starts,
                            refinement, warn)


def mesh_file_arrays(spec, geometry: PlaneGeometry, refinement: int) -> MeshArrays:
    """The mesh arrays of a validated mesh-file scene (one rank).

    Args:
        spec: The scene's ``geometry.mesh`` (:class:`poromech.scene.schema.MeshFile`).
        geometry: The plane geometry the scene was validated with.
        refinement: Uniform refinement level.

    Raises:
        RuntimeError: The file no longer gives that geometry (it changed since validation).
    """
    imported = import_mesh(Path(spec.file), spec.fractures, spec.boundaries, spec.starts,
                           refinement, warn=False)
    new = imported.geometry
    tol = 1e-12 * geometry.diameter
    same = (new.boundary_names == geometry.boundary_names
            and new.fracture_names == geometry.fracture_names
            and all(a.shape == b.shape and np.allclose(a, b, rtol=0, atol=tol) for a, b in
                    zip((new.boundary, *new.fractures), (geometry.boundary, *geometry.fractures),
                        strict=True)))
    if not same:
        raise RuntimeError(f"mesh file '{spec.file}' no longer gives the geometry the scene was "
                           "validated with (was it changed?): validate the scene again")
    return imported.arrays
