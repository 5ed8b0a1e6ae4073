"""Scene files: YAML → validated :class:`poromech.scene.Scene`, with ``--set`` overrides.

All checks run here, before any meshing or solving: unknown keys, wrong types, out-of-range
values, and geometric defects. Every failure is a :class:`ConfigError` whose message is one line
naming the key, the value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import logging
import re
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from poromech.expressions import Expression, ExpressionError, compile_expression
from poromech.geometry import GeometryError, PlaneGeometry, check_geometry, segment_meets_polygon
from poromech.scene import Domain, FractureSpec, MeshSpec, Scene

__all__ = [
    "ConfigError",
    "absolute_geometry_paths",
    "apply_overrides",
    "check_expression",
    "check_name",
    "check_permeability",
    "check_values",
    "default_scene_path",
    "load_scene",
    "plane_geometry",
    "scene_from_dict",
    "scene_path",
    "scene_text",
    "shipped_scenes",
]

log = logging.getLogger("poromech")

#: The embedded scene run by ``poromech run`` without a scene file.
DEFAULT_SCENE = "six_fractures.yaml"

RECTANGLE_EDGES = ("bottom", "right", "top", "left")

#: Largest scene file read (bytes): a scene is a page of text, not a data file.
MAX_SCENE_BYTES = 1_000_000
#: Most values a scene may expand to. YAML aliases repeat a node without copying it, so a small
#: file of nested aliases (a "billion laughs") stands for ~10⁹ values; it is refused before
#: anything copies it.
MAX_SCENE_VALUES = 1_000_000
#: Deepest nesting of a scene's lists and mappings.
MAX_SCENE_DEPTH = 64

#: Names that become file names (scene name → results/<name>, probe name → probe_<name>.csv).
_FILE_NAME = re.compile(r"[^\W_][\w.-]*")

#: Before meshing, fields are checked on this many grid points per axis inside the domain, and
#: boundary and fracture data at this many points per domain edge and fracture segment.
FIELD_GRID = 201
LINE_SAMPLES = 1001
#: Most time points at which a time-dependent expression is checked before meshing (evenly
#: chosen among the step times); after meshing every step time is checked.
MAX_CHECK_TIMES = 200


class ConfigError(ValueError):
    """An invalid scene; the message is a single line."""


def _fmt(value: Any) -> str:
    if isinstance(value, np.generic):
        value = value.item()
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def default_scene_path() -> Path:
    """Path of the embedded default scene."""
    return Path(str(importlib.resources.files("poromech.configs").joinpath(DEFAULT_SCENE)))


def shipped_scenes() -> dict[str, Path]:
    """The scenes installed with poromech (``configs/``), by name."""
    root = importlib.resources.files("poromech.configs")
    return {p.name[:-5]: Path(str(p)) for p in sorted(root.iterdir(), key=lambda q: q.name)
            if p.name.endswith(".yaml")}


def scene_path(scene: str | Path) -> Path:
    """The file of a scene given as a path, or by the name of a shipped scene (``sneddon``).

    An existing path wins over a shipped scene of the same name.

    Raises:
        ConfigError: Neither a path nor a shipped scene.
    """
    path = Path(scene)
    if path.exists():
        return path
    shipped = shipped_scenes()
    name = str(scene)[:-5] if str(scene).endswith(".yaml") else str(scene)
    if name in shipped:
        return shipped[name]
    raise ConfigError(f"scene file '{scene}' does not exist, nor is it the name of a shipped "
                      "scene (poromech scenes lists them)")


def scene_text(scene: str | Path) -> str:
    """The text of a scene file or shipped scene (checked like a scene file is)."""
    path = scene_path(scene)
    return _read_text(path, f"scene file '{scene}'")


def _read_text(path: Path, where: str) -> str:
    """The text of a scene file: at most MAX_SCENE_BYTES of UTF-8."""
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_SCENE_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"{where} does not exist") from None
    except IsADirectoryError:
        raise ConfigError(f"{where} is a directory, not a YAML file") from None
    except OSError as err:
        raise ConfigError(f"{where} cannot be read: {err.strerror or err}") from None
    if len(data) > MAX_SCENE_BYTES:
        raise ConfigError(f"{where} is larger than {MAX_SCENE_BYTES / 1e6:g} MB: not a scene")
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise ConfigError(f"{where} is UTF-16 text: save it as UTF-8")
    if b"\0" in data:
        raise ConfigError(f"{where} is a binary file, not YAML text")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{where} is not UTF-8 text (byte 0x{data[err.start]:02x} at offset "
                          f"{err.start}): save it as UTF-8") from None


class _DuplicateKey(yaml.constructor.ConstructorError):
    """A mapping key given twice."""


class _StrictLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (not last-wins)."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    repeated = key in seen
                except TypeError:  # unhashable: PyYAML reports it
                    continue
                if repeated:
                    raise _DuplicateKey(None, None, f"key {_fmt(key)} is given twice",
                                        key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep)


def _line(err: yaml.YAMLError) -> str:
    mark = getattr(err, "problem_mark", None)
    return f" (line {mark.line + 1})" if mark else ""


def _check_expansion(data: Any, where: str) -> None:
    """Refuse recursive, too deep or alias-multiplied YAML before anything copies it."""
    sizes: dict[int, int] = {}
    active: set[int] = set()

    def size(x: Any, depth: int) -> int:
        if not isinstance(x, dict | list):
            return 1
        key = id(x)
        if key in sizes:
            return sizes[key]
        if key in active:
            raise ConfigError(f"{where} contains itself (a recursive YAML alias)")
        if depth > MAX_SCENE_DEPTH:
            raise ConfigError(f"{where} is nested more than {MAX_SCENE_DEPTH} levels deep")
        active.add(key)
        n = 1 + sum(size(v, depth + 1) for v in (x.values() if isinstance(x, dict) else x))
        active.discard(key)
        if n > MAX_SCENE_VALUES:
            raise ConfigError(f"{where} expands to more than {MAX_SCENE_VALUES:,} values "
                              "(nested YAML aliases?)")
        sizes[key] = n
        return n

    size(data, 0)


def _parse_yaml(text: str, where: str) -> Any:
    """Parse YAML text: safe, no repeated keys, bounded expansion."""
    try:
        data = yaml.load(text, Loader=_StrictLoader)  # noqa: S506 (a SafeLoader subclass)
    except _DuplicateKey as err:
        raise ConfigError(f"{where}: {err.problem}{_line(err)}; give each key once") from None
    except yaml.YAMLError as err:
        raise ConfigError(f"{where} is not valid YAML{_line(err)}") from None
    except RecursionError:
        raise ConfigError(f"{where} is nested too deeply") from None
    _check_expansion(data, where)
    return data


def _read_yaml(path: Path) -> dict:
    where = f"scene file '{path}'"
    data = _parse_yaml(_read_text(path, where), where)
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must contain a mapping of keys")
    return data


def _resolve_geometry(raw: dict) -> dict:
    """Replace ``geometry: <name>`` by the mapping in ``meshes/<name>.yaml``."""
    geo = raw.get("geometry")
    if isinstance(geo, str):
        meshes = importlib.resources.files("poromech.meshes")
        names = sorted(p.name[:-5] for p in meshes.iterdir() if p.name.endswith(".yaml"))
        if geo not in names:
            raise ConfigError(
                f"scene key 'geometry' = {geo!r} is not a known geometry "
                f"(allowed: {', '.join(names)})"
            )
        raw = dict(raw)
        raw["geometry"] = yaml.safe_load(meshes.joinpath(f"{geo}.yaml").read_text())
        raw = absolute_geometry_paths(raw, Path(str(meshes)))
    return raw


def apply_overrides(raw: dict, overrides: Sequence[str]) -> dict:
    """Apply ``dotted.key=value`` overrides (values parsed as YAML) to a raw scene mapping."""
    raw = _deepcopy(raw)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected dotted.key=value")
        key, text = item.split("=", 1)
        value = _parse_yaml(text, f"--set {item!r}: the value")
        parts = key.strip().split(".")
        node: Any = raw
        for i, part in enumerate(parts[:-1]):
            nxt = parts[i + 1]
            _check_container(node, parts[:i], key)
            if isinstance(node, list):
                node = _list_item(node, part, key)
                continue
            if part == "geometry" and isinstance(node.get(part), str):
                node.update(_resolve_geometry({"geometry": node[part]}))
            if not isinstance(node.get(part), dict | list):
                node[part] = [] if nxt.isdigit() else {}
            node = node[part]
        last = parts[-1]
        _check_container(node, parts[:-1], key)
        if isinstance(node, list):
            idx = int(last) if last.isdigit() else None
            if idx is None or idx > len(node):
                raise ConfigError(f"--set {key}: index {last!r} is out of range")
            if idx == len(node):
                node.append(value)
            else:
                node[idx] = value
        else:
            node[last] = value
    return raw


def _check_container(node: Any, parts: list[str], key: str) -> None:
    """Refuse to go into a scalar (``--set boundary_conditions.0.displacement.0.x=1``)."""
    if not isinstance(node, dict | list):
        where = ".".join(parts)
        raise ConfigError(f"--set {key}: '{where}' is {_fmt(node)}, not a mapping or list, so "
                          f"it has no key '{key[len(where) + 1:].split('.')[0]}'")


def _list_item(node: list, part: str, key: str):
    if not part.isdigit() or int(part) >= len(node):
        raise ConfigError(f"--set {key}: index {part!r} is out of range (list of {len(node)})")
    return node[int(part)]


def _deepcopy(x):
    if isinstance(x, dict):
        return {k: _deepcopy(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_deepcopy(v) for v in x]
    return x


class _Builder:
    """Turns a raw mapping into dataclasses, following type hints and field metadata."""

    def __init__(self, parameters: Mapping[str, float]):
        self.parameters = dict(parameters)

    def build(self, value: Any, tp: Any, path: str, meta: Mapping | None = None) -> Any:
        if (meta and _list_type(tp) is not None and value is not None
                and not isinstance(value, list | tuple)):
            if _list_of(tp) is Expression and isinstance(value, int | float | str) \
                    and not isinstance(value, bool):
                value = [value]  # one expression where a list of them is asked: [value]
            else:
                raise ConfigError(f"scene key '{path}' = {_fmt(value)} must be a list: "
                                  f"{meta['doc']}")
        out = self._convert(value, tp, path)
        if meta:
            self._check_range(out, path, meta)
        return out

    def _convert(self, value: Any, tp: Any, path: str) -> Any:
        origin = typing.get_origin(tp)
        args = typing.get_args(tp)
        if origin in (typing.Union, types.UnionType):
            if value is None and type(None) in args:
                return None
            inner = [a for a in args if a is not type(None)]
            for a in inner:  # a value already of one of the member types is kept as it is
                if a in (str, float, int, bool) and type(value) is a:
                    return value
            return self._convert(value, inner[0], path)
        if value is None:
            raise ConfigError(f"scene key '{path}' is null but a value is required")
        if tp is Expression:
            try:
                return compile_expression(value, self.parameters)
            except ExpressionError as err:
                raise ConfigError(f"scene key '{path}' = {_fmt(value)}: {err}") from None
        if tp is float:
            return self._number(value, path)
        if tp is int:
            if isinstance(value, bool) or not (
                isinstance(value, int) or isinstance(value, float) and value.is_integer()
            ):
                raise ConfigError(f"scene key '{path}' = {_fmt(value)} must be an integer")
            return int(value)
        if tp is bool:
            if not isinstance(value, bool):
                raise ConfigError(f"scene key '{path}' = {_fmt(value)} must be true or false")
            return value
        if tp is str:
            if not isinstance(value, str):
                raise ConfigError(f"scene key '{path}' = {_fmt(value)} must be a string")
            return value
        if origin is Literal:
            if value not in args:
                allowed = ", ".join(str(a) for a in args)
                raise ConfigError(f"scene key '{path}' = {_fmt(value)} is not one of: {allowed}")
            return value
        if origin is tuple:
            return self._tuple(value, args, path)
        if origin is dict:
            if not isinstance(value, dict):
                raise ConfigError(f"scene key '{path}' = {_fmt(value)} must be a mapping")
            return {str(k): self._convert(v, args[1], f"{path}.{k}") for k, v in value.items()}
        if dataclasses.is_dataclass(tp):
            return self.dataclass(value, tp, path)
        if tp is type(None):
            raise ConfigError(f"scene key '{path}' must be null")
        raise TypeError(f"unsupported schema type {tp} at {path}")  # pragma: no cover

    def _number(self, value: Any, path: str) -> float:
        if isinstance(value, bool):
            raise ConfigError(f"scene key '{path}' = {_fmt(value)} must be a number")
        if isinstance(value, int | float):
            return float(value)
        if isinstance(value, str):
            try:
                return float(value)
            except ValueError:
                pass
            if value in self.parameters:
                return float(self.parameters[value])
        raise ConfigError(f"scene key '{path}' = {_fmt(value)} must be a number")

    def _tuple(self, value: Any, args: tuple, path: str) -> tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"scene key '{path}' = {_fmt(value)} must be a list")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(self._convert(v, args[0], f"{path}.{i}") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(
                f"scene key '{path}' = {_fmt(value)} must have {len(args)} entries, "
                f"not {len(value)}"
            )
        return tuple(self._convert(v, a, f"{path}.{i}")
                     for i, (v, a) in enumerate(zip(value, args, strict=True)))

    def dataclass(self, value: Any, cls: type, path: str) -> Any:
        prefix = f"{path}." if path else ""
        if not isinstance(value, dict):
            raise ConfigError(f"scene key '{path}' = {_fmt(value)} must be a mapping")
        hints = typing.get_type_hints(cls)
        fields = {f.name: f for f in dataclasses.fields(cls)}
        for key in value:
            if key not in fields:
                allowed = ", ".join(fields)
                raise ConfigError(f"scene key '{prefix}{key}' is unknown (allowed: {allowed})")
        kwargs = {}
        for name, f in fields.items():
            if name in value:
                kwargs[name] = self.build(value[name], hints[name], prefix + name, f.metadata)
            elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"scene key '{prefix}{name}' is required ({f.metadata['doc']})")
        return cls(**kwargs)

    def _check_range(self, value: Any, path: str, meta: Mapping) -> None:
        if value is None:
            return
        if isinstance(value, tuple):
            for i, v in enumerate(value):
                self._check_range(v, f"{path}.{i}", meta)
            return
        if isinstance(value, Expression):
            if not value.is_constant:
                return  # checked on a sample grid once the domain is known
            value = value.value()
        if not isinstance(value, int | float) or isinstance(value, bool):
            return
        _check_number(value, path, meta)


def _list_type(tp: Any) -> Any:
    """The ``tuple[...]`` type of a field, Optional unwrapped, or None."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        tp = inner[0] if len(inner) == 1 else None
    return tp if typing.get_origin(tp) is tuple else None


