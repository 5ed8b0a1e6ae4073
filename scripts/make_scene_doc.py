"""Generate ``docs/scene_schema.md`` from the scene dataclasses (units, defaults, checks).

Run::

    python scripts/make_scene_doc.py
"""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path

from poromech.expressions import Expression
from poromech.scene import Scene

ROOT = Path(__file__).resolve().parents[1]


def type_name(tp) -> str:
    """Readable name of a schema type."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [type_name(a) for a in args if a is not type(None)]
        return " or ".join(inner) + (" or null" if type(None) in args else "")
    if origin is typing.Literal:
        return " \\| ".join(str(a) for a in args)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {type_name(args[0])}"
        return "[" + ", ".join(type_name(a) for a in args) + "]"
    if origin is dict:
        return f"mapping of {type_name(args[1])}"
    if tp is Expression:
        return "expr"
    if dataclasses.is_dataclass(tp):
        return "mapping (below)" if tp is not Scene else "scene"
    return getattr(tp, "__name__", str(tp))


def default_text(f: dataclasses.Field) -> str:
    """The documented default of a field."""
    if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
        return "**required**"
    value = f.default if f.default is not dataclasses.MISSING else f.default_factory()
    if dataclasses.is_dataclass(value):
        return "(defaults below)"
    if isinstance(value, Expression):
        return str(value.source)
    if isinstance(value, tuple) and value and isinstance(value[0], Expression):
        return "[" + ", ".join(str(v.source) for v in value) + "]"
    return "null" if value is None else repr(value) if not isinstance(value, str) else value


def checks(meta: dict) -> str:
    """Allowed values from the field metadata."""
    out = []
    for key, sym in (("gt", ">"), ("lt", "<"), ("min", "≥"), ("max", "≤")):
        if key in meta:
            out.append(f"{sym} {meta[key]}")
    if "choices" in meta:
        out.append("one of " + ", ".join(str(c) for c in meta["choices"]))
    return "; ".join(out)


def nested(tp):
    """Dataclass types referenced by a field type."""
    if dataclasses.is_dataclass(tp):
        return [tp]
    return [t for a in typing.get_args(tp) for t in nested(a)]


def section(cls, path: str, seen: set) -> list[str]:
    """Table of one dataclass and, recursively, the ones it references."""
    hints = typing.get_type_hints(cls)
    title = path or "top level"
    lines = [f"## `{title}`", "", (cls.__doc__ or "").strip().splitlines()[0], "",
             "| key | type | unit | default | allowed | meaning |", "|---|---|---|---|---|---|"]
    children = []
    for f in dataclasses.fields(cls):
        meta = f.metadata
        lines.append(f"| `{f.name}` | {type_name(hints[f.name])} | {meta.get('unit', '')} | "
                     f"{default_text(f)} | {checks(meta)} | {meta.get('doc', '')} |")
        for sub in nested(hints[f.name]):
            if sub not in seen:
                seen.add(sub)
                children.append((sub, f"{path}.{f.name}" if path else f.name))
    lines.append("")
    for sub, p in children:
        lines += section(sub, p, seen)
    return lines


def main() -> None:
    lines = [
        "# Scene file reference",
        "",
        "Generated from `poromech/scene.py` by `python scripts/make_scene_doc.py`. A scene is a "
        "YAML mapping; unknown keys, wrong types and out-of-range values are rejected with a "
        "one-line message before any meshing. SI units throughout.",
        "",
        "**Expressions** (`expr`): a number or a string in `x`, `y` (m), `t` (s) and the scene "
        "`parameters`, with `+ - * / ** %`, comparisons, `and`/`or`, and the functions `sin cos "
        "tan arcsin arccos arctan arctan2 sinh cosh tanh exp log log10 sqrt abs min max where "
        "clip hypot radians degrees`, plus the exact fields `sneddon_ux/uy(x, y, a, p, E, nu)` "
        "and `inclined_crack_ux/uy(x, y, b, psi, sigma, F, E, nu)` of `poromech.analytic`. "
        "Numbers written `4e9` (which YAML reads as text) are accepted.",
        "",
        "**Overrides**: `poromech run scene.yaml --set contact.formulation=mixed --set "
        "boundary_conditions.1.displacement=[0.001,0]` (values are parsed as YAML; list items "
        "by index). **PETSc options**: `solver.petsc` / `flow.petsc` in the scene (without the "
        "`mech_` / `flow_` prefix), or on the command line with it (`-mech_snes_monitor`), "
        "which wins.",
        "",
    ]
    lines += section(Scene, "", {Scene})
    out = ROOT / "docs" / "scene_schema.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
