"""From the scene's ``geometry`` and ``mesh`` keys to a geometry and mesh sizes.

The geometry is given in the scene, or read from a CSV file of fractures
(:mod:`poromech.geometry.dfn`) or a mesh file (:mod:`poromech.mesh.imported`); file names are
made absolute so that the scene stored next to the outputs finds them again.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from poromech.errors import ConfigError
from poromech.geometry.box import BoxGeometry, Fracture3D
from poromech.geometry.plane import PlaneGeometry
from poromech.mesh.generate import CELLS_PER_AREA, MeshSizes, SizeZone
from poromech.scene.builder import Builder, deep_copy, field_meta, format_value
from poromech.scene.schema import Domain, FractureSpec, MeshSpec, Scene, scene_dimension

__all__ = [
    "RECTANGLE_EDGES",
    "absolute_geometry_paths",
    "check_domain",
    "geometry_file",
    "geometry_source",
    "mesh_file_refinement",
    "mesh_sizes",
    "scene_dimension",
    "scene_geometry",
    "read_geometry_files",
]


RECTANGLE_EDGES = ("bottom", "right", "top", "left")


def scene_geometry(scene: Scene) -> PlaneGeometry | BoxGeometry:
    """The geometry of a scene: plane (2D, edge names resolved) or a box (3D, ``domain.box``)."""
    dom = scene.geometry.domain
    fnames = _names(scene.geometry.fractures)
    if dom.box is not None:
        fractures = []
        for f, name in zip(scene.geometry.fractures, fnames, strict=True):
            if f.disc is not None:
                fractures.append(Fracture3D.disc(name, f.disc.center, f.disc.normal,
                                                 f.disc.radius))
            else:
                fractures.append(Fracture3D.polygon(name, np.array(f.polygon, dtype=float)))
        surfaces = tuple(Fracture3D.polygon(name, np.array(sf.polygon, float))
                         for sf, name in zip(scene.geometry.surfaces,
                                             _names(scene.geometry.surfaces), strict=True))
        return BoxGeometry(tuple(float(v) for v in dom.box), tuple(fractures), surfaces)
    if dom.rectangle is not None:
        x0, y0, x1, y1 = dom.rectangle
        boundary = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)
        names = RECTANGLE_EDGES
    else:
        boundary = np.array(dom.polygon, dtype=np.float64)
        names = [f"edge{i}" for i in range(len(boundary))]
        for name, edges in dom.boundary_names.items():
            for e in edges:
                names[e] = name
        names = tuple(names)
    fractures = tuple(np.array(f.points, dtype=np.float64) for f in scene.geometry.fractures)
    return PlaneGeometry(boundary, names, fractures, fnames)


def check_domain(scene: Scene) -> None:
    """One rectangle, polygon or box; edge names exist; fractures of the domain's kind; names.

    Fractures are polylines in 2D, polygons or discs in 3D; fracture names are unique.
    """
    dom = scene.geometry.domain
    given = [k for k in ("rectangle", "polygon", "box") if getattr(dom, k) is not None]
    if len(given) != 1:
        raise ConfigError("scene key 'geometry.domain' needs exactly one of rectangle, polygon, "
                          f"box (given: {', '.join(given) or 'none'})")
    if dom.box is not None:
        lo, hi = np.array(dom.box[:3]), np.array(dom.box[3:])
        if not np.all(hi > lo):
            raise ConfigError(f"scene key 'geometry.domain.box' = {list(dom.box)} needs "
                              "x1 > x0, y1 > y0, z1 > z0")
        if dom.boundary_names:
            raise ConfigError("scene key 'geometry.domain.boundary_names' is for polygons only")
    elif dom.rectangle is not None:
        x0, y0, x1, y1 = dom.rectangle
        if not (x1 > x0 and y1 > y0):
            raise ConfigError(
                f"scene key 'geometry.domain.rectangle' = {list(dom.rectangle)} "
                "needs x1 > x0, y1 > y0"
            )
        if dom.boundary_names:
            raise ConfigError("scene key 'geometry.domain.boundary_names' is for polygons only")
    else:
        n = len(dom.polygon)
        named: dict[int, str] = {}
        for name, edges in dom.boundary_names.items():
            key = f"scene key 'geometry.domain.boundary_names.{name}' = {list(edges)}"
            for e in edges:
                if not 0 <= e < n:
                    raise ConfigError(f"{key}: edge {e} does not exist (0..{n - 1})")
                if e in named:
                    raise ConfigError(f"{key}: edge {e} is already named {named[e]!r} (allowed: "
                                      "one name per edge)")
                named[e] = name
        for name, edges in dom.boundary_names.items():
            default = re.fullmatch(r"edge(\d+)", str(name))
            k = int(default[1]) if default else -1
            if 0 <= k < n and k not in named:
                raise ConfigError(
                    f"scene key 'geometry.domain.boundary_names.{name}' = {list(edges)}: "
                    f"{name!r} is also the default name of edge {k}, which would answer to it "
                    "too (allowed: another name, or name that edge as well)")
    _check_fracture_kinds(scene, dom.box is not None)
    if scene.geometry.surfaces and dom.box is None:
        raise ConfigError("scene key 'geometry.surfaces' is for a box (3D) only: in 2D the mesh "
                          "conforms to fractures and domain edges")
    for key in ("fractures", "surfaces"):
        items = getattr(scene.geometry, key)
        for i, item in enumerate(items):
            if item.name is not None and not item.name.strip():
                raise ConfigError(f"scene key 'geometry.{key}.{i}.name' = {item.name!r} is "
                                  "empty (allowed: a name, or no key for the 1-based number)")
        names = _names(items)
        if len(set(names)) != len(names):
            repeated = sorted({n for n in names if names.count(n) > 1})
            raise ConfigError(f"scene key 'geometry.{key}': names repeat: {repeated} (an "
                              f"unnamed one is named by its 1-based number; names: {list(names)})")


def _names(items) -> tuple[str, ...]:
    """The names of fractures or surfaces: each one's ``name``, else its 1-based number."""
    return tuple(str(i + 1) if item.name is None else item.name for i, item in enumerate(items))