def _list_of(tp: Any) -> Any:
    """The entry type of a variable-length ``tuple[X, ...]`` field, or None."""
    args = typing.get_args(_list_type(tp))
    return args[0] if len(args) == 2 and args[1] is Ellipsis else None


_RULES = {
    "gt": (lambda v, b: v > b, "> {}"),
    "lt": (lambda v, b: v < b, "< {}"),
    "min": (lambda v, b: v >= b, ">= {}"),
    "max": (lambda v, b: v <= b, "<= {}"),
}


def _check_number(value: float, path: str, meta: Mapping, where: str = "") -> None:
    if not np.isfinite(value):
        raise ConfigError(f"scene key '{path}' = {value}{where} must be finite")
    for rule, (ok, text) in _RULES.items():
        if rule in meta and not ok(value, meta[rule]):
            allowed = text.format(meta[rule])
            raise ConfigError(
                f"scene key '{path}' = {_fmt(value)}{where} is not allowed: must be {allowed}"
            )
    if "choices" in meta and value not in meta["choices"]:
        allowed = ", ".join(str(c) for c in meta["choices"])
        raise ConfigError(f"scene key '{path}' = {_fmt(value)} is not one of: {allowed}")


def plane_geometry(scene: Scene) -> PlaneGeometry:
    """The plane geometry of a scene, with boundary edge names resolved."""
    dom = scene.geometry.domain
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
    fnames = tuple(f.name or str(i + 1) for i, f in enumerate(scene.geometry.fractures))
    return PlaneGeometry(boundary, names, fractures, fnames)


