"""Scene files: YAML → validated :class:`~poromech.scene.schema.Scene`, with ``--set`` overrides.

All checks run before any meshing or solving: unknown keys, wrong types and out-of-range values
(:mod:`poromech.scene.builder`), the geometry (:mod:`poromech.scene.geometry`) and the physics
data (:mod:`poromech.scene.checks`). Every failure is a :class:`~poromech.errors.ConfigError`
whose message is one line naming the key, the value and what is allowed.
"""

from __future__ import annotations

import importlib.resources
import keyword
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from poromech.errors import ConfigError
from poromech.geometry.box import BoxGeometry, check_box_geometry
from poromech.geometry.plane import GeometryError, check_geometry
from poromech.scene.builder import Builder, deep_copy, format_value
from poromech.scene.checks import check_name, check_scene
from poromech.scene.expressions import reserved_names
from poromech.scene.geometry import (
    absolute_geometry_paths,
    check_domain,
    geometry_source,
    mesh_file_refinement,
    mesh_sizes,
    read_geometry_files,
    scene_geometry,
)
from poromech.scene.schema import Scene
from poromech.scene.usage import check_keys_used

__all__ = [
    "apply_overrides",
    "default_scene_path",
    "load_scene",
    "load_scene_and_raw",
    "parse_yaml",
    "scene_from_dict",
    "scene_path",
    "scene_text",
    "shipped_scenes",
]


#: The embedded scene run by ``poromech run`` without a scene file.
DEFAULT_SCENE = "six_fractures.yaml"


#: Largest scene file read (bytes): a scene is a page of text, not a data file.
MAX_SCENE_BYTES = 1_000_000


#: Most values a scene may expand to. YAML aliases repeat a node without copying it, so a small
#: file of nested aliases (a "billion laughs") stands for ~10⁹ values; it is refused before
#: anything copies it.
MAX_SCENE_VALUES = 1_000_000


#: Deepest nesting of a scene's lists and mappings.
MAX_SCENE_DEPTH = 64


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
                try:  # (a set is looked up as a frozenset, but cannot be added)
                    repeated = key in seen
                    seen.add(key)
                except TypeError:  # unhashable: PyYAML reports it
                    continue
                if repeated:
                    raise _DuplicateKey(None, None, f"key {format_value(key)} is given twice",
                                        key_node.start_mark)
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


def parse_yaml(text: str, where: str) -> Any:
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
    data = parse_yaml(_read_text(path, where), where)
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must contain a mapping of keys")
    return data


def resolve_geometry(raw: dict) -> dict:
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
    raw = deep_copy(raw)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected dotted.key=value")
        key, text = item.split("=", 1)
        value = parse_yaml(text, f"--set {item!r}: the value")
        parts = key.strip().split(".")
        if not all(parts):
            raise ConfigError(f"--set {item!r}: the key has an empty part (allowed: "
                              "dotted.key=value, e.g. mesh.size=0.1)")
        node: Any = raw
        for i, part in enumerate(parts[:-1]):
            nxt = parts[i + 1]
            _check_container(node, parts[:i], key)
            if isinstance(node, list):
                node = _list_item(node, part, key)
                continue
            if part == "geometry" and isinstance(node.get(part), str):
                node.update(resolve_geometry({"geometry": node[part]}))
            if not isinstance(node.get(part), dict | list):
                node[part] = [] if nxt.isdigit() else {}
            node = node[part]
        last = parts[-1]
        _check_container(node, parts[:-1], key)
        if isinstance(node, list):
            idx = int(last) if last.isdigit() else None
            if idx is None:
                raise ConfigError(f"--set {key}: {last!r} is not an index of a list of "
                                  f"{len(node)} (allowed: 0..{len(node)})")
            if idx > len(node):
                raise ConfigError(f"--set {key}: index {last!r} is out of range (allowed: "
                                  f"0..{len(node)}; {len(node)} appends)")
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
        raise ConfigError(f"--set {key}: '{where}' is {format_value(node)}, not a mapping or "
                          "list, so "
                          f"it has no key '{key[len(where) + 1:].split('.')[0]}'")


def _list_item(node: list, part: str, key: str):
    allowed = f"allowed: 0..{len(node) - 1}" if node else "the list is empty"
    if not part.isdigit():
        raise ConfigError(f"--set {key}: {part!r} is not an index of a list of {len(node)} "
                          f"({allowed})")
    if int(part) >= len(node):
        raise ConfigError(f"--set {key}: index {part!r} is out of range (list of {len(node)}; "
                          f"{allowed})")
    return node[int(part)]


def scene_from_dict(raw: Mapping) -> Scene:
    """Validate a raw scene mapping and build the :class:`Scene` (no meshing)."""
    raw = resolve_geometry(dict(raw))
    raw, refinement = mesh_file_refinement(raw)
    params = raw.get("parameters", {}) or {}
    if not isinstance(params, dict):
        raise ConfigError(f"scene key 'parameters' = {format_value(params)} must be a mapping")
    for name in params:
        if not isinstance(name, str) or not name.isidentifier() or keyword.iskeyword(name):
            raise ConfigError(f"scene key 'parameters.{name}' is not a usable name (allowed: a "
                              "name of letters, digits and _, not a Python keyword)")
        if name in reserved_names():
            raise ConfigError(f"scene key 'parameters.{name}' would hide the variable, constant "
                              f"or function {name!r} of expressions (allowed: another name)")
    numeric: dict[str, float] = {}
    for k, v in params.items():  # each one may use those above it
        numeric[k] = Builder(numeric).build(v, float, f"parameters.{k}")
    scene = Builder(numeric).dataclass(raw, Scene, "")
    check_name("name", scene.name)
    if scene.geometry is None:
        raise ConfigError("scene key 'geometry' is required")
    scene = read_geometry_files(scene, refinement)
    check_domain(scene)
    try:
        geo = scene_geometry(scene)
        if isinstance(geo, BoxGeometry):
            sizes = mesh_sizes(scene) if scene.mesh is not None else None
            # the size the mesh has on the fractures: gmsh takes the smaller of the two (a
            # fracture_size above size refused a disc 0.2 m from a face for 0.41 m / 2)
            check_box_geometry(geo, min(sizes.fracture_size, sizes.size) if sizes else None)
        else:
            check_geometry(geo)
    except GeometryError as err:
        raise ConfigError(f"{geometry_source(scene)}: {err}") from None
    except (OverflowError, FloatingPointError, ZeroDivisionError) as err:
        raise ConfigError(f"{geometry_source(scene)}: its numbers are beyond what double "
                          f"precision computes with ({type(err).__name__} in its checks; "
                          "allowed: sizes and coordinates of a rock mass in metres)") from None
    check_scene(scene, geo)
    check_keys_used(scene, raw, geo)
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