def _check_fracture_kinds(scene: Scene, box: bool) -> None:
    """Polylines (``points``) in a 2D domain; a ``polygon`` or a ``disc`` in a box."""
    for i, f in enumerate(scene.geometry.fractures):
        key = f"geometry.fractures.{i}"
        given = [k for k in ("points", "polygon", "disc") if getattr(f, k) is not None]
        allowed = ("polygon", "disc") if box else ("points",)
        if len(given) != 1 or given[0] not in allowed:
            where = "a box (3D)" if box else "a 2D domain"
            raise ConfigError(f"scene key '{key}' needs exactly one of {', '.join(allowed)} in "
                              f"{where} (given: {', '.join(given) or 'none'})")


#: Suffixes of the shipped geometry files that scenes may name without a path (``meshes/``).
GEOMETRY_FILE_SUFFIXES = (".msh", ".geo", ".csv")


def _shipped_geometry_files() -> dict[str, Path]:
    """Mesh and fracture files installed with poromech (``meshes/``), by file name."""
    root = importlib.resources.files("poromech.meshes")
    return {p.name: Path(str(p)) for p in sorted(root.iterdir(), key=lambda q: q.name)
            if p.name.endswith(GEOMETRY_FILE_SUFFIXES)}


def geometry_file(value: str, key: str, base: Path | None = None) -> Path:
    """The absolute path of a file named in the geometry.

    A relative path is taken from ``base`` (the scene file's folder; default the working
    directory); a bare name that is no file there may be a shipped file (``meshes/``).

    Raises:
        ConfigError: Neither.
    """
    path = Path(value).expanduser()
    if not path.is_absolute():
        path = (base or Path.cwd()) / path
    if path.is_file():
        return path.resolve()
    shipped = _shipped_geometry_files()
    if value in shipped:
        return shipped[value]
    raise ConfigError(f"scene key '{key}' = {value!r}: there is no file {str(path)!r} nor a "
                      f"shipped file of that name (shipped: {', '.join(shipped)})")