def _check_domain(scene: Scene) -> None:
    dom = scene.geometry.domain
    if (dom.rectangle is None) == (dom.polygon is None):
        raise ConfigError("scene key 'geometry.domain' needs exactly one of rectangle, polygon")
    if dom.rectangle is not None:
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
        for name, edges in dom.boundary_names.items():
            for e in edges:
                if not 0 <= e < n:
                    raise ConfigError(
                        f"scene key 'geometry.domain.boundary_names.{name}' = {list(edges)}: "
                        f"edge {e} does not exist (0..{n - 1})"
                    )
    names = [f.name for f in scene.geometry.fractures if f.name]
    if len(set(names)) != len(names):
        raise ConfigError(f"scene key 'geometry.fractures': fracture names repeat: {names}")


#: Suffixes of the shipped geometry files that scenes may name without a path (``meshes/``).
GEOMETRY_FILE_SUFFIXES = (".msh", ".geo", ".csv")


def _shipped_geometry_files() -> dict[str, Path]:
    """Mesh and fracture files installed with poromech (``meshes/``), by file name."""
    root = importlib.resources.files("poromech.meshes")
    return {p.name: Path(str(p)) for p in sorted(root.iterdir(), key=lambda q: q.name)
            if p.name.endswith(GEOMETRY_FILE_SUFFIXES)}


