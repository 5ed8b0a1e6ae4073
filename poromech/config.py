"""Scene files: YAML → validated :class:`poromech.scene.Scene`, with ``--set`` overrides.

All checks run here, before any meshing or solving: unknown keys, wrong types, out-of-range
values, and geometric defects. Every failure is a :class:`ConfigError` whose message is one line
naming the key, the value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from poromech.expressions import Expression, ExpressionError, compile_expression
from poromech.geometry import GeometryError, PlaneGeometry, check_geometry
from poromech.scene import Scene

__all__ = [
    "ConfigError",
    "apply_overrides",
    "default_scene_path",
    "load_scene",
    "plane_geometry",
    "scene_from_dict",
]

#: The embedded scene run by ``poromech run`` without a scene file.
DEFAULT_SCENE = "six_fractures_mechanics.yaml"

RECTANGLE_EDGES = ("bottom", "right", "top", "left")


class ConfigError(ValueError):
    """An invalid scene; the message is a single line."""


def _fmt(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def default_scene_path() -> Path:
    """Path of the embedded default scene."""
    return Path(str(importlib.resources.files("poromech.configs").joinpath(DEFAULT_SCENE)))


def _read_yaml(path: Path) -> dict:
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"scene file '{path}' does not exist") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark else ""
        raise ConfigError(f"scene file '{path}' is not valid YAML{where}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"scene file '{path}' must contain a mapping of keys")
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
    return raw


def apply_overrides(raw: dict, overrides: Sequence[str]) -> dict:
    """Apply ``dotted.key=value`` overrides (values parsed as YAML) to a raw scene mapping."""
    raw = _deepcopy(raw)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected dotted.key=value")
        key, text = item.split("=", 1)
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError:
            raise ConfigError(f"--set {item!r}: the value is not valid YAML") from None
        parts = key.strip().split(".")
        node: Any = raw
        for i, part in enumerate(parts[:-1]):
            nxt = parts[i + 1]
            if isinstance(node, list):
                node = _list_item(node, part, key)
                continue
            if part == "geometry" and isinstance(node.get(part), str):
                node.update(_resolve_geometry({"geometry": node[part]}))
            if not isinstance(node.get(part), dict | list):
                node[part] = [] if nxt.isdigit() else {}
            node = node[part]
        last = parts[-1]
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


def _sample_points(geo: PlaneGeometry) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = geo.boundary.min(axis=0), geo.boundary.max(axis=0)
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], 41), np.linspace(lo[1], hi[1], 41))
    return gx.ravel(), gy.ravel()


def _check_field(expr: Expression | None, path: str, meta: Mapping, geo, times) -> None:
    """Check a space/time-dependent expression on a sample grid of the domain box."""
    if expr is None or expr.is_constant:
        return
    x, y = _sample_points(geo)
    for t in times:
        values = expr(x, y, t)
        bad = ~np.isfinite(values)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ConfigError(
                f"scene key '{path}' = {_fmt(expr.source)} is not finite at x={x[i]:g}, y={y[i]:g}"
            )
        for rule, (ok, _) in _RULES.items():
            if rule in meta:
                fails = ~ok(values, meta[rule])
                if fails.any():
                    i = int(np.flatnonzero(fails)[0])
                    _check_number(float(values[i]), path, meta, f" (at x={x[i]:g}, y={y[i]:g})")


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
    if c.friction == "tresca" and c.slip_bound is None:
        raise ConfigError(
            "scene key 'contact.slip_bound' is required when contact.friction is tresca"
        )
    times = [0.0] if scene.time is None else np.linspace(0, scene.time.final, 5)
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


def _check_flow(scene: Scene, geo: PlaneGeometry) -> None:
    """Validate a flow scene (physics ``flow``): every failure is a one-line ConfigError."""
    from poromech.scene import Flow, FractureFlow

    flow = scene.flow
    if flow is None:
        raise ConfigError("scene key 'flow' is required for physics 'flow'")
    if scene.mesh is None:
        raise ConfigError("scene key 'mesh' is required for physics 'flow'")
    times = [0.0] if scene.time is None else np.linspace(0, scene.time.final, 5)
    _check_flow_permeability(flow.permeability, geo, times)
    fields = ("aperture", "fracture_permeability", "fracture_normal_permeability",
              "fracture_conductivity", "source", "fracture_source", "initial_pressure")
    for name in fields:
        _check_field(getattr(flow, name), f"flow.{name}", _field_meta(Flow, name), geo, times)
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
        for name in ("aperture", "permeability", "normal_permeability", "conductivity"):
            _check_field(getattr(ff, name), f"{path}.{name}", _field_meta(FractureFlow, name),
                         geo, times)
    _check_flow_boundaries(scene, geo)
    _check_flow_petsc(flow.petsc)
    _check_probes(scene)


def _check_flow_permeability(perm, geo: PlaneGeometry, times) -> None:
    """Permeability: 1, 2 or 3 components forming an SPD tensor everywhere."""
    allowed = "[k], [k_xx, k_yy] or [k_xx, k_xy, k_yy]"
    if len(perm) not in (1, 2, 3):
        raise ConfigError(f"scene key 'flow.permeability' has {len(perm)} entries "
                          f"(allowed: {allowed})")
    x, y = _sample_points(geo)
    for t in times:
        k = [np.broadcast_to(e(x, y, t), x.shape) for e in perm]
        kxx, kyy = k[0], k[-1]
        det = kxx * kyy - (k[1] ** 2 if len(k) == 3 else 0.0)
        bad = ~(np.isfinite(det) & (kxx > 0) & (kyy > 0) & (det > 0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            value = [float(c[i]) for c in k]
            raise ConfigError(
                f"scene key 'flow.permeability' = {value} at x={x[i]:g}, y={y[i]:g} is not "
                "allowed: must be positive definite (k_xx > 0, k_yy > 0, k_xx k_yy > k_xy²)"
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
    transient_storage = scene.time is not None and flow.biot_modulus is not None
    if not transient_storage and all(bc.pressure is None for bc in flow.boundary_conditions):
        raise ConfigError(
            "scene key 'flow.boundary_conditions' has no pressure condition: the pressure is not "
            "unique without one (allowed: add a pressure condition, or time with biot_modulus)"
        )


def _check_flow_petsc(options: Mapping) -> None:
    """PETSc option names are given without the dash and without the flow_ prefix."""
    for key in options:
        if key.startswith("-") or key.startswith("flow_"):
            raise ConfigError(f"scene key 'flow.petsc.{key}' is not allowed: give the option "
                              f"without '-' and without the flow_ prefix (e.g. ksp_rtol)")


def _check_probes(scene: Scene) -> None:
    """Probe names are unique and usable in file names; lines have a length."""
    names: set[str] = set()
    for i, probe in enumerate(scene.probes):
        path = f"probes.{i}"
        if not probe.name[:1].isalnum() or not all(c.isalnum() or c in "_-." for c in probe.name):
            raise ConfigError(f"scene key '{path}.name' = {probe.name!r} is not allowed: "
                              "use letters, digits, '_', '-' or '.' (starting with a letter "
                              "or digit)")
        if probe.name in names:
            raise ConfigError(f"scene key '{path}.name' = {probe.name!r} repeats")
        names.add(probe.name)
        if np.allclose(probe.start, probe.end, rtol=0.0, atol=0.0):
            raise ConfigError(f"scene key '{path}.end' = {list(probe.end)} equals start: "
                              "a probe line needs two distinct points")


def scene_from_dict(raw: Mapping) -> Scene:
    """Validate a raw scene mapping and build the :class:`Scene` (no meshing)."""
    raw = _resolve_geometry(dict(raw))
    params = raw.get("parameters", {}) or {}
    if not isinstance(params, dict):
        raise ConfigError(f"scene key 'parameters' = {_fmt(params)} must be a mapping")
    builder = _Builder({})
    numeric = {str(k): builder.build(v, float, f"parameters.{k}") for k, v in params.items()}
    for name in numeric:
        if name in ("x", "y", "t") or not name.isidentifier():
            raise ConfigError(f"scene key 'parameters.{name}' is not a usable name")
    scene = _Builder(numeric).dataclass(raw, Scene, "")
    if scene.geometry is None:
        raise ConfigError("scene key 'geometry' is required")
    _check_domain(scene)
    geo = plane_geometry(scene)
    try:
        check_geometry(geo)
    except GeometryError as err:
        raise ConfigError(f"scene key 'geometry': {err}") from None
    if scene.physics == "mechanics":
        _check_mechanics(scene, geo)
    else:
        _check_flow(scene, geo)
    return scene


def load_scene(path: str | Path | None = None, overrides: Sequence[str] = ()) -> Scene:
    """Read, override and validate a scene (the embedded default when ``path`` is None)."""
    raw = _read_yaml(Path(path) if path is not None else default_scene_path())
    return scene_from_dict(apply_overrides(raw, overrides))