def _geometry_file_keys(raw: Mapping) -> list[tuple[dict, str, str]]:
    """``(mapping, key, scene key)`` of the file names in a raw geometry mapping."""
    geo = raw.get("geometry")
    out = []
    if isinstance(geo, dict):
        if isinstance(geo.get("fracture_file"), str):
            out.append((geo, "fracture_file", "geometry.fracture_file"))
        if isinstance(geo.get("mesh"), dict) and isinstance(geo["mesh"].get("file"), str):
            out.append((geo["mesh"], "file", "geometry.mesh.file"))
    return out


def absolute_geometry_paths(raw: dict, base: Path) -> dict:
    """A raw scene with its geometry file names made absolute paths (relative ones from ``base``).

    The scene stored next to the outputs (for ``--restart``) then finds the files again.

    Raises:
        ConfigError: A file that exists neither under ``base`` nor among the shipped files.
    """
    raw = deep_copy(raw)
    for node, key, path in _geometry_file_keys(raw):
        node[key] = str(geometry_file(node[key], path, base))
    return raw


def mesh_file_refinement(raw: dict) -> tuple[dict, int | None]:
    """For a mesh-file geometry: the refinement level, and the scene without its ``mesh`` key.

    The element sizes come from the file; ``mesh`` may only give ``refinement``.
    """
    geo = raw.get("geometry")
    if not (isinstance(geo, dict) and geo.get("mesh") is not None):
        return raw, None
    spec = raw.get("mesh")
    if spec is None:
        return raw, 0
    if not isinstance(spec, dict):
        raise ConfigError(f"scene key 'mesh' = {format_value(spec)} must be a mapping")
    for key in spec:
        if key != "refinement":
            raise ConfigError(f"scene key 'mesh.{key}' is not allowed with geometry.mesh: the "
                              "element sizes come from the mesh file (allowed: mesh.refinement)")
    level = Builder({}).build(spec.get("refinement", 0), int, "mesh.refinement",
                               field_meta(MeshSpec, "refinement"))
    return {k: v for k, v in raw.items() if k != "mesh"}, level


def _check_geometry_sources(geometry) -> None:
    """A mesh file, or a domain with fractures from the scene or from a CSV file."""
    if geometry.mesh is not None:
        given = [k for k in ("domain", "fracture_file") if getattr(geometry, k) is not None]
        given += ["fractures"] if geometry.fractures else []
        if given:
            raise ConfigError(f"scene key 'geometry.{given[0]}' is not allowed with "
                              "geometry.mesh: the mesh file gives the domain and the fractures")
    elif geometry.domain is None:
        raise ConfigError("scene key 'geometry.domain' is required (or geometry.mesh, a mesh "
                          "file)")
    if geometry.fracture_file is not None and geometry.fractures:
        raise ConfigError("scene key 'geometry': give fractures or fracture_file, not both")
    if (geometry.fracture_file is not None and geometry.domain is not None
            and geometry.domain.box is not None):
        raise ConfigError(f"scene key 'geometry.fracture_file' = {geometry.fracture_file!r}: a "
                          "fracture file gives 2D polylines (a rectangle or polygon domain); in a "
                          "box (3D) give the fractures as geometry.fractures, each a polygon or "
                          "a disc")


def _fractures_from_csv(geometry):
    """The geometry with the fractures of its CSV file."""
    from poromech.geometry.dfn import FractureFileError, read_fracture_csv

    key = "geometry.fracture_file"
    path = geometry_file(geometry.fracture_file, key)
    try:
        network = read_fracture_csv(path)
    except FractureFileError as err:
        raise ConfigError(f"scene key '{key}' = {geometry.fracture_file!r}: {err}") from None
    fractures = tuple(FractureSpec(points=tuple(map(tuple, p.tolist())), name=name)
                      for name, p in network)
    return dataclasses.replace(geometry, fracture_file=str(path), fractures=fractures)