def _geometry_file(value: str, key: str, base: Path | None = None) -> Path:
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
    raw = _deepcopy(raw)
    for node, key, path in _geometry_file_keys(raw):
        node[key] = str(_geometry_file(node[key], path, base))
    return raw


def _mesh_file_refinement(raw: dict) -> tuple[dict, int | None]:
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
        raise ConfigError(f"scene key 'mesh' = {_fmt(spec)} must be a mapping")
    for key in spec:
        if key != "refinement":
            raise ConfigError(f"scene key 'mesh.{key}' is not allowed with geometry.mesh: the "
                              "element sizes come from the mesh file (allowed: mesh.refinement)")
    level = _Builder({}).build(spec.get("refinement", 0), int, "mesh.refinement",
                               _field_meta(MeshSpec, "refinement"))
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


def _fractures_from_csv(geometry):
    """The geometry with the fractures of its CSV file."""
    from poromech.dfn import FractureFileError, read_fracture_csv

    key = "geometry.fracture_file"
    path = _geometry_file(geometry.fracture_file, key)
    try:
        network = read_fracture_csv(path)
    except FractureFileError as err:
        raise ConfigError(f"scene key '{key}' = {geometry.fracture_file!r}: {err}") from None
    fractures = tuple(FractureSpec(tuple(map(tuple, p.tolist())), name) for name, p in network)
    return dataclasses.replace(geometry, fracture_file=str(path), fractures=fractures)


