"""Generate ``docs/scene_schema.md`` from the scene dataclasses (units, defaults, checks).

Everything in the reference comes from the code the loader runs: the keys, types, defaults and
checks from :mod:`poromech.scene.schema` (the classes :mod:`poromech.scene` builds), the expression
functions from :mod:`poromech.scene.expressions`, the limits from :mod:`poromech.scene`. A test
(``tests/test_config.py``) checks that the file is up to date and that every documented key is
accepted by the loader.

Run::

    python scripts/make_scene_doc.py
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import types
import typing
from pathlib import Path

from poromech.scene import expressions
from poromech.scene import loading as config
from poromech.scene.expressions import Expression
from poromech.scene.schema import Scene

ROOT = Path(__file__).resolve().parents[1]
OUTPUT = ROOT / "docs" / "scene_schema.md"


def geometry_names() -> list[str]:
    """Names accepted for ``geometry:`` (files of ``poromech.meshes``)."""
    meshes = importlib.resources.files("poromech.meshes")
    return sorted(p.name[:-5] for p in meshes.iterdir() if p.name.endswith(".yaml"))


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
            item = type_name(args[0])
            return f"list of ({item})" if " or " in item else f"list of {item}"
        return "[" + ", ".join(type_name(a) for a in args) + "]"
    if origin is dict:
        return f"mapping of {type_name(args[1])}"
    if tp is Expression:
        return "expr"
    if dataclasses.is_dataclass(tp):
        return "mapping (below)" if tp is not Scene else "scene"
    return getattr(tp, "__name__", str(tp))


def field_type(path: str, f: dataclasses.Field, tp) -> str:
    """The type column; ``geometry`` also takes the name of a shipped geometry."""
    text = type_name(tp)
    if path == "" and f.name == "geometry":
        text = text.replace(" or null", f", a name ({', '.join(geometry_names())}) or null")
    return text


def default_text(f: dataclasses.Field) -> str:
    """The documented default of a field."""
    if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
        return "**required**"
    value = f.default if f.default is not dataclasses.MISSING else f.default_factory()
    if isinstance(value, Expression):
        return str(value.source)
    if dataclasses.is_dataclass(value):
        return "(defaults below)"
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


def nested(tp) -> list:
    """Scene dataclasses referenced by a field type (an ``Expression`` is a value, not a table)."""
    if tp is Expression:
        return []
    if dataclasses.is_dataclass(tp):
        return [tp]
    return [t for a in typing.get_args(tp) for t in nested(a)]


def is_list(tp) -> bool:
    """Whether a field holds a list of mappings (``tuple[X, ...]``)."""
    args = [a for a in typing.get_args(tp) if a is not type(None)]
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return any(is_list(a) for a in args)
    return typing.get_origin(tp) is tuple and len(args) == 2 and args[1] is Ellipsis


def section(cls, path: str, seen: set) -> list[str]:
    """Table of one dataclass and, recursively, the ones it references.

    List items are titled ``key[i]``: ``--set boundary_conditions.0.boundary=top`` sets key
    ``boundary`` of item 0.
    """
    hints = typing.get_type_hints(cls)
    title = path or "top level"
    lines = [f"## `{title}`", "", (cls.__doc__ or "").strip().splitlines()[0], "",
             "| key | type | unit | default | allowed | meaning |", "|---|---|---|---|---|---|"]
    children = []
    for f in dataclasses.fields(cls):
        meta = f.metadata
        tp = hints[f.name]
        lines.append(f"| `{f.name}` | {field_type(path, f, tp)} | {meta.get('unit', '')} | "
                     f"{default_text(f)} | {checks(meta)} | {meta.get('doc', '')} |")
        for sub in nested(tp):
            if sub not in seen:
                seen.add(sub)
                child = f"{path}.{f.name}" if path else f.name
                children.append((sub, child + ("[i]" if is_list(tp) else "")))
    lines.append("")
    for sub, p in children:
        lines += section(sub, p, seen)
    return lines


def header() -> list[str]:
    """What applies to every scene: the file, expressions, names, overrides, PETSc options."""
    functions = ", ".join(f"`{s}`" for s in expressions.function_signatures())
    return [
        "# Scene file reference",
        "",
        "Generated from `poromech/scene/schema.py` by `python scripts/make_scene_doc.py`: the "
        "tables "
        "list exactly the keys the loader accepts. A scene is a YAML mapping in a UTF-8 file of "
        f"at most {config.MAX_SCENE_BYTES / 1e6:g} MB. Unknown keys, a key given twice, wrong "
        "types and out-of-range values are rejected with a one-line message (exit status 2) "
        "before any meshing; so are YAML aliases that expand to more than "
        f"{config.MAX_SCENE_VALUES:,} values or nest more than {config.MAX_SCENE_DEPTH} "
        "levels. SI units throughout. A shipped scene is given by its name "
        "(`poromech run sneddon`; `poromech scenes` lists them, `poromech show NAME` prints "
        "one).",
        "",
        "**Expressions** (`expr`): a number or a string in `x`, `y`, `z` (m; `z` is 0 in 2D), "
        "`t` (s), the scene "
        "`parameters` and `pi`, `e`, with `+ - * / ** %`, comparisons, `and`/`or`, and the "
        f"functions {functions} (the last six are the exact fields of `poromech.analytic`), at "
        f"most {expressions.MAX_LENGTH} characters and {expressions.MAX_DEPTH} levels of "
        "nesting. Numbers written `4e9` (which YAML reads as text) are accepted. Every "
        "expression must be finite, and within the `allowed` range of its key, wherever it is "
        "used and at every step time: before meshing, fields are checked on a grid inside the "
        "domain, boundary data along their edges (corners included) and fracture data along "
        "the fractures; after meshing, each one at the points where the solver evaluates it "
        "(cell centres, mesh nodes, boundary nodes, fracture face midpoints).",
        "",
        "**Numbers** (`float`, and the numbers in lists such as a disc's `center`): a number, "
        "or an expression of the scene `parameters` alone (no `x`, `y`, `z`, `t`), evaluated "
        "when the scene is read: `radius: a`, `center: [0.5, 0.5, \"h/2\"]`. A parameter may "
        "be an expression of the parameters above it (`parameters: {a: 0.4, b: a/2}`).",
        "",
        "**Names**: `name` and `probes[i].name` become file names (`results/<name>`, "
        "`probe_<name>.csv`): letters, digits, `_`, `-` and `.`, starting with a letter or "
        "digit.",
        "",
        "**Overrides**: `poromech run scene.yaml --set contact.formulation=mixed --set "
        "boundary_conditions.1.displacement=[0.001,0]` (values are parsed as YAML; list items "
        "by index). **PETSc options**: `solver.petsc` / `flow.petsc` / `coupling.petsc` in the "
        "scene (without the `mech_` / `flow_` / `coupling_` prefix), or on the command line "
        "with it (`-mech_snes_monitor`), which wins. Solver types (`*ksp_type`, `*pc_type`, "
        "`*snes_type`, `*snes_linesearch_type`, `*pc_factor_mat_solver_type`) are checked "
        "against the PETSc build before meshing, and so are numbers (`*rtol`, `*atol`, "
        "`*max_it`, …); also refused there: a Newton-type `coupling_snes_type` without its "
        "matrix-free Jacobian (`coupling.method: newtonkrylov` is the coupled Newton) and a "
        "one-step `mech_snes_type` (`ksponly`) with contact conditions, and a "
        "`mech_snes_linesearch_type` with poromech's contact search (it would search again "
        "along its step: `solver.line_search` chooses the search). Command-line options "
        "no solver used are reported at the end.",
        "",
        "**No key is ignored** (`poromech/scene/usage.py`): a section of another physics is "
        "refused (`flow` or `coupling` in a mechanics scene; `material`, `contact`, `solver`, "
        "`degree`, `boundary_conditions`, `fracture_pressure` or `coupling` in a flow scene). "
        "A key whose effect depends on another choice and has none under the scene's (e.g. "
        "`contact.theta` with `mixed`, `contact.beta_n` with `mixed` (which takes `beta_sm_n`), "
        "`contact.friction_coefficient` without Coulomb friction, `flow.biot_modulus` in a "
        "steady scene, `mesh.tip_size` without fractures, `flow.aperture` when every fracture "
        "has its own, a parameter no expression uses) is reported by a one-line warning "
        "`scene key '...' has no effect: <why>` and the run goes on, so that a scene varied "
        "with `--set` keeps working. `tests/test_scene_keys.py` walks every key of this "
        "reference for each physics and checks that it changes the results, or is refused, or "
        "is reported and changes nothing.",
        "",
    ]


def render() -> str:
    """The whole reference as Markdown."""
    return "\n".join(header() + section(Scene, "", {Scene})) + "\n"


def main() -> None:
    OUTPUT.parent.mkdir(parents=True, exist_ok=True)
    OUTPUT.write_text(render())


if __name__ == "__main__":
    main()