def _geometry_from_mesh(geometry):
    """The geometry with the domain and fractures of its mesh file; and the file's cell count."""
    from poromech.mesh.imported import MeshFileError, import_mesh

    spec = geometry.mesh
    path = geometry_file(spec.file, "geometry.mesh.file")
    try:
        imported = import_mesh(path, spec.fractures, spec.boundaries, spec.starts)
    except MeshFileError as err:
        value = f" = {spec.file!r}" if err.key == "file" else ""
        raise ConfigError(f"scene key 'geometry.mesh.{err.key}'{value}: {err}") from None
    geo = imported.geometry
    edges: dict[str, list[int]] = {}
    for i, name in enumerate(geo.boundary_names):
        edges.setdefault(name, []).append(i)
    domain = Domain(polygon=tuple(map(tuple, geo.boundary.tolist())),
                    boundary_names={k: tuple(v) for k, v in edges.items()})
    fractures = tuple(FractureSpec(points=tuple(map(tuple, p.tolist())), name=name)
                      for p, name in zip(geo.fractures, geo.fracture_names, strict=True))
    geometry = dataclasses.replace(geometry, domain=domain, fractures=fractures,
                                   mesh=dataclasses.replace(spec, file=str(path)))
    return geometry, len(imported.arrays.cells)


def _imported_mesh_spec(geometry, cells: int, refinement: int) -> MeshSpec:
    """``mesh`` of a mesh-file scene: its refinement and an equivalent uniform size.

    The size is the one that the memory estimate (:mod:`poromech.scene.resources`) turns into the
    file's number of cells; nothing else uses it.
    """
    p = np.asarray(geometry.domain.polygon)
    area = 0.5 * abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1))
                           - np.dot(p[:, 1], np.roll(p[:, 0], -1))))
    return MeshSpec(size=float(np.sqrt(CELLS_PER_AREA * area / cells)), refinement=refinement)


def read_geometry_files(scene: Scene, refinement: int | None) -> Scene:
    """The scene with its geometry files read into ``domain`` and ``fractures``.

    A CSV file gives the fractures; a mesh file the domain and fractures, and ``mesh`` (with the
    given refinement).
    """
    geometry = scene.geometry
    _check_geometry_sources(geometry)
    if geometry.fracture_file is not None:
        geometry = _fractures_from_csv(geometry)
    if geometry.mesh is not None:
        geometry, cells = _geometry_from_mesh(geometry)
        scene = dataclasses.replace(scene, mesh=_imported_mesh_spec(geometry, cells, refinement))
    return dataclasses.replace(scene, geometry=geometry)


def geometry_source(scene: Scene) -> str:
    """Where a geometric defect is reported: the geometry key, or the file it came from."""
    geometry = scene.geometry
    if geometry.mesh is not None:
        return f"scene key 'geometry.mesh.file' = {Path(geometry.mesh.file).name!r}"
    if geometry.fracture_file is not None:
        return f"scene key 'geometry.fracture_file' = {Path(geometry.fracture_file).name!r}"
    return "scene key 'geometry'"


def mesh_sizes(scene: Scene) -> MeshSizes:
    """Mesh sizes of a scene with the documented defaults filled in."""
    m = scene.mesh
    fracture = m.fracture_size or m.size
    transition = m.transition or 4 * m.size
    zones = tuple(SizeZone((*map(float, z.center), 0.0)[:3], z.radius, z.size,
                           z.transition or transition, z.region == "fractures") for z in m.zones)
    return MeshSizes(
        size=m.size,
        fracture_size=fracture,
        tip_size=m.tip_size or fracture,
        transition=transition,
        refinement=m.refinement,
        zones=zones,
    )