def _geometry_from_mesh(geometry):
    """The geometry with the domain and fractures of its mesh file; and the file's cell count."""
    from poromech.mesh_import import MeshFileError, import_mesh

    spec = geometry.mesh
    path = _geometry_file(spec.file, "geometry.mesh.file")
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
    fractures = tuple(FractureSpec(tuple(map(tuple, p.tolist())), name)
                      for p, name in zip(geo.fractures, geo.fracture_names, strict=True))
    geometry = dataclasses.replace(geometry, domain=domain, fractures=fractures,
                                   mesh=dataclasses.replace(spec, file=str(path)))
    return geometry, len(imported.arrays.cells)


def _imported_mesh_spec(geometry, cells: int, refinement: int) -> MeshSpec:
    """``mesh`` of a mesh-file scene: its refinement and an equivalent uniform size.

    The size is the one that the memory estimate (:mod:`poromech.resources`) turns into the
    file's number of cells; nothing else uses it.
    """
    from poromech.resources import CELLS_PER_AREA

    p = np.asarray(geometry.domain.polygon)
    area = 0.5 * abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1))
                           - np.dot(p[:, 1], np.roll(p[:, 0], -1))))
    return MeshSpec(size=float(np.sqrt(CELLS_PER_AREA * area / cells)), refinement=refinement)


def _read_geometry_files(scene: Scene, refinement: int | None) -> Scene:
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


def _geometry_source(scene: Scene) -> str:
    """Where a geometric defect is reported: the geometry key, or the file it came from."""
    geometry = scene.geometry
    if geometry.mesh is not None:
        return f"scene key 'geometry.mesh.file' = {Path(geometry.mesh.file).name!r}"
    if geometry.fracture_file is not None:
        return f"scene key 'geometry.fracture_file' = {Path(geometry.fracture_file).name!r}"
    return "scene key 'geometry'"


def _inside(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Mask of the points strictly inside a polygon (crossing number; vectorized)."""
    x, y = points[:, 0], points[:, 1]
    inside = np.zeros(len(points), dtype=bool)
    for a, b in zip(polygon, np.roll(polygon, -1, axis=0), strict=True):
        crosses = (a[1] > y) != (b[1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = a[0] + (y - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
        inside ^= crosses & (x < xc)
    return inside


def _grid_points(geo: PlaneGeometry, n: int = FIELD_GRID) -> np.ndarray:
    """Cell-centred grid points of the bounding box that lie inside the domain, ``(m, 2)``."""
    lo, hi = geo.boundary.min(axis=0), geo.boundary.max(axis=0)
    s = (np.arange(n) + 0.5) / n
    gx, gy = np.meshgrid(lo[0] + s * (hi[0] - lo[0]), lo[1] + s * (hi[1] - lo[1]))
    points = np.column_stack([gx.ravel(), gy.ravel()])
    return points[_inside(points, geo.boundary)]


def _edge_points(geo: PlaneGeometry, name: str, n: int = LINE_SAMPLES) -> np.ndarray:
    """Points along the domain edges called ``name``, their end vertices included."""
    poly = geo.boundary
    s = np.linspace(0.0, 1.0, n)[:, None]
    return np.concatenate([poly[e] + s * (poly[(e + 1) % len(poly)] - poly[e])
                           for e, edge in enumerate(geo.boundary_names) if edge == name])


def _fracture_points(geo: PlaneGeometry, which=None, n: int = LINE_SAMPLES) -> np.ndarray:
    """Points inside the segments of fractures ``which`` (default all): face midpoints lie there.

    Segment end points are excluded (no face has its midpoint there).
    """
    s = ((np.arange(n) + 0.5) / n)[:, None]
    parts = [p[i] + s * (p[i + 1] - p[i]) for k, p in enumerate(geo.fractures)
             if which is None or k in which for i in range(len(p) - 1)]
    return np.concatenate(parts) if parts else np.empty((0, 2))


def _check_times(scene: Scene) -> list[float]:
    """Times at which expressions are checked before meshing: the step times (thinned)."""
    from poromech.stepping import step_times

    times = step_times(scene)
    if len(times) > MAX_CHECK_TIMES:
        keep = np.unique(np.linspace(0, len(times) - 1, MAX_CHECK_TIMES).round().astype(int))
        times = [times[i] for i in keep]
    return times


def check_values(values: np.ndarray, points: np.ndarray, path: str, expr: Expression,
                 meta: Mapping | None = None, t: float | None = None, what: str = "") -> None:
    """Refuse the first point where an expression's values are not finite or out of range.

    Args:
        values: The values at ``points``.
        points: ``(n, 2)`` evaluation points (m).
        path: Scene key of the expression.
        expr: The expression (for its text).
        meta: Field metadata with the checks (``gt``, ``min``, ...).
        t: The time of the values, when it matters (s).
        what: What the points are (e.g. "a cell centre"), for the message.

    Raises:
        ConfigError: One line with the key, the expression, the value and the point.
    """
    values = np.broadcast_to(np.asarray(values, dtype=np.float64), (len(points),))
    bad, rule = ~np.isfinite(values), None
    for name, (ok, text) in _RULES.items():
        if bad.any():
            break
        if meta and name in meta:
            bad, rule = ~ok(values, meta[name]), text.format(meta[name])
    if not bad.any():
        return
    i = int(np.flatnonzero(bad)[0])
    at = f"x={points[i, 0]:g}, y={points[i, 1]:g}" + ("" if t is None else f", t={t:g}")
    at += f" ({what})" if what else ""
    head = f"scene key '{path}' = {_fmt(expr.source)} is {float(values[i]):g} at {at}"
    if rule is None:
        raise ConfigError(f"{head}: must be finite")
    raise ConfigError(f"{head}, not allowed: must be {rule}")


def check_expression(expr: Expression | None, points: np.ndarray, path: str,
                     meta: Mapping | None, times, what: str = "") -> None:
    """Check an expression at points and times (one point if uniform, one time if static).

    Raises:
        ConfigError: See :func:`check_values`.
    """
    if expr is None or not len(points):
        return
    pts = points[:1] if expr.is_uniform else points
    for t in (times if expr.depends_on_time else times[:1]):
        values = expr(pts[:, 0], pts[:, 1], t)
        check_values(values, pts, path, expr, meta, t if expr.depends_on_time else None, what)


def _check_field(expr: Expression | None, path: str, meta: Mapping, geo, times) -> None:
    """Check a space/time-dependent field on a grid of points inside the domain."""
    check_expression(expr, _grid_points(geo), path, meta, times)


def _field_meta(cls, name) -> Mapping:
    return {f.name: f for f in dataclasses.fields(cls)}[name].metadata


def check_boundary_name(key: str, name: str, known: set[str]) -> None:
    """Reject a boundary name that no domain edge has."""
    if name not in known:
        raise ConfigError(f"scene key '{key}' = {name!r} is not a boundary "
                          f"(allowed: {', '.join(sorted(known))})")


def _check_mechanics(scene: Scene, geo: PlaneGeometry) -> None:
    from poromech.scene import Material

    for key in ("geometry", "mesh", "material"):
        if getattr(scene, key) is None:
            raise ConfigError(f"scene key '{key}' is required for physics 'mechanics'")
    c = scene.contact
    if c.slip_bound is not None and not c.slip_bound.is_uniform:
        raise ConfigError(f"scene key 'contact.slip_bound' = {_fmt(c.slip_bound.source)} is not "
                          "allowed: the Tresca slip bound must not depend on x or y (a number, "
                          "or an expression in t)")
    if c.friction == "tresca" and c.slip_bound is None:
        raise ConfigError(
            "scene key 'contact.slip_bound' is required when contact.friction is tresca"
        )
    times = _check_times(scene)
    for name in ("young", "poisson"):
        _check_field(getattr(scene.material, name), f"material.{name}",
                     _field_meta(Material, name), geo, times)
    known = set(geo.boundary_names)
    fixed = [False, False]
    for i, bc in enumerate(scene.boundary_conditions):
        path = f"boundary_conditions.{i}"
        check_boundary_name(f"{path}.boundary", bc.boundary, known)
        if (bc.displacement is None) == (bc.traction is None):
            raise ConfigError(f"scene key '{path}' needs exactly one of displacement, traction")
        if bc.displacement is not None:
            for k, comp in enumerate(bc.displacement):
                fixed[k] |= comp is not None
    if not all(fixed):
        comp = "xy"[fixed.index(False)]
        raise ConfigError(
            f"scene key 'boundary_conditions': no displacement {comp} is imposed anywhere "
            "(rigid body motion); add a displacement condition"
        )
    _check_mechanics_data(scene, geo, times)


def _check_mechanics_data(scene: Scene, geo: PlaneGeometry, times) -> None:
    """Check the mechanical data where the solver will evaluate them (before meshing).

    Body force on the domain grid, boundary data along their edges (vertices included), fracture
    pressure and slip bound along the fractures.
    """
    from poromech.scene import Contact

    grid = _grid_points(geo)
    for k, e in enumerate(scene.material.body_force):
        check_expression(e, grid, f"material.body_force.{k}", None, times)
    for i, bc in enumerate(scene.boundary_conditions):
        points = _edge_points(geo, bc.boundary)
        for kind in ("displacement", "traction"):
            for k, e in enumerate(getattr(bc, kind) or ()):
                check_expression(e, points, f"boundary_conditions.{i}.{kind}.{k}", None, times)
    points = _fracture_points(geo)
    check_expression(scene.fracture_pressure, points, "fracture_pressure", None, times)
    check_expression(scene.contact.slip_bound, points, "contact.slip_bound",
                _field_meta(Contact, "slip_bound"), times)


def _check_flow(scene: Scene, geo: PlaneGeometry) -> None:
    """Validate a flow scene (physics ``flow``): every failure is a one-line ConfigError."""
    from poromech.scene import Flow, FractureFlow

    flow = scene.flow
    if flow is None:
        raise ConfigError("scene key 'flow' is required for physics 'flow'")
    if scene.mesh is None:
        raise ConfigError("scene key 'mesh' is required for physics 'flow'")
    times = _check_times(scene)
    _check_flow_permeability(flow.permeability, geo, times)
    _check_field(flow.source, "flow.source", _field_meta(Flow, "source"), geo, times)
    if scene.time is not None:  # the initial state of a transient run
        _check_field(flow.initial_pressure, "flow.initial_pressure",
                     _field_meta(Flow, "initial_pressure"), geo, [0.0])
    for name, override in _FRACTURE_DEFAULTS.items():
        kept = {ff.fracture for ff in flow.fractures if getattr(ff, override, None) is not None}
        which = [k for k, n in enumerate(geo.fracture_names) if n not in kept]
        check_expression(getattr(flow, name), _fracture_points(geo, which), f"flow.{name}",
                    _field_meta(Flow, name), times)
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
        points = _fracture_points(geo, [geo.fracture_names.index(ff.fracture)])
        for name in ("aperture", "permeability", "normal_permeability", "conductivity"):
            check_expression(getattr(ff, name), points, f"{path}.{name}",
                        _field_meta(FractureFlow, name), times)
    _check_flow_boundaries(scene, geo)
    _check_probes(scene, geo)


#: Fracture fields of ``flow`` and the ``flow.fractures`` entry overriding each on one fracture.
_FRACTURE_DEFAULTS = {
    "aperture": "aperture",
    "fracture_permeability": "permeability",
    "fracture_normal_permeability": "normal_permeability",
    "fracture_conductivity": "conductivity",
    "fracture_source": "",
}


def _check_flow_permeability(perm, geo: PlaneGeometry, times) -> None:
    """Permeability: 1, 2 or 3 components forming an SPD tensor everywhere."""
    allowed = "[k], [k_xx, k_yy] or [k_xx, k_xy, k_yy]"
    if len(perm) not in (1, 2, 3):
        raise ConfigError(f"scene key 'flow.permeability' has {len(perm)} entries "
                          f"(allowed: {allowed})")
    check_permeability(perm, _grid_points(geo), times)


def check_permeability(perm, points: np.ndarray, times, what: str = "") -> None:
    """Refuse the first point where the permeability tensor is not finite and SPD."""
    x, y = points[:, 0], points[:, 1]
    steps = times if any(e.depends_on_time for e in perm) else times[:1]
    for t in steps:
        k = [np.broadcast_to(e(x, y, t), x.shape) for e in perm]
        kxx, kyy = k[0], k[-1]
        det = kxx * kyy - (k[1] ** 2 if len(k) == 3 else 0.0)
        bad = ~(np.isfinite(det) & (kxx > 0) & (kyy > 0) & (det > 0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            value = [float(c[i]) for c in k]
            where = f" ({what})" if what else ""
            raise ConfigError(
                f"scene key 'flow.permeability' = {value} at x={x[i]:g}, y={y[i]:g}{where} is "
                "not allowed: must be positive definite (k_xx > 0, k_yy > 0, k_xx k_yy > k_xy²)"
            )


def _check_flow_boundaries(scene: Scene, geo: PlaneGeometry) -> None:
    """Boundary names, one of pressure/flux each, and a pressure condition when needed."""
    flow = scene.flow
    known = set(geo.boundary_names)
    used: set[str] = set()
    for i, bc in enumerate(flow.boundary_conditions):
        path = f"flow.boundary_conditions.{i}"
        check_boundary_name(f"{path}.boundary", bc.boundary, known)
        if bc.boundary in used:
            raise ConfigError(f"scene key '{path}.boundary' = {bc.boundary!r} already has a "
                              "flow condition (one per boundary)")
        used.add(bc.boundary)
        if (bc.pressure is None) == (bc.flux is None):
            raise ConfigError(f"scene key '{path}' needs exactly one of pressure, flux")
        points, times = _edge_points(geo, bc.boundary), _check_times(scene)
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
    """Refuse a name that becomes part of a file name unless it is a plain name."""
    if not _FILE_NAME.fullmatch(name):
        raise ConfigError(f"scene key '{key}' = {name!r} is not allowed: use letters, digits, "
                          "'_', '-' or '.' (starting with a letter or digit); it names files")


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
        if np.allclose(probe.start, probe.end, rtol=0.0, atol=0.0):
            raise ConfigError(f"scene key '{path}.end' = {list(probe.end)} equals start: "
                              "a probe line needs two distinct points")
        if not segment_meets_polygon(np.array(probe.start), np.array(probe.end), geo.boundary):
            log.warning("probe '%s' (scene key '%s') lies entirely outside the domain: "
                        "probe_%s.csv will have no values", probe.name, path, probe.name)


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


def _check_poromechanics(scene: Scene) -> None:
    """What a coupled scene needs beyond a mechanics and a flow scene."""
    if scene.fracture_pressure is not None:
        raise ConfigError("scene key 'fracture_pressure' is not allowed for physics "
                          "'poromechanics': the fracture pressure is computed by the flow")


def scene_from_dict(raw: Mapping) -> Scene:
    """Validate a raw scene mapping and build the :class:`Scene` (no meshing)."""
    raw = _resolve_geometry(dict(raw))
    raw, refinement = _mesh_file_refinement(raw)
    params = raw.get("parameters", {}) or {}
    if not isinstance(params, dict):
        raise ConfigError(f"scene key 'parameters' = {_fmt(params)} must be a mapping")
    builder = _Builder({})
    numeric = {str(k): builder.build(v, float, f"parameters.{k}") for k, v in params.items()}
    for name in numeric:
        if name in ("x", "y", "t") or not name.isidentifier():
            raise ConfigError(f"scene key 'parameters.{name}' is not a usable name")
    scene = _Builder(numeric).dataclass(raw, Scene, "")
    check_name("name", scene.name)
    _check_petsc_keys(scene)
    if scene.geometry is None:
        raise ConfigError("scene key 'geometry' is required")
    scene = _read_geometry_files(scene, refinement)
    _check_domain(scene)
    geo = plane_geometry(scene)
    try:
        check_geometry(geo)
    except GeometryError as err:
        raise ConfigError(f"{_geometry_source(scene)}: {err}") from None
    _check_time(scene)
    if scene.physics in ("mechanics", "poromechanics"):
        _check_mechanics(scene, geo)
    if scene.physics in ("flow", "poromechanics"):
        _check_flow(scene, geo)
    if scene.physics == "poromechanics":
        _check_poromechanics(scene)
    return scene


def load_scene(path: str | Path | None = None, overrides: Sequence[str] = ()) -> Scene:
    """Read, override and validate a scene (the embedded default when ``path`` is None)."""
    return load_scene_and_raw(path, overrides)[0]


def load_scene_and_raw(path: str | Path | None = None,
                       overrides: Sequence[str] = ()) -> tuple[Scene, dict]:
    """The validated scene and the mapping it was built from (after the overrides)."""
    file = scene_path(path) if path is not None else default_scene_path()
    raw = apply_overrides(_read_yaml(file), overrides)
    raw = absolute_geometry_paths(raw, file.resolve().parent)
    return scene_from_dict(raw), raw
